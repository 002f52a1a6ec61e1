//! The sphere-probing side of `nc-send calibrate`: the fit of a probing file
//! (`--probes`), the probing plan (`plan --sphere`), the simulated probing of a
//! touch list (`simulate` on a plan with a `sphere` column) and the study
//! (`study --probe`).

use super::data::{self, format_number, Table};
use super::fit::{fit, Fit};
use super::model::Model;
use super::sphere::{header, rms_max_um, spheres_of, touches, worst_approach, Probing, Sphere};
use super::sphere_plan::{self, Planned, Setup, SpherePlan};
use super::sphere_study;
use super::truth::{self, Rng};
use pkmc::config::MachineConfig;
use std::path::Path;

/// The probe's settings from the command line.
#[derive(Clone, Debug)]
pub struct ProbeArgs {
    /// `--sphere X,Y,Z,R`, each.
    pub spheres: Vec<String>,
    /// `--tip-radius`.
    pub tip: Option<f64>,
    /// The probe's noise along the normal, µm.
    pub noise_um: f64,
    /// Start of a probing move out from the surface, mm.
    pub standoff: f64,
    /// Largest move past the nominal surface, mm.
    pub overtravel: f64,
}

/// The setup: spheres and tip from the command line, else from the file's comments
/// `text` (`# sphere K = X,Y,Z,R`, `# tip_radius = R`).
pub fn setup(a: &ProbeArgs, file: Option<(&str, &str)>) -> Result<Setup, String> {
    let (mut spheres, mut tip) = (Vec::new(), a.tip);
    if let Some((text, origin)) = file {
        let (s, t) = header(text, origin)?;
        spheres = s;
        tip = tip.or(t);
    }
    if !a.spheres.is_empty() {
        spheres = a
            .spheres
            .iter()
            .map(|s| Sphere::parse(s).map_err(|e| format!("--sphere {e}")))
            .collect::<Result<_, _>>()?;
    }
    if spheres.is_empty() {
        return Err("probing needs its spheres: --sphere X,Y,Z,R (repeatable) or `# sphere 0 = X,Y,Z,R` in the file".into());
    }
    let tip =
        tip.ok_or("probing needs the probe tip's radius: --tip-radius MM or `# tip_radius = MM`")?;
    if a.noise_um.is_nan() || a.noise_um <= 0.0 {
        return Err("the probe's noise must be positive".into());
    }
    Ok(Setup {
        spheres,
        tip,
        standoff: a.standoff,
        overtravel: a.overtravel,
        noise: a.noise_um * 1e-3,
    })
}

fn read(path: &Path) -> Result<(String, Table), String> {
    let text = crate::input::read_text(path, crate::input::MAX_PROGRAM_BYTES)?;
    let table = Table::parse(&text, &path.display().to_string())?;
    Ok((text, table))
}

/// The joints latched by each probing move of `nc-send`'s JSON report at `path`
/// (`--report json` of the probing program's run), mm or degrees, in order; `joints`:
/// how many the machine has. Errors name the report and the probe.
pub fn report_joints(path: &Path, joints: usize) -> Result<Vec<Vec<f64>>, String> {
    let origin = path.display().to_string();
    let text = crate::input::read_text(path, crate::input::MAX_PROGRAM_BYTES)?;
    let v: serde_json::Value = serde_json::from_str(&text).map_err(|e| {
        format!(
            "{origin}:{}:{}: not a JSON report: {e}",
            e.line(),
            e.column()
        )
    })?;
    let probes = v.get("probes").and_then(|p| p.as_array()).ok_or_else(|| {
        format!("{origin}: no `probes` in the report (run the probing program with --report json)")
    })?;
    let mut out = Vec::new();
    for (i, p) in probes.iter().enumerate() {
        let line = p.get("line").and_then(|l| l.as_u64()).unwrap_or(0);
        let at = format!("{origin}: probes[{i}] (NC line {line})");
        if p.get("contact").and_then(|c| c.as_bool()) != Some(true) {
            return Err(format!("{at}: the probe made no contact"));
        }
        let q: Vec<f64> = p
            .get("joints")
            .and_then(|j| j.as_array())
            .map(|j| j.iter().filter_map(|v| v.as_f64()).collect())
            .unwrap_or_default();
        if q.len() != joints {
            return Err(format!(
                "{at}: `joints` holds {} numbers; the machine has {joints} joints",
                q.len()
            ));
        }
        out.push(q);
    }
    Ok(out)
}

/// `nc-send calibrate --probes FILE`: the fit, its report, and with `out` the
/// corrected machine file. With `latched` (`--probe-report`), the joints of the
/// touches are those latched in that run's report, touch by touch in order.
#[allow(clippy::too_many_arguments)]
pub fn fit_command(
    a: &ProbeArgs,
    path: &Path,
    latched: Option<&Path>,
    machine_text: &str,
    model: &Model,
    tolerance: f64,
    hold: &[String],
    out: Option<&Path>,
) -> Result<(), String> {
    let (text, table) = read(path)?;
    let setup = setup(a, Some((&text, &path.display().to_string())))?;
    let ext = super::sphere::extend(model, &setup.spheres);
    let mut list = touches(&table, model, setup.spheres.len())?;
    if let Some(r) = latched {
        let q = report_joints(r, model.joints())?;
        if q.len() != list.len() {
            return Err(format!(
                "{}: {} probing moves with contact, but {} lists {} touches",
                r.display(),
                q.len(),
                path.display(),
                list.len()
            ));
        }
        for (t, q) in list.iter_mut().zip(q) {
            t.q = q;
        }
    }
    let mut data = Probing {
        touches: list,
        radii: setup.spheres.iter().map(|s| s.radius).collect(),
        tip: setup.tip,
        noise: setup.noise,
        machine_params: model.params.len(),
    };
    let requested = super::cli::held(&ext, hold)?;
    let all: Vec<usize> = (0..model.params.len()).collect();
    let before = fit(&ext, &mut data, tolerance, &all)?;
    let gaps_before = data.gaps(&ext, &before.theta).ok_or("lost a touch")?;
    let f = fit(&ext, &mut data, tolerance, &requested)?;
    let gaps_after = data.gaps(&ext, &f.theta).ok_or("lost a touch")?;
    super::cli::report(&ext, &f, (data.touches.len(), "touches"), None, None);
    let fitted = spheres_of(&f.theta, model.params.len(), &data.radii);
    for (k, s) in fitted.iter().enumerate() {
        println!("sphere {k}: centre {}", s.text());
    }
    let (b, af) = (rms_max_um(&gaps_before), rms_max_um(&gaps_after));
    println!(
        "touches' distance from their sphere, RMS / max µm: nominal machine (centres fitted) {:.2} / {:.2}, calibrated {:.2} / {:.2}",
        b.0, b.1, af.0, af.1
    );
    if let Some(w) = worst_approach(&data, &ext, &f.theta) {
        println!("largest angle between a touch's approach and the surface normal: {w:.1}°");
    }
    if let Some(out) = out {
        let (corrected, notes) = super::write::corrected(machine_text, &ext, &f)?;
        crate::machine_file::parse(&corrected, &out.display().to_string())
            .map_err(|e| format!("the corrected machine file does not load: {e}"))?;
        std::fs::write(out, corrected).map_err(|e| format!("{}: {e}", out.display()))?;
        for n in notes {
            println!("note: {n}");
        }
        println!("wrote {}", out.display());
    }
    Ok(())
}

/// The plan's numbers as printed.
pub fn describe(model: &Model, p: &SpherePlan, candidates: usize) -> String {
    format!(
        "{} touches from {candidates} candidates: {} of {} parameters identifiable ({} of the machine's {}, the rest the spheres' centres); condition number {:.1} (the first {} candidates: {:.1})",
        p.touches.len(),
        p.ident.free.len(),
        p.model.params.len(),
        p.ident.free.iter().filter(|&&j| j < model.params.len()).count(),
        model.params.len(),
        p.condition,
        p.touches.len(),
        p.random_condition
    )
}

/// `nc-send calibrate plan --sphere …`.
#[allow(clippy::too_many_arguments)]
pub fn plan_command(
    config: &MachineConfig,
    model: &Model,
    a: &ProbeArgs,
    n: usize,
    candidates: usize,
    seed: u64,
    out: &Path,
    gcode: Option<&Path>,
    feeds: [f64; 2],
) -> Result<(), String> {
    let setup = setup(a, None)?;
    let p = sphere_plan::plan(config, model, &setup, n, candidates, seed)?;
    let write = |path: &Path, text: String| {
        std::fs::write(path, text).map_err(|e| format!("{}: {e}", path.display()))
    };
    write(out, sphere_plan::csv(model, &setup, &p.touches, None))?;
    if let Some(g) = gcode {
        let axes = model.measured_axes();
        write(
            g,
            sphere_plan::gcode(model, &setup, &p, axes, feeds[0], feeds[1]),
        )?;
    }
    println!("{}", describe(model, &p, candidates));
    Ok(())
}

/// The planned touches of a touch list.
fn planned(table: &Table, model: &Model, spheres: usize) -> Result<Vec<Planned>, String> {
    let poses = data::poses(table)?.ok_or(format!("{}: no cmd_X… columns", table.origin()))?;
    let list = touches(table, model, spheres)?;
    let th = model.nominal();
    let mut out = Vec::new();
    for (r, (t, pose)) in list.into_iter().zip(poses).enumerate() {
        let a = t
            .approach
            .ok_or(format!("{}: no dir_x dir_y dir_z columns", table.origin()))?;
        let (q, x) = model
            .inverse(&th, &pose)
            .ok_or(format!("{}: the touch pose is out of reach", table.at(r)))?;
        out.push(Planned {
            sphere: t.sphere,
            pose,
            normal: a.map(|v| -v),
            q,
            x,
        });
    }
    Ok(out)
}

/// `nc-send calibrate simulate TOUCHES --truth-seed S`: the true machine of seed `S`
/// probing true spheres (each centre off by up to ±1 mm, seeded) at the touch list.
pub fn simulate_command(
    model: &Model,
    a: &ProbeArgs,
    path: &Path,
    seed: u64,
    out: &Path,
) -> Result<(), String> {
    let (text, table) = read(path)?;
    let setup = setup(a, Some((&text, &path.display().to_string())))?;
    let list = planned(&table, model, setup.spheres.len())?;
    let th = truth::perturb(model, seed);
    let mut rng = Rng::new(seed ^ 0x5f4e);
    let spheres = sphere_study::displaced(&setup.spheres, &mut rng);
    let mut latched = Vec::new();
    for (r, t) in list.iter().enumerate() {
        let (q, _) =
            sphere_study::touch(model, &th, &spheres[t.sphere], &setup, t, &mut rng).ok_or(
                format!("{}: the true machine finds no contact", table.at(r)),
            )?;
        latched.push(q);
    }
    for (k, s) in spheres.iter().enumerate() {
        println!("true sphere {k}: {}", s.text());
    }
    let csv = sphere_plan::csv(model, &setup, &list, Some(&latched));
    std::fs::write(out, csv).map_err(|e| format!("{}: {e}", out.display()))
}

/// `nc-send calibrate study --probe`: seeds 0..`seeds`.
pub fn study_command(
    origin: &str,
    config: &MachineConfig,
    model: &Model,
    a: &ProbeArgs,
    seeds: u64,
    n: usize,
    tests: usize,
) -> Result<(), String> {
    let mut setup = sphere_study::default_setup(model);
    if !a.spheres.is_empty() {
        let given = self::setup(a, None)?;
        setup.spheres = given.spheres;
        setup.tip = given.tip;
    } else if let Some(t) = a.tip {
        setup.tip = t;
    }
    setup.noise = a.noise_um * 1e-3;
    let p = sphere_plan::plan(config, model, &setup, n, 2000, 1)?;
    println!("{origin}: {}", describe(model, &p, 2000));
    for (k, s) in setup.spheres.iter().enumerate() {
        println!(
            "sphere {k}: {}; tip radius {}",
            s.text(),
            format_number(setup.tip)
        );
    }
    println!("seed | touches: RMS / max µm before, after | test position error: RMS / max µm before, after; after in the best frame | held");
    let (mut worst, mut range) = (0.0f64, [f64::MAX, 0.0f64]);
    for seed in 0..seeds {
        let o = sphere_study::run(config, model, &setup, &p, seed, tests)?;
        let [(rb, mb), (ra, ma)] = o.residuals;
        let [(eb, xb), (ea, xa)] = o.errors;
        let (fa, fx) = o.errors_any_frame;
        worst = worst.max(ea);
        range = [range[0].min(eb), range[1].max(eb)];
        println!(
            "{seed} | {rb:.1} / {mb:.1}, {ra:.2} / {ma:.2} | {eb:.1} / {xb:.1}, {ea:.2} / {xa:.2}; {fa:.2} / {fx:.2} | {}",
            held(&p.model, &o.fit)
        );
    }
    println!(
        "summary: test position RMS before {:.1} to {:.1} µm, after at worst {worst:.2} µm",
        range[0], range[1]
    );
    Ok(())
}

fn held(model: &Model, f: &Fit) -> String {
    let h: Vec<&str> = f
        .ident
        .held
        .iter()
        .map(|&j| model.params[j].name.as_str())
        .collect();
    h.join(" ")
}
