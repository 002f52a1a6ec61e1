//! How far one curve reaches from a point of a run: the farthest fit by doubling and
//! bisection, along the block before or the curve's own direction, and the choice
//! among those fits that [`super::fit_run`] takes (see the parent module).

use super::fit::{self, fit, fit_free, Goal};
use super::{dot, norm, sub, unit, Settings, V};

/// The curve from point `a` that the run takes: one whose start matches the block
/// before it (along `lead`, at its |dP/du| ratio), unless one that does not reaches
/// much farther ([`Settings::matched_reach`]); and where that is a long curve
/// ([`Settings::even_from_moves`]) or one whose uneven pace costs much time
/// ([`Settings::even_cost_s`]), and it runs unevenly, one of at least a quarter as
/// many moves (two at least; half of `even_from_moves` is always enough) that runs
/// more evenly ([`Settings::even_ratio`]) and faster for its length ([`fit::pace`]):
/// the controller runs a curve's parameter at one rate, so the tool goes at its
/// |dP/du| over the largest times the path speed.
pub(super) fn next_curve(
    pts: &[V],
    t: &[V],
    a: usize,
    (lead, into): (Option<V>, Option<V>),
    g: &Goal,
    s: &Settings,
) -> Option<(usize, V, V)> {
    let strict = curve_from(pts, t, a, (lead, into), g, s);
    let loose = curve_from(
        pts,
        t,
        a,
        (lead, into),
        g,
        &Settings {
            min_junction_share: 0.0,
            ..*s
        },
    );
    let reach = |f: &Option<(usize, V, V)>| f.as_ref().map_or(0, |f| f.0 - a);
    let found = if reach(&strict) as f64 >= s.matched_reach * reach(&loose) as f64 {
        strict
    } else {
        loose
    };
    let pace = |f: &Option<(usize, V, V)>| {
        f.as_ref().map_or(0.0, |&(b, c1, c2)| {
            fit::pace(&[pts[a], c1, c2, pts[b]], g, s)
        })
    };
    // Only a long curve, or one of four moves or more whose uneven pace costs time,
    // is looked at again.
    let moves = reach(&found);
    if moves < s.even_from_moves.min(4) {
        return found;
    }
    let paced = pace(&found);
    let costly = || uneven_cost(&pts[a..=a + moves], paced, g) >= s.even_cost_s;
    if paced >= s.even_ratio || !(moves >= s.even_from_moves || costly()) {
        return found;
    }
    let even = &Settings {
        min_speed_ratio: s.even_ratio,
        ..*s
    };
    // Along the lead: a curve that leaves along its own direction would make a corner.
    let shorter = farthest(pts, t, a, lead.as_ref(), g, even);
    let least = (s.even_from_moves / 2).min((moves / 4).max(2));
    if reach(&shorter) >= least && pace(&shorter) > paced {
        shorter
    } else {
        found
    }
}

/// The time a curve through the points `run` loses at the speed asked for by running
/// at `paced` of it, s: their polyline's length over the speed, times 1/pace − 1 (0
/// when the speed is not known).
fn uneven_cost(run: &[V], paced: f64, g: &Goal) -> f64 {
    if g.speed <= 0.0 {
        return 0.0;
    }
    let len: f64 = run.windows(2).map(|w| norm(&sub(&w[1], &w[0]))).sum();
    len / g.speed * (1.0 / paced.max(1e-3) - 1.0)
}

/// The curve from point `a` ([`farthest`]), leaving along `lead` when there is one,
/// or along its own direction when that reaches farther and turns no more than the
/// program does at this point (from the chord `into` it).
fn curve_from(
    pts: &[V],
    t: &[V],
    a: usize,
    (lead, into): (Option<V>, Option<V>),
    g: &Goal,
    s: &Settings,
) -> Option<(usize, V, V)> {
    let mut found = farthest(pts, t, a, lead.as_ref(), g, s);
    if let (Some(l), Some(into)) = (lead, into) {
        // Leaving along its own direction, turning no more than the program does
        // at this point.
        let own = dot(&into, &unit(&sub(&pts[a + 1], &pts[a])));
        if let Some(o) = farthest(pts, t, a, None, g, s) {
            let turn_ok = dot(&l, &unit(&sub(&o.1, &pts[a]))) >= own.min(1.0);
            if turn_ok && found.as_ref().is_none_or(|f| o.0 > f.0) {
                found = Some(o);
            }
        }
    }
    found
}

/// The farthest one curve from `a` leaving along `lead` (or the data's tangent)
/// reaches, with either end tangent fixed to the data's or the far end's free
/// (preferred when it reaches [`Settings::free_gain`] times as far).
fn farthest(
    pts: &[V],
    t: &[V],
    a: usize,
    lead: Option<&V>,
    g: &Goal,
    s: &Settings,
) -> Option<(usize, V, V)> {
    let fixed = reach(pts, t, a, lead, g, s, false);
    let free = reach(pts, t, a, lead, g, s, true);
    match (fixed, free) {
        (Some(f), Some(o)) if (o.0 - a) as f64 > s.free_gain * (f.0 - a) as f64 => Some(o),
        (Some(f), _) => Some(f),
        (None, o) => o,
    }
}

/// The farthest point `b` (two chords or more from `a`) one curve from `a` reaches,
/// leaving along `lead` (or its own best direction), with its inner control points:
/// by doubling, then bisection.
fn reach(
    pts: &[V],
    t: &[V],
    a: usize,
    lead: Option<&V>,
    g: &Goal,
    s: &Settings,
    free: bool,
) -> Option<(usize, V, V)> {
    let top = (pts.len() - 1).min(a + s.max_chords);
    let try_to = |b: usize| {
        if let Some((_, unsure)) = g.edge.filter(|e| b >= e.0) {
            unsure.set(true);
        }
        if free && b - a >= 4 {
            fit_free(&pts[a..=b], lead, g, s)
        } else {
            fit(&pts[a..=b], lead.unwrap_or(&t[a]), &t[b], g, s)
        }
    };
    let (mut good, mut best, mut bad) = (a + 1, None, None);
    let mut step = 2;
    while a + step <= top {
        match try_to(a + step) {
            Some(c) => (good, best, step) = (a + step, Some(c), step * 2),
            None => {
                bad = Some(a + step);
                break;
            }
        }
    }
    if bad.is_none() && good < top {
        match try_to(top) {
            Some(c) => (good, best) = (top, Some(c)),
            None => bad = Some(top),
        }
    }
    if let Some(mut hi) = bad {
        while hi - good > 1 {
            let mid = (good + hi) / 2;
            match try_to(mid) {
                Some(c) => (good, best) = (mid, Some(c)),
                None => hi = mid,
            }
        }
    }
    best.map(|(c1, c2)| (good, c1, c2))
}
