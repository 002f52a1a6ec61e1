//! One curve through a stretch of a run: least squares with the end tangents fixed,
//! or with the far one free (reweighted towards the worst points), Newton steps for
//! the points' parameters, and the tests a curve must pass (see the parent module).

use super::{dot, norm, sub, unit, Settings, V};
use pkmc::config::AXES;

/// Curves of fewer moves are not weighed for time (their bend is the data's noise as
/// much as the path's).
const WEIGH_FROM: usize = 4;

/// The controller's interpolation period, s.
const TICK_S: f64 = 1.0 / pkmc::units::TICK_HZ as f64;

/// What one run's curves must meet: its tolerance (fit space) and the speed asked for
/// (nm/s; 0: unknown).
#[derive(Clone, Copy, Debug)]
pub(super) struct Goal<'a> {
    pub(super) tol: f64,
    pub(super) speed: f64,
    /// The tool's speed over the path speed where the curve starts: the end of the
    /// curve before it (|dP/du| there over its largest), 1 after a line or at a run's
    /// start.
    pub(super) lead_ratio: f64,
    /// A run that more moves may follow: the first of its points whose tangent looks
    /// past its last, and the flag a fit that tries to reach it sets (its result
    /// could change with what follows).
    pub(super) edge: Option<(usize, &'a core::cell::Cell<bool>)>,
}

fn bernstein(u: f64) -> [f64; 4] {
    let v = 1.0 - u;
    [v * v * v, 3.0 * v * v * u, 3.0 * v * u * u, u * u * u]
}

fn point(c: &[V; 4], u: f64) -> V {
    let w = bernstein(u);
    core::array::from_fn(|i| (0..4).map(|k| w[k] * c[k][i]).sum())
}

fn deriv(c: &[V; 4], u: f64) -> V {
    let v = 1.0 - u;
    core::array::from_fn(|i| {
        3.0 * (v * v * (c[1][i] - c[0][i])
            + 2.0 * v * u * (c[2][i] - c[1][i])
            + u * u * (c[3][i] - c[2][i]))
    })
}

fn deriv2(c: &[V; 4], u: f64) -> V {
    core::array::from_fn(|i| {
        6.0 * ((1.0 - u) * (c[2][i] - 2.0 * c[1][i] + c[0][i])
            + u * (c[3][i] - 2.0 * c[2][i] + c[1][i]))
    })
}

/// The points' chord-length parameters (0 to 1) and the polyline's length; `None`
/// for a polyline of no length.
fn chord_params(p: &[V]) -> Option<(Vec<f64>, f64)> {
    let n = p.len() - 1;
    let mut u = vec![0.0; n + 1];
    for k in 1..=n {
        u[k] = u[k - 1] + norm(&sub(&p[k], &p[k - 1]));
    }
    let total = u[n];
    if total <= 0.0 {
        return None;
    }
    u.iter_mut().for_each(|x| *x /= total);
    Some((u, total))
}

/// The cubic through `p[0]` and `p[last]` along `t0` and `t1` that fits the points
/// between, or `None` when no such cubic stays within `tol` (see the module doc).
/// Tried: the least-squares fit, the one whose end speeds are the polyline's length
/// (a near-uniform parameter, which a least-squares fit over few points may miss),
/// blends of the two, and, where one of those fits, the least-squares fit with its
/// handles evened or lengthened ([`handle_variants`]); of those within the tolerance,
/// the one that runs most evenly ([`accept`]'s score, junctions included). Returns
/// the two inner control points.
pub(super) fn fit(p: &[V], t0: &V, t1: &V, g: &Goal, s: &Settings) -> Option<(V, V)> {
    let n = p.len() - 1;
    let (u, total) = chord_params(p)?;
    let chord = norm(&sub(&p[n], &p[0]));
    let mut c = lengths(p, &u, t0, t1, chord);
    let mut uu = u.clone();
    for _ in 0..2 {
        for k in 1..n {
            uu[k] = newton(&c, &p[k], uu[k]);
        }
        c = lengths(p, &uu, t0, t1, chord);
    }
    // The least-squares lengths, the uniform ones (a third of the polyline each) and
    // three blends: the one that runs most evenly among those that fit.
    let (p0, p3) = (p[0], p[n]);
    let (al, be) = (norm(&sub(&c[1], &p0)), norm(&sub(&p3, &c[2])));
    let mut best: Option<(f64, V, V)> = None;
    let blends = [0.0, 0.25, 0.5, 0.75, 1.0]
        .map(|w| (al + w * (total / 3.0 - al), be + w * (total / 3.0 - be)));
    for (k, (a, b)) in blends.into_iter().enumerate() {
        // The least-squares fit starts from its own refined parameters.
        let start = if k == 0 { &uu } else { &u };
        consider(&along(p0, p3, t0, t1, a, b), p, start, g, s, &mut best);
    }
    let best = improve((p0, p3), (t0, t1), (al, be), p, &u, g, s, best);
    best.map(|(_, c1, c2)| (c1, c2))
}

/// The cubic from `p[0]` to `p[last]` that fits the points between by least squares,
/// leaving along `t0` when given (the previous curve's end tangent) and with its end
/// tangent free (the next curve starts along it).
pub(super) fn fit_free(p: &[V], t0: Option<&V>, g: &Goal, s: &Settings) -> Option<(V, V)> {
    let n = p.len() - 1;
    let (mut u, total) = chord_params(p)?;
    let (p0, p3) = (p[0], p[n]);
    let solve = |u: &[f64], wt: &[f64]| -> Option<[V; 4]> {
        let (mut s11, mut s12, mut s22) = (0.0, 0.0, 0.0);
        let (mut r1, mut r2) = ([0.0; AXES], [0.0; AXES]);
        // Weighted: each point's equation scaled by √weight.
        let rs: Vec<(f64, f64, V)> = p
            .iter()
            .zip(u)
            .zip(wt)
            .map(|((q, &x), &g)| {
                let w = bernstein(x);
                let g = g.sqrt();
                let r: V =
                    core::array::from_fn(|i| g * (q[i] - (w[0] + w[1]) * p0[i] - w[3] * p3[i]));
                (g * w[1], g * w[2], r)
            })
            .collect();
        match t0 {
            Some(t) => {
                // C1 = P0 + α·t, C2 free: for fixed α the best C2 is linear in α; α then
                // minimises a quadratic.
                let r = &rs;
                for (b1, b2, _) in r {
                    s12 += b1 * b2;
                    s22 += b2 * b2;
                }
                if s22 <= 0.0 {
                    return None;
                }
                let mut cr = [0.0; AXES];
                for (_, b2, rr) in r {
                    for i in 0..AXES {
                        cr[i] += b2 * rr[i] / s22;
                    }
                }
                let (mut num, mut den) = (0.0, 0.0);
                for (b1, b2, rr) in r {
                    let w = b1 - b2 * s12 / s22;
                    let e: V = core::array::from_fn(|i| b2 * cr[i] - rr[i]);
                    num += w * dot(t, &e);
                    den += w * w;
                }
                if den <= 0.0 {
                    return None;
                }
                let al = -num / den;
                let c1: V = core::array::from_fn(|i| p0[i] + al * t[i]);
                let c2: V = core::array::from_fn(|i| cr[i] - al * t[i] * s12 / s22);
                (al > 1e-3 * total).then_some([p0, c1, c2, p3])
            }
            None => {
                for (b1, b2, r) in &rs {
                    s11 += b1 * b1;
                    s12 += b1 * b2;
                    s22 += b2 * b2;
                    for i in 0..AXES {
                        r1[i] += b1 * r[i];
                        r2[i] += b2 * r[i];
                    }
                }
                let det = s11 * s22 - s12 * s12;
                if det.abs() <= 1e-12 * (s11 * s22).max(1e-300) {
                    return None;
                }
                // r is Q − B0·P0 − B3·P3 less B1·P0: the solution is C1 − P0.
                let c1: V = core::array::from_fn(|i| p0[i] + (r1[i] * s22 - r2[i] * s12) / det);
                let c2: V = core::array::from_fn(|i| (s11 * r2[i] - s12 * r1[i]) / det);
                Some([p0, c1, c2, p3])
            }
        }
    };
    // Least squares, then reweighted towards the worst points (the test is the
    // largest deviation, not the sum of squares).
    let mut wt = vec![1.0; n + 1];
    let mut c = solve(&u, &wt)?;
    for _ in 0..s.reweights.max(2) {
        for k in 1..n {
            u[k] = newton(&c, &p[k], u[k]);
        }
        let r: Vec<f64> = (0..=n)
            .map(|k| norm(&sub(&point(&c, u[k]), &p[k])))
            .collect();
        let top = r.iter().cloned().fold(0.0, f64::max);
        if top <= 0.0 {
            break;
        }
        for k in 0..=n {
            wt[k] *= 1.0 + 4.0 * (r[k] / top).powi(2);
        }
        c = solve(&u, &wt)?;
    }
    // The end tangent must point forward.
    let chord = sub(&p3, &p0);
    if dot(&sub(&p3, &c[2]), &chord) <= 0.0 || dot(&sub(&c[1], &p0), &chord) <= 0.0 {
        return None;
    }
    // The least-squares fit; where it fits, the same with its handles evened or
    // lengthened too: of those within the tolerance, the one that runs most evenly.
    let mut best = accept(&c, p, &u, g, s).map(|e| (e, c[1], c[2]));
    let (d0, d1) = (sub(&c[1], &p0), sub(&p3, &c[2]));
    let (al, be) = (norm(&d0), norm(&d1));
    if al > 0.0 && be > 0.0 {
        let tangents = (&unit(&d0), &unit(&d1));
        best = improve((p0, p3), tangents, (al, be), p, &u, g, s, best);
    }
    best.map(|(_, c1, c2)| (c1, c2))
}

/// `best` (the score and inner control points of the fit kept so far) or a better one
/// among the [`handle_variants`] of handles `al` and `be` along the end tangents
/// `t0` and `t1` from `p0` to `p3`, the points' parameters starting from `u`. Only a
/// fit already found is improved by them: where none fits, the curve ends sooner, as
/// it would without the variants (one that reached further than any other fit would
/// run slower, and merge fewer moves per curve elsewhere). The handles whose start
/// matches the block before ([`matched_start`]) are tried in any case: a fit refused
/// for its start's jump alone ([`Settings::min_junction_share`]) is not one that
/// reaches further than the others.
#[allow(clippy::too_many_arguments)]
fn improve(
    (p0, p3): (V, V),
    (t0, t1): (&V, &V),
    (al, be): (f64, f64),
    p: &[V],
    u: &[f64],
    g: &Goal,
    s: &Settings,
    mut best: Option<(f64, V, V)>,
) -> Option<(f64, V, V)> {
    if best.is_some() {
        for (a, b) in handle_variants(al, be) {
            consider(&along(p0, p3, t0, t1, a, b), p, u, g, s, &mut best);
        }
    }
    // Handles whose start runs as fast as the curve before it ends, with the far
    // handle as fitted and as long: a junction where the tool's speed jumps is nearly
    // a stop ([`junction_share`]).
    let third = p.windows(2).map(|w| norm(&sub(&w[1], &w[0]))).sum::<f64>() / 3.0;
    for b in [be, al.max(be), third] {
        let a = matched_start((p0, p3), (t0, t1), b, g.lead_ratio);
        for b in [b, a, b * 1.1] {
            consider(&along(p0, p3, t0, t1, a, b), p, u, g, s, &mut best);
        }
    }
    best
}

/// The start handle (with the far one `b`) at which the cubic from `p0` to `p3`
/// along `t0` and `t1` starts at `ratio` of its largest |dP/du| ([`end_ratio`]'s
/// grid): that ratio grows with the handle, so by bisection.
fn matched_start((p0, p3): (V, V), (t0, t1): (&V, &V), b: f64, ratio: f64) -> f64 {
    let chord = norm(&sub(&p3, &p0));
    let start_ratio = |a: f64| {
        let c = along(p0, p3, t0, t1, a, b);
        let speed = |u: f64| norm(&deriv(&c, u));
        let top = (0..=64).map(|k| speed(k as f64 / 64.0)).fold(0.0, f64::max);
        if top > 0.0 {
            speed(0.0) / top
        } else {
            1.0
        }
    };
    let (mut lo, mut hi) = (0.0, 2.0 * chord);
    for _ in 0..16 {
        let mid = (lo + hi) / 2.0;
        if start_ratio(mid) < ratio - 1e-4 {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    hi
}

/// The cubic from `p0` to `p3` leaving along `t0` with handle `a` and arriving along
/// `t1` with handle `b`.
fn along(p0: V, p3: V, t0: &V, t1: &V, a: f64, b: f64) -> [V; 4] {
    [
        p0,
        core::array::from_fn(|i| p0[i] + a * t0[i]),
        core::array::from_fn(|i| p3[i] - b * t1[i]),
        p3,
    ]
}

/// Keeps `c` in `best` when it passes [`accept`] with a higher score, its points'
/// parameters refined by two Newton steps from `start`.
fn consider(
    c: &[V; 4],
    p: &[V],
    start: &[f64],
    g: &Goal,
    s: &Settings,
    best: &mut Option<(f64, V, V)>,
) {
    let mut v = start.to_vec();
    for _ in 0..2 {
        for k in 1..p.len() - 1 {
            v[k] = newton(c, &p[k], v[k]);
        }
    }
    if let Some(e) = accept(c, p, &v, g, s) {
        if best.as_ref().is_none_or(|b| e > b.0) {
            *best = Some((e, c[1], c[2]));
        }
    }
}

/// Handle lengths to try beside a fit's own `al` and `be` (along its end tangents):
/// both the longer one, both their mean, and those lengthened by 5 and 10 %. Longer
/// and equal handles bring a curve's speed at its ends up to its largest, which is
/// what a neighbour's end meets ([`accept`]).
fn handle_variants(al: f64, be: f64) -> [(f64, f64); 6] {
    let (m, h) = (al.max(be), (al + be) / 2.0);
    [
        (m, m),
        (h, h),
        (al * 1.05, be * 1.05),
        (al * 1.1, be * 1.1),
        (h * 1.05, h * 1.05),
        (h * 1.1, h * 1.1),
    ]
}

/// Does the cubic `c` follow the points `p` (parameters `u`) within the tolerance,
/// and run about as fast as the chords would? The controller runs a block at one speed
/// limit, from its tightest bend, and the parameter at a uniform rate (the tool is
/// slower where |dP/du| is below its largest): the curve's time at that speed is
/// compared with the chords' own ([`chords_time`]), and must be no longer, for a
/// curve that turns more than [`Settings::max_turn_deg`]. Its score, when it passes: the slowest |dP/du| over
/// the largest, times what its ends let the junctions keep ([`junction_share`]).
fn accept(c: &[V; 4], p: &[V], u: &[f64], g: &Goal, s: &Settings) -> Option<f64> {
    let n = p.len() - 1;
    let tol = g.tol;
    // Every programmed point near the curve.
    for k in 1..n {
        if norm(&sub(&point(c, u[k]), &p[k])) > tol {
            return None;
        }
    }
    // Every point of the curve near the polyline; speed and bend along it.
    let samples = 8 * n;
    let mut seg = 0;
    let mut along = Vec::with_capacity(samples + 1);
    let mut farthest = 0.0f64;
    for j in 0..=samples {
        let x = j as f64 / samples as f64;
        while seg + 1 < n && u[seg + 1] < x {
            seg += 1;
        }
        let q = point(c, x);
        let lo = seg.saturating_sub(2);
        let hi = (seg + 3).min(n);
        let d = (lo..hi)
            .map(|k| to_segment(&q, &p[k], &p[k + 1]))
            .fold(f64::INFINITY, f64::min);
        if d > tol {
            return None;
        }
        farthest = farthest.max(d);
        along.push(curvature(&deriv(c, x), &deriv2(c, x)));
    }
    // The drives move straight from one tick's pose to the next: each tick's chord of
    // the curve cuts inside it ([`tick_sag`]), which the tolerance must hold as well
    // (at 100 mm/s on a 5 mm radius, 0.25 µm; on cartesian-xyz, whose bends take up to
    // 1155 mm/s², at most 0.14 µm).
    let tightest = along.iter().map(|a| a.1).fold(0.0, f64::max);
    if farthest + tick_sag(g.speed, tightest, s) > tol {
        return None;
    }
    let vmax = along.iter().map(|a| a.0).fold(0.0, f64::max);
    let even = along.iter().map(|a| a.0).fold(f64::INFINITY, f64::min) / vmax;
    if vmax <= 0.0 || even < s.min_speed_ratio {
        return None;
    }
    // The score: how evenly the curve runs, times what its ends let the junctions
    // keep ([`junction_share`]): it starts at the end of the curve before it, and ends
    // at its largest speed (what a line, or the next curve's best start, has).
    let start = junction_share(along[0].0 / vmax - g.lead_ratio, g, s);
    let end = junction_share(1.0 - along[samples].0 / vmax, g, s);
    if start < s.min_junction_share {
        return None;
    }
    let even = even * start * end;
    if g.speed <= 0.0 || s.accel <= 0.0 || n < WEIGH_FROM {
        return Some(even);
    }
    // A curve that turns little is always fine: over a few degrees, its bend's speed
    // limit is the chords' own.
    let turn = dot(&unit(&sub(&c[1], &c[0])), &unit(&sub(&c[3], &c[2])));
    if turn >= s.max_turn_deg.to_radians().cos() {
        return Some(even);
    }
    let limit = |k: f64| {
        if k > 0.0 {
            g.speed.min((s.accel / (2.0 * k)).sqrt())
        } else {
            g.speed
        }
    };
    // The curve's time: ∫ |dP/du| du / (limit · |dP/du| / max) over u in [0, 1].
    let own = vmax / limit(tightest);
    (chords_time(p, g, s) >= own).then_some(even)
}

/// The share of the speed asked for that a junction where the tool's speed over the
/// path speed jumps by `jump` allows. The controller runs a curve's parameter at one
/// rate, the tool at |dP/du| over its largest times the path speed, so where two
/// curves meet along one direction the tool's speed jumps by the difference of their
/// ends' ratios, which the planner limits as a turn, with at most half the
/// acceleration in one tick: v·|jump| ≤ a·T/2. A jump of 1 % holds a junction to
/// 50 mm/s at 1000 mm/s². 1 when
/// the machine's figures are not known.
fn junction_share(jump: f64, g: &Goal, s: &Settings) -> f64 {
    let jump = jump.abs();
    if g.speed <= 0.0 || s.accel <= 0.0 || jump <= 0.0 {
        return 1.0;
    }
    (s.accel * TICK_S / 2.0 / (g.speed * jump)).min(1.0)
}

/// The ratio of |dP/du| at the end of `c` to its largest, over X Y Z (sampled as the
/// host's length is, [`pkmc::motion::geometry::spline::host_length`]'s grid).
pub(super) fn end_ratio(c: &[V; 4]) -> f64 {
    let speed = |u: f64| curvature(&deriv(c, u), &[0.0; AXES]).0;
    let top = (0..=64).map(|k| speed(k as f64 / 64.0)).fold(0.0, f64::max);
    if top > 0.0 {
        speed(1.0) / top
    } else {
        1.0
    }
}

/// How fast the controller runs `c` for its length, as a share of the speed asked for:
/// its mean |dP/du| over its largest (it runs the parameter at one rate, the tool at
/// |dP/du| over the largest times the path speed), times what its tightest bend allows
/// with the most a bend may take ([`Settings::bend_accel`]) over the speed asked for
/// (at most 1; the bend is not counted when the machine's figures are not known).
pub(super) fn pace(c: &[V; 4], g: &Goal, s: &Settings) -> f64 {
    let along: Vec<(f64, f64)> = (0..=64)
        .map(|k| {
            let u = k as f64 / 64.0;
            curvature(&deriv(c, u), &deriv2(c, u))
        })
        .collect();
    let top = along.iter().map(|a| a.0).fold(0.0, f64::max);
    if top <= 0.0 {
        return 1.0;
    }
    let mean = along.iter().map(|a| a.0).sum::<f64>() / along.len() as f64;
    let tightest = along.iter().map(|a| a.1).fold(0.0, f64::max);
    let bend = if g.speed > 0.0 && s.bend_accel > 0.0 && tightest > 0.0 {
        ((s.bend_accel / tightest).sqrt() / g.speed).min(1.0)
    } else {
        1.0
    };
    mean / top * bend
}

/// |dP/du| and the bend |dP/du × d²P/du²| / |dP/du|³ (per nm) over X Y Z, from the
/// first and second derivatives.
pub(super) fn curvature(d1: &V, d2: &V) -> (f64, f64) {
    let v = (d1[0] * d1[0] + d1[1] * d1[1] + d1[2] * d1[2]).sqrt();
    let cross = [
        d1[1] * d2[2] - d1[2] * d2[1],
        d1[2] * d2[0] - d1[0] * d2[2],
        d1[0] * d2[1] - d1[1] * d2[0],
    ];
    let bend = (cross[0] * cross[0] + cross[1] * cross[1] + cross[2] * cross[2]).sqrt()
        / v.powi(3).max(1e-300);
    (v, bend)
}

/// How far a tick's straight chord of a curve of bend `kappa` (per nm) cuts inside it,
/// nm: (v·T)²·κ/8, with v²κ at most the feed's (`speed`, nm/s) and at most what the
/// bend may take ([`Settings::bend_accel`]); 0 when that is not known (the machine's
/// settings, [`crate::job::compress_for_machine`], always give it).
pub(super) fn tick_sag(speed: f64, kappa: f64, s: &Settings) -> f64 {
    if s.bend_accel <= 0.0 {
        return 0.0;
    }
    (speed * speed * kappa).min(s.bend_accel) * TICK_S * TICK_S / 8.0
}

/// The chords' own time, s, estimated as the planner takes them: each vertex at the
/// speed its turn allows in one tick with half the acceleration (v·Δθ ≤ a·T/2) and its
/// bend allows (v²·κ ≤ a/2, κ = Δθ over the mean of the chords beside it), each chord
/// at the mean of its vertices' speeds, nothing faster than the feed.
fn chords_time(p: &[V], g: &Goal, s: &Settings) -> f64 {
    let n = p.len() - 1;
    let xyz = |v: &V| [v[0], v[1], v[2]];
    let d: Vec<[f64; 3]> = (0..n).map(|k| xyz(&sub(&p[k + 1], &p[k]))).collect();
    let len: Vec<f64> = d
        .iter()
        .map(|v| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt())
        .collect();
    let speed: Vec<f64> = (0..=n)
        .map(|k| {
            if k == 0 || k == n || len[k - 1] <= 0.0 || len[k] <= 0.0 {
                return g.speed;
            }
            let c = (d[k - 1][0] * d[k][0] + d[k - 1][1] * d[k][1] + d[k - 1][2] * d[k][2])
                / (len[k - 1] * len[k]);
            let turn = c.clamp(-1.0, 1.0).acos();
            if turn <= 0.0 {
                return g.speed;
            }
            let bend = turn / ((len[k - 1] + len[k]) / 2.0);
            g.speed
                .min(s.accel * TICK_S / (2.0 * turn))
                .min((s.accel / (2.0 * bend)).sqrt())
        })
        .collect();
    (0..n)
        .map(|k| len[k] / ((speed[k] + speed[k + 1]) / 2.0))
        .sum()
}

/// The control points with the least-squares lengths along the fixed tangents (the
/// chord's third when the fit is degenerate or points backwards).
fn lengths(p: &[V], u: &[f64], t0: &V, t1: &V, chord: f64) -> [V; 4] {
    let (p0, p3) = (p[0], p[p.len() - 1]);
    let (mut c11, mut c12, mut c22, mut x1, mut x2) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for (q, &x) in p.iter().zip(u) {
        let w = bernstein(x);
        let a1 = t0.map(|t| t * w[1]);
        let a2 = t1.map(|t| -t * w[2]);
        let base: V = core::array::from_fn(|i| (w[0] + w[1]) * p0[i] + (w[2] + w[3]) * p3[i]);
        let r = sub(q, &base);
        c11 += dot(&a1, &a1);
        c12 += dot(&a1, &a2);
        c22 += dot(&a2, &a2);
        x1 += dot(&a1, &r);
        x2 += dot(&a2, &r);
    }
    let det = c11 * c22 - c12 * c12;
    let (mut al, mut be) = if det.abs() > 1e-12 * (c11 * c22).max(1e-300) {
        ((x1 * c22 - x2 * c12) / det, (c11 * x2 - c12 * x1) / det)
    } else {
        (chord / 3.0, chord / 3.0)
    };
    if !(al > 1e-3 * chord && be > 1e-3 * chord && al < 2.0 * chord && be < 2.0 * chord) {
        al = chord / 3.0;
        be = chord / 3.0;
    }
    along(p0, p3, t0, t1, al, be)
}

/// One Newton step for the parameter of the curve point nearest `q`, kept in [0, 1].
fn newton(c: &[V; 4], q: &V, u: f64) -> f64 {
    let d = sub(&point(c, u), q);
    let (d1, d2) = (deriv(c, u), deriv2(c, u));
    let den = dot(&d1, &d1) + dot(&d, &d2);
    if den.abs() < 1e-12 {
        return u;
    }
    (u - dot(&d, &d1) / den).clamp(0.0, 1.0)
}

/// Distance from `q` to the segment `a`–`b`.
fn to_segment(q: &V, a: &V, b: &V) -> f64 {
    super::space::on_segment(q, a, b).1
}

/// Distance from `q` to the polyline through `pts` (the nearest of its segments).
pub fn to_polyline(q: &[f64; AXES], pts: &[[f64; AXES]]) -> f64 {
    pts.windows(2)
        .map(|w| to_segment(q, &w[0], &w[1]))
        .fold(f64::INFINITY, f64::min)
}
