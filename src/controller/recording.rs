//! The controller's side of the data recorder ([`crate::drive::recorder`]): arming it
//! and reading it out over the link (`HostMsg::Record`), its events and its samples at the tick.
//!
//! At the tick the signals are formed from what the controller holds: a servo joint's
//! commanded position is its channel's target for the end of this tick and its
//! measured position the encoder's count at the tick edge (counts, the homing offset
//! taken off, as `Status::measured`), the following error their difference; a
//! stepper's are both its steps emitted (no feedback: no following error), its output
//! its steps this tick (signed). A servo channel's DAC code is the mean of the tick's
//! servo periods, the contour errors (path and tool direction) the last period's.
//! Sampling every servo period, the servo side stages each period's sample, packed as
//! the ring keeps it: the per-joint signals of servo joints and the contour errors,
//! plus what the tick asked to add (`Outputs::servo_record`, `servo_record_add`: the
//! joints' zeros off the positions, and the values of the other signals, held over
//! the periods; `pacing::ServoPacer::staged`), and the caller hands the tick's ten
//! over after the next tick ([`Controller::record_servo`]).

use super::pacing::{HELD, HELD_NARROW, NOT_SERVO};
use super::session::push_frame_into;
use super::Controller;
use crate::config::{Drive, MAX_JOINTS, MAX_SERVOS};
use crate::drive::excite::{Excite, Signal as ExciteSignal};
use crate::drive::recorder::{
    Capture, Phase, RecorderError, Reply, Row, Setup, Signal, MAX_SIGNALS, REPLY_HEADER,
};
use crate::drive::servo::SETPOINT_FRAC_BITS;
use crate::units::TICK_HZ;
use crate::wire::store::CHUNK_BYTES;
use crate::wire::{
    encode_record, CtrlMsg, State, MAX_FRAME, RECORD_ARM, RECORD_CHUNK, RECORD_DISARM,
    RECORD_EXCITE, RECORD_READ,
};

/// Streaming: ticks a sample may wait before a piece goes out not full.
pub const STREAM_WAIT: u8 = 10;
/// Streaming: bytes of the link's send buffer kept free for everything else.
pub const STREAM_HEADROOM: usize = 768;

impl Controller {
    /// Is the recorder sampling (armed, filling after its trigger, or streaming), or a
    /// test signal running? Time passes for them even at rest: a simulator behind a
    /// port ticks on while they are.
    pub fn recording(&self) -> bool {
        self.excite.is_some() || self.recorder.wants(false) || self.recorder.wants(true)
    }

    /// Is the recorder streaming, or a test signal running? Both need time to pass
    /// to mean anything, even for a simulator that otherwise ticks only while there
    /// is work (an armed capture fills with the ticks that run anyway).
    pub fn streams(&self) -> bool {
        self.excite.is_some() || self.recorder.capture().phase == Phase::Streaming
    }

    /// `HostMsg::Record`: a read, answered at once, or a control (arm, disarm),
    /// acted on once per id and acknowledged; a bad request is answered with
    /// `CtrlMsg::Record` naming what is wrong.
    #[inline(never)]
    pub(super) fn record(&mut self, id: u16, req: &[u8]) {
        let (what, arg) = match req.split_first() {
            Some((&what, arg)) => (what, arg),
            None => (RECORD_READ, &[][..]),
        };
        if what == RECORD_READ {
            return self.record_reply(u32::from_le_bytes(arg.try_into().unwrap_or([0; 4])));
        }
        if self.last_control != Some(id) {
            self.last_control = Some(id);
            let result = match what {
                RECORD_ARM => Setup::unpack(arg).and_then(|setup| self.recorder.arm(&setup)),
                RECORD_DISARM => {
                    self.recorder.disarm();
                    self.excite = None;
                    Ok(())
                }
                RECORD_EXCITE => Excite::unpack(arg)
                    .map_err(|at| RecorderError::Malformed { at: at + 1 })
                    .and_then(|e| self.excite_start(e)),
                _ => Err(RecorderError::Malformed { at: 255 }),
            };
            self.record_refused = result.err();
            if self.record_refused.is_some() {
                self.record_reply(0);
            }
        }
        self.send(&CtrlMsg::ControlAck { id });
    }

    /// Answers a read (`HostMsg::Record`): where the recorder is, and the capture's bytes
    /// from `offset` once it is done.
    #[inline(never)]
    pub(super) fn record_reply(&mut self, offset: u32) {
        let offset = offset as usize;
        let n = self
            .recorder
            .readable(offset)
            .min(CHUNK_BYTES - REPLY_HEADER);
        let setup = self.recorder.setup();
        let reply = Reply {
            capture: self.recorder.capture(),
            signals: setup.signals,
            count: setup.count,
            servo: setup.servo,
            decimate: setup.decimate,
            refused: self.record_refused,
            offset: offset as u32,
            streamed: false,
        };
        let sent = self.push_record(&reply, n, |recorder, out| {
            recorder.read(offset, out);
        });
        if !sent {
            self.stats.tx_dropped += 1;
        }
    }

    /// Adds a `CtrlMsg::Record` frame to the transmit buffer: `reply`'s header, then
    /// `n` bytes that `copy` writes (from the recorder) straight into the frame's body
    /// ([`encode_record`]); false when it does not fit (nothing added).
    fn push_record(
        &mut self,
        reply: &Reply,
        n: usize,
        copy: impl FnOnce(&crate::drive::recorder::Recorder, &mut [u8]),
    ) -> bool {
        let recorder = &self.recorder;
        let fill = |out: &mut [u8]| {
            let (header, samples) = out.split_at_mut(REPLY_HEADER.min(out.len()));
            if let Ok(header) = <&mut [u8; REPLY_HEADER]>::try_from(header) {
                reply.pack(header);
            }
            copy(recorder, samples);
        };
        let len = REPLY_HEADER + n;
        let scratch = (&mut self.tx_body, &mut self.tx_frame);
        let encode = |seq, b: &mut _, out: &mut _| encode_record(seq, len, fill, b, out);
        push_frame_into(&mut self.tx, scratch, &mut self.tx_seq, encode)
    }

    /// The tick's part: events, then a sample when one is wanted (last in the tick),
    /// then, streaming, a piece of the samples not sent yet.
    #[inline(never)]
    pub(super) fn record_tick(&mut self) {
        // A job starts when its first block is queued, or (a move sent alone, as MDI
        // and jogs are) when the machine starts running.
        let job = self.job_open || self.state == State::Running;
        self.recorder
            .observe(job, self.exec.line, self.alarm.is_some());
        self.out.servo_record = [NOT_SERVO; MAX_SIGNALS];
        self.out.servo_record_add = [0; MAX_SIGNALS];
        if self.recorder.wants(true) {
            self.servo_plan();
            return;
        }
        if !self.recorder.wants(false) {
            return;
        }
        let mut values = [0i32; MAX_SIGNALS];
        for (v, s) in values.iter_mut().zip(self.recorder.signals()) {
            *v = self.signal(*s);
        }
        self.recorder.sample(&values);
        if self.recorder.capture().phase == Phase::Streaming {
            self.stream_tick();
        }
    }

    /// Streaming, each tick: a piece is due once the waiting samples fill one or have
    /// waited [`STREAM_WAIT`] ticks. It is encoded when the link asks for bytes
    /// (`Controller::transmit`), not in the tick.
    fn stream_tick(&mut self) {
        self.stream_wait = self.stream_wait.saturating_add(1);
        let c = self.recorder.capture();
        let full = c.samples as usize >= RECORD_CHUNK / c.width.max(1) as usize;
        self.stream_due = c.samples > 0 && (full || self.stream_wait >= STREAM_WAIT);
    }

    /// The recorder samples every servo period: after each tick, hand it the servo
    /// side's samples ([`Controller::record_servo`]).
    pub fn records_servo(&self) -> bool {
        self.recorder.wants(true)
    }

    /// The recorder's signals as the servo side samples them, into the outputs
    /// (`Outputs::servo_record`, `servo_record_add`): a servo joint's per-joint
    /// signal with its channel in place of the joint (a position with the joint's
    /// zero to take off), the contour errors as they are, the rest [`HELD`] or
    /// [`HELD_NARROW`] with this tick's value, held over its periods.
    fn servo_plan(&mut self) {
        let mut ids = [NOT_SERVO; MAX_SIGNALS];
        let mut add = [0i32; MAX_SIGNALS];
        for (i, &id) in self.recorder.signals().iter().enumerate() {
            let kind = id >> 4;
            let j = (id & 0x0f) as usize;
            let drive = self.machine.joints.get(j).map(|jc| jc.drive);
            ids[i] = match (kind, drive) {
                (0..=3, Some(Drive::Servo { channel })) => {
                    if kind <= 1 {
                        add[i] = (self.offset[j % MAX_JOINTS] as i32).wrapping_neg();
                    }
                    kind << 4 | (channel & 0x0f)
                }
                (9 | 10, _) => id,
                _ => {
                    add[i] = self.signal(id);
                    match Signal::from_id(id).map(Signal::width) {
                        Some(2) => HELD_NARROW,
                        _ => HELD,
                    }
                }
            };
        }
        self.out.servo_record = ids;
        self.out.servo_record_add = add;
    }

    /// The servo side's samples of a tick (`rows`, periods in time order, packed),
    /// staged for the signals `ids` ([`crate::controller::pacing::ServoPacer::staged`]),
    /// stored when the recorder samples every servo period and they are of its
    /// signals as this tick samples them (the two ticks after arming have none).
    #[inline(never)]
    pub fn record_servo(&mut self, ids: &[u8; MAX_SIGNALS], rows: &[Row]) {
        if !self.recorder.wants(true) || *ids != self.out.servo_record {
            return;
        }
        for row in rows {
            self.recorder.sample_packed(row);
        }
        if self.recorder.capture().phase == Phase::Streaming {
            self.stream_tick();
        }
    }

    /// Streaming, when the link asks for bytes and a piece is due
    /// ([`Controller::stream_tick`]): sends one piece of the samples not sent yet (one
    /// a tick at most: a stream of more than 132 bytes of samples a millisecond loses
    /// samples, as a gap in their numbers),
    /// only while the link's send buffer keeps room for [`STREAM_HEADROOM`] bytes
    /// besides (the job's acknowledgements and status come first). Samples that wait
    /// too long are overwritten in the ring: the host sees the gap in their numbers.
    pub(super) fn record_stream(&mut self) {
        let width = self.recorder.capture().width.max(1) as usize;
        let waiting = self.recorder.capture().samples as usize;
        if self.recorder.capture().phase != Phase::Streaming || waiting == 0 {
            self.stream_due = false;
            return;
        }
        if self.tx.free() < STREAM_HEADROOM + MAX_FRAME {
            return;
        }
        let (first, n) = self.recorder.unsent(CHUNK_BYTES - REPLY_HEADER);
        let setup = self.recorder.setup();
        let reply = Reply {
            capture: Capture {
                phase: Phase::Streaming,
                samples: n,
                pre: 0,
                width: width as u16,
            },
            signals: setup.signals,
            count: setup.count,
            servo: setup.servo,
            decimate: setup.decimate,
            refused: None,
            offset: first,
            streamed: true,
        };
        // The header and the samples are written straight into the frame's body.
        let bytes = n as usize * width;
        if self.push_record(&reply, bytes, |recorder, out| recorder.copy_unsent(out)) {
            self.recorder.sent(n);
            self.stream_wait = 0;
            // One piece a tick at most: the link's work for the stream stays bounded
            // (132 bytes of samples a millisecond), whatever the tick asked.
            self.stream_due = false;
        }
    }

    /// Checks a test signal's request against the machine and starts it.
    fn excite_start(&mut self, e: Excite) -> Result<(), RecorderError> {
        let joint = e.joint;
        let Some(Drive::Servo { channel }) =
            self.machine.joints.get(joint as usize).map(|j| j.drive)
        else {
            return Err(RecorderError::ExciteJoint { joint });
        };
        let jc = self.machine.joints[joint as usize];
        let limit = self.machine.servo.gains[channel as usize % MAX_SERVOS].min_ferror;
        if e.amplitude >= limit {
            let limit = limit.min(u16::MAX as u32) as u16;
            return Err(RecorderError::ExciteAmplitude { joint, limit });
        }
        // A machine without home switches cannot home: unlocked, it counts as homed.
        let switches = self.machine.joints.iter().any(|j| j.homing.enabled());
        let homed = self.homed || (!switches && !self.locked);
        let idle = self.state == State::Idle && homed && !self.job_open;
        if !idle || !self.planner.is_empty() || self.moving() {
            return Err(RecorderError::ExciteBusy);
        }
        let q = self.joints[joint as usize];
        let reach = jc.scale.position_of(e.amplitude as i64 + 1);
        if q - reach < jc.min || q + reach > jc.max {
            return Err(RecorderError::ExciteTravel { joint });
        }
        self.excite = Some(ExciteSignal::new(e));
        Ok(())
    }

    /// The test signal's part of the tick (after the outputs): its offset on the
    /// joint's servo target; it stops at once on an alarm or when anything else would
    /// move.
    #[inline(never)]
    pub(super) fn excite_tick(&mut self) {
        let busy = self.state != State::Idle || self.job_open || !self.planner.is_empty();
        let Some(sig) = self.excite.as_mut() else {
            return;
        };
        let j = sig.joint();
        let offset = if busy || self.alarm.is_some() {
            None
        } else {
            sig.offset()
        };
        match (offset, self.machine.joints.get(j).map(|jc| jc.drive)) {
            (Some(o), Some(Drive::Servo { channel })) => {
                self.out.servo_target[channel as usize % MAX_SERVOS] +=
                    (o as i64) << SETPOINT_FRAC_BITS;
            }
            _ => self.excite = None,
        }
    }

    /// The value of the signal of wire id `id` (checked by the recorder's `arm`:
    /// kind `id >> 4`, joint `id & 15`; see `drive::recorder::Signal`). Positions are
    /// actuator counts or steps from the joint's zero, as `Status::measured`, kept to
    /// their low 32 bits.
    #[inline(never)]
    fn signal(&self, id: u8) -> i32 {
        let j = (id & 0x0f) as usize;
        let kind = id >> 4;
        if kind >= 4 {
            return match kind {
                // Q32 units a tick to units a second (shifted first: no overflow).
                8 => (((self.exec.speed >> 12) * TICK_HZ as i64) >> 20) as i32,
                9 => norm(&self.last.contour[..3]),
                10 => norm(&self.last.contour[3..]),
                11 => self.exec.line as i32,
                12 => self.state as i32,
                _ => 0,
            };
        }
        let (Some(jc), true) = (self.machine.joints.get(j), j < MAX_JOINTS) else {
            return 0;
        };
        // Commanded, measured: a servo joint's target for the end of this tick and its
        // encoder at the tick edge; a stepper's steps emitted, both (no feedback).
        let (cmd, at) = match jc.drive {
            Drive::Servo { channel } => {
                let c = channel as usize % MAX_SERVOS;
                if kind == 3 {
                    return self.last.servo_dac[c] as i32;
                }
                (
                    self.out.servo_target[c] >> SETPOINT_FRAC_BITS,
                    self.last.encoder_counts[c],
                )
            }
            Drive::Stepper { .. } => {
                if kind == 3 {
                    let t = &self.trains[j];
                    return if t.forward {
                        t.count as i32
                    } else {
                        -(t.count as i32)
                    };
                }
                let s = self.steps.steps(j);
                (s, s)
            }
        };
        let off = self.offset[j];
        match kind {
            0 => (cmd - off) as i32,
            1 => (at - off) as i32,
            2 => (cmd - at) as i32,
            _ => 0,
        }
    }
}

/// The length of a vector of whole nm or µ°, rounded (saturating).
fn norm(v: &[i32]) -> i32 {
    let sq: f32 = v.iter().map(|&x| x as f32 * x as f32).sum();
    (crate::math::sqrtf(sq) + 0.5) as i32
}

const _: () = assert!(MAX_JOINTS <= 16);
