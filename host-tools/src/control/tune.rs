//! Servo gains from a plant model (an identified one, [`crate::control::ident`]):
//! the core's PID for a stated crossover and phase margin, the feed-forwards from the
//! model's low-frequency inverse, and the figures to judge them on any plant — gain
//! and phase margins, the loop's Bode data, the predicted closed-loop step.
//!
//! * **The loop as the core runs it** ([`pkmc::drive::servo`]): e = target −
//!   feedback in counts, I ← I + ki·T·e (this period's error included),
//!   u = kp·e + I + kd·(e − e₋₁)/T, the command held over the period (zero-order
//!   hold) and the encoder read at the start of the next:
//!   C(z) = kp + ki·T·z/(z − 1) + kd·(z − 1)/(T·z), P(z) the plant discretised with a zero-order hold at T, both
//!   from [`crate::control::lqg::pid_loop_response`], so that the sample-and-hold
//!   delay is in every figure. Gains are per encoder count, as in
//!   [`pkmc::config::ServoGains`].
//! * **PID design** ([`design_pid`]): the integral's zero a factor `integral_ratio`
//!   below the crossover ωc (ki = kp·ωc/ratio); kp and kd solve
//!   C(e^{jωcT})·P(e^{jωcT}) = e^{j(−180° + PM)} (two real equations, linear in kp
//!   and kd). When that needs kd < 0 (the plant has phase to spare) kd is 0 and kp
//!   alone puts |L| = 1 at ωc, leaving a larger margin.
//! * **Feed-forward** ([`feed_forward`]): u ≈ c₁·ṙ + c₂·r̈ from the series of 1/G(s)
//!   at s = 0 ([`TransferFunction::inverse_series`]): kvff = c₁, kaff = c₂, divided
//!   by the counts per unit.
//! * **Margins** ([`margins`]): on a grid of 4001 log-spaced frequencies from
//!   0.1 rad/s to 0.95 of the Nyquist frequency, the phase margin is the smallest
//!   180° − |∠L| where |L| crosses 1 (the distance of L's phase from −180°), the gain
//!   margin the smallest 1/|L| where L crosses the negative real axis.

use crate::control::lqg::{pid_loop_figures, pid_loop_response, LoopFigures, LqgError};
use crate::control::plant::{Complex, TransferFunction};

/// What [`design_pid`] aims at.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PidSpec {
    /// Gain crossover ωc, rad/s.
    pub crossover_rad_s: f64,
    /// Phase margin at ωc on the model, degrees (aim above the 45° wanted on the
    /// real plant, to leave room for the model's error).
    pub phase_margin_deg: f64,
    /// ωc over the integral's corner ki/kp.
    pub integral_ratio: f64,
}

impl PidSpec {
    /// Crossover `crossover_rad_s`, 60° phase margin on the model, the integral's
    /// corner five times below the crossover.
    pub fn new(crossover_rad_s: f64) -> Self {
        Self {
            crossover_rad_s,
            phase_margin_deg: 60.0,
            integral_ratio: 5.0,
        }
    }
}

/// Stability margins of a loop.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Margins {
    /// The highest frequency where |L| falls through 1, rad/s.
    pub crossover_rad_s: f64,
    /// Smallest phase margin over all gain crossovers, degrees.
    pub phase_margin_deg: f64,
    /// Where it occurs, rad/s.
    pub phase_margin_at_rad_s: f64,
    /// Smallest 1/|L| where L crosses the negative real axis (infinite if it never
    /// does).
    pub gain_margin: f64,
    /// Where it occurs, rad/s (0 if never).
    pub gain_margin_at_rad_s: f64,
    /// Every closed-loop pole inside the unit circle.
    pub stable: bool,
}

impl Margins {
    /// The gain margin in dB.
    pub fn gain_margin_db(&self) -> f64 {
        20.0 * self.gain_margin.log10()
    }
}

/// A PID design.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PidTuning {
    /// Proportional gain, c.u. per count.
    pub kp: f64,
    /// Integral gain, c.u. per (count·s).
    pub ki: f64,
    /// Derivative gain, c.u. per (count/s).
    pub kd: f64,
    /// Velocity feed-forward, c.u. per (count/s).
    pub kvff: f64,
    /// Acceleration feed-forward, c.u. per (count/s²).
    pub kaff: f64,
    /// Margins on the design model.
    pub margins: Margins,
    /// Peak sensitivity, load response and poles on the design model.
    pub figures: LoopFigures,
}

impl PidTuning {
    /// [kp, ki, kd].
    pub fn pid(&self) -> [f64; 3] {
        [self.kp, self.ki, self.kd]
    }
}

/// Why a design is refused.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum TuneError {
    /// The model is not one the loop figures take.
    #[error(transparent)]
    Model(#[from] LqgError),
    /// The specification is not finite and positive, or the crossover is above the
    /// Nyquist frequency.
    #[error("tuning: the crossover must be in (0, π/T) rad/s, the phase margin in (0°, 90°) and the integral ratio > 0")]
    Spec,
    /// The designed loop is unstable on the model.
    #[error("tuning: the design is unstable on the model (crossover too high for the plant)")]
    Unstable,
}

/// `n` frequencies log-spaced from `lo` to `hi` rad/s.
pub fn log_grid(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    let n = n.max(2);
    (0..n)
        .map(|i| lo * (hi / lo).powf(i as f64 / (n - 1) as f64))
        .collect()
}

/// [`Margins`] of the core's PID `gains` on `plant` (mm or degrees per c.u.) at
/// `counts_per_unit` encoder counts per mm or degree and period `period_s`.
pub fn margins(
    plant: &TransferFunction,
    counts_per_unit: f64,
    period_s: f64,
    gains: [f64; 3],
) -> Result<Margins, LqgError> {
    let top = 0.95 * std::f64::consts::PI / period_s;
    let ws = log_grid(0.1, top, 4001);
    let resp = pid_loop_response(plant, counts_per_unit, period_s, gains, &ws)?;
    let fig = pid_loop_figures(plant, counts_per_unit, period_s, gains)?;
    let mut m = Margins {
        crossover_rad_s: 0.0,
        phase_margin_deg: f64::INFINITY,
        phase_margin_at_rad_s: 0.0,
        gain_margin: f64::INFINITY,
        gain_margin_at_rad_s: 0.0,
        stable: fig.max_pole < 1.0,
    };
    for i in 1..ws.len() {
        let (l0, l1) = (resp[i - 1].1, resp[i].1);
        if (l0.abs() > 1.0) != (l1.abs() > 1.0) {
            let pm = 180.0 - l1.arg().to_degrees().abs();
            if pm < m.phase_margin_deg {
                m.phase_margin_deg = pm;
                m.phase_margin_at_rad_s = ws[i];
            }
            if l0.abs() > 1.0 {
                m.crossover_rad_s = ws[i];
            }
        }
        if (l0.im > 0.0) != (l1.im > 0.0) && l1.re < 0.0 {
            // Interpolate |L| where Im L = 0.
            let f = l0.im / (l0.im - l1.im);
            let re = l0.re + f * (l1.re - l0.re);
            let gm = 1.0 / re.abs();
            if gm < m.gain_margin {
                m.gain_margin = gm;
                m.gain_margin_at_rad_s = ws[i];
            }
        }
    }
    Ok(m)
}

/// Velocity and acceleration feed-forwards (kvff, kaff per count) inverting `model`
/// at low frequency (module documentation).
pub fn feed_forward(model: &TransferFunction, counts_per_unit: f64) -> [f64; 2] {
    let [_, c1, c2] = model.inverse_series();
    [c1 / counts_per_unit, c2 / counts_per_unit]
}

/// Designs the core's PID for `model` (mm or degrees per c.u.) to `spec` (module
/// documentation), with its feed-forwards and its figures on the model.
pub fn design_pid(
    model: &TransferFunction,
    counts_per_unit: f64,
    period_s: f64,
    spec: &PidSpec,
) -> Result<PidTuning, TuneError> {
    let (wc, pm) = (spec.crossover_rad_s, spec.phase_margin_deg);
    let nyquist = std::f64::consts::PI / period_s;
    let ok = wc > 0.0 && wc < nyquist && pm > 0.0 && pm < 90.0 && spec.integral_ratio > 0.0;
    if !ok {
        return Err(TuneError::Spec);
    }
    let p = pid_loop_response(model, counts_per_unit, period_s, [0.0; 3], &[wc])?[0].0;
    let want = Complex::expj((pm - 180.0).to_radians()) / p;
    let zinv = Complex::expj(-wc * period_s);
    let one = Complex::new(1.0, 0.0);
    let gi = Complex::new(period_s, 0.0) / (one - zinv);
    let gd = (one - zinv).scale(1.0 / period_s);
    let wi = wc / spec.integral_ratio;
    // C = kp·(1 + wi·gi) + kd·gd = want.
    let a = one + gi.scale(wi);
    let det = a.re * gd.im - a.im * gd.re;
    let mut kp = (want.re * gd.im - want.im * gd.re) / det;
    let mut kd = (a.re * want.im - a.im * want.re) / det;
    if !(kd >= 0.0 && kp > 0.0) {
        kd = 0.0;
        kp = want.abs() / a.abs();
    }
    let gains = [kp, kp * wi, kd];
    let margins = margins(model, counts_per_unit, period_s, gains)?;
    let figures = pid_loop_figures(model, counts_per_unit, period_s, gains)?;
    if !margins.stable {
        return Err(TuneError::Unstable);
    }
    let [kvff, kaff] = feed_forward(model, counts_per_unit);
    Ok(PidTuning {
        kp,
        ki: gains[1],
        kd,
        kvff,
        kaff,
        margins,
        figures,
    })
}

/// Bounds a default design keeps on the model besides its phase margin (see
/// [`highest_crossover`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Robustness {
    /// Smallest gain margin, dB.
    pub min_gain_margin_db: f64,
    /// Largest peak sensitivity max |1/(1 + L)|.
    pub max_sensitivity: f64,
}

impl Default for Robustness {
    /// 10 dB of gain margin, |S|max ≤ 1.7 (a 36° and 4.6 dB guaranteed margin).
    fn default() -> Self {
        Self {
            min_gain_margin_db: 10.0,
            max_sensitivity: 1.7,
        }
    }
}

/// The highest crossover from `lo` to `hi` rad/s (40 log-spaced trials) up to which
/// every trial's design for `spec`'s phase margin and integral ratio meets, on
/// `model`: a stable loop, that phase margin at every gain crossover (within 1°), and
/// `bounds`. `None` when the design at `lo` already fails them.
pub fn highest_crossover(
    model: &TransferFunction,
    counts_per_unit: f64,
    period_s: f64,
    spec: &PidSpec,
    (lo, hi): (f64, f64),
    bounds: &Robustness,
) -> Option<f64> {
    let mut best = None;
    for wc in log_grid(lo, hi.max(lo), 40) {
        let trial = PidSpec {
            crossover_rad_s: wc,
            ..*spec
        };
        let ok = design_pid(model, counts_per_unit, period_s, &trial).is_ok_and(|t| {
            t.margins.phase_margin_deg >= spec.phase_margin_deg - 1.0
                && t.margins.gain_margin_db() >= bounds.min_gain_margin_db
                && t.figures.peak_sensitivity <= bounds.max_sensitivity
        });
        if !ok {
            break;
        }
        best = Some(wc);
    }
    best
}

/// The closed loop's response to a unit step of the target (1 mm or degree) at time
/// 0, the loop at rest and running before: the core's PID `gains` (per count) on
/// `plant`, linear (no output clamp, no DAC or encoder quantisation, no
/// feed-forward: a step has no finite velocity), `samples` periods of `period_s`;
/// the joint's position each period, mm or degrees.
pub fn closed_loop_step(
    plant: &TransferFunction,
    counts_per_unit: f64,
    period_s: f64,
    [kp, ki, kd]: [f64; 3],
    samples: usize,
) -> Vec<f64> {
    let mut p = plant.discretize(period_s);
    let target = counts_per_unit;
    let (mut integral, mut previous) = (0.0, 0.0);
    let mut out = Vec::with_capacity(samples);
    for _ in 0..samples {
        let y = p.output(0.0) * counts_per_unit;
        out.push(y / counts_per_unit);
        let e = target - y;
        integral += ki * period_s * e;
        let u = kp * e + integral + kd * (e - previous) / period_s;
        previous = e;
        p.step(u);
    }
    out
}

/// How far a predicted step response lies from the true one, over the true one's rise.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepError {
    /// ∫₀^{t₉₀} |ŷ − y| dt / ∫₀^{t₉₀} |y_∞ − y| dt (see [`step_error`]).
    pub ratio: f64,
    /// t₉₀: when y first reaches 90 % of y_∞, s.
    pub rise_s: f64,
}

/// Compares the predicted step response `model` with the true one `truth` (both
/// sampled every `period_s` from the step): with y_∞ the last value of `truth` and
/// t₉₀ the first time `truth` reaches 0.9·y_∞ (the whole record if never), the
/// ratio ∫₀^{t₉₀} |ŷ − y| dt / ∫₀^{t₉₀} |y_∞ − y| dt, the integrals as sums over the
/// samples: the error in the rise relative to the area the rise sweeps.
pub fn step_error(truth: &[f64], model: &[f64], period_s: f64) -> StepError {
    let n = truth.len().min(model.len());
    let fin = truth[n - 1];
    let end = truth[..n]
        .iter()
        .position(|&y| y * fin.signum() >= 0.9 * fin.abs())
        .unwrap_or(n - 1)
        .max(1);
    let err: f64 = (0..=end).map(|k| (model[k] - truth[k]).abs()).sum();
    let area: f64 = (0..=end).map(|k| (fin - truth[k]).abs()).sum();
    StepError {
        ratio: err / area,
        rise_s: end as f64 * period_s,
    }
}

/// One frequency of a loop's Bode data.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BodePoint {
    /// ω, rad/s.
    pub w: f64,
    /// The plant as the loop sees it (held and sampled), counts per c.u.
    pub plant: Complex,
    /// The loop gain L = C·P.
    pub loop_gain: Complex,
}

/// Bode data of the core's PID `gains` on `plant` at each of `ws` rad/s.
pub fn bode(
    plant: &TransferFunction,
    counts_per_unit: f64,
    period_s: f64,
    gains: [f64; 3],
    ws: &[f64],
) -> Result<Vec<BodePoint>, LqgError> {
    let r = pid_loop_response(plant, counts_per_unit, period_s, gains, ws)?;
    Ok(ws
        .iter()
        .zip(r)
        .map(|(&w, (plant, loop_gain))| BodePoint {
            w,
            plant,
            loop_gain,
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    const H: f64 = 1e-4;
    const CPU: f64 = 1000.0;

    fn default_plant() -> TransferFunction {
        TransferFunction::new(&[0.3], &[0.02, 1.0, 0.0]).unwrap()
    }

    #[test]
    fn a_design_meets_its_crossover_and_phase_margin_on_its_model() {
        let g = default_plant();
        let t = design_pid(&g, CPU, H, &PidSpec::new(40.0)).unwrap();
        assert!(
            (t.margins.crossover_rad_s / 40.0 - 1.0).abs() < 0.01,
            "{t:?}"
        );
        assert!((t.margins.phase_margin_deg - 60.0).abs() < 0.5, "{t:?}");
        assert!(t.kd > 0.0 && t.ki > 0.0 && t.margins.stable);
    }

    #[test]
    fn the_feed_forwards_invert_the_default_plant() {
        // 1/G = (0.02 s² + s)/0.3: kvff = 1/300, kaff = 0.02/300 c.u. per count.
        let [kvff, kaff] = feed_forward(&default_plant(), CPU);
        assert!((kvff - 1.0 / 300.0).abs() < 1e-12 && (kaff - 0.02 / 300.0).abs() < 1e-12);
    }

    #[test]
    fn the_step_error_is_zero_for_the_same_response_and_grows_with_a_gain_error() {
        let g = default_plant();
        let y = closed_loop_step(&g, CPU, H, [0.1, 1.0, 0.0], 10_000);
        assert!((y[9_999] - 1.0).abs() < 0.01);
        assert_eq!(step_error(&y, &y, H).ratio, 0.0);
        let off = TransferFunction::new(&[0.45], &[0.02, 1.0, 0.0]).unwrap();
        let z = closed_loop_step(&off, CPU, H, [0.1, 1.0, 0.0], 10_000);
        assert!(step_error(&y, &z, H).ratio > 0.1);
    }

    #[test]
    fn too_high_a_crossover_is_refused() {
        let g = default_plant();
        assert_eq!(
            design_pid(&g, CPU, H, &PidSpec::new(4e4)),
            Err(TuneError::Spec)
        );
    }
}
