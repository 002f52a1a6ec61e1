//! Literal numbers: the exact decimal a word's value is kept as ([`Num`]), its exact
//! conversion to axis units, and the reading of a literal from the line.
//!
//! A literal keeps its digits as written (`mant / 10^scale`); a value computed by an
//! expression or read from a parameter is an `f64` ([`Num::Real`]). Scaling to axis units
//! ([`Num::scaled`]) rounds once, to the nearest unit, ties away from zero.
//!
//! Invariants: a literal has at most 18 significant digits and [`MAX_DECIMALS`]
//! decimals, so its mantissa never overflows; scaling never panics (it falls back to
//! `i128`, and returns `None` when the result does not fit an `i64`); a computed value
//! converts only when it is finite and inside the `i64` range ([`f64_to_i64`]).
//!
//! Source: LinuxCNC G-code overview (numbers; 0.0001 as the tolerance of whole numbers).

use super::{Cursor, LexError};
use std::fmt;

/// Powers of ten that fit an `i64`.
const POW10: [i64; 19] = [
    1,
    10,
    100,
    1_000,
    10_000,
    100_000,
    1_000_000,
    10_000_000,
    100_000_000,
    1_000_000_000,
    10_000_000_000,
    100_000_000_000,
    1_000_000_000_000,
    10_000_000_000_000,
    100_000_000_000_000,
    1_000_000_000_000_000,
    10_000_000_000_000_000,
    100_000_000_000_000_000,
    1_000_000_000_000_000_000,
];

/// Most digits after the decimal point of a literal.
pub const MAX_DECIMALS: u32 = 18;

/// Tolerance within which a computed value counts as a whole number (LinuxCNC's).
const WHOLE_TOLERANCE: f64 = 1e-4;

/// A word's value: an exact decimal as written, or a value computed in `f64`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Num {
    /// `mant / 10^scale`, exactly as written.
    Lit {
        /// Digits as a signed integer.
        mant: i64,
        /// Digits after the decimal point (at most [`MAX_DECIMALS`]).
        scale: u32,
    },
    /// Computed by an expression or read from a parameter.
    Real(f64),
}

impl Num {
    /// The value as `f64`.
    #[inline]
    pub fn to_f64(self) -> f64 {
        match self {
            Num::Lit { mant, scale } => mant as f64 / POW10[scale as usize] as f64,
            Num::Real(v) => v,
        }
    }

    /// `self × num / den` rounded to the nearest integer (ties away from zero), or
    /// `None` when that does not fit an `i64`. `den > 0`.
    #[inline]
    pub fn scaled(self, num: i64, den: i64) -> Option<i64> {
        match self {
            Num::Lit { mant, scale } => {
                if den == 1 {
                    if let Some(n) = mant.checked_mul(num) {
                        return Some(div_round_pow10(n, scale));
                    }
                } else if let (Some(n), Some(d)) = (
                    mant.checked_mul(num),
                    POW10[scale as usize].checked_mul(den),
                ) {
                    return Some(div_round_i64(n, d));
                }
                let p = POW10[scale as usize] as i128;
                let q = pkmc::units::div_round(mant as i128 * num as i128, p * den as i128);
                i64::try_from(q).ok()
            }
            Num::Real(v) => f64_to_i64(v * num as f64 / den as f64),
        }
    }

    /// The value as a whole number, if it is one (exactly for literals, within
    /// LinuxCNC's 0.0001 for computed values).
    pub fn whole(self) -> Option<i64> {
        match self {
            Num::Lit { mant, scale } => {
                let p = POW10[scale as usize];
                (mant % p == 0).then_some(mant / p)
            }
            Num::Real(v) => {
                let r = v.round();
                if (v - r).abs() < WHOLE_TOLERANCE {
                    f64_to_i64(r)
                } else {
                    None
                }
            }
        }
    }

    /// Ten times the value, if that is a whole number (G and M codes: `G28.1` is 281).
    pub fn tenths(self) -> Option<i64> {
        match self {
            Num::Lit { mant, scale: 0 } => mant.checked_mul(10),
            Num::Lit { mant, scale } => {
                let p = POW10[scale as usize - 1];
                (mant % p == 0).then_some(mant / p)
            }
            Num::Real(v) => {
                let t = v * 10.0;
                let r = t.round();
                if (t - r).abs() < 1e-3 {
                    f64_to_i64(r)
                } else {
                    None
                }
            }
        }
    }

    /// Is the value zero?
    pub fn is_zero(self) -> bool {
        match self {
            Num::Lit { mant, .. } => mant == 0,
            Num::Real(v) => v == 0.0,
        }
    }

    /// Is the value below zero?
    pub fn is_negative(self) -> bool {
        match self {
            Num::Lit { mant, .. } => mant < 0,
            Num::Real(v) => v < 0.0,
        }
    }
}

impl fmt::Display for Num {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Num::Lit { mant, scale: 0 } => write!(f, "{mant}"),
            Num::Lit { mant, scale } => {
                let p = POW10[scale as usize].unsigned_abs();
                let sign = if mant < 0 { "-" } else { "" };
                let m = mant.unsigned_abs();
                write!(
                    f,
                    "{sign}{}.{:0width$}",
                    m / p,
                    m % p,
                    width = scale as usize
                )
            }
            Num::Real(v) => write!(f, "{v}"),
        }
    }
}

/// Rounds `n / d` to the nearest integer, ties away from zero; `d > 0`.
#[inline(always)]
fn div_round_i64(n: i64, d: i64) -> i64 {
    let q = n / d;
    let r = n % d;
    // |r| >= d/2 rounds away from zero; compare without overflow.
    if r.unsigned_abs() >= d.unsigned_abs() - r.unsigned_abs() {
        if n < 0 {
            q - 1
        } else {
            q + 1
        }
    } else {
        q
    }
}

/// [`div_round_i64`] by a constant, which the compiler turns into a multiplication.
#[inline(always)]
fn div_round_const<const D: i64>(n: i64) -> i64 {
    div_round_i64(n, D)
}

/// Rounds `n / 10^scale` to the nearest integer, ties away from zero.
fn div_round_pow10(n: i64, scale: u32) -> i64 {
    match scale {
        0 => n,
        1 => div_round_const::<10>(n),
        2 => div_round_const::<100>(n),
        3 => div_round_const::<1_000>(n),
        4 => div_round_const::<10_000>(n),
        5 => div_round_const::<100_000>(n),
        6 => div_round_const::<1_000_000>(n),
        7 => div_round_const::<10_000_000>(n),
        8 => div_round_const::<100_000_000>(n),
        9 => div_round_const::<1_000_000_000>(n),
        s => div_round_i64(n, POW10[(s as usize).min(18)]),
    }
}

/// Rounds a finite `f64` to the nearest `i64` (ties away from zero), or `None` when it
/// is not finite or out of range.
#[inline]
pub(crate) fn f64_to_i64(v: f64) -> Option<i64> {
    // 2^63 is exactly representable; everything strictly inside converts. Rounding by
    // hand avoids a libm call on baseline x86-64.
    const LIMIT: f64 = 9_223_372_036_854_775_000.0;
    if !(v > -LIMIT && v < LIMIT) {
        return None;
    }
    let t = v as i64;
    let frac = v - t as f64;
    Some(if frac >= 0.5 {
        t + 1
    } else if frac <= -0.5 {
        t - 1
    } else {
        t
    })
}

impl Cursor<'_> {
    /// `[+-] digits [. digits]`, blanks allowed between characters; starts at
    /// `self.i` (already at the sign or first digit). `col_at` is where a malformed
    /// number is reported.
    pub(super) fn literal(&mut self, col_at: usize) -> Result<Num, LexError> {
        let start = self.i;
        let mut negative = false;
        if let Some(&s @ (b'+' | b'-')) = self.b.get(self.i) {
            negative = s == b'-';
            self.i += 1;
        }
        // The mantissa stays below 10^18 (18 significant digits), so it never overflows.
        const MANT_LIMIT: i64 = 99_999_999_999_999_999;
        let (mut mant, mut digits, mut point_at) = (0i64, 0u32, None);
        loop {
            while let Some(&c @ b'0'..=b'9') = self.b.get(self.i) {
                if mant > MANT_LIMIT {
                    return Err(self.err(start, "number with too many digits"));
                }
                mant = mant * 10 + i64::from(c - b'0');
                digits += 1;
                self.i += 1;
            }
            match self.b.get(self.i) {
                Some(b'.') if point_at.is_none() => point_at = Some(digits),
                Some(b'.') => {
                    return Err(self.err(col_at.min(start), "malformed number (two decimal points)"))
                }
                Some(b' ' | b'\t') => {}
                _ => break,
            }
            self.i += 1;
        }
        let scale = point_at.map_or(0, |p| digits - p);
        if scale > MAX_DECIMALS {
            return Err(self.err(
                start,
                format!("number with more than {MAX_DECIMALS} decimals"),
            ));
        }
        if digits == 0 {
            return Err(self.err(start, "malformed number (no digits)"));
        }
        Ok(Num::Lit {
            mant: if negative { -mant } else { mant },
            scale,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scaling_rounds_half_away_from_zero() {
        let n = Num::Lit { mant: 15, scale: 1 };
        assert_eq!(n.scaled(1, 1), Some(2));
        let n = Num::Lit {
            mant: -15,
            scale: 1,
        };
        assert_eq!(n.scaled(1, 1), Some(-2));
        assert_eq!(Num::Real(1e300).scaled(1_000_000, 1), None);
        let inch = Num::Lit {
            mant: 1_234_567,
            scale: 6,
        };
        assert_eq!(inch.scaled(25_400_000, 1), Some(31_358_002));
    }
}
