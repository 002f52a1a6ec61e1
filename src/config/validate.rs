//! Validation of a machine configuration: [`MachineConfig::validate`] and the
//! geometry checks of the kinematics, each refusal naming its field
//! ([`ConfigError`]). [`MachineConfig::validate_on`] checks the drive channels against
//! the board that runs the machine ([`BoardChannels`]): a firmware build wires fewer
//! channels than the core has room for.

use super::*;

/// Why a machine configuration was refused; each variant names the field.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[non_exhaustive]
pub enum ConfigError {
    /// The machine has no joints.
    NoJoints,
    /// `motion.smoothing_ticks` is not a power of two up to the largest window.
    Smoothing,
    /// `joints[joint]` needs more steps per tick than its board channel can emit.
    BoardChannel {
        /// Joint index, 0-based.
        joint: u8,
    },
    /// `joints[joint].limits` has a non-positive speed or acceleration.
    JointLimits {
        /// Joint index, 0-based.
        joint: u8,
    },
    /// `joints[joint].min` is not below `max`.
    JointTravel {
        /// Joint index, 0-based.
        joint: u8,
    },
    /// `joints[joint].scale` has a zero term.
    JointScale {
        /// Joint index, 0-based.
        joint: u8,
    },
    /// `joints[joint].drive.channel` is beyond the board, or used twice.
    JointChannel {
        /// Joint index, 0-based.
        joint: u8,
    },
    /// `joints[joint]`: at its speed limit the drive would need more steps per second
    /// than its timing allows.
    StepRate {
        /// Joint index, 0-based.
        joint: u8,
    },
    /// `kinematics.axis_of_joint[joint]` names no axis, or an axis with no limits.
    JointAxis {
        /// Joint index, 0-based.
        joint: u8,
    },
    /// `axes[axis]` has a negative limit, or a speed without an acceleration.
    AxisLimits {
        /// Axis index, 0-based (X=0 .. C=5).
        axis: u8,
    },
    /// `home` lies outside a joint's travel.
    HomeOutsideTravel {
        /// Joint index, 0-based.
        joint: u8,
    },
    /// The kinematics' geometry is out of range, or does not fit the joints.
    Geometry {
        /// The offending field.
        field: GeometryField,
    },
    /// `servo.gains[channel]` of a channel in use is not finite, has a negative limit,
    /// a zero DAC scale or `min_ferror > ferror`, or its `servo.law` names an LQG
    /// design that is missing or invalid.
    ServoGains {
        /// Servo channel, 0-based.
        channel: u8,
    },
    /// `servo.contour` has a bad gain, or couples axes of a non-Cartesian machine.
    Contour,
    /// `joints[joint].homing`: the switch lies outside the travel, a speed is above
    /// the joint's limit, the latch speed is not positive, or `use_index` on a stepper.
    Homing {
        /// Joint index, 0-based.
        joint: u8,
    },
}

/// The geometry field a [`ConfigError::Geometry`] refers to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[non_exhaustive]
pub enum GeometryField {
    /// The number or kind (linear/rotary) of the joints does not fit the kinematics.
    Joints,
    /// H-4 `rails`.
    Rails,
    /// H-4 `forearm`.
    Forearm,
    /// H-4 `bar_half`.
    BarHalf,
    /// H-4 `sides`.
    Sides,
    /// H-4 `attach`.
    Attach,
    /// H-4 `tool_length`.
    ToolLength,
    /// H-4 `table_pivot`.
    TablePivot,
    /// H-4 `min_elevation`.
    MinElevation,
    /// Hexapod `base`.
    Base,
    /// Hexapod `platform`.
    Platform,
    /// Hexapod-XY `platform_home`.
    PlatformHome,
    /// Hexapod-XY `tool_z`.
    ToolZ,
}

fn within(v: &[i64]) -> bool {
    v.iter().all(|c| c.unsigned_abs() < GEOMETRY_MAX as u64)
}

/// Are `joints` exactly `n` joints with the given rotary flags (`rotary_from`.. rotary)?
fn joint_kinds(joints: &[JointConfig], n: usize, rotary_from: usize) -> bool {
    joints.len() == n
        && joints
            .iter()
            .enumerate()
            .all(|(j, jc)| jc.rotary == (j >= rotary_from))
}

impl H4TableGeometry {
    /// Checks ranges and that `joints` are four linear carriages and a rotary table.
    pub fn check(&self, joints: &[JointConfig]) -> Result<(), ConfigError> {
        let bad = |field| Err(ConfigError::Geometry { field });
        if !joint_kinds(joints, 5, 4) {
            return bad(GeometryField::Joints);
        }
        if !self.rails.iter().all(|r| within(r)) {
            return bad(GeometryField::Rails);
        }
        if self.forearm <= 0 || !within(&[self.forearm]) {
            return bad(GeometryField::Forearm);
        }
        if self.bar_half <= 0 || !within(&[self.bar_half]) {
            return bad(GeometryField::BarHalf);
        }
        if !self.sides.iter().all(|s| s.abs() == 1) {
            return bad(GeometryField::Sides);
        }
        if !self.attach.iter().all(|a| within(a)) {
            return bad(GeometryField::Attach);
        }
        if !within(&[self.tool_length]) {
            return bad(GeometryField::ToolLength);
        }
        if !within(&self.table_pivot) {
            return bad(GeometryField::TablePivot);
        }
        if self.min_elevation <= 0 || self.min_elevation >= 90 * crate::units::NDEG_PER_DEG {
            return bad(GeometryField::MinElevation);
        }
        Ok(())
    }
}

impl HexapodGeometry {
    /// Checks ranges, a platform of non-zero size and that `joints` are six linear legs.
    pub fn check(&self, joints: &[JointConfig]) -> Result<(), ConfigError> {
        let bad = |field| Err(ConfigError::Geometry { field });
        if !joint_kinds(joints, 6, 6) {
            return bad(GeometryField::Joints);
        }
        // Fixed-point ranges of the kinematics (crate::kinematics::hexapod): base
        // coordinates below 2^29 nm (537 mm), platform joints within 2^28 nm (268 mm)
        // of the platform origin.
        let base_max = 1u64 << 29;
        if !self
            .base
            .iter()
            .flatten()
            .all(|c| c.unsigned_abs() < base_max)
        {
            return bad(GeometryField::Base);
        }
        let radius_sq = |b: &[i64; 3]| {
            b.iter()
                .map(|c| c.unsigned_abs().min(1 << 31).pow(2))
                .sum::<u64>()
        };
        if !self.platform.iter().all(|b| radius_sq(b) < 1 << 56)
            || self.platform.iter().all(|b| b == &[0; 3])
        {
            return bad(GeometryField::Platform);
        }
        Ok(())
    }
}
impl HexapodXyGeometry {
    /// Checks the legs as [`HexapodGeometry::check`] does, that `joints` are six linear
    /// legs and a linear X-Y table, and the ranges of the fixed-point split (platform
    /// home within 2^29 nm, the tool's height within 2^30 nm).
    pub fn check(&self, joints: &[JointConfig]) -> Result<(), ConfigError> {
        let bad = |field| Err(ConfigError::Geometry { field });
        if !joint_kinds(joints, 8, 8) {
            return bad(GeometryField::Joints);
        }
        self.hexapod.check(&joints[..6])?;
        if !self
            .platform_home
            .iter()
            .all(|c| c.unsigned_abs() < 1 << 29)
        {
            return bad(GeometryField::PlatformHome);
        }
        if !within(&[self.tool_z]) {
            return bad(GeometryField::ToolZ);
        }
        Ok(())
    }
}

/// The drive channels a board wires: stepper channels `0..steppers` and servo channels
/// `0..servos`. A machine on another channel is refused with
/// [`ConfigError::JointChannel`], naming the joint.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BoardChannels {
    /// Stepper channels wired, at most [`MAX_STEPPERS`].
    pub steppers: u8,
    /// Servo channels wired, at most [`MAX_SERVOS`].
    pub servos: u8,
}

impl BoardChannels {
    /// Every channel the core has room for: the simulator's board, and what
    /// [`MachineConfig::validate`] checks against.
    pub const ALL: BoardChannels = BoardChannels {
        steppers: MAX_STEPPERS as u8,
        servos: MAX_SERVOS as u8,
    };
}

impl MachineConfig {
    /// Checks every field against the core's capacities ([`BoardChannels::ALL`]); the
    /// first problem found is returned.
    pub fn validate(&self) -> Result<(), ConfigError> {
        self.validate_on(BoardChannels::ALL)
    }

    /// Checks every field, and that each joint's drive channel is one `board` wires;
    /// the first problem found is returned.
    pub fn validate_on(&self, board: BoardChannels) -> Result<(), ConfigError> {
        if self.joints.is_empty() {
            return Err(ConfigError::NoJoints);
        }
        let w = self.motion.smoothing_ticks as usize;
        if !w.is_power_of_two() || w > MAX_WINDOW {
            return Err(ConfigError::Smoothing);
        }
        for (i, l) in self.axes.iter().enumerate() {
            if l.max_velocity < 0 || l.max_accel < 0 || (l.max_velocity > 0) != (l.max_accel > 0) {
                return Err(ConfigError::AxisLimits { axis: i as u8 });
            }
        }
        let mut used = ChannelsUsed::default();
        for (j, jc) in self.joints.iter().enumerate() {
            self.check_joint(j as u8, jc, board, &mut used)?;
        }
        match self.kinematics {
            KinematicsConfig::Cartesian { axis_of_joint } => {
                for (j, &a) in axis_of_joint.iter().enumerate().take(self.joints.len()) {
                    let a = a as usize;
                    if a >= AXES || self.axes[a].max_velocity == 0 {
                        return Err(ConfigError::JointAxis { joint: j as u8 });
                    }
                }
            }
            KinematicsConfig::H4Table(g) => g.check(&self.joints)?,
            KinematicsConfig::Hexapod(g) => g.check(&self.joints)?,
            KinematicsConfig::HexapodXy(g) => g.check(&self.joints)?,
        }
        let contour = &self.servo.contour;
        let mapped = matches!(
            self.kinematics,
            KinematicsConfig::Cartesian { .. } | KinematicsConfig::HexapodXy(_)
        );
        if !contour.is_valid() || (contour.mode != ContourMode::Uncoupled && !mapped) {
            return Err(ConfigError::Contour);
        }
        Ok(())
    }

    /// Checks `joints[joint]` (`jc`): limits, travel, scale, homing and its drive (on
    /// a channel of `board`), marking its channel in `used`.
    fn check_joint(
        &self,
        joint: u8,
        jc: &JointConfig,
        board: BoardChannels,
        used: &mut ChannelsUsed,
    ) -> Result<(), ConfigError> {
        if jc.limits.max_velocity <= 0 || jc.limits.max_accel <= 0 {
            return Err(ConfigError::JointLimits { joint });
        }
        if jc.min >= jc.max {
            return Err(ConfigError::JointTravel { joint });
        }
        if jc.scale.steps == 0 || jc.scale.per_units == 0 {
            return Err(ConfigError::JointScale { joint });
        }
        let h = &jc.homing;
        if h.enabled()
            && (h.switch_at < jc.min
                || h.switch_at > jc.max
                || h.search_velocity.unsigned_abs() > jc.limits.max_velocity as u64
                || h.latch_velocity <= 0
                || h.latch_velocity > jc.limits.max_velocity
                || (h.use_index && matches!(jc.drive, Drive::Stepper { .. })))
        {
            return Err(ConfigError::Homing { joint });
        }
        match jc.drive {
            Drive::Stepper {
                channel, timing, ..
            } => {
                let bit = 1u32 << channel.min(31);
                let wired = MAX_STEPPERS.min(board.steppers as usize);
                if channel as usize >= wired || used.steppers & bit != 0 {
                    return Err(ConfigError::JointChannel { joint });
                }
                used.steppers |= bit;
                if timing.max_rate_hz == 0 || timing.min_pulse_ns == 0 {
                    return Err(ConfigError::StepRate { joint });
                }
                // Steps one tick may need at full speed, against what fits in the
                // tick after a DIR-setup window (as the step scheduler plans it).
                let per_tick = jc.scale.steps as i128 * jc.limits.max_velocity as i128
                    / (jc.scale.per_units as i128 * crate::units::TICK_HZ as i128)
                    + 1;
                if per_tick > timing.steps_in_tick_after(timing.dir_setup_ns) as i128 {
                    return Err(ConfigError::StepRate { joint });
                }
                // What the board's timer on this channel can emit in one tick.
                if per_tick > BOARD_STEPS_PER_TICK[channel as usize] as i128 {
                    return Err(ConfigError::BoardChannel { joint });
                }
            }
            Drive::Servo { channel, .. } => {
                let bit = 1u32 << channel.min(31);
                let wired = MAX_SERVOS.min(board.servos as usize);
                if channel as usize >= wired || used.servos & bit != 0 {
                    return Err(ConfigError::JointChannel { joint });
                }
                used.servos |= bit;
                let c = channel as usize;
                let law = self.servo.law[c] as usize;
                let lqg_ok = law == 0 || self.servo.lqg_of(c).is_some_and(|g| g.is_valid());
                if !self.servo.gains[c].is_valid() || !lqg_ok {
                    return Err(ConfigError::ServoGains { channel });
                }
            }
        }
        Ok(())
    }
}

/// The board channels taken by the joints checked so far (bit c: channel c).
#[derive(Default)]
struct ChannelsUsed {
    steppers: u32,
    servos: u32,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_flat_h4_forearm_limit_is_refused_with_its_field() {
        let mut m = MachineConfig::h4_table();
        if let KinematicsConfig::H4Table(g) = &mut m.kinematics {
            g.min_elevation = 0;
        }
        let field = GeometryField::MinElevation;
        assert_eq!(m.validate(), Err(ConfigError::Geometry { field }));
    }

    #[test]
    fn a_hexapod_with_a_missing_leg_is_refused() {
        let mut m = MachineConfig::hexapod();
        m.joints.pop();
        let field = GeometryField::Joints;
        assert_eq!(m.validate(), Err(ConfigError::Geometry { field }));
    }

    #[test]
    fn a_channel_used_twice_is_refused_with_its_joint() {
        let mut m = MachineConfig::cartesian_xyz();
        if let Drive::Stepper { channel, .. } = &mut m.joints[2].drive {
            *channel = 0;
        }
        assert_eq!(m.validate(), Err(ConfigError::JointChannel { joint: 2 }));
    }

    #[test]
    fn a_joint_on_a_channel_the_board_does_not_wire_is_refused_with_its_joint() {
        let mut m = MachineConfig::h4_table();
        // Servo channels 0..3 and stepper channel 0: fine on a board wiring exactly
        // those, refused with the joint when one channel fewer of either kind is wired.
        let board = BoardChannels {
            steppers: 1,
            servos: 4,
        };
        assert_eq!(m.validate_on(board), Ok(()));
        let fewer_servos = BoardChannels { servos: 3, ..board };
        assert_eq!(
            m.validate_on(fewer_servos),
            Err(ConfigError::JointChannel { joint: 3 })
        );
        let no_steppers = BoardChannels {
            steppers: 0,
            ..board
        };
        assert_eq!(
            m.validate_on(no_steppers),
            Err(ConfigError::JointChannel { joint: 4 })
        );
        // A servo channel beyond the core's room is refused whatever the board says.
        if let Drive::Servo { channel } = &mut m.joints[3].drive {
            *channel = MAX_SERVOS as u8;
        }
        let generous = BoardChannels {
            steppers: u8::MAX,
            servos: u8::MAX,
        };
        assert_eq!(
            m.validate_on(generous),
            Err(ConfigError::JointChannel { joint: 3 })
        );
    }

    #[test]
    fn a_speed_beyond_the_drive_step_rate_is_refused() {
        let mut m = MachineConfig::cartesian_xyz();
        m.joints[1].limits.max_velocity = 10_000 * crate::units::NM_PER_MM; // 4 MHz
        assert_eq!(m.validate(), Err(ConfigError::StepRate { joint: 1 }));
    }

    #[test]
    fn a_joint_on_a_channel_the_board_cannot_drive_fast_enough_is_refused() {
        let mut m = MachineConfig::cartesian_xyz();
        let set_channel = |m: &mut MachineConfig, c: u8| {
            if let Drive::Stepper { channel, .. } = &mut m.joints[2].drive {
                *channel = c;
            }
        };
        // Channels 3–6 take 256 steps per tick: 100 mm/s at 400 steps/mm needs 41.
        for c in [3, 6] {
            set_channel(&mut m, c);
            assert_eq!(m.validate(), Ok(()));
        }
        // 1000 mm/s needs 401: within the drive's 2 MHz, beyond 8-bit repetition counters.
        m.joints[2].limits.max_velocity = 1_000 * crate::units::NM_PER_MM;
        for c in [3, 6] {
            set_channel(&mut m, c);
            assert_eq!(m.validate(), Err(ConfigError::BoardChannel { joint: 2 }));
        }
        set_channel(&mut m, 2); // TIM20: 65 536
        assert_eq!(m.validate(), Ok(()));
    }
}
