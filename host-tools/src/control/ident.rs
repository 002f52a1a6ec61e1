//! Identification of a servo joint's plant from sampled data: the DAC command and
//! the encoder position recorded every servo period while an external signal
//! (a PRBS or chirp offset of the position command, [`prbs`]) excites the closed
//! loop.
//!
//! * **Method.** An ARX model A(q)·w = B(q)·U + c + e fitted by least squares
//!   (Householder QR) — the direct method of closed-loop identification: the
//!   estimate is consistent on closed-loop data when the excitation is external and
//!   the model structure contains the true system (Ljung, *System Identification*,
//!   2nd ed., §13.4). `c` absorbs a constant load or amplifier offset. The ARX
//!   estimate is then refined by Steiglitz–McBride passes (see `fit`): with the
//!   encoder's noise on the output the plain equation-error fit misplaces a lightly
//!   damped resonance (report B's table Y: 51 rad/s, ζ = 0.06), the refined one
//!   finds it within 1 %.
//! * **Decimation.** At 10 kHz the plant's poles all sit within 0.5 % of z = 1: the
//!   regressors are nearly collinear and the one-period change of the position is
//!   mostly encoder quantisation. Input and output are therefore passed through the
//!   same low-pass filter — a D-tap moving average applied `filter_passes` times
//!   (4 by default: sidelobes below −50 dB, so the derivative kicks and PRBS edges
//!   of the input hardly alias) — and kept every D periods (D·h = 2 ms). The same
//!   filter on both sides leaves the plant's relation between them unchanged; the
//!   filter also averages the encoder's noise over the block.
//! * **Integrating plants.** A plant commanded in velocity (a pole at s = 0) is
//!   modelled as G(s) = Gᵥ(s)/s: the ARX output is the position change over a block,
//!   wⱼ = y(jD) − y((j−1)D), and B/A is the velocity model (the ARX denominator times
//!   (1 − z⁻¹), i.e. the integrator imposed). Why: from a second of data a pole below
//!   about 1 rad/s cannot be told from an integrator (report B's legs and table have
//!   them at 0.02 to 0.6 rad/s), an unconstrained fit then puts a pole just outside
//!   or inside z = 1 by chance, and the position's slow drift under an offset would
//!   dominate the least-squares error. With `integrating = false` the output is the
//!   position itself.
//! * **Orders.** Every (na, nb, nk) up to the options' limits (nk ≥ 1 block: the
//!   filtered input at the instant of the output sample is Uⱼ₋₁) is fitted on the first part
//!   of the data and simulated from the input alone on the rest (validation); the
//!   fit is 100·(1 − ‖w − ŵ‖/‖w − mean w‖) %. The smallest model within 0.5 points of
//!   the best fit is kept and refitted on all the data. Models with a pole outside
//!   the unit circle or on the negative real axis (no continuous counterpart) are
//!   passed over; if the best fit is below `min_fit` the data are refused.
//! * **Output-error refinement** (`output_error`, on by default; `ident/refine.rs`): the
//!   chosen model's poles and numerator fitted again on the record at the servo
//!   rate, simulated from the recorded input itself, its integrator freed — the
//!   block model above is its starting point. The test signal's edges put a DAC
//!   doublet into the input that the block filter lets alias (see that module).
//! * **Continuous model.** The ARX poles map to s = ln z / (D·h); the numerator is
//!   the least-squares fit of the block model's frequency response (relative error,
//!   up to a quarter of the block rate's Nyquist frequency). The result is a
//!   [`TransferFunction`] in the machine file's units: input c.u., output mm or
//!   degrees.

mod refine;
mod signals;
#[cfg(test)]
mod tests;

use crate::control::plant::{polymul, polyval, roots, Complex, TransferFunction};
pub use signals::{empirical_response, prbs};

/// Sampled data of one joint.
#[derive(Clone, Debug, PartialEq)]
pub struct Record {
    /// Sample period, s (the servo period).
    pub h: f64,
    /// Plant input each period, c.u.: (DAC code − mid-scale − offset)/dac_per_unit.
    pub u: Vec<f64>,
    /// Joint position at the start of each period (before `u` of that period acts),
    /// mm or degrees.
    pub y: Vec<f64>,
}

/// Settings of [`identify`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IdentOptions {
    /// Periods per block (D).
    pub decimation: usize,
    /// Passes of the D-tap boxcar before decimation (1: block means; 2: a triangle
    /// of 2D − 1 taps, which averages the encoder's noise over the block).
    pub filter_passes: usize,
    /// Largest denominator order tried (of the velocity model when integrating).
    pub max_na: usize,
    /// Largest numerator length tried.
    pub max_nb: usize,
    /// Largest input delay tried, blocks (≥ 1).
    pub max_nk: usize,
    /// Impose a pole at s = 0 (see the module documentation).
    pub integrating: bool,
    /// Share of the blocks, at the end, kept for validation.
    pub validation_share: f64,
    /// Lowest acceptable validation fit, %.
    pub min_fit: f64,
    /// Refine the chosen model by output error at the servo rate (module
    /// documentation).
    pub output_error: bool,
}

impl Default for IdentOptions {
    fn default() -> Self {
        Self {
            decimation: 20,
            filter_passes: 4,
            max_na: 3,
            max_nb: 3,
            max_nk: 1,
            integrating: true,
            validation_share: 1.0 / 3.0,
            min_fit: 60.0,
            output_error: true,
        }
    }
}

/// Why data are refused.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum IdentError {
    /// `u` and `y` differ in length, or the period is not positive.
    #[error("record: u and y must have the same length and the period must be > 0")]
    Shape,
    /// A sample is NaN or infinite.
    #[error("record: a sample is not a finite number")]
    NotFinite,
    /// Too few blocks for the orders asked.
    #[error("record: {blocks} blocks of {decimation} periods, at least {needed} needed")]
    TooShort {
        /// Blocks in the record.
        blocks: usize,
        /// Periods per block.
        decimation: usize,
        /// Blocks needed.
        needed: usize,
    },
    /// The input does not vary.
    #[error("record: the input does not vary (no excitation)")]
    NoExcitation,
    /// No model order gave a usable model.
    #[error("identification: no model order gave a stable model with a continuous counterpart")]
    NoModel,
    /// The best model explains too little of the validation data.
    #[error("identification: best validation fit {fit:.1} % is below {min_fit:.1} %: the data do not determine the plant")]
    Rejected {
        /// The best fit, %.
        fit: f64,
        /// The lowest acceptable, %.
        min_fit: f64,
    },
}

/// An ARX model at the block period: A(q)·w = B(q)·U + c.
#[derive(Clone, Debug, PartialEq)]
pub struct Arx {
    /// Block period D·h, s.
    pub period_s: f64,
    /// Sample period h of the record, s.
    pub sample_s: f64,
    /// 1, a₁ … a_na.
    pub a: Vec<f64>,
    /// b₀ … b_{nb−1}, the coefficients of q^−nk … q^−(nk+nb−1).
    pub b: Vec<f64>,
    /// Input delay, blocks.
    pub nk: usize,
    /// Constant term c (output units per block).
    pub offset: f64,
    /// w is the position change over a block (the plant integrates).
    pub integrating: bool,
}

impl Arx {
    fn ab(&self, w: f64) -> (Complex, Complex, Complex) {
        let zinv = Complex::expj(-w * self.period_s);
        let mut pow = Complex::new(1.0, 0.0);
        let mut a = Complex::new(0.0, 0.0);
        for &c in &self.a {
            a = a + pow.scale(c);
            pow = pow * zinv;
        }
        let mut pow = Complex::new(1.0, 0.0);
        for _ in 0..self.nk {
            pow = pow * zinv;
        }
        let mut b = Complex::new(0.0, 0.0);
        for &c in &self.b {
            b = b + pow.scale(c);
            pow = pow * zinv;
        }
        (a, b, zinv)
    }

    /// Block model of the position per unit of block-mean input at ω rad/s
    /// (z = e^{jωT}, T the block period): B/A, over (1 − z⁻¹) when integrating.
    pub fn response(&self, w: f64) -> Complex {
        let (a, b, zinv) = self.ab(w);
        let p = b / a;
        if self.integrating {
            p / (Complex::new(1.0, 0.0) - zinv)
        } else {
            p
        }
    }

    /// The continuous plant G(jω) the block model stands for (mm or degrees per
    /// c.u.): the output and the block-mean input compared at the same instant (see
    /// the module documentation).
    pub fn continuous_estimate(&self, w: f64) -> Complex {
        let (a, b, zinv) = self.ab(w);
        let t = self.period_s;
        let same_instant = b / (a * zinv);
        if self.integrating {
            same_instant / Complex::new(0.0, w * t)
        } else {
            let x = 0.5 * w * self.sample_s;
            let sinc = if x == 0.0 { 1.0 } else { x.sin() / x };
            same_instant * Complex::expj(-x).scale(sinc)
        }
    }

    /// Poles of the block model, z (the imposed integrator's z = 1 included).
    pub fn poles(&self) -> Vec<Complex> {
        let mut p = if self.a.len() > 1 {
            roots(&self.a)
        } else {
            Vec::new()
        };
        if self.integrating {
            p.push(Complex::new(1.0, 0.0));
        }
        p
    }

    /// The position response to a unit input step from rest, one value per block
    /// boundary (the constant term left out).
    pub fn step(&self, blocks: usize) -> Vec<f64> {
        let w = self.run(&vec![1.0; blocks], &[], blocks, 0.0);
        if !self.integrating {
            return w;
        }
        let mut y = 0.0;
        w.iter()
            .map(|v| {
                y += v;
                y
            })
            .collect()
    }

    /// Outputs 0..`to`: `measured` ones first, the rest simulated from the block
    /// inputs `u` (zero before the first) with constant term `offset`.
    fn run(&self, u: &[f64], measured: &[f64], to: usize, offset: f64) -> Vec<f64> {
        let mut out: Vec<f64> = measured.to_vec();
        for j in measured.len()..to {
            let mut v = offset;
            for (i, a) in self.a.iter().enumerate().skip(1) {
                if j >= i {
                    v -= a * out[j - i];
                }
            }
            for (i, b) in self.b.iter().enumerate() {
                let k = self.nk + i;
                if j >= k && j - k < u.len() {
                    v += b * u[j - k];
                }
            }
            out.push(v);
        }
        out
    }
}

/// One order tried.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Candidate {
    /// Denominator order.
    pub na: usize,
    /// Numerator length.
    pub nb: usize,
    /// Delay, blocks.
    pub nk: usize,
    /// Validation fit, %; `None` when the model had a pole outside the unit circle or
    /// on the negative real axis.
    pub fit_percent: Option<f64>,
}

/// The identified plant.
#[derive(Clone, Debug, PartialEq)]
pub struct Identified {
    /// The block model, refitted on all the data.
    pub arx: Arx,
    /// Its continuous counterpart: input c.u., output mm or degrees.
    pub plant: TransferFunction,
    /// Validation fit of the chosen order, %.
    pub fit_percent: f64,
    /// Every order tried.
    pub candidates: Vec<Candidate>,
}

/// The block signals: input means and outputs (index j: output at the end of block
/// j − 1, so U[j − 1] is the input of the block just before out[j]).
struct Blocks {
    u: Vec<f64>,
    out: Vec<f64>,
    period_s: f64,
    sample_s: f64,
}

/// The anti-alias filter: a boxcar of `d` taps applied `passes` times, its weights
/// summing to 1.
fn boxcars(d: usize, passes: usize) -> Vec<f64> {
    let one = vec![1.0 / d as f64; d];
    (0..passes.max(1)).fold(vec![1.0], |f, _| polymul(&f, &one))
}

fn blocks(rec: &Record, o: &IdentOptions) -> Blocks {
    let d = o.decimation.max(1);
    let f = boxcars(d, o.filter_passes);
    let filtered = |x: &dyn Fn(usize) -> f64, k: usize| {
        f.iter().enumerate().map(|(i, c)| c * x(k - i)).sum::<f64>()
    };
    let (y, u) = (&rec.y, &rec.u);
    let (mut bu, mut out) = (Vec::new(), Vec::new());
    let mut k = f.len() - 1;
    while k + 1 < y.len() {
        out.push(if o.integrating {
            d as f64 * filtered(&|i| y[i + 1] - y[i], k)
        } else {
            filtered(&|i| y[i + 1], k)
        });
        if k >= f.len() - 1 + d {
            bu.push(filtered(&|i| u[i], k));
        }
        k += d;
    }
    Blocks {
        u: bu,
        out,
        period_s: d as f64 * rec.h,
        sample_s: rec.h,
    }
}

/// Least squares min ‖X·θ − r‖ by Householder QR on unit-norm columns; `None` if a
/// column is zero or dependent to working precision.
fn lstsq(mut x: Vec<Vec<f64>>, mut r: Vec<f64>) -> Option<Vec<f64>> {
    let (m, n) = (x.len(), x.first()?.len());
    if m < n {
        return None;
    }
    let norms: Vec<f64> = (0..n)
        .map(|j| x.iter().map(|row| row[j] * row[j]).sum::<f64>().sqrt())
        .collect();
    if norms.iter().any(|v| !(v.is_finite() && *v > 0.0)) {
        return None;
    }
    for row in &mut x {
        for (v, s) in row.iter_mut().zip(&norms) {
            *v /= s;
        }
    }
    let mut diag = vec![0.0; n];
    for k in 0..n {
        let alpha = x[k..].iter().map(|row| row[k] * row[k]).sum::<f64>().sqrt();
        if alpha < 1e-13 {
            return None;
        }
        let alpha = if x[k][k] > 0.0 { -alpha } else { alpha };
        let mut v: Vec<f64> = x[k..].iter().map(|row| row[k]).collect();
        v[0] -= alpha;
        let vv: f64 = v.iter().map(|a| a * a).sum();
        diag[k] = alpha;
        for j in k + 1..n {
            let dot: f64 = v.iter().zip(&x[k..]).map(|(a, row)| a * row[j]).sum();
            let f = 2.0 * dot / vv;
            for (a, row) in v.iter().zip(&mut x[k..]) {
                row[j] -= f * a;
            }
        }
        let dot: f64 = v.iter().zip(&r[k..]).map(|(a, b)| a * b).sum();
        let f = 2.0 * dot / vv;
        for (a, b) in v.iter().zip(&mut r[k..]) {
            *b -= f * a;
        }
    }
    let mut theta = vec![0.0; n];
    for i in (0..n).rev() {
        let s: f64 = (i + 1..n).map(|j| x[i][j] * theta[j]).sum();
        theta[i] = (r[i] - s) / diag[i];
    }
    Some(theta.iter().zip(&norms).map(|(t, s)| t / s).collect())
}

/// θ = [a₁ … a_na, b₀ … b_{nb−1}, c] of out = −Σaᵢ·out₋ᵢ + Σbᵢ·u₋ₙₖ₋ᵢ + c·one
/// fitted on the outputs `range` (u[j − 1] at the instant of out[j]).
fn regress(
    (out, u, one): (&[f64], &[f64], &[f64]),
    (na, nb, nk): (usize, usize, usize),
    range: (usize, usize),
) -> Option<Vec<f64>> {
    let (mut rows, mut rhs) = (Vec::new(), Vec::new());
    for j in range.0..range.1 {
        let mut row: Vec<f64> = (1..=na).map(|i| -out[j - i]).collect();
        row.extend((0..nb).map(|i| u[j - nk - i]));
        row.push(one[j]);
        rows.push(row);
        rhs.push(out[j]);
    }
    lstsq(rows, rhs)
}

/// `x` through 1/A(q).
fn through_inverse(a: &[f64], x: &[f64]) -> Vec<f64> {
    let mut y: Vec<f64> = Vec::with_capacity(x.len());
    for (k, v) in x.iter().enumerate() {
        let past: f64 = (1..a.len().min(k + 1)).map(|i| a[i] * y[k - i]).sum();
        y.push(v - past);
    }
    y
}

/// Steiglitz–McBride passes after the ARX fit.
const REFINE_PASSES: usize = 8;

/// The model of orders (na, nb, nk) fitted on the outputs `range` of `b`: least
/// squares ARX, then [`REFINE_PASSES`] Steiglitz–McBride passes (both signals and
/// the constant through 1/Â of the previous pass, the ARX fit repeated), which
/// move the equation-error estimate towards the output-error one — the model that
/// best reproduces the output from the input (Steiglitz and McBride, IEEE Trans.
/// Automatic Control 10, 1965). A pass that leaves the unit circle is not taken.
fn fit(
    b: &Blocks,
    orders: (usize, usize, usize),
    range: (usize, usize),
    integ: bool,
) -> Option<Arx> {
    let (na, nb, nk) = orders;
    let ones = vec![1.0; b.out.len()];
    let model = |theta: Vec<f64>| {
        let mut a = vec![1.0];
        a.extend(&theta[..na]);
        Arx {
            period_s: b.period_s,
            sample_s: b.sample_s,
            a,
            b: theta[na..na + nb].to_vec(),
            nk,
            offset: theta[na + nb],
            integrating: integ,
        }
    };
    let mut m = model(regress((&b.out, &b.u, &ones), orders, range)?);
    for _ in 0..if na > 0 { REFINE_PASSES } else { 0 } {
        if !admissible(&m) {
            break;
        }
        let f = |x: &[f64]| through_inverse(&m.a, x);
        let (out, u, one) = (f(&b.out), f(&b.u), f(&ones));
        let Some(theta) = regress((&out, &u, &one), orders, range) else {
            break;
        };
        let next = model(theta);
        if !admissible(&next) {
            break;
        }
        m = next;
    }
    Some(m)
}

/// Validation fit of `m` on the outputs from `split` on, %.
fn validation_fit(m: &Arx, b: &Blocks, split: usize) -> f64 {
    let sim = m.run(&b.u, &b.out[..split], b.out.len(), m.offset);
    let (meas, sim) = (&b.out[split..], &sim[split..]);
    let mean = meas.iter().sum::<f64>() / meas.len() as f64;
    let err: f64 = meas.iter().zip(sim).map(|(a, s)| (a - s).powi(2)).sum();
    let spread: f64 = meas.iter().map(|a| (a - mean).powi(2)).sum();
    100.0 * (1.0 - (err / spread).sqrt())
}

/// No pole outside the unit circle or on the negative real axis.
fn admissible(m: &Arx) -> bool {
    m.a.len() == 1
        || roots(&m.a)
            .iter()
            .all(|z| z.abs() < 1.0 && !(z.im == 0.0 && z.re <= 0.0))
}

fn check(rec: &Record) -> Result<(), IdentError> {
    if rec.u.len() != rec.y.len() || !(rec.h.is_finite() && rec.h > 0.0) {
        return Err(IdentError::Shape);
    }
    if rec.u.iter().chain(&rec.y).any(|v| !v.is_finite()) {
        return Err(IdentError::NotFinite);
    }
    Ok(())
}

/// Identifies the plant of `rec` (see the module documentation).
pub fn identify(rec: &Record, o: &IdentOptions) -> Result<Identified, IdentError> {
    check(rec)?;
    let b = blocks(rec, o);
    let d = o.decimation.max(1);
    let max_nk = o.max_nk.max(1);
    let lag = o.max_na.max(max_nk + o.max_nb - 1);
    let n = b.out.len();
    let params = o.max_na + o.max_nb + 1;
    let needed = lag + 8 * params;
    if n < needed {
        return Err(IdentError::TooShort {
            blocks: n,
            decimation: d,
            needed,
        });
    }
    let mean = b.u.iter().sum::<f64>() / b.u.len() as f64;
    if b.u
        .iter()
        .all(|v| (v - mean).abs() <= 1e-12 * mean.abs().max(1e-300))
    {
        return Err(IdentError::NoExcitation);
    }
    let valid = ((n as f64 * o.validation_share.clamp(0.05, 0.8)) as usize).max(2);
    let split = (n - valid).max(lag + 4 * params);
    let mut candidates = Vec::new();
    for na in usize::from(!o.integrating)..=o.max_na {
        for nb in 1..=o.max_nb.max(1) {
            for nk in 1..=max_nk {
                let j0 = na.max(nk + nb - 1);
                let m = fit(&b, (na, nb, nk), (j0, split), o.integrating);
                let fit_percent = m
                    .filter(admissible)
                    .map(|m| validation_fit(&m, &b, split))
                    .filter(|f| f.is_finite());
                candidates.push(Candidate {
                    na,
                    nb,
                    nk,
                    fit_percent,
                });
            }
        }
    }
    let best = candidates
        .iter()
        .filter_map(|c| c.fit_percent)
        .fold(f64::NEG_INFINITY, f64::max);
    if best == f64::NEG_INFINITY {
        return Err(IdentError::NoModel);
    }
    if best < o.min_fit {
        return Err(IdentError::Rejected {
            fit: best,
            min_fit: o.min_fit,
        });
    }
    let mut good: Vec<&Candidate> = candidates
        .iter()
        .filter(|c| c.fit_percent.is_some_and(|f| f >= best - 0.5))
        .collect();
    good.sort_by_key(|c| (c.na + c.nb, c.na, c.nk));
    let record_s = rec.y.len() as f64 * rec.h;
    for c in good {
        let j0 = c.na.max(c.nk + c.nb - 1);
        let orders = (c.na, c.nb, c.nk);
        let all = fit(&b, orders, (j0, n), o.integrating).filter(admissible);
        let arx = all.or_else(|| fit(&b, orders, (j0, split), o.integrating));
        let Some(arx) = arx else { continue };
        if let Some(plant) = to_continuous(&arx, record_s) {
            let refined = o
                .output_error
                .then(|| refine::refine(rec, &plant, o.integrating))
                .flatten();
            let plant = refined.map_or(plant, |r| r.0);
            return Ok(Identified {
                arx,
                plant,
                fit_percent: c.fit_percent.unwrap_or(f64::NAN),
                candidates,
            });
        }
    }
    Err(IdentError::NoModel)
}

/// Frequencies of the numerator fit: 60 log-spaced from 2π over the record (at least
/// 0.5 rad/s) to a quarter of the block rate's Nyquist frequency, rad/s.
fn fit_band(period_s: f64, record_s: f64) -> Vec<f64> {
    let lo = (std::f64::consts::TAU / record_s).max(0.5);
    let hi = 0.25 * std::f64::consts::PI / period_s;
    (0..60)
        .map(|i| lo * (hi / lo).powf(i as f64 / 59.0))
        .collect()
}

/// The continuous plant of `arx` (module documentation), from a record of
/// `record_s` seconds; `None` if the model has a pole with no continuous counterpart
/// or the fit fails.
pub fn to_continuous(arx: &Arx, record_s: f64) -> Option<TransferFunction> {
    let t = arx.period_s;
    let mut den = vec![1.0];
    if arx.a.len() > 1 {
        for z in roots(&arx.a) {
            if z.abs() <= 0.0 || (z.im == 0.0 && z.re <= 0.0) {
                return None;
            }
            let s = Complex::new(z.abs().ln() / t, z.arg() / t);
            if z.im == 0.0 {
                den = polymul(&den, &[1.0, -s.re]);
            } else if z.im > 0.0 {
                den = polymul(&den, &[1.0, -2.0 * s.re, s.re * s.re + s.im * s.im]);
            }
        }
    }
    let nd = den.len() - 1;
    // The velocity model may be biproper; the position model is strictly proper.
    let m = if arx.integrating {
        nd
    } else {
        nd.checked_sub(1)?
    };
    let (mut rows, mut rhs) = (Vec::new(), Vec::new());
    for w in fit_band(t, record_s) {
        let jw = Complex::new(0.0, w);
        let mut g = arx.continuous_estimate(w);
        if arx.integrating {
            g = g * jw;
        }
        let scale = Complex::new(1.0, 0.0) / (g * polyval(&den, jw));
        let cols: Vec<Complex> = (0..=m).map(|i| pow(jw, m - i) * scale).collect();
        rows.push(cols.iter().map(|c| c.re).collect());
        rhs.push(1.0);
        rows.push(cols.iter().map(|c| c.im).collect());
        rhs.push(0.0);
    }
    let num = lstsq(rows, rhs)?;
    let den = if arx.integrating {
        polymul(&den, &[1.0, 0.0])
    } else {
        den
    };
    TransferFunction::new(&num, &den).ok()
}

fn pow(x: Complex, k: usize) -> Complex {
    (0..k).fold(Complex::new(1.0, 0.0), |p, _| p * x)
}
