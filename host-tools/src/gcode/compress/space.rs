//! The fit space: X Y Z in nm, A B C with 1° counted as 1 mm. The compressor fits its
//! curves in it, the deviation meter measures a run's distance from its chords in it,
//! and the pre-flight's singularity margin counts a rotary axis's or joint's motion by
//! it (`crate::analysis`). This is the one definition of that rule.

use pkmc::config::{axis_is_rotary, AXES};

/// A point in fit space.
pub type Point = [f64; AXES];

/// Units of a rotary axis or joint (n°) per nm of fit space: 1° (10⁹ n°) counts as
/// 1 mm (10⁶ nm).
pub const ROTARY_PER_NM: f64 = 1000.0;

/// Axis or joint units per nm of fit space: 1 for a linear one (nm), [`ROTARY_PER_NM`]
/// for a rotary one.
pub fn units_per_nm(rotary: bool) -> f64 {
    if rotary {
        ROTARY_PER_NM
    } else {
        1.0
    }
}

/// The point of the segment `a`–`b` nearest `q`: how far along it (0 to 1) and the
/// distance, in any space of `N` coordinates. The compressor's tolerance checks, the
/// deviation meter, the pre-flight's chords and the true path errors all measure by it.
pub fn on_segment<const N: usize>(q: &[f64; N], a: &[f64; N], b: &[f64; N]) -> (f64, f64) {
    let ab: [f64; N] = core::array::from_fn(|i| b[i] - a[i]);
    let aq: [f64; N] = core::array::from_fn(|i| q[i] - a[i]);
    let dot = |u: &[f64; N], v: &[f64; N]| -> f64 { u.iter().zip(v).map(|(x, y)| x * y).sum() };
    let l2 = dot(&ab, &ab);
    let t = if l2 > 0.0 {
        (dot(&aq, &ab) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let off: [f64; N] = core::array::from_fn(|i| q[i] - (a[i] + t * ab[i]));
    (t, dot(&off, &off).sqrt())
}

/// A pose (axis units) in fit space.
pub fn to_fit(p: &[i64; AXES]) -> Point {
    core::array::from_fn(|i| {
        if axis_is_rotary(i) {
            p[i] as f64 / ROTARY_PER_NM
        } else {
            p[i] as f64
        }
    })
}

/// Axis `i`'s coordinate `x` in fit space, in the axis's units (rounded).
pub fn from_fit(i: usize, x: f64) -> i64 {
    (if axis_is_rotary(i) {
        x * ROTARY_PER_NM
    } else {
        x
    })
    .round() as i64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_degree_counts_as_a_millimetre_and_comes_back_exact() {
        let p = [1_000_000, -2, 3, 1_000_000_000, 0, -7_000];
        let v = to_fit(&p);
        assert_eq!(v[0], 1e6);
        assert_eq!(v[3], 1e6);
        assert_eq!(v[5], -7.0);
        for (i, &x) in v.iter().enumerate() {
            assert_eq!(from_fit(i, x), p[i]);
        }
        assert_eq!(1e6 * units_per_nm(true), 1e9);
    }
}
