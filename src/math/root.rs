//! Square roots: integer roots to ±0.51 ([`isqrt`], [`isqrt_wide`]) on top of the
//! correctly rounded single-precision root ([`sqrt_f32`]), and the exact floor root
//! [`isqrt_floor`] for code off the hot path.
//!
//! Invariants: no panics, no loops in the hot path (one bounded loop in the software
//! square root of exotic hosts), no `f64`; every result is within the bound stated on
//! its function and bit-identical on the MCU and the host: `f32` appears only where
//! IEEE 754 fixes the result (conversions, +, ×, ÷ and a correctly rounded square root,
//! never fused). [`isqrt`] is a few dozen Cortex-M4 instructions, one `VSQRT` and one
//! `VDIV` among them.
//!
//! Sources: the integer root is one Newton step x₁ = x₀ + (N − x₀²)/(2x₀) from the
//! `f32` root, with the residual N − x₀² exact in 64-bit integers.

use super::u64_to_f32;

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

/// ⌊√x⌋, exact (Newton's iteration from above; a loop, for code off the hot path).
pub fn isqrt_floor(x: u128) -> u128 {
    if x < 2 {
        return x;
    }
    // Newton from above converges monotonically.
    let mut r = 1u128 << (128 - x.leading_zeros()).div_ceil(2);
    loop {
        let next = (r + x / r) / 2;
        if next >= r {
            return r;
        }
        r = next;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::lcg;

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
    fn the_integer_square_root_is_exact() {
        for x in [
            0u128,
            1,
            2,
            3,
            4,
            15,
            16,
            17,
            1 << 70,
            (1 << 70) - 1,
            u64::MAX as u128,
        ] {
            let r = isqrt_floor(x);
            assert!(r * r <= x && (r + 1) * (r + 1) > x, "{x}: {r}");
        }
    }
}
