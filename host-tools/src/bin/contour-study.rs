//! `contour-study`: runs report B's helix on the `seed-b` machine under the four
//! controllers and prints the contour errors (see `docs/contour.md`).

use anyhow::Result;
use clap::Parser;
use pkmc_host::contour_study::{Conditions, Disturbance, Scheme, StudyMachine, SEED_B};
use pkmc_host::machine_file::MachineFile;
use pkmc_host::plant::Mismatch;
use std::path::PathBuf;

#[derive(Parser)]
#[command(about = "Contour-error study of report B's helix under four controllers")]
struct Args {
    /// Machine file (default: the bundled examples/machines/seed-b.toml).
    #[arg(long)]
    machine: Option<PathBuf>,
    /// Simulate the plants exactly as modelled (no mismatch).
    #[arg(long)]
    exact_plants: bool,
    /// No cutting force.
    #[arg(long)]
    no_disturbance: bool,
    /// Lead-in on the curve before t = 0, s (0: start from rest at t = 0).
    #[arg(long)]
    lead_in: Option<f64>,
    /// Cutting force: steady part, c.u.
    #[arg(long)]
    force_mean: Option<f64>,
    /// Cutting force: periodic amplitude, c.u.
    #[arg(long)]
    force_amplitude: Option<f64>,
    /// Cutting force: frequency, Hz.
    #[arg(long)]
    force_hz: Option<f64>,
    /// Writes every run's trace as CSV (t, contour error and X Y Z tracking errors, mm).
    #[arg(long)]
    csv: Option<PathBuf>,
}

fn main() -> Result<()> {
    let args = Args::parse();
    let text = match &args.machine {
        Some(p) => std::fs::read_to_string(p)?,
        None => SEED_B.to_string(),
    };
    let file: MachineFile = toml::from_str(&text)?;
    let machine = StudyMachine::new(&file)?;
    let mut c = Conditions::STUDY;
    if args.exact_plants {
        c.mismatch = [Mismatch::NONE; 3];
    }
    if args.no_disturbance {
        c.disturbance = Disturbance::NONE;
    }
    if let Some(v) = args.force_mean {
        c.disturbance.mean = v;
    }
    if let Some(v) = args.force_amplitude {
        c.disturbance.amplitude = v;
    }
    if let Some(v) = args.force_hz {
        c.disturbance.freq_hz = v;
    }
    if let Some(l) = args.lead_in {
        c.lead_in_s = l;
    }
    println!("conditions: {c:?}");
    let results: Vec<_> = Scheme::ALL.iter().map(|s| machine.run(*s, &c)).collect();
    let base = results[0].max_mm;
    println!("| controller | max contour error (um) | RMS (um) | max at (s) | max / uncoupled | max tracking (um) | saturated periods |");
    println!("|---|---:|---:|---:|---:|---:|---:|");
    for r in &results {
        println!(
            "| {} | {:.2} | {:.2} | {:.3} | {:.4} | {:.1} | {} |{}",
            r.scheme.name(),
            r.max_mm * 1e3,
            r.rms_mm * 1e3,
            r.max_at_s,
            r.max_mm / base,
            r.max_tracking_mm * 1e3,
            r.saturated_periods,
            r.trip
                .as_ref()
                .map(|t| format!(" TRIP {t:?}"))
                .unwrap_or_default()
        );
    }
    if let Some(path) = &args.csv {
        use std::io::Write;
        let mut f = std::io::BufWriter::new(std::fs::File::create(path)?);
        write!(f, "t_s")?;
        for r in &results {
            let n = r.scheme.name();
            write!(f, ",{n}_contour_mm,{n}_ex_mm,{n}_ey_mm,{n}_ez_mm")?;
        }
        writeln!(f)?;
        for i in 0..results[0].trace.len() {
            write!(f, "{:.4}", results[0].trace[i].0)?;
            for r in &results {
                let (c, a) = (
                    r.trace.get(i).map_or(f64::NAN, |x| x.1),
                    r.axis_trace.get(i).copied().unwrap_or([f64::NAN; 3]),
                );
                write!(f, ",{c:.7},{:.7},{:.7},{:.7}", a[0], a[1], a[2])?;
            }
            writeln!(f)?;
        }
    }
    Ok(())
}
