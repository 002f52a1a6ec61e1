//! `pkmc-sim`: the simulated controller on a pseudo-terminal, for `nc-send --port`.
//! Prints the port to open, then serves until interrupted. `--link-faults RATE`
//! puts the faulty line of `pkmc_host::sim::faults` between the port and the controller;
//! `--inject FAULT@SECONDS` injects a fault into the simulated machine (docs/safety.md).
//! With `--link PATH` it serves through a symbolic link at PATH (printed instead of the
//! pseudo-terminal), and SIGUSR1 unplugs it: the pseudo-terminal is closed and the link
//! removed for `--replug-secs`, while the machine runs on, then a new one is served
//! at the same PATH (as a board's USB cable pulled and plugged back).

use clap::Parser;
use pkmc_host::sim::faults::{FaultConfig, FaultyLine};
use serialport::SerialPort;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

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
    /// Serve through a symbolic link at this path (printed in place of the port).
    #[arg(long, value_name = "PATH")]
    link: Option<PathBuf>,
    /// How long SIGUSR1 unplugs the port (needs --link), seconds.
    #[arg(long, value_name = "S", default_value_t = 2.0)]
    replug_secs: f64,
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
    if args.link.is_none() && args.replug_secs != 2.0 {
        anyhow::bail!("--replug-secs needs --link (the path a replugged port comes back at)");
    }
    if !(args.replug_secs.is_finite() && (0.0..=3600.0).contains(&args.replug_secs)) {
        anyhow::bail!("--replug-secs {}: 0 to 3600 s", args.replug_secs);
    }
    if args.link.is_some() {
        // SIGUSR1: unplug (see the module documentation).
        let handler = on_usr1 as extern "C" fn(libc::c_int);
        unsafe { libc::signal(libc::SIGUSR1, handler as libc::sighandler_t) };
    }
    let mut line = args
        .link_faults
        .map(|rate| FaultyLine::new(FaultConfig::new(rate, args.seed)));
    let clock = if args.real_time {
        pkmc_host::sim::serve::ServeClock::RealTime
    } else {
        pkmc_host::sim::serve::ServeClock::Paced
    };
    let mut first = true;
    loop {
        let (mut master, slave) = serialport::TTYPort::pair()?;
        let name = slave.name().unwrap_or_default();
        if let Some(l) = &args.link {
            // Replaced at once (a new link renamed over the old path).
            let tmp = l.with_extension("pkmc-sim-new");
            let _ = std::fs::remove_file(&tmp);
            std::os::unix::fs::symlink(&name, &tmp)?;
            std::fs::rename(&tmp, l)?;
        }
        if first {
            match &args.link {
                Some(l) => println!("{}", l.display()),
                None => println!("{name}"),
            }
            first = false;
        }
        pkmc_host::sim::serve::serve(
            &mut sim,
            &mut master,
            &UNPLUG,
            line.as_mut(),
            clock,
            &mut |_| {},
        )?;
        // Unplugged: the port goes away, the machine runs on.
        drop((master, slave));
        if let Some(l) = &args.link {
            let _ = std::fs::remove_file(l);
        }
        let until = Instant::now() + Duration::from_secs_f64(args.replug_secs);
        let mut next = Instant::now();
        while Instant::now() < until {
            if sim.busy() {
                sim.tick()?;
            }
            next += Duration::from_millis(1);
            std::thread::sleep(next.saturating_duration_since(Instant::now()));
        }
        UNPLUG.store(false, Ordering::SeqCst);
    }
}

/// Set by SIGUSR1: the served port is unplugged for `--replug-secs`.
static UNPLUG: AtomicBool = AtomicBool::new(false);

extern "C" fn on_usr1(_: libc::c_int) {
    UNPLUG.store(true, Ordering::SeqCst);
}
