//! Machine files: the human TOML description of a machine (mm, degrees, seconds),
//! checked and converted to the core's integer [`MachineConfig`].
//!
//! Every error names the file and the field (`joints[2].steps_per_unit`); TOML syntax
//! errors carry the file's line and column. Unknown fields are refused, so a misspelt
//! limit is never silently ignored.
//!
//! Rooms: [`sections`] (each table as written, and its conversion), `convert` (file
//! units to axis units), `exact` (fixed-size arrays read exactly), `locate` (the line
//! of a field, the field at a line); this module reads a file and converts the whole.

mod convert;
mod exact;
mod host;
mod locate;
pub mod lqg;
pub mod sections;

pub use host::{load_host_timeout, DEFAULT_HOST_TIMEOUT};
pub use sections::{
    ContourFile, ContourMode, DriveKind, H4TableFile, HexapodFile, HexapodXyFile, HomingFile,
    JointFile, KinematicsKind, LimitsFile, MotionFile, Profile, ServoFile, TimingFile, ToolFile,
};

use convert::{axis_index, to_units};
use locate::{field_at, line_col, line_of_field};
use pkmc::config::{KinematicsConfig, Limits, MachineConfig, ServoConfig, AXES, MAX_JOINTS};
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::Path;

/// A value refused, in words that start with the field's name
/// (`joints[2] (Z).max_velocity: must be a positive number, got 0`).
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct FieldError(pub String);

/// Why a machine file was refused; every variant names the file, and the line (and
/// column) where it can.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum MachineFileError {
    /// The file could not be read (the message names it).
    #[error("{0}")]
    Read(String),
    /// Not TOML, a misspelt field, a value of the wrong type or kind.
    #[error("{origin}:{line}:{col}: {message}")]
    Syntax {
        /// The file.
        origin: String,
        /// 1-based line.
        line: usize,
        /// 1-based column.
        col: usize,
        /// What is wrong.
        message: String,
    },
    /// A value out of range or inconsistent with the rest, at the line of its field
    /// when that is written.
    #[error("{origin}{}: {error}", line.map(|l| format!(":{l}")).unwrap_or_default())]
    Invalid {
        /// The file.
        origin: String,
        /// 1-based line of the field.
        line: Option<usize>,
        /// The field and what is wrong.
        error: FieldError,
    },
}

/// `FieldError` from a format string.
macro_rules! refused {
    ($($arg:tt)*) => {
        $crate::machine_file::FieldError(format!($($arg)*))
    };
}
pub(crate) use refused;

/// A machine file.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MachineFile {
    /// Machine name.
    pub name: String,
    /// `"cartesian"`, `"h4-table"`, `"hexapod"` or `"hexapod-xy"`.
    pub kinematics: KinematicsKind,
    /// Home pose X Y Z (mm) A B C (degrees).
    #[serde(default, deserialize_with = "exact::de")]
    pub home: [f64; AXES],
    /// Geometry for `kinematics = "h4-table"`.
    pub h4_table: Option<H4TableFile>,
    /// Geometry for `kinematics = "hexapod"` and the legs of `"hexapod-xy"`.
    pub hexapod: Option<HexapodFile>,
    /// The workpiece and tool of `kinematics = "hexapod-xy"`.
    pub hexapod_xy: Option<HexapodXyFile>,
    /// Limits per used axis, keyed by axis letter.
    pub axes: BTreeMap<String, LimitsFile>,
    /// Joints q1..qN.
    pub joints: Vec<JointFile>,
    /// Contour control of the servo axes; uncoupled when absent.
    pub contour: Option<ContourFile>,
    /// Speed-profile shape; trapezoidal when absent.
    pub motion: Option<MotionFile>,
    /// The tool table (`[[tools]]`); empty when absent.
    #[serde(default)]
    pub tools: Vec<ToolFile>,
    /// Hydraulic supply pressure, MPa (the force limit of a joint with a
    /// `cylinder_area`).
    pub supply_pressure: Option<f64>,
    /// Host silence after which a streamed job is held for take-over, s (default 30;
    /// see `host` and docs/safety.md).
    pub host_timeout_s: Option<f64>,
}

impl MachineFile {
    /// Converts to the core form and validates it.
    pub fn to_config(&self) -> Result<MachineConfig, FieldError> {
        let mut name = heapless::String::new();
        name.push_str(&self.name)
            .map_err(|_| refused!("name: longer than 32 bytes"))?;
        let axes = self.axis_limits()?;
        if self.joints.len() > MAX_JOINTS {
            return Err(refused!(
                "joints: {} joints, the board drives at most {MAX_JOINTS}",
                self.joints.len()
            ));
        }
        let mut servo = ServoConfig::NONE;
        if let Some(c) = &self.contour {
            servo.contour = c.to_config();
        }
        let mut joints = heapless::Vec::new();
        for (j, jf) in self.joints.iter().enumerate() {
            let _ = joints.push(jf.to_config(j, &mut servo.gains)?);
        }
        let kinematics = self.kinematics_config()?;
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
        let mut config = MachineConfig {
            name,
            kinematics,
            joints,
            axes,
            home,
            servo,
            motion,
        };
        self.apply_lqg(&mut config, false)?;
        self.check(&config)?;
        Ok(config)
    }

    /// `[axes]`: the limits of each axis named, none for the others.
    fn axis_limits(&self) -> Result<[Limits; AXES], FieldError> {
        let none = Limits {
            max_velocity: 0,
            max_accel: 0,
        };
        let mut axes = [none; AXES];
        for (key, l) in &self.axes {
            let i = axis_index(key, &format!("axes.{key}"))?;
            axes[i] = l.to_limits(pkmc::config::axis_is_rotary(i), &format!("axes.{key}"))?;
        }
        Ok(axes)
    }

    /// The kinematics and its geometry section; a Cartesian machine's joints each
    /// name the axis they follow, no other machine's do.
    fn kinematics_config(&self) -> Result<KinematicsConfig, FieldError> {
        let mut axis_of_joint = [0u8; MAX_JOINTS];
        let cartesian = self.kinematics == KinematicsKind::Cartesian;
        for (j, jf) in self.joints.iter().enumerate() {
            let field = format!("joints[{j}] ({}).axis", jf.name);
            match &jf.axis {
                Some(_) if !cartesian => {
                    return Err(refused!(
                        "{field}: only Cartesian joints follow a pose axis"
                    ))
                }
                Some(a) => axis_of_joint[j] = axis_index(a, &field)? as u8,
                None if cartesian => {
                    return Err(refused!(
                        "{field}: a Cartesian joint needs the axis it follows"
                    ))
                }
                None => {}
            }
        }
        if self.h4_table.is_some() && self.kinematics != KinematicsKind::H4Table {
            return Err(refused!("h4_table: only for kinematics = \"h4-table\""));
        }
        let legs = matches!(
            self.kinematics,
            KinematicsKind::Hexapod | KinematicsKind::HexapodXy
        );
        if self.hexapod.is_some() && !legs {
            return Err(refused!(
                "hexapod: only for kinematics = \"hexapod\" or \"hexapod-xy\""
            ));
        }
        if self.hexapod_xy.is_some() && self.kinematics != KinematicsKind::HexapodXy {
            return Err(refused!("hexapod_xy: only for kinematics = \"hexapod-xy\""));
        }
        let hexapod = || {
            self.hexapod
                .as_ref()
                .ok_or_else(|| {
                    refused!(
                        "hexapod: kinematics = \"{}\" needs a [hexapod] section",
                        if self.kinematics == KinematicsKind::Hexapod {
                            "hexapod"
                        } else {
                            "hexapod-xy"
                        }
                    )
                })?
                .to_geometry()
        };
        Ok(match self.kinematics {
            KinematicsKind::Cartesian => KinematicsConfig::Cartesian { axis_of_joint },
            KinematicsKind::H4Table => KinematicsConfig::H4Table(
                self.h4_table
                    .as_ref()
                    .ok_or_else(|| {
                        refused!("h4_table: kinematics = \"h4-table\" needs an [h4_table] section")
                    })?
                    .to_geometry()?,
            ),
            KinematicsKind::Hexapod => KinematicsConfig::Hexapod(hexapod()?),
            KinematicsKind::HexapodXy => KinematicsConfig::HexapodXy(
                self.hexapod_xy
                    .as_ref()
                    .ok_or_else(|| {
                        refused!(
                            "hexapod_xy: kinematics = \"hexapod-xy\" needs a [hexapod_xy] section"
                        )
                    })?
                    .to_geometry(hexapod()?)?,
            ),
        })
    }

    /// What the core checks (named by field here), what the controller refuses, and
    /// a mechanism singular at its home pose (which cannot be controlled from there: a
    /// hexapod whose base joints all sit at one angle was accepted, margin 0).
    fn check(&self, config: &MachineConfig) -> Result<(), FieldError> {
        config
            .validate()
            .map_err(|e| FieldError(describe(&e, self)))?;
        pkmc::controller::Controller::new(config.clone())
            .map_err(|e| FieldError(describe(&e, self)))?;
        let kin = pkmc::kinematics::MachineKinematics::new(config);
        let margin = crate::analysis::preflight::margin(&config.home, config, &kin).unwrap_or(0.0);
        if margin < MIN_HOME_MARGIN {
            return Err(refused!(
                "{}: the mechanism is singular at the home pose (singularity margin \
                 {margin:.4}, at least {MIN_HOME_MARGIN} needed): check its geometry",
                self.kinematics.section()
            ));
        }
        Ok(())
    }
}

impl MachineFile {
    /// Each joint's force limit, N (N·m for a rotary joint): `force_limit`, or
    /// `cylinder_area` (mm²) × `supply_pressure` (MPa); each refusal names its field.
    pub fn force_limits(&self) -> Result<Vec<Option<f64>>, FieldError> {
        let positive = |v: f64, field: String| {
            if v.is_finite() && v > 0.0 && v <= 1e12 {
                Ok(v)
            } else {
                Err(refused!("{field}: must be above 0, got {v}"))
            }
        };
        self.joints
            .iter()
            .enumerate()
            .map(|(i, j)| {
                let f = |s: &str| format!("joints[{i}].{s}");
                match (j.force_limit, j.cylinder_area, self.supply_pressure) {
                    (Some(_), Some(_), _) => Err(refused!(
                        "{}: give force_limit or cylinder_area, not both",
                        f("cylinder_area")
                    )),
                    (Some(l), None, _) => positive(l, f("force_limit")).map(Some),
                    (None, Some(_), None) => Err(refused!(
                        "{}: a cylinder area needs the machine's supply_pressure (MPa)",
                        f("cylinder_area")
                    )),
                    (None, Some(a), Some(p)) => {
                        let a = positive(a, f("cylinder_area"))?;
                        let p = positive(p, "supply_pressure".into())?;
                        Ok(Some(a * p))
                    }
                    (None, None, _) => Ok(None),
                }
            })
            .collect()
    }

    /// The `[[tools]]` table for the G-code front end; each refusal names its entry
    /// (`tools[1].diameter: ...`).
    pub fn tool_table(&self) -> Result<crate::gcode::ToolTable, FieldError> {
        let mut table = crate::gcode::ToolTable::new();
        for (i, t) in self.tools.iter().enumerate() {
            let f = |s: &str| format!("tools[{i}].{s}");
            if table.get(t.number).is_some() {
                return Err(refused!(
                    "{}: tool {} is listed twice",
                    f("number"),
                    t.number
                ));
            }
            let diameter = to_units(t.diameter, false, &f("diameter"))?;
            if diameter < 0 {
                return Err(refused!(
                    "{}: must not be negative, got {}",
                    f("diameter"),
                    t.diameter
                ));
            }
            let tool = crate::gcode::Tool {
                offset: [
                    to_units(t.x, false, &f("x"))?,
                    to_units(t.y, false, &f("y"))?,
                    to_units(t.length, false, &f("length"))?,
                    to_units(t.a, true, &f("a"))?,
                    to_units(t.b, true, &f("b"))?,
                    to_units(t.c, true, &f("c"))?,
                ],
                diameter_nm: diameter,
            };
            table.insert(t.number, tool);
        }
        Ok(table)
    }
}

/// Smallest singularity margin ([`crate::analysis::preflight::margin`]) accepted at the home
/// pose.
pub const MIN_HOME_MARGIN: f64 = 0.01;

/// Names the field a core configuration error points at, its joints as the file
/// names them (the core's wording, `pkmc::wording`).
pub fn describe(e: &pkmc::config::ConfigError, m: &MachineFile) -> String {
    let names: Vec<&str> = m.joints.iter().map(|j| j.name.as_str()).collect();
    let text = e.with_joint_names(&names).to_string();
    text
}

/// Reads and converts a machine file.
pub fn load(path: &Path) -> Result<MachineConfig, MachineFileError> {
    parse(&read(path)?, &path.display().to_string())
}

fn read(path: &Path) -> Result<String, MachineFileError> {
    crate::input::read_text(path, crate::input::MAX_MACHINE_FILE_BYTES)
        .map_err(MachineFileError::Read)
}

/// Reads the sections of machine-file text; `origin` names it in errors.
pub fn read_file(text: &str, origin: &str) -> Result<MachineFile, MachineFileError> {
    toml::from_str(text).map_err(|e| {
        let at = e.span().map_or(0, |s| s.start);
        let (line, col) = e.span().map_or((0, 0), |s| line_col(text, s.start));
        let mut message = e.message().to_string();
        if message.starts_with("unknown variant") {
            // A word that names no kind (a drive, a kinematics): say whose.
            if let Some(field) = field_at(text, at) {
                message = format!("{field}: {message}");
            }
        }
        MachineFileError::Syntax {
            origin: origin.to_string(),
            line,
            col,
            message,
        }
    })
}

/// The force limit of each joint of the machine file at `path` (`None` for a joint
/// without one).
pub fn load_force_limits(path: &Path) -> Result<Vec<Option<f64>>, MachineFileError> {
    let text = read(path)?;
    let origin = path.display().to_string();
    let file = read_file(&text, &origin)?;
    file.force_limits()
        .map_err(|error| MachineFileError::Invalid {
            line: line_of_field(&text, &error.0),
            origin,
            error,
        })
}

/// The joints' names in the machine file at `path`, in order.
pub fn load_joint_names(path: &Path) -> Result<Vec<String>, MachineFileError> {
    let text = read(path)?;
    let file = read_file(&text, &path.display().to_string())?;
    Ok(file.joints.iter().map(|j| j.name.clone()).collect())
}

/// The tool table of the machine file at `path` (`[[tools]]`; empty when it has none).
pub fn load_tools(path: &Path) -> Result<crate::gcode::ToolTable, MachineFileError> {
    let text = read(path)?;
    let origin = path.display().to_string();
    let file = read_file(&text, &origin)?;
    file.tool_table()
        .map_err(|error| MachineFileError::Invalid {
            line: line_of_field(&text, &error.0),
            origin,
            error,
        })
}

/// The simulator's plant of each joint in the machine file at `path` (`None` for a
/// joint without one).
pub fn load_plants(
    path: &Path,
) -> Result<Vec<Option<crate::control::plant::PlantFile>>, MachineFileError> {
    let file = read_file(&read(path)?, &path.display().to_string())?;
    Ok(file.joints.into_iter().map(|j| j.plant).collect())
}

/// Parses machine-file text; `origin` names it in errors.
pub fn parse(text: &str, origin: &str) -> Result<MachineConfig, MachineFileError> {
    let file = read_file(text, origin)?;
    file.to_config().map_err(|error| MachineFileError::Invalid {
        origin: origin.to_string(),
        line: line_of_field(text, &error.0),
        error,
    })
}

/// The built-in default machine file (Cartesian X Y Z steppers).
pub const DEFAULT_MACHINE: &str = include_str!("../../../examples/machines/cartesian-xyz.toml");

/// The H-4 with rolling table machine file.
pub const H4_TABLE_MACHINE: &str = include_str!("../../../examples/machines/h4-table.toml");

/// The hexapod machine file.
pub const HEXAPOD_MACHINE: &str = include_str!("../../../examples/machines/hexapod.toml");

/// Report B's machine file (`examples/machines/hexapod-xy.toml`).
pub const HEXAPOD_XY_MACHINE: &str = include_str!("../../../examples/machines/hexapod-xy.toml");

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
        let m = parse(HEXAPOD_XY_MACHINE, "hexapod-xy.toml").unwrap();
        assert_eq!(m, MachineConfig::hexapod_xy());
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
    fn a_scale_is_reduced_before_it_must_fit_and_refused_when_it_cannot() {
        // 100 000 counts/mm is 10^11 per 10^12 nm, 1 per 10 nm reduced: it loads.
        let scale = |v: &str| {
            let text = HEXAPOD_XY_MACHINE.replacen("steps_per_unit = 100000", v, 1);
            parse(&text, "m.toml").map(|m| m.joints[0].scale)
        };
        let s = scale("steps_per_unit = 100000").unwrap();
        assert_eq!((s.steps, s.per_units), (1, 10));
        // 4294.967297 per mm has no common factor with 10^12: 4 294 967 297 steps, one
        // more than the core's u32 holds; 2^32 per nm neither fits.
        for v in [
            "steps_per_unit = 4294.967297",
            "steps_per_unit = 4294967296000000",
        ] {
            let e = scale(v).unwrap_err().to_string();
            assert!(
                e.contains("joints[0] (leg1).steps_per_unit") && e.contains("too large"),
                "{e}"
            );
        }
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

    #[test]
    fn a_word_naming_no_kind_is_refused_where_written_with_its_field() {
        let text = DEFAULT_MACHINE.replacen("drive = \"stepper\"", "drive = \"steper\"", 1);
        let line = 1 + text.lines().position(|l| l.contains("\"steper\"")).unwrap();
        let e = parse(&text, "m.toml").unwrap_err().to_string();
        assert!(
            e.starts_with(&format!(
                "m.toml:{line}:9: joints[0].drive: unknown variant `steper`"
            )),
            "{e}"
        );
        assert!(e.contains("`stepper`") && e.contains("`servo`"), "{e}");
        let text = H4_TABLE_MACHINE.replacen("kinematics = \"h4-table\"", "kinematics = \"h4\"", 1);
        let e = parse(&text, "m.toml").unwrap_err().to_string();
        assert!(e.contains(": kinematics: unknown variant `h4`"), "{e}");
    }

    #[test]
    fn a_machine_files_tool_table_is_read_and_its_mistakes_name_their_entry() {
        let text = format!(
            "{DEFAULT_MACHINE}\n[[tools]]\nnumber = 1\nlength = 12.5\ndiameter = 6\n\n\
             [[tools]]\nnumber = 2\nlength = -3.25\n"
        );
        let file = read_file(&text, "m.toml").unwrap();
        let t = file.tool_table().unwrap();
        assert_eq!(t.get(1).unwrap().offset, [0, 0, 12_500_000, 0, 0, 0]);
        assert_eq!(t.get(1).unwrap().diameter_nm, 6_000_000);
        assert_eq!(t.get(2).unwrap().offset[2], -3_250_000);
        let bad = text.replace("diameter = 6", "diameter = -6");
        let file = read_file(&bad, "m.toml").unwrap();
        let e = file.tool_table().unwrap_err().0;
        assert!(
            e.starts_with("tools[0].diameter: must not be negative"),
            "{e}"
        );
        let line = 1 + bad.lines().position(|l| l == "diameter = -6").unwrap();
        assert_eq!(locate::line_of_field(&bad, &e), Some(line));
        let twice = text.replace("number = 2", "number = 1");
        let e = read_file(&twice, "m.toml")
            .unwrap()
            .tool_table()
            .unwrap_err()
            .0;
        assert!(e.contains("tools[1].number: tool 1 is listed twice"), "{e}");
    }
}
