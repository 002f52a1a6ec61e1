//! Machine configuration: geometry, joint types, scales, limits and drive timing.
//!
//! The host reads a human TOML machine file (mm, degrees, seconds), checks it and
//! converts it to this integer form (units in [`crate::units`]); the controller keeps
//! and validates it. Nothing in the kinematics or the planner is hard-coded: every
//! number comes from here. [`MachineConfig::validate`] names the offending field.

use serde::{Deserialize, Serialize};

/// Number of pose axes: X Y Z (linear) and A B C (rotary).
pub const AXES: usize = 6;
/// Most joints a machine may have (4 servo + 7 stepper channels on the board).
pub const MAX_JOINTS: usize = 11;
/// Stepper channels the board drives.
pub const MAX_STEPPERS: usize = 7;
/// Servo channels the board drives.
pub const MAX_SERVOS: usize = 4;
/// Most steps the reference board (NUCLEO-G474RE, `docs/wiring.md`) emits on each
/// stepper channel in one tick: channels 0–2 on TIM1/TIM8/TIM20 (16-bit repetition
/// counters), 3–5 on TIM15/TIM16/TIM17 and 6 on HRTIM1 timer A (8-bit). A machine
/// needing more is refused rather than losing steps.
pub const BOARD_STEPS_PER_TICK: [u32; MAX_STEPPERS] = [65_536, 65_536, 65_536, 256, 256, 256, 256];
/// Most ticks of smoothing, the interpolator's moving-average window
/// ([`MotionConfig::smoothing_ticks`], [`crate::interp`]).
pub const MAX_WINDOW: usize = 32;
/// Axis names in pose order.
pub const AXIS_NAMES: [char; AXES] = ['X', 'Y', 'Z', 'A', 'B', 'C'];

/// Is pose axis `i` rotary (A, B, C)?
pub const fn axis_is_rotary(i: usize) -> bool {
    i >= 3
}

/// Velocity and acceleration limits of one pose axis or joint.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Limits {
    /// Maximum speed, axis units per second (nm/s or n°/s).
    pub max_velocity: i64,
    /// Maximum acceleration, axis units per second² (nm/s² or n°/s²).
    pub max_accel: i64,
}

/// Timing rules of a step/direction drive, in nanoseconds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct StepTiming {
    /// Minimum STEP high time, ns.
    pub min_pulse_ns: u32,
    /// Maximum STEP rate, Hz.
    pub max_rate_hz: u32,
    /// Minimum time from a DIR change to the next STEP rising edge, ns.
    pub dir_setup_ns: u32,
    /// Minimum time DIR must stay put after a STEP rising edge, ns.
    pub dir_hold_ns: u32,
}

impl StepTiming {
    /// Pacific Scientific 6410 microstep drive (seeds-digest C): STEP pulse ≥ 250 ns,
    /// ≤ 2 MHz, DIR setup 50 µs, hold 0.
    pub const PACSCI_6410: StepTiming = StepTiming {
        min_pulse_ns: 250,
        max_rate_hz: 2_000_000,
        dir_setup_ns: 50_000,
        dir_hold_ns: 0,
    };

    /// Shortest allowed time between two STEP rising edges, ns (rounded up).
    pub const fn min_interval_ns(&self) -> u32 {
        1_000_000_000u32.div_ceil(self.max_rate_hz)
    }
}

/// Joint scale: `steps` motor steps (or encoder counts) per `per_units` axis units.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Scale {
    /// Steps or counts.
    pub steps: u32,
    /// Axis units (nm or n°) that those steps move.
    pub per_units: u64,
}

const fn gcd(mut a: u64, mut b: u64) -> u64 {
    while b != 0 {
        let t = a % b;
        a = b;
        b = t;
    }
    a
}

impl Scale {
    /// `steps` per `per_units`, reduced to lowest terms (so equal scales compare equal).
    pub const fn new(steps: u32, per_units: u64) -> Self {
        let g = gcd(steps as u64, per_units);
        let g = if g == 0 { 1 } else { g };
        Scale {
            steps: (steps as u64 / g) as u32,
            per_units: per_units / g,
        }
    }
    /// Nearest whole step count for a joint position in axis units.
    pub fn steps_at(&self, position: i64) -> i64 {
        crate::units::div_round(
            position as i128 * self.steps as i128,
            self.per_units as i128,
        ) as i64
    }
    /// Joint position in axis units of a step count (rounded to the nearest unit).
    pub fn position_of(&self, steps: i64) -> i64 {
        crate::units::div_round(steps as i128 * self.per_units as i128, self.steps as i128) as i64
    }
    /// The same conversions without a division (for the tick).
    pub const fn fast(&self) -> FastScale {
        FastScale {
            steps: self.steps,
            per_units: crate::math::Recip::new(self.per_units),
        }
    }
}

/// A [`Scale`] with its divisor's reciprocal formed once: the same results as the
/// `Scale` methods, bit for bit, without a 128-bit division.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FastScale {
    steps: u32,
    per_units: crate::math::Recip,
}

impl FastScale {
    /// [`Scale::steps_at`].
    #[inline]
    pub fn steps_at(&self, position: i64) -> i64 {
        self.per_units
            .div_round(position as i128 * self.steps as i128)
    }
    /// `position` in steps or counts × 2^`frac_bits`, rounded to nearest.
    #[inline]
    pub fn steps_at_frac(&self, position: i64, frac_bits: u32) -> i64 {
        self.per_units
            .div_round(((position as i128) << frac_bits) * self.steps as i128)
    }
}

/// How a joint is driven.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Drive {
    /// STEP/DIR/ENABLE drive on stepper channel `channel` (0-based).
    Stepper {
        /// Board stepper channel, 0..[`MAX_STEPPERS`].
        channel: u8,
        /// Drive timing rules.
        timing: StepTiming,
        /// Reverse the DIR output.
        invert_dir: bool,
    },
    /// Quadrature encoder in, analog command out, on servo channel `channel` (0-based);
    /// its loop's gains are `MachineConfig::servo.gains[channel]`.
    Servo {
        /// Board servo channel, 0..[`MAX_SERVOS`].
        channel: u8,
    },
}

/// Gains, limits and output stage of one servo channel's position loop, run every
/// servo period by [`crate::servo::ServoAxis`] (PID on the following error plus velocity
/// and acceleration feed-forward, LinuxCNC `pid` style).
///
/// "Command units" (c.u.) are the amplifier's input unit, chosen per machine (volts,
/// or the identified model's "command pulses"); [`dac_per_unit`](Self::dac_per_unit)
/// turns them into DAC counts. Gains are `f32` because the loop runs in single
/// precision on the Cortex-M4F FPU (see [`crate::servo`]); equality compares bits.
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
pub struct ServoGains {
    /// Proportional gain, c.u. per encoder count of following error.
    pub kp: f32,
    /// Integral gain, c.u. per (count · s).
    pub ki: f32,
    /// Derivative gain, c.u. per (count/s) of error rate.
    pub kd: f32,
    /// Velocity feed-forward, c.u. per (count/s) of commanded velocity.
    pub kvff: f32,
    /// Acceleration feed-forward, c.u. per (count/s²) of commanded acceleration.
    pub kaff: f32,
    /// Output clamp, ± c.u.
    pub max_output: f32,
    /// Integrator clamp, ± c.u.
    pub max_integral: f32,
    /// DAC counts per c.u.; negative reverses the output.
    pub dac_per_unit: f32,
    /// DAC counts added to mid-scale (amplifier offset trim).
    pub dac_offset: i16,
    /// Following-error limit at the joint's maximum speed, counts (LinuxCNC `FERROR`).
    pub ferror: u32,
    /// Following-error limit at standstill, counts (LinuxCNC `MIN_FERROR`).
    pub min_ferror: u32,
}

impl ServoGains {
    /// An unused channel: no gain, no output.
    pub const NONE: ServoGains = ServoGains {
        kp: 0.0,
        ki: 0.0,
        kd: 0.0,
        kvff: 0.0,
        kaff: 0.0,
        max_output: 0.0,
        max_integral: 0.0,
        dac_per_unit: 1.0,
        dac_offset: 0,
        ferror: 0,
        min_ferror: 0,
    };

    /// Gains for the simulator's default servo plant (`G(s) = K / (s·(τs + 1))` with
    /// K = 300 counts/s per DAC count, τ = 20 ms; c.u. = DAC counts): velocity and
    /// acceleration feed-forward from the model's inverse (1/K, τ/K), a P+I loop
    /// crossing over near 30 rad/s, following error 2 000 counts at full speed and 200
    /// at rest.
    pub const DEFAULT_PLANT: ServoGains = ServoGains {
        kp: 0.1,
        ki: 1.0,
        kd: 0.0,
        kvff: 3.3333e-3,
        kaff: 6.6667e-5,
        max_output: 2047.0,
        max_integral: 500.0,
        dac_per_unit: 1.0,
        dac_offset: 0,
        ferror: 2000,
        min_ferror: 200,
    };

    fn bits(&self) -> [u32; 11] {
        [
            self.kp.to_bits(),
            self.ki.to_bits(),
            self.kd.to_bits(),
            self.kvff.to_bits(),
            self.kaff.to_bits(),
            self.max_output.to_bits(),
            self.max_integral.to_bits(),
            self.dac_per_unit.to_bits(),
            self.dac_offset as u32,
            self.ferror,
            self.min_ferror,
        ]
    }

    /// Are the gains usable: finite, non-negative limits, a non-zero DAC scale and
    /// `min_ferror <= ferror`? ([`ServoGains::NONE`] is: an idle loop whose output
    /// stays at zero; `ferror == 0` turns the following-error check off.)
    pub fn is_valid(&self) -> bool {
        let finite = [
            self.kp,
            self.ki,
            self.kd,
            self.kvff,
            self.kaff,
            self.max_output,
            self.max_integral,
            self.dac_per_unit,
        ]
        .iter()
        .all(|v| v.is_finite());
        finite
            && self.max_output >= 0.0
            && self.max_integral >= 0.0
            && self.dac_per_unit != 0.0
            && self.min_ferror <= self.ferror
    }
}

impl PartialEq for ServoGains {
    fn eq(&self, other: &Self) -> bool {
        self.bits() == other.bits()
    }
}
impl Eq for ServoGains {}

/// How the servo loops of the linear Cartesian axes are coordinated ([`crate::contour`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum ContourMode {
    /// Each axis on its own (the per-axis feed-forward still applies).
    Uncoupled,
    /// Cross-coupled control (Koren 1980; Koren and Lo 1991): the estimated contour
    /// error through a PI, distributed to the axes' commands by the direction cosines.
    CrossCoupled,
    /// Cross-coupling pre-compensation method (report B, §3.5): cross-coupled control
    /// plus the contour error fed back as an offset of every axis' reference, on top of
    /// the per-axis velocity pre-compensation (feed-forward).
    Ccpm,
}

/// Contour-control settings. Contour errors are in mm (the coupled axes are X Y Z).
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
pub struct ContourConfig {
    /// Which scheme.
    pub mode: ContourMode,
    /// Cross-coupled proportional gain, c.u. per mm of contour error.
    pub kp: f32,
    /// Cross-coupled integral gain, c.u. per (mm · s).
    pub ki: f32,
    /// Cross-coupled integrator clamp, ± c.u. per axis.
    pub max_integral: f32,
    /// CCPM reference pre-compensation rate, 1/s: the reference offset grows by
    /// `kr · ε · dt` each servo period.
    pub kr: f32,
    /// CCPM reference offset clamp, ± mm per axis.
    pub max_offset: f32,
}

impl ContourConfig {
    /// No coupling.
    pub const UNCOUPLED: ContourConfig = ContourConfig {
        mode: ContourMode::Uncoupled,
        kp: 0.0,
        ki: 0.0,
        max_integral: 0.0,
        kr: 0.0,
        max_offset: 0.0,
    };

    fn bits(&self) -> [u32; 5] {
        [
            self.kp.to_bits(),
            self.ki.to_bits(),
            self.max_integral.to_bits(),
            self.kr.to_bits(),
            self.max_offset.to_bits(),
        ]
    }

    /// Are the gains finite and the clamps non-negative?
    pub fn is_valid(&self) -> bool {
        [
            self.kp,
            self.ki,
            self.max_integral,
            self.kr,
            self.max_offset,
        ]
        .iter()
        .all(|v| v.is_finite())
            && self.max_integral >= 0.0
            && self.max_offset >= 0.0
    }
}

impl PartialEq for ContourConfig {
    fn eq(&self, other: &Self) -> bool {
        self.mode == other.mode && self.bits() == other.bits()
    }
}
impl Eq for ContourConfig {}

/// Servo settings of the machine: the loop of each servo channel and their coupling.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ServoConfig {
    /// Loop of each servo channel, indexed by `Drive::Servo::channel`.
    pub gains: [ServoGains; MAX_SERVOS],
    /// Coupling of the channels that drive the X, Y and Z axes.
    pub contour: ContourConfig,
}

impl ServoConfig {
    /// No servo channels in use.
    pub const NONE: ServoConfig = ServoConfig {
        gains: [ServoGains::NONE; MAX_SERVOS],
        contour: ContourConfig::UNCOUPLED,
    };
}

/// One joint: its drive, scale, travel and limits.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct JointConfig {
    /// Drive type and channel.
    pub drive: Drive,
    /// Steps (stepper) or encoder counts (servo) per axis units.
    pub scale: Scale,
    /// Rotary joint (positions in n°) rather than linear (nm).
    pub rotary: bool,
    /// Lowest allowed position, axis units.
    pub min: i64,
    /// Highest allowed position, axis units.
    pub max: i64,
    /// Velocity and acceleration limits, axis units.
    pub limits: Limits,
    /// How the joint finds its position after a reset ([`Homing::NONE`]: it does not).
    pub homing: Homing,
}

/// Homing of one joint by [`crate::homing`]: search for the home switch, back off it
/// slowly until it releases, then (optionally) go on to the encoder's index pulse.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Homing {
    /// Joint position where the home switch releases on the way back (or, with
    /// `use_index`, of the first index pulse after it), axis units.
    pub switch_at: i64,
    /// Search speed towards the switch, axis units/s; its sign is the direction, zero
    /// means the joint has no home switch.
    pub search_velocity: i64,
    /// Speed backing off the switch (and on to the index), axis units/s, > 0.
    pub latch_velocity: i64,
    /// After the switch, latch on the encoder's index pulse (servo joints only).
    pub use_index: bool,
}

impl Homing {
    /// No home switch: the joint keeps the position it is believed to have.
    pub const NONE: Homing = Homing {
        switch_at: 0,
        search_velocity: 0,
        latch_velocity: 0,
        use_index: false,
    };

    /// Does the joint home on a switch?
    pub const fn enabled(&self) -> bool {
        self.search_velocity != 0
    }
}

/// Which kinematics the machine uses, with its parameters.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum KinematicsConfig {
    /// Each joint follows one pose axis: `axis_of_joint[j]` is joint j's axis index.
    Cartesian {
        /// Pose axis (0..6) followed by each joint.
        axis_of_joint: [u8; MAX_JOINTS],
    },
    /// H-4 head on four vertical rails with a rolling table (tilting about an axis
    /// parallel to X). Joints: q1..q4 the carriage heights (linear), q5 the table angle
    /// A (rotary). Pose: X Y Z tool tip in workpiece coordinates, C head rotation θ,
    /// A table; B unused.
    H4Table(H4TableGeometry),
    /// Gough–Stewart platform with six legs; joint i is the length of leg i.
    /// Pose: platform origin X Y Z and orientation R = Rz(C)·Ry(B)·Rx(A).
    Hexapod(HexapodGeometry),
}

/// Largest magnitude of any geometry coordinate or length, nm (2^30 nm ≈ 1.07 m):
/// keeps every difference of a pose and a geometry point inside 32 bits (see
/// [`crate::kinematics`]).
pub const GEOMETRY_MAX: i64 = 1 << 30;

/// H-4 with rolling table, in nm and n° (machine frame: Z up, home plane z = 0).
///
/// Head point E; bar-end attachment of arm i: `P_i = E + sides[i]·bar_half·(cos θ,
/// sin θ, 0) + attach[i]`; carriage i runs on the vertical line `rails[i]` at height
/// `q_i = P_iz + sqrt(forearm² − ρ_i²)`, ρ_i the horizontal distance from P_i to the
/// rail. Tool tip `T = E − (0, 0, tool_length)`. The table turns by A (right hand about
/// +X) about the line through `table_pivot` parallel to X; a workpiece point p sits at
/// `T = pivot + Rx(A)·(p − pivot)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct H4TableGeometry {
    /// X Y of each vertical rail, nm.
    pub rails: [[i64; 2]; 4],
    /// Forearm length L, nm.
    pub forearm: i64,
    /// Half length d of the central bar, nm.
    pub bar_half: i64,
    /// Bar end each arm pair holds: −1 or +1.
    pub sides: [i8; 4],
    /// Attachment offsets e_i (not turned with θ), nm.
    pub attach: [[i64; 3]; 4],
    /// Tool tip below the head point E, nm.
    pub tool_length: i64,
    /// A point of the table axis, nm (its X is irrelevant).
    pub table_pivot: [i64; 3],
    /// Lowest forearm elevation above horizontal, n°; flatter poses are refused as too
    /// near the singularity at ρ = L.
    pub min_elevation: i64,
}

/// Hexapod: leg i joins base joint `base[i]` to platform joint `platform[i]`; its
/// length is `|p + R·platform[i] − base[i]|`. All nm; base coordinates below 537 mm,
/// platform joints within 268 mm of the platform origin (the fixed-point range).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct HexapodGeometry {
    /// Base joints a_i, machine frame, nm.
    pub base: [[i64; 3]; 6],
    /// Platform joints b_i, platform frame, nm.
    pub platform: [[i64; 3]; 6],
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

/// The whole machine.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct MachineConfig {
    /// Machine name, shown to the user.
    pub name: heapless::String<32>,
    /// Kinematics and geometry.
    pub kinematics: KinematicsConfig,
    /// Joints in order q1..qN.
    pub joints: heapless::Vec<JointConfig, MAX_JOINTS>,
    /// Per-axis limits of the programmed pose; a zero max_velocity marks an unused axis.
    pub axes: [Limits; AXES],
    /// Home pose, axis units: where the controller starts.
    pub home: [i64; AXES],
    /// Servo loops and contour control ([`ServoConfig::NONE`] without servo joints).
    pub servo: ServoConfig,
    /// Speed-profile shape.
    pub motion: MotionConfig,
}

/// Shape of the speed profiles.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct MotionConfig {
    /// Jerk limitation: the path distance is averaged over this many ticks (a power
    /// of two, at most [`MAX_WINDOW`]); 1 gives plain trapezoids. With
    /// a window of w ticks every axis's and joint's jerk stays below 3·aᵢ/(w·T).
    pub smoothing_ticks: u8,
}

impl MotionConfig {
    /// Trapezoidal profiles (no jerk limitation).
    pub const TRAPEZOID: MotionConfig = MotionConfig { smoothing_ticks: 1 };
}

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
    /// a zero DAC scale or `min_ferror > ferror`.
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

impl MachineConfig {
    /// Checks every field; the first problem found is returned.
    pub fn validate(&self) -> Result<(), ConfigError> {
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
        let mut steppers_used = 0u32;
        let mut servos_used = 0u32;
        for (j, jc) in self.joints.iter().enumerate() {
            let joint = j as u8;
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
                    if channel as usize >= MAX_STEPPERS || steppers_used & bit != 0 {
                        return Err(ConfigError::JointChannel { joint });
                    }
                    steppers_used |= bit;
                    if timing.max_rate_hz == 0 || timing.min_pulse_ns == 0 {
                        return Err(ConfigError::StepRate { joint });
                    }
                    // Steps one tick may need at full speed, against what fits in the
                    // tick after a DIR-setup window.
                    let per_tick = jc.scale.steps as i128 * jc.limits.max_velocity as i128
                        / (jc.scale.per_units as i128 * crate::units::TICK_HZ as i128)
                        + 1;
                    let window = crate::units::TICK_NS.saturating_sub(timing.dir_setup_ns);
                    let fits = window / timing.min_interval_ns().max(2 * timing.min_pulse_ns);
                    if per_tick > fits as i128 {
                        return Err(ConfigError::StepRate { joint });
                    }
                    // What the board's timer on this channel can emit in one tick.
                    if per_tick > BOARD_STEPS_PER_TICK[channel as usize] as i128 {
                        return Err(ConfigError::BoardChannel { joint });
                    }
                }
                Drive::Servo { channel, .. } => {
                    let bit = 1u32 << channel.min(31);
                    if channel as usize >= MAX_SERVOS || servos_used & bit != 0 {
                        return Err(ConfigError::JointChannel { joint });
                    }
                    servos_used |= bit;
                    if !self.servo.gains[channel as usize].is_valid() {
                        return Err(ConfigError::ServoGains { channel });
                    }
                }
            }
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
        }
        let contour = &self.servo.contour;
        let cartesian = matches!(self.kinematics, KinematicsConfig::Cartesian { .. });
        if !contour.is_valid() || (contour.mode != ContourMode::Uncoupled && !cartesian) {
            return Err(ConfigError::Contour);
        }
        Ok(())
    }

    /// A Cartesian 3-axis stepper machine (X Y Z on stepper channels 0..2, 400 steps/mm,
    /// 200 × 300 × 100 mm travel, 100 mm/s, 1000 mm/s², PacSci 6410 drives): the
    /// built-in default until a machine file is loaded.
    pub fn cartesian_xyz() -> Self {
        let mm = crate::units::NM_PER_MM;
        let limits = Limits {
            max_velocity: 100 * mm,
            max_accel: 1000 * mm,
        };
        let travel = [(-100, 100), (-150, 150), (-80, 20)];
        let mut joints = heapless::Vec::new();
        for (c, (lo, hi)) in travel.iter().enumerate() {
            let _ = joints.push(JointConfig {
                drive: Drive::Stepper {
                    channel: c as u8,
                    timing: StepTiming::PACSCI_6410,
                    invert_dir: false,
                },
                scale: Scale::new(400, mm as u64),
                rotary: false,
                min: lo * mm,
                max: hi * mm,
                limits,
                homing: Homing {
                    switch_at: hi * mm,
                    search_velocity: 20 * mm,
                    latch_velocity: mm,
                    use_index: false,
                },
            });
        }
        let none = Limits {
            max_velocity: 0,
            max_accel: 0,
        };
        let mut axis_of_joint = [0u8; MAX_JOINTS];
        axis_of_joint[..3].copy_from_slice(&[0, 1, 2]);
        let mut name = heapless::String::new();
        let _ = name.push_str("cartesian-xyz");
        MachineConfig {
            name,
            kinematics: KinematicsConfig::Cartesian { axis_of_joint },
            joints,
            axes: [limits, limits, limits, none, none, none],
            home: [0; AXES],
            servo: ServoConfig::NONE,
            motion: MotionConfig::TRAPEZOID,
        }
    }

    /// The H-4 with rolling table (`examples/machines/h4-table.toml`): rails at
    /// (±250, ±250) mm, forearms 550 mm, bar half-length 60 mm, attachments ±50 mm in Y,
    /// tool 80 mm below E, table axis through (0, 0, −130) mm, forearms ≥ 25° above
    /// horizontal. q1..q4 are servo carriages (1000 counts/mm, 150..650 mm, 500 mm/s)
    /// on servo channels 0..3; q5 the table, a stepper on channel 0 (50 steps/°,
    /// 0..90°, 90 °/s). Home: E at the origin, θ = 0, A = 0, so the tool tip is at
    /// Z −80 mm and every carriage at 475.815 mm.
    pub fn h4_table() -> Self {
        let mm = crate::units::NM_PER_MM;
        let deg = crate::units::NDEG_PER_DEG;
        let mut joints = heapless::Vec::new();
        for c in 0..4u8 {
            let _ = joints.push(JointConfig {
                drive: Drive::Servo { channel: c },
                scale: Scale::new(1000, mm as u64),
                rotary: false,
                min: 150 * mm,
                max: 650 * mm,
                limits: Limits {
                    max_velocity: 500 * mm,
                    max_accel: 5000 * mm,
                },
                homing: Homing {
                    switch_at: 650 * mm,
                    search_velocity: 50 * mm,
                    latch_velocity: mm,
                    use_index: false,
                },
            });
        }
        let _ = joints.push(JointConfig {
            drive: Drive::Stepper {
                channel: 0,
                timing: StepTiming::PACSCI_6410,
                invert_dir: false,
            },
            scale: Scale::new(50, deg as u64),
            rotary: true,
            min: 0,
            max: 90 * deg,
            limits: Limits {
                max_velocity: 90 * deg,
                max_accel: 900 * deg,
            },
            homing: Homing {
                switch_at: 0,
                search_velocity: -10 * deg,
                latch_velocity: deg,
                use_index: false,
            },
        });
        let linear = Limits {
            max_velocity: 200 * mm,
            max_accel: 2000 * mm,
        };
        let rotary = Limits {
            max_velocity: 90 * deg,
            max_accel: 900 * deg,
        };
        let none = Limits {
            max_velocity: 0,
            max_accel: 0,
        };
        let mut name = heapless::String::new();
        let _ = name.push_str("h4-table");
        MachineConfig {
            name,
            kinematics: KinematicsConfig::H4Table(H4TableGeometry {
                rails: [
                    [-250 * mm, 250 * mm],
                    [-250 * mm, -250 * mm],
                    [250 * mm, -250 * mm],
                    [250 * mm, 250 * mm],
                ],
                forearm: 550 * mm,
                bar_half: 60 * mm,
                sides: [-1, -1, 1, 1],
                attach: [
                    [0, 50 * mm, 0],
                    [0, -50 * mm, 0],
                    [0, -50 * mm, 0],
                    [0, 50 * mm, 0],
                ],
                tool_length: 80 * mm,
                table_pivot: [0, 0, -130 * mm],
                min_elevation: 25 * deg,
            }),
            joints,
            axes: [linear, linear, linear, rotary, none, rotary],
            home: [0, 0, -80 * mm, 0, 0, 0],
            servo: ServoConfig {
                gains: [ServoGains::DEFAULT_PLANT; MAX_SERVOS],
                contour: ContourConfig::UNCOUPLED,
            },
            motion: MotionConfig::TRAPEZOID,
        }
    }

    /// The thesis hexapod (`examples/machines/hexapod.toml`): base joints on a 300 mm
    /// circle at 348°, 12°, 108°, 132°, 228°, 252°, platform joints on a 150 mm circle
    /// at 312°, 48°, 72°, 168°, 192°, 288° (both in their z = 0 planes; coordinates
    /// rounded to the nm as the host rounds the machine file). Six stepper legs on
    /// channels 0..5, 400 steps/mm, 350..650 mm, 100 mm/s; home (0, 0, 450 mm) level.
    pub fn hexapod() -> Self {
        let mm = crate::units::NM_PER_MM;
        let deg = crate::units::NDEG_PER_DEG;
        let mut joints = heapless::Vec::new();
        for c in 0..6u8 {
            let _ = joints.push(JointConfig {
                drive: Drive::Stepper {
                    channel: c,
                    timing: StepTiming::PACSCI_6410,
                    invert_dir: false,
                },
                scale: Scale::new(400, mm as u64),
                rotary: false,
                min: 350 * mm,
                max: 650 * mm,
                limits: Limits {
                    max_velocity: 100 * mm,
                    max_accel: 1000 * mm,
                },
                homing: Homing {
                    switch_at: 650 * mm,
                    search_velocity: 20 * mm,
                    latch_velocity: mm,
                    use_index: false,
                },
            });
        }
        let linear = Limits {
            max_velocity: 100 * mm,
            max_accel: 1000 * mm,
        };
        let rotary = Limits {
            max_velocity: 30 * deg,
            max_accel: 300 * deg,
        };
        let mut name = heapless::String::new();
        let _ = name.push_str("hexapod");
        MachineConfig {
            name,
            kinematics: KinematicsConfig::Hexapod(HexapodGeometry {
                base: [
                    [293_444_280, -62_373_507, 0],
                    [293_444_280, 62_373_507, 0],
                    [-92_705_098, 285_316_955, 0],
                    [-200_739_182, 222_943_448, 0],
                    [-200_739_182, -222_943_448, 0],
                    [-92_705_098, -285_316_955, 0],
                ],
                platform: [
                    [100_369_591, -111_471_724, 0],
                    [100_369_591, 111_471_724, 0],
                    [46_352_549, 142_658_477, 0],
                    [-146_722_140, 31_186_754, 0],
                    [-146_722_140, -31_186_754, 0],
                    [46_352_549, -142_658_477, 0],
                ],
            }),
            joints,
            axes: [linear, linear, linear, rotary, rotary, rotary],
            home: [0, 0, 450 * mm, 0, 0, 0],
            servo: ServoConfig::NONE,
            motion: MotionConfig::TRAPEZOID,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_built_in_machine_is_valid() {
        assert_eq!(MachineConfig::cartesian_xyz().validate(), Ok(()));
    }

    #[test]
    fn the_h4_and_hexapod_machines_are_valid() {
        assert_eq!(MachineConfig::h4_table().validate(), Ok(()));
        assert_eq!(MachineConfig::hexapod().validate(), Ok(()));
    }

    #[test]
    fn the_h4_and_hexapod_machines_fit_the_configuration_store() {
        let mut buf = [0u8; crate::store::MAX_CONFIG_BYTES];
        for m in [MachineConfig::h4_table(), MachineConfig::hexapod()] {
            let n = crate::store::encode(&m, &mut buf).expect("fits");
            let back: MachineConfig = postcard::from_bytes(&buf[..n]).unwrap();
            assert_eq!(back, m);
        }
    }

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

    #[test]
    fn scale_round_trips_whole_steps() {
        let s = Scale {
            steps: 400,
            per_units: 1_000_000,
        };
        assert_eq!(s.steps_at(10_000_000), 4000);
        assert_eq!(s.steps_at(-1_250), -1); // -0.5 step rounds away from zero
        assert_eq!(s.position_of(4000), 10_000_000);
    }
}
