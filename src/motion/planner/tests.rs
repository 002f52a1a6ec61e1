//! The planner's tests: the passes' invariants, corners, holds, the queue.

use super::limits::*;
use super::lookahead::*;
use super::queue::*;
use crate::config::*;
use crate::kinematics::*;
use crate::math::fmax;
use crate::motion::block::*;
use crate::motion::geometry::*;

fn line(x: i64, y: i64, feed_mm_s: i64, tol: u32) -> Block {
    Block {
        line: 1,
        motion: Motion::Linear,
        target: [x, y, 0, 0, 0, 0],
        feed: feed_mm_s * 1_000_000,
        tolerance_nm: tol,
    }
}

fn planner_with(blocks: &[Block]) -> Vec<PlanBlock> {
    let m = MachineConfig::cartesian_xyz();
    let k = MachineKinematics::new(&m);
    let mut out = vec![PlanBlock::default(); blocks.len()];
    plan_into(blocks, [0; AXES], &m, &k, 1, &mut out).unwrap();
    out
}

fn planned(blocks: &[Block]) -> Vec<PlannedBlock> {
    blocks
        .iter()
        .zip(planner_with(blocks))
        .map(|(b, p)| PlannedBlock {
            block: *b,
            plan: p.plan(),
        })
        .collect()
}

#[test]
fn the_last_block_always_plans_to_stop() {
    let p = planner_with(&[
        line(50_000_000, 0, 50, u32::MAX),
        line(100_000_000, 0, 50, u32::MAX),
    ]);
    let last = p.iter().last().unwrap();
    // It can stop within its own length from its entry speed.
    assert!(last.entry * last.entry <= 2.0 * last.accel * last.length() * 1.0001);
    // Collinear blocks are joined at full speed (50 mm/s = 50 000 nm/tick).
    assert!((last.entry - 50_000.0).abs() < 1.0, "{}", last.entry);
}

#[test]
fn exact_stop_mode_stops_at_every_corner() {
    let p = planner_with(&[line(50_000_000, 0, 50, 0), line(100_000_000, 0, 50, 0)]);
    assert_eq!(p.iter().last().unwrap().entry, 0.0);
}

/// Two lines of `len_mm` at 50 mm/s meeting at a turn of `deg` degrees, with path
/// tolerance `tol` nm.
fn turn(deg: f64, len_mm: f64, tol: u32) -> Vec<PlanBlock> {
    let (c, s) = (deg.to_radians().cos(), deg.to_radians().sin());
    let l = len_mm * 1e6;
    planner_with(&[
        line(l as i64, 0, 50, tol),
        line((l + l * c) as i64, (l * s) as i64, 50, tol),
    ])
}

#[test]
fn a_sharp_turn_between_long_lines_stops_rather_than_take_half_their_acceleration() {
    // Passing a right angle within one tick allows ½·a·T = 500 nm/tick (0.5 mm/s) with
    // half of each line's acceleration; a 10° turn 2 880 nm/tick. Either costs the
    // lines far more time in their ramps to 50 mm/s than the corner's speed gains.
    for deg in [10.0, 90.0] {
        let p = turn(deg, 50.0, u32::MAX);
        assert_eq!(p[1].entry, 0.0, "{deg}°");
        assert_eq!((p[0].accel, p[1].accel), (p[0].accel_full, p[1].accel_full));
        let (a, l, v) = (1000.0, 50e6, 50_000.0);
        let stopping = 2.0 * ramp_time(0.0, v, 0.0, a, l);
        let r = deg.to_radians() as f32;
        let c = 500.0 / fmax(r.sin(), 1.0 - r.cos());
        let sharing = ramp_time(0.0, v, c, a / 2.0, l) + ramp_time(c, v, 0.0, a / 2.0, l);
        assert!(stopping < sharing, "{deg}°: {stopping} vs {sharing} ticks");
    }
}

#[test]
fn a_gentle_turn_keeps_the_share_of_acceleration_it_needs() {
    // A 1° turn: |Δu| = 2 sin 0.5°, |Δu_y| ≈ sin 1°; half of a = 1000 nm/tick² per axis
    // passes it at 500 / sin 1° nm/tick (28.6 mm/s), the lines keep the other half.
    for len_mm in [1.0, 50.0] {
        let p = turn(1.0, len_mm, u32::MAX);
        let want = 500.0 / 1f32.to_radians().sin();
        assert!(
            (p[1].entry - want).abs() < want * 0.01,
            "{} vs {want}",
            p[1].entry
        );
        assert!((p[0].accel - 500.0).abs() < 1.0, "{}", p[0].accel);
        // The turn and the profile together stay within each axis's acceleration.
        let turn_y = p[1].entry * 1f32.to_radians().sin();
        assert!(
            turn_y + p[1].accel * 1f32.to_radians().sin() <= 1000.5,
            "{turn_y}"
        );
    }
}

#[test]
fn a_path_tolerance_bounds_the_corner_speed() {
    // G64 P0.001 at 1° allows 4 · 1000 nm / (2 sin 0.5°) per tick, more than the
    // acceleration budget (500 nm/tick / sin 1°): the budget decides.
    let budget = 500.0 / 1f32.to_radians().sin();
    let e = turn(1.0, 10.0, 1_000)[1].entry;
    assert!((e - budget).abs() < budget * 0.01, "{e} vs {budget}");
    // G64 P0.0001: 400 nm / (2 sin 0.5°) per tick.
    let by_tolerance = 400.0 / (2.0 * 0.5f32.to_radians().sin());
    let e = turn(1.0, 10.0, 100)[1].entry;
    assert!(
        (e - by_tolerance).abs() < by_tolerance * 0.01,
        "{e} vs {by_tolerance}"
    );
}

#[test]
fn a_hold_caps_every_block_at_zero() {
    let mut p = planner_with(&[
        line(50_000_000, 0, 50, u32::MAX),
        line(100_000_000, 0, 50, u32::MAX),
    ]);
    reverse_pass(&mut p, 100, true);
    forward_pass(&mut p, 30_000.0);
    let e = p.iter().last().unwrap().entry;
    // Entered at 30 000 nm/tick, the first block (50 mm) can only slow to
    // sqrt(30000² − 2·1000·5e7) < 0 → 0.
    assert_eq!(e, 0.0);
}

#[test]
fn the_controller_never_leaves_faster_than_it_can_stop_within_its_queue() {
    let m = MachineConfig::cartesian_xyz();
    let k = MachineKinematics::new(&m);
    // 600 collinear 0.05 mm segments at 100 mm/s: the host plans the middle ones
    // at full speed (its look-ahead sees the whole 30 mm), but a queue holding only
    // 0.5 mm of them can stop from √(2·a·0.5 mm) only.
    let blocks: Vec<Block> = (1..=600)
        .map(|i| line(i * 50_000, 0, 100, u32::MAX))
        .collect();
    let plan = planned(&blocks);
    assert!(plan[200].plan.entry > 99_000.0, "{}", plan[200].plan.entry);
    let mut p = Planner::new(plan[199].block.target);
    for b in &plan[200..211] {
        p.push_planned(b, &m, &k).unwrap();
    }
    p.pop();
    // Ten segments behind: 2 · 1000 nm/tick² · 0.5 mm.
    let want = (2.0f32 * 1000.0 * LIMIT_MARGIN * 500_000.0).sqrt();
    let got = p.exit_target();
    assert!((got - want).abs() < want * 1e-4, "{got} vs {want}");
    assert!(got <= plan[201].plan.entry);
    // A full queue lets the planned speed through.
    let mut p = Planner::new(plan[199].block.target);
    for b in &plan[200..200 + QUEUE_CAPACITY] {
        p.push_planned(b, &m, &k).unwrap();
    }
    p.pop();
    assert_eq!(p.exit_target(), plan[201].plan.entry);
    // Draining the queue brings the budget back to exactly zero.
    let mut p = Planner::new([0; AXES]);
    for b in &plan[..11] {
        p.push_planned(b, &m, &k).unwrap();
    }
    while p.pop().is_some() {}
    assert_eq!(p.exit_target(), 0.0);
    assert_eq!(p.buffered_ticks(), 0.0);
}

/// A full circle about `center` from and back to the current point.
fn circle(x: i64, center: [i64; 2]) -> Block {
    Block {
        line: 2,
        motion: Motion::Arc {
            center,
            plane: crate::motion::block::Plane::Xy,
            clockwise: true,
            turns: 0,
        },
        target: [x, 0, 0, 0, 0, 0],
        feed: 50_000_000,
        tolerance_nm: u32::MAX,
    }
}

#[test]
fn arcs_wait_for_a_free_bend_lines_do_not_and_each_arc_runs_on_its_own_bend() {
    let m = MachineConfig::cartesian_xyz();
    let k = MachineKinematics::new(&m);
    // A line to X10, then circles through X10 about X5 and X0 in turn (radii 5 and
    // 10 mm), more than the ring of bends holds, then a line.
    let mut blocks = vec![line(10_000_000, 0, 50, u32::MAX)];
    for i in 0..=BEND_CAPACITY {
        blocks.push(circle(10_000_000, [5_000_000 * (i as i64 % 2), 0]));
    }
    blocks.push(line(20_000_000, 0, 50, u32::MAX));
    let plan = planned(&blocks);
    let mut p = Planner::new([0; AXES]);
    for b in &plan[..=BEND_CAPACITY] {
        assert_eq!(p.push_planned(b, &m, &k), Ok(()));
    }
    assert_eq!(p.free_bends(), 0);
    assert_eq!(p.free(), QUEUE_CAPACITY - BEND_CAPACITY - 1);
    // One more arc does not fit; a line does (tried here out of turn, from where the
    // last arc ends, as it would be sent if it came next).
    let extra = &plan[BEND_CAPACITY + 1];
    assert_eq!(p.push_planned(extra, &m, &k), Err(PushError::Full));
    let mut q = p.clone();
    assert_eq!(q.push_planned(&plan[BEND_CAPACITY + 2], &m, &k), Ok(()));
    // The line leaves: still no bend. The first arc leaves: one.
    assert_eq!(p.pop().map(|b| b.course.form), Some(Form::Line));
    assert_eq!(p.free_bends(), 0);
    assert!(p.start());
    assert_eq!(p.bend().circle().r0, 10_000_000);
    p.finish();
    assert_eq!(p.free_bends(), 1);
    assert_eq!(p.push_planned(extra, &m, &k), Ok(()));
    // Every arc executes on its own bend, in order.
    for i in 1..=BEND_CAPACITY {
        assert!(p.start());
        let want = if i % 2 == 0 { 10_000_000 } else { 5_000_000 };
        assert_eq!(p.bend().circle().r0, want, "arc {i}");
        let mut pose = [0; AXES];
        let b = *p.executing().unwrap();
        b.course
            .pose_at(p.bend(), p.front_start(), b.course.length << 15, &mut pose);
        let c = 5_000_000 * (i as i64 % 2);
        assert!((pose[0] - (c - want)).abs() <= 2, "arc {i}: {pose:?}");
        p.finish();
    }
    assert!(p.is_empty());
    assert_eq!(p.free_bends(), BEND_CAPACITY);
}

#[test]
fn a_plan_that_does_not_match_its_block_is_refused() {
    let m = MachineConfig::cartesian_xyz();
    let k = MachineKinematics::new(&m);
    let plan = planned(&[line(10_000_000, 0, 50, u32::MAX)]);
    let mut p = Planner::new([0; AXES]);
    let mut short = plan[0];
    short.plan.length /= 2;
    assert_eq!(
        p.push_planned(&short, &m, &k),
        Err(PushError::Geometry(GeometryError::PlanMismatch))
    );
    let mut elsewhere = plan[0];
    elsewhere.block.target[1] = 3_000_000;
    elsewhere.block.target[0] = 9_539_392;
    assert_eq!(
        p.push_planned(&elsewhere, &m, &k),
        Err(PushError::Geometry(GeometryError::PlanMismatch))
    );
    let mut nan = plan[0];
    nan.plan.v_limit = f32::NAN;
    assert!(p.push_planned(&nan, &m, &k).is_err());
    assert_eq!(p.push_planned(&plan[0], &m, &k), Ok(()));
}

/// A curve that bends hardest at its end: it leaves a line along X straight (no bend
/// at its start) and turns to Y, into a line along Y; its parameter runs as fast at
/// both ends.
fn hooked_curve() -> Vec<Block> {
    let mm = 1_000_000i64;
    let cubic = Block {
        line: 2,
        motion: Motion::Cubic {
            c1: [10 * mm, 0, 0, 0, 0, 0],
            c2: [0, -10 * mm, 0, 0, 0, 0],
        },
        target: [30 * mm, 10 * mm, 0, 0, 0, 0],
        feed: 100 * mm,
        tolerance_nm: 1000,
    };
    let mut first = line(10 * mm, 0, 100, 1000);
    first.line = 1;
    let mut last = line(30 * mm, 140 * mm, 100, 1000);
    last.line = 3;
    vec![line(-90 * mm, 0, 100, 0), first, cubic, last]
}

#[test]
fn a_curve_bent_hardest_at_one_end_runs_faster_away_from_it_within_every_axis_limit() {
    // Cartesian XYZ with 200 mm/s² per axis and joint: the curve's bend binds below
    // the 100 mm/s the axes allow.
    let mut m = MachineConfig::cartesian_xyz();
    let slow = 200_000_000;
    for l in m.axes.iter_mut().take(3) {
        l.max_accel = slow;
    }
    for j in m.joints.iter_mut() {
        j.limits.max_accel = slow;
    }
    let k = MachineKinematics::new(&m);
    let blocks = hooked_curve();
    let mut plan = vec![PlanBlock::default(); blocks.len()];
    plan_into(&blocks, [0; AXES], &m, &k, 1, &mut plan).unwrap();
    let b = &plan[2];
    assert_eq!(b.path.form, Form::Spline);
    let amax = slow as f32 / 1e6;
    // The tightest bend: at the whole acceleration it allows no more than this.
    let n = 64;
    let tightest = (0..=n)
        .map(|k| {
            let x2 = b.path.bend_at((b.path.length << 16) / n * k);
            x2[0].abs().max(x2[1].abs())
        })
        .fold(0.0f32, f32::max);
    let bend_speed = (amax / tightest).sqrt();
    assert!(
        b.v_limit > 1.2 * bend_speed,
        "limit {} nm/tick, the tightest bend's {bend_speed}",
        b.v_limit
    );
    assert!(b.exit_most <= bend_speed, "exit {} nm/tick", b.exit_most);
    // Run the curve from its planned entry to the next block's, each tick's pose from
    // the profile: no axis accelerates by more than its limit (and a few nanometres'
    // rounding per tick).
    let exit = plan[3].entry;
    let (profile, achieved) = crate::motion::profile::Profile::plan(
        b.path.length << 16,
        b.entry,
        cap(b, 100, false),
        exit,
        b.accel,
    );
    assert!(achieved.exit <= exit * 1.0001 + 1.0);
    let start = plan[1].path.end;
    let ticks = (profile.duration() >> 32) + 2;
    let mut pose = [0i64; AXES];
    let poses: Vec<[i64; AXES]> = (0..=ticks)
        .map(|t| {
            b.path.pose_at(&start, profile.at(t << 32).0, &mut pose);
            pose
        })
        .collect();
    let mut fastest = 0.0f64;
    // The first and last ticks join the neighbours' motion: not this block's alone.
    for w in poses[1..poses.len() - 2].windows(3) {
        for (i, ((p0, p1), p2)) in w[0].iter().zip(&w[1]).zip(&w[2]).take(2).enumerate() {
            let a = (p2 - 2 * p1 + p0).abs() as f32;
            assert!(a <= amax * 1.001 + 3.0, "axis {i}: {a} nm/tick² of {amax}");
        }
        let v = ((w[2][0] - w[1][0]) as f64).hypot((w[2][1] - w[1][1]) as f64);
        fastest = fastest.max(v);
    }
    assert!(
        fastest > 1.2 * bend_speed as f64,
        "fastest {fastest} nm/tick; bend {bend_speed}; {b:?}; exit {exit}"
    );
}

/// A U-turn between a line out along X and a line back: a cubic whose bend is
/// tightest in its middle, at the turn's tip, and gentle at both ends, where it joins
/// the lines with their tangents.
fn u_turn() -> Vec<Block> {
    let mm = 1_000_000i64;
    let mut out = line(40 * mm, 0, 100, 1000);
    out.line = 1;
    let cubic = Block {
        line: 2,
        motion: Motion::Cubic {
            c1: [24 * mm, 0, 0, 0, 0, 0],
            c2: [24 * mm, 0, 0, 0, 0, 0],
        },
        target: [40 * mm, 12 * mm, 0, 0, 0, 0],
        feed: 100 * mm,
        tolerance_nm: 1000,
    };
    let mut back = line(0, 12 * mm, 100, 1000);
    back.line = 3;
    vec![out, cubic, back]
}

/// Each tick's commanded pose, line and path speed (nm/tick) of the controller's queue
/// and executor running `plan` from the origin; `hold` holds at that tick and resumes
/// 200 ticks later.
fn run_queued(
    plan: &[PlannedBlock],
    m: &MachineConfig,
    k: &MachineKinematics,
    hold: Option<usize>,
) -> Vec<([i64; AXES], u32, f32)> {
    use crate::motion::interp::Executor;
    let mut p = Planner::new([0; AXES]);
    for b in plan {
        p.push_planned(b, m, k).unwrap();
    }
    let mut e = Executor::new([0; AXES]);
    let mut out = vec![([0; AXES], 0, 0.0)];
    for t in 0..100_000 {
        if hold == Some(t) || hold.map(|h| h + 200) == Some(t) {
            p.hold = hold == Some(t);
            e.replan(&mut p);
        }
        assert_eq!(e.tick(&mut p), None);
        out.push((e.pose, e.line, crate::motion::profile::from_q32(e.speed)));
        if !e.busy() && p.is_empty() {
            return out;
        }
    }
    panic!("the run did not end");
}

#[test]
fn a_spline_with_a_dip_slows_there_alone_within_every_axis_limit_and_holds_on_its_path() {
    let m = MachineConfig::cartesian_xyz();
    let k = MachineKinematics::new(&m);
    let blocks = u_turn();
    let mut plan = planned(&blocks);
    let b = &mut plan[1].plan;
    assert!(matches!(b.shape, Shape::Spline { .. }), "{b:?}");
    // A dip half-way along, at half the curve's limit: a plan is free to ask for one
    // wherever it likes (it is a limit, so a lower one is always safe).
    let dip = Dip::new(128, 0.5 * b.v_limit, b.v_limit);
    with_dip(b, Some(dip));
    let accel = b.accel;
    let amax = m.axes[0].max_accel as f32 / 1e6;
    // Held before the dip (on the curve's first half) and beyond it.
    for hold in [None, Some(560), Some(900)] {
        let ticks = run_queued(&plan, &m, &k, hold);
        let end = ticks.last().unwrap().0;
        assert_eq!(end, blocks[2].target, "hold {hold:?}");
        // No axis accelerates by more than its limit (and a few nanometres' rounding
        // per tick), through the dip and the hold alike.
        for w in ticks.windows(3) {
            for i in 0..2 {
                let a = (w[2].0[i] - 2 * w[1].0[i] + w[0].0[i]).abs() as f32;
                assert!(
                    a <= amax * 1.001 + 3.0,
                    "axis {i}: {a} nm/tick², hold {hold:?}"
                );
            }
        }
        if hold.is_some() {
            continue;
        }
        // On the curve: slowest along it (its path speed, which the dip limits) at the
        // tip, at no more than the dip's speed, and faster on either side of it.
        let speeds: Vec<(f32, f32)> = ticks
            .iter()
            .filter(|t| t.1 == 2)
            .map(|t| (t.0[0] as f32, t.2))
            .collect();
        let (tip, slowest) =
            speeds.iter().fold(
                (0.0, f32::INFINITY),
                |m, &(x, v)| if v < m.1 { (x, v) } else { m },
            );
        // (Ticks fall on either side of the dip: within a tick's change of speed.)
        assert!(
            slowest <= dip.speed() + accel,
            "{slowest} at the dip {dip:?}"
        );
        assert!(
            slowest >= dip.speed() - accel,
            "{slowest} at the dip {dip:?}"
        );
        assert!(tip > 50e6, "slowest at x = {tip} nm");
        let half = speeds.len() / 2;
        let fastest = |s: &[(f32, f32)]| s.iter().fold(0.0f32, |m, &(_, v)| m.max(v));
        for side in [&speeds[..half / 2], &speeds[speeds.len() - half / 2..]] {
            assert!(
                fastest(side) > 1.2 * slowest,
                "{} vs {slowest}",
                fastest(side)
            );
        }
    }
}

/// `plan`, a curve's, with `dip`.
fn with_dip(plan: &mut Plan, dip: Option<Dip>) {
    let Shape::Spline { dip: d, .. } = &mut plan.shape else {
        panic!("not a curve: {plan:?}");
    };
    *d = dip;
}

#[test]
fn a_dip_at_its_curves_start_is_refused() {
    let m = MachineConfig::cartesian_xyz();
    let k = MachineKinematics::new(&m);
    let plan = planned(&u_turn());
    let dip = Dip::new(128, 1000.0, 2000.0);
    let refused = |pb: &PlannedBlock, start: [i64; AXES]| {
        let mut p = Planner::new(start);
        assert_eq!(
            p.push_planned(pb, &m, &k),
            Err(PushError::Geometry(GeometryError::PlanMismatch)),
            "{pb:?}"
        );
    };
    let start = plan[0].block.target;
    let mut pb = plan[1];
    with_dip(&mut pb.plan, Some(Dip { at: 0, ..dip }));
    refused(&pb, start);
    let mut p = Planner::new(start);
    with_dip(&mut pb.plan, Some(dip));
    assert_eq!(p.push_planned(&pb, &m, &k), Ok(()));
    assert_eq!(p.len(), 1);
}

#[test]
fn a_spline_tightest_inside_gets_a_dip_there_that_its_ends_can_reach() {
    // 50 mm whose bend allows 100 mm/s everywhere but over one stretch in its middle,
    // 40 mm/s there; entered and left at 70 mm/s, 100 mm/s².
    let k = STRETCHES / 2;
    let mut bend = [100_000.0f32; STRETCHES];
    bend[k] = 40_000.0;
    let limits = super::limits::Limits {
        v: 100_000.0,
        a: 1000.0,
        bend,
    };
    let (a, length) = (100.0, 50e6);
    // One limit for the whole block would be the stretch's.
    assert_eq!(limits.top(70_000.0, 70_000.0, a, length), 40_000.0);
    let (dip, before, t) = limits
        .dip(70_000.0, 70_000.0, a, length, 100_000.0)
        .expect("a dip");
    let stretch = length / STRETCHES as f32;
    let at = length * dip.at as f32 / 256.0;
    assert!((at - stretch * (k as f32 + 0.5)).abs() < 1.0, "{dip:?}");
    // From the dip's speed, ramps at a reach the stretch's limit at its ends (the
    // speed rounded down to 11 bits).
    let reach = (dip.speed() * dip.speed() + a * stretch).sqrt();
    assert!(reach <= 40_000.0 && reach > 39_970.0, "{dip:?}: {reach}");
    assert_eq!(before, 100_000.0);
    assert!(
        dip.after() <= 100_000.0 && dip.after() > 99_950.0,
        "{dip:?}"
    );
    let whole = ramp_time(70_000.0, 40_000.0, 70_000.0, a, length);
    assert!(t < 0.75 * whole, "{t} ticks against {whole}");
    // Ends it cannot slow down from in time get none: 10 mm/s² leaves the dip out of
    // reach from 70 mm/s.
    assert!(limits
        .dip(70_000.0, 70_000.0, 10.0, length, 100_000.0)
        .is_none());
    // A block tightest over its first stretch gets a step there: held to that
    // stretch's limit before it, free beyond.
    let mut at_start = limits;
    at_start.bend = [100_000.0; STRETCHES];
    at_start.bend[0] = 40_000.0;
    let (dip, before, _) = at_start
        .dip(40_000.0, 70_000.0, a, length, 100_000.0)
        .expect("a step");
    assert_eq!(before, 40_000.0);
    assert!(dip.speed() <= 40_000.0 && dip.after() > 99_950.0, "{dip:?}");
}

#[test]
fn a_dips_speeds_are_kept_rounded_down_to_eleven_bits() {
    let mut x = 0x2545_F491u32;
    for _ in 0..100_000 {
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        let v = f32::from_bits(x & 0x7FFF_FFFF);
        let kept = Dip::new(1, v, v).speed();
        if (1.0 / 256.0..16_000_000.0).contains(&v) {
            assert!(kept <= v && kept >= v * (1.0 - 1.0 / 2048.0), "{v}: {kept}");
        } else if v < 1.0 / 256.0 || v.is_nan() {
            assert_eq!(kept, 0.0, "{v}");
        } else {
            assert!(kept <= v, "{v}: {kept}");
        }
    }
    assert_eq!(Dip::new(1, f32::INFINITY, 0.0).speed(), 16_773_120.0);
}
