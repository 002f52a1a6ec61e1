//! The core controller driven purely through its byte interface and ticks, as the
//! firmware and the simulator drive it: random programs arrive in random-sized chunks
//! between ticks, and the machine must end exactly on the last target, in whole steps,
//! having never moved faster or accelerated harder than its limits on any axis.

mod common;

use pkmc::config::{MachineConfig, AXES};
use pkmc::controller::{Controller, Inputs};
use pkmc::protocol::{
    decode_frame, encode_frame, Block, CtrlMsg, FrameReader, HostMsg, Motion, Pushed, State,
    MAX_BODY, MAX_FRAME, PROTOCOL_VERSION,
};
use pkmc::units::TICK_HZ;
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
        let mut poses = vec![*c.pose()];
        let (mut reader, mut replies) = (FrameReader::new(), Vec::new());
        for tick_no in 0..2_000_000 {
            // The host's keepalive (nc-send asks for a status every 100 ms).
            if tick_no % 100 == 0 {
                c.receive(&frame(0, &HostMsg::StatusRequest));
            }
            c.tick(&Inputs::default());
            drain(&mut c, &mut reader, &mut replies);
            poses.push(*c.pose());
            if c.state() == State::Idle {
                break;
            }
        }
        prop_assert_eq!(&c.pose()[..3], &moves.last().unwrap().0[..]);
        let a = m.axes[0].max_accel as f64 / (TICK_HZ as f64 * TICK_HZ as f64);
        // 3a/w per tick³, plus rounding of the 1 nm positions (8 nm in a third difference).
        let j_max = 3.0 * a / w as f64 + 8.0;
        for i in 0..3 {
            let x: Vec<f64> = poses.iter().map(|p| p[i] as f64).collect();
            for (k, d) in x.windows(4).enumerate() {
                let j = d[3] - 3.0 * d[2] + 3.0 * d[1] - d[0];
                prop_assert!(j.abs() <= j_max, "axis {} tick {}: jerk {} > {} nm/tick³", i, k, j, j_max);
            }
        }
    }
}
