//! Tests of the servo and tick pacing (`controller::pacing`).
use super::*;
use crate::drive::contour::PeriodInputs;

/// Four channels' values, the others' default.
fn pad<T: Copy + Default>(a: [T; 4]) -> [T; MAX_SERVOS] {
    core::array::from_fn(|i| a.get(i).copied().unwrap_or_default())
}
use crate::wire::{encode_frame, Control, HostMsg, MAX_FRAME};

/// The H-4 table machine: four servo joints (channels 0–3) and steppers.
fn machine() -> MachineConfig {
    MachineConfig::h4_table()
}

/// A pacer and the slot its commands wait in (the firmware's mailbox).
#[derive(Clone)]
struct Paced {
    pacer: ServoPacer,
    slot: CommandSlot,
}

impl Paced {
    fn period(
        &mut self,
        feedback: &[i64; MAX_SERVOS],
        fault: &[bool; MAX_SERVOS],
    ) -> ServoPeriod<'_> {
        self.slot.period(&mut self.pacer, feedback, fault)
    }
    fn post(&mut self, command: Command) {
        self.slot.post(command);
    }
    fn restart(&mut self, bank: ServoBank) {
        self.pacer.restart(bank);
    }
    fn snapshot(&self) -> Snapshot {
        self.pacer.snapshot()
    }
    fn staged(&self, half: usize) -> (&[u8; MAX_SIGNALS], &[Row]) {
        self.pacer.staged(half)
    }
    fn stats(&self) -> ServoStats {
        self.pacer.stats()
    }
    fn trips(&self) -> [Option<Trip>; MAX_SERVOS] {
        self.pacer.trips()
    }
}

/// A pacer standing at `counts`, its bank of the H-4 machine.
fn pacer(counts: &[i64; MAX_SERVOS]) -> Paced {
    Paced {
        pacer: ServoPacer::new(ServoBank::new(&machine(), counts), counts),
        slot: CommandSlot::new(),
    }
}

/// Runs the `SERVO_PER_TICK` periods of one tick at `feedback`, no fault;
/// returns whether each was an edge.
fn one_tick(p: &mut Paced, feedback: &[i64; MAX_SERVOS]) -> [bool; SERVO_PER_TICK] {
    core::array::from_fn(|_| p.period(feedback, &[false; MAX_SERVOS]).tick)
}

#[test]
fn every_tenth_period_is_a_tick_edge_starting_with_the_first() {
    let mut p = pacer(&[0; MAX_SERVOS]);
    for _ in 0..3 {
        let edges = one_tick(&mut p, &[0; MAX_SERVOS]);
        assert!(edges[0]);
        assert!(edges[1..].iter().all(|&e| !e));
    }
    assert_eq!(p.stats().periods, 3 * SERVO_PER_TICK as u32);
    // The first edge holds the standing targets; nothing was posted for the others.
    assert_eq!(p.stats().late_ticks, 2);
}

#[test]
fn a_posted_target_is_loaded_at_the_next_edge_and_ramped_over_one_tick() {
    // The pacer against a bank fed by hand on the board's schedule: the command
    // posted after edge N is loaded at edge N + 1, never earlier.
    let counts = pad([100, -50, 0, 7]);
    let m = machine();
    let mut p = pacer(&counts);
    let mut reference = ServoBank::new(&m, &counts);
    let mut posted = Command::standing(&counts);
    let mut loaded = posted;
    let enabled = PeriodInputs {
        feedback: counts,
        fault: [false; MAX_SERVOS],
        enable: true,
    };
    for tick in 0..4i64 {
        for k in 0..SERVO_PER_TICK {
            let got = p.period(&counts, &[false; MAX_SERVOS]);
            if k == 0 {
                loaded = posted;
                reference.load_tick(&loaded.targets);
            }
            let want = reference.period(&PeriodInputs {
                enable: loaded.enable,
                ..enabled
            });
            assert_eq!(*got.out, want, "tick {tick}, period {k}");
            if k == 0 {
                // The tick runs here and posts its command for the next edge.
                let c = Command {
                    reset: false,
                    targets: counts.map(|c| (c + 40 * (tick + 1)) << SETPOINT_FRAC_BITS),
                    enable: true,
                    map: None,
                    record: [NOT_SERVO; MAX_SIGNALS],
                    record_add: [0; MAX_SIGNALS],
                };
                p.post(c);
                posted = c;
            }
        }
    }
    assert_eq!(p.stats().late_ticks, 0);
}

#[test]
fn a_late_tick_is_counted_and_the_loops_hold_their_last_target() {
    // Standing at 200 counts, the encoders reading 195: the loops are driving.
    let at = [200; MAX_SERVOS];
    let feedback = [195; MAX_SERVOS];
    let hold = Command {
        reset: false,
        targets: at.map(|c| c << SETPOINT_FRAC_BITS),
        enable: true,
        map: None,
        record: [NOT_SERVO; MAX_SIGNALS],
        record_add: [0; MAX_SIGNALS],
    };
    let mut p = pacer(&at);
    one_tick(&mut p, &feedback);
    p.post(hold);
    one_tick(&mut p, &feedback);
    // No command for the next edge: one late tick, and the loops run exactly as
    // if the same target had been posted again.
    let mut late = p.clone();
    let mut held = p;
    held.post(hold);
    for _ in 0..SERVO_PER_TICK {
        let a = late.period(&feedback, &[false; MAX_SERVOS]);
        let b = held.period(&feedback, &[false; MAX_SERVOS]);
        assert_eq!(a.out, b.out);
        assert_eq!(a.out.enable, pad([true; 4]));
    }
    assert_eq!(late.stats().late_ticks, 1);
    assert_eq!(held.stats().late_ticks, 0);
}

#[test]
fn of_two_commands_posted_before_an_edge_the_last_is_taken() {
    let counts = [0; MAX_SERVOS];
    let mut p = pacer(&counts);
    one_tick(&mut p, &counts);
    p.post(Command {
        enable: true,
        ..Command::standing(&counts)
    });
    p.post(Command::standing(&counts));
    let s = p.period(&counts, &[false; MAX_SERVOS]);
    assert!(s.tick);
    assert_eq!(s.out.enable, [false; MAX_SERVOS]);
    assert_eq!(p.stats().late_ticks, 0);
}

#[test]
fn the_snapshot_holds_the_edge_counts_and_any_fault_since_the_last_edge() {
    let mut p = pacer(&[0; MAX_SERVOS]);
    let no = [false; MAX_SERVOS];
    let s = p.period(&pad([1, 2, 3, 4]), &no);
    assert!(s.tick);
    let snap = p.snapshot();
    assert_eq!(snap.counts, pad([1, 2, 3, 4]));
    assert_eq!(snap.fault, no);
    assert_eq!(snap.periods, 1);
    // A one-period pulse on channel 2 between edges is reported at the next edge,
    // once; the counts stay those of the edge until the next one.
    for k in 1..SERVO_PER_TICK {
        let fault = pad([false, false, k == 4, false]);
        p.period(&pad([9, 9, 9, 9]), &fault);
        assert_eq!(p.snapshot().counts, pad([1, 2, 3, 4]));
    }
    p.post(Command::standing(&[0; MAX_SERVOS]));
    assert!(p.period(&pad([5, 6, 7, 8]), &no).tick);
    let snap = p.snapshot();
    assert_eq!(snap.counts, pad([5, 6, 7, 8]));
    assert_eq!(snap.fault, pad([false, false, true, false]));
    assert!(p.stats().fault);
    for _ in 1..SERVO_PER_TICK {
        p.period(&pad([5, 6, 7, 8]), &no);
    }
    p.post(Command::standing(&[0; MAX_SERVOS]));
    p.period(&pad([5, 6, 7, 8]), &no);
    assert_eq!(p.snapshot().fault, no);
    assert!(!p.stats().fault);
}

#[test]
fn an_amplifier_fault_trips_its_loop_and_the_snapshot_carries_the_trip() {
    let counts = [0; MAX_SERVOS];
    let mut p = pacer(&counts);
    one_tick(&mut p, &counts);
    p.post(Command {
        reset: false,
        targets: [0; MAX_SERVOS],
        enable: true,
        map: None,
        record: [NOT_SERVO; MAX_SIGNALS],
        record_add: [0; MAX_SIGNALS],
    });
    let fault = pad([true, false, false, false]);
    let s = p.period(&counts, &fault);
    assert!(!s.out.enable[0], "the tripped loop is disabled");
    assert_eq!(p.trips()[0], Some(Trip::AmplifierFault));
    assert_eq!(p.snapshot().trips[0], Some(Trip::AmplifierFault));
    assert_eq!(p.snapshot().trips[1], None);
}

#[test]
fn a_restart_replaces_the_bank_at_once_and_the_reset_command_loads_at_the_edge() {
    let m = machine();
    let counts = [0; MAX_SERVOS];
    let mut p = pacer(&counts);
    one_tick(&mut p, &counts);
    p.post(Command {
        reset: false,
        targets: [0; MAX_SERVOS],
        enable: true,
        map: None,
        record: [NOT_SERVO; MAX_SIGNALS],
        record_add: [0; MAX_SIGNALS],
    });
    // Trip channel 0, then reset the bank standing at new counts.
    p.period(&counts, &pad([true, false, false, false]));
    for _ in 1..SERVO_PER_TICK {
        p.period(&counts, &[false; MAX_SERVOS]);
    }
    let at = pad([300, 0, 0, 0]);
    let out = Outputs {
        servo_target: at.map(|c| c << SETPOINT_FRAC_BITS),
        servo_enable: true,
        servo_reset: true,
        ..Outputs::default()
    };
    let command = Command::of(&out, None);
    assert!(command.reset);
    p.restart(ServoBank::new(&m, &at));
    assert_eq!(p.snapshot().trips[0], Some(Trip::AmplifierFault));
    p.post(command);
    let enable = p.period(&at, &[false; MAX_SERVOS]).out.enable;
    assert_eq!(p.trips(), [None; MAX_SERVOS]);
    assert_eq!(enable, pad([true; 4]));
}

fn control(ctrl: &mut Controller, id: u16, cmd: Control) {
    let mut f = [0u8; MAX_FRAME];
    let n = encode_frame(0, &HostMsg::Control { id, cmd }, &mut f).unwrap();
    ctrl.receive(&f[..n]);
}

/// A jog as `nc-send` sends it, from where `c` stands.
fn jog_cmd(c: &Controller, axis: usize, distance: i64, feed: i64) -> Control {
    let kin = crate::kinematics::MachineKinematics::new(c.machine());
    Control::Jog(
        crate::motion::planner::plan_jog(c.machine(), &kin, c.pose(), axis, distance, feed)
            .unwrap(),
    )
}

#[test]
fn a_ticks_step_trains_are_due_at_the_start_of_the_next_tick() {
    let mut ctrl = Controller::new(MachineConfig::cartesian_xyz()).unwrap();
    ctrl.unlock();
    let mut t = TickPacer::new();
    let snap = Snapshot::default();
    let raw = RawInputs::default();
    t.tick(&mut ctrl, &raw, &snap);
    let jog = jog_cmd(&ctrl, 0, 1_000_000, 10_000_000);
    control(&mut ctrl, 1, jog);
    let mut applied = 0i64;
    let mut computed = 0i64;
    for _ in 0..2000 {
        // What the board applies at the start of the tick: the last tick's trains.
        let due = t.due().steps[0];
        applied += i64::from(due.count) * if due.forward { 1 } else { -1 };
        assert_eq!(applied, computed, "one tick behind the controller");
        t.tick(&mut ctrl, &raw, &snap);
        computed = ctrl.steps_emitted(0);
    }
    assert_eq!(computed, 400, "1 mm at 400 steps/mm");
    assert_eq!(applied, computed);
}

#[test]
fn a_limit_switch_reaches_the_controller_at_its_third_sample_and_the_estop_at_once() {
    let mut ctrl = Controller::new(MachineConfig::cartesian_xyz()).unwrap();
    ctrl.unlock();
    let mut t = TickPacer::new();
    let snap = Snapshot::default();
    let mut raw = RawInputs::default();
    t.tick(&mut ctrl, &raw, &snap);
    raw.switches.limit = 1 << 1;
    let mut seen = 0;
    while ctrl.status().alarm.is_none() {
        t.tick(&mut ctrl, &raw, &snap);
        seen += 1;
        assert!(seen <= 3);
    }
    assert_eq!(seen, 3);
    assert_eq!(t.switches().limit, 1 << 1);

    let mut ctrl = Controller::new(MachineConfig::cartesian_xyz()).unwrap();
    ctrl.unlock();
    let mut t = TickPacer::new();
    let raw = RawInputs {
        switches: Switches {
            estop: true,
            ..Switches::default()
        },
        ..RawInputs::default()
    };
    t.tick(&mut ctrl, &raw, &snap);
    assert!(
        ctrl.status().alarm.is_some(),
        "the e-stop in the tick that reads it"
    );
}

#[test]
fn an_amplifier_fault_in_the_snapshot_is_the_drive_fault_of_its_servo_joint() {
    let m = machine();
    let mut fault = [false; MAX_SERVOS];
    fault[2] = true;
    let bits = servo_joints_faulted(&m, &fault);
    let expected = m
        .joints
        .iter()
        .enumerate()
        .filter(|(_, j)| matches!(j.drive, Drive::Servo { channel: 2 }))
        .fold(0u16, |b, (i, _)| b | 1 << i);
    assert_ne!(expected, 0);
    assert_eq!(bits, expected);
    assert_eq!(servo_joints_faulted(&m, &[false; MAX_SERVOS]), 0);
}

#[test]
fn the_hexapod_xys_command_carries_its_contour_map_every_map_phases_ticks() {
    use crate::kinematics::{hexapod_xy_map::MAP_PHASES, MachineKinematics};
    let m = MachineConfig::hexapod_xy();
    let MachineKinematics::HexapodXy(k) = MachineKinematics::new(&m) else {
        panic!("the hexapod-xy's kinematics");
    };
    let want = ContourMap::of_joints(&m, &k.contour_map(&m.home).unwrap());
    let mut ctrl = Controller::new(m).unwrap();
    let mut t = TickPacer::new();
    let (raw, snap) = (RawInputs::default(), Snapshot::default());
    let mut carried = 0;
    for tick in 1..=4 * MAP_PHASES as usize {
        let command = t.tick(&mut ctrl, &raw, &snap);
        if tick % MAP_PHASES as usize == 0 {
            assert_eq!(command.map, Some(want), "tick {tick}");
            carried += 1;
        } else {
            assert_eq!(command.map, None, "tick {tick}");
        }
    }
    assert_eq!(carried, 4);
}

#[test]
fn the_recorders_servo_samples_are_each_periods_and_read_a_tick_later() {
    let counts = [1000; MAX_SERVOS];
    let mut p = pacer(&counts);
    one_tick(&mut p, &counts);
    // Channel 1's setpoint, feedback, error and DAC code every period of the next
    // tick, which moves it by 100 counts; the positions counted from 900 (the joint's
    // zero); then a value the tick sampled itself, held, 16 bits.
    let mut record = [NOT_SERVO; MAX_SIGNALS];
    record[..5].copy_from_slice(&[0x01, 0x11, 0x21, 0x31, HELD_NARROW]);
    let mut record_add = [0; MAX_SIGNALS];
    record_add[..5].copy_from_slice(&[-900, -900, 0, 0, 40_000]);
    p.post(Command {
        reset: false,
        targets: counts.map(|c| (c + 100) << SETPOINT_FRAC_BITS),
        enable: true,
        map: None,
        record,
        record_add,
    });
    // The feedback lags the setpoint by 3 counts from the second period on.
    let mut dacs = Vec::new();
    for k in 0..SERVO_PER_TICK {
        let mut fb = counts;
        fb[1] = 1000 + (10 * k as i64 - 3).max(0);
        dacs.push(p.period(&fb, &[false; MAX_SERVOS]).out.dac[1] as i32);
    }
    // Not yet complete: the bank being read is the previous tick's, of no signals.
    assert_eq!(p.staged(0).0, &[NOT_SERVO; MAX_SIGNALS]);
    p.post(Command::standing(&counts));
    p.period(&counts, &[false; MAX_SERVOS]);
    let (ids, first) = p.staged(0);
    assert_eq!(ids, &record);
    let (_, second) = p.staged(1);
    let rows: Vec<_> = first.iter().chain(second).copied().collect();
    assert_eq!(rows.len(), SERVO_PER_TICK);
    let i32_at = |r: &[u8], at: usize| i32::from_le_bytes([r[at], r[at + 1], r[at + 2], r[at + 3]]);
    let i16_at = |r: &[u8], at: usize| i16::from_le_bytes([r[at], r[at + 1]]) as i32;
    for (k, row) in rows.iter().enumerate() {
        let setpoint = 1000 + 10 * (k as i32 + 1);
        let feedback = 1000 + (10 * k as i32 - 3).max(0);
        let got = [
            i32_at(row, 0),
            i32_at(row, 4),
            i16_at(row, 8),
            i16_at(row, 10),
            i16_at(row, 12),
        ];
        // The held value saturates at 16 bits, as the ring keeps it.
        let want = [
            setpoint - 900,
            feedback - 900,
            setpoint - feedback,
            dacs[k],
            32_767,
        ];
        assert_eq!(got, want, "period {k}");
        assert!(row[14..].iter().all(|&b| b == 0));
    }
}
