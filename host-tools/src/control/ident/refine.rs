//! Output-error refinement at the servo rate (see [`refine`]).
//!
//! Why: the block model (decimated, filtered data) assumes that the filtered input
//! holds no energy above the block rate's Nyquist frequency. Under the core's loop
//! the test signal's edges do not respect that: the interpolator turns each PRBS
//! edge into one tick of velocity and acceleration feed-forward, and kaff times
//! that tick's acceleration saturates the DAC for a tick each way (a doublet of
//! ±full scale, some 50 dB above the rest of the input). What of that doublet
//! passes the block filter aliases, and the least-squares fit gives it the
//! plant's slow part to explain: the H-4's default plant came out with its pole at
//! 41 rad/s instead of 50 and its velocity gain 3 % high. Simulating the model at
//! the servo rate from the recorded input itself, held over each period as the DAC
//! holds it, needs no assumption on the input's spectrum: that is what this module
//! fits.
//!
//! * **Model.** y = N(s)/D(s)·u (zero-order hold at the record's period) + a
//!   constant load through 1/D + D's free response from an unknown initial state.
//!   D is monic, its poles those of the block model to start with; N has degree
//!   deg D − 1. The integrator the block model imposes is freed here (a real pole
//!   started at 0.01 rad/s): on the servo-rate positions of the whole record a slow
//!   pole shows, and report B's table X came out with its pole at 0.0171 rad/s
//!   (the plant's 0.0171) where an imposed integrator had moved the velocity gain
//!   and kvff by 0.1 to 1 %. A true integrator stays within 10⁻⁵ rad/s of s = 0.
//! * **Separable least squares** (Golub and Pereyra's variable projection): for a
//!   given D the output is linear in N's coefficients, the load and the initial
//!   state. D's canonical state (w, ẇ, …, w⁽ⁿ⁻¹⁾ with D(s)·w = u) simulated once
//!   gives N's columns; the load's and the free responses' columns come the same
//!   way. Only D's poles are iterated: Levenberg–Marquardt on ln(−p) of each real
//!   pole and (ln ω, ln ζ) of each complex pair, so that every step stays stable.
//! * **Weighting.** Every sample's position error counts alike: the encoder's
//!   quantisation and noise are white at the servo rate, and the position holds
//!   the low frequencies (the velocity gain, kvff) that a fit of block-to-block
//!   changes weights least.

use super::Record;
use crate::control::plant::{expm, polymul, roots, TransferFunction};

/// Where the freed integrator's pole starts, rad/s.
const SLOW_POLE_START: f64 = 1e-2;

/// Levenberg–Marquardt iterations at most.
const ITERATIONS: usize = 40;

/// D's poles as iterated parameters.
#[derive(Clone, Debug)]
struct Poles {
    /// ln(−p) of each stable real pole.
    real: Vec<f64>,
    /// (ln ω, ln ζ) of each complex pair.
    pairs: Vec<(f64, f64)>,
    /// A pole at s = 0, imposed.
    integrator: bool,
}

impl Poles {
    fn of(den: &[f64], integrator: bool) -> Option<Self> {
        let mut p = Self {
            real: Vec::new(),
            pairs: Vec::new(),
            integrator,
        };
        let mut den = den.to_vec();
        if integrator {
            // Take the imposed s factor off.
            if den.last().copied() != Some(0.0) {
                return None;
            }
            den.pop();
        }
        if den.len() > 1 {
            for r in roots(&den) {
                if r.im == 0.0 {
                    if r.re >= 0.0 {
                        return None;
                    }
                    p.real.push((-r.re).ln());
                } else if r.im > 0.0 {
                    let w = r.abs();
                    let zeta = -r.re / w;
                    if zeta <= 0.0 {
                        return None;
                    }
                    p.pairs.push((w.ln(), zeta.ln()));
                }
            }
        }
        Some(p)
    }

    fn params(&self) -> Vec<f64> {
        let mut v = self.real.clone();
        for (a, b) in &self.pairs {
            v.push(*a);
            v.push(*b);
        }
        v
    }

    fn with(&self, v: &[f64]) -> Self {
        let n = self.real.len();
        Self {
            real: v[..n].to_vec(),
            pairs: v[n..].chunks(2).map(|c| (c[0], c[1])).collect(),
            integrator: self.integrator,
        }
    }

    /// D(s), monic, highest power first.
    fn den(&self) -> Vec<f64> {
        let mut d = vec![1.0];
        for r in &self.real {
            d = polymul(&d, &[1.0, r.exp()]);
        }
        for (lw, lz) in &self.pairs {
            let w = lw.exp();
            d = polymul(&d, &[1.0, 2.0 * lz.exp() * w, w * w]);
        }
        if self.integrator {
            d = polymul(&d, &[1.0, 0.0]);
        }
        d
    }
}

/// The canonical state of 1/D(s) (x₁ = w, …, xₙ = w⁽ⁿ⁻¹⁾), discretised with a hold.
struct Canonical {
    phi: Vec<Vec<f64>>,
    gamma: Vec<f64>,
}

impl Canonical {
    fn new(den: &[f64], h: f64) -> Self {
        let n = den.len() - 1;
        let mut aug = vec![vec![0.0; n + 1]; n + 1];
        for (i, row) in aug.iter_mut().enumerate().take(n - 1) {
            row[i + 1] = h;
        }
        for j in 0..n {
            aug[n - 1][j] = -den[n - j] * h;
        }
        aug[n - 1][n] = h;
        let e = expm(&aug);
        Self {
            phi: (0..n).map(|i| e[i][..n].to_vec()).collect(),
            gamma: (0..n).map(|i| e[i][n]).collect(),
        }
    }

    /// The state at the start of each period from `x0`, under the inputs `u`.
    fn run(&self, x0: &[f64], u: &dyn Fn(usize) -> f64, len: usize) -> Vec<Vec<f64>> {
        let mut x = x0.to_vec();
        let mut out = Vec::with_capacity(len);
        for k in 0..len {
            out.push(x.clone());
            let uk = u(k);
            x = self
                .phi
                .iter()
                .zip(&self.gamma)
                .map(|(row, g)| row.iter().zip(&x).map(|(p, x)| p * x).sum::<f64>() + g * uk)
                .collect();
        }
        out
    }
}

/// For the poles `p`: the numerator (highest power first) and the residual of the
/// separable least-squares fit on `rec`, or `None` if it fails.
fn project(rec: &Record, p: &Poles) -> Option<(Vec<f64>, Vec<f64>)> {
    let den = p.den();
    let n = den.len() - 1;
    let len = rec.y.len();
    let c = Canonical::new(&den, rec.h);
    let zero = vec![0.0; n];
    let forced = c.run(&zero, &|k| rec.u[k], len);
    let load = c.run(&zero, &|_| 1.0, len);
    let free: Vec<Vec<Vec<f64>>> = (0..n)
        .map(|j| {
            let mut e = zero.clone();
            e[j] = 1.0;
            c.run(&e, &|_| 0.0, len)
        })
        .collect();
    let rows: Vec<Vec<f64>> = (0..len)
        .map(|k| {
            let mut row = forced[k].clone();
            row.push(load[k][0]);
            row.extend(free.iter().map(|f| f[k][0]));
            row
        })
        .collect();
    let theta = super::lstsq(rows.clone(), rec.y.clone())?;
    let residual = rows
        .iter()
        .zip(&rec.y)
        .map(|(r, y)| y - r.iter().zip(&theta).map(|(a, b)| a * b).sum::<f64>())
        .collect();
    // θ's first n entries weigh s⁰ … sⁿ⁻¹.
    let num: Vec<f64> = theta[..n].iter().rev().copied().collect();
    Some((num, residual))
}

fn cost(r: &[f64]) -> f64 {
    r.iter().map(|v| v * v).sum()
}

/// The output-error model of `rec` started from `start` (whose denominator gives the
/// poles; `integrating`: its pole at s = 0 is kept there), with its residual's sum of
/// squares; `None` if `start` has a pole this parametrisation cannot hold or the fit
/// fails. Never worse than the start's poles with their best numerator.
pub(super) fn refine(
    rec: &Record,
    start: &TransferFunction,
    integrating: bool,
) -> Option<(TransferFunction, f64)> {
    let lead = start.den[0];
    let den: Vec<f64> = start.den.iter().map(|c| c / lead).collect();
    let mut poles = Poles::of(&den, integrating)?;
    if integrating {
        // The block model's integrator, freed: started at 0.01 rad/s.
        poles.integrator = false;
        poles.real.push(SLOW_POLE_START.ln());
    }
    let (mut num, mut res) = project(rec, &poles)?;
    let mut theta = poles.params();
    let mut best = cost(&res);
    let mut lambda = 1e-3;
    for _ in 0..ITERATIONS {
        if theta.is_empty() {
            break;
        }
        // Forward-difference Jacobian of the residual.
        let step = 1e-6;
        let mut jac = Vec::with_capacity(theta.len());
        for i in 0..theta.len() {
            let mut t = theta.clone();
            t[i] += step;
            let (_, r) = project(rec, &poles.with(&t))?;
            jac.push(
                r.iter()
                    .zip(&res)
                    .map(|(a, b)| (a - b) / step)
                    .collect::<Vec<f64>>(),
            );
        }
        let m = theta.len();
        let mut jtj = vec![vec![0.0; m]; m];
        let mut jtr = vec![0.0; m];
        for i in 0..m {
            for j in 0..m {
                jtj[i][j] = jac[i].iter().zip(&jac[j]).map(|(a, b)| a * b).sum();
            }
            jtr[i] = jac[i].iter().zip(&res).map(|(a, b)| a * b).sum();
        }
        let mut improved = false;
        while lambda < 1e8 {
            let mut a = jtj.clone();
            for (i, row) in a.iter_mut().enumerate() {
                row[i] += lambda * jtj[i][i].max(1e-300);
            }
            let Some(delta) = solve(a, jtr.iter().map(|v| -v).collect()) else {
                lambda *= 10.0;
                continue;
            };
            let t: Vec<f64> = theta.iter().zip(&delta).map(|(a, d)| a + d).collect();
            if let Some((n2, r2)) = project(rec, &poles.with(&t)) {
                let c2 = cost(&r2);
                if c2 < best {
                    let gain = (best - c2) / best;
                    (theta, num, res, best) = (t, n2, r2, c2);
                    lambda = (lambda / 10.0).max(1e-9);
                    improved = gain > 1e-10;
                    break;
                }
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    let den = poles.with(&theta).den();
    TransferFunction::new(&num, &den).ok().map(|tf| (tf, best))
}

/// Solves the small system `a`·x = `b` by Gaussian elimination with partial pivoting.
fn solve(mut a: Vec<Vec<f64>>, mut b: Vec<f64>) -> Option<Vec<f64>> {
    let n = b.len();
    for k in 0..n {
        let p = (k..n).max_by(|&i, &j| a[i][k].abs().total_cmp(&a[j][k].abs()))?;
        if a[p][k].abs() < 1e-300 {
            return None;
        }
        a.swap(k, p);
        b.swap(k, p);
        let pivot = a[k].clone();
        for i in k + 1..n {
            let f = a[i][k] / pivot[k];
            for (x, p) in a[i][k..].iter_mut().zip(&pivot[k..]) {
                *x -= f * p;
            }
            b[i] -= f * b[k];
        }
    }
    let mut x = vec![0.0; n];
    for i in (0..n).rev() {
        let s: f64 = (i + 1..n).map(|j| a[i][j] * x[j]).sum();
        x[i] = (b[i] - s) / a[i][i];
    }
    Some(x)
}
