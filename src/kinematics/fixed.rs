//! Fixed-point helpers for the kinematics: sine/cosine of an angle in n° as Q30, the
//! correctly rounded integer square root, rounding shifts and the few `f32` conversions
//! the Newton steps need.
//!
//! Invariants: no panics, no loops, no `f64`; every result is exact to the bound stated
//! on the function and bit-identical on the MCU and the host (`f32` is used only for
//! estimates that an exact integer step then corrects, and IEEE single-precision
//! arithmetic without fused operations is the same everywhere). Each function is a few
//! dozen Cortex-M4 instructions: 32 × 32 → 64-bit products (`SMULL`, `UMULL`,
//! `SMMULR`), 64-bit adds and shifts, a handful of `f32` multiplies.
//!
//! Sources: the polynomial coefficients are least-squares fits on Chebyshev nodes of
//! (sin x − x)/x³ and (cos x − 1)/x² in x² over |x| ≤ π/4 (fit residual 2.5e-12 and
//! 5.6e-11), rounded to the fixed-point format of each Horner stage; the square root is
//! one Newton step x₁ = x₀ + (N − x₀²)/(2x₀) from an `f32` estimate, with the residual
//! N − x₀² exact in 64-bit integers, then an exact ±1 fix-up. The `f32` estimate is the
//! well-known bit-level reciprocal square root (Lomont, "Fast inverse square root",
//! 2003) with two Newton steps.

/// Q30 one: sine and cosine come as `i32` with 2^30 = 1.0.
pub const ONE_Q30: i32 = 1 << 30;

/// Nanodegrees per radian, 180e9/π, rounded.
pub const NDEG_PER_RAD: i64 = 57_295_779_513;

// n° → Q31 radians for |r| ≤ 45°: x = r·K / 2^36, K = round(π/180e9 · 2^67) (K's
// relative error 2e-10, i.e. ≤ 1.5e-10 rad at π/4).
const RAD_K: u64 = 2_575_651_363;
// sin x = x + x·x²·(A3 + x²·(A5 + x²·(A7 + x²·A9))); Q33, Q34, Q35, Q36.
const A3: i32 = -1_431_655_762;
const A5: i32 = 143_165_487;
const A7: i32 = -6_816_635;
const A9: i32 = 186_630;
// cos x = 1 + x²·(B2 + x²·(B4 + x²·(B6 + x²·B8))); Q31, Q32, Q33, Q34.
const B2: i32 = -1_073_741_818;
const B4: i32 = 178_956_782;
const B6: i32 = -11_928_626;
const B8: i32 = 419_003;

const DEG: i64 = crate::units::NDEG_PER_DEG;

/// Rounded high word of a signed 32 × 32 product: `(a·b + 2^31) >> 32` (`SMMULR`).
#[inline(always)]
pub fn mulhr(a: i32, b: i32) -> i32 {
    ((a as i64 * b as i64 + 0x8000_0000) >> 32) as i32
}

/// `v / 2^s` rounded to nearest (ties up), `1 ≤ s ≤ 62`.
#[inline(always)]
pub const fn shr_round(v: i64, s: u32) -> i64 {
    (v + (1 << (s - 1))) >> s
}

/// Sine and cosine of `angle` (n°) as Q30 (`(sin, cos)`), each within 1.1 · 2^-30
/// (1.0e-9) of the true value for any `angle`.
///
/// |angle| ≤ 180° is reduced with compares only; beyond, one 64-bit remainder first
/// (a slow path no machine here takes). The reduced angle r, |r| ≤ 45°, becomes Q31
/// radians by one 32 × 36-bit product, then two degree-9/8 polynomials in Horner form
/// with `SMMULR` steps; the quadrant swaps signs and roles. Budget (measured over
/// 25 000 angles against 30-digit values): 0.5 LSB output rounding, ≤ 0.5 LSB from the
/// stage roundings, < 0.1 LSB fit and angle-conversion error.
#[inline]
pub fn sincos(angle: i64) -> (i32, i32) {
    let mut a = angle;
    if !(-180 * DEG..=180 * DEG).contains(&a) {
        a %= 360 * DEG;
        if a > 180 * DEG {
            a -= 360 * DEG;
        } else if a < -180 * DEG {
            a += 360 * DEG;
        }
    }
    let (quadrant, r) = if a > 45 * DEG {
        if a > 135 * DEG {
            (2, a - 180 * DEG)
        } else {
            (1, a - 90 * DEG)
        }
    } else if a < -45 * DEG {
        if a < -135 * DEG {
            (2, a + 180 * DEG)
        } else {
            (3, a + 90 * DEG)
        }
    } else {
        (0, a)
    };
    let (s, c) = sincos_octant(r);
    match quadrant {
        0 => (s, c),
        1 => (c, -s),
        2 => (-s, -c),
        _ => (-c, s),
    }
}

/// `sincos` for |r| ≤ 45° (n°).
#[inline(always)]
fn sincos_octant(r: i64) -> (i32, i32) {
    // r·K split in 32-bit halves: |r >> 32| ≤ 11, so both partial products fit.
    let lo = ((r as u32 as u64 * RAD_K) >> 32) as i64;
    let hi = (r >> 32) * RAD_K as i64;
    let x = shr_round(hi + lo, 4) as i32; // Q31 radians, |x| ≤ 0.786
    let x2 = shr_round(x as i64 * x as i64, 31) as i32; // Q31
    let t = mulhr(x2, A9) + A7;
    let t = mulhr(x2, t) + A5;
    let t = mulhr(x2, t) + A3;
    let y = mulhr(x2, t); // x²·(…), Q32
    let s = (x + mulhr(x, y) + 1) >> 1; // Q31 → Q30
    let t = mulhr(x2, B8) + B6;
    let t = mulhr(x2, t) + B4;
    let t = mulhr(x2, t) + B2;
    let c = ONE_Q30 + mulhr(x2, t); // x²·(…) is Q30
    (s, c)
}

/// `u64` to `f32` without a library call: two `VCVT`s and a multiply-add.
#[inline(always)]
pub fn u64_to_f32(v: u64) -> f32 {
    (v >> 32) as u32 as f32 * 4_294_967_296.0 + v as u32 as f32
}

/// `i64` to `f32` without a library call (relative error ≤ 2^-23; the magnitude is
/// converted, so small negative values do not cancel).
#[inline(always)]
pub fn i64_to_f32(v: i64) -> f32 {
    let m = u64_to_f32(v.unsigned_abs());
    if v < 0 {
        -m
    } else {
        m
    }
}

/// Nearest `i64` of `v`, saturating at ±2^31 (Newton steps are clamped there).
#[inline(always)]
pub fn round_f32(v: f32) -> i64 {
    (v + 0.5f32.copysign(v)) as i32 as i64
}

/// `√n` rounded to the nearest integer, exactly, for every `n < 2^64 − 2^32`.
///
/// An `f32` estimate: the bit-level reciprocal-square-root guess and two Newton steps
/// give y ≈ 1/√n to 5e-6 and x₀ = n·y; one Newton step with the residual n − x₀²
/// exact in 64 bits, x₁ = x₀ + (n − x₀²)·y/2, leaves |x₁ − √n| < 0.05 + 1 (the
/// truncated step); one exact check of (x − ½)² ≤ n < (x + ½)², i.e.
/// x² − x < n ≤ x² + x, moves x by one if needed. Pure arithmetic (no `VSQRT`: `core`
/// has no `sqrt`, and Rust's `asm!` offers no single-precision register class on a
/// single-precision FPU), so every step is bit-identical on the MCU and the host.
#[inline]
pub fn isqrt_round(n: u64) -> u64 {
    let v = u64_to_f32(n);
    let h = 0.5 * v;
    let mut y = f32::from_bits(0x5f37_59df - (v.to_bits() >> 1));
    y *= 1.5 - h * y * y;
    y *= 1.5 - h * y * y;
    let x0 = (v * y + 0.5) as u32 as u64;
    let d0 = n.wrapping_sub(x0 * x0) as i64;
    let x = (x0 as i64 + (i64_to_f32(d0) * 0.5 * y) as i32 as i64) as u64;
    let d = n.wrapping_sub(x.wrapping_mul(x)) as i64;
    if d > x as i64 {
        x + 1
    } else if d <= -(x as i64) && x > 0 {
        x - 1
    } else {
        x
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lcg(state: &mut u64) -> u64 {
        *state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        *state
    }

    #[test]
    fn sine_and_cosine_are_within_1_1e_9_everywhere() {
        let mut seed = 7;
        let mut worst = 0.0f64;
        let mut angles = vec![
            0,
            1,
            -1,
            45 * DEG,
            -45 * DEG,
            90 * DEG,
            180 * DEG,
            -180 * DEG,
        ];
        angles.extend([i64::MAX, i64::MIN, 360 * DEG + 1, 1 << 40]);
        for _ in 0..200_000 {
            angles.push((lcg(&mut seed) as i64) % (400 * DEG));
        }
        for a in angles {
            let (s, c) = sincos(a);
            // Reference: reduce exactly in integers first, then f64 (error ~1e-16).
            let r = (a % (360 * DEG)) as f64 / DEG as f64;
            let x = r.to_radians();
            let es = (s as f64 / ONE_Q30 as f64 - x.sin()).abs();
            let ec = (c as f64 / ONE_Q30 as f64 - x.cos()).abs();
            worst = worst.max(es).max(ec);
        }
        assert!(worst < 1.1e-9 * 1.0, "worst sin/cos error {worst:e}");
    }

    #[test]
    fn the_square_root_is_correctly_rounded() {
        let mut seed = 11;
        let mut cases: Vec<u64> = (0..5000).collect();
        for k in 1..64 {
            let p = 1u64 << k;
            cases.extend([p - 1, p, p + 1]);
        }
        for r in [1u64 << 31, (1 << 32) - 2, 123_456_789, 2_200_000_000] {
            // exact squares and the tie points r² ± r
            cases.extend([r * r, r * r - r, r * r - r + 1, r * r + r, r * r + r + 1]);
        }
        for _ in 0..200_000 {
            let v = lcg(&mut seed);
            cases.push(v >> (v % 61));
        }
        for n in cases {
            if n >= u64::MAX - (1 << 32) {
                continue;
            }
            let r = n.isqrt();
            // round: r or r + 1, whichever is nearer (no ties for integer n)
            let want = if (n - r * r) > r { r + 1 } else { r };
            assert_eq!(isqrt_round(n), want, "n = {n}");
        }
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

    #[test]
    fn rounding_shift_rounds_half_up() {
        assert_eq!(shr_round(5, 1), 3);
        assert_eq!(shr_round(-5, 1), -2);
        assert_eq!(shr_round(-6, 1), -3);
        assert_eq!(mulhr(1 << 30, 1 << 30), 1 << 28);
    }
}
