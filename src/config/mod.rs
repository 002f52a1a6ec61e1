//! Machine configuration: geometry, joint types, scales, limits and drive timing.
//!
//! The host reads a human TOML machine file (mm, degrees, seconds), checks it and
//! converts it to this integer form (units in [`crate::units`]); the controller keeps
//! and validates it. Nothing in the kinematics or the planner is hard-coded: every
//! number comes from here. [`MachineConfig::validate`] names the offending field.
//!
//! Files: this one holds the types and the board's limits; `validate.rs` the checks
//! ([`MachineConfig::validate`], [`ConfigError`]); `builtin.rs` the built-in machines
//! ([`MachineConfig::cartesian_xyz`], [`MachineConfig::h4_table`],
//! [`MachineConfig::hexapod`]).

use serde::{Deserialize, Serialize};

mod builtin;
mod lqg;
mod validate;

pub use lqg::{LqgGains, LQG_STATES};
pub use validate::{BoardChannels, ConfigError, GeometryField};

/// Number of pose axes: X Y Z (linear) and A B C (rotary).
pub const AXES: usize = 6;
/// Most joints a machine may have (the board's 7 stepper channels and 4 of its servo
/// channels; the eight-servo board has 8).
pub const MAX_JOINTS: usize = 11;
/// Stepper channels the board drives.
pub const MAX_STEPPERS: usize = 7;
/// Servo channels the board drives.
pub const MAX_SERVOS: usize = 8;
/// Most steps a stepper channel on an advanced timer (TIM1, TIM8, TIM20) emits in one
/// tick: one step per timer period, counted by its 16-bit repetition counter.
pub const STEPS_PER_TICK_ADVANCED: u32 = 1 << 16;
/// Most steps a stepper channel on a compact timer (TIM15, TIM16, TIM17) emits in one
/// tick: its repetition counter has 8 bits.
pub const STEPS_PER_TICK_COMPACT: u32 = 1 << 8;
/// Most steps the HRTIM1 timer A channel emits in one tick: its repetition counter
/// (REPxR) has 8 bits.
pub const STEPS_PER_TICK_HRTIM: u32 = 1 << 8;
/// Most steps the reference board (NUCLEO-G474RE, `docs/wiring.md`) emits on each
/// stepper channel in one tick: channels 0–2 on TIM1/TIM8/TIM20, 3–5 on
/// TIM15/TIM16/TIM17 and 6 on HRTIM1 timer A. A machine needing more is refused
/// rather than losing steps. The firmware's pin map (`src/bin/firmware/board.rs`)
/// checks at compile time that its timers agree.
pub const BOARD_STEPS_PER_TICK: [u32; MAX_STEPPERS] = [
    STEPS_PER_TICK_ADVANCED,
    STEPS_PER_TICK_ADVANCED,
    STEPS_PER_TICK_ADVANCED,
    STEPS_PER_TICK_COMPACT,
    STEPS_PER_TICK_COMPACT,
    STEPS_PER_TICK_COMPACT,
    STEPS_PER_TICK_HRTIM,
];
/// Most ticks of smoothing, the interpolator's moving-average window
/// ([`MotionConfig::smoothing_ticks`], [`crate::motion::interp`]).
pub const MAX_WINDOW: usize = 32;

/// The smoothing window in force for a request of `ticks`: a power of two, at most
/// [`MAX_WINDOW`] (1: none).
pub fn window_of(ticks: u32) -> u32 {
    ticks.max(1).next_power_of_two().min(MAX_WINDOW as u32)
}
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

    /// Shortest time between two STEP rising edges of a train: the drive's rate limit,
    /// and at least twice its pulse (high, then as long low), ns (at least 1).
    #[inline(always)]
    pub fn min_step_period_ns(&self) -> u32 {
        self.min_interval_ns().max(2 * self.min_pulse_ns).max(1)
    }

    /// Most steps that fit in one tick from `start_ns` after its start (after a DIR
    /// change: from the DIR-setup time), each a [`min_step_period_ns`] apart: the one
    /// rule of the step scheduler ([`crate::drive::stepper`]) and of the configuration's
    /// speed check.
    ///
    /// [`min_step_period_ns`]: Self::min_step_period_ns
    #[inline(always)]
    pub fn steps_in_tick_after(&self, start_ns: u32) -> u32 {
        crate::units::TICK_NS.saturating_sub(start_ns) / self.min_step_period_ns()
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

/// Greatest common divisor (0 for 0 and 0).
pub const fn gcd(mut a: u64, mut b: u64) -> u64 {
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
/// servo period by [`crate::drive::servo::ServoAxis`] (PID on the following error plus velocity
/// and acceleration feed-forward, LinuxCNC `pid` style).
///
/// "Command units" (c.u.) are the amplifier's input unit, chosen per machine (volts,
/// or the identified model's "command pulses"); [`dac_per_unit`](Self::dac_per_unit)
/// turns them into DAC counts. Gains are `f32` because the loop runs in single
/// precision on the Cortex-M4F FPU (see [`crate::drive::servo`]); equality compares bits.
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

/// How the servo loops of the linear Cartesian axes are coordinated ([`crate::drive::contour`]).
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

/// Most distinct LQG designs a machine carries ([`ServoConfig::lqg`]): report B's
/// machine needs three (the legs', the table X's and Y's); each is 136 bytes of RAM in
/// the configuration and again in the servo bank.
pub const MAX_LQG: usize = 3;

/// Servo settings of the machine: the loop of each servo channel and their coupling.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ServoConfig {
    /// Loop of each servo channel, indexed by `Drive::Servo::channel`: its limits,
    /// output stage and feed-forward, and the PID gains.
    pub gains: [ServoGains; MAX_SERVOS],
    /// Each channel's feedback law: 0 the PID of `gains`, k ≥ 1 the LQG design
    /// `lqg[k − 1]` ([`crate::drive::lqg`]; the feed-forward and limits of `gains` still apply).
    pub law: [u8; MAX_SERVOS],
    /// The LQG designs the channels use (channels with the same plant share one).
    pub lqg: heapless::Vec<crate::config::LqgGains, MAX_LQG>,
    /// Coupling of the channels in pose coordinates ([`crate::drive::contour`]).
    pub contour: ContourConfig,
}

impl ServoConfig {
    /// No servo channels in use.
    pub const NONE: ServoConfig = ServoConfig {
        gains: [ServoGains::NONE; MAX_SERVOS],
        law: [0; MAX_SERVOS],
        lqg: heapless::Vec::new(),
        contour: ContourConfig::UNCOUPLED,
    };

    /// The LQG design channel `c` runs, if it runs one.
    pub fn lqg_of(&self, c: usize) -> Option<&crate::config::LqgGains> {
        let k = *self.law.get(c)? as usize;
        k.checked_sub(1).and_then(|i| self.lqg.get(i))
    }
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

/// Homing of one joint by [`crate::drive::homing`]: search for the home switch, back off it
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
    /// Hexapod carrying the workpiece under a tool on an X-Y table (report B's
    /// machine): joints q1..q6 the legs, q7 q8 the table's X and Y. Pose: X Y Z A B in
    /// workpiece coordinates, the tool axis along `Rx(A)·Ry(B)·ẑ` there; C unused.
    /// See [`crate::kinematics::hexapod_xy`].
    HexapodXy(HexapodXyGeometry),
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

/// Hexapod under an X-Y table's tool ([`KinematicsConfig::HexapodXy`]), nm.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct HexapodXyGeometry {
    /// The platform's legs, as [`HexapodGeometry`].
    pub hexapod: HexapodGeometry,
    /// Platform origin at home (level), machine frame: workpiece coordinates are
    /// machine coordinates there.
    pub platform_home: [i64; 3],
    /// Height of the tool tip, machine frame (the table moves it in X and Y only).
    pub tool_z: i64,
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

#[cfg(test)]
mod tests {
    use super::*;

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
