//! The fit: which parameters the data can identify, Levenberg–Marquardt on those,
//! their covariance, and the residuals before and after.
//!
//! The residual is a trait ([`Residual`]): [`PoseMeasurements`] compares measured tool
//! poses with the model's; [`super::sphere::Probing`] asks every probed point to lie on
//! its sphere.
#![allow(clippy::needless_range_loop)]

use super::forward::{forward, measure_jacobian};
use super::model::Model;
use crate::control::linalg::{at_r, chol_inverse, gram, solve_vec, svd, Mat};

/// A source of whitened residuals (measured − model, each divided by its noise).
pub trait Residual {
    /// The residuals at parameters `th` and, when `jacobian`, their model's
    /// derivatives (rows as the residuals, a column per parameter, divided by the same
    /// noise); `None` where the model cannot be evaluated (a pose out of reach).
    fn evaluate(&mut self, model: &Model, th: &[f64], jacobian: bool) -> Option<(Vec<f64>, Mat)>;
}

/// Standard deviations of the measurement, mm and degrees.
#[derive(Clone, Copy, Debug)]
pub struct Noise {
    /// Position, mm per coordinate.
    pub position: f64,
    /// Orientation, degrees per angle.
    pub angle: f64,
}

/// One measured pose: the joints commanded and the tool pose measured there.
#[derive(Clone, Debug)]
pub struct Sample {
    /// Joints, mm or degrees.
    pub q: Vec<f64>,
    /// The measured axes ([`Model::measured_axes`]), mm and degrees.
    pub measured: Vec<f64>,
    /// Where forward kinematics starts (the last solution).
    pub guess: Vec<f64>,
}

/// Measured tool poses against the model's.
pub struct PoseMeasurements {
    /// The samples.
    pub samples: Vec<Sample>,
    /// Their noise.
    pub noise: Noise,
}

impl Residual for PoseMeasurements {
    fn evaluate(&mut self, model: &Model, th: &[f64], jacobian: bool) -> Option<(Vec<f64>, Mat)> {
        let (mut r, mut jac) = (Vec::new(), Vec::new());
        for s in &mut self.samples {
            let x = forward(model, th, &s.q, &s.guess)?;
            s.guess.clone_from(&x);
            let y = if jacobian {
                let (y, j) = measure_jacobian(model, th, &s.q, &x)?;
                for (k, row) in j.into_iter().enumerate() {
                    let w = 1.0 / sigma(self.noise, k);
                    jac.push(row.into_iter().map(|v| v * w).collect());
                }
                y
            } else {
                model.measure(th, &x, &s.q)
            };
            for k in 0..y.len() {
                r.push((s.measured[k] - y[k]) / sigma(self.noise, k));
            }
        }
        Some((r, jac))
    }
}

fn sigma(n: Noise, k: usize) -> f64 {
    if k < 3 {
        n.position
    } else {
        n.angle
    }
}

/// Tool pose errors over a set of poses.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Errors {
    /// RMS of the position error's length, mm.
    pub pos_rms: f64,
    /// Largest position error, mm.
    pub pos_max: f64,
    /// RMS of the orientation error (the angles' differences as a vector), degrees.
    pub ang_rms: f64,
    /// Largest orientation error, degrees.
    pub ang_max: f64,
}

impl Errors {
    /// The errors of `pairs` (model, reference) of measured-axis vectors.
    pub fn of<'a>(pairs: impl Iterator<Item = (&'a [f64], &'a [f64])>) -> Errors {
        let (mut e, mut n) = (Errors::default(), 0usize);
        for (a, b) in pairs {
            let d2 = |r: std::ops::Range<usize>| r.map(|k| (a[k] - b[k]).powi(2)).sum::<f64>();
            let (p2, o2) = (d2(0..3), d2(3..a.len()));
            e.pos_rms += p2;
            e.ang_rms += o2;
            e.pos_max = e.pos_max.max(p2.sqrt());
            e.ang_max = e.ang_max.max(o2.sqrt());
            n += 1;
        }
        e.pos_rms = (e.pos_rms / n.max(1) as f64).sqrt();
        e.ang_rms = (e.ang_rms / n.max(1) as f64).sqrt();
        e
    }
}

/// What the data can identify, at the nominal parameters.
#[derive(Clone, Debug)]
pub struct Identifiability {
    /// Singular values of the Jacobian, each column scaled by its parameter's
    /// [`super::model::Param::scale`], descending.
    pub singular: Vec<f64>,
    /// Numerical rank (singular values above `tolerance` × the largest).
    pub rank: usize,
    /// Parameters held at their nominal value, one per unidentifiable combination.
    pub held: Vec<usize>,
    /// Parameters fitted.
    pub free: Vec<usize>,
    /// Each unidentifiable combination: (held parameter, [(other parameter, its
    /// change per unit change of the held one)]): moving them together changes no
    /// measurement.
    pub combinations: Vec<(usize, Vec<(usize, f64)>)>,
    /// Condition number of the scaled Jacobian of the free parameters.
    pub condition: f64,
}

/// The rank, the parameters to hold and the condition number from the whitened
/// Jacobian `jac` (a column per parameter); the parameters `requested` are held
/// whatever the data say.
pub fn identifiability(
    model: &Model,
    jac: &Mat,
    tolerance: f64,
    requested: &[usize],
) -> Identifiability {
    let p = model.params.len();
    let scaled: Mat = jac
        .iter()
        .map(|row| {
            (0..p)
                .map(|j| {
                    if requested.contains(&j) {
                        0.0
                    } else {
                        row[j] * model.params[j].scale
                    }
                })
                .collect()
        })
        .collect();
    let (singular, v) = svd(&scaled, p);
    let rank = singular
        .iter()
        .filter(|s| **s > tolerance * singular[0])
        .count();
    let null: Mat = v[rank..].to_vec();
    // Pivoted Gram–Schmidt over the null space's columns: hold the parameter that
    // moves most in the remaining unidentifiable directions (preferring those marked
    // `hold_first`), then remove its direction.
    let mut cols: Mat = (0..p)
        .map(|j| null.iter().map(|n| n[j]).collect())
        .collect();
    let mut held = Vec::new();
    for k in 0..null.len() {
        let weight = |j: usize| match &model.params[j] {
            p if p.hold_first => 1.5,
            p if p.hold_last => 0.1,
            _ => 1.0,
        };
        let forced = requested.get(k).copied();
        let norm = |c: &Vec<f64>| c.iter().map(|x| x * x).sum::<f64>().sqrt();
        let best = (0..p)
            .filter(|j| !held.contains(j))
            .max_by(|&a, &b| (weight(a) * norm(&cols[a])).total_cmp(&(weight(b) * norm(&cols[b]))))
            .unwrap_or(0);
        let best = forced.unwrap_or(best);
        let n = norm(&cols[best]).max(1e-300);
        let unit: Vec<f64> = cols[best].iter().map(|x| x / n).collect();
        for c in cols.iter_mut() {
            let dot: f64 = c.iter().zip(&unit).map(|(a, b)| a * b).sum();
            for (a, b) in c.iter_mut().zip(&unit) {
                *a -= dot * b;
            }
        }
        held.push(best);
    }
    held.sort_unstable();
    let combinations = combinations(model, &null, &held);
    let free: Vec<usize> = (0..p).filter(|j| !held.contains(j)).collect();
    let reduced: Mat = scaled
        .iter()
        .map(|row| free.iter().map(|&j| row[j]).collect())
        .collect();
    let (s, _) = svd(&reduced, free.len());
    let condition = s[0] / s[s.len() - 1];
    Identifiability {
        singular,
        rank,
        held,
        free,
        combinations,
        condition,
    }
}

/// The null space written with one held parameter per combination at unit change.
fn combinations(model: &Model, null: &Mat, held: &[usize]) -> Vec<(usize, Vec<(usize, f64)>)> {
    let k = held.len();
    let p = model.params.len();
    // Solve N_Fᵀ·E = N for the basis E whose held entries are the identity.
    let nf: Mat = (0..k)
        .map(|r| held.iter().map(|&h| null[r][h]).collect())
        .collect();
    let nft: Mat = (0..k).map(|i| (0..k).map(|r| nf[r][i]).collect()).collect();
    let mut out = Vec::new();
    for (i, &h) in held.iter().enumerate() {
        let e: Vec<f64> = (0..k).map(|r| f64::from(u8::from(r == i))).collect();
        // Coefficients c with Σ_r c_r·N_r = the basis vector of `h`.
        let Some(c) = solve_vec(nft.clone(), e) else {
            continue;
        };
        let others = (0..p)
            .filter(|&j| j != h && !held.contains(&j))
            .filter_map(|j| {
                // Scaled units back to parameter units.
                let v: f64 = (0..k).map(|r| c[r] * null[r][j]).sum::<f64>();
                let v = v * model.params[j].scale / model.params[h].scale;
                (v.abs() > 1e-3).then_some((j, v))
            })
            .collect();
        out.push((h, others));
    }
    out
}

/// The result of a fit.
#[derive(Clone, Debug)]
pub struct Fit {
    /// The identifiability analysis at the nominal parameters.
    pub ident: Identifiability,
    /// Fitted parameters (held ones at nominal).
    pub theta: Vec<f64>,
    /// 1σ uncertainty of each parameter (0 for a held one), from the covariance
    /// scaled by `s2`.
    pub sigma: Vec<f64>,
    /// Reduced χ² of the whitened residuals (1 when the noise is as stated).
    pub s2: f64,
    /// Levenberg–Marquardt iterations.
    pub iterations: usize,
}

/// Fits `model`'s parameters to `data` from the nominal values: identifiability at
/// the nominal parameters with `tolerance` (relative singular value), the parameters
/// `requested` held too, then Levenberg–Marquardt on the free parameters.
pub fn fit(
    model: &Model,
    data: &mut dyn Residual,
    tolerance: f64,
    requested: &[usize],
) -> Result<Fit, String> {
    let mut th = model.nominal();
    let (mut r, jac) = data
        .evaluate(model, &th, true)
        .ok_or("a measured pose is out of reach of the nominal machine")?;
    let ident = identifiability(model, &jac, tolerance, requested);
    let free = ident.free.clone();
    let nf = free.len();
    if r.len() <= nf {
        return Err(format!(
            "{} measurements for {nf} parameters: measure more poses",
            r.len()
        ));
    }
    let cost = |r: &[f64]| r.iter().map(|v| v * v).sum::<f64>();
    let reduce = |j: &Mat| -> Mat {
        j.iter()
            .map(|row| free.iter().map(|&c| row[c]).collect())
            .collect()
    };
    let mut jf = reduce(&jac);
    let (mut c, mut lambda, mut iterations) = (cost(&r), 1e-3, 0);
    while iterations < 100 {
        iterations += 1;
        let a = gram(&jf, nf);
        let g = at_r(&jf, &r, nf);
        let mut damped = a.clone();
        for i in 0..nf {
            damped[i][i] += lambda * a[i][i].max(1e-12);
        }
        let Some(step) = solve_vec(damped, g) else {
            lambda *= 10.0;
            continue;
        };
        let mut trial = th.clone();
        for (i, &j) in free.iter().enumerate() {
            trial[j] += step[i];
        }
        match data.evaluate(model, &trial, false) {
            Some((rt, _)) if cost(&rt) < c => {
                let gain = (c - cost(&rt)) / c;
                th = trial;
                c = cost(&rt);
                lambda = (lambda / 10.0).max(1e-12);
                let (rn, jn) = data.evaluate(model, &th, true).ok_or("lost a pose")?;
                r = rn;
                jf = reduce(&jn);
                if gain < 1e-12 {
                    break;
                }
            }
            _ => {
                lambda *= 10.0;
                if lambda > 1e12 {
                    break;
                }
            }
        }
    }
    let s2 = c / (r.len() - nf) as f64;
    let (_, cov) = chol_inverse(&gram(&jf, nf)).ok_or("the normal matrix is singular")?;
    let mut sigma = vec![0.0; th.len()];
    for (i, &j) in free.iter().enumerate() {
        sigma[j] = (cov[i][i] * s2).sqrt();
    }
    Ok(Fit {
        ident,
        theta: th,
        sigma,
        s2,
        iterations,
    })
}
