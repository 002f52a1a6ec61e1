//! Planned motion on the H-4 with rolling table, checked in joint space: whatever the
//! program, no joint moves faster or accelerates harder than its own limit (through
//! the kinematics, beyond rounding), every block ends exactly on its target, and the
//! motion is continuous across blocks.

mod common;

use pkmc::config::{MachineConfig, AXES, MAX_JOINTS};
use pkmc::controller::{Controller, Inputs};
use pkmc::kinematics::MachineKinematics;
use pkmc::motion::block::{Block, Motion};
use pkmc::units::{NDEG_PER_DEG, NM_PER_MM, TICK_HZ};
use pkmc::wire::{encode_frame, HostMsg, State, MAX_FRAME, PROTOCOL_VERSION};
use proptest::prelude::*;

fn frame(seq: u16, msg: &HostMsg) -> Vec<u8> {
    let mut f = [0u8; MAX_FRAME];
    let n = encode_frame(seq, msg, &mut f).unwrap();
    f[..n].to_vec()
}

/// The H-4 with joint limits tight enough that they, not the Cartesian ones, bind.
fn h4_tight() -> MachineConfig {
    let mut m = MachineConfig::h4_table();
    for j in m.joints.iter_mut().take(4) {
        j.limits.max_velocity = 60 * NM_PER_MM;
        j.limits.max_accel = 600 * NM_PER_MM;
    }
    m.joints[4].limits.max_velocity = 30 * NDEG_PER_DEG;
    m.joints[4].limits.max_accel = 300 * NDEG_PER_DEG;
    m
}

fn pose_strategy() -> impl Strategy<Value = [i64; AXES]> {
    (
        -50i64..=50,
        -50i64..=50,
        -100i64..=-60,
        0i64..=30,
        -20i64..=20,
    )
        .prop_map(|(x, y, z, a, c)| {
            [
                x * NM_PER_MM,
                y * NM_PER_MM,
                z * NM_PER_MM,
                a * NDEG_PER_DEG,
                0,
                c * NDEG_PER_DEG,
            ]
        })
}

/// Ticks `c` (with the host's keepalive: nc-send asks for a status every 100 ms) while
/// it runs: the commanded joints and pose of every tick, the first before any.
fn run(c: &mut Controller) -> (Vec<[i64; MAX_JOINTS]>, Vec<[i64; AXES]>) {
    let (mut joints, mut pose) = (vec![*c.joints()], vec![*c.pose()]);
    let mut sink = [0u8; 4096];
    for tick_no in 0..200_000 {
        if tick_no % 100 == 0 {
            c.receive(&frame(0, &HostMsg::StatusRequest));
        }
        c.tick(&Inputs::default());
        while c.transmit(&mut sink) > 0 {}
        joints.push(*c.joints());
        pose.push(*c.pose());
        if c.state() != State::Running {
            break;
        }
    }
    (joints, pose)
}

/// Positions `x` (one a tick) never move faster than `v_lim` or accelerate harder than
/// `a_lim` (units/s, units/s²), beyond rounding.
fn within(x: Vec<f64>, v_lim: i64, a_lim: i64, what: &str) -> Result<(), TestCaseError> {
    let t = 1.0 / TICK_HZ as f64;
    let v_max = v_lim as f64 * t * (1.0 + 1e-6) + 2.0;
    let a_max = a_lim as f64 * t * t * 1.02 + 4.0;
    for (k, w) in x.windows(3).enumerate() {
        let (v, a) = (w[2] - w[1], w[2] - 2.0 * w[1] + w[0]);
        prop_assert!(
            v.abs() <= v_max,
            "{} tick {}: speed {} > {}",
            what,
            k,
            v,
            v_max
        );
        prop_assert!(
            a.abs() <= a_max,
            "{} tick {}: accel {} > {}",
            what,
            k,
            a,
            a_max
        );
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]
    #[test]
    fn no_joint_exceeds_its_speed_or_acceleration_and_blocks_end_exactly(
        poses in prop::collection::vec(pose_strategy(), 1..6),
        feeds in prop::collection::vec(5i64..=150, 6),
        blend in any::<bool>(),
    ) {
        let m = h4_tight();
        let kin = MachineKinematics::new(&m);
        let mut q = [0i64; MAX_JOINTS];
        for p in &poses {
            prop_assume!(kin.inverse_checked(p, &m.joints, &mut q).is_ok());
        }
        let mut c = Controller::new(m.clone()).unwrap();
    c.unlock();
        c.receive(&frame(0, &HostMsg::Hello { version: PROTOCOL_VERSION, machine: c.machine_id(), host: 1 }));
        let blocks: Vec<Block> = poses.iter().enumerate().map(|(i, p)| Block {
            line: i as u32 + 1,
            motion: if i % 2 == 0 { Motion::Linear } else { Motion::Rapid },
            target: *p,
            feed: feeds[i] * NM_PER_MM,
            tolerance_nm: if blend { u32::MAX } else { 0 },
        }).collect();
        for (i, b) in common::planned(&m, *c.pose(), 1, &blocks).into_iter().enumerate() {
            c.receive(&frame(i as u16 + 1, &HostMsg::Block(b)));
        }
        let (history, _) = run(&mut c);
        prop_assert_eq!(c.state(), State::Idle, "alarm: {:?}", c.status().alarm);
        prop_assert_eq!(c.pose(), poses.last().unwrap());
        for (j, jc) in m.joints.iter().enumerate() {
            let x = history.iter().map(|h| h[j] as f64).collect();
            within(x, jc.limits.max_velocity, jc.limits.max_accel, &format!("joint {j}"))?;
        }
    }
}

#[test]
fn a_joint_limit_tighter_than_the_feed_is_what_binds() {
    // A 20 mm rise of the head at F9000 (150 mm/s): the carriages must rise as fast,
    // but may only do 60 mm/s, so the move runs at their limit, not at F.
    let m = h4_tight();
    let mut c = Controller::new(m.clone()).unwrap();
    c.unlock();
    c.receive(&frame(
        0,
        &HostMsg::Hello {
            version: PROTOCOL_VERSION,
            machine: c.machine_id(),
            host: 1,
        },
    ));
    let mut target = m.home;
    target[2] += 20 * NM_PER_MM;
    let b = Block {
        line: 1,
        motion: Motion::Linear,
        target,
        feed: 150 * NM_PER_MM,
        tolerance_nm: 0,
    };
    let b = common::planned(&m, *c.pose(), 1, &[b])[0];
    c.receive(&frame(1, &HostMsg::Block(b)));
    let mut peak = 0i64;
    let mut last = c.joints()[0];
    for tick_no in 0..5000 {
        // The host's keepalive (nc-send asks for a status every 100 ms).
        if tick_no % 100 == 0 {
            c.receive(&frame(0, &HostMsg::StatusRequest));
        }
        c.tick(&Inputs::default());
        peak = peak.max((c.joints()[0] - last).abs());
        last = c.joints()[0];
    }
    assert_eq!(c.pose(), &target);
    let limit = m.joints[0].limits.max_velocity / TICK_HZ as i64;
    assert!(
        peak <= limit + 2 && peak * 100 >= limit * 95,
        "peak {peak} nm/tick, limit {limit}"
    );
}

/// A spline block to `target` from `from`: cubic (control offsets a fraction of the
/// chord, each way) or quadratic.
fn spline_to(from: &[i64; AXES], target: [i64; AXES], k: &[i64; 4], cubic: bool) -> Motion {
    let chord: [i64; AXES] = core::array::from_fn(|i| target[i] - from[i]);
    // Offsets in X Y Z only, as G5 and the compressor make them; A B C move with
    // their ends' straight parameter (c1 = Δ/3, c2 = −Δ/3 for a cubic, c = Δ/2 for a
    // quadratic) so that they stay within their travel.
    let side = |f: i64, g: i64| -> [i64; AXES] {
        core::array::from_fn(|i| match i {
            0 => chord[0] * f / 8 - chord[1] * g / 8,
            1 => chord[1] * f / 8 + chord[0] * g / 8,
            2 => chord[2] * f / 8,
            _ => 0,
        })
    };
    if cubic {
        let (a, b) = (side(k[0], k[1]), side(k[2], k[3]));
        Motion::Cubic {
            c1: core::array::from_fn(|i| if i < 3 { a[i] } else { chord[i] / 3 }),
            c2: core::array::from_fn(|i| if i < 3 { -b[i] } else { -chord[i] / 3 }),
        }
    } else {
        let a = side(k[0] + 4, k[1]);
        Motion::Quadratic {
            c: core::array::from_fn(|i| if i < 3 { a[i] } else { chord[i] / 2 }),
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(32))]
    /// Spline blocks (cubic and quadratic, blended or not) on the H-4 whose joints
    /// bind: no joint and no Cartesian axis exceeds its speed or acceleration, the
    /// motion is continuous across blocks, and the last block ends exactly on its
    /// target.
    #[test]
    fn splines_keep_every_joint_and_axis_limit_and_end_exactly(
        poses in prop::collection::vec(pose_strategy(), 2..6),
        shape in prop::collection::vec(prop::array::uniform4(1i64..=4), 6),
        cubic in prop::collection::vec(any::<bool>(), 6),
        feeds in prop::collection::vec(5i64..=150, 6),
        blend in any::<bool>(),
    ) {
        let m = h4_tight();
        let kin = MachineKinematics::new(&m);
        let mut q = [0i64; MAX_JOINTS];
        let start = MachineConfig::h4_table().home;
        let mut from = start;
        let mut blocks = Vec::new();
        for (i, p) in poses.iter().enumerate() {
            let chord = ((0..3).map(|k| ((p[k] - from[k]) as f64).powi(2)).sum::<f64>()).sqrt();
            prop_assume!(chord > 1e5);
            let b = Block {
                line: i as u32 + 1,
                motion: spline_to(&from, *p, &shape[i], cubic[i]),
                target: *p,
                feed: feeds[i] * NM_PER_MM,
                tolerance_nm: if blend { 10_000 } else { 0 },
            };
            // The whole curve within reach.
            let path = pkmc::motion::geometry::Path::new(&b, &from).unwrap();
            let mut at = [0i64; AXES];
            for k in 0..=40 {
                path.pose_at(&from, (path.length << 16) / 40 * k, &mut at);
                prop_assume!(kin.inverse_checked(&at, &m.joints, &mut q).is_ok());
            }
            blocks.push(b);
            from = *p;
        }
        let mut c = Controller::new(m.clone()).unwrap();
        c.unlock();
        prop_assert_eq!(*c.pose(), start);
        c.receive(&frame(0, &HostMsg::Hello { version: PROTOCOL_VERSION, machine: c.machine_id(), host: 1 }));
        for (i, b) in common::planned(&m, *c.pose(), 1, &blocks).into_iter().enumerate() {
            c.receive(&frame(i as u16 + 1, &HostMsg::Block(b)));
        }
        let (joints, pose) = run(&mut c);
        prop_assert_eq!(c.state(), State::Idle, "alarm: {:?}", c.status().alarm);
        prop_assert_eq!(c.pose(), poses.last().unwrap());
        for (j, jc) in m.joints.iter().enumerate() {
            let x = joints.iter().map(|h| h[j] as f64).collect();
            within(x, jc.limits.max_velocity, jc.limits.max_accel, &format!("joint {j}"))?;
        }
        for (i, lim) in m.axes.iter().enumerate().filter(|(_, l)| l.max_velocity > 0) {
            let x = pose.iter().map(|h| h[i] as f64).collect();
            within(x, lim.max_velocity, lim.max_accel, &format!("axis {i}"))?;
        }
    }
}
