//! A simulated "true" machine: the nominal geometry with every parameter perturbed by
//! a seeded random amount, measured with stated noise. Used by the tests and by
//! `nc-send calibrate simulate` (the worked example in docs/calibration.md).

use super::fit::{Fit, Noise, Sample};
use super::forward::predict;
use super::model::Model;
use pkmc::config::MachineConfig;

/// A seeded generator (SplitMix64): the same seed gives the same machine anywhere.
pub struct Rng(u64);

impl Rng {
    /// The generator of `seed`.
    pub fn new(seed: u64) -> Rng {
        Rng(seed ^ 0x5eed_ca11_b7a7_e000)
    }

    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in [lo, hi).
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.uniform()
    }

    /// Standard normal (Box–Muller).
    pub fn normal(&mut self) -> f64 {
        let u = 1.0 - self.uniform();
        let v = self.uniform();
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

/// The true parameters of seed `seed`: each nominal value moved by a uniform amount
/// within ± its scale (0.5 mm for a length or coordinate, 0.3° for a rotary joint's
/// zero).
pub fn perturb(model: &Model, seed: u64) -> Vec<f64> {
    let mut rng = Rng::new(seed);
    model
        .params
        .iter()
        .map(|p| p.value + rng.range(-p.scale, p.scale))
        .collect()
}

/// A measured pose: the true machine at joints `q` (the nominal machine's for the
/// commanded pose), plus Gaussian noise; `None` if the true machine cannot get there.
pub fn measure(
    model: &Model,
    truth: &[f64],
    q: &[f64],
    guess: &[f64],
    noise: Noise,
    rng: &mut Rng,
) -> Option<Sample> {
    let (y, x) = predict(model, truth, q, guess)?;
    let measured = y
        .iter()
        .enumerate()
        .map(|(k, v)| v + rng.normal() * if k < 3 { noise.position } else { noise.angle })
        .collect();
    Some(Sample {
        q: q.to_vec(),
        measured,
        guess: x,
    })
}

/// The true parameters as the fit can know them: each held parameter moved back to
/// its nominal value along its unidentifiable combination (the others move with it),
/// so that the identified parameters can be compared with it.
pub fn equivalent(model: &Model, truth: &[f64], fit: &Fit) -> Vec<f64> {
    let mut eq = truth.to_vec();
    for (h, others) in &fit.ident.combinations {
        let delta = model.params[*h].value - truth[*h];
        eq[*h] += delta;
        for (j, v) in others {
            eq[*j] += delta * v;
        }
    }
    eq
}

/// The tool point of a machine with parameters `th`: from its joints (mm or degrees)
/// and a pose near it (mm, degrees) as the first guess, the measured tool point in mm
/// (`None` where forward kinematics finds no pose). Each answer is the next call's
/// starting point.
pub fn tool_point_of(
    model: Model,
    th: Vec<f64>,
) -> impl FnMut(&[f64], &[f64; 6]) -> Option<[f64; 3]> + Send {
    let mut last: Option<Vec<f64>> = None;
    move |q, pose| {
        let start = last
            .take()
            .or_else(|| model.inverse(&th, pose).map(|(_, x)| x))?;
        let (y, x) = predict(&model, &th, q, &start)?;
        last = Some(x);
        Some([y[0], y[1], y[2]])
    }
}

/// The true machine of `seed` for `machine`'s file ([`perturb`]) as a tool point
/// ([`tool_point_of`]): what the simulator's probe sees with `--probe-truth-seed`.
/// A Cartesian machine has no calibration model: an error.
#[allow(clippy::type_complexity)]
pub fn tool_point(
    machine: &MachineConfig,
    seed: u64,
) -> Result<Box<dyn FnMut(&[f64], &[f64; 6]) -> Option<[f64; 3]> + Send>, String> {
    let model = Model::from_config(machine).ok_or_else(|| {
        format!(
            "--probe-truth-seed {seed}: machine `{}` is Cartesian; only a parallel machine's \
             geometry is perturbed",
            machine.name
        )
    })?;
    let th = perturb(&model, seed);
    Ok(Box::new(tool_point_of(model, th)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use pkmc::config::{AXES, MAX_JOINTS};
    use pkmc::kinematics::{Kinematics, MachineKinematics};
    use pkmc::units::units_per_user;

    fn load(name: &str) -> MachineConfig {
        let path = format!(
            "{}/../examples/machines/{name}.toml",
            env!("CARGO_MANIFEST_DIR")
        );
        crate::machine_file::load(std::path::Path::new(&path)).unwrap()
    }

    /// With its parameters at their nominal values, the model's tool point is the
    /// controller's own pose, on every parallel machine kind; a seed moves it by tenths
    /// of a millimetre.
    #[test]
    fn the_tool_point_at_nominal_is_the_controllers_kinematics() {
        for (name, d) in [
            ("h4-table", [20.0, -15.0, -60.0, 25.0, 0.0, 10.0]),
            ("hexapod", [15.0, -10.0, 0.0, 4.0, -3.0, 6.0]),
            ("hexapod-xy", [10.0, -12.0, 5.0, 3.0, -2.0, 0.0]),
        ] {
            let m = load(name);
            let unit = |i: usize| units_per_user(i >= 3) as f64;
            let pose: [i64; AXES] =
                std::array::from_fn(|i| (m.home[i] as f64 + d[i] * unit(i)).round() as i64);
            let mut q = [0i64; MAX_JOINTS];
            MachineKinematics::new(&m).inverse(&pose, &mut q).unwrap();
            let qf: Vec<f64> = m
                .joints
                .iter()
                .enumerate()
                .map(|(j, jc)| q[j] as f64 / units_per_user(jc.rotary) as f64)
                .collect();
            let guess = std::array::from_fn(|i| pose[i] as f64 / unit(i));
            let model = Model::from_config(&m).unwrap();
            let th = model.nominal();
            let mut at = tool_point_of(model, th);
            let a = at(&qf, &guess).unwrap();
            for k in 0..3 {
                assert!(
                    (a[k] - pose[k] as f64 / 1e6).abs() < 1e-4,
                    "{name}: {a:?} against {pose:?}"
                );
            }
            // The same joints a second time start from the last answer.
            let again = at(&qf, &guess).unwrap();
            assert!((0..3).all(|k| (again[k] - a[k]).abs() < 1e-9), "{again:?}");
            let b = tool_point(&m, 3).unwrap()(&qf, &guess).unwrap();
            let off = (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt();
            assert!(off > 0.01 && off < 5.0, "{name}: seed 3 is {off} mm off");
        }
        let e = tool_point(&MachineConfig::cartesian_xyz(), 3)
            .err()
            .unwrap();
        assert!(e.contains("is Cartesian"), "{e}");
    }
}
