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
//! Planning the phases uses `f64` once per block; evaluating a tick uses integer
//! multiplies only. The last phase is evaluated backwards from the block's end
//! (s = S − (v₁·r + A·r²/2), r the time left), so the block ends exactly at S whatever
//! the rounding of the phase times.
//!
//! Sampling a continuous profile whose speed changes at most A per unit time gives
//! per-tick speed differences of at most A·T (each tick's displacement is the integral
//! of the speed over the tick), so the discrete motion keeps the limits too.

/// One tick in Q32.32.
pub const TICK_Q32: i64 = 1 << 32;
/// A cruise that never ends: the block is held at rest (feed hold).
pub const HELD: i64 = i64::MAX / 4;

/// Converts a speed or time in `f64` to Q32.32, saturating.
pub fn to_q32(v: f64) -> i64 {
    let x = v * 4_294_967_296.0;
    if x >= i64::MAX as f64 {
        i64::MAX
    } else if x <= i64::MIN as f64 {
        i64::MIN
    } else {
        libm::round(x) as i64
    }
}

/// Converts Q32.32 to `f64`.
pub fn from_q32(v: i64) -> f64 {
    v as f64 / 4_294_967_296.0
}

/// Converts an acceleration in `f64` to Q24.40, saturating.
pub fn to_q40(a: f64) -> i64 {
    let x = a * 1_099_511_627_776.0;
    if x >= i64::MAX as f64 {
        i64::MAX
    } else if x <= i64::MIN as f64 {
        i64::MIN
    } else {
        libm::round(x) as i64
    }
}

/// `v·t + a·t²/2` for Q32.32 `v` and `t` and Q24.40 `a`; result in nm Q16.
fn distance(v: i64, t: i64, a: i64) -> i64 {
    let vt = (v as i128 * t as i128) >> 48;
    let at = (a as i128 * t as i128) >> 40;
    let at2 = (at * t as i128) >> 49;
    (vt + at2) as i64
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
    pub exit: f64,
}

impl Profile {
    /// Plans a profile over `length` nm from `v0` toward `v_max`, leaving at `v1`, with
    /// acceleration `a` (speeds nm/tick, accel nm/tick², all ≥ 0, `a` > 0). `v_max`
    /// = 0 with `v1` = 0 means "stop as soon as possible and hold" when `v0` > 0.
    pub fn plan(length: f64, v0: f64, v_max: f64, v1: f64, a: f64) -> (Profile, Achieved) {
        let length = length.max(0.0);
        let a = a.max(1e-12);
        let (v0, v_max) = (v0.max(0.0), v_max.max(0.0));
        let mut v1 = v1.max(0.0);
        // Exit speed the block can reach at all from v0 over its length.
        let reach_hi = libm::sqrt(v0 * v0 + 2.0 * a * length);
        let reach_lo = libm::sqrt((v0 * v0 - 2.0 * a * length).max(0.0));
        // max/min rather than clamp: see `Planner::push`.
        #[allow(clippy::manual_clamp)]
        {
            v1 = v1.min(v_max).max(reach_lo).min(reach_hi);
        }
        let hold = v_max <= 0.0 && v1 <= 0.0 && v0 * v0 < 2.0 * a * length;
        let (vc, a1, t1, t2, t3);
        if hold {
            // Decelerate to rest inside the block and stay there.
            vc = 0.0;
            a1 = -a;
            t1 = v0 / a;
            t2 = f64::INFINITY;
            t3 = 0.0;
        } else {
            // Highest speed reachable between v0 and v1 over the length.
            let peak = libm::sqrt(((2.0 * a * length + v0 * v0 + v1 * v1) / 2.0).max(0.0));
            let top = if v0 > v_max {
                v_max.max(v1)
            } else {
                peak.min(v_max).max(v0).max(v1)
            };
            let first = (top * top - v0 * v0).abs() / (2.0 * a);
            let last = (top * top - v1 * v1) / (2.0 * a);
            if first + last <= length * (1.0 + 1e-12) {
                vc = top;
                a1 = if top >= v0 { a } else { -a };
                t1 = (top - v0).abs() / a;
                t3 = (top - v1) / a;
                let cruise = (length - first - last).max(0.0);
                t2 = if vc > 0.0 { cruise / vc } else { 0.0 };
            } else {
                // Entered too fast to reach v_max and then v1: decelerate throughout.
                vc = v0;
                a1 = 0.0;
                t1 = 0.0;
                t2 = 0.0;
                t3 = (v0 - v1).max(0.0) / a;
            }
        }
        let p = Profile {
            v0: to_q32(v0),
            a1: to_q40(a1),
            t1: to_q32(t1),
            vc: to_q32(vc),
            t2: if t2.is_finite() {
                to_q32(t2).min(HELD)
            } else {
                HELD
            },
            v1: to_q32(v1),
            a3: to_q40(a),
            t3: to_q32(t3),
            s1: 0,
            length: (length * 65_536.0) as i64,
        };
        let s1 = distance(p.v0, p.t1, p.a1);
        (Profile { s1, ..p }, Achieved { exit: v1 })
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

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Samples positions (nm) every tick until the profile ends (or `max` ticks), then
    /// two ticks more of the continuation at the exit speed.
    fn samples(p: &Profile, max: i64) -> Vec<f64> {
        let end = (p.duration() >> 32) + 2;
        (0..=end.min(max))
            .map(|k| {
                let t = k << 32;
                let over = from_q32((t - p.duration()).max(0)) * from_q32(p.v1);
                p.at(t).0 as f64 / 65_536.0 + over
            })
            .collect()
    }

    #[test]
    fn a_rest_to_rest_move_reaches_cruise_and_ends_exactly() {
        // 100 mm at 50 mm/s (50 000 nm/tick), 500 mm/s² (500 nm/tick²).
        let (p, got) = Profile::plan(1e8, 0.0, 5e4, 0.0, 500.0);
        assert_eq!(got.exit, 0.0);
        assert_eq!(p.at(p.duration()).0, p.length);
        assert_eq!(p.at(p.duration() + TICK_Q32).0, p.length);
        assert!((from_q32(p.duration()) - 2100.0).abs() < 1e-6);
    }

    #[test]
    fn a_hold_stops_inside_the_block_and_stays() {
        let (p, _) = Profile::plan(1e8, 5e4, 0.0, 0.0, 500.0);
        assert_eq!(p.t2, HELD);
        let (s, v) = p.at(200 * TICK_Q32);
        assert_eq!(v, 0);
        assert!((s as f64 / 65_536.0 - 2.5e6).abs() < 1.0, "stopped at {s}");
        assert_eq!(p.at(100_000 * TICK_Q32).0, s);
    }

    #[test]
    fn a_block_too_short_to_slow_down_reports_its_real_exit_speed() {
        let (p, got) = Profile::plan(1e6, 5e4, 5e4, 0.0, 500.0);
        assert!(got.exit > 0.0);
        assert_eq!(p.at(p.duration()).0, p.length);
    }

    proptest! {
        #[test]
        fn speed_and_acceleration_stay_within_limits_and_the_end_is_exact(
            length in 1.0f64..2e9, v0 in 0.0f64..2e5, vmax in 1.0f64..2e5, v1 in 0.0f64..2e5,
            a in 0.5f64..2000.0,
        ) {
            let (p, got) = Profile::plan(length, v0, vmax, v1, a);
            prop_assume!(p.duration() < 4_000_000 * TICK_Q32);
            let x = samples(&p, 4_000_000);
            prop_assert_eq!(p.at(p.duration()).0, p.length);
            let top = vmax.max(v0).max(got.exit);
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
