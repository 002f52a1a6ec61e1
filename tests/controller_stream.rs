//! The core controller driven purely through its byte interface and ticks, as the
//! firmware and the simulator drive it: random programs arrive in random-sized chunks
//! between ticks, and the machine must end exactly on the last target, in whole steps,
//! having never moved faster or accelerated harder than its limits on any axis.

mod common;

use pkmc::config::{MachineConfig, AXES};
use pkmc::controller::{Controller, Inputs};
use pkmc::motion::block::{Block, Motion};
use pkmc::units::TICK_HZ;
use pkmc::wire::{
    decode_frame, encode_frame, CtrlMsg, FrameReader, HostMsg, Pushed, State, MAX_BODY, MAX_FRAME,
    PROTOCOL_VERSION,
};
use proptest::prelude::*;

fn frame(seq: u16, msg: &HostMsg) -> Vec<u8> {
    let mut f = [0u8; MAX_FRAME];
    let n = encode_frame(seq, msg, &mut f).unwrap();
    f[..n].to_vec()
}

fn drain(c: &mut Controller, reader: &mut FrameReader, out: &mut Vec<CtrlMsg>) {
    let mut buf = [0u8; 512];
    loop {
        let n = c.transmit(&mut buf);
        if n == 0 {
            return;
        }
        for &b in &buf[..n] {
            if let Pushed::Frame(f) = reader.push(b) {
                let mut body = [0u8; MAX_BODY];
                out.push(decode_frame::<CtrlMsg>(f, &mut body).unwrap().1);
            }
        }
    }
}

fn target_strategy() -> impl Strategy<Value = ([i64; 3], i64, bool)> {
    (
        -100_000_000i64..=100_000_000,
        -150_000_000i64..=150_000_000,
        -80_000_000i64..=20_000_000,
        1_000_000i64..=150_000_000, // 1..150 mm/s (above the axis limit too)
        any::<bool>(),
    )
        .prop_map(|(x, y, z, f, rapid)| ([x, y, z], f, rapid))
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]
    #[test]
    fn random_programs_end_on_exact_steps_within_limits(
        moves in prop::collection::vec(target_strategy(), 1..12),
        chunk in 1usize..64,
    ) {
        let m = MachineConfig::cartesian_xyz();
        let mut c = Controller::new(m.clone()).unwrap();
    c.unlock();
        let mut bytes = frame(0, &HostMsg::Hello { version: PROTOCOL_VERSION, machine: c.machine_id(), host: 1 });
        let blocks: Vec<Block> = moves.iter().enumerate().map(|(i, (t, f, rapid))| {
            let mut target = [0i64; AXES];
            target[..3].copy_from_slice(t);
            Block {
                line: i as u32 + 1,
                motion: if *rapid { Motion::Rapid } else { Motion::Linear },
                target,
                feed: *f,
                tolerance_nm: if i % 3 == 0 { 0 } else { u32::MAX },
            }
        }).collect();
        for (i, b) in common::planned(&m, *c.pose(), 1, &blocks).into_iter().enumerate() {
            bytes.extend(frame(i as u16 + 1, &HostMsg::Block(b)));
        }
        let (mut reader, mut replies) = (FrameReader::new(), Vec::new());
        let inputs = Inputs::default();
        let mut prev = *c.pose();
        let mut prev_v = [0i64; 3];
        let v_max = m.axes[0].max_velocity as f64 / TICK_HZ as f64 + 2.0; // nm per tick
        // nm per tick², plus two nanometres of rounding per sample.
        let a_max = m.axes[0].max_accel as f64 / (TICK_HZ as f64 * TICK_HZ as f64) + 4.0;
        let mut fed = 0;
        for tick_no in 0..20_000_000 {
            // The host's keepalive (nc-send asks for a status every 100 ms).
            if tick_no % 100 == 0 && fed == bytes.len() {
                c.receive(&frame(0, &HostMsg::StatusRequest));
            }
            if fed < bytes.len() {
                let end = (fed + chunk).min(bytes.len());
                c.receive(&bytes[fed..end]);
                fed = end;
            }
            c.tick(&inputs);
            drain(&mut c, &mut reader, &mut replies);
            for i in 0..3 {
                let v = c.pose()[i] - prev[i];
                prop_assert!((v as f64).abs() <= v_max, "axis {} speed {} nm/tick", i, v);
                prop_assert!(((v - prev_v[i]) as f64).abs() <= a_max, "axis {} accel {} nm/tick²", i, v - prev_v[i]);
                prev_v[i] = v;
            }
            prev = *c.pose();
            if fed == bytes.len() && c.state() == State::Idle && !c.has_work() {
                break;
            }
        }
        let last = moves.last().unwrap().0;
        prop_assert_eq!(&c.pose()[..3], &last[..]);
        for (j, (jc, q)) in m.joints.iter().zip(&last).enumerate() {
            prop_assert_eq!(c.steps_emitted(j), jc.scale.steps_at(*q));
        }
        prop_assert_eq!(c.status().blocks_done as usize, moves.len());
        // Every block is acknowledged (freed slots are credited by more `Ack`s of the
        // last block accepted).
        let mut acked: Vec<u16> = replies.iter().filter_map(|r| match r {
            CtrlMsg::Ack { seq, .. } => Some(*seq),
            _ => None,
        }).collect();
        acked.dedup();
        let want: Vec<u16> = (1..=moves.len() as u16).collect();
        prop_assert_eq!(acked, want);
    }
}

#[test]
fn a_controller_at_rest_emits_no_steps_and_stays_idle() {
    let mut c = Controller::new(MachineConfig::cartesian_xyz()).unwrap();
    c.unlock();
    for tick_no in 0..1000 {
        // The host's keepalive (nc-send asks for a status every 100 ms).
        if tick_no % 100 == 0 {
            c.receive(&frame(0, &HostMsg::StatusRequest));
        }
        let out = c.tick(&Inputs::default());
        assert!(out.steps.iter().all(|t| t.count == 0));
    }
    assert_eq!(c.state(), State::Idle);
    assert_eq!(c.pose(), &[0; AXES]);
}

/// Ticks `c` (with the host's keepalive: nc-send asks for a status every 100 ms) until
/// it is idle; the commanded pose of every tick, the first before any.
fn run_until_idle(c: &mut Controller) -> Vec<[i64; AXES]> {
    let mut poses = vec![*c.pose()];
    let (mut reader, mut replies) = (FrameReader::new(), Vec::new());
    for tick_no in 0..2_000_000 {
        if tick_no % 100 == 0 {
            c.receive(&frame(0, &HostMsg::StatusRequest));
        }
        c.tick(&Inputs::default());
        drain(c, &mut reader, &mut replies);
        poses.push(*c.pose());
        if c.state() == State::Idle {
            break;
        }
    }
    poses
}

/// The third difference of four consecutive positions.
fn third_difference(d: &[f64]) -> f64 {
    d[3] - 3.0 * d[2] + 3.0 * d[1] - d[0]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(16))]
    #[test]
    fn jerk_limited_programs_keep_every_axis_within_its_jerk(
        moves in prop::collection::vec(target_strategy(), 1..8),
        window_log2 in 1u32..=5,
    ) {
        let m = MachineConfig::cartesian_xyz();
        let w = 1u32 << window_log2;
        let mut c = Controller::new(m.clone()).unwrap();
    c.unlock();
        c.set_smoothing(w);
        let mut bytes = frame(0, &HostMsg::Hello { version: PROTOCOL_VERSION, machine: c.machine_id(), host: 1 });
        let blocks: Vec<Block> = moves.iter().enumerate().map(|(i, (t, f, rapid))| {
            let mut target = [0i64; AXES];
            target[..3].copy_from_slice(t);
            Block {
                line: i as u32 + 1,
                motion: if *rapid { Motion::Rapid } else { Motion::Linear },
                target,
                feed: *f,
                tolerance_nm: u32::MAX,
            }
        }).collect();
        for (i, b) in common::planned(&m, *c.pose(), w, &blocks).into_iter().enumerate() {
            bytes.extend(frame(i as u16 + 1, &HostMsg::Block(b)));
        }
        c.receive(&bytes);
        let poses = run_until_idle(&mut c);
        prop_assert_eq!(&c.pose()[..3], &moves.last().unwrap().0[..]);
        let a = m.axes[0].max_accel as f64 / (TICK_HZ as f64 * TICK_HZ as f64);
        // 3a/w per tick³, plus rounding of the 1 nm positions (8 nm in a third difference).
        let j_max = 3.0 * a / w as f64 + 8.0;
        for i in 0..3 {
            let x: Vec<f64> = poses.iter().map(|p| p[i] as f64).collect();
            for (k, d) in x.windows(4).enumerate() {
                let j = third_difference(d);
                prop_assert!(j.abs() <= j_max, "axis {} tick {}: jerk {} > {} nm/tick³", i, k, j, j_max);
            }
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(16))]
    /// Tangent chains of curves, arcs and lines in XY under jerk limitation: every
    /// axis keeps its jerk (the bend's jump at a join and the smoothing's overshoot in
    /// a bend are planned for) and its acceleration, and the program ends on its
    /// target.
    #[test]
    fn jerk_limited_curves_and_arcs_keep_every_axis_within_its_jerk_and_acceleration(
        moves in prop::collection::vec((0u8..3, 2i64..=20, 10i64..=80, any::<bool>()), 1..8),
        window_log2 in 1u32..=5,
    ) {
        let m = MachineConfig::cartesian_xyz();
        let w = 1u32 << window_log2;
        let mut c = Controller::new(m.clone()).unwrap();
        c.unlock();
        c.set_smoothing(w);
        let mut bytes = frame(0, &HostMsg::Hello { version: PROTOCOL_VERSION, machine: c.machine_id(), host: 1 });
        // A tangent-continuous chain from (−60, 0) heading +X: arcs of radius r mm
        // turning `deg` degrees either way, cubics bending `deg` degrees, lines r mm
        // long; where a bend changes (arc to arc the other way, arc to line) the path
        // keeps its direction and its bend jumps.
        let (mut p, mut heading) = ([-60.0f64, 0.0], 0.0f64);
        let nm = |v: f64| (v * 1e6).round() as i64;
        let mut blocks = vec![Block {
            line: 100,
            motion: Motion::Rapid,
            target: [nm(p[0]), 0, 0, 0, 0, 0],
            feed: 0,
            tolerance_nm: 0,
        }];
        for (i, (kind, r, deg, left)) in moves.iter().enumerate() {
            let (r, turn) = (*r as f64, (*deg as f64).to_radians() * if *left { 1.0 } else { -1.0 });
            let (motion, end, h) = match kind {
                0 => {
                    let e = [p[0] + r * heading.cos(), p[1] + r * heading.sin()];
                    (Motion::Linear, e, heading)
                }
                1 => {
                    let side = turn.signum();
                    let c = [p[0] - side * r * heading.sin(), p[1] + side * r * heading.cos()];
                    let (s, co) = turn.sin_cos();
                    let (dx, dy) = (p[0] - c[0], p[1] - c[1]);
                    let e = [c[0] + co * dx - s * dy, c[1] + s * dx + co * dy];
                    let m = Motion::Arc {
                        center: [nm(c[0]), nm(c[1])],
                        plane: pkmc::motion::block::Plane::Xy,
                        clockwise: turn < 0.0,
                        turns: 0,
                    };
                    (m, e, heading + turn)
                }
                _ => {
                    let h = heading + turn;
                    let mid = heading + turn / 2.0;
                    let e = [p[0] + r * mid.cos(), p[1] + r * mid.sin()];
                    let m = Motion::Cubic {
                        c1: [nm(r / 3.0 * heading.cos()), nm(r / 3.0 * heading.sin()), 0, 0, 0, 0],
                        c2: [nm(-r / 3.0 * h.cos()), nm(-r / 3.0 * h.sin()), 0, 0, 0, 0],
                    };
                    (m, e, h)
                }
            };
            blocks.push(Block {
                line: i as u32 + 1,
                motion,
                target: [nm(end[0]), nm(end[1]), 0, 0, 0, 0],
                feed: 80_000_000,
                tolerance_nm: u32::MAX,
            });
            p = end;
            heading = h;
        }
        // Every curve within the machine's travel.
        let mut at = *c.pose();
        let mut start = *c.pose();
        for b in &blocks {
            let path = pkmc::motion::geometry::Path::new(b, &start).unwrap();
            for k in 0..=32 {
                path.pose_at(&start, (path.length << 16) / 32 * k, &mut at);
                prop_assume!(at[0].abs() < 95_000_000 && at[1].abs() < 95_000_000);
            }
            start = b.target;
        }
        for (i, b) in common::planned(&m, *c.pose(), w, &blocks).into_iter().enumerate() {
            bytes.extend(frame(i as u16 + 1, &HostMsg::Block(b)));
        }
        c.receive(&bytes);
        let poses = run_until_idle(&mut c);
        prop_assert_eq!(c.state(), State::Idle, "alarm: {:?}", c.status().alarm);
        prop_assert_eq!(&c.pose()[..2], &blocks.last().unwrap().target[..2]);
        let a = m.axes[0].max_accel as f64 / (TICK_HZ as f64 * TICK_HZ as f64);
        let j_max = 3.0 * a / w as f64 + 8.0;
        for i in 0..2 {
            let x: Vec<f64> = poses.iter().map(|p| p[i] as f64).collect();
            for (k, d) in x.windows(4).enumerate() {
                let j = third_difference(d);
                prop_assert!(j.abs() <= j_max, "axis {} tick {}: jerk {} > {} nm/tick³", i, k, j, j_max);
                let acc = d[2] - 2.0 * d[1] + d[0];
                prop_assert!(acc.abs() <= a * 1.002 + 4.0, "axis {} tick {}: accel {} > {}", i, k, acc, a);
            }
        }
    }
}
