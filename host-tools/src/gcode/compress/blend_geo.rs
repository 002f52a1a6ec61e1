//! A blended block's geometry in fit space ([`Geo`]): a line or a cubic Bézier, its
//! points, derivative, bend, arc length and parts, and the block it is sent as.

use super::super::space::{from_fit, to_fit};
use super::super::{norm, sub, V};
use pkmc::config::AXES;
use pkmc::motion::block::{Block, Motion};

/// Steps of the arc-length table of a curve.
pub(super) const STEPS: usize = 64;

/// A block's geometry in fit space: a line or a cubic Bézier.
#[derive(Clone, Copy, Debug)]
pub(super) enum Geo {
    Line([V; 2]),
    Cubic([V; 4]),
}

fn lerp(a: &V, b: &V, t: f64) -> V {
    core::array::from_fn(|i| a[i] + (b[i] - a[i]) * t)
}

impl Geo {
    pub(super) fn of(b: &Block, from: &[i64; AXES]) -> Option<Self> {
        let (p0, p3) = (to_fit(from), to_fit(&b.target));
        match b.motion {
            Motion::Linear => Some(Geo::Line([p0, p3])),
            Motion::Cubic { c1, c2 } => {
                let c1: [i64; AXES] = core::array::from_fn(|i| from[i] + c1[i]);
                let c2: [i64; AXES] = core::array::from_fn(|i| b.target[i] + c2[i]);
                Some(Geo::Cubic([p0, to_fit(&c1), to_fit(&c2), p3]))
            }
            _ => None,
        }
    }

    pub(super) fn at(&self, u: f64) -> V {
        match self {
            Geo::Line([a, b]) => lerp(a, b, u),
            Geo::Cubic(p) => {
                let (a, b, c) = (
                    lerp(&p[0], &p[1], u),
                    lerp(&p[1], &p[2], u),
                    lerp(&p[2], &p[3], u),
                );
                let (d, e) = (lerp(&a, &b, u), lerp(&b, &c, u));
                lerp(&d, &e, u)
            }
        }
    }

    /// dP/du.
    pub(super) fn deriv(&self, u: f64) -> V {
        match self {
            Geo::Line([a, b]) => sub(b, a),
            Geo::Cubic(p) => {
                let (d0, d1, d2) = (sub(&p[1], &p[0]), sub(&p[2], &p[1]), sub(&p[3], &p[2]));
                let (a, b) = (lerp(&d0, &d1, u), lerp(&d1, &d2, u));
                lerp(&a, &b, u).map(|x| 3.0 * x)
            }
        }
    }

    /// Its bend (curvature over X Y Z) at u, per nm.
    pub(super) fn bend(&self, u: f64) -> f64 {
        let Geo::Cubic(p) = self else {
            return 0.0;
        };
        let d2: V = core::array::from_fn(|i| {
            6.0 * ((1.0 - u) * (p[2][i] - 2.0 * p[1][i] + p[0][i])
                + u * (p[3][i] - 2.0 * p[2][i] + p[1][i]))
        });
        super::super::fit::curvature(&self.deriv(u), &d2).1
    }

    /// Cumulative arc length at u = k/STEPS.
    pub(super) fn table(&self) -> Vec<f64> {
        let mut t = vec![0.0];
        let mut prev = self.at(0.0);
        for k in 1..=STEPS {
            let p = self.at(k as f64 / STEPS as f64);
            t.push(t[k - 1] + norm(&sub(&p, &prev)));
            prev = p;
        }
        t
    }

    /// The parameter where the arc length from the start is `s`.
    pub(super) fn u_at(&self, table: &[f64], s: f64) -> f64 {
        if let Geo::Line(_) = self {
            return (s / table[STEPS]).clamp(0.0, 1.0);
        }
        let k = table.partition_point(|&x| x < s).clamp(1, STEPS);
        let (a, b) = (table[k - 1], table[k]);
        let f = if b > a { (s - a) / (b - a) } else { 0.0 };
        ((k - 1) as f64 + f.clamp(0.0, 1.0)) / STEPS as f64
    }

    /// The part between parameters `u0` and `u1`.
    pub(super) fn part(&self, u0: f64, u1: f64) -> Geo {
        match self {
            Geo::Line(_) => Geo::Line([self.at(u0), self.at(u1)]),
            Geo::Cubic(_) => {
                let h = (u1 - u0) / 3.0;
                let (a, b) = (self.at(u0), self.at(u1));
                let (da, db) = (self.deriv(u0), self.deriv(u1));
                Geo::Cubic([
                    a,
                    core::array::from_fn(|i| a[i] + h * da[i]),
                    core::array::from_fn(|i| b[i] - h * db[i]),
                    b,
                ])
            }
        }
    }
}

/// A point of fit space in whole axis units; axes 3.. (A B C, which do not move in a
/// blended block) are `keep`'s.
pub(super) fn round(p: &V, keep: &[i64; AXES]) -> [i64; AXES] {
    core::array::from_fn(|i| if i < 3 { from_fit(i, p[i]) } else { keep[i] })
}

/// The block for `g` (whose ends are already whole units), with `b`'s line, feed and
/// tolerance.
pub(super) fn block_of(g: &Geo, b: &Block, keep: &[i64; AXES]) -> Block {
    match g {
        Geo::Line([_, e]) => Block {
            motion: Motion::Linear,
            target: round(e, keep),
            ..*b
        },
        Geo::Cubic(p) => {
            let (s, e) = (round(&p[0], keep), round(&p[3], keep));
            let (c1, c2) = (round(&p[1], keep), round(&p[2], keep));
            Block {
                motion: Motion::Cubic {
                    c1: core::array::from_fn(|i| c1[i] - s[i]),
                    c2: core::array::from_fn(|i| c2[i] - e[i]),
                },
                target: e,
                ..*b
            }
        }
    }
}
