//! The simulator as `--sim` runs it: set up from the machine file, served on a
//! pseudo-terminal in a thread (optionally through a faulty line), and its outcome.

use super::{exit, Failure};
use crate::analysis::plot::Recorder;
use crate::link::SimClock;
use crate::sim::faults::{FaultConfig, FaultReport, FaultyLine};
use crate::sim::serve::{serve, ServeClock};
use crate::sim::{Simulator, Violation};
use pkmc::config::{MachineConfig, MAX_JOINTS};
use pkmc::units::TICK_NS;
use serde::Serialize;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;

/// What the simulator side reports after a job.
#[derive(Clone, Debug, Serialize)]
pub struct SimOutcome {
    /// Drive positions per joint, steps or counts.
    pub joint_steps: Vec<i64>,
    /// Timing breaches counted.
    pub violation_count: u64,
    /// First breaches in full.
    pub violations: Vec<Violation>,
    /// Ticks simulated.
    pub ticks: u64,
    /// Frames the controller found corrupt.
    pub corrupt_frames: u32,
    /// What the faulty line did, when faults were injected.
    pub faults: Option<FaultReport>,
    /// Simulated time when the controller first entered `Alarm` or `EStop` (not the
    /// lock after reset), s.
    pub alarm_time_s: Option<f64>,
    /// NC lines executed and the tool path.
    #[serde(skip)]
    pub recorder: Recorder,
}

pub(super) fn outcome_of(
    sim: &Simulator,
    faults: Option<FaultReport>,
    recorder: Recorder,
) -> SimOutcome {
    let n = sim.ctrl.machine().joints.len();
    let (violation_count, violations) = sim.violations();
    SimOutcome {
        joint_steps: (0..n).map(|j| sim.feedback_steps(j).unwrap_or(0)).collect(),
        violation_count,
        violations,
        ticks: sim.ticks,
        corrupt_frames: sim.ctrl.link_stats().corrupt,
        faults,
        alarm_time_s: sim.alarm_tick.map(|t| t as f64 * TICK_NS as f64 * 1e-9),
        recorder,
    }
}

/// How the simulator is set up.
#[derive(Clone, Debug, Default)]
pub struct SimSetup<'a> {
    /// Write a CSV trace row per tick here.
    pub trace: Option<&'a Path>,
    /// Inject faults on the line.
    pub faults: Option<FaultConfig>,
    /// Keep the tool path (for plots).
    pub record_path: bool,
    /// Plant of each joint from the machine file (servo joints; `None`: the default).
    pub plants: Vec<Option<crate::control::plant::PlantFile>>,
    /// Faults to inject ([`crate::sim::Injection`]).
    pub inject: Vec<crate::sim::Injection>,
    /// How the served simulator advances its clock (paced to the wall clock while
    /// the host streams, by default).
    pub clock: ServeClock,
    /// Measure how far merged curves stray from their chords.
    pub deviation: Option<crate::analysis::deviation::Meter>,
    /// A touch probe and what it touches ([`crate::sim::probe`]; `None`: its input
    /// stays clear).
    pub probe: Option<crate::sim::probe::ProbeModel>,
    /// The probe sees this true machine ([`crate::sim::probe::Frame`]).
    pub truth: Option<crate::sim::probe::Truth>,
}

impl SimSetup<'_> {
    /// A simulator for `machine` with this set-up's plants and trace (not its faults);
    /// failures to build it exit with `code`.
    pub(super) fn simulator(
        &self,
        machine: MachineConfig,
        code: i32,
    ) -> Result<Simulator, Failure> {
        let mut sim = Simulator::with_plants(machine, self.plants.clone(), [0; MAX_JOINTS])
            .map_err(|e| Failure::new(code, format!("simulator: {e:#}")))?;
        sim.set_probe(self.probe.clone(), self.truth.as_ref())
            .map_err(|e| Failure::new(exit::BAD_INPUT, e))?;
        if let Some(p) = self.trace {
            let f = std::fs::File::create(p).map_err(|e| {
                Failure::new(
                    exit::BAD_INPUT,
                    format!("{}: cannot create: {e}", p.display()),
                )
            })?;
            sim.trace_to(Box::new(std::io::BufWriter::new(f)))
                .map_err(|e| Failure::new(code, format!("{}: {e:#}", p.display())))?;
        }
        Ok(sim)
    }
}

/// A simulator serving on a pseudo-terminal in a thread.
pub struct SimServer {
    /// Path of the port a client opens.
    pub port_path: String,
    /// The simulator's clock, for the client's stall guard.
    pub clock: SimClock,
    stop: Arc<AtomicBool>,
    handle: JoinHandle<Result<SimOutcome, String>>,
    _client_end: serialport::TTYPort,
}

impl SimServer {
    /// Starts a simulator for `machine` as `setup` says.
    pub fn start(machine: MachineConfig, setup: &SimSetup<'_>) -> Result<Self, Failure> {
        let fail = |m: String| Failure::new(exit::LINK, m);
        let mut sim = setup.simulator(machine, exit::LINK)?;
        sim.inject(&setup.inject)
            .map_err(|e| Failure::new(exit::BAD_INPUT, format!("{e:#}")))?;
        let (mut master, slave) = serialport::TTYPort::pair()
            .map_err(|e| fail(format!("cannot create a pseudo-terminal: {e}")))?;
        let port_path = serialport::SerialPort::name(&slave)
            .ok_or_else(|| fail("the pseudo-terminal has no name".into()))?;
        let stop = Arc::new(AtomicBool::new(false));
        let stop2 = stop.clone();
        let faults = setup.faults;
        let serve_clock = setup.clock;
        let joints = sim.ctrl.machine().joints.len();
        let mut recorder = Recorder::new(joints, setup.record_path);
        recorder.deviation = setup.deviation.clone();
        let clock = SimClock::default();
        let ticks = clock.clone();
        let handle = std::thread::spawn(move || -> Result<SimOutcome, String> {
            let mut line = faults.map(FaultyLine::new);
            let mut on_tick = |s: &Simulator| {
                recorder.record(s);
                ticks.set(s.ticks);
            };
            serve(
                &mut sim,
                &mut master,
                &stop2,
                line.as_mut(),
                serve_clock,
                &mut on_tick,
            )
            .map_err(|e| e.to_string())?;
            let report = match (&line, &faults) {
                (Some(l), Some(c)) => Some(l.report(c)),
                _ => None,
            };
            Ok(outcome_of(&sim, report, recorder))
        });
        Ok(Self {
            port_path,
            clock,
            stop,
            handle,
            _client_end: slave,
        })
    }

    /// Stops the simulator and returns its outcome.
    pub fn finish(self) -> Result<SimOutcome, Failure> {
        self.stop.store(true, Ordering::Relaxed);
        self.handle
            .join()
            .map_err(|_| Failure::new(exit::LINK, "the simulator thread panicked"))?
            .map_err(|e| Failure::new(exit::LINK, format!("simulator: {e}")))
    }
}
