//! LQG axis controller: a steady-state Kalman estimator (current form) with LQR state
//! feedback and an integral of the following error (LQI), run each servo period in
//! place of the PID's feedback terms. The gains are designed on the host from the
//! joint's plant model and noise and weight settings (`pkmc-host`'s `sim::lqg`) and
//! carried by the machine file as an [`LqgGains`] table.
//!
//! **Formulation.** The controller regulates the deviation from the feed-forward
//! trajectory, as PID with feed-forward does: the command is u = u_ff + δu, u_ff the
//! velocity and acceleration feed-forward computed elsewhere, and the measured
//! deviation is δy = measured − reference, encoder counts (it may carry a fraction).
//! The plant model's deviation state x̂ (order n ≤ [`LQG_STATES`], discretised with a
//! zero-order hold at the servo period T: x⁺ = Φx + Γu, y = Cx) is estimated and fed
//! back with the integral term i (c.u.) of δy. Each period ([`LqgState::update`]):
//!
//! ```text
//! x̂ ← x̂ + M·(δy − C·x̂)                    measurement update (current estimator)
//! δu = −K·x̂ − i                             state feedback plus integral term
//! u  = clamp(u_ff + δu, ±max_output)
//! x̂ ← x̂ + (Φ − I)·x̂ + Γ·(u − u_ff)          time update with the input applied
//! i  ← clamp(i + ki_t·δy, ±max_integral)    unless u is saturated and δy drives it
//!                                           further (conditional integration)
//! ```
//!
//! The integral term i = ki·∫δy dt is kept in c.u., so `max_integral` has the PID's
//! meaning (the largest command the integral may hold); ki_t = ki·T is its gain per
//! period. The time update uses the command actually applied (after the clamp), so
//! the estimate stays right while the output saturates (estimator anti-windup), and
//! it is stored in delta form: at 10 kHz Φ is within 1 % of the identity, and Φ − I
//! kept as such holds its small entries to full `f32` precision where Φ would round
//! them to a few digits.
//!
//! **Arithmetic.** As [`crate::drive::servo`]: `f32`, fixed-length loops over
//! [`LQG_STATES`] (states beyond the model's order have zero gains and stay zero), no
//! division, no `f64`, no panic path (the clamp is [`clamp_sym`]). About 35
//! multiply-adds per period.

use crate::config::{LqgGains, LQG_STATES};
use crate::math::clamp_sym;

/// The controller's memory: the predicted state estimate and the integral term.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LqgState {
    x: [f32; LQG_STATES],
    integral: f32,
}

impl LqgState {
    /// At rest: no deviation estimated, no integral.
    pub const fn new() -> Self {
        Self {
            x: [0.0; LQG_STATES],
            integral: 0.0,
        }
    }

    /// Back to [`LqgState::new`] (an idle or tripped loop).
    pub fn reset(&mut self) {
        *self = Self::new();
    }

    /// The integral term, c.u.
    pub fn integral(&self) -> f32 {
        self.integral
    }

    /// The state estimate predicted for the next period.
    pub fn estimate(&self) -> [f32; LQG_STATES] {
        self.x
    }

    /// One servo period (see the module documentation): the deviation `dy` =
    /// measured − reference (counts), the feed-forward command `u_ff` (c.u.), the
    /// output and integral clamps (c.u., ≥ 0). Returns the command after the clamp.
    pub fn update(
        &mut self,
        g: &LqgGains,
        dy: f32,
        u_ff: f32,
        max_output: f32,
        max_integral: f32,
    ) -> f32 {
        // Over the model's order only (the states beyond it stay zero): the servo
        // period's largest cost (docs/performance.md).
        if g.order <= 3 {
            self.run::<3>(g, dy, u_ff, max_output, max_integral)
        } else {
            self.run::<LQG_STATES>(g, dy, u_ff, max_output, max_integral)
        }
    }

    /// [`LqgState::update`] over the first `N` states.
    #[inline(always)]
    fn run<const N: usize>(
        &mut self,
        g: &LqgGains,
        dy: f32,
        u_ff: f32,
        max_output: f32,
        max_integral: f32,
    ) -> f32 {
        // Written out (no loop): `N > 3` folds at compile time.
        let mut x = self.x;
        let innovation = dy - dot::<N>(&g.c, &x);
        x[0] += g.m[0] * innovation;
        x[1] += g.m[1] * innovation;
        x[2] += g.m[2] * innovation;
        if N > 3 {
            x[3] += g.m[3] * innovation;
        }
        let u = u_ff - self.integral - dot::<N>(&g.k, &x);
        let out = clamp_sym(u, max_output);
        let applied = out - u_ff;
        let (p, gamma) = (&g.phi_minus_i, &g.gamma);
        self.x[0] = x[0] + (gamma[0] * applied + dot::<N>(&p[0], &x));
        self.x[1] = x[1] + (gamma[1] * applied + dot::<N>(&p[1], &x));
        self.x[2] = x[2] + (gamma[2] * applied + dot::<N>(&p[2], &x));
        if N > 3 {
            self.x[3] = x[3] + (gamma[3] * applied + dot::<N>(&p[3], &x));
        }
        let winding = (u > max_output && dy < 0.0) || (u < -max_output && dy > 0.0);
        if !winding {
            self.integral = clamp_sym(self.integral + g.ki_t * dy, max_integral);
        }
        out
    }
}

/// `a · b` over the first `N` states (`N` is 3 or 4).
#[inline(always)]
fn dot<const N: usize>(a: &[f32; LQG_STATES], b: &[f32; LQG_STATES]) -> f32 {
    let s = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    if N > 3 {
        s + a[3] * b[3]
    } else {
        s
    }
}

// `LqgState::run` is written out for three or four states.
const _: () = assert!(LQG_STATES == 4);

#[cfg(test)]
mod tests {
    use super::*;

    /// A first-order model y' = b·u scaled to counts (an integrator): Φ − I = 0,
    /// Γ = b·T, with hand-picked gains.
    fn integrator() -> LqgGains {
        let mut g = LqgGains {
            order: 1,
            phi_minus_i: [[0.0; LQG_STATES]; LQG_STATES],
            gamma: [0.0; LQG_STATES],
            c: [0.0; LQG_STATES],
            m: [0.0; LQG_STATES],
            k: [0.0; LQG_STATES],
            ki_t: 1e-3,
        };
        g.gamma[0] = 0.02; // 200 counts/s per c.u. at 10 kHz
        g.c[0] = 1.0;
        g.m[0] = 0.25;
        g.k[0] = 0.3;
        g
    }

    #[test]
    fn one_period_follows_the_equations() {
        let g = integrator();
        let mut s = LqgState::new();
        s.x[0] = 4.0;
        s.integral = 0.5;
        let u = s.update(&g, 8.0, 1.0, 100.0, 50.0);
        // x̂ = 4 + 0.25·(8 − 4) = 5; δu = −0.3·5 − 0.5 = −2; u = 1 − 2.
        assert_eq!(u, -1.0);
        // Time update: 5 + 0.02·(−2); integral 0.5 + 1e-3·8.
        assert_eq!(s.estimate()[0], 5.0 + 0.02 * -2.0);
        assert_eq!(s.integral(), 0.5 + 1e-3 * 8.0);
        s.reset();
        assert_eq!(s, LqgState::new());
    }

    #[test]
    fn a_saturated_output_holds_the_integral_and_the_estimate_sees_the_clamp() {
        let g = integrator();
        let mut s = LqgState::new();
        // Far below the reference: the loop pushes up and saturates at +10.
        let u = s.update(&g, -1000.0, 0.0, 10.0, 50.0);
        assert_eq!(u, 10.0);
        assert_eq!(s.integral(), 0.0, "no wind-up while saturated");
        // Estimate: −250 after the measurement update, then Γ·10 (the clamp), not
        // Γ·75 (the unclamped command).
        assert_eq!(s.estimate()[0], -250.0 + 0.02 * 10.0);
        // A deviation that drives the output back integrates again.
        let mut s = LqgState::new();
        s.integral = -20.0; // holding the output up
        let u = s.update(&g, 10.0, 0.0, 10.0, 50.0);
        assert_eq!(u, 10.0);
        assert_eq!(s.integral(), -20.0 + 1e-3 * 10.0);
    }

    #[test]
    fn the_integral_is_clamped() {
        let g = integrator();
        let mut s = LqgState::new();
        s.integral = 49.999;
        s.update(&g, 100.0, 0.0, 1e6, 50.0);
        assert_eq!(s.integral(), 50.0);
        s.integral = -49.999;
        s.update(&g, -100.0, 0.0, 1e6, 50.0);
        assert_eq!(s.integral(), -50.0);
    }

    #[test]
    fn gains_compare_by_bits_and_are_checked() {
        let g = integrator();
        assert!(g.is_valid());
        assert_eq!(g, g);
        let mut nan = g;
        nan.k[0] = f32::NAN;
        assert!(!nan.is_valid());
        assert_eq!(nan, nan, "reflexive even with NaN");
        let mut zero = g;
        zero.m[0] = -0.0;
        assert_ne!(zero, {
            let mut z = g;
            z.m[0] = 0.0;
            z
        });
        let mut beyond = g;
        beyond.phi_minus_i[2][0] = 1e-3;
        assert!(!beyond.is_valid(), "an entry beyond the order");
        let mut order = g;
        order.order = 5;
        assert!(!order.is_valid());
        order.order = 0;
        assert!(!order.is_valid());
        let mut negative = g;
        negative.ki_t = -1e-3;
        assert!(!negative.is_valid());
    }

    #[test]
    fn a_stable_loop_on_the_model_settles_on_the_reference() {
        // The integrator plant y⁺ = y + 0.02·u in counts, the loop regulating δy.
        let g = integrator();
        let mut s = LqgState::new();
        let mut y = 500.0f32; // start 500 counts off, a constant load of −3 c.u.
        for _ in 0..20_000 {
            let u = s.update(&g, y, 0.0, 100.0, 50.0);
            y += 0.02 * (u - 3.0);
        }
        assert!(y.abs() < 1e-3, "{y}");
        // At rest the estimator, which does not know the load, predicts the drift
        // Γ·3 = M·x̂⁻: x̂⁻ = 0.24, x̂ = 0.18 after the update, so the integral term
        // holds −3 − K·0.18.
        assert!((s.integral() + 3.054).abs() < 1e-3, "{}", s.integral());
    }
}
