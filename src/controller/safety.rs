//! The controller's safety: the alarms, how a fault stops the machine, the lock after
//! a reset, homing, and the servo loops' restart after a trip (see the table in the
//! parent module's documentation).
//!
//! Invariants: the first alarm is kept (an e-stop replaces any other); a fault stops
//! the motion on the path at the planned deceleration, then drops the queue; nothing
//! moves until `AlarmReset`, which is refused while the cause is still there; the
//! position the controller believes is the position the drives have.

use super::{Controller, Inputs, LINK_LOSS_TICKS};
use crate::config::{Drive, MAX_SERVOS};
use crate::drive::homing::{HomeEvent, HomeInputs};
use crate::drive::servo::Trip;
use crate::kinematics::{Kinematics, Unreachable};
use crate::wire::{Alarm, AlarmCause, State, NO_JOINT};

pub(super) fn alarm_of(why: Unreachable, line: u32) -> Alarm {
    let (cause, joint) = match why {
        Unreachable::JointLimit { joint } => (AlarmCause::JointLimit, joint),
        Unreachable::Singular => (AlarmCause::Singularity, NO_JOINT),
        _ => (AlarmCause::Unreachable, NO_JOINT),
    };
    Alarm { cause, joint, line }
}

/// The lock after a reset: no joint, no NC line.
pub(super) const UNHOMED: Alarm = Alarm {
    cause: AlarmCause::Unhomed,
    joint: NO_JOINT,
    line: 0,
};

/// Lowest set bit of `bits` among the first `n`.
pub(super) fn first_bit(bits: u16, n: usize) -> Option<usize> {
    (0..n).find(|j| bits & (1 << j) != 0)
}

impl Controller {
    /// Unlocks a controller locked after a reset, at the position it believes it is at
    /// (what `AlarmReset` does to the `Unhomed` alarm).
    pub fn unlock(&mut self) {
        if self.alarm.map(|a| a.cause) == Some(AlarmCause::Unhomed) {
            self.locked = false;
            self.alarm = None;
            self.state = State::Idle;
        }
    }

    /// Raises an alarm found at start-up (the firmware: a watchdog reset); the
    /// controller stays locked.
    pub fn raise_at_start(&mut self, cause: AlarmCause) {
        self.alarm = Some(Alarm {
            cause,
            joint: NO_JOINT,
            line: 0,
        });
        self.state = State::Alarm;
    }

    /// `AlarmReset`: refused while the cause is still there (e-stop or a drive fault
    /// active) or the motion is still stopping.
    pub(super) fn reset_alarm(&mut self) {
        if self.state == State::Hold && self.held_for_silence() {
            // The link loss or host timeout over a held job: the job stays held.
            self.alarm = None;
            return;
        }
        if !matches!(self.state, State::Alarm | State::EStop) || self.mismatch || self.stopping {
            return;
        }
        let n = self.machine.joints.len();
        if self.last.estop || first_bit(self.last.drive_fault, n).is_some() {
            return;
        }
        let servo_tripped = self.last.servo_trip.iter().any(Option::is_some);
        let cause = self.alarm.map(|a| a.cause);
        if cause == Some(AlarmCause::Unhomed) {
            self.unlock();
            return;
        }
        if servo_tripped || cause == Some(AlarmCause::FollowingError) {
            // The loops restart where the joints are: resynchronise on the next tick.
            self.resync = true;
        }
        if self.locked {
            self.alarm = Some(UNHOMED);
            self.state = State::Alarm;
        } else {
            self.alarm = None;
            self.state = State::Idle;
        }
    }

    /// `Home`: the homing cycle on a machine with home switches (a machine without
    /// them goes home by a move the host plans, `Control::Jog`).
    pub(super) fn home(&mut self) {
        let switches = self.machine.joints.iter().any(|j| j.homing.enabled());
        let locked = self.alarm.map(|a| a.cause) == Some(AlarmCause::Unhomed);
        if switches && (locked || (self.state == State::Idle && !self.has_work())) {
            self.alarm = None;
            self.state = State::Homing;
            self.homed = false;
            self.homer.start(&self.machine.joints);
        }
    }

    /// An alarm that ends motion at once (the motion has already stopped, or must).
    /// The per-period guard: the first joint whose setpoint would move from the
    /// present one to `next` by more than its [`Controller::max_step`]. O(joints).
    #[inline]
    pub(super) fn overspeed(&self, next: &crate::kinematics::Joints) -> Option<usize> {
        let n = self.machine.joints.len();
        (0..n).find(|&j| next[j].wrapping_sub(self.joints[j]).unsigned_abs() > self.max_step[j])
    }

    /// A breach of the per-period guard at joint `j`: the new setpoints are not applied
    /// (the drives stay where the controller believes they are), the pose is the one
    /// of those joints, and the machine stops at once with `JointSpeed`.
    #[cold]
    #[inline(never)]
    pub(super) fn guard_trip(&mut self, j: usize) {
        let mut pose = self.exec.pose;
        if self
            .kin
            .forward(&self.joints, &self.exec.pose, &mut pose)
            .is_ok()
        {
            self.exec.pose = pose;
        }
        if self.state == State::Homing {
            self.cancel_homing();
        }
        self.raise(Alarm {
            cause: AlarmCause::JointSpeed,
            joint: j as u8,
            line: self.exec.line,
        });
    }

    /// Homing stops where the joints are: the machine is locked (not homed), and the
    /// pose and the queue start from those joints (homing moves joints, not the pose:
    /// without this the next move would start from the pose before homing, a jump).
    #[cold]
    pub(super) fn cancel_homing(&mut self) {
        self.homer.cancel();
        self.locked = true;
        self.homed = false;
        let mut pose = self.exec.pose;
        if self
            .kin
            .forward(&self.joints, &self.exec.pose, &mut pose)
            .is_ok()
        {
            let completed = self.exec.completed;
            self.exec.reset(pose);
            self.exec.completed = completed;
            self.planner.clear(pose);
        }
    }

    /// The alarm is the one a held job gets when its host goes silent (the job was
    /// kept): `LinkLoss` or `HostTimeout` in `Hold`.
    pub(super) fn held_for_silence(&self) -> bool {
        matches!(
            self.alarm.map(|a| a.cause),
            Some(AlarmCause::LinkLoss | AlarmCause::HostTimeout)
        )
    }

    pub(super) fn raise(&mut self, alarm: Alarm) {
        self.job_open = false;
        self.patience = 0;
        self.alarm = Some(alarm);
        self.state = State::Alarm;
        self.exec.stop();
        self.planner.hold = false;
        self.abort_pending = false;
        self.stopping = false;
        self.planner.clear(self.exec.pose);
    }

    /// A fault: the first alarm is kept (an e-stop replaces any other), motion stops
    /// on the path at the planned deceleration, homing stops at once.
    pub(super) fn fault(&mut self, alarm: Alarm, estop: bool) {
        match self.state {
            State::EStop => return,
            State::Alarm if !estop => return,
            _ => {}
        }
        let homing = self.state == State::Homing;
        // In a hold, an alarm can only be the one that says its host went silent.
        let informational = self.state == State::Hold;
        self.job_open = false;
        self.patience = 0;
        self.state = if estop { State::EStop } else { State::Alarm };
        if self.alarm.is_none() || estop || informational {
            self.alarm = Some(alarm);
        }
        self.abort_pending = false;
        if homing {
            self.cancel_homing();
            return;
        }
        if self.stopping {
            return;
        }
        if self.exec.stopped() {
            self.exec.stop();
            self.planner.hold = false;
            self.planner.clear(self.exec.pose);
        } else {
            self.planner.hold = true;
            self.exec.replan(&mut self.planner);
            self.stopping = true;
        }
    }

    /// Reads the safety inputs and raises what they say.
    pub(super) fn check_inputs(&mut self, inputs: &Inputs) {
        let n = self.machine.joints.len();
        let line = self.exec.line;
        let at = |cause, joint: Option<usize>| Alarm {
            cause,
            joint: joint.map_or(NO_JOINT, |j| j as u8),
            line,
        };
        if inputs.estop {
            self.fault(at(AlarmCause::EStop, None), true);
        }
        // Many drives report a fault while disabled: a fault line counts only while the
        // drives are powered (after an e-stop they are not, and the reset must pass).
        let powered = self.out.enable || self.out.servo_enable;
        let drive_fault = if powered { inputs.drive_fault } else { 0 };
        if let Some(j) = first_bit(drive_fault, n) {
            self.fault(at(AlarmCause::DriveFault, Some(j)), false);
        }
        // A reset restarts the loops this tick: their trips until then are the ones
        // just cleared.
        let trips = if self.resync {
            [None; MAX_SERVOS]
        } else {
            inputs.servo_trip
        };
        for (c, trip) in trips.iter().enumerate() {
            let joint = self.servo_joint[c] as usize;
            match trip {
                Some(Trip::AmplifierFault) => {
                    self.fault(at(AlarmCause::DriveFault, Some(joint)), false)
                }
                Some(_) => self.fault(at(AlarmCause::FollowingError, Some(joint)), false),
                None => {}
            }
        }
        let mut rising = inputs.limit & !self.last.limit;
        if self.state == State::Homing {
            // Shared home/limit switches: a homing joint's limit is its home switch.
            for (j, jc) in self.machine.joints.iter().enumerate() {
                if jc.homing.enabled() {
                    rising &= !(1 << j);
                }
            }
        }
        if let Some(j) = first_bit(rising, n) {
            self.fault(at(AlarmCause::LimitSwitch, Some(j)), false);
        }
        if self.session {
            self.silent_ticks = self.silent_ticks.saturating_add(1);
        }
        let moving = match self.state {
            State::Running | State::Homing => true,
            State::Hold => !self.exec.stopped(),
            _ => false,
        };
        // A streamed job (`Control::BeginJob`) starves rather than stops; its host
        // timeout holds it. A hold's link loss below applies to it too.
        let patient = self.patience > 0
            && matches!(self.state, State::Running | State::Starved | State::Hold);
        if self.link_watch && patient {
            if self.silent_ticks >= self.patience_ticks()
                && matches!(self.state, State::Running | State::Starved)
            {
                self.hold_for_take_over(at(AlarmCause::HostTimeout, None));
            } else if self.silent_ticks >= LINK_LOSS_TICKS
                && self.state == State::Hold
                && self.alarm.is_none()
                && self.job_held()
            {
                self.alarm = Some(at(AlarmCause::LinkLoss, None));
            }
        } else if self.link_watch && self.silent_ticks >= LINK_LOSS_TICKS {
            if moving {
                self.fault(at(AlarmCause::LinkLoss, None), false);
            } else if self.job_open && self.state == State::Idle {
                // The queue ran dry before the host said the job was complete: an
                // interrupted job, not a finished one.
                self.fault(at(AlarmCause::LinkLoss, None), false);
            } else if self.state == State::Hold && self.alarm.is_none() && self.job_held() {
                // A held job whose host went silent: nothing moves, the job is kept
                // (a host may resume or abort it), and the alarm says what happened.
                self.alarm = Some(at(AlarmCause::LinkLoss, None));
            }
        }
        self.last = Inputs {
            drive_fault,
            ..*inputs
        };
    }

    /// A streamed job whose host has been silent for its host timeout: a feed hold
    /// (decelerating on the path if it still moves), the job kept, and the alarm that
    /// says why; a host resumes or aborts it.
    #[cold]
    fn hold_for_take_over(&mut self, alarm: Alarm) {
        self.planner.hold = true;
        self.exec.replan(&mut self.planner);
        self.state = State::Hold;
        self.alarm = Some(alarm);
    }

    /// Re-bases joint `j`: the actuator reading `reference` (steps or counts) is the
    /// joint position `at`. The actuator's command stays where it is; the joint's
    /// believed position moves.
    pub(super) fn rebase(&mut self, j: usize, reference: i64, at: i64, moved: i64) {
        let scale = self.machine.joints[j].scale;
        let before = self.joints[j] - moved;
        let command = scale.steps_at(before) + self.offset[j];
        self.offset[j] = reference - scale.steps_at(at);
        self.steps.offset[j] = self.offset[j];
        self.joints[j] = scale.position_of(command - self.offset[j]) + moved;
    }

    pub(super) fn home_tick(&mut self, inputs: &Inputs) {
        self.motion_ticks += 1;
        let before = self.joints;
        let hin = HomeInputs {
            home: inputs.home,
            index: inputs.index,
        };
        let mut next = self.joints;
        let event = self
            .homer
            .tick(&self.machine.joints, &self.home_joints, &hin, &mut next);
        if let Some(j) = self.overspeed(&next) {
            self.guard_trip(j);
            return;
        }
        self.joints = next;
        match event {
            Some(HomeEvent::Latched { joint, index }) => {
                let jc = self.machine.joints[joint];
                let reference = match (jc.drive, index) {
                    (_, Some(count)) => count,
                    (Drive::Servo { channel }, None) => inputs.encoder_counts[channel as usize],
                    (Drive::Stepper { .. }, None) => self.steps.steps(joint),
                };
                let moved = self.joints[joint] - before[joint];
                self.rebase(joint, reference, jc.homing.switch_at, moved);
            }
            Some(HomeEvent::Failed { joint }) => {
                self.locked = true;
                self.raise(Alarm {
                    cause: AlarmCause::HomingFailed,
                    joint: joint as u8,
                    line: 0,
                });
            }
            Some(HomeEvent::Finished) => {
                let completed = self.exec.completed;
                self.exec.reset(self.machine.home);
                self.exec.completed = completed;
                self.planner.clear(self.machine.home);
                self.homed = true;
                self.locked = false;
                self.state = State::Idle;
            }
            None => {}
        }
    }

    /// After a servo trip is reset: the servo joints take their feedback as their
    /// position and the pose follows by the forward kinematics.
    pub(super) fn resync_servos(&mut self, inputs: &Inputs) {
        self.resync = false;
        let mut joints = self.joints;
        for (j, jc) in self.machine.joints.iter().enumerate() {
            if let Drive::Servo { channel } = jc.drive {
                joints[j] = jc
                    .scale
                    .position_of(inputs.encoder_counts[channel as usize] - self.offset[j]);
            }
        }
        let mut pose = self.exec.pose;
        match self.kin.forward(&joints, &self.exec.pose, &mut pose) {
            Ok(()) => {
                self.joints = joints;
                let completed = self.exec.completed;
                let line = self.exec.line;
                self.exec.reset(pose);
                self.exec.completed = completed;
                self.exec.line = line;
                self.planner.clear(pose);
                self.out.servo_reset = true;
            }
            Err(_) => {
                self.joints = joints;
                self.locked = true;
                self.homed = false;
                self.out.servo_reset = true;
                self.raise(UNHOMED);
            }
        }
    }
}
