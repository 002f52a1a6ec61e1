//! File units to the core's integer units, each refusal naming its field: positive
//! numbers, lengths and angles in range, axis letters, point sets, and the kinematics
//! sections' geometry.

use super::sections::{H4TableFile, HexapodFile};
use super::{refused, FieldError};
use pkmc::config::{H4TableGeometry, HexapodGeometry, AXIS_NAMES};
use pkmc::units::units_per_user;

/// `v` when it is a finite number above zero.
pub(super) fn positive(v: f64, field: &str) -> Result<f64, FieldError> {
    if v.is_finite() && v > 0.0 {
        Ok(v)
    } else {
        Err(refused!("{field}: must be a positive number, got {v}"))
    }
}

/// `v` mm (or degrees when `rotary`) in axis units, rounded to the nearest.
pub(super) fn to_units(v: f64, rotary: bool, field: &str) -> Result<i64, FieldError> {
    if !v.is_finite() || v.abs() > 1e9 {
        return Err(refused!("{field}: {v} is out of range"));
    }
    Ok((v * units_per_user(rotary) as f64).round() as i64)
}

/// A positive speed or acceleration, in axis units.
pub(super) fn positive_units(v: f64, rotary: bool, field: &str) -> Result<i64, FieldError> {
    to_units(positive(v, field)?, rotary, field)
}

/// The pose axis a letter names (X Y Z A B C, either case).
pub(super) fn axis_index(name: &str, field: &str) -> Result<usize, FieldError> {
    let unknown = || refused!("{field}: unknown axis {name:?} (expected one of X Y Z A B C)");
    let mut chars = name.chars();
    match (chars.next().map(|c| c.to_ascii_uppercase()), chars.next()) {
        (Some(c), None) => AXIS_NAMES.iter().position(|&a| a == c).ok_or_else(unknown),
        _ => Err(unknown()),
    }
}

/// Points in mm to axis units, each coordinate named `field[i][k]`.
fn mm_points<const N: usize, const D: usize>(
    v: &[[f64; D]; N],
    field: &str,
) -> Result<[[i64; D]; N], FieldError> {
    let mut out = [[0; D]; N];
    for (i, p) in v.iter().enumerate() {
        for (k, c) in p.iter().enumerate() {
            out[i][k] = to_units(*c, false, &format!("{field}[{i}][{k}]"))?;
        }
    }
    Ok(out)
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
