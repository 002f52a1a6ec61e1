//! The simulator is paced as the board is (`pkmc::controller::pacing`, `pkmc::drive::debounce`): the
//! drives follow the controller's commands one tick late, and the switches reach it
//! through the board's debouncing.

use pkmc::config::MachineConfig;
use pkmc::wire::{encode_frame, AlarmCause, Control, HostMsg, MAX_FRAME};
use pkmc_host::sim::{FaultKind, Injection, Simulator};
use std::path::Path;

/// Encoder counts per mm of the servo joints of `cartesian-servo.toml`.
const SERVO_COUNTS_PER_MM: f64 = 1000.0;

fn control(sim: &mut Simulator, id: u16, cmd: Control) {
    let mut f = [0u8; MAX_FRAME];
    let n = encode_frame(0, &HostMsg::Control { id, cmd }, &mut f).unwrap();
    sim.ctrl.receive(&f[..n]);
}

/// An unlocked simulator of `machine`, at rest for a few ticks.
fn unlocked(machine: MachineConfig) -> Simulator {
    let mut sim = Simulator::new(machine).unwrap();
    sim.ctrl.unlock();
    for _ in 0..20 {
        sim.tick().unwrap();
    }
    sim
}

/// Jogs X by `mm` at `mm_s`.
fn jog_x(sim: &mut Simulator, mm: f64, mm_s: f64) {
    let m = sim.ctrl.machine().clone();
    let kin = pkmc::kinematics::MachineKinematics::new(&m);
    let from = *sim.ctrl.pose();
    let planned =
        pkmc::motion::planner::plan_jog(&m, &kin, &from, 0, (mm * 1e6) as i64, (mm_s * 1e6) as i64)
            .unwrap();
    control(sim, 1, Control::Jog(planned));
}

#[test]
fn a_stepper_drive_takes_each_ticks_steps_one_tick_after_the_controller_computed_them() {
    let m = MachineConfig::cartesian_xyz();
    let mut sim = unlocked(m.clone());
    let start = sim.feedback_steps(0).unwrap();
    let emitted_at_start = sim.ctrl.steps_emitted(0);
    jog_x(&mut sim, 5.0, 20.0);
    let mut emitted_before = 0;
    let mut moving_ticks = 0;
    while sim.busy() {
        sim.tick().unwrap();
        // After tick N the drive has run the trains of ticks up to N − 1.
        assert_eq!(sim.feedback_steps(0).unwrap() - start, emitted_before);
        let emitted = sim.ctrl.steps_emitted(0) - emitted_at_start;
        if emitted != emitted_before {
            moving_ticks += 1;
        }
        emitted_before = emitted;
    }
    assert!(moving_ticks > 200, "{moving_ticks} ticks with steps");
    // The last train ran too: the drive ends on the exact step.
    assert_eq!(sim.feedback_steps(0).unwrap() - start, 2000);
    assert_eq!(sim.violations().0, 0);
}

#[test]
fn a_servo_joint_follows_each_ticks_target_one_tick_later() {
    let m = pkmc_host::machine_file::load(Path::new("../examples/machines/cartesian-servo.toml"))
        .unwrap();
    let mut sim = unlocked(m.clone());
    let scale = m.joints[0].scale;
    jog_x(&mut sim, 10.0, 20.0);
    // Commanded joint position of each tick, counts; encoder after each tick.
    let mut commanded = Vec::new();
    let mut feedback = Vec::new();
    while sim.ctrl.has_work() {
        sim.tick().unwrap();
        commanded.push(scale.steps_at(sim.ctrl.joints()[0]));
        feedback.push(sim.feedback_steps(0).unwrap());
    }
    // At the steady 20 mm/s (20 counts per tick, 2 per servo period), the encoder
    // read at the edge after tick N stands where tick N − 1's target is plus the one
    // servo period the plant has moved since its setpoint reached it (to a count):
    // the loops reached tick N − 1's target at the end of tick N, a tick late.
    let per_period = 20.0 * SERVO_COUNTS_PER_MM / 10_000.0;
    let steady = commanded.len() / 2 - 50..commanded.len() / 2 + 50;
    for n in steady {
        let ahead = (feedback[n] - commanded[n - 1]) as f64;
        assert!(
            (ahead - per_period).abs() <= 1.0,
            "tick {n}: {ahead} counts from the previous target"
        );
    }
}

/// Ticks from an injection (at a time between two ticks) to the alarm it raises.
fn ticks_to_alarm(machine: MachineConfig, kind: FaultKind) -> (u64, AlarmCause) {
    let mut sim = unlocked(machine);
    // Between ticks 50 and 51: the tick at 51 ms is the first to read it.
    sim.inject(&[Injection {
        kind,
        joint: Some(0),
        at_s: 0.0505,
    }])
    .unwrap();
    while sim.alarm_tick.is_none() {
        assert!(sim.ticks < 200, "no alarm");
        sim.tick().unwrap();
    }
    let first_read = 51;
    // `alarm_tick` counts the ticks run, the alarm's own included.
    let seen_in = sim.alarm_tick.unwrap() - 1;
    (seen_in - first_read, sim.ctrl.status().alarm.unwrap().cause)
}

#[test]
fn an_injected_estop_reaches_the_controller_in_the_tick_that_first_reads_it() {
    let (delay, cause) = ticks_to_alarm(MachineConfig::cartesian_xyz(), FaultKind::EStop);
    assert_eq!(cause, AlarmCause::EStop);
    assert_eq!(delay, 0);
}

#[test]
fn an_injected_limit_switch_reaches_the_controller_at_the_boards_third_sample() {
    let (delay, cause) = ticks_to_alarm(MachineConfig::cartesian_xyz(), FaultKind::Limit);
    assert_eq!(cause, AlarmCause::LimitSwitch);
    assert_eq!(delay, 2, "three equal samples: two ticks after the first");
}

#[test]
fn a_stepper_drive_fault_line_is_read_undebounced_and_an_amplifier_fault_at_the_next_edge() {
    // A stepper drive's fault line is read by the tick itself (no debouncing).
    let (delay, cause) = ticks_to_alarm(MachineConfig::cartesian_xyz(), FaultKind::DriveFault);
    assert_eq!(cause, AlarmCause::DriveFault);
    assert_eq!(delay, 0);
    // A servo amplifier's fault input reaches the loops and the snapshot of the edge
    // that opens the same tick.
    let m = pkmc_host::machine_file::load(Path::new("../examples/machines/cartesian-servo.toml"))
        .unwrap();
    let (delay, cause) = ticks_to_alarm(m, FaultKind::DriveFault);
    assert_eq!(cause, AlarmCause::DriveFault);
    assert_eq!(delay, 0);
}
