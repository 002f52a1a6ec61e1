//! The simulated-truth study of sphere probing: a true machine per seed (every
//! parameter perturbed, [`super::truth::perturb`]) and true spheres (each centre off
//! the given one by up to ±1 mm per coordinate), probed at a plan's touches with
//! noise along the surface normal, fitted, and compared with the truth at random test
//! poses not used in the fit.
//!
//! No probing sees where the machine stands against the artefact (a rigid motion of
//! both leaves every touch alike), so the tool position is compared in the artefact's
//! frame: the calibrated model's positions are carried by the rigid motion that best
//! takes its fitted sphere centres onto the true ones, as setting the work offsets by
//! probing the artefact would. "Before" is the nominal machine file with its own
//! centres, probed the same way (only the centres fitted).
#![allow(clippy::needless_range_loop)]

use super::fit::{fit, Fit};
use super::forward::{forward, predict};
use super::model::{Kind, Model};
use super::plan::{random_pose, Usable};
use super::sphere::{apply, rigid, rms_max_um, spheres_of, Probing, Sphere, Touch};
use super::sphere_plan::{Planned, Setup, SpherePlan};
use super::truth::{perturb, Rng};
use pkmc::config::MachineConfig;

/// The probe's noise of the study: 1 µm along the surface normal.
pub const NOISE: f64 = 0.001;

/// The study's artefact for a machine kind: three 25.4 mm balls (12.7 mm radius)
/// spread over the workspace, probed with a 3 mm tip (1.5 mm radius).
pub fn default_setup(model: &Model) -> Setup {
    let h = model.home;
    let ball = |x: f64, y: f64, z: f64| Sphere {
        centre: [x, y, z],
        radius: 12.7,
    };
    let spheres = match model.kind {
        Kind::H4 { .. } => vec![
            ball(-100.0, -80.0, h[2] - 60.0),
            ball(100.0, -80.0, h[2] - 60.0),
            ball(0.0, 90.0, h[2] - 40.0),
        ],
        Kind::Hexapod => vec![
            ball(-40.0, -35.0, h[2] - 15.0),
            ball(40.0, -35.0, h[2] - 15.0),
            ball(0.0, 45.0, h[2] - 5.0),
        ],
        Kind::HexapodXy { .. } => vec![
            ball(-50.0, -45.0, h[2] - 15.0),
            ball(50.0, -45.0, h[2] - 15.0),
            ball(0.0, 55.0, h[2] - 10.0),
        ],
    };
    Setup {
        spheres,
        tip: 1.5,
        standoff: 5.0,
        overtravel: 3.0,
        noise: NOISE,
    }
}

/// The true machine `truth` (its own parameters) probing `sphere` (true) along the
/// planned touch `t` of the nominal machine: the commanded line from the start in
/// along the normal, each point's joints by the nominal inverse kinematics, until the
/// true tool tip is at the tip's radius plus a Gaussian `noise` from the true surface.
/// The latched joints and internal pose, or `None` without contact.
pub fn touch(
    model: &Model,
    truth: &[f64],
    sphere: &Sphere,
    setup: &Setup,
    t: &Planned,
    rng: &mut Rng,
) -> Option<(Vec<f64>, Vec<f64>)> {
    let th = model.nominal();
    let target = sphere.radius + setup.tip + setup.noise * rng.normal();
    let at = |s: f64| -> Option<(f64, Vec<f64>, Vec<f64>)> {
        let (q, x) = model.inverse(&th, &t.along(setup.standoff - s))?;
        let xt = forward(model, truth, &q, &x)?;
        let y = model.measure(truth, &xt, &q);
        let d = (0..3)
            .map(|k| (y[k] - sphere.centre[k]).powi(2))
            .sum::<f64>();
        Some((d.sqrt() - target, q, x))
    };
    // Illinois regula falsi on the gap along the move.
    let (mut a, mut b) = (0.0, setup.standoff + setup.overtravel);
    let (mut fa, mut fb) = (at(a)?.0, at(b)?.0);
    if fa <= 0.0 || fb > 0.0 {
        return None;
    }
    let mut side = 0;
    for _ in 0..100 {
        let s = (a * fb - b * fa) / (fb - fa);
        let (f, q, x) = at(s)?;
        if f.abs() < 1e-10 || (b - a).abs() < 1e-12 {
            return Some((q, x));
        }
        if f > 0.0 {
            (a, fa) = (s, f);
            if side == 1 {
                fb *= 0.5;
            }
            side = 1;
        } else {
            (b, fb) = (s, f);
            if side == -1 {
                fa *= 0.5;
            }
            side = -1;
        }
    }
    None
}

/// The outcome of one seed.
#[derive(Clone, Debug)]
pub struct Outcome {
    /// The fit (over the machine's parameters and the centres).
    pub fit: Fit,
    /// The touches' distance from the surface, RMS and max µm: nominal machine with
    /// its fitted centres, then calibrated.
    pub residuals: [(f64, f64); 2],
    /// Tool position error at the test poses in the artefact's frame, RMS and max µm:
    /// before, after.
    pub errors: [(f64, f64); 2],
    /// The calibrated model's error, RMS and max µm, after the rigid motion that best
    /// carries its positions at the test poses onto the true ones (what the fit
    /// identified, whatever fixes the artefact's frame: with one or two spheres their
    /// centres do not fix its rotation).
    pub errors_any_frame: (f64, f64),
}

/// The true balls: `spheres` with each centre off by up to ±1 mm per coordinate.
pub fn displaced(spheres: &[Sphere], rng: &mut Rng) -> Vec<Sphere> {
    spheres
        .iter()
        .map(|s| Sphere {
            centre: s.centre.map(|c| c + rng.range(-1.0, 1.0)),
            radius: s.radius,
        })
        .collect()
}

fn centres(f: &Fit, machine: usize, setup: &Setup) -> Vec<[f64; 3]> {
    let radii: Vec<f64> = setup.spheres.iter().map(|s| s.radius).collect();
    let s = spheres_of(&f.theta, machine, &radii);
    s.iter().map(|s| s.centre).collect()
}

/// Runs seed `seed` on the plan `p` with `tests` random test poses.
pub fn run(
    config: &MachineConfig,
    model: &Model,
    setup: &Setup,
    p: &SpherePlan,
    seed: u64,
    tests: usize,
) -> Result<Outcome, String> {
    let m = model.params.len();
    let truth = perturb(model, seed);
    let mut rng = Rng::new(seed.wrapping_mul(6007).wrapping_add(11));
    let true_spheres = displaced(&setup.spheres, &mut rng);
    let mut touches = Vec::new();
    for (i, t) in p.touches.iter().enumerate() {
        let (q, x) = touch(model, &truth, &true_spheres[t.sphere], setup, t, &mut rng)
            .ok_or(format!("seed {seed}: touch {} finds no contact", i + 1))?;
        touches.push(Touch {
            q,
            sphere: t.sphere,
            approach: Some(t.normal.map(|v| -v)),
            guess: x,
        });
    }
    let mut data = Probing {
        touches,
        radii: setup.spheres.iter().map(|s| s.radius).collect(),
        tip: setup.tip,
        noise: setup.noise,
        machine_params: m,
    };
    assess(
        config,
        model,
        &p.model,
        setup,
        &mut data,
        &truth,
        &true_spheres,
        seed,
        tests,
    )
}

/// Fits the touches `data` with the model `ext` (the machine's and the spheres'
/// centres) twice, the machine held at its nominal file (before) and free (after),
/// and compares both with the true machine `truth` and its balls `true_spheres` at
/// `tests` random usable test poses of seed `seed`.
#[allow(clippy::too_many_arguments)]
pub fn assess(
    config: &MachineConfig,
    model: &Model,
    ext: &Model,
    setup: &Setup,
    data: &mut Probing,
    truth: &[f64],
    true_spheres: &[Sphere],
    seed: u64,
    tests: usize,
) -> Result<Outcome, String> {
    let m = model.params.len();
    let all_machine: Vec<usize> = (0..m).collect();
    let before = fit(ext, data, 1e-6, &all_machine)?;
    let res_before = rms_max_um(&data.gaps(ext, &before.theta).ok_or("lost a touch")?);
    let after = fit(ext, data, 1e-6, &[])?;
    let res_after = rms_max_um(&data.gaps(ext, &after.theta).ok_or("lost a touch")?);
    let truth_c: Vec<[f64; 3]> = true_spheres.iter().map(|s| s.centre).collect();
    let frames = [&before, &after].map(|f| rigid(&centres(f, m, setup), &truth_c));
    let usable = Usable::new(config);
    let mut test_rng = Rng::new(seed ^ 0x7e57);
    let mut errs: [Vec<f64>; 2] = [Vec::new(), Vec::new()];
    let (mut raw, mut real) = (Vec::new(), Vec::new());
    while errs[0].len() < tests {
        let (_, q, x) = random_pose(model, &usable, &mut test_rng).ok_or("no usable test pose")?;
        let Some((t, _)) = predict(model, truth, &q, &x) else {
            continue;
        };
        let models = [&before.theta[..m], &after.theta[..m]];
        let mut e = [0.0; 2];
        for (i, th) in models.iter().enumerate() {
            let (y, _) = predict(model, th, &q, &x).ok_or("the model misses a test pose")?;
            if i == 1 {
                raw.push([y[0], y[1], y[2]]);
                real.push([t[0], t[1], t[2]]);
            }
            let (r, tr) = &frames[i];
            let y = apply(r, *tr, [y[0], y[1], y[2]]);
            e[i] = (0..3).map(|k| (y[k] - t[k]).powi(2)).sum::<f64>().sqrt();
        }
        errs[0].push(e[0]);
        errs[1].push(e[1]);
    }
    let (r, tr) = rigid(&raw, &real);
    let any: Vec<f64> = raw
        .iter()
        .zip(&real)
        .map(|(a, b)| {
            let a = apply(&r, tr, *a);
            (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt()
        })
        .collect();
    Ok(Outcome {
        fit: after,
        residuals: [res_before, res_after],
        errors: [rms_max_um(&errs[0]), rms_max_um(&errs[1])],
        errors_any_frame: rms_max_um(&any),
    })
}
