//! The second look at the splines ([`refine_splines`]): once the passes know how fast
//! each block runs, a spline's limits are found again for the speeds it is entered and
//! left at; and each pass sequence starts again from the blocks as they were planned
//! ([`restore`]).

use super::limits::{limits_along, ramp_time, Limits, SPLINE_BEND_SHARE};
use super::lookahead::{Kind, PlanBlock};
use crate::config::{MachineConfig, AXES};
use crate::kinematics::MachineKinematics;
use crate::math::{fmax, fmin, sqrtf};
use crate::motion::block::Dip;
use crate::motion::geometry::{Form, Path};

/// `blocks[from..]` as they were planned ([`PlanBlock::first`]), before an earlier
/// pass sequence set their splines for the speeds it found; the first one entered no
/// faster than the block before it (final) may be left at.
pub(super) fn restore(blocks: &mut [PlanBlock], from: usize) {
    for i in from..blocks.len() {
        let rho_out = blocks.get(i + 1).map_or(0.0, |n| n.rho_in);
        let b = &mut blocks[i];
        let [corner, v_limit, accel_full, exit_most] = b.first;
        b.corner = corner;
        b.v_limit = v_limit;
        b.exit_most = exit_most;
        b.dip = None;
        if accel_full != b.accel_full {
            b.accel_full = accel_full;
            b.accel = accel_full * (1.0 - fmax(b.rho_in, rho_out));
        }
    }
    if let Some(last) = from.checked_sub(1) {
        let most = blocks[last].exit_most;
        if let Some(b) = blocks.get_mut(from) {
            b.corner = fmin(b.corner, most);
        }
    }
}

/// A second look at the splines once the passes know how fast each one runs
/// (`blocks[from..]`; `start`: where `blocks[0]` starts). Each spline's limits are
/// found again (as it was planned, with [`Lookahead`]'s jerk-limitation window
/// `smoothing`), for the entry and exit the passes planned:
/// * its speed limit is raised to what those ends allow ([`Limits::top`]): ramps from
///   ends slower than its own limits leave more of it under its bend's limits;
/// * a spline that does not reach its speed limit (a neighbour's corner, a bend
///   further on, the stop at the end) gives its bend the acceleration share it needs
///   at the speed it reaches ([`split`]), and its profile the rest, when that is more;
///   its speed limit is then what the bend allows at that share.
///
/// Its entry and exit are then held at most at the planned ones (its corner and the
/// next block's), for which its limit holds. True when any spline changed (the passes
/// are then run again). `between` is called before each spline is looked at.
pub fn refine_splines(
    blocks: &mut [PlanBlock],
    from: usize,
    start: [i64; AXES],
    smoothing: u32,
    machine: &MachineConfig,
    kin: &MachineKinematics,
    between: &mut dyn FnMut(),
) -> bool {
    let mut changed = false;
    for i in from..blocks.len() {
        let b = &blocks[i];
        if b.path.form != Form::Spline || b.kind != Kind::Feed {
            continue;
        }
        between();
        let next = blocks.get(i + 1);
        let exit = next
            .filter(|n| matches!(n.kind, Kind::Rapid | Kind::Feed))
            .map_or(0.0, |n| n.entry);
        let from_pose = if i == 0 {
            start
        } else {
            blocks[i - 1].path.end
        };
        let rho_out = next.map_or(0.0, |n| n.rho_in);
        let entry = b.entry;
        let Some((v_limit, accel_full, dip)) =
            better_spline(b, &from_pose, exit, smoothing, machine, kin)
        else {
            continue;
        };
        let b = &mut blocks[i];
        b.v_limit = v_limit;
        b.accel_full = accel_full;
        b.accel = accel_full * (1.0 - fmax(b.rho_in, rho_out));
        b.dip = dip;
        b.corner = fmin(b.corner, entry);
        b.exit_most = fmin(b.exit_most, exit);
        if let Some(n) = blocks.get_mut(i + 1) {
            n.corner = fmin(n.corner, exit);
        }
        changed = true;
    }
    changed
}

/// [`refine_splines`]'s look at spline `b` (from `from_pose`) entered at its planned
/// entry and left at `exit`: its new speed limit (before its dip, when it has one),
/// acceleration and dip ([`Limits::dip`]), if better.
fn better_spline(
    b: &PlanBlock,
    from_pose: &[i64; AXES],
    exit: f32,
    smoothing: u32,
    machine: &MachineConfig,
    kin: &MachineKinematics,
) -> Option<(f32, f32, Option<Dip>)> {
    let (entry, length) = (b.entry, b.length());
    let limits = |bend_speed, most| {
        limits_along(
            from_pose,
            &b.path,
            b.feed * 2.0,
            bend_speed,
            most,
            machine,
            kin,
        )
        .ok()
        .map(|l| smoothed(l, &b.path, smoothing))
    };
    // The share of the acceleration its corners take.
    let kept = b.accel / b.accel_full;
    let time = |v: f32, a: f32| ramp_time(entry, fmin(v, b.feed), exit, a, length);
    // Each split's profile time between the planned ends: one speed limit for the
    // whole curve, or a dip ([`Limits::dip`]) where that is faster.
    let timed = |l: Limits, a_full: f32| {
        let a = a_full * kept;
        let v = l.top(entry, exit, a, length);
        let plain = time(v, a);
        match l.dip(entry, exit, a, length, b.feed) {
            Some((dip, before, t)) if t < plain => (t, before, a_full, Some(dip)),
            _ => (plain, v, a_full, None),
        }
    };
    let planned = limits(None, SPLINE_BEND_SHARE)?;
    let top = fmin(b.feed, planned.top(entry, exit, b.accel, length));
    let peak = fmin(
        sqrtf((entry * entry + exit * exit) / 2.0 + b.accel * length),
        top,
    );
    let mut best = timed(planned, b.accel_full);
    // Another split of the axes' acceleration between the bend and the profile: less
    // for the bend where the profile's ramps bind, more where the bend does. Each is
    // timed between the planned ends, which its profile must still join.
    const CAPS: [f32; 7] = [0.2, 1.0 / 3.0, 0.5, 0.6, 0.75, 0.85, 0.95];
    // And the planned cap with the bend sized for the speed the profile peaks at,
    // where that is well below the top.
    let at_peak =
        (peak < 0.98 * top && peak > 0.0).then_some((Some(peak * 1.01), SPLINE_BEND_SHARE));
    for (bend_speed, most) in CAPS.iter().map(|&most| (None, most)).chain(at_peak) {
        if let Some(l) = limits(bend_speed, most) {
            // A split whose profile cannot join the planned ends is not timed.
            if (entry * entry - exit * exit).abs() > 2.0 * l.a * kept * length {
                continue;
            }
            let t = timed(l, l.a);
            if t.0 < best.0 {
                best = t;
            }
        }
    }
    let (_, v, a, dip) = best;
    (v > b.v_limit || a != b.accel_full || dip.is_some()).then_some((v, a, dip))
}

/// `limits` with a curve's or an arc's bend limit lowered for jerk limitation over
/// `smoothing` ticks, by which the smoothed speed may exceed the profile's (a·w·T/2,
/// see [`Lookahead::plan_path`]): its bend, sized for the limit, would otherwise take
/// more than its share.
pub(super) fn smoothed(mut limits: Limits, path: &Path, smoothing: u32) -> Limits {
    if smoothing <= 1 || !path.form.bends() {
        return limits;
    }
    let lower = |v: f32| fmax(v - limits.a * smoothing as f32 / 2.0, 0.25 * v);
    if path.form == Form::Spline {
        limits.bend = limits.bend.map(lower);
    } else {
        limits.v = lower(limits.v);
    }
    limits
}
