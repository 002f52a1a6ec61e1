//! A simulated "true" machine: the nominal geometry with every parameter perturbed by
//! a seeded random amount, measured with stated noise. Used by the tests and by
//! `nc-send calibrate simulate` (the worked example in docs/calibration.md).

use super::fit::{Fit, Noise, Sample};
use super::forward::predict;
use super::model::Model;

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
