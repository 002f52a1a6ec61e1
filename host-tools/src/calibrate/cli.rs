//! `nc-send calibrate`: fit a machine file to measurements, plan the poses to
//! measure, simulate a measured machine, run the simulated-truth study.

use super::data::{self, format_number, Table};
use super::fit::{fit, Errors, Fit, Noise, PoseMeasurements};
use super::model::Model;
use super::{plan, study, truth};
use pkmc::config::MachineConfig;
use std::path::{Path, PathBuf};

/// The arguments of `nc-send calibrate`.
#[derive(clap::Args, Debug)]
#[command(args_conflicts_with_subcommands = true)]
pub struct CalibrateArgs {
    /// What else to do than fit.
    #[command(subcommand)]
    pub action: Option<Box<Action>>,
    /// Measurements (CSV: q1… or cmd_X…, and the measured X Y Z and angles; see
    /// docs/calibration.md).
    pub measurements: Option<PathBuf>,
    /// Write the corrected machine file here.
    #[arg(long, value_name = "FILE")]
    pub out: Option<PathBuf>,
    /// Position noise of the measurements, µm per coordinate.
    #[arg(long, default_value_t = 10.0)]
    pub noise_um: f64,
    /// Orientation noise of the measurements, millidegrees per angle.
    #[arg(long, default_value_t = 1.0)]
    pub noise_mdeg: f64,
    /// A parameter combination is unidentifiable below this singular value, relative
    /// to the largest (columns scaled by each parameter's typical error).
    #[arg(long, default_value_t = 1e-6)]
    pub tolerance: f64,
    /// Hold the parameters whose name starts with this at their nominal value (e.g.
    /// `offset` for joints whose zero the machine file cannot carry); repeatable.
    #[arg(long, value_name = "PREFIX")]
    pub hold: Vec<String>,
    /// Fit to sphere probing instead: the touches (CSV: q1… or the latched pose cmd_X…,
    /// `sphere`, optionally dir_x dir_y dir_z; see docs/calibration.md).
    #[arg(long, value_name = "FILE", conflicts_with = "measurements")]
    pub probes: Option<PathBuf>,
    /// With `--probes`: nc-send's JSON report (`--report json`) of the run of the
    /// plan's probing program. Its probes' latched joints replace the touch list's
    /// joints, touch by touch in order.
    #[arg(long, value_name = "REPORT", requires = "probes")]
    pub probe_report: Option<PathBuf>,
    /// The artefact and the probe.
    #[command(flatten)]
    pub probe: ProbeOptions,
}

/// The artefact and the probe (sphere probing).
#[derive(clap::Args, Debug, Clone)]
pub struct ProbeOptions {
    /// A sphere of the artefact: its centre (approximate; fitted) and radius (known),
    /// mm; repeatable, numbered from 0 in order. Else the file's `# sphere K = X,Y,Z,R`.
    #[arg(long = "sphere", value_name = "X,Y,Z,R")]
    pub spheres: Vec<String>,
    /// The probe tip's radius, mm (else the file's `# tip_radius = R`).
    #[arg(long = "tip-radius", value_name = "MM")]
    pub tip_radius: Option<f64>,
    /// The probe's trigger noise along the surface normal, µm.
    #[arg(long, default_value_t = 1.0)]
    pub probe_noise_um: f64,
}

impl ProbeOptions {
    fn args(&self, standoff: f64, overtravel: f64) -> super::sphere_cli::ProbeArgs {
        super::sphere_cli::ProbeArgs {
            spheres: self.spheres.clone(),
            tip: self.tip_radius,
            noise_um: self.probe_noise_um,
            standoff,
            overtravel,
        }
    }
}

/// The subcommands.
#[derive(clap::Subcommand, Debug)]
pub enum Action {
    /// Propose measurement poses (greedy D-optimal over random usable poses) and write
    /// them as a pose list, and optionally as a G-code program visiting them; with
    /// `--sphere`, touches of the spheres and a G38.2 probing program.
    Plan {
        /// How many poses.
        #[arg(long, default_value_t = 60)]
        poses: usize,
        /// How many touches (with --sphere).
        #[arg(long, default_value_t = 150)]
        touches: usize,
        /// Random usable candidates to choose from (default 400 poses, 2000 touches).
        #[arg(long)]
        candidates: Option<usize>,
        /// The artefact and the probe.
        #[command(flatten)]
        probe: ProbeOptions,
        /// A probing move starts this far out from the nominal surface, mm.
        #[arg(long, default_value_t = 5.0)]
        standoff: f64,
        /// A probing move ends this far past the nominal surface, mm.
        #[arg(long, default_value_t = 3.0)]
        overtravel: f64,
        /// Feed of the probing moves, mm/min.
        #[arg(long, default_value_t = 50.0)]
        probe_feed: f64,
        /// Seed of the candidates.
        #[arg(long = "plan-seed", default_value_t = 1)]
        plan_seed: u64,
        /// The pose list (CSV).
        #[arg(long, value_name = "FILE")]
        out: PathBuf,
        /// Also a G-code program that visits the poses and dwells at each.
        #[arg(long, value_name = "FILE")]
        gcode: Option<PathBuf>,
    },
    /// Measure a simulated true machine (every parameter perturbed by up to its
    /// scale, seeded) at the poses of a pose list, with Gaussian noise; a touch list
    /// (a `sphere` column) is probed instead, on true spheres off by up to ±1 mm.
    Simulate {
        /// The pose list (`calibrate plan --out`).
        poses: PathBuf,
        /// Seed of the true machine and of the noise.
        #[arg(long = "truth-seed")]
        truth_seed: u64,
        /// The measurements (CSV).
        #[arg(long, value_name = "FILE")]
        out: PathBuf,
        /// The artefact and the probe.
        #[command(flatten)]
        probe: ProbeOptions,
    },
    /// The simulated-truth study: for seeds 0..N, fit at a plan's poses and compare
    /// with the truth at random test poses.
    Study {
        /// Number of seeds.
        #[arg(long, default_value_t = 10)]
        seeds: u64,
        /// Measured poses per fit.
        #[arg(long, default_value_t = 60)]
        poses: usize,
        /// Test poses per seed.
        #[arg(long, default_value_t = 200)]
        tests: usize,
        /// Draw the position error over X and Y (at home Z and angles) before and
        /// after, for the seed `--plot-seed` (.svg or .png).
        #[arg(long, value_name = "FILE")]
        plot: Option<PathBuf>,
        /// The seed the plot shows.
        #[arg(long, default_value_t = 0)]
        plot_seed: u64,
        /// Study sphere probing instead (three balls per machine, or --sphere).
        #[arg(long)]
        probe: bool,
        /// Touches per fit (with --probe).
        #[arg(long, default_value_t = 150)]
        touches: usize,
        /// The artefact and the probe.
        #[command(flatten)]
        probe_options: ProbeOptions,
    },
}

fn load(machine: Option<&Path>) -> Result<(String, String, MachineConfig, Model), String> {
    let path = machine.ok_or("calibrate needs --machine FILE (a parallel machine)")?;
    let origin = path.display().to_string();
    let text = crate::input::read_text(path, crate::input::MAX_MACHINE_FILE_BYTES)?;
    let config = crate::machine_file::parse(&text, &origin).map_err(|e| e.to_string())?;
    let model = Model::from_config(&config).ok_or(format!(
        "{origin}: a Cartesian machine has no geometry to calibrate"
    ))?;
    Ok((origin, text, config, model))
}

fn write(path: &Path, text: &str) -> Result<(), String> {
    std::fs::write(path, text).map_err(|e| format!("{}: {e}", path.display()))
}

fn read_table(path: &Path) -> Result<Table, String> {
    let text = crate::input::read_text(path, crate::input::MAX_PROGRAM_BYTES)?;
    Table::parse(&text, &path.display().to_string())
}

/// Runs `nc-send calibrate` on the machine file `machine`.
pub fn run(args: &CalibrateArgs, machine: Option<&Path>) -> Result<(), String> {
    let (origin, text, config, model) = load(machine)?;
    let noise = Noise {
        position: args.noise_um * 1e-3,
        angle: args.noise_mdeg * 1e-3,
    };
    match args.action.as_deref() {
        Some(Action::Plan {
            probe,
            touches,
            candidates,
            standoff,
            overtravel,
            probe_feed,
            plan_seed,
            out,
            gcode,
            ..
        }) if !probe.spheres.is_empty() => super::sphere_cli::plan_command(
            &config,
            &model,
            &probe.args(*standoff, *overtravel),
            *touches,
            candidates.unwrap_or(2000),
            *plan_seed,
            out,
            gcode.as_deref(),
            [600.0, *probe_feed],
        ),
        Some(Action::Plan {
            poses,
            candidates,
            plan_seed,
            out,
            gcode,
            ..
        }) => pose_plan(
            &config,
            &model,
            (*poses, candidates.unwrap_or(400), *plan_seed),
            noise,
            out,
            gcode.as_deref(),
        ),
        Some(Action::Simulate {
            poses,
            truth_seed,
            out,
            probe,
        }) => {
            let table = read_table(poses)?;
            if table.column("sphere").is_some() {
                let a = probe.args(5.0, 3.0);
                return super::sphere_cli::simulate_command(&model, &a, poses, *truth_seed, out);
            }
            let list =
                data::poses(&table)?.ok_or(format!("{}: no cmd_X… columns", poses.display()))?;
            let joints = data::joints(&table, &model)?;
            let th = truth::perturb(&model, *truth_seed);
            let mut rng = truth::Rng::new(truth_seed ^ 0x0b5e);
            let mut measured = Vec::new();
            for (r, (q, guess)) in joints.iter().enumerate() {
                let s = truth::measure(&model, &th, q, guess, noise, &mut rng)
                    .ok_or(format!("{}: the true machine cannot reach it", table.at(r)))?;
                measured.push(s.measured);
            }
            let qs: Vec<Vec<f64>> = joints.into_iter().map(|j| j.0).collect();
            write(out, &data::write(&model, &list, &qs, Some(&measured)))
        }
        Some(Action::Study {
            seeds,
            tests,
            probe: true,
            touches,
            probe_options,
            ..
        }) => super::sphere_cli::study_command(
            &origin,
            &config,
            &model,
            &probe_options.args(5.0, 3.0),
            *seeds,
            *touches,
            *tests,
        ),
        Some(Action::Study {
            seeds,
            poses,
            tests,
            plot,
            plot_seed,
            ..
        }) => {
            let p = study_command(&origin, &config, &model, *seeds, *poses, *tests)?;
            if let Some(path) = plot {
                let o = study::run(&config, &model, &p, *plot_seed, 1)?;
                let truth = truth::perturb(&model, *plot_seed);
                let [b, a] = super::plot::draw(path, &config, &model, &truth, &o.fit.theta)?;
                println!(
                    "{}: seed {plot_seed}, largest position error over the map {b:.1} µm before, {a:.1} µm after",
                    path.display()
                );
            }
            Ok(())
        }
        None => match &args.probes {
            Some(p) => super::sphere_cli::fit_command(
                &args.probe.args(5.0, 3.0),
                p,
                args.probe_report.as_deref(),
                &text,
                &model,
                args.tolerance,
                &args.hold,
                args.out.as_deref(),
            ),
            None => fit_command(args, &text, &model, noise),
        },
    }
}

fn pose_plan(
    config: &MachineConfig,
    model: &Model,
    (poses, candidates, plan_seed): (usize, usize, u64),
    noise: Noise,
    out: &Path,
    gcode: Option<&Path>,
) -> Result<(), String> {
    let p = plan::plan(config, model, poses, candidates, plan_seed, noise)?;
    write(out, &data::write(model, &p.poses, &p.joints, None))?;
    if let Some(g) = gcode {
        write(g, &plan::gcode(&p, model.measured_axes(), 2.0, 600.0))?;
    }
    println!(
        "{} poses from {candidates} candidates: {} of {} parameters identifiable; \
         condition number {:.1} (the first {} candidates: {:.1})",
        p.poses.len(),
        p.ident.free.len(),
        model.params.len(),
        p.condition,
        p.poses.len(),
        p.random_condition
    );
    Ok(())
}

fn study_command(
    origin: &str,
    config: &MachineConfig,
    model: &Model,
    seeds: u64,
    poses: usize,
    tests: usize,
) -> Result<Vec<Vec<f64>>, String> {
    let p = plan::plan(config, model, poses, 400, 1, study::NOISE)?;
    println!(
        "{origin}: {} poses, condition {:.1}",
        p.poses.len(),
        p.condition
    );
    println!(
        "seed | before: pos RMS / max (µm), ang RMS / max (mdeg) | after: the same | worst |Δ|/σ"
    );
    let (mut worst_b, mut worst_a) = (Errors::default(), Errors::default());
    let mut best_b = Errors {
        pos_rms: f64::MAX,
        pos_max: f64::MAX,
        ang_rms: f64::MAX,
        ang_max: f64::MAX,
    };
    let (mut z2, mut nz, mut beyond) = (0.0, 0usize, 0usize);
    for seed in 0..seeds {
        let o = study::run(config, model, &p.joints, seed, tests)?;
        let (b, a) = (o.before, o.after);
        best_b = Errors {
            pos_rms: best_b.pos_rms.min(b.pos_rms),
            pos_max: best_b.pos_max.min(b.pos_max),
            ang_rms: best_b.ang_rms.min(b.ang_rms),
            ang_max: best_b.ang_max.min(b.ang_max),
        };
        worst_b = Errors {
            pos_rms: worst_b.pos_rms.max(b.pos_rms),
            pos_max: worst_b.pos_max.max(b.pos_max),
            ang_rms: worst_b.ang_rms.max(b.ang_rms),
            ang_max: worst_b.ang_max.max(b.ang_max),
        };
        worst_a = Errors {
            pos_rms: worst_a.pos_rms.max(a.pos_rms),
            pos_max: worst_a.pos_max.max(a.pos_max),
            ang_rms: worst_a.ang_rms.max(a.ang_rms),
            ang_max: worst_a.ang_max.max(a.ang_max),
        };
        z2 += o.z.iter().map(|v| v * v).sum::<f64>();
        nz += o.z.len();
        beyond += o.beyond_3sigma.len();
        println!(
            "{seed} | {} | {} | {:.2}{}",
            errors(&o.before),
            errors(&o.after),
            o.worst_z,
            if o.beyond_3sigma.is_empty() {
                String::new()
            } else {
                format!(" beyond 3σ: {}", o.beyond_3sigma.join(", "))
            }
        );
    }
    println!(
        "summary: before {} to {} | after at worst {} | |Δ|/σ RMS {:.3}, {beyond} of {nz} beyond 3σ",
        errors(&best_b),
        errors(&worst_b),
        errors(&worst_a),
        (z2 / nz.max(1) as f64).sqrt()
    );
    Ok(p.joints)
}

fn fit_command(
    args: &CalibrateArgs,
    text: &str,
    model: &Model,
    noise: Noise,
) -> Result<(), String> {
    let path = args
        .measurements
        .as_ref()
        .ok_or("calibrate: give the measurements CSV (or --probes FILE), or plan/simulate/study")?;
    let table = read_table(path)?;
    let samples = data::measurements(&table, model)?;
    let before = study::residuals(model, &model.nominal(), &samples);
    let mut meas = PoseMeasurements { samples, noise };
    let requested = held(model, &args.hold)?;
    let f = fit(model, &mut meas, args.tolerance, &requested)?;
    let after = study::residuals(model, &f.theta, &meas.samples);
    report(
        model,
        &f,
        (meas.samples.len(), "measured poses"),
        before,
        after,
    );
    if let Some(out) = &args.out {
        let (corrected, notes) = super::write::corrected(text, model, &f)?;
        crate::machine_file::parse(&corrected, &out.display().to_string())
            .map_err(|e| format!("the corrected machine file does not load: {e}"))?;
        write(out, &corrected)?;
        for n in notes {
            println!("note: {n}");
        }
        println!("wrote {}", out.display());
    }
    Ok(())
}

/// The parameters `--hold` names (by the start of their names).
pub fn held(model: &Model, hold: &[String]) -> Result<Vec<usize>, String> {
    if let Some(h) = hold
        .iter()
        .find(|h| !model.params.iter().any(|p| p.name.starts_with(h.as_str())))
    {
        return Err(format!("--hold {h}: no parameter's name starts with it"));
    }
    Ok((0..model.params.len())
        .filter(|&j| {
            hold.iter()
                .any(|h| model.params[j].name.starts_with(h.as_str()))
        })
        .collect())
}

fn errors(e: &super::fit::Errors) -> String {
    format!(
        "{:.1} / {:.1}, {:.2} / {:.2}",
        e.pos_rms * 1e3,
        e.pos_max * 1e3,
        e.ang_rms * 1e3,
        e.ang_max * 1e3
    )
}

/// The fit's report: rank, unidentifiable combinations, held and identified
/// parameters with their 1σ, and the residuals before and after when given.
pub fn report(
    model: &Model,
    f: &Fit,
    (n, what): (usize, &str),
    before: Option<super::fit::Errors>,
    after: Option<super::fit::Errors>,
) {
    let id = &f.ident;
    println!(
        "{n} {what}, {} parameters: rank {} (singular values {:.3e} … {:.3e})",
        model.params.len(),
        id.rank,
        id.singular[0],
        id.singular[id.singular.len() - 1]
    );
    for (h, others) in id.combinations.iter().filter(|(_, o)| !o.is_empty()) {
        let terms: Vec<String> = others
            .iter()
            .map(|(j, v)| format!("{v:+.3}·{}", model.params[*j].name))
            .collect();
        println!(
            "unidentifiable: {} with {} (held at {})",
            model.params[*h].name,
            terms.join(" "),
            format_number(model.params[*h].value)
        );
    }
    let alone: Vec<&str> = id
        .combinations
        .iter()
        .filter(|(_, o)| o.is_empty())
        .map(|(h, _)| model.params[*h].name.as_str())
        .collect();
    if !alone.is_empty() {
        println!(
            "held (no measurement sees them, or --hold): {}",
            alone.join(", ")
        );
    }
    println!(
        "identified: {} parameters, condition number {:.1}; Levenberg–Marquardt: {} iterations, reduced χ² {:.3}",
        id.free.len(),
        id.condition,
        f.iterations,
        f.s2
    );
    for &j in &id.free {
        let p = &model.params[j];
        println!(
            "  {:<22} {:>12} -> {:>12} ± {}",
            p.name,
            format_number(p.value),
            format_number(f.theta[j]),
            format_number(f.sigma[j])
        );
    }
    for (what, e) in [("before", before), ("after", after)] {
        if let Some(e) = e {
            println!(
                "residuals {what}: position RMS / max µm, orientation RMS / max mdeg: {}",
                errors(&e)
            );
        }
    }
}
