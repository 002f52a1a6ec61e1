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
//!
//! Rooms: [`compile`] (G-code to blocks for a machine), [`pipeline`] (canonical
//! commands to checked blocks, a whole program or a line at a time), [`sim_server`]
//! (the simulator `--sim` serves), [`report`] (the summary and exit code),
//! [`commands`] (single commands, homing or unlocking before a job); this module runs
//! jobs.

use crate::analysis::plot::Recorder;
use crate::link::{ClientStats, JobEnd, JobHooks, Link, LinkError, LinkOptions, PortTransport};
use crate::sim::serve::InProcess;
use pkmc::config::MachineConfig;
use pkmc::motion::block::Block;
use pkmc::wire::Status;
use std::path::Path;

mod commands;
mod compile;
pub mod from_line;
pub mod pieces;
mod pipeline;
pub mod probing;
mod replug;
mod report;
mod resume;
mod sim_server;
pub mod streamed;

pub use commands::{
    connect, home_command, jog_command, jog_request, mdi, move_and_wait, prepare, state_text,
    with_link, JogRequest,
};
pub use compile::{
    compile_compressed, compile_for, compile_job, compile_located, compile_program, compile_text,
    compile_text_with, for_machine as compress_for_machine, load_tools, machine_axes, Compiled,
};
pub use pipeline::{
    checked, checked_with, front_end_options, Checked, LineBlocks, LineFault, LinePipeline,
};
pub use report::{
    pose_text, print_report, status_json, CompressionSummary, LinesExecuted, PreflightSummary,
    Report,
};
pub use resume::{missing_text, program_lines, program_mark, resume, Resumed};
use sim_server::outcome_of;
pub use sim_server::{SimOutcome, SimServer, SimSetup};

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

/// Does `b` move the machine (not a dwell or an auxiliary function)?
pub(crate) fn moves(b: &Block) -> bool {
    !matches!(
        b.motion,
        pkmc::motion::block::Motion::Dwell(_) | pkmc::motion::block::Motion::Aux(_)
    )
}

/// Where the machine stands after `blocks`, which start at `from`: the last move's
/// target.
pub(crate) fn pose_after(blocks: &[Block], from: [i64; 6]) -> [i64; 6] {
    blocks
        .iter()
        .rev()
        .find(|b| moves(b))
        .map_or(from, |b| b.target)
}

/// Where to run a job.
#[derive(Clone, Copy, Debug)]
pub enum Target<'a> {
    /// The built-in simulator on a pseudo-terminal.
    Sim,
    /// A controller on this serial port.
    Port(&'a str),
    /// The board found on USB at `port`, known by its USB serial number: after a replug
    /// it is looked for by that number (its port may come back under another name).
    Board {
        /// Where it was found.
        port: &'a str,
        /// Its USB serial number.
        serial: &'a str,
    },
}

impl<'a> Target<'a> {
    /// The board `found` on USB: by its serial number when it has one.
    pub fn board(found: &'a crate::link::usb::Found) -> Self {
        match &found.serial {
            Some(serial) => Target::Board {
                port: &found.port,
                serial,
            },
            None => Target::Port(&found.port),
        }
    }
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
    /// The tool table the G-code front end uses (G43, #5400–#5410, G10 L1/L10/L11).
    pub tools: crate::gcode::ToolTable,
    /// A cutting load whose joint forces are checked before anything runs.
    pub statics: Option<StaticsSpec>,
    /// Merge runs of short moves into curves ([`crate::gcode::compress`]); `None`:
    /// stream the program as written.
    pub compress: Option<crate::gcode::compress::Settings>,
}

/// A cutting load and the joints' force limits ([`crate::analysis::statics`]).
#[derive(Clone, Debug, Default)]
pub struct StaticsSpec {
    /// The wrench on the tool, by NC line.
    pub loads: crate::analysis::statics::Loads,
    /// Each joint's force limit (N, N·m), from the machine file.
    pub limits: Vec<Option<f64>>,
}

/// The statics of `compiled`'s blocks under `opts.statics`, if any (as the compile
/// computed it, else here): a joint over its limit, or a machine statics does not
/// cover, refuses the program (nothing runs).
fn statics_gate(
    compiled: &Compiled,
    machine: &MachineConfig,
    program: &str,
    opts: &RunOptions<'_>,
) -> Result<Option<crate::analysis::statics::Statics>, Failure> {
    let Some(spec) = &opts.statics else {
        return Ok(None);
    };
    let s = match &compiled.statics {
        Some(s) => s.clone(),
        None => crate::analysis::statics::check(
            &compiled.blocks,
            machine,
            machine.home,
            &spec.loads,
            &spec.limits,
        ),
    }
    .map_err(|m| Failure::new(exit::BAD_INPUT, format!("{program}: {m}")))?;
    let over: Vec<String> = s
        .over_limit()
        .map(|p| {
            format!(
                "{program}:{}: joint q{} would carry {:.0} N, over its limit of {:.0} N",
                p.line,
                p.joint + 1,
                p.force.abs(),
                p.limit.unwrap_or(0.0)
            )
        })
        .collect();
    let limited = spec.limits.iter().any(Option::is_some);
    let mut over = over;
    if let (Some(line), true) = (s.singular_at, limited) {
        over.push(format!(
            "{program}:{line}: the joints cannot hold the load at a singular pose (the \
             forces are unbounded)"
        ));
    }
    if !over.is_empty() {
        return Err(Failure::new(
            exit::PREFLIGHT,
            format!(
                "{}
{} joint(s) over their force limit; nothing was sent",
                over.join("\n"),
                over.len()
            ),
        ));
    }
    Ok(Some(s))
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
        Target::Port(p) | Target::Board { port: p, .. } => {
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
    run_blocks_at(machine, program, &|_| blocks.into(), None, opts, hooks)
}

/// [`run_blocks`] of the blocks `blocks_at` makes for the pose where the controller
/// stands once connected (a restart's approach starts there: [`from_line`]); `derived`:
/// their paths, derived already (only for blocks that `blocks_at` returns unchanged).
pub fn run_blocks_at<'b>(
    machine: &MachineConfig,
    program: &str,
    blocks_at: &dyn Fn([i64; 6]) -> std::borrow::Cow<'b, [Block]>,
    derived: Option<crate::link::Derived<'_>>,
    opts: &RunOptions<'_>,
    hooks: &mut dyn JobHooks,
) -> Result<RunResult, Failure> {
    let (server, path) = open_target(machine, opts)?;
    let mut count = 0;
    let outcome = (|| -> Result<(JobEnd, Status, ClientStats), Failure> {
        let io = open_port(&path, server.as_ref())?;
        let mut link = Link::connect(io, machine, opts.link)?;
        let sim = matches!(opts.target, Target::Sim);
        if let Some(end) = prepare(&mut link, opts.home, sim, hooks)? {
            let status = link.request_status()?;
            return Ok((end, status, link.stats));
        }
        let pose = link.request_status()?.pose;
        let blocks = blocks_at(pose);
        count = blocks.len();
        let end = match link.run_job_on(&blocks, derived, hooks) {
            // The port went away (a cable pulled): wait for it and go on.
            Err(e) if replug::applies(&e, opts, &path) => {
                let job = replug::Interrupted {
                    blocks: &blocks,
                    pose,
                    stats: link.stats,
                };
                drop(link);
                return replug::rejoin(e, &path, machine, opts, job, hooks);
            }
            r => r?,
        };
        let status = link.request_status()?;
        Ok((end, status, link.stats))
    })();
    let sim = match server {
        Some(s) => Some(s.finish()?),
        None => None,
    };
    let (end, status, stats) = outcome?;
    let report = Report::new(machine, program, count, &end, &status, sim.as_ref(), stats);
    Ok(RunResult { report, sim })
}

/// Compiles and runs `program` as `opts` says.
pub fn run(
    machine: &MachineConfig,
    program: &Path,
    opts: &RunOptions<'_>,
    hooks: &mut dyn JobHooks,
) -> Result<RunResult, Failure> {
    if let Some(r) = run_probing(machine, program, opts, hooks, false)? {
        return Ok(r);
    }
    let compiled = compile_for(program, machine, opts)?;
    let name = program.display().to_string();
    let statics = statics_gate(&compiled, machine, &name, opts)?;
    let mut opts = opts.clone();
    opts.sim.deviation = Some(compiled.deviation_meter());
    let blocks = |_| compiled.blocks.as_slice().into();
    let mut result = run_blocks_at(machine, &name, &blocks, compiled.derived(), &opts, hooks)?;
    result.report.statics = statics;
    result.report.compression = Some(CompressionSummary::of(&compiled, result.sim.as_ref()));
    Ok(result)
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
    if streamed::applies(program, opts) {
        if let Some(r) = streamed::check(machine, program, opts, hooks)? {
            return Ok(r);
        }
    }
    if let Some(r) = run_probing(machine, program, opts, hooks, true)? {
        return Ok(r);
    }
    let compiled = compile_for(program, machine, opts)?;
    check_compiled(
        machine,
        &program.display().to_string(),
        &compiled,
        opts,
        hooks,
    )
}

/// [`check`] of a program already compiled (named `name`).
pub fn check_compiled(
    machine: &MachineConfig,
    name: &str,
    compiled: &Compiled,
    opts: &RunOptions<'_>,
    hooks: &mut dyn JobHooks,
) -> Result<RunResult, Failure> {
    let blocks = &compiled.blocks;
    let statics = statics_gate(compiled, machine, name, opts)?;
    // The compile's pre-flight when it ran from the machine's home, as this does.
    let pre = match &compiled.preflight {
        Some(p) if compiled.start == machine.home => std::borrow::Cow::Borrowed(p),
        _ => {
            let paths = crate::analysis::preflight::paths(blocks, machine.home);
            std::borrow::Cow::Owned(crate::analysis::preflight::check_paths(
                blocks,
                &paths,
                machine,
                machine.home,
                Some(&compiled.chords()),
            ))
        }
    };
    let deviation = Some(compiled.deviation_meter());
    let derived = compiled.derived();
    let (end, status, stats, outcome) =
        run_in_process(machine, blocks, derived, deviation, opts, hooks)?;
    let mut report = Report::new(
        machine,
        name,
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
    report.statics = statics;
    report.compression = Some(CompressionSummary::of(compiled, Some(&outcome)));
    Ok(RunResult {
        report,
        sim: Some(outcome),
    })
}

/// Runs `blocks` (and what `hooks` feed while they run) on the controller core in
/// this process on the simulated clock, as [`check`] does; the recorder measures
/// `deviation` when given.
fn run_in_process(
    machine: &MachineConfig,
    blocks: &[Block],
    derived: Option<crate::link::Derived<'_>>,
    deviation: Option<crate::analysis::deviation::Meter>,
    opts: &RunOptions<'_>,
    hooks: &mut dyn JobHooks,
) -> Result<(JobEnd, Status, ClientStats, SimOutcome), Failure> {
    let mut work = |link: &mut Link<InProcess>, hooks: &mut dyn JobHooks| {
        Ok(link.run_job_on(blocks, derived, hooks)?)
    };
    run_in_process_with(machine, deviation, opts, hooks, &mut work)
}

/// What a run does once connected and prepared: how it ends.
type Work<'w, T> = dyn FnMut(&mut Link<T>, &mut dyn JobHooks) -> Result<JobEnd, Failure> + 'w;

/// [`run_in_process`] of `work`.
fn run_in_process_with(
    machine: &MachineConfig,
    deviation: Option<crate::analysis::deviation::Meter>,
    opts: &RunOptions<'_>,
    hooks: &mut dyn JobHooks,
    work: &mut Work<'_, InProcess>,
) -> Result<(JobEnd, Status, ClientStats, SimOutcome), Failure> {
    let setup = &opts.sim;
    let sim = setup.simulator(machine.clone(), exit::BAD_INPUT)?;
    let recorder = std::rc::Rc::new(std::cell::RefCell::new(Recorder::new(
        machine.joints.len(),
        setup.record_path,
    )));
    recorder.borrow_mut().deviation = deviation;
    let rec = recorder.clone();
    let io = InProcess::new(sim, Box::new(move |s| rec.borrow_mut().record(s)));
    let mut link = Link::connect(io, machine, LinkOptions::default())?;
    let end = match prepare(&mut link, opts.home, true, hooks)? {
        Some(end) => end,
        None => work(&mut link, hooks)?,
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
    Ok((end, status, stats, outcome))
}

/// A program that probes (G38, [`probing`]): run a stage at a time on the target, or
/// in this process (`in_process`: `--check`). `None`: the program does not probe (its
/// text names no G38, or no probing move is ever reached), and runs as any other.
pub fn run_probing(
    machine: &MachineConfig,
    program: &Path,
    opts: &RunOptions<'_>,
    hooks: &mut dyn JobHooks,
    in_process: bool,
) -> Result<Option<RunResult>, Failure> {
    let text = crate::input::read_text(program, crate::input::MAX_PROGRAM_BYTES)
        .map_err(|m| Failure::new(exit::BAD_INPUT, m))?;
    if !probing::names_g38(&text) {
        return Ok(None);
    }
    let name = program.display().to_string();
    let p = probing::ProbingProgram {
        text: &text,
        name: &name,
        machine,
        start: machine.home,
        tools: &opts.tools,
        compress: opts.compress.as_ref(),
    };
    if probing::stage(&p, &[])?.probe.is_none() {
        return Ok(None);
    }
    let mut records = Vec::new();
    let mut sent = 0;
    let (end, status, stats, sim) = if in_process {
        let mut work = |link: &mut Link<InProcess>, hooks: &mut dyn JobHooks| {
            let (end, r, n) = probing::run_on(link, &p, &mut probing::Plain(hooks))?;
            (records, sent) = (r, n);
            Ok(end)
        };
        let (end, status, stats, outcome) =
            run_in_process_with(machine, None, opts, hooks, &mut work)?;
        (end, status, stats, Some(outcome))
    } else {
        let (server, path) = open_target(machine, opts)?;
        let outcome = (|| -> Result<(JobEnd, Status, ClientStats), Failure> {
            let io = open_port(&path, server.as_ref())?;
            let mut link = Link::connect(io, machine, opts.link)?;
            let sim = matches!(opts.target, Target::Sim);
            let end = match prepare(&mut link, opts.home, sim, hooks)? {
                Some(end) => end,
                None => {
                    let (end, r, n) = probing::run_on(&mut link, &p, &mut probing::Plain(hooks))?;
                    (records, sent) = (r, n);
                    end
                }
            };
            Ok((end, link.request_status()?, link.stats))
        })();
        let sim = match server {
            Some(s) => Some(s.finish()?),
            None => None,
        };
        let (end, status, stats) = outcome?;
        (end, status, stats, sim)
    };
    let mut report = Report::new(machine, &name, sent, &end, &status, sim.as_ref(), stats);
    report.probes = records;
    Ok(Some(RunResult { report, sim }))
}

/// The cutting load (`--wrench F`, `--wrench-file FILE`) with the force limits of the
/// machine file at `machine_file` (none: the built-in machine, no limits), if a load is
/// given. Errors name the option or the file.
pub fn statics_spec(
    wrench: Option<&str>,
    wrench_file: Option<&Path>,
    machine_file: Option<&Path>,
    machine: &MachineConfig,
) -> Result<Option<StaticsSpec>, Failure> {
    use crate::analysis::statics::Loads;
    let bad = |m: String| Failure::new(exit::BAD_INPUT, m);
    let loads = match (wrench, wrench_file) {
        (Some(w), _) => {
            Loads::constant(Loads::parse_wrench(w).map_err(|m| bad(format!("--wrench {w}: {m}")))?)
        }
        (None, Some(p)) => {
            let text = std::fs::read_to_string(p)
                .map_err(|e| bad(format!("{}: cannot read the loads ({e})", p.display())))?;
            Loads::parse_file(&text, &p.display().to_string()).map_err(bad)?
        }
        (None, None) => return Ok(None),
    };
    let limits = match machine_file {
        Some(p) => crate::machine_file::load_force_limits(p).map_err(|e| bad(e.to_string()))?,
        None => vec![None; machine.joints.len()],
    };
    Ok(Some(StaticsSpec { loads, limits }))
}
