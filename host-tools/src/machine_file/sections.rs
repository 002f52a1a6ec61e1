//! The sections of a machine file as they are written (mm, degrees, seconds), one type
//! per table, and the conversion of each to the core's form. Names that choose
//! between kinds (`drive`, `kinematics`, `contour.mode`, `motion.profile`) are enums:
//! serde refuses any other word where it is written.

use super::convert::{mm_points, positive, positive_units, to_units};
use super::{exact, refused, FieldError};
use pkmc::config::{
    ContourConfig, Drive, H4TableGeometry, HexapodGeometry, HexapodXyGeometry, Homing, JointConfig,
    Limits, MotionConfig, Scale, ServoGains, StepTiming,
};
use pkmc::units::units_per_user;
use serde::Deserialize;

/// A joint's drive (`drive = "stepper"`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum DriveKind {
    /// Step and direction.
    Stepper,
    /// Encoder in, DAC out.
    Servo,
}

/// The machine's kinematics (`kinematics = "h4-table"`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum KinematicsKind {
    /// Each joint follows one pose axis.
    Cartesian,
    /// The H-4 parallel head over a rolling table (`[h4_table]`).
    H4Table,
    /// The hexapod (`[hexapod]`).
    Hexapod,
    /// The hexapod carrying the workpiece under a tool on an X-Y table (`[hexapod]`
    /// and `[hexapod_xy]`).
    HexapodXy,
}

impl KinematicsKind {
    /// The section holding this kinematics' geometry (`kinematics` for Cartesian).
    pub fn section(self) -> &'static str {
        match self {
            KinematicsKind::Cartesian => "kinematics",
            KinematicsKind::H4Table => "h4_table",
            KinematicsKind::Hexapod => "hexapod",
            KinematicsKind::HexapodXy => "hexapod_xy",
        }
    }
}

/// `contour.mode`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ContourMode {
    /// Each axis on its own.
    Uncoupled,
    /// Cross-coupled control.
    CrossCoupled,
    /// Cross-coupled pre-compensation.
    Ccpm,
}

/// `motion.profile`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Profile {
    /// Trapezoidal speed profiles.
    Trapezoid,
    /// Trapezoids smoothed to a jerk limit.
    JerkLimited,
}

/// Limits of one axis or joint, in mm or degrees and seconds.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LimitsFile {
    /// mm/s or °/s.
    pub max_velocity: f64,
    /// mm/s² or °/s².
    pub max_accel: f64,
}

/// Step/direction drive timing, ns and Hz; defaults to the Pacific Scientific 6410.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TimingFile {
    /// Minimum STEP high time, ns.
    pub min_pulse_ns: u32,
    /// Maximum step rate, Hz.
    pub max_rate_hz: u32,
    /// DIR setup before a STEP rising edge, ns.
    pub dir_setup_ns: u32,
    /// DIR hold after a STEP rising edge, ns.
    pub dir_hold_ns: u32,
}

/// One joint.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JointFile {
    /// Display name.
    pub name: String,
    /// Cartesian machines: the pose axis this joint follows (X Y Z A B C).
    pub axis: Option<String>,
    /// `"stepper"` or `"servo"`.
    pub drive: DriveKind,
    /// Board channel of that drive type, 0-based.
    pub channel: u8,
    /// Rotary joint (degrees) instead of linear (mm).
    #[serde(default)]
    pub rotary: bool,
    /// Steps (stepper) or encoder counts (servo) per mm or per degree.
    pub steps_per_unit: f64,
    /// Travel, mm or degrees.
    pub min: f64,
    /// Travel, mm or degrees.
    pub max: f64,
    /// mm/s or °/s.
    pub max_velocity: f64,
    /// mm/s² or °/s².
    pub max_accel: f64,
    /// Stepper: reverse DIR.
    #[serde(default)]
    pub invert_dir: bool,
    /// Stepper timing; the PacSci 6410 when absent.
    pub timing: Option<TimingFile>,
    /// Servo: the 10 kHz loop's gains ([`pkmc::drive::servo`]); required for a servo joint.
    pub servo: Option<ServoFile>,
    /// Homing on a switch ([`pkmc::drive::homing`]); without it the joint is not homed.
    pub homing: Option<HomingFile>,
    /// Servo: the plant's transfer function, for simulation ([`crate::control::plant`]).
    pub plant: Option<crate::control::plant::PlantFile>,
    /// Largest force the joint may carry, N (N·m for a rotary joint), for the statics
    /// of a cutting load ([`crate::analysis::statics`]).
    pub force_limit: Option<f64>,
    /// A hydraulic joint's cylinder area, mm²: its force limit is this times the
    /// machine's `supply_pressure`.
    pub cylinder_area: Option<f64>,
    /// Servo: the weights of its LQG design ([`super::lqg`]).
    pub lqg: Option<crate::control::lqg::LqgWeights>,
    /// Servo: the LQG design's gains, as `contour-study --design-lqg` prints them.
    pub lqg_gains: Option<pkmc::config::LqgGains>,
    /// Servo: the model the LQG design was made on, when it is not `plant` (the model
    /// `nc-send tune` identified, [`super::lqg`]).
    pub lqg_model: Option<super::lqg::LqgModel>,
}

/// A servo joint's `servo = { ... }` table: [`pkmc::config::ServoGains`] in file units
/// (c.u. = the amplifier's command unit, counts = encoder counts).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ServoFile {
    /// The feedback law: `"pid"` (the default) or `"lqg"` (`lqg_gains`).
    #[serde(default)]
    pub law: super::lqg::LawKind,
    /// c.u. per count of following error (PID).
    #[serde(default)]
    pub kp: f32,
    /// c.u. per (count · s).
    #[serde(default)]
    pub ki: f32,
    /// c.u. per (count/s).
    #[serde(default)]
    pub kd: f32,
    /// Velocity feed-forward, c.u. per (count/s).
    #[serde(default)]
    pub kvff: f32,
    /// Acceleration feed-forward, c.u. per (count/s²).
    #[serde(default)]
    pub kaff: f32,
    /// Output clamp, ± c.u.
    pub max_output: f32,
    /// Integrator clamp, ± c.u. (defaults to `max_output`).
    pub max_integral: Option<f32>,
    /// DAC counts per c.u. (negative reverses).
    pub dac_per_unit: f32,
    /// DAC offset trim, counts.
    #[serde(default)]
    pub dac_offset: i16,
    /// Following-error limit at full speed, mm or degrees.
    pub ferror: f64,
    /// Following-error limit at standstill, mm or degrees.
    pub min_ferror: f64,
}

/// A joint's `homing = { ... }` table: [`pkmc::config::Homing`] in file units.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HomingFile {
    /// Where the switch releases on the way back (or the index pulse after it), mm or
    /// degrees.
    pub switch_at: f64,
    /// Speed towards the switch, mm/s or °/s; the sign is the direction.
    pub search_velocity: f64,
    /// Speed backing off the switch, mm/s or °/s (> 0).
    pub latch_velocity: f64,
    /// Latch on the encoder's index pulse after the switch (servo joints).
    #[serde(default)]
    pub use_index: bool,
}

/// The `[contour]` table: [`pkmc::config::ContourConfig`].
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ContourFile {
    /// `"uncoupled"`, `"cross-coupled"` or `"ccpm"`.
    pub mode: ContourMode,
    /// Cross-coupled P gain, c.u. per mm of contour error.
    #[serde(default)]
    pub kp: f32,
    /// Cross-coupled I gain, c.u. per (mm · s).
    #[serde(default)]
    pub ki: f32,
    /// Cross-coupled integrator clamp, ± c.u.
    #[serde(default)]
    pub max_integral: f32,
    /// CCPM reference pre-compensation rate, 1/s.
    #[serde(default)]
    pub kr: f32,
    /// CCPM reference offset clamp, ± mm.
    #[serde(default)]
    pub max_offset: f32,
}

impl ContourFile {
    /// The core form.
    pub fn to_config(&self) -> ContourConfig {
        use pkmc::config::ContourMode as Core;
        ContourConfig {
            mode: match self.mode {
                ContourMode::Uncoupled => Core::Uncoupled,
                ContourMode::CrossCoupled => Core::CrossCoupled,
                ContourMode::Ccpm => Core::Ccpm,
            },
            kp: self.kp,
            ki: self.ki,
            max_integral: self.max_integral,
            kr: self.kr,
            max_offset: self.max_offset,
        }
    }
}

/// `[h4_table]`: geometry of the H-4 with rolling table, mm and degrees (conventions:
/// [`H4TableGeometry`]).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct H4TableFile {
    /// X Y of each vertical rail.
    #[serde(deserialize_with = "exact::de")]
    pub rails: [[f64; 2]; 4],
    /// Forearm length L.
    pub forearm: f64,
    /// Half length d of the central bar.
    pub bar_half: f64,
    /// Bar end each arm holds: -1 or +1.
    #[serde(deserialize_with = "exact::de")]
    pub sides: [i8; 4],
    /// Attachment offsets e_i (not turned with C).
    #[serde(deserialize_with = "exact::de")]
    pub attach: [[f64; 3]; 4],
    /// Tool tip below the head point E.
    pub tool_length: f64,
    /// A point of the table axis (parallel to X).
    #[serde(deserialize_with = "exact::de")]
    pub table_pivot: [f64; 3],
    /// Lowest forearm elevation above horizontal, degrees.
    pub min_elevation: f64,
}

/// `[hexapod]`: joint positions in mm, each set either as coordinates (`base`,
/// `platform`) or as a radius and six angles in degrees in the z = 0 plane
/// (`base_radius` + `base_angles`, `platform_radius` + `platform_angles`).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HexapodFile {
    /// Base joints a_i, machine frame.
    #[serde(default, deserialize_with = "exact::de_some")]
    pub base: Option<[[f64; 3]; 6]>,
    /// Radius of the base joints' circle.
    pub base_radius: Option<f64>,
    /// Angles of the base joints on their circle, degrees.
    #[serde(default, deserialize_with = "exact::de_some")]
    pub base_angles: Option<[f64; 6]>,
    /// Platform joints b_i, platform frame.
    #[serde(default, deserialize_with = "exact::de_some")]
    pub platform: Option<[[f64; 3]; 6]>,
    /// Radius of the platform joints' circle.
    pub platform_radius: Option<f64>,
    /// Angles of the platform joints on their circle, degrees.
    #[serde(default, deserialize_with = "exact::de_some")]
    pub platform_angles: Option<[f64; 6]>,
}

/// `[motion]`: the shape of the speed profiles.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MotionFile {
    /// `"trapezoid"` or `"jerk-limited"`.
    pub profile: Profile,
    /// Jerk limit for "jerk-limited", mm/s³ (°/s³ for rotary axes and joints).
    pub jerk: Option<f64>,
}

impl MotionFile {
    /// The core form: the smoothing window that keeps every axis's and joint's jerk
    /// within `jerk` (3·a/(w·T) ≤ J, see `pkmc::motion::interp`), as a power of two of ticks.
    pub fn to_config(
        &self,
        axes: &[LimitsFile],
        joints: &[JointFile],
    ) -> Result<MotionConfig, FieldError> {
        match self.profile {
            Profile::Trapezoid => Ok(MotionConfig::TRAPEZOID),
            Profile::JerkLimited => {
                let jerk = self
                    .jerk
                    .ok_or_else(|| refused!("motion.jerk: \"jerk-limited\" needs a jerk limit"))?;
                let jerk = positive(jerk, "motion.jerk")?;
                let a_max = axes
                    .iter()
                    .map(|l| l.max_accel)
                    .chain(joints.iter().map(|j| j.max_accel))
                    .fold(0.0f64, f64::max);
                let ticks = (3.0 * a_max / jerk * pkmc::units::TICK_HZ as f64)
                    .ceil()
                    .max(1.0);
                let max = pkmc::motion::interp::MAX_WINDOW as f64;
                if ticks > max {
                    return Err(refused!(
                        "motion.jerk: {jerk} is too low for accelerations of {a_max}: it needs \
                         {ticks} ticks of smoothing, at most {max} are available (raise the \
                         jerk or lower the accelerations)"
                    ));
                }
                Ok(MotionConfig {
                    smoothing_ticks: (ticks as u32).next_power_of_two() as u8,
                })
            }
        }
    }
}

impl LimitsFile {
    /// The core form, in axis units; `field` names the table (`axes.X`).
    pub fn to_limits(&self, rotary: bool, field: &str) -> Result<Limits, FieldError> {
        Ok(Limits {
            max_velocity: positive_units(
                self.max_velocity,
                rotary,
                &format!("{field}.max_velocity"),
            )?,
            max_accel: positive_units(self.max_accel, rotary, &format!("{field}.max_accel"))?,
        })
    }
}

impl JointFile {
    /// The core form of joint `j`; a servo joint's loop gains go to `gains` (by its
    /// channel).
    pub fn to_config(&self, j: usize, gains: &mut [ServoGains]) -> Result<JointConfig, FieldError> {
        let f = |s: &str| format!("joints[{j}] ({}).{s}", self.name);
        let per_unit = positive(self.steps_per_unit, &f("steps_per_unit"))?;
        // Scale as a ratio: steps per 10^6 user units, to 1e-6 step per user unit.
        // Reduced to lowest terms before it must fit the core's u32 of steps, so a
        // whole number of counts per unit fits up to u32::MAX (10 nm: 100 000/mm).
        let steps = (per_unit * 1e6).round();
        let per = (1_000_000 * units_per_user(self.rotary)) as u64;
        let g = if steps < 1.8e19 {
            pkmc::config::gcd(steps as u64, per).max(1)
        } else {
            1
        };
        if steps / g as f64 > u32::MAX as f64 {
            return Err(refused!("{}: {per_unit} is too large", f("steps_per_unit")));
        }
        let scale = Scale::new((steps as u64 / g) as u32, per / g);
        let drive = self.drive(&f)?;
        if let (Drive::Servo { channel }, Some(sf)) = (drive, &self.servo) {
            if let Some(g) = gains.get_mut(channel as usize) {
                // Following-error limits in counts: per_unit is counts per mm or degree.
                *g = sf.to_gains(per_unit);
            }
        }
        Ok(JointConfig {
            drive,
            scale,
            rotary: self.rotary,
            min: to_units(self.min, self.rotary, &f("min"))?,
            max: to_units(self.max, self.rotary, &f("max"))?,
            limits: Limits {
                max_velocity: positive_units(self.max_velocity, self.rotary, &f("max_velocity"))?,
                max_accel: positive_units(self.max_accel, self.rotary, &f("max_accel"))?,
            },
            homing: match &self.homing {
                None => Homing::NONE,
                Some(h) => h.to_homing(self.rotary, &f)?,
            },
        })
    }

    fn drive(&self, f: &dyn Fn(&str) -> String) -> Result<Drive, FieldError> {
        Ok(match self.drive {
            DriveKind::Stepper => Drive::Stepper {
                channel: self.channel,
                timing: self
                    .timing
                    .as_ref()
                    .map_or(StepTiming::PACSCI_6410, |t| StepTiming {
                        min_pulse_ns: t.min_pulse_ns,
                        max_rate_hz: t.max_rate_hz,
                        dir_setup_ns: t.dir_setup_ns,
                        dir_hold_ns: t.dir_hold_ns,
                    }),
                invert_dir: self.invert_dir,
            },
            DriveKind::Servo if self.servo.is_none() => {
                return Err(refused!(
                    "{}: a servo joint needs its loop's gains: servo = {{ kp = .., \
                     max_output = .., dac_per_unit = .., ferror = .., min_ferror = .. }}",
                    f("servo")
                ))
            }
            DriveKind::Servo => Drive::Servo {
                channel: self.channel,
            },
        })
    }
}

impl ServoFile {
    /// The core's gains; following-error limits from mm (or degrees) to counts at
    /// `counts` per unit.
    fn to_gains(&self, counts: f64) -> ServoGains {
        ServoGains {
            kp: self.kp,
            ki: self.ki,
            kd: self.kd,
            kvff: self.kvff,
            kaff: self.kaff,
            max_output: self.max_output,
            max_integral: self.max_integral.unwrap_or(self.max_output),
            dac_per_unit: self.dac_per_unit,
            dac_offset: self.dac_offset,
            ferror: (self.ferror * counts).round().clamp(0.0, u32::MAX as f64) as u32,
            min_ferror: (self.min_ferror * counts)
                .round()
                .clamp(0.0, u32::MAX as f64) as u32,
        }
    }
}

impl HomingFile {
    fn to_homing(&self, rotary: bool, f: &dyn Fn(&str) -> String) -> Result<Homing, FieldError> {
        Ok(Homing {
            switch_at: to_units(self.switch_at, rotary, &f("homing.switch_at"))?,
            search_velocity: to_units(self.search_velocity, rotary, &f("homing.search_velocity"))?,
            latch_velocity: to_units(self.latch_velocity, rotary, &f("homing.latch_velocity"))?,
            use_index: self.use_index,
        })
    }
}

impl H4TableFile {
    /// The core's geometry of the H-4 with rolling table.
    pub(super) fn to_geometry(&self) -> Result<H4TableGeometry, FieldError> {
        let f = |s: &str| format!("h4_table.{s}");
        Ok(H4TableGeometry {
            rails: mm_points(&self.rails, &f("rails"))?,
            forearm: to_units(positive(self.forearm, &f("forearm"))?, false, &f("forearm"))?,
            bar_half: to_units(
                positive(self.bar_half, &f("bar_half"))?,
                false,
                &f("bar_half"),
            )?,
            sides: self.sides,
            attach: mm_points(&self.attach, &f("attach"))?,
            tool_length: to_units(self.tool_length, false, &f("tool_length"))?,
            table_pivot: mm_points(&[self.table_pivot], &f("table_pivot"))?[0],
            min_elevation: to_units(self.min_elevation, true, &f("min_elevation"))?,
        })
    }
}

/// One set of hexapod joints from coordinates or from a radius and angles.
fn hexapod_joints(
    points: &Option<[[f64; 3]; 6]>,
    radius: Option<f64>,
    angles: &Option<[f64; 6]>,
    name: &str,
) -> Result<[[i64; 3]; 6], FieldError> {
    match (points, radius, angles) {
        (Some(p), None, None) => mm_points(p, &format!("hexapod.{name}")),
        (None, Some(r), Some(a)) => {
            let r = positive(r, &format!("hexapod.{name}_radius"))?;
            let mut p = [[0.0; 3]; 6];
            for (pi, deg) in p.iter_mut().zip(a) {
                let t = deg.to_radians();
                *pi = [r * t.cos(), r * t.sin(), 0.0];
            }
            mm_points(&p, &format!("hexapod.{name}_angles"))
        }
        _ => Err(refused!(
            "hexapod.{name}: give either {name} = [[x, y, z], ...] (six joints) or \
             {name}_radius and {name}_angles"
        )),
    }
}

impl HexapodFile {
    /// The core's geometry of the hexapod.
    pub(super) fn to_geometry(&self) -> Result<HexapodGeometry, FieldError> {
        Ok(HexapodGeometry {
            base: hexapod_joints(&self.base, self.base_radius, &self.base_angles, "base")?,
            platform: hexapod_joints(
                &self.platform,
                self.platform_radius,
                &self.platform_angles,
                "platform",
            )?,
        })
    }
}

/// `[hexapod_xy]`: where the workpiece and the tool are, mm (the legs are in
/// `[hexapod]`; the table's X and Y are joints q7 and q8).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HexapodXyFile {
    /// The platform origin at home (level), machine frame: workpiece coordinates are
    /// machine coordinates there.
    #[serde(deserialize_with = "exact::de")]
    pub platform_home: [f64; 3],
    /// Height of the tool tip, machine frame.
    pub tool_z: f64,
}

impl HexapodXyFile {
    /// The core's geometry, with the legs of `hexapod`.
    pub(super) fn to_geometry(
        &self,
        hexapod: HexapodGeometry,
    ) -> Result<HexapodXyGeometry, FieldError> {
        Ok(HexapodXyGeometry {
            hexapod,
            platform_home: mm_points(&[self.platform_home], "hexapod_xy.platform_home")?[0],
            tool_z: to_units(self.tool_z, false, "hexapod_xy.tool_z")?,
        })
    }
}

/// One `[[tools]]` entry: a tool of the machine's tool table, mm (the table
/// `nc-send --tools FILE` replaces).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ToolFile {
    /// Tool number (T).
    pub number: u32,
    /// Length offset along Z that G43 applies, mm.
    #[serde(default)]
    pub length: f64,
    /// Offset along X that G43 applies, mm.
    #[serde(default)]
    pub x: f64,
    /// Offset along Y, mm.
    #[serde(default)]
    pub y: f64,
    /// Offset about A, degrees.
    #[serde(default)]
    pub a: f64,
    /// Offset about B, degrees.
    #[serde(default)]
    pub b: f64,
    /// Offset about C, degrees.
    #[serde(default)]
    pub c: f64,
    /// Diameter, mm (≥ 0).
    #[serde(default)]
    pub diameter: f64,
    /// What the tool is (not used).
    pub comment: Option<String>,
}
