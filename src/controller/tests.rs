//! The controller's unit tests: the link session, motion, faults and homing, each test
//! named as the sentence it checks.

use super::*;
use crate::config::MAX_STEPPERS;
use crate::drive::servo::Trip;
use crate::motion::block::{Block, Motion};
use crate::wire::{
    decode_frame, encode_frame, AlarmCause, Control, CtrlMsg, FrameReader, HostMsg, NakReason,
    Pushed, PROTOCOL_VERSION,
};

pub(super) fn frame(seq: u16, msg: &HostMsg) -> Vec<u8> {
    let mut f = [0u8; MAX_FRAME];
    let n = encode_frame(seq, msg, &mut f).unwrap();
    f[..n].to_vec()
}

pub(super) fn replies(c: &mut Controller) -> Vec<CtrlMsg> {
    let mut buf = [0u8; TX_CAPACITY];
    let n = c.transmit(&mut buf);
    let mut reader = FrameReader::new();
    let mut out = Vec::new();
    for &b in &buf[..n] {
        if let Pushed::Frame(f) = reader.push(b) {
            let mut body = [0u8; MAX_BODY];
            out.push(decode_frame::<CtrlMsg>(f, &mut body).unwrap().1);
        }
    }
    out
}

/// The host's plan of `blocks` from `start` on `m` (unlimited look-ahead).
pub(super) fn planned(m: &MachineConfig, start: [i64; 6], blocks: &[Block]) -> Vec<HostMsg> {
    let kin = MachineKinematics::new(m);
    let mut out = vec![crate::motion::planner::PlanBlock::default(); blocks.len()];
    crate::motion::planner::plan_into(blocks, start, m, &kin, 1, &mut out).unwrap();
    blocks
        .iter()
        .zip(&out)
        .map(|(b, p)| {
            HostMsg::Block(crate::motion::block::PlannedBlock {
                block: *b,
                plan: p.plan(),
            })
        })
        .collect()
}

/// A line along X from X = 0 on the Cartesian machine, planned by the host.
pub(super) fn line_to(x_mm: i64, line: u32) -> HostMsg {
    line_from(0, x_mm, line)
}

pub(super) fn line_from(from_mm: i64, x_mm: i64, line: u32) -> HostMsg {
    let b = Block {
        line,
        motion: Motion::Linear,
        target: [x_mm * 1_000_000, 0, 0, 0, 0, 0],
        feed: 50_000_000,
        tolerance_nm: u32::MAX,
    };
    let start = [from_mm * 1_000_000, 0, 0, 0, 0, 0];
    planned(&MachineConfig::cartesian_xyz(), start, &[b]).remove(0)
}

pub(super) fn hello(c: &Controller) -> HostMsg {
    HostMsg::Hello {
        version: PROTOCOL_VERSION,
        machine: c.machine_id(),
        host: 1,
    }
}

pub(super) fn session() -> Controller {
    let mut c = Controller::new(MachineConfig::cartesian_xyz()).unwrap();
    c.unlock();
    c.receive(&frame(0, &hello(&c)));
    c
}

#[test]
fn a_machine_config_on_a_servo_channel_the_board_does_not_wire_is_refused_naming_its_joint() {
    // A board with every stepper channel and servo channels 0..3 only.
    let board = BoardChannels {
        steppers: MAX_STEPPERS as u8,
        servos: 3,
    };
    let mut slot = core::mem::MaybeUninit::uninit();
    let c = Controller::init_on(&mut slot, MachineConfig::cartesian_xyz(), board).unwrap();
    // The H-4's joint 3 is on servo channel 3: the core has room for it, this board
    // does not wire it.
    let other = MachineConfig::h4_table();
    assert_eq!(other.validate(), Ok(()));
    let mut payload = [0u8; crate::wire::store::MAX_CONFIG_BYTES];
    let n = crate::wire::store::encode(&other, &mut payload).unwrap();
    let id = crate::wire::store::identity(&other);
    for (chunk_id, off) in (100..).zip((0..n).step_by(crate::wire::store::CHUNK_BYTES)) {
        let end = (off + crate::wire::store::CHUNK_BYTES).min(n);
        c.receive(&frame(
            0,
            &HostMsg::Machine {
                id: chunk_id,
                offset: off as u16,
                total: n as u16,
                crc: id,
                data: heapless::Vec::from_slice(&payload[off..end]).unwrap(),
            },
        ));
    }
    let refused = CtrlMsg::MachineRefused {
        error: crate::wire::store::StoreError::Invalid(ConfigError::JointChannel { joint: 3 }),
    };
    assert!(replies(c).contains(&refused));
    assert_eq!(c.machine(), &MachineConfig::cartesian_xyz());
    // Nor can it be the first machine.
    let mut slot = core::mem::MaybeUninit::uninit();
    assert_eq!(
        Controller::init_on(&mut slot, other, board).err(),
        Some(ConfigError::JointChannel { joint: 3 })
    );
}

#[test]
fn a_controller_that_disagrees_about_the_machine_refuses_to_move_until_sent_it() {
    let mut other = MachineConfig::cartesian_xyz();
    other.joints[0].limits.max_velocity /= 2;
    other.axes[0].max_velocity /= 2;
    let mut c = Controller::new(MachineConfig::cartesian_xyz()).unwrap();
    let id = crate::wire::store::identity(&other);
    c.receive(&frame(
        0,
        &HostMsg::Hello {
            version: PROTOCOL_VERSION,
            machine: id,
            host: 1,
        },
    ));
    c.receive(&frame(1, &line_to(10, 1)));
    let r = replies(&mut c);
    assert!(matches!(r[0], CtrlMsg::HelloAck { machine, .. } if machine != id));
    assert_eq!(
        r[1],
        CtrlMsg::Nak {
            expected: 1,
            reason: NakReason::MachineMismatch
        }
    );
    assert_eq!(
        c.status().alarm.map(|a| a.cause),
        Some(AlarmCause::MachineMismatch)
    );
    // Send the machine in chunks, each twice (a resend), the first once more.
    let mut payload = [0u8; crate::wire::store::MAX_CONFIG_BYTES];
    let n = crate::wire::store::encode(&other, &mut payload).unwrap();
    let offsets = (0..n).step_by(crate::wire::store::CHUNK_BYTES).chain([0]);
    for (chunk_id, off) in (100..).zip(offsets) {
        let end = (off + crate::wire::store::CHUNK_BYTES).min(n);
        let msg = HostMsg::Machine {
            id: chunk_id,
            offset: off as u16,
            total: n as u16,
            crc: id,
            data: heapless::Vec::from_slice(&payload[off..end]).unwrap(),
        };
        c.receive(&frame(0, &msg));
        c.receive(&frame(0, &msg));
    }
    assert!(replies(&mut c).contains(&CtrlMsg::MachineLoaded { machine: id }));
    assert_eq!(c.machine(), &other);
    assert_eq!(c.take_store_request(), Some(&other));
    assert_eq!(c.take_store_request(), None);
    // A new machine: locked until homed or unlocked.
    assert_eq!(c.status().alarm.map(|a| a.cause), Some(AlarmCause::Unhomed));
    c.unlock();
    assert_eq!(c.state(), State::Idle);
    c.receive(&frame(1, &line_to(10, 1)));
    run(&mut c, 10_000);
    assert_eq!(c.pose()[0], 10_000_000);
}

/// Runs `ticks` periods, the host asking for a status every 100 ms as nc-send does.
pub(super) fn run(c: &mut Controller, ticks: usize) {
    for t in 0..ticks {
        if t % 100 == 0 {
            c.receive(&frame(0, &HostMsg::StatusRequest));
        }
        c.tick(&Inputs::default());
    }
}

#[test]
fn a_block_is_acknowledged_executed_and_ends_on_its_target() {
    let mut c = session();
    c.receive(&frame(1, &line_to(10, 7)));
    let r = replies(&mut c);
    assert!(matches!(r[0], CtrlMsg::HelloAck { .. }));
    assert!(matches!(
        r[1],
        CtrlMsg::Ack {
            seq: 1,
            free_slots,
            ..
        } if free_slots as usize == QUEUE_CAPACITY - 1
    ));
    run(&mut c, 10_000);
    assert_eq!(c.state(), State::Idle);
    assert_eq!(c.pose()[0], 10_000_000);
    assert_eq!(c.steps_emitted(0), 4000);
    assert_eq!(c.line(), 7);
}

#[test]
fn a_duplicate_block_is_acknowledged_but_not_queued_twice() {
    let mut c = session();
    c.receive(&frame(1, &line_to(10, 1)));
    let _ = replies(&mut c);
    c.receive(&frame(1, &line_to(10, 1)));
    // Acks are owed until `transmit`: the duplicate is acknowledged on its own.
    let one_block_acked = |r: &[CtrlMsg]| {
        matches!(
            r[..],
            [CtrlMsg::Ack {
                seq: 1,
                free_slots,
                ..
            }] if free_slots as usize == QUEUE_CAPACITY - 1
        )
    };
    assert!(one_block_acked(&replies(&mut c)));
    // Received together, the block and its duplicate draw one cumulative ack.
    let mut c = session();
    let _ = replies(&mut c);
    c.receive(&frame(1, &line_to(10, 1)));
    c.receive(&frame(1, &line_to(10, 1)));
    assert!(one_block_acked(&replies(&mut c)));
}

#[test]
fn a_gap_and_a_corrupt_frame_are_refused_with_the_expected_sequence() {
    let mut c = session();
    c.receive(&frame(5, &line_to(10, 1)));
    let mut bad = frame(1, &line_to(10, 1));
    bad[3] ^= 0x10;
    c.receive(&bad);
    let r = replies(&mut c);
    assert_eq!(
        r[1],
        CtrlMsg::Nak {
            expected: 1,
            reason: NakReason::Gap
        }
    );
    assert_eq!(
        r[2],
        CtrlMsg::Nak {
            expected: 1,
            reason: NakReason::Corrupt
        }
    );
    assert_eq!(c.link_stats().corrupt, 1);
}

#[test]
fn an_unreachable_block_raises_an_alarm_naming_line_and_joint() {
    let mut c = session();
    c.receive(&frame(1, &line_to(50, 41)));
    c.receive(&frame(2, &line_from(50, 500, 42)));
    run(&mut c, 5000);
    assert_eq!(c.state(), State::Alarm);
    assert_eq!(
        c.status().alarm,
        Some(Alarm {
            cause: AlarmCause::JointLimit,
            joint: 0,
            line: 42
        })
    );
    // It stopped at rest at the end of the reachable block.
    assert_eq!(c.pose()[0], 50_000_000);
}

#[test]
fn a_feed_hold_stops_on_the_path_within_the_braking_distance_and_resumes() {
    let mut c = session();
    c.receive(&frame(1, &line_to(80, 1)));
    run(&mut c, 1000); // at 50 mm/s by now
    let v = c.status().speed as f64 / 1e6; // mm/s
    let at = c.pose()[0];
    c.receive(&frame(
        0,
        &HostMsg::Control {
            id: 1,
            cmd: Control::Hold,
        },
    ));
    run(&mut c, 500);
    assert_eq!(c.state(), State::Hold);
    assert_eq!(c.status().speed, 0);
    let stop = (c.pose()[0] - at) as f64 / 1e6;
    let limit = v * v / (2.0 * 1000.0) + v * 1e-3;
    assert!(
        stop <= limit + 1e-6,
        "stopped after {stop} mm, limit {limit}"
    );
    assert_eq!(c.pose()[1], 0, "on the path");
    let held = *c.pose();
    run(&mut c, 500);
    assert_eq!(c.pose(), &held, "a hold keeps its position");
    c.receive(&frame(
        0,
        &HostMsg::Control {
            id: 2,
            cmd: Control::Resume,
        },
    ));
    run(&mut c, 5000);
    assert_eq!(c.state(), State::Idle);
    assert_eq!(c.pose()[0], 80_000_000);
}

#[test]
fn a_resume_after_a_pause_that_ends_the_queue_is_idle_at_once() {
    let mut c = session();
    // (A held job with a live link watch is work: time runs for the watch.)
    c.set_link_watch(false);
    c.receive(&frame(1, &line_to(1, 1)));
    let pause = Block {
        line: 2,
        motion: Motion::Aux(Aux::Pause(true)),
        target: [1_000_000, 0, 0, 0, 0, 0],
        feed: 0,
        tolerance_nm: 0,
    };
    let at = [1_000_000, 0, 0, 0, 0, 0];
    let pause = planned(&MachineConfig::cartesian_xyz(), at, &[pause]).remove(0);
    c.receive(&frame(2, &pause));
    run(&mut c, 2000);
    assert_eq!(c.state(), State::Hold, "M1 pauses");
    assert!(!c.has_work());
    c.receive(&frame(
        0,
        &HostMsg::Control {
            id: 1,
            cmd: Control::Resume,
        },
    ));
    assert_eq!(
        c.state(),
        State::Idle,
        "nothing left to run: no tick needed"
    );
    assert_eq!(c.status().blocks_done, 2);
}

#[test]
fn a_repeated_control_id_is_acknowledged_but_acted_on_once() {
    let mut c = session();
    c.receive(&frame(
        0,
        &HostMsg::Control {
            id: 9,
            cmd: Control::FeedOverride(50),
        },
    ));
    c.receive(&frame(
        0,
        &HostMsg::Control {
            id: 9,
            cmd: Control::FeedOverride(150),
        },
    ));
    assert_eq!(c.status().feed_override, 50);
    let acks = replies(&mut c)
        .iter()
        .filter(|m| matches!(m, CtrlMsg::ControlAck { id: 9 }))
        .count();
    assert_eq!(acks, 2);
}

pub(super) fn run_with(c: &mut Controller, ticks: usize, inputs: &Inputs) {
    for t in 0..ticks {
        if t % 100 == 0 {
            c.receive(&frame(0, &HostMsg::StatusRequest));
        }
        c.tick(inputs);
    }
}

/// A jog as `nc-send` sends it, from where `c` stands.
pub(super) fn jog_cmd(c: &Controller, axis: usize, distance: i64, feed: i64) -> Control {
    let kin = crate::kinematics::MachineKinematics::new(c.machine());
    Control::Jog(
        crate::motion::planner::plan_jog(c.machine(), &kin, c.pose(), axis, distance, feed)
            .unwrap(),
    )
}

pub(super) fn control(c: &mut Controller, id: u16, cmd: Control) {
    c.receive(&frame(0, &HostMsg::Control { id, cmd }));
}

#[test]
fn after_reset_nothing_moves_until_unlocked() {
    let mut c = Controller::new(MachineConfig::cartesian_xyz()).unwrap();
    c.receive(&frame(0, &hello(&c)));
    assert_eq!(c.state(), State::Alarm);
    assert_eq!(c.status().alarm.map(|a| a.cause), Some(AlarmCause::Unhomed));
    c.receive(&frame(1, &line_to(10, 1)));
    let jog = jog_cmd(&c, 0, 1_000_000, 10_000_000);
    control(&mut c, 1, jog);
    run(&mut c, 2000);
    assert_eq!(
        c.pose()[0],
        0,
        "locked: neither the block nor the jog moved"
    );
    control(&mut c, 2, Control::AlarmReset);
    assert_eq!(c.state(), State::Idle);
    assert!(!c.homed(), "unlocked, not homed");
}

#[test]
fn an_estop_stops_on_the_path_disables_the_drives_and_holds_until_released() {
    let mut c = session();
    c.receive(&frame(1, &line_to(80, 3)));
    run(&mut c, 1000);
    let v = c.status().speed as f64 / 1e6;
    let at = c.pose()[0];
    let pressed = Inputs {
        estop: true,
        ..Inputs::default()
    };
    run_with(&mut c, 500, &pressed);
    assert_eq!(c.state(), State::EStop);
    assert_eq!(
        c.status().alarm,
        Some(Alarm {
            cause: AlarmCause::EStop,
            joint: NO_JOINT,
            line: 3
        })
    );
    let stop = (c.pose()[0] - at) as f64 / 1e6;
    assert!(stop <= v * v / 2000.0 + v * 1e-3 + 1e-6, "{stop} mm");
    assert!(!c.tick(&pressed).enable, "drives off once stopped");
    let held = *c.pose();
    // Reset is refused while the e-stop is pressed; once released it is accepted
    // and the controller stays where it stopped.
    control(&mut c, 1, Control::AlarmReset);
    assert_eq!(c.state(), State::EStop);
    run(&mut c, 10);
    control(&mut c, 2, Control::AlarmReset);
    assert_eq!(c.state(), State::Idle);
    run(&mut c, 100);
    assert_eq!(c.pose(), &held);
    assert_eq!(
        c.steps_emitted(0),
        c.machine().joints[0].scale.steps_at(held[0])
    );
}

#[test]
fn a_limit_switch_alarms_on_its_edge_naming_the_joint() {
    let mut c = session();
    c.receive(&frame(1, &line_to(80, 9)));
    run(&mut c, 300);
    let tripped = Inputs {
        limit: 0b100,
        ..Inputs::default()
    };
    run_with(&mut c, 500, &tripped);
    assert_eq!(
        c.status().alarm,
        Some(Alarm {
            cause: AlarmCause::LimitSwitch,
            joint: 2,
            line: 9
        })
    );
    // Reset is allowed with the switch still active (to move off it) and the
    // still-active switch does not alarm again.
    control(&mut c, 1, Control::AlarmReset);
    run_with(&mut c, 10, &tripped);
    assert_eq!(c.state(), State::Idle);
}

#[test]
fn jogs_stop_at_the_soft_limits() {
    let mut c = session();
    let jog = jog_cmd(&c, 0, 500_000_000, 100_000_000);
    control(&mut c, 1, jog);
    run(&mut c, 10_000);
    assert_eq!(c.state(), State::Idle);
    assert_eq!(c.pose()[0], c.machine().joints[0].max);
}

#[test]
fn silence_from_the_host_while_moving_stops_the_machine_on_the_path() {
    let mut c = session();
    c.receive(&frame(1, &line_to(80, 4)));
    for _ in 0..LINK_LOSS_TICKS - 1 {
        c.tick(&Inputs::default());
    }
    assert_eq!(c.state(), State::Running);
    c.tick(&Inputs::default());
    assert_eq!(
        c.status().alarm,
        Some(Alarm {
            cause: AlarmCause::LinkLoss,
            joint: NO_JOINT,
            line: 4
        })
    );
    assert!(c.has_work(), "still stopping on the path");
    for _ in 0..1000 {
        c.tick(&Inputs::default());
    }
    assert!(!c.has_work());
    assert_eq!(c.status().speed, 0);
}

#[test]
fn a_servo_trip_names_the_joint_of_its_channel() {
    let mut c = Controller::new(MachineConfig::h4_table()).unwrap();
    c.unlock();
    c.receive(&frame(0, &hello(&c)));
    let trip = Inputs {
        servo_trip: [
            None,
            None,
            Some(Trip::FollowingError {
                error: 5000,
                limit: 2000,
            }),
            None,
            None,
            None,
            None,
            None,
        ],
        ..Inputs::default()
    };
    c.tick(&trip);
    assert_eq!(
        c.status().alarm.map(|a| (a.cause, a.joint)),
        Some((AlarmCause::FollowingError, 2))
    );
    // After the reset the loops restart from their feedback; the trip the bank
    // still reports in that tick is the one cleared.
    control(&mut c, 1, Control::AlarmReset);
    assert!(c.tick(&trip).servo_reset);
    assert_eq!(c.state(), State::Idle);
    assert!(c.status().alarm.is_none());
}
