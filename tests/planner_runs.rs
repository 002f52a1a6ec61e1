//! Whole runs through the planner and interpolator, checked from the outside: dense
//! micro-segment programs keep their feed, and arcs follow the true circle.

mod common;

use pkmc::config::{MachineConfig, AXES};
use pkmc::controller::{Controller, Inputs};
use pkmc::motion::block::{Block, Motion, Plane};
use pkmc::units::{NM_PER_MM, TICK_HZ};
use pkmc::wire::{encode_frame, HostMsg, State, MAX_FRAME, PROTOCOL_VERSION};

fn frame(seq: u16, msg: &HostMsg) -> Vec<u8> {
    let mut f = [0u8; MAX_FRAME];
    let n = encode_frame(seq, msg, &mut f).unwrap();
    f[..n].to_vec()
}

/// Streams `blocks` as fast as the queue accepts them and runs to the end; returns the
/// pose after every tick.
fn run(machine: MachineConfig, blocks: &[Block]) -> (Controller, Vec<[i64; AXES]>) {
    run_smoothed(machine, blocks, 1)
}

fn run_smoothed(
    machine: MachineConfig,
    blocks: &[Block],
    window: u32,
) -> (Controller, Vec<[i64; AXES]>) {
    let mut c = Controller::new(machine).unwrap();
    c.unlock();
    c.set_smoothing(window);
    c.receive(&frame(
        0,
        &HostMsg::Hello {
            version: PROTOCOL_VERSION,
            machine: c.machine_id(),
            host: 1,
        },
    ));
    let blocks = common::planned(c.machine(), *c.pose(), window, blocks);
    let mut next = 0;
    let mut poses = Vec::new();
    let mut sink = [0u8; 4096];
    for tick_no in 0..10_000_000 {
        // The host's keepalive (nc-send asks for a status every 100 ms).
        if tick_no % 100 == 0 {
            c.receive(&frame(0, &HostMsg::StatusRequest));
        }
        // Keep the queue topped up, as nc-send does.
        while next < blocks.len() && c.status().free_slots > 0 {
            c.receive(&frame(next as u16 + 1, &HostMsg::Block(blocks[next])));
            next += 1;
        }
        c.tick(&Inputs::default());
        while c.transmit(&mut sink) > 0 {}
        poses.push(*c.pose());
        if next == blocks.len() && c.state() == State::Idle {
            break;
        }
    }
    (c, poses)
}

fn fast_machine(accel_mm_s2: i64) -> MachineConfig {
    let mut m = MachineConfig::cartesian_xyz();
    for a in m.axes.iter_mut().take(3) {
        a.max_accel = accel_mm_s2 * NM_PER_MM;
    }
    for j in m.joints.iter_mut() {
        j.limits.max_accel = accel_mm_s2 * NM_PER_MM;
    }
    m
}

#[test]
fn micro_segments_at_f6000_run_at_full_feed() {
    // A quarter circle of radius 80 mm as 0.05 mm chords, at F6000 (100 mm/s). With
    // a = 3000 mm/s², stopping from 100 mm/s takes 1.7 mm: within the 64-block
    // look-ahead (3.2 mm), so nothing but the ends should slow it down.
    let (r, seg, feed) = (80.0f64, 0.05f64, 100.0f64);
    let n = (r * std::f64::consts::FRAC_PI_2 / seg).round() as usize;
    let mut blocks = Vec::new();
    let mut length = 0.0;
    let mut prev = (r, 0.0);
    for k in 1..=n {
        let a = std::f64::consts::FRAC_PI_2 * k as f64 / n as f64;
        let p = (r * a.cos(), r * a.sin());
        length += ((p.0 - prev.0).powi(2) + (p.1 - prev.1).powi(2)).sqrt();
        prev = p;
        blocks.push(Block {
            line: k as u32,
            motion: Motion::Linear,
            target: [
                (p.0 * 1e6).round() as i64 - 80_000_000,
                (p.1 * 1e6).round() as i64,
                0,
                0,
                0,
                0,
            ],
            feed: (feed * 1e6) as i64,
            tolerance_nm: u32::MAX,
        });
    }
    let accel = 3000.0;
    let (c, poses) = run(fast_machine(accel as i64), &blocks);
    let t = c.status().motion_ticks as f64 / TICK_HZ as f64;
    let ideal = length / feed + feed / accel;
    eprintln!(
        "{n} segments, {length:.3} mm: {t:.3} s against {ideal:.3} s ({:.4}×)",
        t / ideal
    );
    assert!(t <= 1.05 * ideal, "ran {t} s, bound {}", 1.05 * ideal);
    // Full feed was reached and held.
    let peak = poses
        .windows(2)
        .map(|w| {
            (((w[1][0] - w[0][0]) as f64).powi(2) + ((w[1][1] - w[0][1]) as f64).powi(2)).sqrt()
        })
        .fold(0.0, f64::max);
    assert!(
        peak * 1e-6 * TICK_HZ as f64 >= 0.99 * feed,
        "peak {peak} nm/tick"
    );
    assert_eq!(c.pose()[..2], blocks.last().unwrap().target[..2]);
}

#[test]
fn a_native_arc_never_leaves_its_circle() {
    // G2 full circle of radius 30 mm about (0, 0) from (30, 0), plus a helix turn.
    let r = 30_000_000i64;
    let arc = |target: [i64; AXES], turns: u16| Block {
        line: 1,
        motion: Motion::Arc {
            center: [0, 0],
            plane: Plane::Xy,
            clockwise: true,
            turns,
        },
        target,
        feed: 40 * NM_PER_MM,
        tolerance_nm: u32::MAX,
    };
    let lead_in = Block {
        line: 0,
        motion: Motion::Rapid,
        target: [r, 0, 0, 0, 0, 0],
        feed: 0,
        tolerance_nm: 0,
    };
    let blocks = [lead_in, arc([r, 0, -5_000_000, 0, 0, 0], 1)];
    let (c, poses) = run(MachineConfig::cartesian_xyz(), &blocks);
    let mut worst = 0.0f64;
    let mut on_arc = 0;
    for p in &poses {
        if p[2] < 0 {
            on_arc += 1;
            let rad = ((p[0] as f64).powi(2) + (p[1] as f64).powi(2)).sqrt();
            worst = worst.max((rad - r as f64).abs());
        }
    }
    assert!(on_arc > 1000);
    assert!(worst <= 1.5, "left the circle by {worst} nm");
    assert_eq!(c.pose(), &[r, 0, -5_000_000, 0, 0, 0]);
}

/// Second and third differences of one axis, nm per tick² and tick³.
fn differences(poses: &[[i64; AXES]], axis: usize) -> (f64, f64) {
    let x: Vec<f64> = poses.iter().map(|p| p[axis] as f64).collect();
    let a: Vec<f64> = x.windows(3).map(|w| w[2] - 2.0 * w[1] + w[0]).collect();
    let j: Vec<f64> = a.windows(2).map(|w| w[1] - w[0]).collect();
    let max = |v: &[f64]| v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    (max(&a), max(&j))
}

#[test]
fn jerk_limited_motion_bounds_jerk_and_still_ends_exactly() {
    // Out and back along X with a dwell between: 40 mm at 100 mm/s, a = 1000 mm/s²
    // (1000 nm/tick²). A 16-tick window bounds the jerk at 2a/16 = 125 nm/tick³
    // (125 000 mm/s³).
    let go = |x: i64, line: u32| Block {
        line,
        motion: Motion::Linear,
        target: [x, 0, 0, 0, 0, 0],
        feed: 100 * NM_PER_MM,
        tolerance_nm: u32::MAX,
    };
    let dwell = Block {
        line: 2,
        motion: Motion::Dwell(100),
        target: [40_000_000, 0, 0, 0, 0, 0],
        feed: 0,
        tolerance_nm: 0,
    };
    let blocks = [go(40_000_000, 1), dwell, go(0, 3)];
    let (plain, p_poses) = run(MachineConfig::cartesian_xyz(), &blocks);
    let (smooth, s_poses) = run_smoothed(MachineConfig::cartesian_xyz(), &blocks, 16);
    let (a_plain, j_plain) = differences(&p_poses, 0);
    let (a_smooth, j_smooth) = differences(&s_poses, 0);
    eprintln!("plain: a {a_plain} j {j_plain}; smoothed: a {a_smooth} j {j_smooth}");
    assert!(a_smooth <= 1000.0 + 2.0);
    assert!(j_smooth <= 125.0 + 2.0, "jerk {j_smooth} nm/tick³");
    assert!(
        j_plain >= 450.0,
        "the plain trapezoid has acceleration steps"
    );
    assert_eq!(smooth.pose(), plain.pose());
    assert_eq!(smooth.pose()[0], 0);
    // The dwell holds still for its full 100 ms after the smoothed motion arrives.
    let still = s_poses
        .windows(2)
        .map(|w| w[0] == w[1] && w[0][0] == 40_000_000)
        .filter(|b| *b)
        .count();
    assert!(still >= 100, "{still} ticks at rest at the turn");
}
