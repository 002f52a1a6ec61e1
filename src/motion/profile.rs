//! Speed profile of one block: accelerate or decelerate from the entry speed toward the
//! cruise speed, cruise, then decelerate to the exit speed, with one acceleration A.
//!
//! Source: seeds-digest A's three-phase move (A for dt1, V for dt2, −A for dt3, with
//! ds1 = A·dt1²/2, ds3 = V²/(2A), ds2 = S − ds1 − ds3), generalised to non-zero entry
//! and exit speeds for look-ahead, and to a first phase that decelerates when the block
//! is entered faster than its cruise speed (after a feed-override drop or a hold).
//!
//! Representation (all fixed point, chosen here once): time in ticks Q32.32 (`i64`),
//! speed in nm/tick Q32.32, acceleration in nm/tick² Q24.40 (fine enough that a·t²/2
//! stays exact to 10⁻⁴ nm over ten thousand ticks), distance in nm Q47.16.
//!
//! Planning the phases uses `f32` (the Cortex-M4F's hardware floats: no software
//! `f64`, no division of wide integers) once per block, then fixes the phases up in
//! fixed point so that the profile is continuous whatever the single-precision
//! rounding: the cruise speed is the first phase's end speed (v₀ + a₁·t₁, exact), the
//! exit speed is the cruise speed less the last phase's (v_c − A·t₃, exact), and the
//! cruise time is refined by one correction step until the cruise ends where the last
//! phase begins (to a fraction of a nanometre). Evaluating a tick uses integer
//! multiplies only. The last phase is evaluated backwards from the block's end
//! (s = S − (v₁·r + A·r²/2), r the time left), so the block ends exactly at S.
//!
//! Sampling a continuous profile whose speed changes at most A per unit time gives
//! per-tick speed differences of at most A·T (each tick's displacement is the integral
//! of the speed over the tick), so the discrete motion keeps the limits too.

use crate::math::{f32_to_i64, f32_to_q32, fmax, fmin, i64_to_f32, sqrtf};

/// One tick in Q32.32.
pub const TICK_Q32: i64 = 1 << 32;
/// A cruise that never ends: the block is held at rest (feed hold).
pub const HELD: i64 = i64::MAX / 4;

/// 2³² and 2¹⁶ as `f32` (exact).
const Q32F: f32 = 4_294_967_296.0;
const Q16F: f32 = 65_536.0;

/// Converts a speed or time in `f32` to Q32.32 (saturating; NaN gives 0).
#[inline(always)]
pub fn to_q32(v: f32) -> i64 {
    f32_to_q32(v)
}

/// Converts Q32.32 to `f32`.
#[inline(always)]
pub fn from_q32(v: i64) -> f32 {
    i64_to_f32(v) * (1.0 / Q32F)
}

/// Converts an acceleration in `f32` to Q24.40 (saturating).
#[inline(always)]
pub fn to_q40(a: f32) -> i64 {
    f32_to_q32(a * 256.0)
}

/// `v·t + a·t²/2` for Q32.32 `v` and `t` and Q24.40 `a`; result in nm Q16. Not
/// inlined: the planner's fix-ups call it several times (flash).
#[inline(never)]
fn distance(v: i64, t: i64, a: i64) -> i64 {
    if t == 0 {
        // A phase that does not exist (a cruise block has two).
        return 0;
    }
    // The mean speed over the phase, v + a·t/2 (Q32; a speed, so it fits an i64),
    // times t: two 64 × 64 → 128-bit products. The mean speed is truncated to 2⁻³² nm
    // per tick: over ten thousand ticks, 2·10⁻⁶ nm.
    let mean = v + ((a as i128 * t as i128) >> 41) as i64;
    ((mean as i128 * t as i128) >> 48) as i64
}

/// Time (ticks Q32) to cover `rem` (nm Q16) at `vc` (nm/tick Q32): a single-precision
/// estimate, then its error, measured exactly, corrected (0 when either is not
/// positive).
fn cruise_ticks(rem: i64, vc: i64) -> i64 {
    if rem <= 0 || vc <= 0 {
        return 0;
    }
    // Ticks Q32 per nm at the cruise speed.
    let inv_vc = Q32F / from_q32(vc);
    let est = f32_to_i64(i64_to_f32(rem) * (1.0 / Q16F) * inv_vc);
    let err = rem - ((vc as i128 * est as i128) >> 48) as i64;
    (est + f32_to_i64(i64_to_f32(err) * (1.0 / Q16F) * inv_vc)).max(0)
}

/// A planned profile over `length` nm.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Profile {
    /// Entry speed, nm/tick Q32.
    pub v0: i64,
    /// Signed acceleration of the first phase, nm/tick² Q24.40.
    pub a1: i64,
    /// Duration of the first phase, ticks Q32.
    pub t1: i64,
    /// Cruise speed, nm/tick Q32.
    pub vc: i64,
    /// Duration of the cruise, ticks Q32 ([`HELD`]: forever).
    pub t2: i64,
    /// Exit speed, nm/tick Q32.
    pub v1: i64,
    /// Deceleration of the last phase (positive), nm/tick² Q24.40.
    pub a3: i64,
    /// Duration of the last phase, ticks Q32.
    pub t3: i64,
    /// Distance covered by the first phase, nm Q16.
    pub s1: i64,
    /// Length, nm Q16.
    pub length: i64,
}

/// Speeds a profile was asked for and what it achieved, nm/tick.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Achieved {
    /// Exit speed actually reached (higher than asked when the block is too short to
    /// slow down, lower when too short to speed up).
    pub exit: f32,
}

impl Profile {
    /// [`Profile::plan`] written into `self` (the controller keeps its profile in
    /// place).
    #[inline(always)]
    pub fn plan_into(&mut self, length_q16: i64, v0: f32, v_max: f32, v1: f32, a: f32) -> Achieved {
        let (p, got) = Self::plan(length_q16, v0, v_max, v1, a);
        *self = p;
        got
    }

    /// A profile that does nothing (a placeholder to plan into).
    pub const IDLE: Profile = Profile {
        v0: 0,
        a1: 0,
        t1: 0,
        vc: 0,
        t2: 0,
        v1: 0,
        a3: 0,
        t3: 0,
        s1: 0,
        length: 0,
    };

    /// Plans a profile over `length_q16` (nm Q16, exact: the profile ends there) from
    /// `v0` toward `v_max`, leaving at `v1`, with acceleration `a` (speeds nm/tick,
    /// accel nm/tick², all ≥ 0, `a` > 0). `v_max` = 0 with `v1` = 0 means "stop as
    /// soon as possible and hold" when `v0` > 0.
    #[inline(always)]
    pub fn plan(length_q16: i64, v0: f32, v_max: f32, v1: f32, a: f32) -> (Profile, Achieved) {
        let length_q16 = length_q16.max(0);
        let a = fmax(a, 1e-12);
        let (v0, v_max, v1) = (fmax(v0, 0.0), fmax(v_max, 0.0), fmax(v1, 0.0));
        if v0 > 0.0 && v0 == v_max && v1 >= v0 {
            // Entered at the cap and free to leave at it: a cruise throughout (what the
            // general case below gives, bit for bit, without its square roots; the
            // common case of dense short blocks at the programmed feed).
            let (a_q, vc) = (to_q40(a), to_q32(v0));
            let p = Profile {
                v0: vc,
                a1: a_q,
                t1: 0,
                vc,
                t2: cruise_ticks(length_q16, vc).min(HELD),
                v1: vc,
                a3: a_q,
                t3: 0,
                s1: 0,
                length: length_q16,
            };
            return (p, Achieved { exit: from_q32(vc) });
        }
        Self::plan_general(length_q16, v0, v_max, v1, a)
    }

    /// [`Profile::plan`] without its cruise shortcut (arguments already clamped).
    #[inline(always)]
    fn plan_general(length_q16: i64, v0: f32, v_max: f32, v1: f32, a: f32) -> (Profile, Achieved) {
        let length = i64_to_f32(length_q16) * (1.0 / Q16F);
        let mut v1 = v1;
        let two_a_s = 2.0 * a * length;
        // Exit speed the block can reach at all from v0 over its length.
        let reach_hi = sqrtf(v0 * v0 + two_a_s);
        let reach_lo = sqrtf(fmax(v0 * v0 - two_a_s, 0.0));
        v1 = fmin(fmax(fmin(v1, v_max), reach_lo), reach_hi);
        let a_q = to_q40(a);
        let v0_q = to_q32(v0);
        if v_max <= 0.0 && v1 <= 0.0 && v0 * v0 < two_a_s {
            // Decelerate to rest inside the block and stay there.
            let t1 = to_q32(v0 / a);
            let p = Profile {
                v0: v0_q,
                a1: -a_q,
                t1,
                vc: 0,
                t2: HELD,
                v1: 0,
                a3: a_q,
                t3: 0,
                s1: distance(v0_q, t1, -a_q),
                length: length_q16,
            };
            return (p, Achieved { exit: 0.0 });
        }
        // Highest speed reachable between v0 and v1 over the length, a hair under
        // (10⁻⁶) so that single-precision rounding leaves the ramps a little room
        // rather than overlapping them.
        let peak = sqrtf(fmax((two_a_s + v0 * v0 + v1 * v1) / 2.0, 0.0)) * (1.0 - 1e-6);
        let top = if v0 > v_max {
            fmax(v_max, v1)
        } else {
            fmax(fmax(fmin(peak, v_max), v0), v1)
        };
        let first = (top * top - v0 * v0).abs() / (2.0 * a);
        let last = (top * top - v1 * v1) / (2.0 * a);
        let (a1, t1, t3) = if first + last <= length {
            let a1 = if top >= v0 { a_q } else { -a_q };
            // A hair short (the quotient's rounding is within 2⁻²²), so that the first
            // phase never ends beyond the top speed.
            let t1 = to_q32((top - v0).abs() / a * (1.0 - 3e-7));
            (a1, t1, to_q32(fmax(top - v1, 0.0) / a))
        } else if v1 > v0 {
            // Too short to reach v1 and come back: accelerate throughout, over a hair
            // less than the length (the rest is a cruise at the exit speed), the time
            // from the form without cancellation: (v1 − v0)/a = 2·s/(v0 + v1).
            let gain = two_a_s * (1.0 - 2e-6);
            let v1 = fmin(v1, sqrtf(v0 * v0 + gain));
            let s = fmin((v1 * v1 - v0 * v0) / (2.0 * a), gain / (2.0 * a));
            (a_q, to_q32(2.0 * fmax(s, 0.0) / fmax(v0 + v1, 1e-30)), 0)
        } else {
            // Entered too fast to reach v_max and then v1: decelerate throughout, over
            // a hair less than the length (the rest is a cruise at v0), the time from
            // the form without cancellation: (v0 − v1)/a = 2·s/(v0 + v1).
            let shed = two_a_s * (1.0 - 2e-6);
            let v1 = fmax(v1, sqrtf(fmax(v0 * v0 - shed, 0.0)));
            let s = fmin((v0 * v0 - v1 * v1) / (2.0 * a), shed / (2.0 * a));
            (0, 0, to_q32(2.0 * fmax(s, 0.0) / fmax(v0 + v1, 1e-30)))
        };
        Self::assemble(length_q16, v0_q, (a1, t1), t3, a)
    }

    /// The profile of phases planned in single precision (first phase `a1` for `t1`
    /// from `v0_q`, last phase `t3` at `a`), made continuous in fixed point.
    #[inline(always)]
    fn assemble(
        length_q16: i64,
        v0_q: i64,
        (a1, t1): (i64, i64),
        t3: i64,
        a: f32,
    ) -> (Profile, Achieved) {
        let a_q = to_q40(a);
        // Continuity in fixed point: the cruise speed is where the first phase ends,
        // the exit where the last phase, run backwards from the cruise, ends.
        let vc = v0_q + ((a1 as i128 * t1 as i128) >> 40) as i64;
        let mut t3 = t3;
        let mut v1_q = vc - ((a_q as i128 * t3 as i128) >> 40) as i64;
        if v1_q < 0 {
            // Rounding overshot the stop: the last phase ends exactly at rest.
            t3 = to_q32(from_q32(vc) / a);
            v1_q = (vc - ((a_q as i128 * t3 as i128) >> 40) as i64).max(0);
        }
        let s1 = distance(v0_q, t1, a1);
        let mut s3 = distance(v1_q, t3, a_q);
        let mut rem = length_q16 - s1 - s3;
        // Ramps that overlap by rounding (a difference of nearly equal speeds): a
        // Newton step on the last phase's time, at fixed cruise speed (ds₃/dt₃ = v₁),
        // lands just short of the overlap, since s₃(t₃) is concave.
        // With no last phase to shorten, the same on the first phase's time
        // (ds₁/dt₁ = v_c; the exit is then the new cruise speed).
        // A last phase that ends at or near rest is at its longest (ds₃/dt₃ = v₁ ≈ 0):
        // there the step would throw it away and leave the block at its cruise speed,
        // so it stops instead, a hair harder than `a` over the room the first phase
        // leaves (the overlap is a rounding's, so the rise is of the order of 10⁻⁶).
        let (mut t1, mut vc, mut s1, mut a3) = (t1, vc, s1, a_q);
        for _ in 0..3 {
            if rem >= 0 {
                break;
            }
            let over = i64_to_f32(rem) * (1.0 / Q16F);
            let shortened = (v1_q > 0 && t3 > 0)
                .then(|| t3 + to_q32(over / from_q32(v1_q)))
                .filter(|&t| t > t3 / 2);
            if let Some(t) = shortened {
                t3 = t;
            } else if let Some((a, t)) = stop_within(length_q16 - s1, vc, a) {
                (a3, t3) = (a, t);
            } else if vc > 0 && t1 > 0 {
                t1 = (t1 + to_q32(over / from_q32(vc))).max(0);
                vc = v0_q + ((a1 as i128 * t1 as i128) >> 40) as i64;
                s1 = distance(v0_q, t1, a1);
            } else {
                break;
            }
            v1_q = (vc - ((a3 as i128 * t3 as i128) >> 40) as i64).max(0);
            s3 = distance(v1_q, t3, a3);
            rem = length_q16 - s1 - s3;
        }
        // The cruise covers what the ramps leave: t2 = rem / vc, refined once so that
        // the cruise ends where the last phase starts (single-precision estimate,
        // then its error, measured exactly, corrected).
        let t2 = cruise_ticks(rem, vc);
        let p = Profile {
            v0: v0_q,
            a1,
            t1,
            vc,
            t2: t2.min(HELD),
            v1: v1_q,
            a3,
            t3,
            s1,
            length: length_q16,
        };
        let exit = from_q32(v1_q);
        (p, Achieved { exit })
    }

    /// Total duration, ticks Q32 (≥ [`HELD`] when held).
    pub fn duration(&self) -> i64 {
        self.t1.saturating_add(self.t2).saturating_add(self.t3)
    }

    /// Distance (nm Q16, ≤ length) and speed (nm/tick Q32) at time `t` (ticks Q32).
    pub fn at(&self, t: i64) -> (i64, i64) {
        let t = t.max(0);
        if self.t2 != HELD && t >= self.duration() {
            return (self.length, self.v1);
        }
        if t <= self.t1 {
            let s = distance(self.v0, t, self.a1);
            let v = self.v0 + ((self.a1 as i128 * t as i128) >> 40) as i64;
            return (s.min(self.length), v);
        }
        let end_cruise = self.t1.saturating_add(self.t2);
        if t <= end_cruise {
            let s = self.s1 + (((self.vc as i128) * ((t - self.t1) as i128)) >> 48) as i64;
            return (s.min(self.length), self.vc);
        }
        let left = (self.duration() - t).max(0);
        let s = self.length - distance(self.v1, left, self.a3);
        let v = self.v1 + ((self.a3 as i128 * left as i128) >> 40) as i64;
        (s.clamp(0, self.length), v)
    }
}

/// The deceleration (nm/tick² Q24.40) and time (ticks Q32) that bring `vc` (nm/tick
/// Q32) to rest within `room` (nm Q16), a hair short of it, when that is at most 10⁻⁴
/// above `a` (nm/tick²); `None` otherwise.
#[inline(always)]
fn stop_within(room: i64, vc: i64, a: f32) -> Option<(i64, i64)> {
    let (room, v) = (i64_to_f32(room) * (1.0 / Q16F), from_q32(vc));
    if room <= 0.0 || v <= 0.0 {
        return None;
    }
    let need = v * v / (2.0 * room) * (1.0 + 2e-6);
    (need <= a * (1.0 + 1e-4)).then(|| (to_q40(need), to_q32(v / need)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn q32(v: i64) -> f64 {
        v as f64 / 4_294_967_296.0
    }

    /// Samples positions (nm) every tick until the profile ends (or `max` ticks), then
    /// two ticks more of the continuation at the exit speed.
    fn samples(p: &Profile, max: i64) -> Vec<f64> {
        let end = (p.duration() >> 32) + 2;
        (0..=end.min(max))
            .map(|k| {
                let t = k << 32;
                let over = q32((t - p.duration()).max(0)) * q32(p.v1);
                p.at(t).0 as f64 / 65_536.0 + over
            })
            .collect()
    }

    #[test]
    fn the_cruise_shortcut_gives_the_general_plan_bit_for_bit() {
        let mut x = 0x2545_F491u32;
        let mut rnd = move || {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            x
        };
        for _ in 0..100_000 {
            let v = (rnd() % 2_000_000) as f32 / 7.0 + 0.001;
            let length = (rnd() % 50_000_000) as i64 * (1 + (rnd() % 3) as i64 * 1000);
            let v1 = v * (1.0 + (rnd() % 4) as f32 * 0.3);
            let a = (rnd() % 10_000) as f32 / 1000.0 + 1e-4;
            assert_eq!(
                Profile::plan(length, v, v, v1, a),
                Profile::plan_general(length, v, v, v1, a),
                "{length} {v} {v1} {a}"
            );
        }
    }

    #[test]
    fn a_rest_to_rest_move_reaches_cruise_and_ends_exactly() {
        // 100 mm at 50 mm/s (50 000 nm/tick), 500 mm/s² (500 nm/tick²).
        let (p, got) = Profile::plan(100_000_000 << 16, 0.0, 5e4, 0.0, 500.0);
        assert_eq!(got.exit, 0.0);
        assert_eq!(p.at(p.duration()).0, p.length);
        assert_eq!(p.at(p.duration() + TICK_Q32).0, p.length);
        // Single-precision planning: within a microsecond.
        assert!(
            (q32(p.duration()) - 2100.0).abs() < 1e-3,
            "{}",
            q32(p.duration())
        );
    }

    #[test]
    fn a_hold_stops_inside_the_block_and_stays() {
        let (p, _) = Profile::plan(100_000_000 << 16, 5e4, 0.0, 0.0, 500.0);
        assert_eq!(p.t2, HELD);
        let (s, v) = p.at(200 * TICK_Q32);
        assert_eq!(v, 0);
        assert!((s as f64 / 65_536.0 - 2.5e6).abs() < 1.0, "stopped at {s}");
        assert_eq!(p.at(100_000 * TICK_Q32).0, s);
    }

    #[test]
    fn a_block_entered_right_at_its_stopping_reach_stops_at_its_end() {
        // Session 27's circle: the host planned its last curve's entry at exactly the
        // speed it can stop from over its length (v₀² = 2·a·S in single precision), and
        // the fix-up of the ramps' rounding dropped the last phase: it ran out at
        // 98.65 mm/s and stopped in a tick.
        let (p, got) = Profile::plan(5_650_540 << 16, 98_653.55, 99_987.586, 0.0, 861.2028);
        assert!(got.exit < 1.0, "left at {} nm/tick", got.exit);
        assert_eq!(p.at(p.duration()).0, p.length);
        let x = samples(&p, 1_000);
        for w in x.windows(3) {
            let dv = (w[2] - 2.0 * w[1] + w[0]).abs();
            assert!(dv <= 861.2028 * (1.0 + 1e-4) + 2e-3, "accel {dv}");
        }
        // Across the neighbourhood of that speed, a stop asked for is a stop.
        for k in -2000..2000 {
            let v0 = 98_653.55 * (1.0 + k as f32 * 1e-8);
            let (_, got) = Profile::plan(5_650_540 << 16, v0, 99_987.586, 0.0, 861.2028);
            let reach = (v0 as f64).powi(2) - 2.0 * 861.2028 * 5_650_540.0;
            assert!(
                (got.exit as f64) <= reach.max(0.0).sqrt() * 1.01 + 1.0,
                "from {v0}: left at {}",
                got.exit
            );
        }
    }

    #[test]
    fn a_block_too_short_to_slow_down_reports_its_real_exit_speed() {
        let (p, got) = Profile::plan(1_000_000 << 16, 5e4, 5e4, 0.0, 500.0);
        assert!(got.exit > 0.0);
        assert_eq!(p.at(p.duration()).0, p.length);
    }

    proptest! {
        #[test]
        fn speed_and_acceleration_stay_within_limits_and_the_end_is_exact(
            length in 1.0f64..2e9, v0 in 0.0f64..2e5, vmax in 1.0f64..2e5, v1 in 0.0f64..2e5,
            a in 0.5f64..2000.0,
        ) {
            // The profile plans in single precision: check it against what it was given.
            let [v0, vmax, v1, a] = [v0, vmax, v1, a].map(|x| x as f32);
            let (p, got) = Profile::plan((length * 65_536.0) as i64, v0, vmax, v1, a);
            let [v0, vmax, a] = [v0, vmax, a].map(f64::from);
            prop_assume!(p.duration() < 4_000_000 * TICK_Q32);
            let x = samples(&p, 4_000_000);
            prop_assert_eq!(p.at(p.duration()).0, p.length);
            let top = vmax.max(v0).max(got.exit as f64);
            let mut prev = v0;
            for w in x.windows(2) {
                let v = w[1] - w[0];
                prop_assert!(v >= -1e-3, "moved backwards");
                prop_assert!(v <= top * (1.0 + 1e-9) + 1e-3, "speed {} > {}", v, top);
                prop_assert!((v - prev).abs() <= a * (1.0 + 1e-6) + 2e-3, "accel {} > {}", v - prev, a);
                prev = v;
            }
        }
    }
}
