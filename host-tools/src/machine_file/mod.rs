//! Machine files: the human TOML description of a machine (mm, degrees, seconds),
//! checked and converted to the core's integer [`MachineConfig`].
//!
//! Every error names the file and the field (`joints[2].steps_per_unit`); TOML syntax
//! errors carry the file's line and column. Unknown fields are refused, so a misspelt
//! limit is never silently ignored.

use anyhow::{anyhow, bail, Result};
use pkmc::config::{
    Drive, GeometryField, H4TableGeometry, HexapodGeometry, Homing, JointConfig, KinematicsConfig,
    Limits, MachineConfig, Scale, ServoConfig, ServoGains, StepTiming, AXES, AXIS_NAMES,
    MAX_JOINTS,
};
use pkmc::units::units_per_user;
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::Path;

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
    /// "stepper" or "servo".
    pub drive: String,
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
    /// Servo: the 10 kHz loop's gains ([`pkmc::servo`]); required for a servo joint.
    pub servo: Option<ServoFile>,
    /// Homing on a switch ([`pkmc::homing`]); without it the joint is not homed.
    pub homing: Option<HomingFile>,
    /// Servo: the plant's transfer function, for simulation ([`crate::sim::plant`]).
    pub plant: Option<crate::sim::plant::PlantFile>,
}

/// A servo joint's `servo = { ... }` table: [`pkmc::config::ServoGains`] in file units
/// (c.u. = the amplifier's command unit, counts = encoder counts).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ServoFile {
    /// c.u. per count of following error.
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
    /// "uncoupled", "cross-coupled" or "ccpm".
    pub mode: String,
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
    pub fn to_config(&self) -> Result<pkmc::config::ContourConfig> {
        use pkmc::config::ContourMode;
        let mode = match self.mode.as_str() {
            "uncoupled" => ContourMode::Uncoupled,
            "cross-coupled" => ContourMode::CrossCoupled,
            "ccpm" => ContourMode::Ccpm,
            other => bail!(
                "contour.mode: unknown mode {other:?} (expected \"uncoupled\", \"cross-coupled\" or \"ccpm\")"
            ),
        };
        Ok(pkmc::config::ContourConfig {
            mode,
            kp: self.kp,
            ki: self.ki,
            max_integral: self.max_integral,
            kr: self.kr,
            max_offset: self.max_offset,
        })
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

/// A machine file.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MachineFile {
    /// Machine name.
    pub name: String,
    /// "cartesian", "h4-table" or "hexapod".
    pub kinematics: String,
    /// Home pose X Y Z (mm) A B C (degrees).
    #[serde(default, deserialize_with = "exact::de")]
    pub home: [f64; AXES],
    /// Geometry for `kinematics = "h4-table"`.
    pub h4_table: Option<H4TableFile>,
    /// Geometry for `kinematics = "hexapod"`.
    pub hexapod: Option<HexapodFile>,
    /// Limits per used axis, keyed by axis letter.
    pub axes: BTreeMap<String, LimitsFile>,
    /// Joints q1..qN.
    pub joints: Vec<JointFile>,
    /// Contour control of the servo axes; uncoupled when absent.
    pub contour: Option<ContourFile>,
    /// Speed-profile shape; trapezoidal when absent.
    pub motion: Option<MotionFile>,
}

/// `[motion]`: the shape of the speed profiles.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MotionFile {
    /// "trapezoid" or "jerk-limited".
    pub profile: String,
    /// Jerk limit for "jerk-limited", mm/s³ (°/s³ for rotary axes and joints).
    pub jerk: Option<f64>,
}

impl MotionFile {
    /// The core form: the smoothing window that keeps every axis's and joint's jerk
    /// within `jerk` (3·a/(w·T) ≤ J, see `pkmc::interp`), as a power of two of ticks.
    pub fn to_config(
        &self,
        axes: &[LimitsFile],
        joints: &[JointFile],
    ) -> Result<pkmc::config::MotionConfig> {
        match self.profile.as_str() {
            "trapezoid" => Ok(pkmc::config::MotionConfig::TRAPEZOID),
            "jerk-limited" => {
                let jerk = positive(
                    self.jerk.ok_or_else(|| anyhow!("motion.jerk: \"jerk-limited\" needs a jerk limit"))?,
                    "motion.jerk",
                )?;
                let a_max = axes
                    .iter()
                    .map(|l| l.max_accel)
                    .chain(joints.iter().map(|j| j.max_accel))
                    .fold(0.0f64, f64::max);
                let ticks = (3.0 * a_max / jerk * pkmc::units::TICK_HZ as f64).ceil().max(1.0);
                let max = pkmc::interp::MAX_WINDOW as f64;
                if ticks > max {
                    bail!(
                        "motion.jerk: {jerk} is too low for accelerations of {a_max}: it needs {ticks} ticks of smoothing, at most {max} are available (raise the jerk or lower the accelerations)"
                    );
                }
                Ok(pkmc::config::MotionConfig {
                    smoothing_ticks: (ticks as u32).next_power_of_two() as u8,
                })
            }
            other => bail!("motion.profile: unknown profile {other:?} (expected \"trapezoid\" or \"jerk-limited\")"),
        }
    }
}

/// Fixed-size arrays read from TOML arrays of exactly that many elements: serde's
/// arrays take the first N elements and drop the rest without a word (seven `home`
/// values or five rails were accepted so).
mod exact {
    use serde::{de::Error, Deserialize, Deserializer};

    /// A value read exactly from a TOML value.
    pub trait Exact: Sized {
        fn exact(v: toml::Value) -> Result<Self, String>;
    }

    impl Exact for f64 {
        fn exact(v: toml::Value) -> Result<Self, String> {
            match v {
                toml::Value::Float(f) => Ok(f),
                toml::Value::Integer(i) => Ok(i as f64),
                other => Err(format!("expected a number, got {}", other.type_str())),
            }
        }
    }

    impl Exact for i8 {
        fn exact(v: toml::Value) -> Result<Self, String> {
            match v {
                toml::Value::Integer(i) => {
                    i8::try_from(i).map_err(|_| format!("{i} is out of range"))
                }
                other => Err(format!("expected an integer, got {}", other.type_str())),
            }
        }
    }

    impl<T: Exact, const N: usize> Exact for [T; N] {
        fn exact(v: toml::Value) -> Result<Self, String> {
            let toml::Value::Array(items) = v else {
                return Err(format!("expected an array of {N}, got {}", v.type_str()));
            };
            if items.len() != N {
                return Err(format!("expected {N} values, got {}", items.len()));
            }
            let items: Vec<T> = items.into_iter().map(T::exact).collect::<Result<_, _>>()?;
            items.try_into().map_err(|_| format!("expected {N} values"))
        }
    }

    pub fn de<'de, D: Deserializer<'de>, T: Exact>(d: D) -> Result<T, D::Error> {
        T::exact(toml::Value::deserialize(d)?).map_err(D::Error::custom)
    }

    pub fn de_some<'de, D: Deserializer<'de>, T: Exact>(d: D) -> Result<Option<T>, D::Error> {
        de(d).map(Some)
    }
}

fn mm_points<const N: usize, const D: usize>(
    v: &[[f64; D]; N],
    field: &str,
) -> Result<[[i64; D]; N]> {
    let mut out = [[0; D]; N];
    for (i, p) in v.iter().enumerate() {
        for (k, c) in p.iter().enumerate() {
            out[i][k] = to_units(*c, false, &format!("{field}[{i}][{k}]"))?;
        }
    }
    Ok(out)
}

impl H4TableFile {
    fn to_geometry(&self) -> Result<H4TableGeometry> {
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
) -> Result<[[i64; 3]; 6]> {
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
        _ => bail!(
            "hexapod.{name}: give either {name} = [[x, y, z], ...] (six joints) or \
             {name}_radius and {name}_angles"
        ),
    }
}

impl HexapodFile {
    fn to_geometry(&self) -> Result<HexapodGeometry> {
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

fn positive(v: f64, field: &str) -> Result<f64> {
    if v.is_finite() && v > 0.0 {
        Ok(v)
    } else {
        bail!("{field}: must be a positive number, got {v}")
    }
}

fn to_units(v: f64, rotary: bool, field: &str) -> Result<i64> {
    if !v.is_finite() || v.abs() > 1e9 {
        bail!("{field}: {v} is out of range");
    }
    Ok((v * units_per_user(rotary) as f64).round() as i64)
}

fn axis_index(name: &str, field: &str) -> Result<usize> {
    let mut chars = name.chars();
    match (chars.next().map(|c| c.to_ascii_uppercase()), chars.next()) {
        (Some(c), None) => AXIS_NAMES
            .iter()
            .position(|&a| a == c)
            .ok_or_else(|| anyhow!("{field}: unknown axis {name:?} (expected one of X Y Z A B C)")),
        _ => bail!("{field}: unknown axis {name:?} (expected one of X Y Z A B C)"),
    }
}

impl MachineFile {
    /// Converts to the core form and validates it.
    pub fn to_config(&self) -> Result<MachineConfig> {
        let mut name = heapless::String::new();
        name.push_str(&self.name)
            .map_err(|_| anyhow!("name: longer than 32 bytes"))?;
        let none = Limits {
            max_velocity: 0,
            max_accel: 0,
        };
        let mut axes = [none; AXES];
        for (key, l) in &self.axes {
            let i = axis_index(key, &format!("axes.{key}"))?;
            let rotary = pkmc::config::axis_is_rotary(i);
            axes[i] = Limits {
                max_velocity: to_units(
                    positive(l.max_velocity, &format!("axes.{key}.max_velocity"))?,
                    rotary,
                    &format!("axes.{key}.max_velocity"),
                )?,
                max_accel: to_units(
                    positive(l.max_accel, &format!("axes.{key}.max_accel"))?,
                    rotary,
                    &format!("axes.{key}.max_accel"),
                )?,
            };
        }
        if self.joints.len() > MAX_JOINTS {
            bail!(
                "joints: {} joints, the board drives at most {MAX_JOINTS}",
                self.joints.len()
            );
        }
        let mut joints = heapless::Vec::new();
        let mut servo = ServoConfig::NONE;
        if let Some(c) = &self.contour {
            servo.contour = c.to_config()?;
        }
        let mut axis_of_joint = [0u8; MAX_JOINTS];
        for (j, jf) in self.joints.iter().enumerate() {
            let f = |s: &str| format!("joints[{j}] ({}).{s}", jf.name);
            let per_unit = positive(jf.steps_per_unit, &f("steps_per_unit"))?;
            // Scale as a ratio: steps per 10^6 user units, to 1e-6 step per user unit.
            let steps = (per_unit * 1e6).round();
            if steps > u32::MAX as f64 {
                bail!("{}: {per_unit} is too large", f("steps_per_unit"));
            }
            let scale = Scale::new(steps as u32, (1_000_000 * units_per_user(jf.rotary)) as u64);
            let drive = match jf.drive.as_str() {
                "stepper" => Drive::Stepper {
                    channel: jf.channel,
                    timing: jf
                        .timing
                        .as_ref()
                        .map_or(StepTiming::PACSCI_6410, |t| StepTiming {
                            min_pulse_ns: t.min_pulse_ns,
                            max_rate_hz: t.max_rate_hz,
                            dir_setup_ns: t.dir_setup_ns,
                            dir_hold_ns: t.dir_hold_ns,
                        }),
                    invert_dir: jf.invert_dir,
                },
                "servo" => {
                    if jf.servo.is_none() {
                        bail!(
                            "{}: a servo joint needs its loop's gains: servo = {{ kp = .., \
                             max_output = .., dac_per_unit = .., ferror = .., min_ferror = .. }}",
                            f("servo")
                        );
                    }
                    Drive::Servo {
                        channel: jf.channel,
                    }
                }
                other => bail!(
                    "{}: unknown drive {other:?} (expected \"stepper\" or \"servo\")",
                    f("drive")
                ),
            };
            if let Some(a) = &jf.axis {
                if self.kinematics != "cartesian" {
                    bail!("{}: only Cartesian joints follow a pose axis", f("axis"));
                }
                axis_of_joint[j] = axis_index(a, &f("axis"))? as u8;
            } else if self.kinematics == "cartesian" {
                bail!("{}: a Cartesian joint needs the axis it follows", f("axis"));
            }
            if let (Drive::Servo { channel, .. }, Some(sf)) = (drive, &jf.servo) {
                let counts = per_unit; // counts per mm or degree
                let gains = ServoGains {
                    kp: sf.kp,
                    ki: sf.ki,
                    kd: sf.kd,
                    kvff: sf.kvff,
                    kaff: sf.kaff,
                    max_output: sf.max_output,
                    max_integral: sf.max_integral.unwrap_or(sf.max_output),
                    dac_per_unit: sf.dac_per_unit,
                    dac_offset: sf.dac_offset,
                    ferror: (sf.ferror * counts).round().clamp(0.0, u32::MAX as f64) as u32,
                    min_ferror: (sf.min_ferror * counts).round().clamp(0.0, u32::MAX as f64) as u32,
                };
                if let Some(g) = servo.gains.get_mut(channel as usize) {
                    *g = gains;
                }
            }
            let _ = joints.push(JointConfig {
                drive,
                scale,
                rotary: jf.rotary,
                min: to_units(jf.min, jf.rotary, &f("min"))?,
                max: to_units(jf.max, jf.rotary, &f("max"))?,
                limits: Limits {
                    max_velocity: to_units(
                        positive(jf.max_velocity, &f("max_velocity"))?,
                        jf.rotary,
                        &f("max_velocity"),
                    )?,
                    max_accel: to_units(
                        positive(jf.max_accel, &f("max_accel"))?,
                        jf.rotary,
                        &f("max_accel"),
                    )?,
                },
                homing: match &jf.homing {
                    None => Homing::NONE,
                    Some(h) => Homing {
                        switch_at: to_units(h.switch_at, jf.rotary, &f("homing.switch_at"))?,
                        search_velocity: to_units(
                            h.search_velocity,
                            jf.rotary,
                            &f("homing.search_velocity"),
                        )?,
                        latch_velocity: to_units(
                            h.latch_velocity,
                            jf.rotary,
                            &f("homing.latch_velocity"),
                        )?,
                        use_index: h.use_index,
                    },
                },
            });
        }
        if self.h4_table.is_some() && self.kinematics != "h4-table" {
            bail!("h4_table: only for kinematics = \"h4-table\"");
        }
        if self.hexapod.is_some() && self.kinematics != "hexapod" {
            bail!("hexapod: only for kinematics = \"hexapod\"");
        }
        let kinematics = match self.kinematics.as_str() {
            "cartesian" => KinematicsConfig::Cartesian { axis_of_joint },
            "h4-table" => KinematicsConfig::H4Table(
                self.h4_table
                    .as_ref()
                    .ok_or_else(|| {
                        anyhow!("h4_table: kinematics = \"h4-table\" needs an [h4_table] section")
                    })?
                    .to_geometry()?,
            ),
            "hexapod" => KinematicsConfig::Hexapod(
                self.hexapod
                    .as_ref()
                    .ok_or_else(|| {
                        anyhow!("hexapod: kinematics = \"hexapod\" needs a [hexapod] section")
                    })?
                    .to_geometry()?,
            ),
            other => bail!(
                "kinematics: unknown kinematics {other:?} (this build knows \"cartesian\", \
                 \"h4-table\" and \"hexapod\")"
            ),
        };
        let mut home = [0i64; AXES];
        for (i, h) in self.home.iter().enumerate() {
            home[i] = to_units(*h, pkmc::config::axis_is_rotary(i), &format!("home[{i}]"))?;
        }
        let motion = match &self.motion {
            Some(m) => m.to_config(
                &self.axes.values().cloned().collect::<Vec<_>>(),
                &self.joints,
            )?,
            None => pkmc::config::MotionConfig::TRAPEZOID,
        };
        let config = MachineConfig {
            name,
            kinematics,
            joints,
            axes,
            home,
            servo,
            motion,
        };
        config
            .validate()
            .map_err(|e| anyhow!("{}", describe(&e, self)))?;
        pkmc::controller::Controller::new(config.clone())
            .map_err(|e| anyhow!("{}", describe(&e, self)))?;
        // A mechanism that is singular where it starts cannot be controlled from there
        // (a hexapod whose base joints all sit at one angle was accepted, margin 0).
        let kin = pkmc::kinematics::MachineKinematics::new(&config);
        let margin = crate::analysis::preflight::margin(&config.home, &config, &kin).unwrap_or(0.0);
        if margin < MIN_HOME_MARGIN {
            let section = match self.kinematics.as_str() {
                "hexapod" => "hexapod",
                "h4-table" => "h4_table",
                _ => "kinematics",
            };
            bail!(
                "{section}: the mechanism is singular at the home pose (singularity margin \
                 {margin:.4}, at least {MIN_HOME_MARGIN} needed): check its geometry"
            );
        }
        Ok(config)
    }
}

/// Smallest singularity margin ([`crate::analysis::preflight::margin`]) accepted at the home
/// pose.
pub const MIN_HOME_MARGIN: f64 = 0.01;

/// Names the field a core configuration error points at.
pub fn describe(e: &pkmc::config::ConfigError, m: &MachineFile) -> String {
    use pkmc::config::ConfigError as E;
    let jn = |j: &u8| {
        let name = m.joints.get(*j as usize).map_or("?", |jf| jf.name.as_str());
        format!("joints[{j}] ({name})")
    };
    match e {
        E::NoJoints => "joints: the machine has no joints".into(),
        E::BoardChannel { joint } => format!(
            "{}.channel: the board's timer on this channel cannot emit the steps its max_velocity needs (channels 3–6 take at most 256 steps per ms)",
            jn(joint)
        ),
        E::Smoothing => "motion: the smoothing window must be a power of two up to 32 ticks".into(),
        E::JointLimits { joint } => {
            format!("{}: speed and acceleration must be positive", jn(joint))
        }
        E::JointTravel { joint } => format!("{}.min must be below max", jn(joint)),
        E::JointScale { joint } => format!("{}.steps_per_unit rounds to zero", jn(joint)),
        E::JointChannel { joint } => {
            format!("{}.channel: beyond the board or used twice", jn(joint))
        }
        E::StepRate { joint } => format!(
            "{}.max_velocity: needs more steps per second than the drive timing allows",
            jn(joint)
        ),
        E::JointAxis { joint } => {
            format!("{}.axis: names no axis with limits in [axes]", jn(joint))
        }
        E::AxisLimits { axis } => format!("axes.{}: bad limits", AXIS_NAMES[*axis as usize]),
        E::HomeOutsideTravel { joint } => format!("home: outside the travel of {}", jn(joint)),
        E::ServoGains { channel } => format!(
            "servo channel {channel}: gains must be finite, limits non-negative, \
             dac_per_unit non-zero and min_ferror <= ferror"
        ),
        E::Homing { joint } => format!(
            "{}.homing: switch_at must lie in the travel, speeds within max_velocity, \
             latch_velocity > 0, and use_index only on a servo joint",
            jn(joint)
        ),
        E::Contour => "contour: gains must be finite, clamps non-negative, and coupling needs a \
             Cartesian machine"
            .into(),
        E::Geometry { field } => {
            let (name, what) = match field {
                GeometryField::Joints => (
                    "joints",
                    "the h4-table needs q1..q4 linear and q5 rotary (5 joints), the hexapod \
                     six linear legs",
                ),
                GeometryField::Rails => ("h4_table.rails", "out of range (±1073 mm)"),
                GeometryField::Forearm => ("h4_table.forearm", "out of range (0..1073 mm)"),
                GeometryField::BarHalf => ("h4_table.bar_half", "out of range (0..1073 mm)"),
                GeometryField::Sides => ("h4_table.sides", "each must be -1 or +1"),
                GeometryField::Attach => ("h4_table.attach", "out of range (±1073 mm)"),
                GeometryField::ToolLength => ("h4_table.tool_length", "out of range (±1073 mm)"),
                GeometryField::TablePivot => ("h4_table.table_pivot", "out of range (±1073 mm)"),
                GeometryField::MinElevation => (
                    "h4_table.min_elevation",
                    "must lie between 0 and 90 degrees",
                ),
                GeometryField::Base => ("hexapod.base", "out of range (±537 mm)"),
                GeometryField::Platform => (
                    "hexapod.platform",
                    "a joint farther than 268 mm from the platform origin, or all at it",
                ),
                _ => ("kinematics", "bad geometry"),
            };
            format!("{name}: {what}")
        }
        _ => format!("{e:?}"),
    }
}

/// Reads and converts a machine file.
pub fn load(path: &Path) -> Result<MachineConfig> {
    let text = crate::input::read_text(path, crate::input::MAX_MACHINE_FILE_BYTES)
        .map_err(|m| anyhow!(m))?;
    parse(&text, &path.display().to_string())
}

/// The simulator's plant of each joint in the machine file at `path` (`None` for a
/// joint without one).
pub fn load_plants(path: &Path) -> Result<Vec<Option<crate::sim::plant::PlantFile>>> {
    let text = crate::input::read_text(path, crate::input::MAX_MACHINE_FILE_BYTES)
        .map_err(|m| anyhow!(m))?;
    let file: MachineFile =
        toml::from_str(&text).map_err(|e| anyhow!("{}: {}", path.display(), e.message()))?;
    Ok(file.joints.into_iter().map(|j| j.plant).collect())
}

/// Parses machine-file text; `origin` names it in errors.
pub fn parse(text: &str, origin: &str) -> Result<MachineConfig> {
    let file: MachineFile = toml::from_str(text).map_err(|e| {
        let (line, col) = e.span().map(|s| line_col(text, s.start)).unwrap_or((0, 0));
        anyhow!("{origin}:{line}:{col}: {}", e.message())
    })?;
    file.to_config().map_err(|e| {
        let message = e.to_string();
        match line_of_field(text, &message) {
            Some(line) => anyhow!("{origin}:{line}: {message}"),
            None => anyhow!("{origin}: {message}"),
        }
    })
}

/// The line of the field that an error message names first (`joints[2] (Z).max_velocity:
/// …`, `axes.X.max_accel: …`, `hexapod.base_angles: …`, `home[3]: …`), 1-based: the
/// line of its key within its table, or the table's header when the key is not
/// written (a default, or a whole section that is wrong).
fn line_of_field(text: &str, message: &str) -> Option<usize> {
    let path = message.split(": ").next()?;
    let strip = |k: &str| k.split('[').next().unwrap_or(k).trim().to_string();
    // (table, index among tables of that name, key)
    let (table, index, key): (Option<String>, usize, Option<String>) =
        if let Some(rest) = path.strip_prefix("joints[") {
            let j: usize = rest.split(']').next()?.parse().ok()?;
            let key = rest.split(").").nth(1).or_else(|| rest.split("].").nth(1));
            (Some("joints".into()), j, key.map(strip))
        } else {
            let parts: Vec<&str> = path.split('.').collect();
            match parts.as_slice() {
                ["axes", axis, key, ..] => (Some(format!("axes.{axis}")), 0, Some(strip(key))),
                ["axes", axis] => (Some(format!("axes.{axis}")), 0, None),
                [t @ ("h4_table" | "hexapod" | "motion" | "contour"), key, ..] => {
                    (Some((*t).into()), 0, Some(strip(key)))
                }
                [t @ ("h4_table" | "hexapod" | "motion" | "contour" | "joints")] => {
                    (Some((*t).into()), 0, None)
                }
                [key] if !key.contains(' ') => (None, 0, Some(strip(key))),
                _ => return None,
            }
        };
    let mut current: Option<String> = None;
    let mut seen = std::collections::HashMap::<String, usize>::new();
    let mut header_line = None;
    for (n, raw) in text.lines().enumerate() {
        let line = raw.split('#').next().unwrap_or("").trim();
        if line.starts_with('[') {
            let name = line
                .trim_matches(|c| c == '[' || c == ']')
                .trim()
                .to_string();
            let k = seen.entry(name.clone()).or_insert(0);
            let this = *k;
            *k += 1;
            let here = table.as_deref() == Some(name.as_str()) && this == index;
            if here {
                header_line = Some(n + 1);
            } else if header_line.is_some() && current.is_some() {
                // Past the table without finding the key.
                break;
            }
            current = here.then_some(name);
            continue;
        }
        let in_table = match &table {
            None => current.is_none() && seen.is_empty(),
            Some(_) => current.is_some(),
        };
        if let (true, Some(key)) = (in_table, &key) {
            let k = line.split('=').next().unwrap_or("").trim();
            if line.contains('=') && k == key {
                return Some(n + 1);
            }
        }
    }
    header_line
}

fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let before = &text[..offset.min(text.len())];
    let line = before.matches('\n').count() + 1;
    let col = before
        .rfind('\n')
        .map_or(before.len(), |p| before.len() - p - 1)
        + 1;
    (line, col)
}

/// The built-in default machine file (Cartesian X Y Z steppers).
pub const DEFAULT_MACHINE: &str = include_str!("../../../examples/machines/cartesian-xyz.toml");

/// The H-4 with rolling table machine file.
pub const H4_TABLE_MACHINE: &str = include_str!("../../../examples/machines/h4-table.toml");

/// The hexapod machine file.
pub const HEXAPOD_MACHINE: &str = include_str!("../../../examples/machines/hexapod.toml");

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_bundled_machine_equals_the_core_default() {
        let m = parse(DEFAULT_MACHINE, "cartesian-xyz.toml").unwrap();
        assert_eq!(m, MachineConfig::cartesian_xyz());
    }

    #[test]
    fn the_bundled_h4_and_hexapod_equal_the_core_machines() {
        let m = parse(H4_TABLE_MACHINE, "h4-table.toml").unwrap();
        assert_eq!(m, MachineConfig::h4_table());
        let m = parse(HEXAPOD_MACHINE, "hexapod.toml").unwrap();
        assert_eq!(m, MachineConfig::hexapod());
    }

    #[test]
    fn hexapod_joints_as_coordinates_equal_radius_and_angles() {
        let text = HEXAPOD_MACHINE.replace(
            "base_radius = 300\nbase_angles = [348, 12, 108, 132, 228, 252]",
            "base = [[293.44428, -62.373507, 0], [293.44428, 62.373507, 0], \
             [-92.705098, 285.316955, 0], [-200.739182, 222.943448, 0], \
             [-200.739182, -222.943448, 0], [-92.705098, -285.316955, 0]]",
        );
        assert_ne!(text, HEXAPOD_MACHINE);
        assert_eq!(parse(&text, "m.toml").unwrap(), MachineConfig::hexapod());
    }

    #[test]
    fn bad_geometry_names_its_field() {
        let text = H4_TABLE_MACHINE.replace("min_elevation = 25", "min_elevation = 95");
        let e = parse(&text, "m.toml").unwrap_err().to_string();
        assert!(e.contains("h4_table.min_elevation"), "{e}");
        let text = H4_TABLE_MACHINE.replace("forearm = 550", "forearm = -550");
        let e = parse(&text, "m.toml").unwrap_err().to_string();
        assert!(e.contains("h4_table.forearm"), "{e}");
        let text = HEXAPOD_MACHINE.replace("platform_radius = 150\n", "");
        let e = parse(&text, "m.toml").unwrap_err().to_string();
        assert!(e.contains("hexapod.platform"), "{e}");
        let text = H4_TABLE_MACHINE.replace("rotary = true", "rotary = false");
        let e = parse(&text, "m.toml").unwrap_err().to_string();
        assert!(e.contains("joints:"), "{e}");
    }

    #[test]
    fn a_misspelt_field_is_refused_with_its_location() {
        let text = DEFAULT_MACHINE.replace("max_accel = 1000", "max_acel = 1000");
        let e = parse(&text, "m.toml").unwrap_err().to_string();
        assert!(e.starts_with("m.toml:"), "{e}");
        assert!(e.contains("max_acel"), "{e}");
    }

    #[test]
    fn a_zero_scale_names_its_joint_field() {
        let text = DEFAULT_MACHINE.replacen("steps_per_unit = 400", "steps_per_unit = 0", 1);
        let e = parse(&text, "m.toml").unwrap_err().to_string();
        assert!(e.contains("joints[0] (X).steps_per_unit"), "{e}");
    }

    #[test]
    fn a_semantic_error_names_the_line_of_its_field() {
        let text = DEFAULT_MACHINE.replacen("steps_per_unit = 400", "steps_per_unit = 0", 1);
        let line = 1 + text
            .lines()
            .position(|l| l.starts_with("steps_per_unit = 0"))
            .unwrap();
        let e = parse(&text, "m.toml").unwrap_err().to_string();
        assert!(
            e.starts_with(&format!("m.toml:{line}: joints[0] (X).steps_per_unit")),
            "{e}"
        );
    }

    #[test]
    fn an_out_of_range_limit_names_its_field_and_line() {
        let text =
            DEFAULT_MACHINE.replacen("max_velocity = 100   # mm/s", "max_velocity = 1e30", 1);
        let line = 1 + text
            .lines()
            .position(|l| l.starts_with("max_velocity = 1e30"))
            .unwrap();
        let e = parse(&text, "m.toml").unwrap_err().to_string();
        assert!(
            e.starts_with(&format!("m.toml:{line}: axes.X.max_velocity: ")),
            "{e}"
        );
    }

    #[test]
    fn arrays_with_more_or_fewer_elements_than_their_field_takes_are_refused_where_written() {
        let seven = DEFAULT_MACHINE.replacen(
            "home = [0, 0, 0, 0, 0, 0]",
            "home = [0, 0, 0, 0, 0, 0, 0]",
            1,
        );
        let e = parse(&seven, "m.toml").unwrap_err().to_string();
        assert!(e.contains(":8: expected 6 values, got 7"), "{e}");
        let five_rails = H4_TABLE_MACHINE.replacen(
            "rails = [[-250, 250], [-250, -250], [250, -250], [250, 250]]",
            "rails = [[-250, 250], [-250, -250], [250, -250], [250, 250], [0, 0]]",
            1,
        );
        let e = parse(&five_rails, "h4.toml").unwrap_err().to_string();
        assert!(e.contains("expected 4 values, got 5"), "{e}");
        let seven_angles = HEXAPOD_MACHINE.replacen(
            "base_angles = [348, 12, 108, 132, 228, 252]",
            "base_angles = [348, 12, 108, 132, 228, 252, 300]",
            1,
        );
        let e = parse(&seven_angles, "hx.toml").unwrap_err().to_string();
        assert!(e.contains("expected 6 values, got 7"), "{e}");
        let short_point =
            H4_TABLE_MACHINE.replacen("[-250, 250], [-250, -250]", "[-250], [-250, -250]", 1);
        let e = parse(&short_point, "h4.toml").unwrap_err().to_string();
        assert!(e.contains("expected 2 values, got 1"), "{e}");
    }

    #[test]
    fn a_hexapod_singular_at_its_home_is_refused() {
        let flat = HEXAPOD_MACHINE.replacen(
            "base_angles = [348, 12, 108, 132, 228, 252]",
            "base_angles = [0, 0, 0, 0, 0, 0]",
            1,
        );
        let e = parse(&flat, "hx.toml").unwrap_err().to_string();
        assert!(
            e.contains("hexapod: the mechanism is singular at the home pose"),
            "{e}"
        );
    }

    #[test]
    fn a_jerk_limit_becomes_a_smoothing_window_and_a_too_low_one_is_refused() {
        let text =
            format!("{DEFAULT_MACHINE}\n[motion]\nprofile = \"jerk-limited\"\njerk = 200000\n");
        let m = parse(&text, "m.toml").unwrap();
        // 3 · 1000 mm/s² / 200 000 mm/s³ = 15 ms: 16 ticks (a power of two).
        assert_eq!(m.motion.smoothing_ticks, 16);
        let text =
            format!("{DEFAULT_MACHINE}\n[motion]\nprofile = \"jerk-limited\"\njerk = 1000\n");
        let e = parse(&text, "m.toml").unwrap_err().to_string();
        assert!(e.contains("motion.jerk"), "{e}");
    }
}
