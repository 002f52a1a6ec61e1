//! A block's speed and acceleration limits from every pose axis and joint, sampled
//! along it through the kinematics, and the acceleration shared at a corner.

use crate::config::{MachineConfig, AXES, MAX_JOINTS};
use crate::kinematics::{Jacobian, Kinematics, MachineKinematics, Unreachable};
use crate::math::sqrtf;
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
    machine: &MachineConfig,
    kin: &MachineKinematics,
) -> Result<(f32, f32), Unreachable> {
    let (mut v, mut a) = (f32::INFINITY, f32::INFINITY);
    let n = machine.joints.len();
    let len = path.length << 16;
    // The speed a bend's share of the acceleration is sized for: the requested one,
    // but on a spline the programmed feed (as at a blended corner, whose limit is
    // sized for the programmed speed: a curve that stands for chords keeps their
    // acceleration, and the override cannot take it faster than its bend allows);
    // and on a spline the bend may take up to [`SPLINE_BEND_SHARE`].
    let bend_feed = match bend_speed {
        Some(v) => v,
        None if path.form == Form::Spline => feed / 2.0,
        None => feed,
    };
    let bend_most = if path.form == Form::Spline {
        SPLINE_BEND_SHARE
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
            split(&mut v, &mut a, bend_feed, d1, d2, amax, bend_most);
        }
    }
    if let Some(r) = path.radius() {
        // Half the acceleration for the tangential profile, half for the centripetal
        // v²/r: an axis then never sees more than a.
        a /= 2.0;
        v = v.min(crate::math::sqrtf(a * r as f32));
    }
    if let crate::motion::geometry::Bend::Spline(c) = &path.bend {
        // An axis moves at x′·v and accelerates at x′·a + x″·v², with x′ and x″ its
        // exact largest first and second derivatives along the curve: half of its
        // acceleration for each term, as for joints.
        let (d1, d2) = path.course.spline_bounds(c);
        for i in 0..AXES {
            let l = &machine.axes[i];
            if d1[i] > 1e-12 && l.max_velocity > 0 {
                v = v.min(per_tick(l.max_velocity) / d1[i]);
            }
            if l.max_accel > 0 {
                split(
                    &mut v,
                    &mut a,
                    bend_feed,
                    d1[i],
                    d2[i],
                    per_tick2(l.max_accel),
                    bend_most,
                );
            }
        }
    }
    // Single-precision planning rounds to about 10⁻⁷: stay that far inside.
    Ok((v * LIMIT_MARGIN, a * LIMIT_MARGIN))
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
pub(super) fn split(v: &mut f32, a: &mut f32, feed: f32, d1: f32, d2: f32, amax: f32, most: f32) {
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
