//! File units to the core's integer units, each refusal naming its field: positive
//! numbers, lengths and angles in range, axis letters, point sets.

use super::{refused, FieldError};
use pkmc::config::AXIS_NAMES;
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
pub(super) fn mm_points<const N: usize, const D: usize>(
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
