//! Sine and cosine in fixed point: [`sincos`] of an angle in n° as Q31, and the two
//! rounding primitives of its Horner stages ([`mulhr`], [`shr_round`]).
//!
//! Invariants: no panics, no loops in the hot path, no `f64`; bit-identical on the MCU
//! and the host (`.ci/m4count.py` checks emulated Cortex-M4 results against the
//! host's). A call is a few dozen Cortex-M4 instructions: `SMMULR`/`SMMLAR`,
//! `SMULL`/`SMLAL`/`UMULL`, 64-bit adds and shifts.
//!
//! Sources: the polynomial coefficients are least-squares fits on Chebyshev nodes of
//! (sin x − x)/x³ and (cos x − 1)/x² in x² over |x| ≤ π/4 (fit residual 2.5e-12 and
//! 5.6e-11), rounded to the fixed-point format of each Horner stage.

/// Q31 one, as `f32` (sine and cosine come as `i32` with 2^31 = 1.0, saturated at
/// 1 − 2^-31).
pub const ONE_Q31: f32 = 2_147_483_648.0;

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::lcg;

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
    fn rounding_shift_rounds_half_up() {
        assert_eq!(shr_round(5, 1), 3);
        assert_eq!(shr_round(-5, 1), -2);
        assert_eq!(shr_round(-6, 1), -3);
        assert_eq!(mulhr(1 << 30, 1 << 30), 1 << 28);
        assert_eq!(sincos(0), (0, i32::MAX));
        assert_eq!(sincos(90 * DEG), (i32::MAX, 0));
    }
}
