//! Probing moves (`Control::Probe`): starting one, watching the probe each tick, and
//! ending it (the latch itself is [`crate::drive::probe`]).

use super::Controller;
use crate::config::{Drive, MAX_JOINTS};
use crate::drive::probe::{ProbeMode, LATCH_FRAC_BITS};
use crate::motion::block::PlannedBlock;
use crate::wire::{Alarm, AlarmCause, State, NO_JOINT};

impl Controller {
    /// Each stepper joint's steps emitted (the trains computed before this tick's),
    /// from its zero, × 2^[`LATCH_FRAC_BITS`] (servo joints: 0, their encoders are read
    /// instead). A stepper stands on whole steps: between two tick starts it is taken
    /// along the steps its train makes in the tick.
    fn stepper_refs(&self) -> [i64; MAX_JOINTS] {
        let mut r = [0; MAX_JOINTS];
        for (j, jc) in self.machine.joints.iter().enumerate() {
            if let Drive::Stepper { .. } = jc.drive {
                r[j] = (self.steps.steps(j) - self.offset[j]) << LATCH_FRAC_BITS;
            }
        }
        r
    }

    /// Where each actuator is at this tick's start, from its zero, ×
    /// 2^[`LATCH_FRAC_BITS`]: a servo's encoder as read at the tick edge, a stepper's
    /// steps up to the train of two ticks ago (which has just run), kept by the last
    /// tick.
    fn actuators_now(&self, counts: &[i64; crate::config::MAX_SERVOS]) -> [i64; MAX_JOINTS] {
        let mut a = self.probe_ref;
        for (j, jc) in self.machine.joints.iter().enumerate() {
            if let Drive::Servo { channel } = jc.drive {
                a[j] = (counts[channel as usize] - self.offset[j]) << LATCH_FRAC_BITS;
            }
        }
        a
    }

    /// `Control::Probe`: acted on at rest with nothing queued, like a jog.
    pub(super) fn probe_start(&mut self, planned: &PlannedBlock, mode: ProbeMode) {
        if !matches!(self.state, State::Idle | State::Starved) || self.has_work() {
            return;
        }
        if self.last.probe == mode.sought() {
            self.raise(Alarm {
                cause: AlarmCause::ProbeAtStart,
                joint: NO_JOINT,
                line: planned.block.line,
            });
            return;
        }
        // Refused (it does not start here, or is malformed): nothing moves, and the
        // host, which waits for the result, says so.
        if self
            .planner
            .push_planned(planned, &self.machine, &self.kin)
            .is_ok()
        {
            self.probe_ref = self.stepper_refs();
            self.probe.arm(mode);
        }
    }

    /// Before the motion of a tick with a probing move armed: takes the probe's
    /// sample, and stops the move on the path once the sought change is confirmed.
    pub(super) fn probe_tick(&mut self) {
        if self.state == State::Alarm || self.state == State::EStop {
            self.probe.disarm();
            return;
        }
        let now = self.actuators_now(&self.last.encoder_counts);
        let (raw, edge, active) = (
            self.last.probe_raw,
            self.last.probe_edge_us,
            self.last.probe,
        );
        if self.probe.tick(&now, raw, edge, active) {
            self.probe_due = true;
            self.planner.hold = true;
            self.probe_stop = true;
            self.exec.replan(&mut self.planner);
        }
    }

    /// After the motion of a tick: keeps the steppers' commanded positions for the
    /// latch, ends a stopped move, and ends a move that reached its end untouched.
    pub(super) fn probe_after(&mut self) {
        if self.probe_stop && self.exec.stopped() {
            // The move is complete where it stopped: its rest is dropped.
            self.exec.stop();
            self.exec.completed = self.exec.completed.wrapping_add(1);
            self.planner.clear(self.exec.pose);
            self.planner.hold = false;
            self.probe_stop = false;
        }
        if !self.probe.armed() {
            return;
        }
        // Before this tick's trains are computed: the next tick's start.
        self.probe_ref = self.stepper_refs();
        if !self.path_moving() {
            // The end: where the actuators will be once the last trains have run (a
            // stepper on a whole step).
            let mut end = [0; MAX_JOINTS];
            for (j, jc) in self.machine.joints.iter().enumerate() {
                let scale = self.steps.scale(j);
                end[j] = match jc.drive {
                    Drive::Stepper { .. } => scale.steps_at(self.joints[j]) << LATCH_FRAC_BITS,
                    Drive::Servo { .. } => scale.steps_at_frac(self.joints[j], LATCH_FRAC_BITS),
                };
            }
            self.probe.finish(false, &end);
            self.probe_due = true;
        }
    }
}
