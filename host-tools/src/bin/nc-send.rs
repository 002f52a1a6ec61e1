//! `nc-send`: parse a G-code program, stream it to a pkmc controller (a board on a
//! serial port, found by its USB identity when no port is given, or the built-in
//! simulator), wait for the end and summarise; or run one command (`status`, `home`,
//! `jog`, `mdi`, `reset`). Exit codes: see `pkmc_host::job::exit` and docs/nc-send.md.

use clap::{Parser, Subcommand};
use pkmc::config::MachineConfig;
use pkmc::wire::{Control, HeldJob, Status};
use pkmc_host::cli::progress::{Interrupts, Operator, Progress, RawKeys, Style};
use pkmc_host::job::{self, exit, print_report, Failure, RunOptions, SimSetup, Target};
use pkmc_host::link::view::{state_name, StatusView};
use pkmc_host::link::{JobEnd, Link, LinkOptions, Transport};
use pkmc_host::sim::faults::FaultConfig;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// Stream a G-code program to a pkmc motion controller.
#[derive(Parser, Debug)]
#[command(name = "nc-send", version)]
struct Args {
    /// Run on the built-in simulated controller (over a pseudo-terminal).
    #[arg(long, global = true, conflicts_with = "port")]
    sim: bool,
    /// Serial port of the controller board; default: the board found on USB
    /// (VID 0x1209, PID 0x0001).
    #[arg(long, global = true, value_name = "DEV")]
    port: Option<String>,
    /// Machine file (TOML); default: the built-in Cartesian X Y Z stepper machine.
    #[arg(long, global = true, value_name = "FILE.toml")]
    machine: Option<PathBuf>,
    /// Tool table in LinuxCNC's tool-file form (`T1 P1 Z12.5 D6 ;comment`, mm); replaces
    /// the machine file's `[[tools]]`.
    #[arg(long, global = true, value_name = "FILE")]
    tools: Option<PathBuf>,
    /// A cutting load on the tool for the whole program, `Fx,Fy,Fz[,Mx,My,Mz]` (N and
    /// N·m about the tool point, machine frame): each joint's largest force is
    /// reported, and a joint over its `force_limit` in the machine file refuses the
    /// program.
    #[arg(
        long,
        global = true,
        value_name = "F",
        conflicts_with = "wrench_file",
        allow_hyphen_values = true
    )]
    wrench: Option<String>,
    /// As `--wrench`, one per NC line: each line of FILE is `LINE Fx Fy Fz [Mx My Mz]`,
    /// the load from NC line LINE on.
    #[arg(long, global = true, value_name = "FILE")]
    wrench_file: Option<PathBuf>,
    /// Print the summary as JSON on stdout (and no progress).
    #[arg(long, global = true, value_name = "FORMAT", value_parser = ["json"])]
    report: Option<String>,
    /// Simulator only: corrupt, drop or duplicate each byte on the line with this
    /// probability, both directions (e.g. 0.01).
    #[arg(long, global = true, value_name = "RATE", value_parser = pkmc_host::sim::faults::parse_rate)]
    link_faults: Option<f64>,
    /// Seed of the fault generator.
    #[arg(long, global = true, default_value_t = 1)]
    seed: u64,
    /// Send no block while the controller has this much motion buffered, ms.
    #[arg(long, global = true, value_name = "MS", default_value_t = pkmc_host::link::MAX_BUFFERED_MS)]
    max_buffered_ms: u32,
    /// Declare the link lost after this many seconds without an answer.
    #[arg(long, global = true, value_name = "S", default_value_t = 3.0)]
    link_timeout: f64,
    /// Simulator only, for tests: cut the line after this many bytes to the host.
    #[arg(long, global = true, hide = true, value_name = "BYTES")]
    link_cut_after: Option<u64>,
    /// Simulator only: inject a fault at a simulated time, KIND[:JOINT]@SECONDS with
    /// KIND one of estop, limit, drive-fault, following-error, link-loss (JOINT
    /// 0-based; default the first joint, the first servo joint for following-error).
    /// May be given more than once.
    #[arg(long, global = true, value_name = "FAULT@SECONDS")]
    inject: Vec<pkmc_host::sim::Injection>,
    /// Home the machine before the program (a controller is locked after a reset
    /// until homed or unlocked; the simulator is unlocked where it stands otherwise).
    #[arg(long)]
    home: bool,
    /// Dry run: compile, pre-check and plan the program on the controller core in
    /// this process (simulated clock, no port, nothing moves).
    #[arg(long)]
    check: bool,
    /// After a --sim or --check run, plot the tool path (top, front and side views),
    /// path speed and joints over time (.svg or .png).
    #[arg(long, value_name = "FILE.svg|FILE.png")]
    plot: Option<PathBuf>,
    /// Write one CSV row per interpolation period (--sim or --check only).
    #[arg(long, value_name = "FILE.csv")]
    trace: Option<PathBuf>,
    /// Stream every move as programmed: do not merge runs of short G1 moves into
    /// curves (on by default: within G64 P, and within --g64-tolerance in G64).
    #[arg(long)]
    no_compress: bool,
    /// Merging: a turn sharper than this between two moves stays a corner, degrees.
    #[arg(long, value_name = "DEGREES", default_value_t = 30.0)]
    corner_deg: f64,
    /// Merging: leave corners between feed moves as corners (by default they are
    /// rounded by blends within G64 P).
    #[arg(long)]
    no_blend: bool,
    /// In G64 without P, merge short G1 moves and blend corners between feed moves
    /// within this many mm (the default 0.001; 0: stream them as programmed).
    #[arg(long, value_name = "MM", default_value_t = 0.001)]
    g64_tolerance: f64,
    /// Restart the program from this NC line, its modal state rebuilt (docs/nc-send.md).
    #[arg(long, value_name = "LINE")]
    from: Option<u32>,
    #[command(flatten)]
    probe: pkmc_host::sim::probe::ProbeArgs,
    /// The G-code program.
    program: Option<PathBuf>,
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Print the controller's status once.
    Status,
    /// Home the machine and wait until it is there.
    Home,
    /// Move one axis by a distance and wait until it stops.
    #[command(allow_negative_numbers = true)]
    Jog {
        /// Axis: X Y Z A B C.
        axis: String,
        /// Distance, mm (X Y Z) or degrees (A B C); negative moves backwards.
        distance: f64,
        /// Feed, mm/min (degrees/min for A B C).
        #[arg(long, default_value_t = 600.0)]
        feed: f64,
    },
    /// Run one line of G-code from where the machine stands (e.g. "G1 X10 F500").
    Mdi {
        /// The line.
        line: String,
    },
    /// Clear an alarm once its cause is gone.
    Reset,
    /// Drop the job the controller holds (another host's unfinished job, or a job
    /// paused or held): a controlled stop if anything moves, then idle.
    Abort,
    /// Continue the job the controller holds (another host's unfinished job, or a
    /// job paused or held) and wait until it ends or pauses again. With PROGRAM (the
    /// held job's own, checked by its hash), the blocks the controller never received
    /// are streamed after it, to the program's end.
    Resume {
        /// The held job's program: its blocks not yet on the controller are sent.
        program: Option<PathBuf>,
        /// Run only what is queued on the controller, although blocks of the program
        /// were never sent (the result is then `incomplete`, exit 7).
        #[arg(long)]
        queued_only: bool,
    },
    /// Serve Grbl 1.1's text protocol to a sender (CNCjs, UGS, bCNC) on a
    /// pseudo-terminal, and with --tcp on a TCP port, until Ctrl-C (docs/senders.md).
    Grbl {
        /// Listen on this TCP address too (bCNC and UGS open socket://HOST:PORT).
        #[arg(long, value_name = "ADDRESS")]
        tcp: Option<String>,
        /// Link the pseudo-terminal at this path too.
        #[arg(long, value_name = "PATH")]
        link: Option<PathBuf>,
        /// M6: `grbl` refuses it with error:20 as Grbl 1.1 does; `pause` holds the
        /// machine for a manual tool change until `~`.
        #[arg(long, value_name = "MODE", default_value = "grbl", value_parser = ["grbl", "pause"])]
        tool_change: String,
    },
    /// Serve the operator station, a web page with the machine in 3-D, the DRO, the
    /// program editor, jog, MDI and teach, until Ctrl-C (docs/ui.md).
    Serve {
        /// Listen on this address (port 0: any free port; the address is printed).
        #[arg(long, value_name = "ADDRESS", default_value = "127.0.0.1:8180")]
        listen: String,
        /// A secret every request must carry (?token=); needed off loopback.
        #[arg(long)]
        token: Option<String>,
        /// Load this program at start.
        #[arg(long, value_name = "FILE")]
        program: Option<PathBuf>,
    },
    /// Calibrate the machine file's geometry from measured tool poses; `plan` the poses
    /// to measure (docs/calibration.md). Runs on this computer, no controller.
    Calibrate(pkmc_host::calibrate::cli::CalibrateArgs),
    /// Record signals with the controller's recorder, to CSV and a plot (docs/recorder.md).
    Record(pkmc_host::scope::cli::RecordArgs),
    /// Identify a servo joint's plant from a test signal and design its gains (docs/tuning.md).
    Tune(pkmc_host::scope::tune::TuneArgs),
}

fn main() {
    let args = Args::parse();
    let code = match run(&args) {
        Ok(code) => code,
        Err(f) => {
            eprintln!("nc-send: {}", f.message);
            if args.report.is_some() {
                // A report on every exit: what failed, and the exit code.
                let v = serde_json::json!({
                    "result": "error",
                    "exit_code": f.code,
                    "error": f.message,
                });
                println!("{}", serde_json::to_string_pretty(&v).unwrap_or_default());
            }
            f.code
        }
    };
    std::process::exit(code);
}

fn bad(message: impl Into<String>) -> Failure {
    Failure::new(exit::BAD_INPUT, message)
}

/// The cutting load (`--wrench`, `--wrench-file`), if given, with the force limits.
fn load_statics(args: &Args, m: &MachineConfig) -> Result<Option<job::StaticsSpec>, Failure> {
    let (w, file) = (args.wrench.as_deref(), args.wrench_file.as_deref());
    job::statics_spec(w, file, args.machine.as_deref(), m)
}

/// The compressor's settings from the command line (`None` with --no-compress).
fn compress_settings(args: &Args) -> Result<Option<pkmc_host::gcode::compress::Settings>, Failure> {
    if args.no_compress {
        return Ok(None);
    }
    pkmc_host::gcode::compress::Settings::of_options(
        args.corner_deg,
        !args.no_blend,
        args.g64_tolerance,
    )
    .map(Some)
    .map_err(bad)
}

fn load_machine(args: &Args) -> Result<MachineConfig, Failure> {
    match &args.machine {
        Some(p) => pkmc_host::machine_file::load(p),
        None => pkmc_host::machine_file::parse(
            pkmc_host::machine_file::DEFAULT_MACHINE,
            "built-in machine",
        ),
    }
    .map_err(|e| bad(format!("{e:#}")))
}

/// The port or simulator to use; finds the board on USB when neither is given.
fn target(args: &Args, found: &mut Option<pkmc_host::link::usb::Found>) -> Result<(), Failure> {
    if args.sim || args.port.is_some() {
        return Ok(());
    }
    let board = pkmc_host::cli::discover::find();
    *found = Some(board.map_err(|e| Failure::new(exit::NO_CONTROLLER, e.to_string()))?);
    Ok(())
}

/// `--link-timeout` (at most an hour) and `--max-buffered-ms` within what can work.
fn check_link_args(args: &Args) -> Result<(), Failure> {
    const MAX_LINK_TIMEOUT_S: f64 = 3600.0;
    if !(args.link_timeout > 0.0 && args.link_timeout <= MAX_LINK_TIMEOUT_S) {
        return Err(bad(format!(
            "--link-timeout {}: must be more than 0 and at most {MAX_LINK_TIMEOUT_S} s",
            args.link_timeout
        )));
    }
    if args.max_buffered_ms == 0 {
        return Err(bad(
            "--max-buffered-ms 0: must be at least 1 (with 0 no block could ever be sent)",
        ));
    }
    Ok(())
}

fn run(args: &Args) -> Result<i32, Failure> {
    let machine = load_machine(args)?;
    if let Some(Command::Calibrate(c)) = &args.command {
        return pkmc_host::calibrate::cli::run(c, args.machine.as_deref())
            .map(|()| exit::OK)
            .map_err(bad);
    }
    let quiet = args.report.is_some();
    if args.check && (args.sim || args.port.is_some()) {
        return Err(bad("--check runs in-process: leave out --sim and --port"));
    }
    if args.command.is_some() && (args.program.is_some() || args.check || args.plot.is_some()) {
        return Err(bad(
            "a command (status, home, jog, mdi, reset) takes no program, --check or --plot",
        ));
    }
    if let Some(p) = &args.plot {
        if !(args.sim || args.check) {
            return Err(bad("--plot needs --sim or --check (the path is simulated)"));
        }
        pkmc_host::analysis::plot::format_of(p).map_err(bad)?;
    }
    let mut found = None;
    if !args.check {
        target(args, &mut found)?;
    }
    let faults = args.link_faults.map(|rate| FaultConfig {
        cut_after_bytes: args.link_cut_after,
        ..FaultConfig::new(rate, args.seed)
    });
    let faults = faults.or(args.link_cut_after.map(|n| FaultConfig {
        cut_after_bytes: Some(n),
        ..FaultConfig::new(0.0, args.seed)
    }));
    check_link_args(args)?;
    if !args.sim && (args.link_faults.is_some() || args.link_cut_after.is_some()) {
        return Err(bad(
            "--link-faults needs --sim: only the simulator's line can be corrupted (--check \
             runs the controller in this process, with no line)",
        ));
    }
    let link = LinkOptions {
        max_buffered_ms: args.max_buffered_ms,
        link_timeout: Duration::from_secs_f64(args.link_timeout),
        ..LinkOptions::default()
    };
    let target = match (&args.port, &found) {
        (Some(p), _) => Target::Port(p),
        (None, Some(b)) => Target::board(b),
        (None, None) => Target::Sim,
    };
    if !args.inject.is_empty() && !args.sim {
        return Err(bad(
            "--inject needs --sim (faults are injected into the simulated machine)",
        ));
    }
    let plants = match &args.machine {
        Some(p) => pkmc_host::machine_file::load_plants(p).map_err(|e| bad(format!("{e:#}")))?,
        None => Vec::new(),
    };
    let tools = job::load_tools(args.tools.as_deref(), args.machine.as_deref())?;
    let statics = load_statics(args, &machine)?;
    let opts = RunOptions {
        target,
        sim: SimSetup {
            trace: args.trace.as_deref(),
            faults,
            record_path: args.plot.is_some(),
            plants,
            inject: args.inject.clone(),
            deviation: None,
            probe: args.probe.model(args.seed).map_err(bad)?,
            truth: args.probe.truth(pkmc_host::calibrate::truth::tool_point),
            // A sender watches the machine move: the simulator keeps real time.
            clock: match args.command {
                Some(Command::Grbl { .. } | Command::Serve { .. }) => {
                    pkmc_host::sim::serve::ServeClock::RealTime
                }
                _ => Default::default(),
            },
        },
        link,
        home: args.home,
        tools,
        statics,
        compress: compress_settings(args)?,
    };
    // Refused by name for every command, used by programs only (MDI, jogs and homing
    // keep the short link-loss watch).
    let host_timeout = match &args.machine {
        Some(p) => pkmc_host::machine_file::load_host_timeout(p).map_err(|e| bad(e.to_string()))?,
        None => pkmc_host::machine_file::DEFAULT_HOST_TIMEOUT,
    };
    let interrupts = Interrupts::install().map_err(|e| Failure::new(exit::LINK, e))?;
    match &args.command {
        Some(cmd @ (Command::Grbl { .. } | Command::Serve { .. })) => {
            serve(args, cmd, &machine, &opts, &interrupts, host_timeout)
        }
        Some(cmd) => {
            let mut opts = opts.clone();
            if matches!(cmd, Command::Resume { .. }) {
                // The rest of a program streams as a program does.
                opts.link.host_timeout = Some(host_timeout);
            }
            command(args, cmd, &machine, &opts, interrupts)
        }
        None => {
            let program = args
                .program
                .as_deref()
                .ok_or_else(|| bad("no program given (nc-send --help lists the commands)"))?;
            let mut opts = opts.clone();
            opts.link.host_timeout = Some(host_timeout);
            run_program(args, program, &machine, &opts, interrupts, quiet)
        }
    }
}

/// `grbl` and `serve`: the bridge or the operator station until Ctrl-C.
fn serve(
    args: &Args,
    cmd: &Command,
    machine: &MachineConfig,
    opts: &RunOptions<'_>,
    interrupts: &Interrupts,
    host_timeout: Duration,
) -> Result<i32, Failure> {
    let stop = || interrupts.count() > 0;
    match cmd {
        Command::Grbl {
            tcp,
            link,
            tool_change,
        } => {
            let bridge = pkmc_host::grbl::BridgeOptions {
                link: link.clone(),
                tcp: tcp.clone(),
                tools: opts.tools.clone(),
                tool_change: tool_change == "pause",
                compress: opts.compress,
            };
            pkmc_host::grbl::run(machine, opts, &bridge, &stop)
        }
        Command::Serve {
            listen,
            token,
            program,
        } => {
            let station = pkmc_host::station::StationOptions {
                listen: listen.clone(),
                token: token.clone(),
                program: program.clone(),
                joint_names: match &args.machine {
                    Some(p) => pkmc_host::machine_file::load_joint_names(p)
                        .map_err(|e| bad(format!("{e:#}")))?,
                    None => Vec::new(),
                },
                host_timeout: Some(host_timeout),
                machine_file: args.machine.clone(),
            };
            pkmc_host::station::run(machine, opts, &station, &stop)
        }
        _ => unreachable!("only grbl and serve serve"),
    }
}

fn run_program(
    args: &Args,
    program: &Path,
    machine: &MachineConfig,
    opts: &RunOptions<'_>,
    interrupts: Interrupts,
    quiet: bool,
) -> Result<i32, Failure> {
    let sim = matches!(opts.target, Target::Sim);
    let streamed = job::streamed::applies(program, opts).then(|| {
        let mut op = operator(args, sim, interrupts.clone(), quiet, 0);
        let from = job::streamed::Restarting::at(args.from, !quiet);
        let r = job::streamed::check_or_run(machine, program, opts, args.check, from, &mut op);
        op.progress.finish();
        r
    });
    let result = match streamed.transpose()?.flatten() {
        Some(r) => r,
        None => run_whole(args, program, machine, opts, interrupts, quiet)?,
    };
    if let (Some(p), Some(sim)) = (&args.plot, &result.sim) {
        pkmc_host::analysis::plot::draw(p, &sim.recorder, machine)
            .map_err(|e| Failure::new(exit::BAD_INPUT, e))?;
    }
    print_report(&result.report, quiet, args.check);
    Ok(result.report.exit_code())
}

/// The operator of a program's run: progress of `total` blocks, keys on a terminal.
fn operator(args: &Args, sim: bool, interrupts: Interrupts, quiet: bool, total: usize) -> Operator {
    let style = Style::for_stderr(quiet);
    let keys = (!quiet && !args.check).then(RawKeys::start).flatten();
    if keys.is_some() && style != Style::Quiet {
        eprintln!("keys: h/space hold, r resume, q stop, +/- feed override");
    }
    let mut op = Operator::new(Progress::new(style, total), interrupts, keys);
    op.auto_resume = args.check || sim;
    op
}

/// `run_program` of a program compiled whole.
fn run_whole(
    args: &Args,
    program: &Path,
    machine: &MachineConfig,
    opts: &RunOptions<'_>,
    interrupts: Interrupts,
    quiet: bool,
) -> Result<job::RunResult, Failure> {
    if args.from.is_none() && job::probing::file_names_g38(program) {
        let mut op = operator(
            args,
            matches!(opts.target, Target::Sim),
            interrupts.clone(),
            quiet,
            0,
        );
        let r = job::run_probing(machine, program, opts, &mut op, args.check);
        if let Some(r) = r.inspect(|_| op.progress.finish())? {
            return Ok(r);
        }
    }
    let (compiled, restart) = match args.from {
        Some(line) => job::from_line::compile_from(program, machine, opts, line, !quiet)
            .map(|(c, r)| (c, Some(r)))?,
        None => (job::compile_for(program, machine, opts)?, None),
    };
    let (blocks, name) = (&compiled.blocks, program.display().to_string());
    let sim = matches!(opts.target, Target::Sim);
    let mut op = operator(args, sim, interrupts, quiet, blocks.len());
    let result = if let (true, Some(r)) = (args.check, &restart) {
        let from = job::from_line::restarted(&compiled, r, machine.home);
        job::check_compiled(machine, &name, &from, opts, &mut op)
    } else if args.check {
        // The program compiled above, with its pre-flight and statics.
        job::check_compiled(machine, &name, &compiled, opts, &mut op)
    } else {
        let mut opts = opts.clone();
        // A restart's path is not the programmed one from the machine's pose.
        opts.sim.deviation = restart.is_none().then(|| compiled.deviation_meter());
        // The controller keeps it with the job: `resume PROGRAM` sends the rest.
        opts.link.mark = job::from_line::mark_for(&compiled, restart.as_ref(), program);
        let at = |pose| job::from_line::blocks_at(blocks, restart.as_ref(), pose);
        let derived = restart.is_none().then(|| compiled.derived()).flatten(); // not a restart's
        job::run_blocks_at(machine, &name, &at, derived, &opts, &mut op).map(|mut r| {
            let summary = job::CompressionSummary::of(&compiled, r.sim.as_ref());
            r.report.compression = Some(summary);
            r
        })
    };
    op.progress.finish();
    result
}

fn command(
    args: &Args,
    cmd: &Command,
    machine: &MachineConfig,
    opts: &RunOptions<'_>,
    interrupts: Interrupts,
) -> Result<i32, Failure> {
    let quiet = args.report.is_some();
    let mut op = Operator::new(Progress::new(Style::for_stderr(quiet), 0), interrupts, None);
    // A simulator has no operator: its pauses resume by themselves, as in a program run.
    op.auto_resume = matches!(opts.target, Target::Sim);
    let mut incomplete = None;
    let (status, result, code, extra, held) = job::with_link(machine, opts, |link| {
        let held = link.held();
        let moves = matches!(
            cmd,
            Command::Jog { .. } | Command::Mdi { .. } | Command::Record(_)
        );
        if moves && matches!(opts.target, Target::Sim) {
            // A fresh simulator is locked after its reset: unlock it where it stands.
            job::prepare(link, false, true, &mut op)?;
        }
        let (end, extra) = match cmd {
            Command::Status => (JobEnd::Done, None),
            Command::Reset => {
                link.control(Control::AlarmReset)?;
                (JobEnd::Done, None)
            }
            Command::Home => {
                let cmd = job::home_command(link)?;
                (job::move_and_wait(link, cmd, &mut op)?, None)
            }

            Command::Jog {
                axis,
                distance,
                feed,
            } => (jog(link, axis, *distance, *feed, &mut op)?, None),
            Command::Record(r) => (
                pkmc_host::scope::cli::run(link, r, machine, opts, &mut op)?,
                None,
            ),
            Command::Tune(t) => {
                pkmc_host::scope::tune::run(link, t, args.machine.as_deref(), opts, &mut op)?
            }
            Command::Mdi { line } => {
                let (blocks, end) = job::mdi(link, machine, line, &opts.tools, &mut op)?;
                (end, Some(blocks.len()))
            }
            Command::Abort => {
                link.control(Control::Abort)?;
                link.release_held();
                (link.wait_idle(&mut op)?, None)
            }
            Command::Resume {
                program,
                queued_only,
            } => {
                let r = job::resume(
                    link,
                    program.as_deref(),
                    *queued_only,
                    machine,
                    opts,
                    &mut op,
                )?;
                incomplete = r.incomplete;
                (r.end, r.blocks_sent)
            }
            Command::Grbl { .. } | Command::Serve { .. } | Command::Calibrate(_) => {
                unreachable!("served by grbl::run and station::run")
            }
        };
        let status = link.request_status()?;
        let (result, code) = match &end {
            JobEnd::Done if matches!(cmd, Command::Reset) && status.alarm.is_some() => {
                ("alarm", exit::ALARM)
            }
            JobEnd::Done if matches!(cmd, Command::Abort) => ("aborted", exit::OK),
            // Only what was queued ran: the program is not done.
            JobEnd::Done if incomplete.is_some() => ("incomplete", exit::HELD),
            JobEnd::Done => ("done", exit::OK),
            JobEnd::Alarm(_) => ("alarm", exit::ALARM),
            JobEnd::Aborted => ("aborted", exit::STOPPED),
            JobEnd::Paused(_) => ("paused", exit::HELD),
            JobEnd::Stopped => ("stopped", exit::STOPPED),
        };
        // What status shows: the job still held (not the one just resumed or aborted).
        let held = held.filter(|_| matches!(cmd, Command::Status | Command::Reset));
        Ok((status, result, code, extra, held))
    })?;
    print_status(&status, machine, result, extra, held, quiet);
    if let Some(m) = incomplete.filter(|_| result == "incomplete") {
        eprintln!("INCOMPLETE: {}", job::missing_text(&m));
    }
    Ok(code)
}

/// `jog AXIS DISTANCE --feed F`: mm (or degrees) and mm/min (or °/min), checked as
/// every jog is ([`job::jog_request`]).
fn jog<T: Transport>(
    link: &mut Link<T>,
    axis: &str,
    distance: f64,
    feed: f64,
    op: &mut Operator,
) -> Result<JobEnd, Failure> {
    let r = job::jog_request(axis, distance, feed, "--feed")?;
    let cmd = job::jog_command(link, r.axis, r.distance, r.feed)?;
    job::move_and_wait(link, cmd, op)
}

/// What `status` (and the other single commands) print: a line, the alarm and a held
/// job in words, or the JSON report.
fn print_status(
    status: &Status,
    machine: &MachineConfig,
    result: &str,
    extra: Option<usize>,
    held: Option<HeldJob>,
    quiet: bool,
) {
    let mut out = std::io::stdout().lock();
    if quiet {
        let mut v = job::status_json(status, machine, result);
        if let Some(n) = extra {
            v["blocks_sent"] = n.into();
        }
        v["held_job"] = match held {
            Some(h) => serde_json::json!({
                "host_process": h.host,
                "state": state_name(h.state),
                "line": h.line,
                "blocks_done": h.done,
                "blocks_queued": h.queued,
            }),
            None => serde_json::Value::Null,
        };
        let text = serde_json::to_string_pretty(&v).unwrap_or_default();
        let _ = writeln!(out, "{text}");
    } else {
        let v = StatusView::new(status);
        let _ = writeln!(
            out,
            "{}, line {}, {}, feed {:.0} mm/min, override {}%",
            v.state_words,
            v.line,
            v.pose_text(),
            v.feed_mm_min,
            v.feed_override
        );
        if let Some(a) = &v.alarm {
            let _ = writeln!(out, "ALARM: {}", a.words);
        }
        if let Some(h) = held {
            let _ = writeln!(
                out,
                "HELD: an unfinished job of another host (process {}, gone): {} at line {}, \
                 {} blocks done, {} still queued; `nc-send resume` continues it, \
                 `nc-send abort` drops it",
                h.host, h.state, h.line, h.done, h.queued
            );
        }
    }
}
