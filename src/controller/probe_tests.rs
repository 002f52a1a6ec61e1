//! Probing moves through the tick pacer, on a stepper machine whose steps run evenly
//! over each tick: the latch against the true crossing, the stop, and the errors.

use super::pacing::{RawInputs, Snapshot, TickPacer};
use super::tests::control;
use super::*;
use crate::drive::probe::{ProbeMode, ProbeResult, LATCH_FRAC_BITS};
use crate::wire::{AlarmCause, Control};

/// A cartesian machine at its home pose with a surface along Z: the probe touches
/// below `surface` (Z steps from the joint's zero).
struct Bench {
    ctrl: Controller,
    pacer: TickPacer,
    raw: RawInputs,
    /// Z steps completed at the start of the last tick and of the one before.
    done: [i64; 2],
    surface: f64,
    per_mm: f64,
    /// Id of the last control sent.
    id: u16,
}

impl Bench {
    fn new(surface_mm: f64) -> Self {
        let mut ctrl = Controller::new(MachineConfig::cartesian_xyz()).unwrap();
        ctrl.unlock();
        let z0 = ctrl.steps_emitted(2);
        let per_mm = ctrl.machine().joints[2].scale.steps as f64 * 1e6
            / ctrl.machine().joints[2].scale.per_units as f64;
        let mut b = Self {
            ctrl,
            pacer: TickPacer::new(),
            raw: RawInputs::default(),
            done: [z0; 2],
            surface: z0 as f64 + surface_mm * per_mm,
            per_mm,
            id: 0,
        };
        b.tick();
        b
    }

    /// Is Z (steps, fractional) below the surface?
    fn touching(&self, z: f64) -> bool {
        z <= self.surface
    }

    /// One tick: the trains due start now; the probe is sampled from where the steps
    /// have run, with the edge time of a crossing in the last tick.
    fn tick(&mut self) {
        let due = self.pacer.due().steps[2];
        let (a, b) = (self.done[1] as f64, self.done[0] as f64);
        let touching = self.touching(b);
        self.raw.probe_edge_us = (touching != self.touching(a)).then(|| {
            let f = (self.surface - a) / (b - a);
            (f * 1000.0).round() as u16
        });
        self.raw.probe = touching;
        self.pacer
            .tick(&mut self.ctrl, &self.raw, &Snapshot::default());
        let now = self.done[0] + i64::from(due.count) * if due.forward { 1 } else { -1 };
        self.done = [now, self.done[0]];
    }

    fn probe(&mut self, distance_mm: i64, mode: ProbeMode) {
        let kin = MachineKinematics::new(self.ctrl.machine());
        let planned = crate::motion::planner::plan_jog(
            self.ctrl.machine(),
            &kin,
            self.ctrl.pose(),
            2,
            distance_mm * 1_000_000,
            5_000_000,
        )
        .unwrap();
        self.id += 1;
        control(&mut self.ctrl, self.id, Control::Probe { planned, mode });
    }

    fn run(&mut self) -> ProbeResult {
        for _ in 0..10_000 {
            self.tick();
            if !self.ctrl.has_work() && self.ctrl.state() != State::Running {
                break;
            }
        }
        for _ in 0..3 {
            self.tick();
        }
        self.ctrl.probe_result().unwrap()
    }

    fn steps(at: i64) -> f64 {
        at as f64 / (1 << LATCH_FRAC_BITS) as f64
    }
}

#[test]
fn a_probing_move_latches_the_crossing_and_stops_within_its_deceleration() {
    let mut b = Bench::new(-3.0);
    b.probe(-10, ProbeMode::Touch);
    let r = b.run();
    assert!(r.contact);
    assert_eq!(r.count, 1);
    let z = Bench::steps(r.at[2]);
    assert!(
        (z - b.surface).abs() < 0.02,
        "latched {z} steps, the surface is at {}",
        b.surface
    );
    assert_eq!(b.ctrl.state(), State::Idle);
    // Three ticks to confirm and start the stop at 5 mm/s (15 µm), then a stop from
    // 5 mm/s at half the machine's 1000 mm/s² (25 µm).
    let over = (b.surface - b.done[0] as f64) / b.per_mm * 1000.0;
    assert!(over > 0.0 && over < 40.0, "{over} µm past the surface");
    assert!(b.ctrl.status().probe_input);
    assert_eq!(b.ctrl.status().probes, 1);
    let sent = super::tests::replies(&mut b.ctrl);
    assert!(sent.contains(&crate::wire::CtrlMsg::Probe(r)), "{sent:?}");
}

#[test]
fn a_probing_move_without_contact_ends_at_its_end_and_says_so() {
    let mut b = Bench::new(-30.0);
    b.probe(-10, ProbeMode::Touch);
    let r = b.run();
    assert!(!r.contact);
    assert_eq!(r.at[2] >> LATCH_FRAC_BITS, b.done[0]);
    assert_eq!(b.ctrl.pose()[2], -10_000_000);
}

#[test]
fn a_probe_touching_at_the_start_raises_an_alarm_and_nothing_moves() {
    let mut b = Bench::new(1.0);
    for _ in 0..3 {
        b.tick();
    }
    b.probe(-10, ProbeMode::Touch);
    b.tick();
    assert_eq!(b.ctrl.state(), State::Alarm);
    assert_eq!(
        b.ctrl.status().alarm.map(|a| a.cause),
        Some(AlarmCause::ProbeAtStart)
    );
    assert_eq!(b.ctrl.pose()[2], 0);
    assert_eq!(b.ctrl.probe_result(), None);
    assert_eq!(b.ctrl.status().probes, 0);
}

#[test]
fn a_release_move_latches_where_contact_is_lost_and_needs_contact_at_the_start() {
    // Touching above the surface here: the probe leaves it going up.
    let mut b = Bench::new(2.0);
    for _ in 0..3 {
        b.tick();
    }
    b.probe(10, ProbeMode::Release);
    let r = b.run();
    assert!(r.contact, "contact lost");
    assert!((Bench::steps(r.at[2]) - b.surface).abs() < 0.02);
    assert!(!b.ctrl.status().probe_input);
    // Not touching now: another release move is refused.
    b.probe(10, ProbeMode::Release);
    b.tick();
    assert_eq!(
        b.ctrl.status().alarm.map(|a| a.cause),
        Some(AlarmCause::ProbeAtStart)
    );
}
