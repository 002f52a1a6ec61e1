//! Running a job end to end: compile the program, check it against the machine, start
//! the simulator behind a pseudo-terminal when asked (optionally through a faulty
//! line, [`crate::sim::faults`]), stream over the serial port, wait for the end, and
//! summarise in a [`Report`]. Also the dry run of `--check` ([`check`]: the same
//! client against the controller in this process, on the simulated clock) and the
//! single commands (`status`, `home`, `jog`, `mdi`, `reset`). Shared by `nc-send` and
//! the tests.
//!
//! Every error is a [`Failure`] carrying its exit code ([`exit`]) and a message that
//! names where it happened (file and line, or port).

use crate::analysis::plot::{lines_digest, Recorder};
use crate::gcode;
use crate::link::{
    ClientStats, JobEnd, JobHooks, Link, LinkError, LinkOptions, PortTransport, SimClock, Transport,
};
use crate::sim::faults::{FaultConfig, FaultReport, FaultyLine};
use crate::sim::serve::{serve, InProcess, ServeClock};
use crate::sim::{Simulator, Violation};
use pkmc::config::{axis_is_rotary, MachineConfig, AXES, AXIS_NAMES, MAX_JOINTS};
use pkmc::kinematics::MachineKinematics;
use pkmc::protocol::{Alarm, Block, Control, Motion, State, Status};
use pkmc::units::{to_user, TICK_NS};
use serde::Serialize;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;

/// Exit codes of `nc-send`.
pub mod exit {
    /// Every block executed (or the command succeeded).
    pub const OK: i32 = 0;
    /// Bad program, machine file or arguments; nothing was sent.
    pub const BAD_INPUT: i32 = 2;
    /// Pre-flight failure: the program leaves the machine's reach, or no controller was
    /// found to send it to; nothing was sent.
    pub const PREFLIGHT: i32 = 3;
    /// No controller found (USB discovery): same code as [`PREFLIGHT`].
    pub const NO_CONTROLLER: i32 = PREFLIGHT;
    /// The link failed: the port could not be opened, nothing answered, or the
    /// controller stopped answering.
    pub const LINK: i32 = 4;
    /// The controller raised an alarm (or, in the simulator, a drive timing breach).
    pub const ALARM: i32 = 5;
    /// The operator stopped the job (Ctrl-C or the `q` key).
    pub const STOPPED: i32 = 6;
    /// A simulated run stalled: the controller said it was moving but made no progress
    /// ([`crate::link::STALL_TICKS`] of simulated time). Same code as [`ALARM`]: like
    /// an alarm (or a drive timing breach), the machine failed to execute the program,
    /// while the link itself was fine (not [`LINK`]); the message names the NC line.
    pub const STALLED: i32 = ALARM;
    /// The controller holds an unfinished job of a host that has gone (a crash, a
    /// closed terminal): nothing was sent; `nc-send resume` continues that job,
    /// `nc-send abort` drops it.
    pub const HELD: i32 = 7;
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
    /// A failure with `code` and `message`.
    pub fn new(code: i32, message: impl Into<String>) -> Self {
        Self {
            code,
            message: message.into(),
        }
    }
}

impl From<LinkError> for Failure {
    fn from(e: LinkError) -> Self {
        let code = match e {
            LinkError::BadBlock { .. } => exit::BAD_INPUT,
            LinkError::MachineMismatch { .. } | LinkError::MachineRefused { .. } => exit::PREFLIGHT,
            LinkError::Stalled { .. } => exit::STALLED,
            LinkError::JobHeld { .. } => exit::HELD,
            _ => exit::LINK,
        };
        Failure::new(code, e.to_string())
    }
}

/// Reads and compiles a program for `machine`; checks every block end against the
/// machine's reach.
pub fn compile_program(path: &Path, machine: &MachineConfig) -> Result<Vec<Block>, Failure> {
    let text = crate::input::read_text(path, crate::input::MAX_PROGRAM_BYTES)
        .map_err(|m| Failure::new(exit::BAD_INPUT, m))?;
    let name = path.display().to_string();
    compile_text(&text, &name, machine, machine.home)
}

/// Compiles program text named `name` for `machine`, starting from pose `start`;
/// refuses axis words for axes the machine lacks ([`machine_axes`]) and checks every
/// block end against the machine's reach. The one place where G-code becomes blocks
/// (files through [`compile_program`], MDI lines directly).
pub fn compile_text(
    text: &str,
    name: &str,
    machine: &MachineConfig,
    start: [i64; AXES],
) -> Result<Vec<Block>, Failure> {
    let options = gcode::Options {
        start,
        axes: machine_axes(machine),
        ..gcode::Options::default()
    };
    let canon = gcode::compile_canon(text, name, &options).map_err(|errs| {
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
    let program = crate::gcode::blocks::from_canon(&canon, start);
    let report = crate::analysis::preflight::check(&program.blocks, machine, start);
    if !report.findings.is_empty() {
        let lines = findings_text(name, &report.findings);
        return Err(Failure::new(
            exit::PREFLIGHT,
            format!(
                "{}\n{} pre-flight problem(s); nothing was sent",
                lines.join("\n"),
                report.findings.len()
            ),
        ));
    }
    Ok(program.blocks)
}

/// The pre-flight findings as lines of text: a run of the same problem on consecutive
/// NC lines (a stretch of a program out of travel, thousands of lines of CAM output)
/// is one line naming its first and last line and how many, at its first pose.
fn findings_text(name: &str, findings: &[crate::analysis::preflight::Finding]) -> Vec<String> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < findings.len() {
        let f = &findings[i];
        let mut j = i + 1;
        while j < findings.len()
            && findings[j].what == f.what
            && findings[j].line <= findings[j - 1].line + 1
        {
            j += 1;
        }
        let at = format!(
            "X{} Y{} Z{} A{} B{} C{}",
            f.at[0], f.at[1], f.at[2], f.at[3], f.at[4], f.at[5]
        );
        let last = &findings[j - 1];
        out.push(if j - i == 1 {
            format!("{name}:{}: {} (at {at})", f.line, f.what)
        } else {
            format!(
                "{name}:{}: {} (at {at}), and on every line to {name}:{} ({} lines)",
                f.line,
                f.what,
                last.line,
                j - i
            )
        });
        i = j;
    }
    out
}

/// The axes `machine` has: those with limits in its `[axes]`. Any other axis has no
/// speed to move at, so a program naming one is refused before anything runs.
pub fn machine_axes(machine: &MachineConfig) -> [bool; AXES] {
    std::array::from_fn(|i| machine.axes[i].max_velocity > 0)
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
    /// What the faulty line did, when faults were injected.
    pub faults: Option<FaultReport>,
    /// Simulated time when the controller first entered `Alarm` or `EStop` (not the
    /// lock after reset), s.
    pub alarm_time_s: Option<f64>,
    /// NC lines executed and the tool path.
    #[serde(skip)]
    pub recorder: Recorder,
}

fn outcome_of(sim: &Simulator, faults: Option<FaultReport>, recorder: Recorder) -> SimOutcome {
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
    pub plants: Vec<Option<crate::sim::plant::PlantFile>>,
    /// Faults to inject ([`crate::sim::Injection`]).
    pub inject: Vec<crate::sim::Injection>,
    /// How the served simulator advances its clock (paced to the wall clock while
    /// the host streams, by default).
    pub clock: ServeClock,
}

impl SimSetup<'_> {
    /// A simulator for `machine` with this set-up's plants and trace (not its faults);
    /// failures to build it exit with `code`.
    fn simulator(&self, machine: MachineConfig, code: i32) -> Result<Simulator, Failure> {
        let mut sim = Simulator::with_plants(machine, self.plants.clone(), [0; MAX_JOINTS])
            .map_err(|e| Failure::new(code, format!("simulator: {e:#}")))?;
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

/// The NC lines a simulated job executed.
#[derive(Clone, Debug, Serialize, PartialEq, Eq)]
pub struct LinesExecuted {
    /// Distinct lines in execution order (consecutive repeats merged).
    pub count: usize,
    /// FNV-1a digest of that sequence ([`lines_digest`]).
    pub digest: String,
}

/// The machine-readable summary of a job.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    /// Machine name.
    pub machine: String,
    /// Program file (or the MDI line).
    pub program: String,
    /// "done", "alarm", "aborted" or "stopped".
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
    /// Motion time on the controller, s (for `--check`, the planned run time).
    pub run_time_s: f64,
    /// Alarms, described.
    pub alarms: Vec<String>,
    /// NC line of the alarm, if any.
    pub alarm_line: Option<u32>,
    /// Cause of the alarm, if any (`EStop`, `LimitSwitch`, `DriveFault`, …).
    pub alarm_cause: Option<String>,
    /// Joint the alarm names, 1-based, if any.
    pub alarm_joint: Option<u8>,
    /// Simulated time the alarm was raised, s (simulator only).
    pub alarm_time_s: Option<f64>,
    /// Drive timing breaches (simulator only).
    pub drive_violations: Option<u64>,
    /// Link counters of the client.
    pub link: ClientStats,
    /// Frames the (simulated) controller found corrupt.
    pub controller_corrupt_frames: Option<u32>,
    /// Injected faults and what became of them (`--link-faults`).
    pub faults: Option<FaultReport>,
    /// NC lines executed (simulator only).
    pub lines_executed: Option<LinesExecuted>,
    /// Pre-flight (`--check`): poses sampled along the path and the smallest
    /// singularity margin met, with its NC line (see [`crate::analysis::preflight`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub preflight: Option<PreflightSummary>,
}

/// What `--check` reports of the pre-flight.
#[derive(Clone, Debug, Serialize)]
pub struct PreflightSummary {
    /// Poses checked through the kinematics.
    pub samples: usize,
    /// Smallest singularity margin met (1 for a Cartesian machine, 0 at a singularity).
    pub min_singularity_margin: Option<f64>,
    /// NC line where it was met.
    pub min_margin_line: Option<u32>,
}

impl Report {
    /// Builds the report from the final status.
    pub fn new(
        machine: &MachineConfig,
        program: &str,
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
        let alarm = match end {
            JobEnd::Alarm(a) => Some(*a),
            _ => status.alarm,
        };
        Report {
            machine: machine.name.to_string(),
            program: program.to_string(),
            result: match end {
                JobEnd::Done => "done",
                JobEnd::Alarm(_) => "alarm",
                JobEnd::Aborted => "aborted",
                JobEnd::Stopped => "stopped",
                JobEnd::Paused(_) => "paused",
            }
            .into(),
            final_state: format!("{:?}", status.state),
            final_pose,
            final_joints,
            final_joint_steps: sim.map(|s| s.joint_steps.clone()),
            blocks_sent: blocks,
            blocks_executed: status.blocks_done,
            run_time_s: status.motion_ticks as f64 * TICK_NS as f64 * 1e-9,
            alarms: alarm.iter().map(describe_alarm).collect(),
            alarm_line: alarm.map(|a| a.line),
            alarm_cause: alarm.map(|a| format!("{:?}", a.cause)),
            alarm_joint: alarm
                .filter(|a| a.joint != pkmc::protocol::NO_JOINT)
                .map(|a| a.joint + 1),
            alarm_time_s: sim.and_then(|s| s.alarm_time_s),
            drive_violations: sim.map(|s| s.violation_count),
            link,
            controller_corrupt_frames: sim.map(|s| s.corrupt_frames),
            faults: sim.and_then(|s| s.faults),
            lines_executed: sim.map(|s| LinesExecuted {
                count: s.recorder.lines.len(),
                digest: lines_digest(&s.recorder.lines),
            }),
            preflight: None,
        }
    }

    /// The exit code this outcome implies.
    pub fn exit_code(&self) -> i32 {
        match self.result.as_str() {
            "alarm" => exit::ALARM,
            "aborted" | "stopped" => exit::STOPPED,
            "paused" => exit::HELD,
            _ if self.drive_violations.unwrap_or(0) > 0 => exit::ALARM,
            _ if self.final_state != "Idle" => exit::ALARM,
            _ => exit::OK,
        }
    }
}

/// An alarm in words: cause, joint and NC line.
pub fn describe_alarm(a: &Alarm) -> String {
    let mut s = format!("{:?}", a.cause);
    if a.joint != pkmc::protocol::NO_JOINT {
        s += &format!(" on joint {}", a.joint as usize + 1);
    }
    if a.line != 0 {
        s += &format!(" at line {}", a.line);
    }
    s
}

/// Where to run a job.
#[derive(Clone, Copy, Debug)]
pub enum Target<'a> {
    /// The built-in simulator on a pseudo-terminal.
    Sim,
    /// A controller on this serial port.
    Port(&'a str),
}

/// How to run a job.
#[derive(Clone, Debug)]
pub struct RunOptions<'a> {
    /// Where.
    pub target: Target<'a>,
    /// Simulator set-up (ignored for a port, where a trace or faults are refused).
    pub sim: SimSetup<'a>,
    /// Client tunables.
    pub link: LinkOptions,
    /// Home the machine before the job.
    pub home: bool,
}

/// What a run produced besides the report: the simulator's outcome, for plots.
pub struct RunResult {
    /// The summary.
    pub report: Report,
    /// The simulator's side, when simulated.
    pub sim: Option<SimOutcome>,
}

/// Starts the simulator when the target asks for it; returns it and the port to open.
fn open_target(
    machine: &MachineConfig,
    opts: &RunOptions<'_>,
) -> Result<(Option<SimServer>, String), Failure> {
    match opts.target {
        Target::Sim => {
            let s = SimServer::start(machine.clone(), &opts.sim)?;
            let path = s.port_path.clone();
            Ok((Some(s), path))
        }
        Target::Port(p) => {
            if opts.sim.trace.is_some() {
                return Err(Failure::new(
                    exit::BAD_INPUT,
                    "--trace needs --sim (a board does not stream every period)",
                ));
            }
            if opts.sim.faults.is_some() {
                return Err(Failure::new(
                    exit::BAD_INPUT,
                    "--link-faults needs --sim (faults are injected in the simulator)",
                ));
            }
            Ok((None, p.to_string()))
        }
    }
}

/// Opens the port at `path`; the port of `server`, when given, with its clock (the
/// stall guard of a simulation).
fn open_port(path: &str, server: Option<&SimServer>) -> Result<PortTransport, Failure> {
    let port = PortTransport::open(path)?;
    Ok(match server {
        Some(s) => port.with_sim_clock(s.clock.clone()),
        None => port,
    })
}

/// Streams `blocks` (named `program`) to the target; returns the report.
pub fn run_blocks(
    machine: &MachineConfig,
    program: &str,
    blocks: &[Block],
    opts: &RunOptions<'_>,
    hooks: &mut dyn JobHooks,
) -> Result<RunResult, Failure> {
    let (server, path) = open_target(machine, opts)?;
    let outcome = (|| -> Result<(JobEnd, Status, ClientStats), Failure> {
        let io = open_port(&path, server.as_ref())?;
        let mut link = Link::connect(io, machine, opts.link)?;
        let sim = matches!(opts.target, Target::Sim);
        if let Some(end) = prepare(&mut link, opts.home, sim, hooks)? {
            let status = link.request_status()?;
            return Ok((end, status, link.stats));
        }
        let end = link.run_job(blocks, hooks)?;
        let status = link.request_status()?;
        Ok((end, status, link.stats))
    })();
    let sim = match server {
        Some(s) => Some(s.finish()?),
        None => None,
    };
    let (end, status, stats) = outcome?;
    let report = Report::new(
        machine,
        program,
        blocks.len(),
        &end,
        &status,
        sim.as_ref(),
        stats,
    );
    Ok(RunResult { report, sim })
}

/// Compiles and runs `program` as `opts` says.
pub fn run(
    machine: &MachineConfig,
    program: &Path,
    opts: &RunOptions<'_>,
    hooks: &mut dyn JobHooks,
) -> Result<RunResult, Failure> {
    let blocks = compile_program(program, machine)?;
    run_blocks(
        machine,
        &program.display().to_string(),
        &blocks,
        opts,
        hooks,
    )
}

/// Dry run: compiles `program`, pre-checks it and runs it through the controller in
/// this process on the simulated clock (no port, nothing moves), tracing to
/// `opts.sim.trace` and keeping the path when `opts.sim.record_path`; homes first with
/// `opts.home`, else unlocks. The report's `run_time_s` is the planned run time; an
/// alarm names its NC line.
pub fn check(
    machine: &MachineConfig,
    program: &Path,
    opts: &RunOptions<'_>,
    hooks: &mut dyn JobHooks,
) -> Result<RunResult, Failure> {
    let setup = &opts.sim;
    let blocks = compile_program(program, machine)?;
    let pre = crate::analysis::preflight::check(&blocks, machine, machine.home);
    let sim = setup.simulator(machine.clone(), exit::BAD_INPUT)?;
    let recorder = std::rc::Rc::new(std::cell::RefCell::new(Recorder::new(
        machine.joints.len(),
        setup.record_path,
    )));
    let rec = recorder.clone();
    let io = InProcess::new(sim, Box::new(move |s| rec.borrow_mut().record(s)));
    let mut link = Link::connect(io, machine, LinkOptions::default())?;
    let end = match prepare(&mut link, opts.home, true, hooks)? {
        Some(end) => end,
        None => link.run_job(&blocks, hooks)?,
    };
    let status = link.request_status()?;
    let stats = link.stats;
    let mut io = link.into_transport();
    // The drives start the last tick's step trains at the next tick edge, as on the
    // board: run it, so the report's drive positions are final.
    while !io.sim.ctrl.has_work() && io.sim.steps_due() {
        io.sim
            .tick()
            .map_err(|e| Failure::new(exit::BAD_INPUT, format!("simulator: {e:#}")))?;
        recorder.borrow_mut().record(&io.sim);
    }
    if let Some(p) = setup.trace {
        io.sim
            .finish_trace()
            .map_err(|e| Failure::new(exit::BAD_INPUT, format!("{}: {e:#}", p.display())))?;
    }
    let recorder = recorder.replace(Recorder::default());
    let outcome = outcome_of(&io.sim, None, recorder);
    let mut report = Report::new(
        machine,
        &program.display().to_string(),
        blocks.len(),
        &end,
        &status,
        Some(&outcome),
        stats,
    );
    report.preflight = Some(PreflightSummary {
        samples: pre.samples,
        min_singularity_margin: pre.min_margin.map(|(m, _)| m),
        min_margin_line: pre.min_margin.map(|(_, l)| l),
    });
    Ok(RunResult {
        report,
        sim: Some(outcome),
    })
}

/// What `home` sends: the homing cycle on a machine with home switches; on one
/// without, the rapid move to its home pose, planned here from where the controller
/// stands (the controller plans nothing itself).
pub fn home_command<T: Transport>(link: &mut Link<T>) -> Result<Control, Failure> {
    let machine = link.machine().clone();
    if machine.joints.iter().any(|j| j.homing.enabled()) {
        return Ok(Control::Home);
    }
    let from = link.request_status()?.pose;
    let block = Block {
        line: 0,
        motion: Motion::Rapid,
        target: machine.home,
        feed: 0,
        tolerance_nm: 0,
    };
    let kin = MachineKinematics::new(&machine);
    let planned = pkmc::planner::plan_move(&block, from, &machine, &kin).map_err(|e| {
        Failure::new(
            exit::PREFLIGHT,
            format!("home: the move home cannot be planned: {e:?}"),
        )
    })?;
    Ok(Control::Jog(planned))
}

/// What `jog` sends: `distance` (axis units) along pose axis `axis` at `feed`
/// (units/s), clipped to the joint travel and planned here from where the controller
/// stands. An axis the machine does not have is refused (exit 2).
pub fn jog_command<T: Transport>(
    link: &mut Link<T>,
    axis: usize,
    distance: i64,
    feed: i64,
) -> Result<Control, Failure> {
    let machine = link.machine().clone();
    if machine.axes[axis].max_velocity <= 0 {
        let have: Vec<String> = (0..AXES)
            .filter(|&i| machine.axes[i].max_velocity > 0)
            .map(|i| AXIS_NAMES[i].to_string())
            .collect();
        return Err(Failure::new(
            exit::BAD_INPUT,
            format!(
                "jog: the machine has no {} axis (its axes: {})",
                AXIS_NAMES[axis],
                have.join(" ")
            ),
        ));
    }
    let from = link.request_status()?.pose;
    let kin = MachineKinematics::new(&machine);
    let planned = pkmc::planner::plan_jog(&machine, &kin, &from, axis, distance, feed)
        .map_err(|e| Failure::new(exit::PREFLIGHT, format!("jog: cannot be planned: {e:?}")))?;
    Ok(Control::Jog(planned))
}

/// Before a job or a move: with `home`, homes the machine and waits until it is
/// there; otherwise a controller locked after a reset (alarm `Unhomed`) is unlocked
/// where it stands on the simulator (`sim`), and is an error naming the fix on a
/// board. Returns how the job ended if homing ended it (an alarm).
pub fn prepare<T: Transport>(
    link: &mut Link<T>,
    home: bool,
    sim: bool,
    hooks: &mut dyn JobHooks,
) -> Result<Option<JobEnd>, Failure> {
    let s = link.request_status()?;
    let locked = s.alarm.map(|a| a.cause) == Some(pkmc::protocol::AlarmCause::Unhomed);
    if home {
        if !locked && s.state != State::Idle {
            return Err(Failure::new(
                exit::ALARM,
                format!(
                    "{}: cannot home: the controller is {:?}{}",
                    link.transport().name(),
                    s.state,
                    s.alarm
                        .map(|a| format!(" ({})", describe_alarm(&a)))
                        .unwrap_or_default()
                ),
            ));
        }
        let cmd = home_command(link)?;
        link.control(cmd)?;
        return match link.wait_idle(hooks)? {
            JobEnd::Done => Ok(None),
            end => Ok(Some(end)),
        };
    }
    if locked {
        if !sim {
            return Err(Failure::new(
                exit::ALARM,
                format!(
                    "{}: the controller is locked after a reset (it does not know where the \
                     machine is): home it (--home, or `nc-send home`) or unlock it where it \
                     stands (`nc-send reset`)",
                    link.transport().name()
                ),
            ));
        }
        link.control(Control::AlarmReset)?;
    }
    Ok(None)
}

/// A single command (`status`, `home`, `jog`, `reset`) on a live link.
pub fn connect(
    machine: &MachineConfig,
    path: &str,
    opts: LinkOptions,
) -> Result<Link<PortTransport>, Failure> {
    Ok(Link::connect(PortTransport::open(path)?, machine, opts)?)
}

/// Runs `f` on a link to `target` (starting the simulator if asked), then stops the
/// simulator.
pub fn with_link<R>(
    machine: &MachineConfig,
    opts: &RunOptions<'_>,
    f: impl FnOnce(&mut Link<PortTransport>) -> Result<R, Failure>,
) -> Result<R, Failure> {
    let (server, path) = open_target(machine, opts)?;
    let result = open_port(&path, server.as_ref())
        .and_then(|io| Ok(Link::connect(io, machine, opts.link)?))
        .and_then(|mut link| f(&mut link));
    if let Some(s) = server {
        s.finish()?;
    }
    result
}

/// Compiles one MDI line from the controller's current pose and runs it on `link`.
pub fn mdi<T: Transport>(
    link: &mut Link<T>,
    machine: &MachineConfig,
    line: &str,
    hooks: &mut dyn JobHooks,
) -> Result<(Vec<Block>, JobEnd), Failure> {
    let status = link.request_status()?;
    let blocks = compile_text(line, "MDI", machine, status.pose)?;
    let end = link.run_job(&blocks, hooks)?;
    Ok((blocks, end))
}

/// Sends `cmd` (home or jog) and waits until the motion it starts is over.
pub fn move_and_wait<T: Transport>(
    link: &mut Link<T>,
    cmd: Control,
    hooks: &mut dyn JobHooks,
) -> Result<JobEnd, Failure> {
    link.refuse_if_held()?;
    let before = link.request_status()?;
    let locked = before.alarm.map(|a| a.cause) == Some(pkmc::protocol::AlarmCause::Unhomed);
    if before.state != State::Idle && !(cmd == Control::Home && locked) {
        return Err(Failure::new(
            exit::ALARM,
            format!(
                "{}: the controller is {:?}{}; it moves only when idle",
                link.transport().name(),
                before.state,
                before
                    .alarm
                    .map(|a| format!(" ({})", describe_alarm(&a)))
                    .unwrap_or_default()
            ),
        ));
    }
    link.control(cmd)?;
    let end = link.wait_idle(hooks)?;
    if let (JobEnd::Done, Control::Jog(planned)) = (&end, cmd) {
        // The controller acts on a planned move only if it starts where it stands:
        // a refusal leaves it where it was, which must not pass for success.
        let after = link.request_status()?;
        if after.pose != planned.block.target {
            return Err(Failure::new(
                exit::ALARM,
                format!(
                    "{}: the controller did not make the move (it refuses a move that does \
                     not start where it stands, or comes while it is busy)",
                    link.transport().name()
                ),
            ));
        }
    }
    Ok(end)
}
