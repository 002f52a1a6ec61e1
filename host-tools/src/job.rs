//! Running a job end to end: compile the program, check it against the machine, start
//! the simulator behind a pseudo-terminal when asked, stream over the serial port,
//! wait for the end, and summarise. Shared by `nc-send` and the tests.

use crate::gcode;
use crate::link::{serve, ClientStats, JobEnd, Link};
use crate::sim::{Simulator, Violation};
use anyhow::{anyhow, Context, Result};
use pkmc::config::{axis_is_rotary, MachineConfig, AXIS_NAMES};
use pkmc::kinematics::MachineKinematics;
use pkmc::protocol::{Block, State, Status};
use pkmc::units::{to_user, TICK_NS};
use serde::Serialize;
use serialport::SerialPort;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;

/// Exit codes of `nc-send`.
pub mod exit {
    /// Every block executed.
    pub const OK: i32 = 0;
    /// Bad program, machine file or arguments.
    pub const BAD_INPUT: i32 = 2;
    /// The program leaves the machine's reach (pre-flight failure).
    pub const PREFLIGHT: i32 = 3;
    /// The link failed or no controller answered.
    pub const LINK: i32 = 4;
    /// The controller raised an alarm.
    pub const ALARM: i32 = 5;
}

/// An error with the exit code it maps to.
#[derive(Debug)]
pub struct Failure {
    /// Exit code, from [`exit`].
    pub code: i32,
    /// What to tell the user.
    pub message: String,
}

impl Failure {
    fn new(code: i32, message: impl Into<String>) -> Self {
        Self {
            code,
            message: message.into(),
        }
    }
}

/// Reads and compiles a program for `machine`; checks every block end against the
/// machine's reach.
pub fn compile_program(path: &Path, machine: &MachineConfig) -> Result<Vec<Block>, Failure> {
    let bytes = std::fs::read(path).map_err(|e| {
        Failure::new(
            exit::BAD_INPUT,
            format!("{}: cannot read: {e}", path.display()),
        )
    })?;
    let name = path.display().to_string();
    let text = String::from_utf8(bytes).map_err(|e| {
        let at = e.utf8_error().valid_up_to();
        let before = &e.as_bytes()[..at];
        let line = before.iter().filter(|&&b| b == b'\n').count() + 1;
        let col = at
            - before
                .iter()
                .rposition(|&b| b == b'\n')
                .map_or(0, |p| p + 1)
            + 1;
        Failure::new(
            exit::BAD_INPUT,
            format!("{name}:{line}:{col}: not text (invalid UTF-8)"),
        )
    })?;
    let blocks = gcode::compile(&text, &name, machine.home).map_err(|errs| {
        let lines: Vec<String> = errs.iter().map(|d| d.to_string()).collect();
        Failure::new(
            exit::BAD_INPUT,
            format!(
                "{}\n{} error(s); nothing was sent",
                lines.join("\n"),
                errs.len()
            ),
        )
    })?;
    let kin = MachineKinematics::new(machine);
    let mut q = [0; pkmc::config::MAX_JOINTS];
    for b in &blocks {
        if let Err(e) = kin.inverse_checked(&b.target, &machine.joints, &mut q) {
            return Err(Failure::new(
                exit::PREFLIGHT,
                format!(
                    "{name}:{}: target out of the machine's reach ({e:?}); nothing was sent",
                    b.line
                ),
            ));
        }
    }
    Ok(blocks)
}

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
}

/// A simulator serving on a pseudo-terminal in a thread.
pub struct SimServer {
    /// Path of the port a client opens.
    pub port_path: String,
    stop: Arc<AtomicBool>,
    handle: JoinHandle<Result<SimOutcome>>,
    _client_end: serialport::TTYPort,
}

impl SimServer {
    /// Starts a simulator for `machine`, tracing to `trace` if given.
    pub fn start(machine: MachineConfig, trace: Option<&Path>) -> Result<Self> {
        let mut sim = Simulator::new(machine)?;
        if let Some(p) = trace {
            let f = std::fs::File::create(p)
                .with_context(|| format!("{}: cannot create", p.display()))?;
            sim.trace_to(Box::new(std::io::BufWriter::new(f)))?;
        }
        let (mut master, slave) =
            serialport::TTYPort::pair().context("cannot create a pseudo-terminal")?;
        let port_path = slave
            .name()
            .ok_or_else(|| anyhow!("the pseudo-terminal has no name"))?;
        let stop = Arc::new(AtomicBool::new(false));
        let stop2 = stop.clone();
        let handle = std::thread::spawn(move || -> Result<SimOutcome> {
            serve(&mut sim, &mut master, &stop2)?;
            let n = sim.ctrl.machine().joints.len();
            let (violation_count, violations) = sim.violations();
            Ok(SimOutcome {
                joint_steps: (0..n).map(|j| sim.feedback_steps(j).unwrap_or(0)).collect(),
                violation_count,
                violations,
                ticks: sim.ticks,
                corrupt_frames: sim.ctrl.link_stats().corrupt,
            })
        });
        Ok(Self {
            port_path,
            stop,
            handle,
            _client_end: slave,
        })
    }

    /// Stops the simulator and returns its outcome.
    pub fn finish(self) -> Result<SimOutcome> {
        self.stop.store(true, Ordering::Relaxed);
        self.handle
            .join()
            .map_err(|_| anyhow!("the simulator thread panicked"))?
    }
}

/// Opens a serial port by path, as for a board.
pub fn open_port(path: &str) -> Result<Box<dyn serialport::SerialPort>> {
    let port = serialport::new(path, 115_200)
        .timeout(std::time::Duration::from_millis(10))
        .open()
        .with_context(|| format!("{path}: cannot open"))?;
    Ok(port)
}

/// The machine-readable summary of a job.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    /// Machine name.
    pub machine: String,
    /// Program file.
    pub program: String,
    /// "done" or "alarm".
    pub result: String,
    /// Controller state at the end.
    pub final_state: String,
    /// Final commanded pose: X Y Z in mm, A B C in degrees.
    pub final_pose: std::collections::BTreeMap<String, f64>,
    /// Final commanded joints, mm or degrees.
    pub final_joints: Vec<f64>,
    /// Final drive positions (simulator only), steps or counts.
    pub final_joint_steps: Option<Vec<i64>>,
    /// Blocks sent.
    pub blocks_sent: usize,
    /// Blocks the controller executed.
    pub blocks_executed: u32,
    /// Motion time on the controller, s.
    pub run_time_s: f64,
    /// Alarms, described.
    pub alarms: Vec<String>,
    /// Drive timing breaches (simulator only).
    pub drive_violations: Option<u64>,
    /// Link counters.
    pub link: ClientStats,
}

impl Report {
    /// Builds the report from the final status.
    pub fn new(
        machine: &MachineConfig,
        program: &Path,
        blocks: usize,
        end: &JobEnd,
        status: &Status,
        sim: Option<&SimOutcome>,
        link: ClientStats,
    ) -> Self {
        let final_pose = (0..6)
            .map(|i| {
                (
                    AXIS_NAMES[i].to_ascii_lowercase().to_string(),
                    to_user(status.pose[i], axis_is_rotary(i)),
                )
            })
            .collect();
        let final_joints = machine
            .joints
            .iter()
            .enumerate()
            .map(|(j, jc)| to_user(status.joints[j], jc.rotary))
            .collect();
        Report {
            machine: machine.name.to_string(),
            program: program.display().to_string(),
            result: match end {
                JobEnd::Done => "done".into(),
                JobEnd::Alarm => "alarm".into(),
            },
            final_state: format!("{:?}", status.state),
            final_pose,
            final_joints,
            final_joint_steps: sim.map(|s| s.joint_steps.clone()),
            blocks_sent: blocks,
            blocks_executed: status.blocks_done,
            run_time_s: status.motion_ticks as f64 * TICK_NS as f64 * 1e-9,
            alarms: status.alarm.iter().map(|a| format!("{a:?}")).collect(),
            drive_violations: sim.map(|s| s.violation_count),
            link,
        }
    }
}

/// Where to run a job.
pub enum Target<'a> {
    /// The built-in simulator on a pseudo-terminal.
    Sim,
    /// A controller on this serial port.
    Port(&'a str),
}

/// Runs `program` on `target`; returns the report and the exit code it implies.
pub fn run(
    machine: &MachineConfig,
    program: &Path,
    target: Target<'_>,
    trace: Option<&Path>,
    mut progress: impl FnMut(&Status),
) -> Result<(Report, i32), Failure> {
    let blocks = compile_program(program, machine)?;
    let link_err = |e: anyhow::Error| Failure::new(exit::LINK, format!("{e:#}"));
    let server = match target {
        Target::Sim => Some(SimServer::start(machine.clone(), trace).map_err(link_err)?),
        Target::Port(_) if trace.is_some() => {
            return Err(Failure::new(
                exit::BAD_INPUT,
                "--trace needs --sim (a board does not stream every period)",
            ))
        }
        Target::Port(_) => None,
    };
    let path = match (&server, target) {
        (Some(s), _) => s.port_path.clone(),
        (None, Target::Port(p)) => p.to_string(),
        (None, Target::Sim) => unreachable!("the simulator was started above"),
    };
    let outcome = (|| -> Result<(JobEnd, Status, ClientStats)> {
        let mut link = Link::connect(open_port(&path)?, machine)?;
        let end = link.run_job(&blocks, &mut progress)?;
        let status = link.request_status()?;
        Ok((end, status, link.stats))
    })();
    let sim = match server {
        Some(s) => Some(s.finish().map_err(link_err)?),
        None => None,
    };
    let (end, status, stats) = outcome.map_err(link_err)?;
    let report = Report::new(
        machine,
        program,
        blocks.len(),
        &end,
        &status,
        sim.as_ref(),
        stats,
    );
    let code = match end {
        JobEnd::Alarm => exit::ALARM,
        JobEnd::Done if sim.as_ref().is_some_and(|s| s.violation_count > 0) => exit::ALARM,
        JobEnd::Done if status.state != State::Idle => exit::ALARM,
        JobEnd::Done => exit::OK,
    };
    Ok((report, code))
}
