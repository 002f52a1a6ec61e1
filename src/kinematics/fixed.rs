//! Fixed-point helpers for the kinematics: sine/cosine of an angle in n° as Q31, an
//! integer square root to ±0.51, and the few `f32` conversions the Newton steps need.
//!
//! Invariants: no panics, no loops in the hot path (one bounded loop in the software
//! square root of exotic hosts), no `f64`; every result is within the bound stated on
//! its function and bit-identical on the MCU and the host: `f32` appears only where
//! IEEE 754 fixes the result (conversions, +, ×, ÷ and a correctly rounded square root,
//! never fused), and `.ci/m4count.py` checks emulated Cortex-M4 results against the
//! host's. Each function is a few dozen Cortex-M4 instructions: `SMMULR`/`SMMLAR`,
//! `SMULL`/`SMLAL`/`UMULL`, 64-bit adds and shifts, a handful of `VCVT`/`VMUL`, one
//! `VSQRT` and one `VDIV` in the square root.
//!
//! Sources: the polynomial coefficients are least-squares fits on Chebyshev nodes of
//! (sin x − x)/x³ and (cos x − 1)/x² in x² over |x| ≤ π/4 (fit residual 2.5e-12 and
//! 5.6e-11), rounded to the fixed-point format of each Horner stage; the square root is
//! one Newton step x₁ = x₀ + (N − x₀²)/(2x₀) from the `f32` root, with the residual
//! N − x₀² exact in 64-bit integers.

/// Q31 one, as `f32` (sine and cosine come as `i32` with 2^31 = 1.0, saturated at
/// 1 − 2^-31).
pub const ONE_Q31: f32 = 2_147_483_648.0;

/// Nanodegrees per radian, 180e9/π, rounded.
pub const NDEG_PER_RAD: i64 = 57_295_779_513;

// n° → Q31 radians for |r| ≤ 45°: x = r·K / 2^36, K = round(π/180e9 · 2^67) (K's
// relative error 2e-10, i.e. ≤ 1.5e-10 rad at π/4).
const RAD_K: u64 = 2_575_651_363;
/// Polynomial coefficients: sin x = x + x·x²·(A3 + x²·(A5 + x²·(A7 + x²·A9))) with
/// A3..A9 in Q33, Q34, Q35, Q36, and cos x = 1 + x²·(B2 + x²·(B4 + x²·(B6 + x²·B8)))
/// with B2..B8 in Q32, Q33, Q34, Q35. Order: A9 A7 A5 A3 B8 B6 B4 B2. A table read
/// with volatile loads: one `LDR` each instead of a `MOVW`/`MOVT` pair.
static COEFFS: [i32; 8] = [
    186_630,
    -6_816_635,
    143_165_487,
    -1_431_655_762,
    838_007,
    -23_857_251,
    357_913_564,
    -2_147_483_636,
];

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

/// Sine and cosine of `angle` (n°) as Q31 (`(sin, cos)`, 2^31 = 1, saturated at
/// 1 − 2^-31), each within 1.5 · 2^-31 (7.0e-10) of the true value for any `angle`.
///
/// |angle| ≤ 180° needs no division: the quadrant k = round(angle/90°) comes from the
/// top bits (one 32-bit multiply; near a boundary it may pick the neighbour, which only
/// widens the octant by 0.003°), r = angle − k·90° exactly (a table of k·90°); beyond
/// ±180.4° one 64-bit remainder first (a slow path the machines here never take). r becomes Q31 radians
/// by one 32 × 36-bit product, then two degree-9/8 polynomials in Horner form with
/// `SMMULR` steps; k swaps and negates. Budget (measured over 200 000 angles against
/// `f64`): 0.5 LSB output rounding, ≤ 0.8 LSB from the stage roundings and the Q31
/// x² (its error times |d cos/d x²| ≤ ½), < 0.1 LSB fit and angle-conversion error.
#[inline(always)]
pub fn sincos(angle: i64) -> (i32, i32) {
    let mut a = angle;
    // Fast path for |a| < 42·2^32 n° (180.4°): a test of the high word only.
    if ((a >> 32) as i32).wrapping_add(42) as u32 >= 84 {
        a = reduce_turns(a);
    }
    // k = floor((a/2^20 + 45°/2^20) / (90°/2^20)) ∈ −2..=2.
    let t = (a >> 20) as i32 + 42_915;
    let k = ((t as i64 * 50_041) >> 32) as i32;
    let (s, c) = sincos_octant(a.wrapping_sub(QUARTERS[(k + 2) as usize & 7]));
    let (s, c) = if k & 1 != 0 { (c, s) } else { (s, c) };
    let s = if k & 2 != 0 { -s } else { s };
    let c = if (k + 1) & 2 != 0 { -c } else { c };
    (s, c)
}

/// k·90° for k = −2..=2 at index k + 2 (n°); padded to 8 entries so the index needs
/// no bounds check.
static QUARTERS: [i64; 8] = [-180 * DEG, -90 * DEG, 0, 90 * DEG, 180 * DEG, 0, 0, 0];

/// `a` reduced to [−180°, 180°] (n°): the slow path of [`sincos`].
#[cold]
#[inline(never)]
fn reduce_turns(a: i64) -> i64 {
    let r = a % (360 * DEG);
    if r > 180 * DEG {
        r - 360 * DEG
    } else if r < -180 * DEG {
        r + 360 * DEG
    } else {
        r
    }
}

/// `sincos` for |r| ≤ 45.003° (n°), Q31.
#[inline(always)]
fn sincos_octant(r: i64) -> (i32, i32) {
    // r·K split in 32-bit halves: |r >> 32| ≤ 11, so both partial products fit.
    let lo = ((r as u32 as u64 * RAD_K) >> 32) as i64;
    let hi = (r >> 32) * RAD_K as i64;
    let x = shr_round(hi + lo, 4) as i32; // Q31 radians, |x| ≤ 0.786
    let x2 = mulhr(x, x) << 1; // Q31 (to 2^-31: one SMMULR)
    let c = COEFFS.as_ptr();
    // SAFETY: reads of an initialised static, in bounds, through an aligned pointer.
    let [a9, a7, a5, a3, b8, b6, b4, b2] = unsafe {
        [
            c.read_volatile(),
            c.add(1).read_volatile(),
            c.add(2).read_volatile(),
            c.add(3).read_volatile(),
            c.add(4).read_volatile(),
            c.add(5).read_volatile(),
            c.add(6).read_volatile(),
            c.add(7).read_volatile(),
        ]
    };
    let t = mulhr(x2, a9) + a7;
    let t = mulhr(x2, t) + a5;
    let t = mulhr(x2, t) + a3;
    let s = x + mulhr(x, mulhr(x2, t)); // x + x·x²·(…), the last factor Q32
    let t = mulhr(x2, b8) + b6;
    let t = mulhr(x2, t) + b4;
    let t = mulhr(x2, t) + b2; // > −2^31: B2 plus a positive term
    let y = mulhr(x2, t); // x²·(…) ≤ 0, Q31
                          // 1 + y, saturated at 2^31 − 1 when y = 0.
    let c = i32::MAX + y + ((y as u32) >> 31) as i32;
    (s, c)
}

pub use crate::math::{i64_to_f32, u64_to_f32};

/// Nearest `i64` of `v`, saturating at ±2^31 (Newton steps are clamped there).
#[inline(always)]
pub fn round_f32(v: f32) -> i64 {
    (v + 0.5f32.copysign(v)) as i32 as i64
}

/// `√n` to the nearest integer or, within 0.51, its neighbour: |isqrt(n) − √n| ≤ 0.51
/// for every n (exact for n < 2^24).
///
/// An `f32` estimate from below: x₀ = ⌊√v·(1 − 2^-20)⌋ ≤ √n with v = n rounded to
/// `f32` and the correctly rounded single-precision root (`VSQRT.F32` on the MCU; the
/// factor outweighs the 1.3e-7 of the two roundings). Then one Newton step with the
/// residual n − x₀² ≥ 0 exact in 64 bits, x₁ = x₀ + (n − x₀²)/(2√v), rounded: its error
/// is (√n − x₀)²/(2√n) + 1e-7·(√n − x₀) < 0.003 for √n < 2^32.
#[inline(always)]
pub fn isqrt(n: u64) -> u64 {
    let v = u64_to_f32(n);
    let s = sqrt_f32(v);
    let x0 = (s * (1.0 - 1.0 / 1_048_576.0)) as u32 as u64;
    let d0 = n.wrapping_sub(x0 * x0);
    x0 + (u64_to_f32(d0) / (s + s) + 0.5) as u32 as u64 // 0/0 = NaN → 0 for n = 0
}

/// `u128` to `f32` without a library call (relative error ≤ 2^-22).
#[inline]
pub fn u128_to_f32(v: u128) -> f32 {
    u64_to_f32((v >> 64) as u64) * 18_446_744_073_709_551_616.0 + u64_to_f32(v as u64)
}

/// `√n` within 0.6 for n < 2^74, as [`isqrt`] but with 128-bit residuals: for the
/// forward kinematics' fine residuals (in 1/16 nm), not the hot path.
#[inline]
pub fn isqrt_wide(n: u128) -> u64 {
    let v = u128_to_f32(n);
    let s = sqrt_f32(v);
    let x0 = (s * (1.0 - 1.0 / 1_048_576.0)) as u64;
    let d0 = n.wrapping_sub(x0 as u128 * x0 as u128);
    x0 + (u128_to_f32(d0) / (s + s) + 0.5) as u64
}

/// Correctly rounded single-precision square root of `v` ≥ 0: `VSQRT.F32`.
///
/// Rust's `asm!` offers no register class for a single-precision-only FPU, so the value
/// goes through a core register and `s0`, which is saved and restored around it.
#[cfg(all(target_arch = "arm", target_abi = "eabihf"))]
#[inline(always)]
pub fn sqrt_f32(v: f32) -> f32 {
    let mut bits = v.to_bits();
    // SAFETY: the hard-float ABI guarantees the FPU; the asm saves and restores the
    // only FPU register it uses and touches no memory but its own stack slot.
    unsafe {
        core::arch::asm!(
            "vpush {{s0}}",
            "vmov s0, {b}",
            "vsqrt.f32 s0, s0",
            "vmov {b}, s0",
            "vpop {{s0}}",
            b = inout(reg) bits,
            options(nomem, preserves_flags),
        );
    }
    f32::from_bits(bits)
}

/// Correctly rounded single-precision square root of `v` ≥ 0 (`SQRTSS`): the same
/// IEEE 754 result as the MCU's `VSQRT.F32`.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub fn sqrt_f32(v: f32) -> f32 {
    use core::arch::x86_64::{_mm_cvtss_f32, _mm_set_ss, _mm_sqrt_ss};
    // SAFETY: SSE is part of the x86-64 baseline.
    unsafe { _mm_cvtss_f32(_mm_sqrt_ss(_mm_set_ss(v))) }
}

/// Correctly rounded single-precision square root of `v` ≥ 0 (`FSQRT`).
#[cfg(target_arch = "aarch64")]
#[inline(always)]
pub fn sqrt_f32(v: f32) -> f32 {
    let r: f32;
    // SAFETY: FSQRT reads and writes only the named registers.
    unsafe {
        core::arch::asm!("fsqrt {0:s}, {1:s}", out(vreg) r, in(vreg) v,
            options(pure, nomem, nostack, preserves_flags));
    }
    r
}

/// Correctly rounded single-precision square root of `v` ≥ 0 for targets without one
/// of the instructions above.
#[cfg(not(any(
    all(target_arch = "arm", target_abi = "eabihf"),
    target_arch = "x86_64",
    target_arch = "aarch64"
)))]
pub fn sqrt_f32(v: f32) -> f32 {
    sqrt_f32_soft(v)
}

/// Correctly rounded single-precision square root of a finite `v` ≥ 0 in integer
/// arithmetic (a bounded bit-by-bit root; no hot path uses it).
pub fn sqrt_f32_soft(v: f32) -> f32 {
    let bits = v.to_bits();
    let exp = (bits >> 23) as i32;
    if bits == 0 || exp == 0xff || bits >> 31 != 0 {
        return v; // 0, and out-of-domain inputs passed through
    }
    // v = m·2^e with m an integer below 2^24 (subnormals: exponent field 0).
    let (mut m, mut e) = if exp == 0 {
        ((bits & 0x7f_ffff) as u64, -149)
    } else {
        (((bits & 0x7f_ffff) | 0x80_0000) as u64, exp - 150)
    };
    while m < 1 << 23 {
        m <<= 1;
        e -= 1;
    }
    if e & 1 != 0 {
        m <<= 1;
        e -= 1;
    }
    // √(m·2^e) = √(m·2^26)·2^((e − 26)/2); √(m·2^26) has 25 or 26 bits.
    let n = m << 26;
    let mut r = 0u64;
    for bit in (0..32).rev() {
        let t = r | 1 << bit;
        if t * t <= n {
            r = t;
        }
    }
    // Round r (25 or 26 bits) to 24 significant bits, to nearest, exactly: up iff
    // √n ≥ (q + ½)·2^shift, i.e. 4n ≥ ((2q + 1)·2^shift)² (never equal for a root of a
    // float).
    let shift = 40 - r.leading_zeros();
    let mut q = r >> shift;
    let b = (2 * q + 1) << shift;
    if 4 * n >= b * b {
        q += 1;
    }
    let mut exp_out = (e - 26) / 2 + shift as i32 + 150;
    if q == 1 << 24 {
        q >>= 1;
        exp_out += 1;
    }
    f32::from_bits(((exp_out as u32) << 23) | (q as u32 & 0x7f_ffff))
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
    fn sine_and_cosine_are_within_7e_10_everywhere() {
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
        // around every quadrant boundary, where the reduction may pick either side
        for k in -4..=4 {
            for d in (-(3 << 20)..(3 << 20)).step_by(1 << 16) {
                angles.push(k * 45 * DEG + d);
            }
        }
        for a in angles {
            let (s, c) = sincos(a);
            // Reference: reduce exactly in integers first, then f64 (error ~1e-16).
            let r = (a % (360 * DEG)) as f64 / DEG as f64;
            let x = r.to_radians();
            let es = (s as f64 / ONE_Q31 as f64 - x.sin()).abs();
            let ec = (c as f64 / ONE_Q31 as f64 - x.cos()).abs();
            worst = worst.max(es).max(ec);
        }
        assert!(worst < 7.0e-10, "worst sin/cos error {worst:e}");
    }

    #[test]
    fn the_square_root_is_within_0_51_of_the_true_root() {
        for n in 0..1u64 << 16 {
            let r = n.isqrt();
            assert_eq!(isqrt(n), if n - r * r > r { r + 1 } else { r }, "{n}");
        }
        let mut seed = 11;
        let mut cases: Vec<u64> = (0..70_000).collect();
        for k in 1..64 {
            let p = 1u64 << k;
            cases.extend([p - 1, p, p + 1]);
        }
        for r in [1u64 << 31, (1 << 32) - 2, 123_456_789, 2_200_000_000] {
            cases.extend([r * r, r * r - r, r * r - r + 1, r * r + r, r * r + r + 1]);
        }
        for _ in 0..300_000 {
            let v = lcg(&mut seed);
            cases.push(v >> (v % 61));
        }
        let mut worst = 0.0f64;
        for n in cases {
            if n >= u64::MAX - (1 << 33) {
                continue;
            }
            let r = isqrt(n);
            // Exact: |r − √n| ≤ e ⟺ (r − e)² ≤ n ≤ (r + e)², checked in u128 with
            // e = 51/100, scaled by 100².
            let (r100, n1e4) = (r as u128 * 100, n as u128 * 10_000);
            let bound = 51;
            let lo = r100.saturating_sub(bound);
            assert!(
                lo * lo <= n1e4 && n1e4 <= (r100 + bound).pow(2),
                "n = {n}: {r}"
            );
            worst = worst.max((r as f64 - (n as f64).sqrt()).abs());
        }
        assert!(worst < 0.51, "{worst}");
    }

    #[test]
    fn the_wide_square_root_is_within_0_6_below_2_74() {
        let mut seed = 3;
        for _ in 0..100_000 {
            let n = ((lcg(&mut seed) as u128) << 64 | lcg(&mut seed) as u128)
                >> (54 + lcg(&mut seed) % 60);
            let r = isqrt_wide(n) as f64;
            let want = (n as f64).sqrt();
            assert!((r - want).abs() <= 0.6 + want * 1e-15, "{n}: {r} vs {want}");
        }
    }

    #[test]
    fn the_single_precision_roots_are_correctly_rounded() {
        let mut seed = 5;
        let mut values = vec![
            0.0f32,
            1.0,
            2.0,
            3.0,
            4.0,
            0.25,
            1e-40,
            3.4e38,
            f32::MIN_POSITIVE,
        ];
        for _ in 0..200_000 {
            values.push(f32::from_bits((lcg(&mut seed) >> 33) as u32 & 0x7f7f_ffff));
        }
        for v in values {
            let want = v.sqrt();
            assert_eq!(sqrt_f32(v).to_bits(), want.to_bits(), "{v:e}");
            assert_eq!(sqrt_f32_soft(v).to_bits(), want.to_bits(), "{v:e}");
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
        assert_eq!(sincos(0), (0, i32::MAX));
        assert_eq!(sincos(90 * DEG), (i32::MAX, 0));
    }
}
