//! The gains of an axis's LQG controller as the machine file gives them; the
//! controller's state and its update are the drive's (`crate::drive::lqg`).

use serde::{Deserialize, Serialize};

/// Highest plant model order the controller holds (report B's table Y(s) is 4th order).
pub const LQG_STATES: usize = 4;

/// Gains of one axis's LQG controller, in the servo period's discrete time. Units:
/// δy in encoder counts, commands in c.u.; the state's units are the design's (its
/// first component is the estimated deviation in counts, the others its derivatives
/// scaled by a characteristic frequency). Entries at indices ≥ `order` are zero.
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
pub struct LqgGains {
    /// Model order n, 1..=[`LQG_STATES`].
    pub order: u8,
    /// Φ − I, the state transition over one period minus the identity.
    pub phi_minus_i: [[f32; LQG_STATES]; LQG_STATES],
    /// Γ, the state change per c.u. held over one period.
    pub gamma: [f32; LQG_STATES],
    /// C, counts per unit of each state.
    pub c: [f32; LQG_STATES],
    /// M, the Kalman estimator's gain per count of innovation.
    pub m: [f32; LQG_STATES],
    /// K, the state feedback, c.u. per unit of each state.
    pub k: [f32; LQG_STATES],
    /// ki·T, the integral term's growth per count of δy per period, c.u./count.
    pub ki_t: f32,
}

impl LqgGains {
    fn values(&self) -> impl Iterator<Item = &f32> {
        self.phi_minus_i
            .iter()
            .flatten()
            .chain(&self.gamma)
            .chain(&self.c)
            .chain(&self.m)
            .chain(&self.k)
            .chain(core::iter::once(&self.ki_t))
    }

    /// Are the gains usable: order 1..=[`LQG_STATES`], every value finite, the
    /// entries beyond the order zero, and `ki_t` ≥ 0 (the conditional integration
    /// assumes the integral term opposes δy)? Stability is the design's to show.
    pub fn is_valid(&self) -> bool {
        let n = self.order as usize;
        let beyond = |v: &[f32; LQG_STATES]| v.iter().skip(n).all(|x| *x == 0.0);
        (1..=LQG_STATES).contains(&n)
            && self.values().all(|v| v.is_finite())
            && self.ki_t >= 0.0
            && beyond(&self.gamma)
            && beyond(&self.c)
            && beyond(&self.m)
            && beyond(&self.k)
            && self
                .phi_minus_i
                .iter()
                .enumerate()
                .all(|(i, row)| beyond(row) && (i < n || row.iter().all(|x| *x == 0.0)))
    }
}

/// Equal when every value has the same bits (as [`crate::config::ServoGains`]): a
/// reflexive comparison that tells a stored table from the one sent.
impl PartialEq for LqgGains {
    fn eq(&self, other: &Self) -> bool {
        self.order == other.order
            && self
                .values()
                .zip(other.values())
                .all(|(a, b)| a.to_bits() == b.to_bits())
    }
}
impl Eq for LqgGains {}
