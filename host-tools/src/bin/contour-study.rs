//! `contour-study`: runs report B's helix on the `seed-b` machine under the four
//! controllers and prints the contour errors (see `docs/contour.md`).

use anyhow::Result;
use clap::Parser;
use pkmc_host::contour_study::{Conditions, Disturbance, RunResult, Scheme, StudyMachine, SEED_B};
use pkmc_host::control::plant::Mismatch;
use pkmc_host::machine_file::MachineFile;
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
    /// Draws the contour error over time of the four controllers (PNG).
    #[arg(long)]
    plot: Option<PathBuf>,
    /// Writes every run's trace as CSV (t, contour error and X Y Z tracking errors, mm).
    #[arg(long)]
    csv: Option<PathBuf>,
    /// Report B's machine itself (the bundled examples/machines/hexapod-xy.toml, or
    /// --machine): the five-axis study, PID and LQG.
    #[arg(long)]
    five_axis: bool,
    /// Designs the LQG law of every servo joint of the machine file (--machine) with a
    /// `plant` and `lqg` weights, and prints each joint's `lqg_gains` with its loop
    /// figures on the model and on the 10 %-off plant.
    #[arg(long)]
    design_lqg: bool,
    /// Five-axis study: the six legs' plant gain factors, comma-separated (default:
    /// 1.1,1.1,1.1,0.9,0.9,0.9).
    #[arg(long, value_delimiter = ',')]
    leg_gains: Option<Vec<f64>>,
    /// Five-axis study: runs uncoupled and CCPM, with PID and with LQG, under each of
    /// the 64 patterns of the legs' gains 10 % high or low, and prints the ratios.
    #[arg(long)]
    sweep_legs: bool,
    /// Five-axis study: the tool axis tilts by this many degrees along the path.
    #[arg(long, default_value_t = 0.0)]
    tilt: f64,
}

fn main() -> Result<()> {
    let args = Args::parse();
    if args.design_lqg {
        return design_lqg(&args);
    }
    if args.five_axis {
        return five_axis(&args);
    }
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
    for (axis, name) in ["X", "Y", "Z"].iter().enumerate() {
        let [nominal, off] = machine.axis_figures(axis, c.mismatch[axis]);
        println!(
            "axis {name}: peak |S| {:.2} (model) {:.2} (plant); crossover {:.1} / {:.1} rad/s",
            nominal.0, off.0, nominal.1, off.1
        );
    }
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
    if let Some(path) = &args.plot {
        plot(path, &results, &c)?;
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

fn plot(path: &std::path::Path, results: &[RunResult], c: &Conditions) -> Result<()> {
    use plotters::prelude::*;
    let _ = plotters::style::register_font(
        "sans-serif",
        plotters::style::FontStyle::Normal,
        dejavu::sans::regular(),
    );
    let fail = |e: String| anyhow::anyhow!("{}: cannot draw: {e}", path.display());
    let root = BitMapBackend::new(path, (1400, 1000)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| fail(e.to_string()))?;
    let (top, bottom) = root.split_vertically(500);
    let colours = [RED, BLUE, RGBColor(0, 150, 0), BLACK];
    let end = c.duration_s;
    let worst = results.iter().map(|r| r.max_mm * 1e3).fold(1.0, f64::max);
    let caption = format!(
        "Contour error on report B's helix, seed-b plants {} / cutting force {} + {} sin(2pi {} t) c.u.",
        "10 % off", c.disturbance.mean, c.disturbance.amplitude, c.disturbance.freq_hz
    );
    {
        let mut chart = ChartBuilder::on(&top)
            .caption(&caption, ("sans-serif", 22))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(70)
            .build_cartesian_2d(0.0..end, 0.0..worst * 1.05)
            .map_err(|e| fail(e.to_string()))?;
        chart
            .configure_mesh()
            .x_desc("t (s)")
            .y_desc("contour error (um)")
            .draw()
            .map_err(|e| fail(e.to_string()))?;
        for (r, col) in results.iter().zip(colours) {
            chart
                .draw_series(LineSeries::new(
                    r.trace.iter().map(|(t, e)| (*t, e * 1e3)),
                    col.stroke_width(1),
                ))
                .map_err(|e| fail(e.to_string()))?
                .label(format!(
                    "{}: max {:.2} um, RMS {:.2} um",
                    r.scheme.name(),
                    r.max_mm * 1e3,
                    r.rms_mm * 1e3
                ))
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], col.stroke_width(3)));
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperLeft)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 18))
            .draw()
            .map_err(|e| fail(e.to_string()))?;
    }
    {
        let mut chart = ChartBuilder::on(&bottom)
            .caption("same, logarithmic scale", ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(70)
            .build_cartesian_2d(0.0..end, (0.01..worst * 2.0).log_scale())
            .map_err(|e| fail(e.to_string()))?;
        chart
            .configure_mesh()
            .x_desc("t (s)")
            .y_desc("contour error (um)")
            .draw()
            .map_err(|e| fail(e.to_string()))?;
        for (r, col) in results.iter().zip(colours) {
            chart
                .draw_series(LineSeries::new(
                    r.trace.iter().map(|(t, e)| (*t, (e * 1e3).max(0.01))),
                    col.stroke_width(1),
                ))
                .map_err(|e| fail(e.to_string()))?;
        }
    }
    root.present().map_err(|e| fail(e.to_string()))?;
    Ok(())
}

/// The five-axis study on report B's machine: every scheme with every axis law.
fn five_axis(args: &Args) -> Result<()> {
    use pkmc_host::contour_study::five_axis::{self as fa, FiveAxisMachine, Law};
    let text = match &args.machine {
        Some(p) => std::fs::read_to_string(p)?,
        None => fa::HEXAPOD_XY.to_string(),
    };
    let file: MachineFile = toml::from_str(&text)?;
    let machine = FiveAxisMachine::new(&file)?;
    let mut c = fa::Conditions::study();
    c.tilt_deg = args.tilt;
    if args.exact_plants {
        c.mismatch = [Mismatch::NONE; 8];
    }
    if args.no_disturbance {
        c.force.steady = [0.0; 3];
    }
    if let Some(g) = &args.leg_gains {
        if g.len() != 6 {
            anyhow::bail!("--leg-gains: six factors, one a leg, not {}", g.len());
        }
        for (m, g) in c.mismatch.iter_mut().zip(g) {
            if !(g.is_finite() && *g > 0.0) {
                anyhow::bail!("--leg-gains: {g} is not a positive gain factor");
            }
            m.gain = *g;
        }
    }
    if args.sweep_legs {
        return sweep_legs(&machine, &c);
    }
    println!("conditions: {c:?}");
    println!("| loops | scheme | path max (um) | path RMS (um) | direction max (mdeg) | direction RMS (mdeg) | max / uncoupled (path, direction) | max following (um) | saturated periods |");
    println!("|---|---|---:|---:|---:|---:|---:|---:|---:|");
    let mut all = Vec::new();
    for law in Law::ALL {
        let runs: Vec<_> = Scheme::ALL
            .iter()
            .map(|s| machine.run(*s, law, &c))
            .collect();
        let (bp, bd) = (runs[0].max_path_mm, runs[0].max_dir_deg);
        for r in &runs {
            println!(
                "| {} | {} | {:.2} | {:.2} | {:.3} | {:.3} | {:.4}, {:.4} | {:.1} | {} |{}",
                law.name(),
                r.scheme.name(),
                r.max_path_mm * 1e3,
                r.rms_path_mm * 1e3,
                r.max_dir_deg * 1e3,
                r.rms_dir_deg * 1e3,
                r.max_path_mm / bp,
                r.max_dir_deg / bd,
                r.max_following_mm * 1e3,
                r.saturated_periods,
                r.trip
                    .as_ref()
                    .map(|t| format!(" TRIP {t:?}"))
                    .unwrap_or_default()
            );
        }
        all.extend(runs);
    }
    if let Some(path) = &args.plot {
        plot_five_axis(path, &all, &c)?;
    }
    Ok(())
}

/// The five-axis study's plot: path and tool-direction error over time (logarithmic),
/// the four schemes, a row per axis law.
fn plot_five_axis(
    path: &std::path::Path,
    runs: &[pkmc_host::contour_study::five_axis::Run],
    c: &pkmc_host::contour_study::five_axis::Conditions,
) -> Result<()> {
    use pkmc_host::contour_study::five_axis::Law;
    use plotters::prelude::*;
    let _ = plotters::style::register_font(
        "sans-serif",
        plotters::style::FontStyle::Normal,
        dejavu::sans::regular(),
    );
    let fail = |e: String| anyhow::anyhow!("{}: cannot draw: {e}", path.display());
    let root = BitMapBackend::new(path, (1600, 1000)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| fail(e.to_string()))?;
    let root = root
        .titled(
            &format!(
                "Report B's helix on the hexapod-xy, tool axis {}: plants 10 % off, cutting force",
                if c.tilt_deg > 0.0 {
                    "tilting +-10 deg"
                } else {
                    "held"
                }
            ),
            ("sans-serif", 24),
        )
        .map_err(|e| fail(e.to_string()))?;
    let colours = [RED, BLUE, RGBColor(0, 150, 0), BLACK];
    let panels = root.split_evenly((2, 2));
    for (i, panel) in panels.iter().enumerate() {
        let law = Law::ALL[i / 2];
        let direction = i % 2 == 1;
        let (unit, scale) = if direction {
            ("mdeg", 1e3)
        } else {
            ("um", 1e3)
        };
        let value = |x: &(f64, f64, f64)| if direction { x.2 } else { x.1 } * scale;
        let chosen: Vec<_> = runs.iter().filter(|r| r.law == law).collect();
        let top = chosen
            .iter()
            .flat_map(|r| r.trace.iter().map(value))
            .fold(1e-2, f64::max);
        let floor = top * 1e-4;
        let mut chart = ChartBuilder::on(panel)
            .caption(
                format!(
                    "{}: {} error ({unit})",
                    law.name(),
                    if direction { "tool-direction" } else { "path" }
                ),
                ("sans-serif", 20),
            )
            .margin(10)
            .x_label_area_size(36)
            .y_label_area_size(70)
            .build_cartesian_2d(0.0..c.duration_s, (floor..top * 2.0).log_scale())
            .map_err(|e| fail(e.to_string()))?;
        chart
            .configure_mesh()
            .x_desc("t (s)")
            .draw()
            .map_err(|e| fail(e.to_string()))?;
        for (r, col) in chosen.iter().zip(colours) {
            let (max, rms) = if direction {
                (r.max_dir_deg * scale, r.rms_dir_deg * scale)
            } else {
                (r.max_path_mm * scale, r.rms_path_mm * scale)
            };
            chart
                .draw_series(LineSeries::new(
                    r.trace.iter().map(|x| (x.0, value(x).max(floor))),
                    col.stroke_width(1),
                ))
                .map_err(|e| fail(e.to_string()))?
                .label(if direction {
                    format!("{}: max {max:.3}, RMS {rms:.3}", r.scheme.name())
                } else {
                    format!("{}: max {max:.2}, RMS {rms:.2}", r.scheme.name())
                })
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], col.stroke_width(3)));
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::LowerRight)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 16))
            .draw()
            .map_err(|e| fail(e.to_string()))?;
    }
    root.present().map_err(|e| fail(e.to_string()))?;
    Ok(())
}

/// `--design-lqg`: every joint's LQG design from its plant and weights.
fn design_lqg(args: &Args) -> Result<()> {
    use pkmc_host::control::lqg::{design, gains_toml};
    use pkmc_host::control::plant::TransferFunction;
    let path = args
        .machine
        .as_ref()
        .ok_or_else(|| anyhow::anyhow!("--design-lqg needs --machine FILE"))?;
    let file: MachineFile = toml::from_str(&std::fs::read_to_string(path)?)?;
    let off = Mismatch {
        gain: 1.1,
        resonance: 0.9,
    };
    for (j, jf) in file.joints.iter().enumerate() {
        // The design is of `lqg_model` where the file has one (`nc-send tune`'s).
        let model = match (&jf.lqg_model, &jf.plant) {
            (Some(m), _) => (&m.num, &m.den),
            (None, Some(p)) => (&p.num, &p.den),
            (None, None) => continue,
        };
        let Some(w) = &jf.lqg else {
            continue;
        };
        let tf = TransferFunction::new(model.0, model.1)?;
        let d = design(
            &tf,
            jf.steps_per_unit,
            1.0 / pkmc::drive::servo::SERVO_HZ as f64,
            w,
        )?;
        let model = d.loop_figures(&tf, jf.steps_per_unit)?;
        let plant = d.loop_figures(&tf.perturbed(off), jf.steps_per_unit)?;
        println!(
            "# joints[{j}] ({}): peak |S| {:.2} (model) {:.2} (10 % off); crossover {:.1} / {:.1} rad/s; \
             1 Hz load {:.2} / {:.2} counts per c.u.; largest closed-loop pole {:.5}",
            jf.name,
            model.peak_sensitivity,
            plant.peak_sensitivity,
            model.crossover_rad_s,
            plant.crossover_rad_s,
            model.load_response_1hz,
            plant.load_response_1hz,
            model.max_pole
        );
        println!("lqg_gains = {}", gains_toml(&d.gains));
    }
    Ok(())
}

/// Every pattern of the legs' gains 10 % high or low: CCPM's errors against
/// uncoupled control's with both laws, and how many patterns meet 1/10.
fn sweep_legs(
    machine: &pkmc_host::contour_study::five_axis::FiveAxisMachine,
    c: &pkmc_host::contour_study::five_axis::Conditions,
) -> Result<()> {
    use pkmc_host::contour_study::five_axis::Law;
    println!(
        "tool axis tilt {} deg; other conditions as the study's",
        c.tilt_deg
    );
    println!("| leg gains | law | US direction (mdeg) | CCPM direction (mdeg) | ratio | US path (um) | CCPM path (um) | ratio |");
    println!("|---|---|---:|---:|---:|---:|---:|---:|");
    let (mut met, mut runs, mut trips) = (0, 0, 0);
    let mut failed_us = Vec::new();
    for bits in 0..64u32 {
        let mut c = *c;
        let mut name = String::new();
        for (leg, m) in c.mismatch[..6].iter_mut().enumerate() {
            m.gain = if bits >> leg & 1 == 0 { 1.1 } else { 0.9 };
            name += if bits >> leg & 1 == 0 { "+" } else { "-" };
        }
        for law in Law::ALL {
            let us = machine.run(Scheme::Uncoupled, law, &c);
            let cc = machine.run(Scheme::Ccpm, law, &c);
            trips += us.trip.is_some() as u32 + cc.trip.is_some() as u32;
            let (rd, rp) = (
                cc.max_dir_deg / us.max_dir_deg,
                cc.max_path_mm / us.max_path_mm,
            );
            runs += 1;
            if rd <= 0.1 && rp <= 0.1 && us.trip.is_none() && cc.trip.is_none() {
                met += 1;
            } else {
                failed_us.push(us.max_dir_deg * 1e3);
            }
            let trip = |r: &pkmc_host::contour_study::five_axis::Run| {
                r.trip
                    .as_ref()
                    .map(|t| format!(" {} TRIP {t:?}", r.scheme.name()))
                    .unwrap_or_default()
            };
            println!(
                "| {name} | {} | {:.3} | {:.3} | {rd:.3} | {:.2} | {:.2} | {rp:.3} |{}{}",
                law.name(),
                us.max_dir_deg * 1e3,
                cc.max_dir_deg * 1e3,
                us.max_path_mm * 1e3,
                cc.max_path_mm * 1e3,
                trip(&us),
                trip(&cc),
            );
        }
    }
    let worst = failed_us.iter().copied().fold(0.0, f64::max);
    println!(
        "{met} of {runs} (pattern, law) runs have CCPM within 1/10 of uncoupled on both errors; \
         {trips} trips; the largest uncoupled direction error among the others: {worst:.3} mdeg"
    );
    Ok(())
}
