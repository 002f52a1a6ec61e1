//! `pkmc-sim`: the simulated controller on a pseudo-terminal, for `nc-send --port`.
//! Prints the port to open, then serves until interrupted. `--link-faults RATE`
//! puts the faulty line of `pkmc_host::sim::faults` between the port and the controller;
//! `--inject FAULT@SECONDS` injects a fault into the simulated machine (docs/safety.md).

use clap::Parser;
use pkmc_host::sim::faults::{FaultConfig, FaultyLine};
use serialport::SerialPort;
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;

/// Serve a simulated pkmc controller on a pseudo-terminal.
#[derive(Parser, Debug)]
#[command(name = "pkmc-sim", version)]
struct Args {
    /// Machine file (TOML); default: the built-in Cartesian X Y Z stepper machine.
    #[arg(long, value_name = "FILE.toml")]
    machine: Option<PathBuf>,
    /// File standing in for the controller's flash: the machine stored there is loaded
    /// at start, and a machine sent by the host is stored there.
    #[arg(long, value_name = "FILE")]
    flash: Option<PathBuf>,
    /// Corrupt, drop or duplicate each byte on the line with this probability (both
    /// directions).
    #[arg(long, value_name = "RATE", value_parser = pkmc_host::sim::faults::parse_rate)]
    link_faults: Option<f64>,
    /// Seed of the fault generator.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Inject a fault at a simulated time, KIND[:JOINT]@SECONDS (as `nc-send --inject`).
    #[arg(long, value_name = "FAULT@SECONDS")]
    inject: Vec<pkmc_host::sim::Injection>,
    /// Keep real time always (one tick per millisecond, as a board), not only while
    /// the host streams: for a page or a sender that watches the machine move.
    #[arg(long)]
    real_time: bool,
    /// Write a CSV row per tick (as `nc-send --trace`) to this file, a line at a time: it is
    /// whole up to the last tick however the simulator is ended.
    #[arg(long, value_name = "FILE.csv")]
    trace: Option<PathBuf>,
}

fn main() {
    if let Err(e) = serve(Args::parse()) {
        eprintln!("pkmc-sim: {e:#}");
        std::process::exit(2);
    }
}

fn serve(args: Args) -> anyhow::Result<()> {
    let machine = match &args.machine {
        Some(p) => pkmc_host::machine_file::load(p)?,
        None => pkmc_host::machine_file::parse(
            pkmc_host::machine_file::DEFAULT_MACHINE,
            "built-in machine",
        )?,
    };
    let plants = match &args.machine {
        Some(p) => pkmc_host::machine_file::load_plants(p)?,
        None => Vec::new(),
    };
    let mut sim = match args.flash {
        Some(f) => pkmc_host::sim::Simulator::with_flash(f, machine, plants)?,
        None => {
            pkmc_host::sim::Simulator::with_plants(machine, plants, [0; pkmc::config::MAX_JOINTS])?
        }
    };
    sim.inject(&args.inject)?;
    if let Some(p) = &args.trace {
        let f = std::fs::File::create(p)
            .map_err(|e| anyhow::anyhow!("--trace {}: {e}", p.display()))?;
        sim.trace_to(Box::new(std::io::LineWriter::new(f)))?;
    }
    let (mut master, slave) = serialport::TTYPort::pair()?;
    println!("{}", slave.name().unwrap_or_default());
    let stop = AtomicBool::new(false);
    let mut line = args
        .link_faults
        .map(|rate| FaultyLine::new(FaultConfig::new(rate, args.seed)));
    pkmc_host::sim::serve::serve(
        &mut sim,
        &mut master,
        &stop,
        line.as_mut(),
        if args.real_time {
            pkmc_host::sim::serve::ServeClock::RealTime
        } else {
            pkmc_host::sim::serve::ServeClock::Paced
        },
        &mut |_| {},
    )?;
    Ok(())
}
