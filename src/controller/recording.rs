//! The controller's side of the data recorder ([`crate::drive::recorder`]): arming it
//! and reading it out over the link (`Control::RecordArm`, `Control::RecordDisarm`,
//! `HostMsg::RecordRead`), its events and its samples at the tick.
//!
//! At the tick the signals are formed from what the controller holds: a joint's
//! commanded position is its actuator reference (counts or steps, the homing offset
//! taken off, as `Status::measured`), the following error commanded − measured, the
//! output a stepper's steps this tick (signed); a servo channel's DAC code, the
//! contour error and its direction are the servo period's and read 0 at the tick.
//! Sampling every servo period is refused until the servo side samples
//! ([`SERVO_SAMPLING`]).

use super::Controller;
use crate::config::{Drive, MAX_JOINTS};
use crate::drive::recorder::{Event, Setup, Signal, MAX_SIGNALS};
use crate::drive::servo::SETPOINT_FRAC_BITS;
use crate::units::TICK_HZ;
use crate::wire::{CtrlMsg, RecordReply, State, RECORD_CHUNK};

/// The servo side samples for the recorder (not yet: a request for the servo period
/// is refused as `RecorderError::Decimation`'s neighbour, `ServoPeriod`).
pub const SERVO_SAMPLING: bool = false;

/// What the recorder last saw of the events it waits for.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(super) struct Seen {
    job: bool,
    line: u32,
    alarm: bool,
}

impl Controller {
    /// `Control::RecordArm`: arms the recorder, or answers why not.
    pub(super) fn record_arm(&mut self, setup: &Setup) {
        let result = if setup.servo && !SERVO_SAMPLING {
            Err(crate::drive::recorder::RecorderError::ServoPeriod)
        } else {
            self.recorder.arm(setup)
        };
        self.record_refused = result.err();
        if self.record_refused.is_some() {
            self.record_reply(0);
        }
        self.seen = Seen {
            job: self.job_open,
            line: self.exec.line,
            alarm: self.alarm.is_some(),
        };
    }

    /// `Control::RecordDisarm`.
    pub(super) fn record_disarm(&mut self) {
        self.recorder.disarm();
        self.record_refused = None;
    }

    /// Answers `HostMsg::RecordRead`: where the recorder is, and the capture's bytes
    /// from `offset` once it is done.
    #[inline(never)]
    pub(super) fn record_reply(&mut self, offset: u32) {
        let mut data = [0; RECORD_CHUNK];
        let n = self.recorder.read(offset as usize, &mut data);
        let setup = self.recorder.setup();
        let msg = CtrlMsg::Record(RecordReply {
            capture: self.recorder.capture(),
            signals: heapless::Vec::from_slice(&setup.signals[..setup.count as usize])
                .unwrap_or_default(),
            servo: setup.servo,
            decimate: setup.decimate,
            refused: self.record_refused,
            offset,
            data: heapless::Vec::from_slice(&data[..n]).unwrap_or_default(),
        });
        self.send(&msg);
    }

    /// The tick's part: events, then a sample when one is wanted (last in the tick).
    #[inline(never)]
    pub(super) fn record_tick(&mut self) {
        let now = Seen {
            job: self.job_open,
            line: self.exec.line,
            alarm: self.alarm.is_some(),
        };
        if now.job && !self.seen.job {
            self.recorder.event(Event::JobStart);
        }
        if now.line != self.seen.line {
            self.recorder.event(Event::Line(now.line));
        }
        if now.alarm && !self.seen.alarm {
            self.recorder.event(Event::Alarm);
        }
        self.seen = now;
        if !self.recorder.wants(false) {
            return;
        }
        let mut values = [0i32; MAX_SIGNALS];
        for (v, s) in values.iter_mut().zip(self.recorder.signals()) {
            *v = self.signal(*s);
        }
        self.recorder.sample(&values);
    }

    fn signal(&self, s: Signal) -> i32 {
        let joints = self.machine.joints.len();
        let commanded = |j: usize| {
            (self.actuator_q16(j, self.joints[j]) >> SETPOINT_FRAC_BITS) - self.offset[j]
        };
        let measured = |j: usize| self.measured()[j];
        let v: i64 = match s {
            Signal::Commanded(j) if (j as usize) < joints => commanded(j as usize),
            Signal::Measured(j) if (j as usize) < joints => measured(j as usize),
            Signal::FollowingError(j) if (j as usize) < joints => {
                commanded(j as usize) - measured(j as usize)
            }
            Signal::Output(j) if (j as usize) < joints => {
                match self.machine.joints[j as usize].drive {
                    Drive::Stepper { .. } => {
                        let t = &self.trains[j as usize];
                        if t.forward {
                            t.count as i64
                        } else {
                            -(t.count as i64)
                        }
                    }
                    Drive::Servo { .. } => 0,
                }
            }
            Signal::PathSpeed => ((self.exec.speed as i128 * TICK_HZ as i128) >> 32) as i64,
            Signal::Line => self.exec.line as i64,
            Signal::State => state_index(self.state) as i64,
            _ => 0,
        };
        v.clamp(i32::MIN as i64, i32::MAX as i64) as i32
    }
}

/// `State`'s index, as the wire numbers it.
fn state_index(s: State) -> u8 {
    match s {
        State::Idle => 0,
        State::Running => 1,
        State::Hold => 2,
        State::Homing => 3,
        State::Alarm => 4,
        State::EStop => 5,
        State::Starved => 6,
    }
}

const _: () = assert!(MAX_JOINTS <= 16);
