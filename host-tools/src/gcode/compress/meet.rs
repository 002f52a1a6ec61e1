//! Where two curves of a run meet. The second is looked for leaving along the first's
//! end tangent, and that tangent came from the first curve's own fit: its far end was
//! the data's tangent there or left free, whichever reached farther. A free end can
//! leave the two curves meeting along a direction neither fits well, so that both run
//! slower than they need to (3D_Chips' junctions). Once the second is found, the
//! tangent where they meet is turned towards the data's there, and both are fitted
//! again through the same points along it (the first keeps its start, the second its
//! end); the first turn for which both still fit within the tolerance is kept
//! (`Settings::turn_steps`).
//!
//! The first curve is handed out only once the second is known ([`Held`]): an open
//! merge (the Grbl bridge) stops before a curve whose end may still turn, and goes on
//! from its start with how the curve before it ended ([`super::Lead`]).

use super::fit::{self, fit, Goal};
use super::{dot, norm, sub, unit, Lead, Settings, V};

/// A curve of a run that is found but not yet handed out.
#[derive(Clone, Copy, Debug)]
pub(super) struct Held {
    /// Its first and last point in the run.
    pub(super) a: usize,
    pub(super) b: usize,
    /// Its control points (fit space).
    pub(super) c: [V; 4],
    /// The direction it leaves along and the ratio of the tool's speed to the path
    /// speed there (the end of the block before it).
    pub(super) start: (V, f64),
    /// The direction it ends along.
    pub(super) end: V,
    /// How the block before it ended: where an open merge stops when this curve's end
    /// may still turn.
    pub(super) before: Option<Lead>,
}

impl Held {
    /// The curve from `pts[a]` to `pts[b]` through `c1`, `c2`, leaving at `ratio`.
    pub(super) fn found(pts: &[V], (a, b): (usize, usize), (c1, c2): (V, V), ratio: f64) -> Self {
        Held {
            a,
            b,
            c: [pts[a], c1, c2, pts[b]],
            start: (unit(&sub(&c1, &pts[a])), ratio),
            end: unit(&sub(&pts[b], &c2)),
            before: None,
        }
    }

    /// Fitted again through its points, leaving along `dir` at `ratio` and ending as
    /// before; `false` (and unchanged) when that does not fit.
    pub(super) fn refit(
        &mut self,
        pts: &[V],
        (dir, ratio): (V, f64),
        g: &Goal,
        s: &Settings,
    ) -> bool {
        let goal = Goal {
            lead_ratio: ratio,
            ..*g
        };
        let Some((c1, c2)) = fit(&pts[self.a..=self.b], &dir, &self.end, &goal, s) else {
            return false;
        };
        self.c = [pts[self.a], c1, c2, pts[self.b]];
        self.start = (dir, ratio);
        true
    }
}

/// Turns the tangent where `first` meets `next` (which leaves along `first`'s end)
/// towards the data's tangent `data` there (module doc); `true` when it turned.
pub(super) fn turn(
    pts: &[V],
    data: &V,
    (first, next): (&mut Held, &mut Held),
    g: &Goal,
    s: &Settings,
) -> bool {
    let was = first.end;
    let along = dot(&next.start.0, &was) >= 1.0 - 1e-9;
    let turned = dot(data, &was) <= 1.0 - 1e-12;
    if first.b != next.a || !along || !turned || norm(&first.start.0) < 0.5 {
        return false;
    }
    let before = time(pts, first, g, s) + time(pts, next, g, s);
    // The data's tangent first, then ever nearer the found one.
    for k in (1..=s.turn_steps).rev() {
        let w = f64::from(k) / f64::from(s.turn_steps);
        let mixed: V = core::array::from_fn(|i| (1.0 - w) * was[i] + w * data[i]);
        if norm(&mixed) < 1e-9 {
            continue;
        }
        let dir = unit(&mixed);
        // The first curve ends along `dir`: fitted with its start as it was and its end
        // turned (its end tangent is what `refit` keeps, so it is set first).
        let mut a = *first;
        a.end = dir;
        if !a.refit(pts, a.start, g, s) {
            continue;
        }
        let mut b = *next;
        if !b.refit(pts, (dir, fit::end_ratio(&a.c)), g, s) {
            continue;
        }
        if time(pts, &a, g, s) + time(pts, &b, g, s) >= before {
            continue;
        }
        *first = a;
        *next = b;
        return true;
    }
    false
}

/// The time the controller takes over `h` at the speed asked for, in units of its
/// polyline's time there: the polyline's length over the curve's pace ([`fit::pace`]).
fn time(pts: &[V], h: &Held, g: &Goal, s: &Settings) -> f64 {
    let len: f64 = pts[h.a..=h.b]
        .windows(2)
        .map(|w| norm(&sub(&w[1], &w[0])))
        .sum();
    len / fit::pace(&h.c, g, s).max(1e-3)
}
