//! Fixed-point helpers of the kinematics: radians per n° and the saturating rounding
//! of the Newton steps. The general arithmetic they build on (sine and cosine in Q31,
//! integer square roots, fast integer/`f32` conversions) is in [`crate::math`].
//!
//! Invariants: no panics, no `f64`; bit-identical on the MCU and the host.

/// [`crate::math::sincos`] and [`crate::math::isqrt`] under their former path, for
/// the emulated-M4 counts (`perf/m4count`); [`crate::math::ONE_Q31`] for the
/// kinematics' own `fixed::ONE_Q31`.
pub use crate::math::{isqrt, sincos, ONE_Q31};

/// Nanodegrees per radian, 180e9/π, rounded.
pub const NDEG_PER_RAD: i64 = 57_295_779_513;

/// Nearest `i64` of `v`, saturating at ±2^31 (Newton steps are clamped there).
#[inline(always)]
pub fn round_f32(v: f32) -> i64 {
    (v + 0.5f32.copysign(v)) as i32 as i64
}
