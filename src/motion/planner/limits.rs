//! A block's speed and acceleration limits from every pose axis and joint, sampled
//! along it through the kinematics, and the acceleration shared at a corner.

use crate::config::{MachineConfig, AXES, MAX_JOINTS};
use crate::kinematics::{Jacobian, Kinematics, MachineKinematics, Unreachable};
use crate::math::{fmax, fmin, sqrtf};
use crate::motion::block::Dip;
use crate::motion::geometry::{Form, Path};
use crate::units::TICK_HZ;

/// Factor applied to every planned limit so that single-precision rounding cannot
/// take a joint past its own limit.
pub const LIMIT_MARGIN: f32 = 1.0 - 4e-6;

/// Points sampled along a block for its speed limits.
pub const LIMIT_SAMPLES: usize = 5;

/// Most of an axis's or joint's acceleration a spline's bend may take (a half on
/// lines and arcs, see [`split`]): a curve that stands for a run of short moves is
/// taken at a near-constant speed, so its profile needs the smaller share; the
/// chords it stands for, with a corner every few hundred micrometres, would turn
/// with about as much.
pub const SPLINE_BEND_SHARE: f32 = 2.0 / 3.0;

/// Points sampled along a spline (whose bend varies along it: the joints' rates
/// between samples are bounded by their change, which closer samples keep tight).
pub const SPLINE_SAMPLES: usize = 17;

pub(super) fn per_tick(v: i64) -> f32 {
    v as f32 / TICK_HZ as f32
}

pub(super) fn per_tick2(a: i64) -> f32 {
    a as f32 / (TICK_HZ as f32 * TICK_HZ as f32)
}

/// Joint rates per unit of path along `tangent` at `pose`: q′ = J·t, with the
/// kinematics' analytic Jacobian J = ∂q/∂p.
pub(super) fn joint_rates(
    pose: &[i64; AXES],
    tangent: &[f32; AXES],
    kin: &MachineKinematics,
    n: usize,
) -> Result<[f32; MAX_JOINTS], Unreachable> {
    let mut jac: Jacobian = [[0.0; AXES]; MAX_JOINTS];
    kin.jacobian(pose, &mut jac)?;
    let mut r = [0f32; MAX_JOINTS];
    for (r, row) in r.iter_mut().zip(&jac).take(n) {
        *r = row.iter().zip(tangent).map(|(j, t)| j * t).sum();
    }
    Ok(r)
}

/// Speed (nm/tick) and acceleration (nm/tick²) limits of a path for a requested speed
/// `feed` (nm/tick), from every axis and joint at [`LIMIT_SAMPLES`] points, and from
/// curvature.
///
/// A joint moves at q′·v and accelerates at q′·a + q″·v² (q′, q″ its first and second
/// derivatives along the path: q′ = J·t from the kinematics' analytic Jacobian, q″ a
/// central difference of q′, free of the joints' nm rounding that a second difference
/// of the inverse would divide by h²). Where the q″·v² term matters at the requested
/// speed, each joint's acceleration budget is split: half for q′·a, half for q″·v²
/// (v ≤ √(aⱼ/(2|q″|))). On arcs the pose axes get the same split against the
/// centripetal v²/r. Fails when a sampled pose is out of reach or outside a joint's
/// travel.
pub(super) fn limits_along(
    start: &[i64; AXES],
    path: &Path,
    feed: f32,
    bend_speed: Option<f32>,
    spline_bend_most: f32,
    machine: &MachineConfig,
    kin: &MachineKinematics,
) -> Result<Limits, Unreachable> {
    let (mut v, mut a) = (f32::INFINITY, f32::INFINITY);
    // On a spline, the bend's limits stay where they are along it: each joint's
    // terms per sample, each axis's per stretch, combined into `bend` below once the
    // acceleration is known.
    let spline = path.form == Form::Spline;
    let mut at_sample = [[Term::NONE; MAX_JOINTS]; SPLINE_SAMPLES];
    let mut per_stretch = [[Term::NONE; AXES]; STRETCHES];
    let n = machine.joints.len();
    let len = path.length << 16;
    // The speed a bend's share of the acceleration is sized for: the requested one,
    // but on a spline the programmed feed (as at a blended corner, whose limit is
    // sized for the programmed speed: a curve that stands for chords keeps their
    // acceleration, and the override cannot take it faster than its bend allows);
    // and on a spline the bend may take up to `spline_bend_most`.
    let bend_feed = match bend_speed {
        Some(v) => v,
        None if path.form == Form::Spline => feed / 2.0,
        None => feed,
    };
    let bend_most = if path.form == Form::Spline {
        spline_bend_most
    } else {
        0.5
    };
    // Difference step: 0.25 mm, or a quarter of a short block (nm Q16).
    let h = (len / 4).clamp(1 << 16, 250_000 << 16);
    let samples = if path.form == Form::Spline {
        SPLINE_SAMPLES
    } else {
        LIMIT_SAMPLES
    };
    let spacing = path.length as f32 / (samples - 1) as f32;
    let mut q = [0i64; MAX_JOINTS];
    let mut pose = [0i64; AXES];
    for k in 0..samples {
        let s = (len as i128 * k as i128 / (samples as i128 - 1)) as i64;
        path.pose_at(start, s, &mut pose);
        kin.inverse_checked(&pose, &machine.joints, &mut q)?;
        let t = path.tangent_at(s);
        for (rate, l) in t.iter().zip(&machine.axes) {
            let r = rate.abs();
            if r > 1e-12 {
                v = v.min(per_tick(l.max_velocity) / r);
                a = a.min(per_tick2(l.max_accel) / r);
            }
        }
        let rate = joint_rates(&pose, &t, kin, n)?;
        // q″: central difference of the rates inside the block.
        let mid = s.clamp(h.min(len / 2), (len - h).max(len / 2));
        let (s0, s2) = (mid - h.min(mid), mid + h);
        path.pose_at(start, s0, &mut pose);
        let r0 = joint_rates(&pose, &path.tangent_at(s0), kin, n)?;
        path.pose_at(start, s2, &mut pose);
        let r2 = joint_rates(&pose, &path.tangent_at(s2), kin, n)?;
        let span = (s2 - s0) as f32 / 65_536.0;
        for j in 0..n {
            let jc = &machine.joints[j];
            let d2 = ((r2[j] - r0[j]) / span).abs();
            // The rate may grow between samples by up to |q″| × half the spacing.
            let d1 = rate[j].abs() + d2 * spacing / 2.0;
            let (vmax, amax) = (
                per_tick(jc.limits.max_velocity),
                per_tick2(jc.limits.max_accel),
            );
            if d1 > 1e-12 {
                v = v.min(vmax / d1);
            }
            if let Some(terms) = at_sample.get_mut(k).filter(|_| spline) {
                // The share is chosen as on other blocks; the speed it allows is
                // found below, where the bend is.
                let mut speed = v;
                let share = split(&mut speed, &mut a, bend_feed, d1, d2, amax, bend_most);
                terms[j] = Term {
                    d1,
                    d2,
                    amax,
                    share,
                };
            } else {
                split(&mut v, &mut a, bend_feed, d1, d2, amax, bend_most);
            }
        }
    }
    if let Some(r) = path.radius() {
        // Half the acceleration for the tangential profile, half for the centripetal
        // v²/r: an axis then never sees more than a.
        a /= 2.0;
        v = v.min(crate::math::sqrtf(a * r as f32));
    }
    if let crate::motion::geometry::Bend::Spline(c, _) = &path.bend {
        (v, a) = spline_axes(
            path,
            c,
            (bend_feed, bend_most),
            machine,
            (v, a),
            &mut per_stretch,
        );
    }
    let bend = spline.then(|| {
        let sampled = joint_terms(machine, kin, n);
        bend_limits(a, &at_sample[..], sampled, &per_stretch)
    });
    // Single-precision planning rounds to about 10⁻⁷: stay that far inside.
    Ok(Limits {
        v: v * LIMIT_MARGIN,
        a: a * LIMIT_MARGIN,
        bend: bend.map_or([f32::INFINITY; STRETCHES], |b| b.map(|b| b * LIMIT_MARGIN)),
    })
}

/// A spline's limits `(v, a)` lowered for its pose axes, and their [`Term`]s over each
/// stretch into `per_stretch`. An axis moves at x′·v and accelerates at x′·a + x″·v²,
/// with x′ and x″ its exact largest first and second derivatives along the curve: the
/// share of its acceleration its bend needs at `bend_feed`, at most `most`, is taken
/// from the profile's, as for joints.
fn spline_axes(
    path: &Path,
    curve: &crate::motion::geometry::Curve,
    (bend_feed, most): (f32, f32),
    machine: &MachineConfig,
    (mut v, mut a): (f32, f32),
    per_stretch: &mut [[Term; AXES]; STRETCHES],
) -> (f32, f32) {
    let (d1, d2) = path.course.spline_bounds(curve);
    let mut shares = [0f32; AXES];
    for (i, l) in machine.axes.iter().enumerate() {
        if d1[i] > 1e-12 && l.max_velocity > 0 {
            v = v.min(per_tick(l.max_velocity) / d1[i]);
        }
        if l.max_accel > 0 {
            let mut speed = v;
            let amax = per_tick2(l.max_accel);
            shares[i] = split(&mut speed, &mut a, bend_feed, d1[i], d2[i], amax, most);
        }
    }
    axis_terms(path, &d1, &shares, machine, per_stretch);
    (v, a)
}

/// A bend's part in an axis's or a joint's acceleration over a stretch of a spline:
/// |x′| ≤ `d1` and |x″| ≤ `d2` there, of a budget `amax` (nm/tick²), of which the
/// share `share` was set aside for the bend ([`split`]).
#[derive(Clone, Copy, Debug)]
struct Term {
    d1: f32,
    d2: f32,
    amax: f32,
    share: f32,
}

impl Term {
    const NONE: Term = Term {
        d1: 0.0,
        d2: 0.0,
        amax: 0.0,
        share: 0.0,
    };
}

/// Each pose axis's [`Term`] over each stretch of a spline. Along a cubic x″ is linear
/// in the parameter, so its largest over a stretch is at one of the stretch's ends;
/// x′ is a quadratic, within the larger of its ends' values and the gap between its
/// middle and their mean (q = line + 4·δ·t(1 − t), 4t(1 − t) ≤ 1), and within its
/// largest along the whole curve, `d1`.
fn axis_terms(
    path: &Path,
    d1: &[f32; AXES],
    shares: &[f32; AXES],
    machine: &MachineConfig,
    out: &mut [[Term; AXES]; STRETCHES],
) {
    let len = path.length << 16;
    let at = |k2: usize| (len as i128 * k2 as i128 / (2 * STRETCHES) as i128) as i64;
    for (k, terms) in out.iter_mut().enumerate() {
        let (s0, sm, s1) = (at(2 * k), at(2 * k + 1), at(2 * k + 2));
        let (b0, b1) = (path.bend_at(s0), path.bend_at(s1));
        let (t0, tm, t1) = (
            path.tangent_at(s0),
            path.tangent_at(sm),
            path.tangent_at(s1),
        );
        for i in 0..AXES {
            let l = &machine.axes[i];
            if l.max_accel <= 0 {
                continue;
            }
            let gap = (tm[i] - (t0[i] + t1[i]) / 2.0).abs();
            terms[i] = Term {
                d1: (t0[i].abs().max(t1[i].abs()) + gap).min(d1[i]),
                d2: b0[i].abs().max(b1[i].abs()),
                amax: per_tick2(l.max_accel),
                share: shares[i],
            };
        }
    }
}

/// The speed (nm/tick) each stretch of a spline's bend allows when its profile
/// accelerates at `a`: every axis and joint keeps |x′|·a + |x″|·v² within its budget
/// there (the joints' terms at the stretch's two samples, `at_sample[k]` and
/// `at_sample[k + 1]`, of `joints` joints; the axes' over the stretch). Where a term's
/// x′ is smaller than the block's largest, which set `a`, the bend gets more than the
/// share it was given (never less, which `a` leaves it whatever the rounding): most of
/// all where the curve turns an axis around.
fn bend_limits(
    a: f32,
    at_sample: &[[Term; MAX_JOINTS]],
    joints: usize,
    per_stretch: &[[Term; AXES]; STRETCHES],
) -> [f32; STRETCHES] {
    core::array::from_fn(|k| {
        let j = k / PER_SAMPLE;
        let joint_terms = at_sample[j][..joints]
            .iter()
            .chain(&at_sample[j + 1][..joints]);
        let v2 = joint_terms
            .chain(&per_stretch[k])
            .filter(|t| t.d2 > 0.0)
            .map(|t| (t.amax - t.d1 * a).max(t.share * t.amax) / t.d2)
            .fold(f32::INFINITY, f32::min);
        sqrtf(v2)
    })
}

/// Stretches a spline is cut into for its bend's speed limits ([`Limits::bend`]).
pub const STRETCHES: usize = 64;

/// Stretches between two of a spline's joint samples.
const PER_SAMPLE: usize = STRETCHES / (SPLINE_SAMPLES - 1);
const _: () = assert!(PER_SAMPLE * (SPLINE_SAMPLES - 1) == STRETCHES);

/// How many joints' sampled terms bound a spline's bend: none on a Cartesian machine
/// whose every joint allows at least its axis's speed and acceleration (a joint there
/// moves exactly as its axis, whose exact terms over each stretch bind it), else all
/// `n`.
fn joint_terms(machine: &MachineConfig, kin: &MachineKinematics, n: usize) -> usize {
    let MachineKinematics::Cartesian(c) = kin else {
        return n;
    };
    let covered = machine.joints.iter().enumerate().all(|(j, jc)| {
        let l = &machine.axes[c.axis_of(j)];
        jc.limits.max_accel >= l.max_accel && jc.limits.max_velocity >= l.max_velocity
    });
    if covered {
        0
    } else {
        n
    }
}

// A dip is kept in 256ths of its block's length, where every stretch's middle falls.
const _: () = assert!(STRETCHES.is_power_of_two() && STRETCHES <= 128);

/// An end speed just under the one whose ramp meets a stretch's limit, so that
/// [`Limits::top`] finds it under whatever the rounding.
const JUST_UNDER: f32 = 1.0 - 4e-6;

/// A block's limits ([`limits_along`]).
#[derive(Clone, Copy, Debug)]
pub(super) struct Limits {
    /// Speed limit from everything but a spline's bend, nm/tick.
    pub v: f32,
    /// Acceleration limit along the block, nm/tick².
    pub a: f32,
    /// On a spline, the speed its bend allows over each of [`STRETCHES`] equal
    /// stretches of its length, nm/tick (∞ on other blocks, whose bend is in `v`).
    pub bend: [f32; STRETCHES],
}

impl Limits {
    /// The smallest speed limit anywhere along the block, nm/tick.
    pub fn lowest(&self) -> f32 {
        self.bend.iter().fold(self.v, |m, &b| m.min(b))
    }

    /// The speed limit (nm/tick) of a spline entered at no more than `entry` and left
    /// at no more than `exit` (nm/tick) at acceleration `a` over `length` nm: over a
    /// stretch that the ramp from either end stays below its bend's limit, the bend
    /// does not bind; elsewhere it does. A profile so limited stays under every
    /// stretch's limit whatever speeds at or below `entry` and `exit` it runs between.
    pub fn top(&self, entry: f32, exit: f32, a: f32, length: f32) -> f32 {
        self.top_within((entry, 0.0), (exit, length), 0..STRETCHES, a, length)
    }

    /// [`Limits::top`] of the piece of a spline from `start` to `end` (nm from its
    /// start) entered at no more than `entry` and left at no more than `exit`, over its
    /// `stretches`.
    fn top_within(
        &self,
        (entry, start): (f32, f32),
        (exit, end): (f32, f32),
        stretches: core::ops::Range<usize>,
        a: f32,
        length: f32,
    ) -> f32 {
        let (e2, x2) = (entry * entry, exit * exit);
        let mut top = self.v;
        for k in stretches {
            let b = self.bend[k];
            let (s0, s1) = (
                length * k as f32 / STRETCHES as f32,
                length * (k + 1) as f32 / STRETCHES as f32,
            );
            let b2 = b * b;
            if e2 + 2.0 * a * (s1 - start) > b2 && x2 + 2.0 * a * (end - s0) > b2 {
                top = top.min(b);
            }
        }
        top
    }

    /// A dip for a spline entered at `entry` and left at `exit` (nm/tick) at
    /// acceleration `a` over `length` nm, asked for at `near`: when its profile through
    /// the middle of one inner stretch at a lower speed, faster on either side, takes
    /// less time than one speed limit for the whole block ([`Limits::top`]), that
    /// stretch's dip, and the speed limit before it. The dip's speed is the one from
    /// which ramps at `a` reach the stretch's limit at its ends, so that the stretch
    /// stays under it; the ends must be within reach of the dip and under the limits on
    /// either side. Returns (dip, limit before it, the profile's time in ticks).
    pub fn dip(
        &self,
        entry: f32,
        exit: f32,
        a: f32,
        length: f32,
        near: f32,
    ) -> Option<(Dip, f32, f32)> {
        let whole = ramp_time(
            entry,
            self.top(entry, exit, a, length).min(near),
            exit,
            a,
            length,
        );
        let stretch = length / STRETCHES as f32;
        let mut best = None;
        // Worth a dip only where it saves more than rounding (a tick in ten thousand).
        let mut best_time = whole * (1.0 - 1e-4);
        for k in 1..STRETCHES - 1 {
            // The stretch's middle, in the 256ths of the length a dip is kept in.
            let at_256 = ((2 * k + 1) * 128 / STRETCHES) as u8;
            let at = length * at_256 as f32 / 256.0;
            let b = self.bend[k].min(self.v);
            let speed = sqrtf((b * b - a * stretch).max(0.0)) * JUST_UNDER;
            let before = self.top_within((entry, 0.0), (speed, at), 0..k, a, length);
            let after = self.top_within((speed, at), (exit, length), k + 1..STRETCHES, a, length);
            // Passed no faster than either side may run (a lower dip leaves the limits
            // on either side as they are or higher), its speeds as they are kept.
            let dip = Dip::new(at_256, speed.min(before).min(after), after);
            let (speed, after) = (dip.speed(), dip.after());
            let v2 = speed * speed;
            if speed <= 0.0
                || entry > before
                || exit > after
                || entry * entry > v2 + 2.0 * a * at
                || exit * exit > v2 + 2.0 * a * (length - at)
            {
                continue;
            }
            let t = ramp_time(entry, before.min(near), speed, a, at)
                + ramp_time(speed, after.min(near), exit, a, length - at);
            if t < best_time {
                best_time = t;
                best = Some((dip, before, t));
            }
        }
        best
    }

    /// The entry and exit limits (nm/tick) to give a spline whose entry is at most
    /// `entry_most`, and the speed limit that goes with them ([`Limits::top`]), for
    /// acceleration `a` over `length` nm: of the ends at which a ramp just stays
    /// under a stretch's limit (lower ends let the block run faster between them),
    /// the pair whose profile at up to `near` (the programmed speed) takes least time,
    /// counting for each end the time a neighbour at that speed loses slowing down to
    /// it. Returns (entry, exit, top).
    pub fn ends(&self, entry_most: f32, a: f32, length: f32, near: f32) -> (f32, f32, f32) {
        let first = self.bend[0].min(self.v).min(entry_most);
        let last = self.bend[STRETCHES - 1].min(self.v);
        // The end speeds at which the ramp from the start (the end) just meets stretch
        // k's limit at its far side.
        let from_start = |k: usize| -> f32 {
            let s1 = length * (k + 1) as f32 / STRETCHES as f32;
            (sqrtf((self.bend[k] * self.bend[k] - 2.0 * a * s1).max(0.0)) * JUST_UNDER).min(first)
        };
        let from_end = |k: usize| -> f32 {
            let s0 = length * k as f32 / STRETCHES as f32;
            let v2 = self.bend[k] * self.bend[k] - 2.0 * a * (length - s0);
            (sqrtf(v2.max(0.0)) * JUST_UNDER).min(last)
        };
        let lost = |v: f32| -> f32 {
            if v >= near {
                0.0
            } else {
                (near - v) * (near - v) / (2.0 * a * near)
            }
        };
        let mut best = (first, last, self.top(first, last, a, length));
        let mut best_time = f32::INFINITY;
        for i in 0..=STRETCHES {
            let e = if i == STRETCHES { first } else { from_start(i) };
            for j in 0..=STRETCHES {
                let x = if j == STRETCHES { last } else { from_end(j) };
                let top = self.top(e, x, a, length);
                // The ends the passes could give it: within its cap, and each within
                // reach of the other over its length.
                let e_at = e.min(top).min(sqrtf(x * x + 2.0 * a * length));
                let x_at = x.min(top).min(sqrtf(e_at * e_at + 2.0 * a * length));
                let t = ramp_time(e_at, top.min(near), x_at, a, length) + lost(e_at) + lost(x_at);
                if t < best_time {
                    best_time = t;
                    best = (e, x, top);
                }
            }
        }
        best
    }
}

/// The time (ticks) of a trapezoidal profile from `entry` to `exit` (nm/tick) capped
/// at `top` over `length` nm at acceleration `a` (entry and exit taken at most `top`).
pub(super) fn ramp_time(entry: f32, top: f32, exit: f32, a: f32, length: f32) -> f32 {
    let (e, x) = (entry.min(top), exit.min(top));
    if top <= 0.0 {
        return f32::INFINITY;
    }
    // The peak the two ramps meet at, if below the cap.
    let peak = sqrtf((e * e + x * x) / 2.0 + a * length).min(top);
    let up = (peak * peak - e * e).max(0.0) / (2.0 * a);
    let down = (peak * peak - x * x).max(0.0) / (2.0 * a);
    let cruise = (length - up - down).max(0.0);
    (peak - e).max(0.0) / a + (peak - x).max(0.0) / a + cruise / peak.max(1e-9)
}

/// One of the two blocks meeting at a corner, for [`corner_share`].
pub(super) struct Side {
    /// Speed at its other end, nm/tick (NaN: as at the corner).
    pub(super) far: f32,
    /// Its speed limit, nm/tick.
    pub(super) top: f32,
    /// Its acceleration before any corner's share, nm/tick².
    pub(super) a: f32,
    /// The share its other corner takes already.
    pub(super) taken: f32,
    /// Its length, nm.
    pub(super) length: f32,
}

/// The share of the acceleration worth giving a corner's turn, at most `most` (what
/// the turn needs at the speed asked for): of `most`, its halves down to 1/32 and 0,
/// the one under which the two blocks meeting there take least time, each a
/// trapezoid through the corner's speed `speed(ρ)` with (1 − ρ) of its acceleration,
/// and a stop the smoothing's `settle` ticks more. A sharp turn passed within one tick
/// goes at a fraction of aᵢ·T, which is seldom worth half of either block's
/// acceleration; a gentle one keeps its share.
pub(super) fn corner_share(
    most: f32,
    (speed, share): (impl Fn(f32) -> f32, impl Fn(f32) -> f32),
    sides: [Option<Side>; 2],
    settle: f32,
) -> f32 {
    // The share at which the corner's speed is what the sides can reach from their
    // other ends at full acceleration: more buys nothing there. Along a chain of
    // short blocks that is where each corner must be for the next to be faster.
    let reach = sides.iter().flatten().fold(f32::INFINITY, |c, s| {
        fmin(c, sqrtf(s.far * s.far + 2.0 * s.a * s.length))
    });
    let enough = fmin(share(reach), most);
    let mut best = (f32::INFINITY, 0.0);
    for k in 0..8 {
        let rho = match k {
            0 => enough,
            7 => 0.0,
            _ => fmin(enough, most / (1u32 << (k - 1)) as f32),
        };
        let a = |s: &Side| s.a * (1.0 - fmax(rho, s.taken));
        // No faster than a side can reach from its other end.
        let c = sides.iter().flatten().fold(speed(rho), |c, s| {
            fmin(c, sqrtf(s.far * s.far + 2.0 * a(s) * s.length))
        });
        let mut t = if c > 0.0 { 0.0 } else { settle };
        for s in sides.iter().flatten() {
            // Nor faster at its other end than it can slow down to the corner from.
            let far = if s.far.is_nan() {
                c
            } else {
                fmin(s.far, sqrtf(c * c + 2.0 * a(s) * s.length))
            };
            t += ramp_time(far, s.top, c, a(s), s.length);
        }
        if t < best.0 {
            best = (t, rho);
        }
    }
    best.1
}

/// The speed (nm/tick) at which a jump `jump` of d²P/ds² (per nm²) at `pose` changes
/// no axis's or joint's acceleration by more than aᵢ/w in one tick (∞ when nothing
/// jumps; 0 where the kinematics cannot be evaluated).
pub(super) fn bend_jump_limit(
    jump: &[f32; AXES],
    pose: &[i64; AXES],
    smoothing: u32,
    machine: &MachineConfig,
    kin: &MachineKinematics,
) -> f32 {
    if jump.iter().all(|j| j.abs() < 1e-20) {
        return f32::INFINITY;
    }
    let w = smoothing.max(1) as f32;
    let mut v2 = f32::INFINITY;
    for (j, l) in jump.iter().zip(&machine.axes) {
        if j.abs() > 1e-20 && l.max_accel > 0 {
            v2 = v2.min(per_tick2(l.max_accel) / (w * j.abs()));
        }
    }
    // The joints' jump: J·Δx″ (the rest of q″, from the Jacobian's change along the
    // tangent, is the same on both sides of a tangent-continuous join).
    let n = machine.joints.len();
    let Ok(dq) = joint_rates(pose, jump, kin, n) else {
        return 0.0;
    };
    for (d, jc) in dq.iter().zip(&machine.joints) {
        if d.abs() > 1e-20 {
            v2 = v2.min(per_tick2(jc.limits.max_accel) / (w * d.abs()));
        }
    }
    sqrtf(v2)
}

/// Splits an axis's or joint's acceleration budget `amax` between the two terms of
/// its acceleration along a path, x′·a + x″·v² (x′, x″ its largest first and second
/// derivatives along the path): the share ρ the bend needs at the speed asked for
/// (`feed`, or the limit `v` found so far when lower), at most `most`, goes to
/// x″·v² — which caps `v` there — and the rest to the profile's x′·a. A straight
/// path keeps its whole budget; together never more than `amax`.
pub(super) fn split(
    v: &mut f32,
    a: &mut f32,
    feed: f32,
    d1: f32,
    d2: f32,
    amax: f32,
    most: f32,
) -> f32 {
    let speed = feed.min(*v);
    let rho = if d2 > 0.0 {
        (d2 * speed * speed / amax).min(most)
    } else {
        0.0
    };
    if d1 > 1e-12 {
        *a = a.min((1.0 - rho) * amax / d1);
    }
    if d2 > 0.0 && rho > 0.0 {
        *v = v.min(crate::math::sqrtf(rho * amax / d2));
    }
    rho
}

/// What turning from `u1` to `u2` at `pose` costs: the largest |Δuᵢ| / aᵢ over every
/// axis and joint (ticks per nm/tick), so that a corner taken at speed v uses the
/// share v·need of the tightest acceleration budget in one tick. `None` when the
/// kinematics cannot be evaluated there (the corner is then a stop).
pub(super) fn corner_need(
    u1: &[f32; AXES],
    u2: &[f32; AXES],
    pose: &[i64; AXES],
    machine: &MachineConfig,
    kin: &MachineKinematics,
) -> Option<f32> {
    let mut need = 0.0f32;
    for i in 0..AXES {
        let d = (u2[i] - u1[i]).abs();
        if d > 1e-9 && machine.axes[i].max_accel > 0 {
            need = need.max(d / per_tick2(machine.axes[i].max_accel));
        }
    }
    let n = machine.joints.len();
    let r1 = joint_rates(pose, u1, kin, n).ok()?;
    let r2 = joint_rates(pose, u2, kin, n).ok()?;
    for (j, jc) in machine.joints.iter().enumerate() {
        let d = (r2[j] - r1[j]).abs();
        if d > 1e-9 {
            need = need.max(d / per_tick2(jc.limits.max_accel));
        }
    }
    Some(need)
}
