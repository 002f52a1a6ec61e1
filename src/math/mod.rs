//! Arithmetic the Cortex-M4F does in hardware, or exactly without a division.
//!
//! On the controller's processor `f64`, 64/128-bit division and `libm`'s square roots
//! are software routines costing hundreds to thousands of cycles each; the tick and
//! receive paths use these instead:
//!
//! * [`sqrtf`]: the FPU's `vsqrt.f32` on the MCU, `libm::sqrtf` elsewhere. Both are
//!   IEEE 754 correctly rounded, so host and MCU compute the same bits.
//! * [`Recip`]: division by an invariant 64-bit divisor through a reciprocal formed
//!   once (Möller & Granlund, "Improved division by invariant integers", IEEE Trans.
//!   Computers 60(2), 2011, algorithm 4): one 64×64→128 multiply, one 64×64 multiply
//!   and two corrections give the exact quotient and remainder. Joint scales divide by
//!   the same numbers every tick, so each gets its reciprocal when the machine loads.
//! * [`fmin`], [`fmax`]: comparisons inline (ARMv7E-M has no `vminnm`; `f32::min`
//!   would call a library routine). Neither argument is ever NaN where they are used.
//! * [`sincos`] (`trig.rs`): sine and cosine of an angle in n° as Q31, for the
//!   kinematics and the arcs of [`crate::motion::geometry`].
//! * [`isqrt`], [`isqrt_wide`] (`root.rs`): integer square roots to ±0.51 from the
//!   correctly rounded single-precision root [`sqrt_f32`]; [`isqrt_floor`], the exact
//!   floor root off the hot path.
//! * Conversions between 64-bit integers and `f32` ([`f32_to_i64`], [`i64_to_f32`],
//!   ...) in one or two hardware conversions.

mod root;
mod trig;

pub use root::{isqrt, isqrt_floor, isqrt_wide, sqrt_f32, sqrt_f32_soft, u128_to_f32};
pub use trig::{mulhr, shr_round, sincos, ONE_Q31};

/// `x` limited to ±`limit` (`limit` ≥ 0). Unlike `f32::clamp` it has no panic path
/// (that one asserts its bounds are ordered), so the loop stays panic-free.
pub fn clamp_sym(x: f32, limit: f32) -> f32 {
    if x > limit {
        limit
    } else if x < -limit {
        -limit
    } else {
        x
    }
}

/// The tests' pseudo-random sequence (Knuth's MMIX LCG): the next value of `state`.
#[cfg(test)]
fn lcg(state: &mut u64) -> u64 {
    *state = state
        .wrapping_mul(6_364_136_223_846_793_005)
        .wrapping_add(1_442_695_040_888_963_407);
    *state
}

/// Square root, correctly rounded (the FPU's `vsqrt.f32` on the MCU).
#[inline(always)]
pub fn sqrtf(x: f32) -> f32 {
    #[cfg(all(target_arch = "arm", target_abi = "eabihf"))]
    {
        // SAFETY: `pkmc_vsqrt` (below) follows the hard-float procedure-call standard:
        // argument and result in s0, nothing else touched.
        unsafe { pkmc_vsqrt(x) }
    }
    #[cfg(not(all(target_arch = "arm", target_abi = "eabihf")))]
    {
        libm::sqrtf(x)
    }
}

// Rust's inline assembly offers single-precision registers only with the
// double-precision `vfp2` feature, which the Cortex-M4F lacks: a two-instruction
// function instead (AAPCS-VFP: the argument and the result in s0).
#[cfg(all(target_arch = "arm", target_abi = "eabihf"))]
core::arch::global_asm!(
    ".section .text.pkmc_vsqrt,\"ax\",%progbits",
    ".global pkmc_vsqrt",
    ".type pkmc_vsqrt,%function",
    ".thumb_func",
    ".fpu fpv4-sp-d16",
    "pkmc_vsqrt:",
    "vsqrt.f32 s0, s0",
    "bx lr",
    ".size pkmc_vsqrt, . - pkmc_vsqrt",
);

#[cfg(all(target_arch = "arm", target_abi = "eabihf"))]
extern "C" {
    fn pkmc_vsqrt(x: f32) -> f32;
}

/// The smaller of two numbers (not NaN).
#[inline(always)]
pub fn fmin(a: f32, b: f32) -> f32 {
    if b < a {
        b
    } else {
        a
    }
}

/// The larger of two numbers (not NaN).
#[inline(always)]
pub fn fmax(a: f32, b: f32) -> f32 {
    if b > a {
        b
    } else {
        a
    }
}

/// Exact division by a fixed divisor `d` > 0 without a division instruction.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Recip {
    /// The divisor shifted left until its top bit is set.
    norm: u64,
    /// That shift.
    shift: u32,
    /// ⌊(2¹²⁸ − 1) / norm⌋ − 2⁶⁴.
    inv: u64,
    /// The divisor.
    d: u64,
}

impl Recip {
    /// The reciprocal of `d` (0 is taken as 1). Divides once, in software: call it
    /// when a machine loads, not per tick.
    #[inline(never)]
    pub const fn new(d: u64) -> Self {
        let d = if d == 0 { 1 } else { d };
        let shift = d.leading_zeros();
        let norm = d << shift;
        let inv = (u128::MAX / norm as u128 - (1u128 << 64)) as u64;
        Self {
            norm,
            shift,
            inv,
            d,
        }
    }

    /// ⌊n / d⌋ and n mod d, for n < d·2⁶⁴ (the quotient fits in 64 bits); larger
    /// numerators take the software division. Not inlined: one copy serves every
    /// joint (flash), at the cost of a call.
    #[inline(never)]
    pub fn div_rem(&self, n: u128) -> (u64, u64) {
        if (n >> 64) as u64 >= self.d {
            return ((n / self.d as u128) as u64, (n % self.d as u128) as u64);
        }
        // n < d·2⁶⁴ < 2^(128 − shift): the shift loses nothing, and u1 < norm.
        let n = n << self.shift;
        let (u1, u0) = ((n >> 64) as u64, n as u64);
        let p = (self.inv as u128 * u1 as u128).wrapping_add(((u1 as u128 + 1) << 64) | u0 as u128);
        let (mut q, low) = ((p >> 64) as u64, p as u64);
        let mut r = u0.wrapping_sub(q.wrapping_mul(self.norm));
        if r > low {
            q = q.wrapping_sub(1);
            r = r.wrapping_add(self.norm);
        }
        if r >= self.norm {
            q += 1;
            r -= self.norm;
        }
        (q, r >> self.shift)
    }

    /// `n / d` rounded to nearest, ties away from zero (as
    /// [`crate::units::div_round`]); the quotient must fit in `i64`.
    #[inline]
    pub fn div_round(&self, n: i128) -> i64 {
        let (q, _) = self.div_rem(n.unsigned_abs() + (self.d / 2) as u128);
        if n < 0 {
            -(q as i64)
        } else {
            q as i64
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn division_is_exact_at_the_edges() {
        for d in [
            1u64,
            2,
            3,
            7,
            1000,
            2500,
            20_000_000,
            u64::MAX / 3,
            u64::MAX,
        ] {
            let r = Recip::new(d);
            for n in [
                0u128,
                1,
                d as u128 - 1,
                d as u128,
                d as u128 + 1,
                (d as u128) << 32,
                (d as u128) * (u64::MAX as u128) + (d as u128 - 1),
            ] {
                assert_eq!(
                    r.div_rem(n),
                    ((n / d as u128) as u64, (n % d as u128) as u64),
                    "{n} / {d}"
                );
            }
        }
    }

    #[test]
    fn rounding_matches_the_reference() {
        let r = Recip::new(2);
        assert_eq!(r.div_round(5), 3);
        assert_eq!(r.div_round(-5), -3);
        let r = Recip::new(3);
        assert_eq!(r.div_round(4), 1);
        assert_eq!(r.div_round(-4), -1);
    }

    proptest! {
        #[test]
        fn quotient_and_remainder_are_exact(d in 1u64.., q in any::<u64>(), rem in any::<u64>()) {
            let n = q as u128 * d as u128 + (rem % d) as u128;
            prop_assert_eq!(Recip::new(d).div_rem(n), (q, rem % d));
        }

        #[test]
        fn rounding_agrees_with_div_round(
            d in 1u64..1u64 << 40, q in -(1i64 << 62)..(1i64 << 62), off in any::<u64>(),
        ) {
            let n = q as i128 * d as i128 + (off % d) as i128;
            prop_assert_eq!(
                Recip::new(d).div_round(n) as i128,
                crate::units::div_round(n, d as i128)
            );
        }

        #[test]
        fn square_roots_are_correctly_rounded(x in 0.0f32..1e30) {
            let r = sqrtf(x) as f64;
            let exact = (x as f64).sqrt();
            prop_assert!((r - exact).abs() <= exact * 6e-8);
        }
    }
}

// Conversions between 64-bit integers and `f32`. The M4's FPU converts only 32-bit
// integers; the 64-bit conversions are library routines of 30–60 instructions. These
// use one or two hardware conversions (float to integer: the same bits as the casts).

/// `x as i64` (truncation toward zero, saturating, NaN → 0). Same bits as the cast.
#[inline]
pub fn f32_to_i64(x: f32) -> i64 {
    let m = x.abs();
    let r = if m < 2_147_483_648.0 {
        m as u32 as i64
    } else if m < 9_223_372_036_854_775_808.0 {
        // m ≥ 2³¹ has no fraction and at most 24 significant bits: its part above 2³²
        // is exact in `f32`, and so is the rest.
        let hi = (m * (1.0 / 4_294_967_296.0)) as u32;
        let lo = (m - hi as f32 * 4_294_967_296.0) as u32;
        ((hi as i64) << 32) | lo as i64
    } else {
        return x as i64;
    };
    if x < 0.0 {
        -r
    } else {
        r
    }
}

/// `(x·2³²) as i64` (the scaling is exact). Same bits as the cast.
#[inline]
pub fn f32_to_q32(x: f32) -> i64 {
    f32_to_i64(x * 4_294_967_296.0)
}

/// `u64` to `f32` without a library call: two `VCVT`s and a multiply-add (relative
/// error ≤ 2⁻²³: the high word's conversion is exact below 2⁵⁶ and the sum rounds
/// once more; not always the bits of the cast, which host and controller need not
/// match since both run this).
#[inline(always)]
pub fn u64_to_f32(v: u64) -> f32 {
    (v >> 32) as u32 as f32 * 4_294_967_296.0 + v as u32 as f32
}

/// `i64` to `f32` as [`u64_to_f32`] (the magnitude is converted, so small negative
/// values do not cancel).
#[inline(always)]
pub fn i64_to_f32(v: i64) -> f32 {
    let m = u64_to_f32(v.unsigned_abs());
    if v < 0 {
        -m
    } else {
        m
    }
}

#[cfg(test)]
mod conversion_tests {
    use super::*;

    #[test]
    fn the_fast_conversions_agree_with_the_casts() {
        let mut x: u32 = 0x1234_5678;
        let mut cases = vec![
            0.0f32,
            -0.0,
            0.5,
            -0.5,
            1.0,
            -1.0,
            2.5e9,
            -2.5e9,
            2_147_483_648.0,
            -2_147_483_648.0,
            4_294_967_296.0,
            9.223_372e18,
            -9.223_372e18,
            1.5e19,
            -1.5e19,
            1e-30,
            -1e-30,
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            3.0e38,
        ];
        for _ in 0..1_000_000 {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            cases.push(f32::from_bits(x));
        }
        for v in cases {
            assert_eq!(f32_to_i64(v), v as i64, "{v:e}");
            assert_eq!(f32_to_q32(v), (v * 4_294_967_296.0) as i64, "{v:e}");
        }
        let mut y: u64 = 0x9E37_79B9_7F4A_7C15;
        for i in 0..200_000 {
            y ^= y << 13;
            y ^= y >> 7;
            y ^= y << 17;
            let v = (y as i64) >> (i % 64);
            let want = v as f64;
            assert!(
                (i64_to_f32(v) as f64 - want).abs() <= want.abs() * 2.4e-7,
                "{v}"
            );
            let u = y >> (i % 64);
            assert!(
                (u64_to_f32(u) as f64 - u as f64).abs() <= u as f64 * 2.4e-7,
                "{u}"
            );
        }
        assert_eq!(u64_to_f32(u64::MAX), 1.8446744e19);
        assert_eq!(i64_to_f32(-40), -40.0);
    }

    #[test]
    fn integer_to_float_conversions_are_accurate_for_any_sign_and_size() {
        for v in [
            0i64,
            1,
            -1,
            -40,
            40,
            -(1 << 32) + 7,
            (1 << 40) + 3,
            i64::MIN,
            i64::MAX,
        ] {
            let want = v as f64;
            let got = i64_to_f32(v) as f64;
            assert!((got - want).abs() <= want.abs() * 2.4e-7, "{v}: {got}");
        }
        assert_eq!(u64_to_f32(u64::MAX), 1.8446744e19);
    }
}
