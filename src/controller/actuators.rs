//! What the controller exchanges with the hardware each tick: the inputs it reads and
//! the outputs it commands, and the conversion of joint positions to actuator
//! references (steps or encoder counts, with the joints' homing offsets).

use super::Controller;
use crate::config::{ContourMode, Drive, MAX_SERVOS, MAX_STEPPERS};
use crate::drive::servo::{Trip, SETPOINT_FRAC_BITS};
use crate::drive::stepper::StepTrain;
use crate::kinematics::MachineKinematics;
use crate::wire::State;

/// What the hardware reports each tick.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Inputs {
    /// Encoder position of each servo channel, counts (extended beyond 16 bits).
    pub encoder_counts: [i64; MAX_SERVOS],
    /// Encoder count latched by the hardware at an index pulse since the last tick.
    pub index: [Option<i64>; MAX_SERVOS],
    /// Emergency stop input active.
    pub estop: bool,
    /// Limit switch of each joint (bit j), active when tripped.
    pub limit: u16,
    /// Home switch of each joint (bit j), active.
    pub home: u16,
    /// Fault input of each joint's drive (bit j), active: stepper drives and servo
    /// amplifiers alike (the servo loops also see their amplifier's line).
    pub drive_fault: u16,
    /// Trip latched by each servo channel's loop ([`crate::drive::contour::ServoBank`]).
    pub servo_trip: [Option<Trip>; MAX_SERVOS],
    /// The touch probe's input, active when touching: debounced
    /// ([`crate::drive::debounce::SWITCH`]).
    pub probe: bool,
    /// The probe's input as sampled this tick.
    pub probe_raw: bool,
    /// When the probe's input last changed within the last tick, µs after its start
    /// (a timer's capture; `None`: not known). See [`crate::drive::probe`].
    pub probe_edge_us: Option<u16>,
    /// Each servo channel's DAC code averaged over the tick's servo periods (the data
    /// recorder's output signal at the tick).
    pub servo_dac: [u16; MAX_SERVOS],
    /// The contour error of the last servo period: X Y Z in nm, the tool direction's
    /// A B in µ° (the data recorder's).
    pub contour: [i32; crate::kinematics::POSE_AXES],
}

/// What the hardware must do this tick.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Outputs {
    /// Step train of each stepper channel; `forward` already includes DIR inversion.
    pub steps: [StepTrain; MAX_STEPPERS],
    /// Target of each servo channel at the end of this tick, counts × 2^16: load into
    /// [`crate::drive::contour::ServoBank::load_tick`].
    pub servo_target: [i64; MAX_SERVOS],
    /// Stepper drives enabled.
    pub enable: bool,
    /// Servo amplifiers enabled (the loops' `enable`).
    pub servo_enable: bool,
    /// The servo loops must restart, clearing their trips, standing at their present
    /// feedback (which `servo_target` now equals): rebuild the bank from it.
    pub servo_reset: bool,
    /// The data recorder's signals the servo side samples every period of the next
    /// tick (wire ids with the channel in place of the joint;
    /// [`crate::controller::pacing::NOT_SERVO`] for none), read back by
    /// [`Controller::record_servo`].
    pub servo_record: [u8; crate::drive::recorder::MAX_SIGNALS],
    /// Added to each of them by the servo side: a position's joint zero taken off,
    /// or the value of a signal the tick samples itself
    /// ([`crate::controller::pacing::HELD`]).
    pub servo_record_add: [i32; crate::drive::recorder::MAX_SIGNALS],
}

impl Default for Outputs {
    fn default() -> Self {
        Self {
            steps: [StepTrain::default(); MAX_STEPPERS],
            servo_target: [0; MAX_SERVOS],
            enable: false,
            servo_enable: false,
            servo_reset: false,
            servo_record: [crate::controller::pacing::NOT_SERVO;
                crate::drive::recorder::MAX_SIGNALS],
            servo_record_add: [0; crate::drive::recorder::MAX_SIGNALS],
        }
    }
}

impl Controller {
    /// Each joint's actuator position from its zero, steps or counts: the servo
    /// encoders as last read, the steppers' steps emitted (see `Status::measured`).
    pub(super) fn measured(&self) -> [i64; crate::config::MAX_JOINTS] {
        let mut m = [0; crate::config::MAX_JOINTS];
        for (j, jc) in self.machine.joints.iter().enumerate() {
            let at = match jc.drive {
                Drive::Servo { channel } => self.last.encoder_counts[channel as usize],
                Drive::Stepper { .. } => self.steps.steps(j),
            };
            m[j] = at - self.offset[j];
        }
        m
    }

    /// Actuator reference of joint `j` (steps or encoder counts) for the position
    /// `q`, counts × 2^16.
    pub(super) fn actuator_q16(&self, j: usize, q: i64) -> i64 {
        self.steps.scale(j).steps_at_frac(q, SETPOINT_FRAC_BITS)
            + (self.offset[j] << SETPOINT_FRAC_BITS)
    }

    pub(super) fn update_servo_targets(&mut self) {
        for (j, jc) in self.machine.joints.iter().enumerate() {
            if let Drive::Servo { channel } = jc.drive {
                self.out.servo_target[channel as usize] = self.actuator_q16(j, self.joints[j]);
            }
        }
    }

    /// The hexapod-xy with contour control: one phase of the channels' map at the
    /// commanded pose each tick, moving or standing (a map is ready every
    /// [`crate::kinematics::hexapod_xy_map::MAP_PHASES`] ticks, at the pose of its
    /// first phase: [`Controller::contour_map`]); where the pose is singular the bank
    /// keeps the map it has.
    fn update_contour_map(&mut self) {
        self.map_fresh = false;
        let MachineKinematics::HexapodXy(k) = &self.kin else {
            return;
        };
        if self.machine.servo.contour.mode == ContourMode::Uncoupled {
            return;
        }
        self.map_fresh = self.map.step(k, &self.exec.pose).is_some();
    }

    /// This tick's outputs from the joints' positions: step trains (DIR inverted where
    /// the drive wants it) on each stepper's channel, servo targets, drive enables.
    pub(super) fn update_outputs(&mut self) {
        let lagged = self
            .steps
            .tick(&self.machine.joints, &self.joints, &mut self.trains);
        if let Some(j) = lagged {
            // Steps that do not fit the drive's timing are carried (the drive catches
            // up to the setpoint once it holds still): the guard stops the machine.
            if !matches!(self.state, State::Alarm | State::EStop) {
                self.guard_trip(j);
            }
        }
        // Every stepper's channel is written below each tick; the others stay idle
        // from when the machine was loaded (`Controller::write` builds `out` afresh).
        for (j, jc) in self.machine.joints.iter().enumerate() {
            if let Drive::Stepper {
                channel,
                invert_dir,
                ..
            } = jc.drive
            {
                let mut t = self.trains[j];
                t.forward ^= invert_dir;
                self.out.steps[channel as usize] = t;
            }
        }
        self.update_servo_targets();
        self.update_contour_map();
        let powered = self.state != State::EStop || self.stopping;
        self.out.enable = powered;
        self.out.servo_enable = powered;
    }
}
