//! The controller's link session: bytes in (frames decoded, blocks queued, controls
//! acted on, machines loaded), bytes out (acknowledgements, statuses and answers,
//! encoded when the link drains them), and the session's sequence numbers.
//!
//! Invariants: the controller accepts exactly the next sequence number; an accepted
//! block, a duplicate, or slots freed by a tick make one cumulative `Ack` owed, and a
//! periodic or requested status makes a `Status` owed: `transmit` encodes what is owed,
//! with the values of that moment, before draining, so neither `receive` nor `tick`
//! encodes them; `Nak`, `HelloAck`, `ControlAck` and the machine answers go at once.

use super::safety::UNHOMED;
use super::{Controller, LinkStats, Prepared, LINK_LOSS_TICKS, QUEUE_CAPACITY, TX_CAPACITY};
use crate::config::MachineConfig;
use crate::motion::block::PlannedBlock;
use crate::motion::planner::PushError;
use crate::units::TICK_HZ;
use crate::wire::ring::ByteRing;
use crate::wire::PlannedControl;
use crate::wire::{
    decode_block_into, decode_planned_control_into, encode_ack, encode_frame_with, encode_status,
    is_block, Alarm, AlarmCause, Control, CtrlMsg, HeldJob, HostMsgOf, JobMark, NakReason,
    NotBlock, State, Status, MAX_BODY, MAX_FRAME, NO_JOINT, PROTOCOL_VERSION,
};

impl Controller {
    /// Ticks since the last valid frame from the host.
    pub fn link_silence_ticks(&self) -> u32 {
        self.silent_ticks
    }

    /// The silence, ticks, at which the link watch acts next in the present state: the
    /// host timeout of a streamed job running or starved, else [`LINK_LOSS_TICKS`]. (A
    /// simulator running ahead of the wall clock must not pass it before its host has
    /// really been silent that long.)
    pub fn silence_limit(&self) -> u32 {
        if self.patience > 0 && matches!(self.state, State::Running | State::Starved) {
            self.patience_ticks()
        } else {
            LINK_LOSS_TICKS
        }
    }

    /// Turns the link-loss watch off (or on): only for a controller fed in the same
    /// process as its host, where there is no link to lose (`nc-send --check`).
    pub fn set_link_watch(&mut self, on: bool) {
        self.link_watch = on;
    }

    /// Link counters.
    pub fn link_stats(&self) -> LinkStats {
        self.stats
    }

    /// Feeds bytes received from the link.
    pub fn receive(&mut self, bytes: &[u8]) {
        let mut rest = bytes;
        while !rest.is_empty() {
            let (taken, frame) = self.reader.feed(rest);
            rest = &rest[taken..];
            let Some(frame) = frame else {
                continue;
            };
            let Ok((seq, message)) = frame else {
                self.corrupt();
                continue;
            };
            // (The sequence number first: for the block expected it alone says no.)
            if (seq.wrapping_sub(self.expected_seq) as i16) < 0 && self.session && is_block(message)
            {
                // A copy of a block accepted already (a resend, or one of the copies
                // a host sends on a noisy line): acknowledged, not decoded again.
                self.silent_ticks = 0;
                self.ack_due = true;
                continue;
            }
            // Messages are handled by reference: a block is some 250 bytes, not to be
            // moved around; blocks, the bulk of the traffic, are decoded by hand.
            let mut slot = core::mem::MaybeUninit::uninit();
            if let Some(block) = decode_block_into(message, &mut slot) {
                match block {
                    Ok(planned) => {
                        self.silent_ticks = 0;
                        self.block(seq, planned);
                    }
                    Err(_) => self.corrupt(),
                }
                continue;
            }
            // A control carrying a planned move (a jog, a probing move): decoded by
            // hand as blocks are; anything else with serde.
            match decode_planned_control_into(message, &mut slot) {
                Some(Ok((id, what, planned))) => {
                    self.silent_ticks = 0;
                    self.planned_control(id, what, planned);
                }
                Some(Err(_)) => self.corrupt(),
                None => match &postcard::from_bytes::<HostMsgOf<NotBlock>>(message) {
                    Ok(msg) => {
                        self.silent_ticks = 0;
                        self.handle(seq, msg);
                    }
                    Err(_) => self.corrupt(),
                },
            }
        }
    }

    /// A control carrying a planned move, as `handle` takes a control: acted on once
    /// per id, acknowledged every time.
    #[inline(never)]
    fn planned_control(&mut self, id: u16, what: PlannedControl, planned: &PlannedBlock) {
        if self.last_control != Some(id) {
            self.last_control = Some(id);
            if !self.mismatch {
                match what {
                    PlannedControl::Jog => self.jog(planned),
                    PlannedControl::Probe(mode) => self.probe_start(planned, mode),
                }
            }
        }
        // Encoded by `transmit`, as a block's `Ack` is: this receive has the move's
        // checks to pay for.
        self.control_ack_due = Some(id);
    }

    /// `Control::Jog`: acted on only when idle with nothing queued.
    fn jog(&mut self, planned: &PlannedBlock) {
        if self.state == State::Idle && !self.has_work() {
            // Refused (it does not start here, or is malformed): nothing moves, and the
            // host, which waits for the target, says so.
            let _ = self.planner.push_planned(planned, &self.machine, &self.kin);
        }
    }

    #[cold]
    pub(super) fn corrupt(&mut self) {
        self.stats.corrupt += 1;
        self.nak(NakReason::Corrupt);
    }

    /// Moves pending outgoing bytes into `out`; returns how many. The `Ack` and the
    /// status owed are encoded first (one of each, however many blocks were accepted,
    /// slots freed or statuses asked for since the last call), then the data
    /// recorder's streamed piece if one is due (encoded here rather than in the tick).
    pub fn transmit(&mut self, out: &mut [u8]) -> usize {
        self.send_due();
        if self.stream_due {
            self.record_stream();
        }
        self.tx.pop_into(out)
    }

    /// Adds a frame to the transmit buffer, made by `encode` from the next sequence
    /// number (into the buffer itself when the largest frame fits there in one piece,
    /// else into scratch, then copied); false when it does not fit (nothing added).
    pub(super) fn push_frame(
        &mut self,
        encode: impl FnOnce(u16, &mut [u8; MAX_BODY], &mut [u8; MAX_FRAME]) -> Option<usize>,
    ) -> bool {
        let scratch = (&mut self.tx_body, &mut self.tx_frame);
        push_frame_into(&mut self.tx, scratch, &mut self.tx_seq, encode)
    }

    pub(super) fn send(&mut self, msg: &CtrlMsg) {
        if !self.push_frame(|seq, body, out| encode_frame_with(seq, msg, body, out).ok()) {
            self.stats.tx_dropped += 1;
        }
    }

    /// Encodes the `Ack` and the status owed; what does not fit stays owed.
    pub(super) fn send_due(&mut self) {
        if self.ack_due {
            let acked = self.expected_seq.wrapping_sub(1);
            let (free, bends, ms) = (
                self.planner.free() as u16,
                self.planner.free_bends() as u16,
                self.buffered_ms(),
            );
            self.ack_due = !self.push_frame(|seq, body, out| {
                Some(encode_ack(seq, acked, free, bends, ms, body, out))
            });
        }
        if self.status_due {
            let s = self.status();
            self.reported = s.state;
            self.status_due =
                !self.push_frame(|seq, body, out| Some(encode_status(seq, &s, body, out)));
        }
        if let Some(id) = self.control_ack_due {
            let msg = CtrlMsg::ControlAck { id };
            if self.push_frame(|seq, body, out| encode_frame_with(seq, &msg, body, out).ok()) {
                self.control_ack_due = None;
            }
        }
        if self.probe_due && !self.status_due {
            if let Some(r) = self.probe.result() {
                let msg = CtrlMsg::Probe(r);
                self.probe_due =
                    !self.push_frame(|seq, body, out| encode_frame_with(seq, &msg, body, out).ok());
            }
        }
    }

    pub(super) fn nak(&mut self, reason: NakReason) {
        self.send(&CtrlMsg::Nak {
            expected: self.expected_seq,
            reason,
        });
    }

    pub(super) fn buffered_ms(&self) -> u32 {
        let ticks = self.planner.buffered_ticks() + self.exec.remaining_ticks();
        (ticks * 1000.0 / TICK_HZ as f32).min(u32::MAX as f32) as u32
    }

    /// A message other than a block (rare: not inlined into `receive`, whose block
    /// path it would slow down).
    #[inline(never)]
    pub(super) fn handle(&mut self, seq: u16, msg: &HostMsgOf<NotBlock>) {
        match *msg {
            HostMsgOf::Hello {
                version,
                machine,
                host,
            } => {
                // What the old session is owed goes first, as it was owed.
                self.send_due();
                if version != PROTOCOL_VERSION {
                    self.nak(NakReason::Version);
                    return;
                }
                // A job left by the earlier session stays the earlier host's until the
                // new one resumes or aborts it.
                if self.job_held() {
                    let first = self.orphan.map_or(self.host, |o| o.host);
                    self.orphan = Some(HeldJob {
                        host: first,
                        line: self.exec.line,
                        done: self.orphan.map_or(0, |o| o.done) + self.exec.completed,
                        queued: self.planner.len() as u16,
                        state: self.state,
                    });
                } else {
                    self.orphan = None;
                    self.patience = 0;
                    self.mark = JobMark::default();
                }
                self.host = host;
                self.session = true;
                self.expected_seq = seq.wrapping_add(1);
                self.last_control = None;
                self.exec.completed = 0;
                self.motion_ticks = 0;
                self.mismatch = machine != self.machine_id;
                if self.mismatch {
                    self.raise(Alarm {
                        cause: AlarmCause::MachineMismatch,
                        joint: NO_JOINT,
                        line: 0,
                    });
                }
                self.send(&CtrlMsg::HelloAck {
                    version: PROTOCOL_VERSION,
                    queue_capacity: QUEUE_CAPACITY as u16,
                    held: self.orphan,
                    mark: self
                        .orphan
                        .filter(|_| self.mark.program != 0)
                        .map(|_| self.mark),
                    machine: self.machine_id,
                });
            }
            HostMsgOf::Machine {
                id,
                offset,
                total,
                crc,
                ref data,
            } => {
                let fresh = self.last_control != Some(id);
                self.last_control = Some(id);
                self.send(&CtrlMsg::ControlAck { id });
                if !fresh {
                    return;
                }
                if self.has_work() {
                    self.send(&CtrlMsg::MachineRefused {
                        error: crate::wire::store::StoreError::Busy,
                    });
                    return;
                }
                match self
                    .assembler
                    .add(offset as usize, total as usize, crc, data)
                {
                    Ok(None) => {}
                    Ok(Some(config)) => {
                        // What is owed goes out before the controller restarts.
                        self.send_due();
                        self.load_machine(config)
                    }
                    Err(error) => self.send(&CtrlMsg::MachineRefused { error }),
                }
            }
            HostMsgOf::StatusRequest => {
                self.status_due = true;
                self.probe_due = self.probe.result().is_some();
            }
            HostMsgOf::Control { id, cmd } => {
                if self.last_control != Some(id) {
                    self.last_control = Some(id);
                    self.control(cmd);
                }
                self.send(&CtrlMsg::ControlAck { id });
            }
            HostMsgOf::Record { id, ref req } => self.record(id, req),
            HostMsgOf::Block(never) => match never {},
        }
    }

    /// A block message (sequenced).
    pub(super) fn block(&mut self, seq: u16, planned: &PlannedBlock) {
        if !self.session {
            self.nak(NakReason::NoSession);
            return;
        }
        let ahead = seq.wrapping_sub(self.expected_seq) as i16;
        if ahead < 0 {
            // A duplicate of an accepted frame: acknowledge, do not execute.
            self.ack_due = true;
            return;
        }
        if ahead > 0 {
            self.nak(NakReason::Gap);
            return;
        }
        if self.mismatch {
            self.nak(NakReason::MachineMismatch);
            return;
        }
        if self.orphan.is_some() {
            self.nak(NakReason::JobHeld);
            return;
        }
        if matches!(self.state, State::Alarm | State::EStop) {
            // Accepted and dropped: the job is over until the alarm is reset.
            self.expected_seq = seq.wrapping_add(1);
            self.ack_due = true;
            return;
        }
        match self.planner.push_planned(planned, &self.machine, &self.kin) {
            Ok(()) => {
                self.expected_seq = seq.wrapping_add(1);
                self.ack_due = true;
                self.job_open = true;
                self.mark.next_block = self.mark.next_block.wrapping_add(1);
                self.mark.last_line = planned.block.line;
            }
            Err(PushError::Full) => self.nak(NakReason::QueueFull),
            Err(PushError::Geometry(_)) => self.nak(NakReason::BadBlock),
        }
    }

    /// Adopts `config`: the controller restarts at its home pose, keeping the session.
    /// Rebuilt in place (no second controller on the stack).
    pub(super) fn load_machine(&mut self, config: MachineConfig) {
        let prepared = match Prepared::of(&config, self.board) {
            Ok(p) => p,
            Err(e) => {
                self.send(&CtrlMsg::MachineRefused {
                    error: crate::wire::store::StoreError::Invalid(e),
                });
                return;
            }
        };
        let (tx_seq, expected_seq, last_control, stats) = (
            self.tx_seq,
            self.expected_seq,
            self.last_control,
            self.stats,
        );
        let mut tx = crate::wire::ring::ByteRing::default();
        core::mem::swap(&mut tx, &mut self.tx);
        // SAFETY: `self` is a valid, aligned controller; `write` overwrites every field
        // and nothing in it needs dropping.
        unsafe { Self::write(self, config, &prepared) };
        core::mem::swap(&mut tx, &mut self.tx);
        (
            self.tx_seq,
            self.expected_seq,
            self.last_control,
            self.stats,
        ) = (tx_seq, expected_seq, last_control, stats);
        self.session = true;
        self.store_pending = true;
        self.send(&CtrlMsg::MachineLoaded {
            machine: self.machine_id,
        });
    }

    /// Identity of the machine configuration in force.
    pub fn machine_id(&self) -> u32 {
        self.machine_id
    }

    /// A configuration adopted from the host that the firmware should now write to
    /// flash; returned once.
    pub fn take_store_request(&mut self) -> Option<&MachineConfig> {
        if core::mem::replace(&mut self.store_pending, false) {
            Some(&self.machine)
        } else {
            None
        }
    }

    pub(super) fn control(&mut self, cmd: Control) {
        if self.mismatch && !matches!(cmd, Control::Stop | Control::Abort) {
            return;
        }
        match cmd {
            Control::Hold => {
                if matches!(self.state, State::Running | State::Idle | State::Starved) {
                    self.planner.hold = true;
                    self.exec.replan(&mut self.planner);
                    self.state = State::Hold;
                }
            }
            Control::Resume => self.resume(),
            Control::Abort => {
                self.orphan = None;
                self.mark = JobMark::default();
                self.job_open = false;
                self.patience = 0;
                self.clear_held_link_loss();
                if matches!(
                    self.state,
                    State::Running | State::Hold | State::Idle | State::Starved
                ) {
                    self.planner.hold = true;
                    self.abort_pending = true;
                    self.exec.replan(&mut self.planner);
                    self.state = State::Hold;
                } else if self.state == State::Homing {
                    self.cancel_homing();
                    self.state = State::Alarm;
                    self.alarm = Some(UNHOMED);
                }
            }
            Control::AlarmReset => self.reset_alarm(),
            Control::FeedOverride(p) => {
                self.planner.feed_override = p.clamp(1, 200);
                self.exec.replan(&mut self.planner);
            }
            Control::Jog(planned) => self.jog(&planned),
            Control::Stop => {
                if self.state == State::Homing {
                    self.cancel_homing();
                }
                self.raise(Alarm {
                    cause: AlarmCause::Aborted,
                    joint: NO_JOINT,
                    line: self.exec.line,
                })
            }
            Control::Probe { planned, mode } => self.probe_start(&planned, mode),
            Control::Home => self.home(),
            Control::EndJob => {
                self.job_open = false;
                self.mark = JobMark::default();
                if self.state == State::Starved {
                    self.state = State::Idle;
                    self.patience = 0;
                }
            }
            Control::BeginJob {
                host_timeout_ms,
                mark,
            } => {
                use super::{MAX_HOST_TIMEOUT_MS, MIN_HOST_TIMEOUT_MS, PATIENCE_UNIT_TICKS};
                if self.orphan.is_some() {
                    // Only the rest of the held job's own program adopts it (it stays
                    // held until `Resume`); anything else leaves it as it is.
                    let own = &self.mark;
                    if mark.program == 0
                        || mark.program != own.program
                        || mark.next_block != own.next_block
                    {
                        return;
                    }
                    self.orphan = None;
                    self.job_open = true;
                } else {
                    self.mark = mark;
                }
                let unit_ms = PATIENCE_UNIT_TICKS * 1000 / TICK_HZ;
                self.patience = match host_timeout_ms {
                    0 => 0,
                    ms => (ms.clamp(MIN_HOST_TIMEOUT_MS, MAX_HOST_TIMEOUT_MS) / unit_ms) as u16,
                };
            }
        }
    }

    /// `Control::Resume`: adopts a job left by an earlier session, ends a starved
    /// wait, and continues after a hold or a pause.
    #[inline(always)]
    fn resume(&mut self) {
        if matches!(self.state, State::Hold | State::Running | State::Starved) {
            // Resuming adopts a job left by an earlier session (held, starved,
            // or still running out its queue), and clears the link loss or
            // host timeout that held it. An adopted job is complete with what
            // is queued: its new host sends none of its blocks.
            if self.orphan.take().is_some() {
                self.job_open = false;
            }
            self.clear_held_link_loss();
        }
        if self.state == State::Starved {
            self.state = self.rest_state();
        }
        if self.state == State::Hold && !self.abort_pending {
            self.planner.hold = false;
            self.exec.paused = false;
            self.exec.replan(&mut self.planner);
            // A pause or hold with nothing after it (M0 then M2): idle at once.
            // Running with nothing to run would wait for a tick to turn idle,
            // and a tick comes only while there is work (`has_work`).
            self.state = if self.path_moving() {
                State::Running
            } else {
                self.rest_state()
            };
        }
    }

    /// A link loss or host timeout raised over a held job (the job was kept) is over
    /// once a host acts on the job.
    fn clear_held_link_loss(&mut self) {
        if self.state == State::Hold && self.held_for_silence() {
            self.alarm = None;
        }
    }

    /// A status snapshot.
    pub fn status(&self) -> Status {
        Status {
            state: self.state,
            line: self.exec.line,
            blocks_done: self.exec.completed,
            motion_ticks: self.motion_ticks,
            pose: self.exec.pose,
            joints: self.joints,
            measured: self.measured(),
            speed: ((self.exec.speed as i128 * TICK_HZ as i128) >> 32) as i64,
            buffered_ms: self.buffered_ms(),
            free_slots: self.planner.free() as u16,
            free_bends: self.planner.free_bends() as u16,
            feed_override: self.planner.feed_override,
            alarm: self.alarm,
            homed: self.homed,
            orphan: self.orphan.is_some(),
            probe_input: self.last.probe,
            probes: self.probe.result().map_or(0, |r| r.count),
        }
    }
}

/// [`Controller::push_frame`] on the transmit side's parts (so that `encode` may borrow
/// the rest of the controller).
pub(super) fn push_frame_into(
    tx: &mut ByteRing<TX_CAPACITY>,
    (body, frame): (&mut [u8; MAX_BODY], &mut [u8; MAX_FRAME]),
    tx_seq: &mut u16,
    encode: impl FnOnce(u16, &mut [u8; MAX_BODY], &mut [u8; MAX_FRAME]) -> Option<usize>,
) -> bool {
    let seq = *tx_seq;
    let added = match tx.tail_mut::<MAX_FRAME>() {
        Some(room) => encode(seq, body, room).map(|n| tx.commit(n)),
        None => encode(seq, body, frame)
            .filter(|&n| tx.push_slice(&frame[..n]))
            .map(drop),
    };
    if added.is_some() {
        *tx_seq = seq.wrapping_add(1);
    }
    added.is_some()
}
