//! The simulated-truth study behind the tests and docs/calibration.md's table: a true
//! machine per seed, measured at a plan's poses with noise, fitted, and compared with
//! the truth at random test poses not used in the fit.

use super::fit::{fit, Errors, Fit, Noise, PoseMeasurements, Sample};
use super::forward::predict;
use super::model::Model;
use super::plan::{random_pose, Usable};
use super::truth::{equivalent, measure, perturb, Rng};
use pkmc::config::MachineConfig;

/// The noise of the study: 10 µm per coordinate; 1 mdeg per angle (17 µrad: 10 µm
/// across a 570 mm target, a laser tracker's 6-DOF probe).
pub const NOISE: Noise = Noise {
    position: 0.010,
    angle: 0.001,
};

/// The outcome of one seed.
#[derive(Clone, Debug)]
pub struct Outcome {
    /// The fit.
    pub fit: Fit,
    /// Tool pose errors at the test poses with the nominal parameters.
    pub before: Errors,
    /// The same with the fitted parameters.
    pub after: Errors,
    /// Largest |fitted − true| / σ over the identified parameters (the truth as the fit
    /// can know it, [`equivalent`]).
    pub worst_z: f64,
    /// Identified parameters farther than 3σ from the truth.
    pub beyond_3sigma: Vec<String>,
    /// (fitted − true) / σ of each identified parameter.
    pub z: Vec<f64>,
}

/// Runs seed `seed` with measurements at `poses` (nominal joints `joints`) and
/// `tests` random test poses.
pub fn run(
    config: &MachineConfig,
    model: &Model,
    joints: &[Vec<f64>],
    seed: u64,
    tests: usize,
) -> Result<Outcome, String> {
    let truth = perturb(model, seed);
    let th = model.nominal();
    let mut rng = Rng::new(seed.wrapping_mul(7919).wrapping_add(1));
    let mut samples = Vec::new();
    for q in joints {
        let guess = super::forward::forward(
            model,
            &th,
            q,
            &model.inverse(&th, &model.home).ok_or("home")?.1,
        )
        .ok_or("a planned pose has no forward kinematics")?;
        samples.push(
            measure(model, &truth, q, &guess, NOISE, &mut rng)
                .ok_or("the true machine misses a pose")?,
        );
    }
    let mut data = PoseMeasurements {
        samples,
        noise: NOISE,
    };
    let fitted = fit(model, &mut data, 1e-6, &[])?;
    // Test poses: the nominal joints of random usable poses, their true tool poses.
    let usable = Usable::new(config);
    let mut test_rng = Rng::new(seed ^ 0x7e57);
    let mut truths: Vec<(Vec<f64>, Vec<f64>)> = Vec::new();
    let (mut nominal, mut calibrated) = (Vec::new(), Vec::new());
    while truths.len() < tests {
        let (_, q, x) = random_pose(model, &usable, &mut test_rng).ok_or("no usable test pose")?;
        let (Some(t), Some(c)) = (
            predict(model, &truth, &q, &x),
            predict(model, &fitted.theta, &q, &x),
        ) else {
            continue;
        };
        let n = predict(model, &th, &q, &x).ok_or("nominal forward")?;
        truths.push((t.0, q));
        nominal.push(n.0);
        calibrated.push(c.0);
    }
    let before = Errors::of(
        nominal
            .iter()
            .zip(&truths)
            .map(|(a, b)| (a.as_slice(), b.0.as_slice())),
    );
    let after = Errors::of(
        calibrated
            .iter()
            .zip(&truths)
            .map(|(a, b)| (a.as_slice(), b.0.as_slice())),
    );
    let eq = equivalent(model, &truth, &fitted);
    let mut worst_z = 0.0f64;
    let mut beyond_3sigma = Vec::new();
    let mut zs = Vec::new();
    for &j in &fitted.ident.free {
        zs.push((fitted.theta[j] - eq[j]) / fitted.sigma[j]);
        let z = (fitted.theta[j] - eq[j]).abs() / fitted.sigma[j];
        worst_z = worst_z.max(z);
        if z > 3.0 {
            beyond_3sigma.push(format!("{} ({z:.2}σ)", model.params[j].name));
        }
    }
    Ok(Outcome {
        fit: fitted,
        before,
        after,
        worst_z,
        beyond_3sigma,
        z: zs,
    })
}

/// Samples of a fit's data as errors: model at `th` against the measurements.
pub fn residuals(model: &Model, th: &[f64], samples: &[Sample]) -> Option<Errors> {
    let mut pred = Vec::new();
    for s in samples {
        pred.push(predict(model, th, &s.q, &s.guess)?.0);
    }
    Some(Errors::of(
        pred.iter()
            .zip(samples)
            .map(|(p, s)| (p.as_slice(), s.measured.as_slice())),
    ))
}
