//! `nc-send`: parse a G-code program, stream it to a pkmc controller (a board on a
//! serial port, or the built-in simulator), wait for the end and summarise.

use clap::Parser;
use pkmc_host::job::{self, exit, Target};
use std::io::Write;
use std::path::PathBuf;

/// Stream a G-code program to a pkmc motion controller.
#[derive(Parser, Debug)]
#[command(name = "nc-send", version)]
struct Args {
    /// Run on the built-in simulated controller (over a pseudo-terminal).
    #[arg(long, conflicts_with = "port")]
    sim: bool,
    /// Serial port of the controller board.
    #[arg(long, value_name = "DEV")]
    port: Option<String>,
    /// Machine file (TOML); default: the built-in Cartesian X Y Z stepper machine.
    #[arg(long, value_name = "FILE.toml")]
    machine: Option<PathBuf>,
    /// Print the summary as JSON on stdout.
    #[arg(long, value_name = "FORMAT", value_parser = ["json"])]
    report: Option<String>,
    /// Write one CSV row per interpolation period (simulator only).
    #[arg(long, value_name = "FILE.csv")]
    trace: Option<PathBuf>,
    /// The G-code program.
    program: PathBuf,
}

fn main() {
    let args = Args::parse();
    std::process::exit(match run(&args) {
        Ok(code) => code,
        Err(f) => {
            eprintln!("nc-send: {}", f.message);
            f.code
        }
    });
}

fn run(args: &Args) -> Result<i32, job::Failure> {
    let machine = match &args.machine {
        Some(p) => pkmc_host::machine_file::load(p),
        None => pkmc_host::machine_file::parse(
            pkmc_host::machine_file::DEFAULT_MACHINE,
            "built-in machine",
        ),
    }
    .map_err(|e| job::Failure {
        code: exit::BAD_INPUT,
        message: format!("{e:#}"),
    })?;
    let target = match (&args.port, args.sim) {
        (Some(p), _) => Target::Port(p),
        (None, true) => Target::Sim,
        (None, false) => {
            return Err(job::Failure {
                code: exit::BAD_INPUT,
                message:
                    "no controller given: use --port DEV for a board or --sim for the simulator"
                        .into(),
            })
        }
    };
    let quiet = args.report.is_some();
    let mut last_line = 0;
    let (report, code) = job::run(
        &machine,
        &args.program,
        target,
        args.trace.as_deref(),
        |s| {
            if !quiet && s.line != last_line {
                last_line = s.line;
                eprint!("\rline {:>6}  {:?}   ", s.line, s.state);
            }
        },
    )?;
    if !quiet {
        eprintln!();
    }
    let mut out = std::io::stdout().lock();
    if quiet {
        let _ = writeln!(
            out,
            "{}",
            serde_json::to_string_pretty(&report).unwrap_or_default()
        );
    } else {
        let p = &report.final_pose;
        let _ = writeln!(
            out,
            "{}: {} on {} — {} of {} blocks in {:.3} s, state {}",
            report.program,
            report.result,
            report.machine,
            report.blocks_executed,
            report.blocks_sent,
            report.run_time_s,
            report.final_state
        );
        let _ = writeln!(
            out,
            "final pose X {:.4} Y {:.4} Z {:.4} A {:.4} B {:.4} C {:.4}",
            p["x"], p["y"], p["z"], p["a"], p["b"], p["c"]
        );
        if let Some(steps) = &report.final_joint_steps {
            let _ = writeln!(
                out,
                "drive positions (steps): {steps:?}; timing violations: {}",
                report.drive_violations.unwrap_or(0)
            );
        }
        for a in &report.alarms {
            let _ = writeln!(out, "ALARM: {a}");
        }
    }
    Ok(code)
}
