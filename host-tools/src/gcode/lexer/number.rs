//! Literal numbers: the exact decimal a word's value is kept as ([`Num`]), its exact
//! conversion to axis units, and the reading of a literal from the line.
//!
//! A literal keeps its digits as written (`mant / 10^scale`); a value computed by an
//! expression or read from a parameter is an `f64` ([`Num::Real`]). Scaling to axis units
//! ([`Num::scaled`], or [`Num::times`] a [`Factor`] such as [`MM`]) rounds once, to the
//! nearest unit, ties away from zero.
//!
//! Speed (this is the parser's hot path): the common literal is read without a check
//! per digit ([`Cursor::plain_literal`]), a length in mm with at most six decimals
//! converts by one multiplication, and rounding adds its ±1 without a branch (which way
//! a value rounds is as good as random, so a branch on it would mispredict).
//!
//! Invariants: a literal has at most 18 significant digits and [`MAX_DECIMALS`]
//! decimals, so its mantissa never overflows; scaling never panics (it falls back to
//! `i128`, and returns `None` when the result does not fit an `i64`); a computed value
//! converts only when it is finite and inside the `i64` range ([`f64_to_i64`]).
//!
//! Source: LinuxCNC G-code overview (numbers; 0.0001 as the tolerance of whole numbers).

use super::{Cursor, ErrorKind, LexError};
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

/// A conversion factor to axis units, `mult × 10^exp`, kept apart so that scaling a
/// literal by it ([`Num::times`]) needs a division only when the literal has more than
/// `exp` decimals (`G21 X1.5` is 1 500 000 nm by one multiplication).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Factor {
    mult: i64,
    exp: u32,
}

impl Factor {
    /// `mult × 10^exp`; `mult > 0` and the product must fit an `i64` (checked when the
    /// constant is built).
    pub const fn new(mult: i64, exp: u32) -> Self {
        assert!(mult > 0 && exp <= MAX_DECIMALS);
        assert!(mult.checked_mul(POW10[exp as usize]).is_some());
        Self { mult, exp }
    }

    /// The factor as one integer.
    pub const fn value(self) -> i64 {
        self.mult * POW10[self.exp as usize]
    }
}

/// nm per mm.
pub const MM: Factor = Factor::new(1, 6);
/// nm per inch (25.4 mm).
pub const INCH: Factor = Factor::new(254, 5);
/// n° per degree.
pub const DEGREE: Factor = Factor::new(1, 9);

const _: () = assert!(MM.value() == pkmc::units::NM_PER_MM);
const _: () = assert!(DEGREE.value() == pkmc::units::NDEG_PER_DEG);
const _: () = assert!(INCH.value() == crate::gcode::interp::NM_PER_INCH);

/// A word's value: an exact decimal as written, or a value computed in `f64`.
///
/// The tag is a whole `u64` so that nothing shares the first eight bytes with it. In
/// Rust's own layout the tag and `scale` share them and the mantissa follows, and the
/// compiler copies a word as 4, 8 and 4 bytes: reading the mantissa of the copy then
/// spans two stores, which the processor cannot forward to the load, and the load waits
/// for both to reach the cache (three times per arc line; 8 % of compile time on
/// arcspiral.ngc).
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(u64)]
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

    /// `self × factor` rounded to the nearest integer (ties away from zero), or `None`
    /// when that does not fit an `i64`: exactly [`Num::scaled`]`(factor.value(), 1)`,
    /// without its division for a literal with at most `factor`'s `exp` decimals, and
    /// with a division by a smaller power of ten for the others (the quotient rounds
    /// the same: numerator and denominator are divided by the same `10^exp`).
    #[inline(always)]
    pub fn times(self, factor: Factor) -> Option<i64> {
        if let Num::Lit { mant, scale } = self {
            if scale <= factor.exp {
                // `mult × 10^(exp - scale)` divides the factor, so it fits an i64.
                let exact = mant.checked_mul(factor.mult * POW10[(factor.exp - scale) as usize]);
                if exact.is_some() {
                    return exact;
                }
            } else if let Some(n) = mant.checked_mul(factor.mult) {
                // Not `Option::map`: its closure would not be inlined.
                return Some(div_round_pow10(n, scale - factor.exp));
            }
        }
        // A computed value, or a product beyond an i64 (which `scaled` takes in i128).
        self.scaled(factor.value(), 1)
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
    // On the magnitude: (|n| + ⌊d/2⌋) / d rounds half up (no tie when d is odd), and
    // cannot overflow (|n| ≤ 2^63, d/2 < 2^62). Without a branch: which way a value
    // rounds is as good as random, a branch on it would mispredict.
    let d = d.unsigned_abs();
    let q = ((n.unsigned_abs() + d / 2) / d) as i64;
    // Wrapping: only n = i64::MIN, d = 1 gives q = 2^63, which wraps back to n.
    if n < 0 {
        q.wrapping_neg()
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
#[inline(always)]
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
#[inline(always)]
pub(crate) fn f64_to_i64(v: f64) -> Option<i64> {
    // 2^63 is exactly representable; everything strictly inside converts. Rounding by
    // hand avoids a libm call on baseline x86-64.
    const LIMIT: f64 = 9_223_372_036_854_775_000.0;
    if !(v > -LIMIT && v < LIMIT) {
        return None;
    }
    let t = v as i64;
    let frac = v - t as f64;
    // Without a branch, as in `div_round_i64`.
    Some(t + i64::from(frac >= 0.5) - i64::from(frac <= -0.5))
}

/// Most digits [`Cursor::plain_literal`] takes: a mantissa of at most 18 digits fits an
/// `i64` and can never have grown past the digit limit of [`Cursor::literal`].
const PLAIN_DIGITS: usize = 18;

impl Cursor<'_> {
    /// `[+-] digits [. digits]`, blanks allowed between characters; starts at
    /// `self.i` (already at the sign or first digit). `col_at` is where a malformed
    /// number is reported.
    pub(super) fn literal(&mut self, col_at: usize) -> Result<Num, LexError> {
        if let Some(num) = self.quick_literal() {
            return Ok(num);
        }
        let start = self.i;
        let negative = self.b.get(start) == Some(&b'-');
        if let Some(b'+' | b'-') = self.b.get(start) {
            self.i += 1;
        }
        let (mant, scale) = self.spaced_literal(start, col_at)?;
        Ok(Num::Lit {
            mant: if negative { -mant } else { mant },
            scale,
        })
    }

    /// [`Self::literal`] for the common literal ([`Self::plain_literal`] after an
    /// optional sign), inlined where values are read; `None`, the cursor unmoved, for
    /// any other.
    #[inline(always)]
    pub(super) fn quick_literal(&mut self) -> Option<Num> {
        let (mant, scale) = self.quick_literal_parts()?;
        Some(Num::Lit { mant, scale })
    }

    /// [`Self::quick_literal`] as its signed mantissa and decimals.
    #[inline(always)]
    pub(super) fn quick_literal_parts(&mut self) -> Option<(i64, u32)> {
        let start = self.i;
        let sign = self.b.get(start).copied();
        let from = start + usize::from(matches!(sign, Some(b'+' | b'-')));
        let (mant, scale, end) = self.plain_literal(from)?;
        self.i = end;
        Some((if sign == Some(b'-') { -mant } else { mant }, scale))
    }

    /// The common literal, read without a check per digit: `digits [. digits]` from byte
    /// `from` (after the sign) with at least one and at most [`PLAIN_DIGITS`] digits and
    /// nothing but the end of the number after its blanks. Returns the unsigned
    /// mantissa, the decimals and where the number ends (after its blanks); `None`
    /// for anything else (blanks inside the number, a second point, no digit, too many
    /// digits), which [`Self::spaced_literal`] reads or reports.
    #[inline(always)]
    fn plain_literal(&self, from: usize) -> Option<(i64, u32, usize)> {
        let b = self.b;
        let mut i = from;
        // Wrapping: a mantissa past PLAIN_DIGITS digits is thrown away below.
        let mut mant = 0u64;
        while let Some(&c @ b'0'..=b'9') = b.get(i) {
            mant = mant.wrapping_mul(10).wrapping_add(u64::from(c - b'0'));
            i += 1;
        }
        let mut digits = i - from;
        let mut scale = 0;
        if b.get(i) == Some(&b'.') {
            i += 1;
            let point = i;
            while let Some(&c @ b'0'..=b'9') = b.get(i) {
                mant = mant.wrapping_mul(10).wrapping_add(u64::from(c - b'0'));
                i += 1;
            }
            scale = i - point;
            digits += scale;
        }
        if digits == 0 || digits > PLAIN_DIGITS {
            return None;
        }
        let mut end = i;
        while let Some(b' ' | b'\t') = b.get(end) {
            end += 1;
        }
        if let Some(b'0'..=b'9' | b'.') = b.get(end) {
            return None; // the number goes on after blanks, or has a second point
        }
        // At most 18 digits: below 10^18, inside an i64.
        Some((mant as i64, scale as u32, end))
    }

    /// Any literal after its sign, blanks allowed between characters (`X1 0` is `X10`),
    /// checked digit by digit: the unsigned mantissa and the decimals. `start`: where
    /// the number (its sign) starts.
    fn spaced_literal(&mut self, start: usize, col_at: usize) -> Result<(i64, u32), LexError> {
        // The mantissa stays below 10^18 (18 significant digits), so it never overflows.
        const MANT_LIMIT: i64 = 99_999_999_999_999_999;
        let (mut mant, mut digits, mut point_at) = (0i64, 0u32, None);
        loop {
            while let Some(&c @ b'0'..=b'9') = self.b.get(self.i) {
                if mant > MANT_LIMIT {
                    return Err(self.err(
                        start,
                        ErrorKind::OutOfRange,
                        "number with too many digits",
                    ));
                }
                mant = mant * 10 + i64::from(c - b'0');
                digits += 1;
                self.i += 1;
            }
            match self.b.get(self.i) {
                Some(b'.') if point_at.is_none() => point_at = Some(digits),
                Some(b'.') => {
                    return Err(self.err(
                        col_at.min(start),
                        ErrorKind::BadNumber,
                        "malformed number (two decimal points)",
                    ))
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
                ErrorKind::OutOfRange,
                format!("number with more than {MAX_DECIMALS} decimals"),
            ));
        }
        if digits == 0 {
            return Err(self.err(start, ErrorKind::BadNumber, "malformed number (no digits)"));
        }
        Ok((mant, scale))
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

    /// A fixed pseudo-random sequence (xorshift), the same on every run.
    fn pseudo_random(n: usize) -> impl Iterator<Item = u64> {
        let mut x = 0x9e37_79b9_7f4a_7c15u64;
        (0..n).map(move |_| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        })
    }

    #[test]
    fn scaling_by_a_factor_is_scaling_by_its_value() {
        let edges = [
            0,
            1,
            5,
            15,
            25,
            99_999,
            123_456_789,
            999_999_999_999_999_999,
        ];
        let random = pseudo_random(2_000).map(|x| (x % 1_000_000_000_000_000_000) as i64);
        let digits = pseudo_random(2_000).map(|x| (x % 100_000_000) as i64);
        for mant in edges.into_iter().chain(random).chain(digits) {
            for m in [mant, -mant] {
                for scale in 0..=MAX_DECIMALS {
                    for f in [MM, INCH, DEGREE, Factor::new(1, 0), Factor::new(7, 18)] {
                        let n = Num::Lit { mant: m, scale };
                        assert_eq!(n.times(f), n.scaled(f.value(), 1), "{n} × {f:?}");
                    }
                }
            }
        }
        for v in [0.5, -2.5e-7, 1.234_567_5, 9.3e12, f64::NAN, f64::INFINITY] {
            assert_eq!(Num::Real(v).times(INCH), Num::Real(v).scaled(25_400_000, 1));
        }
    }

    #[test]
    fn rounded_division_is_that_of_i128() {
        let values = [
            0,
            1,
            4,
            5,
            6,
            14,
            15,
            25,
            99_999,
            1_000_005,
            i64::MAX,
            i64::MIN + 1,
        ];
        let random = pseudo_random(500).map(|x| x as i64);
        for n in values.into_iter().chain(random) {
            for d in [
                1,
                2,
                3,
                7,
                10,
                60,
                1_000,
                1_000_000,
                600_000_000,
                1_000_000_000_000_000_000,
            ] {
                for n in [n, n.wrapping_neg()] {
                    let exact = pkmc::units::div_round(i128::from(n), i128::from(d));
                    assert_eq!(i128::from(div_round_i64(n, d)), exact, "{n} / {d}");
                }
            }
            for s in 0..=MAX_DECIMALS {
                let exact = pkmc::units::div_round(i128::from(n), i128::from(POW10[s as usize]));
                assert_eq!(i128::from(div_round_pow10(n, s)), exact, "{n} / 10^{s}");
            }
        }
        assert_eq!(div_round_i64(i64::MIN, 1), i64::MIN);
        assert_eq!(div_round_i64(i64::MIN, 10), -922_337_203_685_477_581);
    }

    /// `literal` on `text`: its value and where it ends, or the error's column.
    fn read(text: &str) -> Result<(Num, usize), u32> {
        let params = crate::gcode::params::Params::new();
        let mut c = Cursor {
            b: text.as_bytes(),
            text,
            i: 0,
            params: &params,
        };
        c.literal(0).map(|n| (n, c.i)).map_err(|e| e.col)
    }

    /// The same, read by the checked reader alone.
    fn read_spaced(text: &str) -> Result<(Num, usize), u32> {
        let params = crate::gcode::params::Params::new();
        let mut c = Cursor {
            b: text.as_bytes(),
            text,
            i: 0,
            params: &params,
        };
        let negative = text.starts_with('-');
        if negative || text.starts_with('+') {
            c.i = 1;
        }
        let (mant, scale) = c.spaced_literal(0, 0).map_err(|e| e.col)?;
        let mant = if negative { -mant } else { mant };
        Ok((Num::Lit { mant, scale }, c.i))
    }

    #[test]
    fn the_plain_reader_agrees_with_the_checked_one() {
        let alphabet = b"0123456789.. -+X";
        for x in pseudo_random(20_000) {
            let len = 1 + (x % 24) as usize;
            let mut text = String::new();
            let mut bits = x >> 5;
            if x & 16 != 0 {
                text.push('-');
            }
            for _ in 0..len {
                let k = (bits % 13) as usize; // mostly digits and points, some blanks
                bits = (bits / 13) ^ (bits << 7);
                text.push(alphabet[if k < 12 { k } else { 12 + (bits % 4) as usize }] as char);
            }
            assert_eq!(read(&text), read_spaced(&text), "{text:?}");
        }
        let cases = [
            "1.5 x", "1 0", "1 .5", "1. 5", "007", ".", "-.", "1.2.3", "5.\t",
        ];
        for text in cases {
            assert_eq!(read(text), read_spaced(text), "{text:?}");
        }
        let nineteen = "1234567890123456789";
        assert_eq!(read(nineteen), Err(1), "too many digits");
        assert_eq!(
            read("-123456789012345678 y"),
            Ok((
                Num::Lit {
                    mant: -123_456_789_012_345_678,
                    scale: 0
                },
                20
            ))
        );
    }
}
