//! Per-block trapezoidal speed profile on whole interpolation ticks.
//!
//! Source: seeds-digest A, the three-phase move: constant acceleration A for dt1,
//! constant speed V for dt2, constant deceleration −A for dt3 = dt1, with
//! ds1 = A·dt1²/2, ds3 = V²/(2A) and ds2 = S − ds1 − ds3. Each block starts and ends at
//! rest (look-ahead comes with the planner).
//!
//! Quantisation: the phases are rounded *up* to whole ticks (n1 accelerating, n2
//! cruising, n1 decelerating) and the speed and acceleration are then lowered so that
//! the move covers exactly S: V' = S / ((n1 + n2)·T), A' = V' / (n1·T). Hence V' ≤ V and
//! A' ≤ A exactly, and the distance after tick k is the exact rational S·num(k)/den
//! with den = 2·n1·(n1 + n2):
//!
//! * accelerating, k ≤ n1: num = k²
//! * cruising, n1 ≤ k ≤ n1 + n2: num = n1·(2k − n1)
//! * decelerating, k ≥ n1 + n2: num = den − (K − k)², K = 2·n1 + n2
//!
//! so num(K) = den and the block ends exactly on its end point, in integer arithmetic.

/// A planned trapezoid, in ticks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Trapezoid {
    /// Ticks of acceleration (and of deceleration), ≥ 1.
    pub n_accel: u32,
    /// Ticks of constant speed.
    pub n_cruise: u32,
}

/// Smallest `n` with `n * n >= v`.
fn ceil_sqrt(v: u128) -> u128 {
    let r = v.isqrt();
    if r * r < v {
        r + 1
    } else {
        r
    }
}

impl Trapezoid {
    /// Plans a move of `length` units at speed ≤ `v` units/s and acceleration ≤ `a`
    /// units/s², with `tick_hz` ticks per second. `length`, `v` and `a` must be > 0.
    pub fn plan(length: u64, v: u64, a: u64, tick_hz: u32) -> Self {
        let (s, v, a, f) = (
            length.max(1) as u128,
            v.max(1) as u128,
            a.max(1) as u128,
            tick_hz as u128,
        );
        if v * v <= s * a {
            // Full speed is reached: n1 ≥ V/(A·T); cruise covers what ramps leave.
            let n1 = (v * f).div_ceil(a).max(1);
            let ramps = v * n1; // distance of both ramps × f
            let n2 = (s * f).saturating_sub(ramps).div_ceil(v);
            Trapezoid {
                n_accel: n1.min(u32::MAX as u128) as u32,
                n_cruise: n2.min(u32::MAX as u128) as u32,
            }
        } else {
            // Triangle: n1·T ≥ sqrt(S/A), so S/(n1·T)² ≤ A.
            let n1 = ceil_sqrt((s * f * f).div_ceil(a)).max(1);
            Trapezoid {
                n_accel: n1.min(u32::MAX as u128) as u32,
                n_cruise: 0,
            }
        }
    }

    /// Ticks the move lasts.
    pub fn ticks(&self) -> u32 {
        2 * self.n_accel + self.n_cruise
    }

    /// Denominator of [`Self::progress`].
    pub fn den(&self) -> u64 {
        2 * self.n_accel as u64 * (self.n_accel as u64 + self.n_cruise as u64)
    }

    /// Numerator of the fraction of the move done after `k` ticks (over [`Self::den`]).
    pub fn progress(&self, k: u32) -> u64 {
        let (n1, n2) = (self.n_accel as u64, self.n_cruise as u64);
        let k = (k as u64).min(2 * n1 + n2);
        if k <= n1 {
            k * k
        } else if k <= n1 + n2 {
            n1 * (2 * k - n1)
        } else {
            let r = 2 * n1 + n2 - k;
            self.den() - r * r
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Positions after each tick of a move of `s` units.
    fn positions(p: &Trapezoid, s: u64) -> Vec<f64> {
        (0..=p.ticks())
            .map(|k| s as f64 * p.progress(k) as f64 / p.den() as f64)
            .collect()
    }

    #[test]
    fn a_long_move_reaches_full_speed_and_ends_exactly() {
        // 100 mm at 50 mm/s, 500 mm/s², 1 kHz, in nm.
        let p = Trapezoid::plan(100_000_000, 50_000_000, 500_000_000, 1000);
        assert_eq!(p.n_accel, 100);
        assert_eq!(p.n_cruise, 1900);
        assert_eq!(p.progress(p.ticks()), p.den());
    }

    proptest! {
        #[test]
        fn speed_and_acceleration_never_exceed_the_limits(
            s in 1u64..2_000_000_000, v in 1_000u64..500_000_000, a in 10_000u64..20_000_000_000
        ) {
            let f = 1000.0;
            let p = Trapezoid::plan(s, v, a, 1000);
            prop_assert_eq!(p.progress(p.ticks()), p.den());
            let x = positions(&p, s);
            let mut prev_v = 0.0;
            for w in x.windows(2) {
                let vel = (w[1] - w[0]) * f;
                prop_assert!(vel <= v as f64 * (1.0 + 1e-9) + 1e-6, "speed {} > {}", vel, v);
                prop_assert!(((vel - prev_v) * f).abs() <= a as f64 * (1.0 + 1e-9) + 1e-3);
                prev_v = vel;
            }
            // The move ends at rest: the last step's speed change is a deceleration.
            prop_assert!((prev_v * f) <= a as f64 * (1.0 + 1e-9) + 1e-3);
        }
    }
}
