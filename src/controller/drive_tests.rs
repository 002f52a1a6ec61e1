//! The controller's tests of its drives: stepper joints on exact steps, drive faults,
//! the guard on joint speeds, and each actuator's reported position.

use super::*;
use crate::config::MAX_STEPPERS;
use crate::motion::block::{Block, Motion};
use crate::wire::{AlarmCause, Control, HostMsg};

use super::tests::*;

/// A gantry with a second Y motor and rotary A B C: seven stepper joints, one on
/// every board channel (channel 6 is HRTIM1's).
fn seven_steppers() -> MachineConfig {
    let mut m = MachineConfig::cartesian_xyz();
    let deg = crate::units::NDEG_PER_DEG;
    let rotary = crate::config::Limits {
        max_velocity: 90 * deg,
        max_accel: 900 * deg,
    };
    for (c, axis) in [(3u8, 3u8), (4, 4), (5, 5), (6, 1)] {
        let mut j = m.joints[1];
        if let Drive::Stepper { channel, .. } = &mut j.drive {
            *channel = c;
        }
        if axis >= 3 {
            j.rotary = true;
            j.scale = crate::config::Scale::new(50, deg as u64);
            j.min = -180 * deg;
            j.max = 180 * deg;
            j.limits = rotary;
            j.homing = crate::config::Homing::NONE;
            m.axes[axis as usize] = rotary;
        }
        let _ = m.joints.push(j);
        if let crate::config::KinematicsConfig::Cartesian { axis_of_joint } = &mut m.kinematics {
            axis_of_joint[m.joints.len() - 1] = axis;
        }
    }
    m
}

#[test]
fn seven_stepper_joints_end_on_exact_steps() {
    let m = seven_steppers();
    assert_eq!(m.validate(), Ok(()));
    let mut c = Controller::new(m.clone()).unwrap();
    c.unlock();
    c.receive(&frame(0, &hello(&c)));
    let deg = crate::units::NDEG_PER_DEG;
    let target = [
        10_000_000,
        20_000_000,
        -5_000_000,
        30 * deg,
        -45 * deg,
        90 * deg,
    ];
    let b = Block {
        line: 1,
        motion: Motion::Linear,
        target,
        feed: 20_000_000,
        tolerance_nm: 0,
    };
    c.receive(&frame(1, &planned(&m, *c.pose(), &[b])[0]));
    let mut emitted = [0i64; MAX_STEPPERS];
    for t in 0..20_000 {
        if t % 100 == 0 {
            c.receive(&frame(0, &HostMsg::StatusRequest));
        }
        let out = *c.tick(&Inputs::default());
        for (e, train) in emitted.iter_mut().zip(&out.steps) {
            *e += if train.forward {
                train.count as i64
            } else {
                -(train.count as i64)
            };
        }
        if c.state() == State::Idle && !c.has_work() {
            break;
        }
    }
    assert_eq!(c.pose(), &target);
    // Channel 6 (the second Y motor) emitted exactly what Y did.
    let want = [4000, 8000, -2000, 1500, -2250, 4500, 8000];
    assert_eq!(emitted, want);
}

#[test]
fn a_drive_fault_while_the_drives_are_off_does_not_block_the_reset() {
    let mut c = session();
    let pressed = Inputs {
        estop: true,
        drive_fault: 0b1, // this drive reports a fault whenever it is disabled
        ..Inputs::default()
    };
    run_with(&mut c, 10, &pressed);
    assert_eq!(c.state(), State::EStop);
    let released = Inputs {
        drive_fault: 0b1,
        ..Inputs::default()
    };
    run_with(&mut c, 10, &released);
    control(&mut c, 1, Control::AlarmReset);
    assert_eq!(c.state(), State::Idle, "the fault line of a disabled drive");
    // Powered again, the fault is real.
    run_with(&mut c, 2, &released);
    assert_eq!(
        c.status().alarm.map(|a| (a.cause, a.joint)),
        Some((AlarmCause::DriveFault, 0))
    );
}

#[test]
fn a_plan_faster_than_a_joint_may_move_trips_the_guard_and_the_drives_keep_the_believed_position() {
    // A host that plans 1000 mm/s on a machine whose joints allow 100 mm/s (the
    // controller takes the host's speeds as they come: the guard is the backstop).
    let mut c = session();
    let HostMsg::Block(mut pb) = line_to(100, 9) else {
        unreachable!()
    };
    pb.block.feed = 1_000_000_000;
    pb.plan.v_limit = 1_000_000.0;
    pb.plan.accel = 100_000.0;
    c.receive(&frame(1, &HostMsg::Block(pb)));
    let mut ticks = 0;
    while c.state() != State::Alarm && ticks < 1000 {
        c.tick(&Inputs::default());
        ticks += 1;
    }
    let alarm = c.alarm.expect("the guard trips");
    assert_eq!(
        (alarm.cause, alarm.joint, alarm.line),
        (AlarmCause::JointSpeed, 0, 9)
    );
    // It tripped in the first period that would have moved X more than 100 mm/s × T
    // × 1.05 (+ 2 nm): every setpoint applied was within that.
    let limit = 100_000_000 * 105 / 100 / 1000 + 2;
    assert!(c.joints()[0] <= limit * ticks, "{:?}", c.joints());
    // The steps already planned reach the drive; then it stands where the controller
    // believes it is, and so does the pose.
    for _ in 0..3 {
        c.tick(&Inputs::default());
    }
    let x = c.joints()[0];
    assert_eq!(c.steps_emitted(0), c.machine().joints[0].scale.steps_at(x));
    assert_eq!(c.pose()[0], x);
    assert!(c.planner.is_empty());
}

#[test]
fn the_status_reports_each_actuator_from_its_zero_encoders_as_read_steps_as_emitted() {
    let m = MachineConfig::h4_table();
    let mut c = Controller::new(m.clone()).unwrap();
    c.unlock();
    // Power-up: the encoders read 1000 counts; the joints are where the controller
    // believes (the home pose), so each servo reads its home position.
    let mut inputs = Inputs {
        encoder_counts: [1000; crate::config::MAX_SERVOS],
        ..Inputs::default()
    };
    c.tick(&inputs);
    let home = c.status();
    for j in 0..4 {
        assert_eq!(
            home.measured[j],
            m.joints[j].scale.steps_at(home.joints[j]),
            "joint {j}"
        );
    }
    // The carriage of channel 2 lags 37 counts behind: reported as read.
    inputs.encoder_counts[2] -= 37;
    c.tick(&inputs);
    assert_eq!(c.status().measured[2], home.measured[2] - 37);
    // The table's stepper has emitted no step.
    assert_eq!(c.status().measured[4], 0);
}
