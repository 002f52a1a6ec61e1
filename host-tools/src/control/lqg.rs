//! Design of a servo joint's LQG controller ([`pkmc::drive::lqg`]) from its plant model and
//! a machine file's weights and noise levels.
//!
//! * **Model.** The plant G(s) (mm or degrees per c.u., [`TransferFunction`]) times
//!   the joint's counts per unit, so that the output is in encoder counts, realised in
//!   observer canonical form (x₁ = y, x₂ = ẏ + a₁y − b₁u, …; C = [1 0 0 0]) with
//!   state i scaled by ω₀^−(i−1), ω₀ = maxᵢ |aᵢ|^(1/i) (half of Fujiwara's bound
//!   on the poles' magnitudes; the highest natural frequency of report B's plants;
//!   1 rad/s for a chain of integrators): the states are the output and its
//!   derivatives in counts at that frequency, and the continuous system matrix has
//!   entries of at most about ω₀, where those of the controllable canonical form
//!   reach 10⁵. Strictly proper models of order 1 to [`LQG_STATES`] with no zero at
//!   s = 0.
//! * **Discretisation.** Exact zero-order hold at the period T (the matrix
//!   exponential of [[A, B], [0, 0]]·T, as the simulator's plants), kept as Φ − I.
//! * **Regulator (LQI).** The model augmented with z⁺ = z + T·y (the error integral,
//!   count·s); u = −K·x − ki·z minimises Σ (q_y·y² + q_z·z² + r·u²) over the periods,
//!   with K from the stabilising solution of the discrete algebraic Riccati equation
//!   (DARE).
//! * **Estimator.** The steady-state Kalman filter of the model with a white load
//!   disturbance w (c.u., held over each period, so entering through Γ) and white
//!   measurement noise v (counts): the dual DARE for the predicted covariance P, and
//!   the current-estimator gain M = PCᵀ(CPCᵀ + σᵥ²)⁻¹.
//! * By the separation principle the closed loop on the model has the regulator's
//!   poles eig(Φₐ − ΓₐKₐ) and the estimator's eig((I − MC)Φ); both are checked inside
//!   the unit circle, and each DARE's residual is checked.
//!
//! Both DAREs are solved in `f64` by structured doubling (`linalg::dare`); the gains
//! are then rounded to `f32` for the core. [`LqgDesign::loop_figures`] judges a design
//! on a plant (the model, or a mismatched one) as the PID gains were judged
//! (docs/contour.md): peak sensitivity, gain crossover and the response to a load at
//! 1 Hz, from the compensator's and the plant's discrete transfer functions.

// Matrix code reads best with its indices.
#![allow(clippy::needless_range_loop)]

#[cfg(test)]
mod tests;

use crate::control::linalg::{
    self, add, col, dare, eigenvalues_delta, lqr_gain, mul, response, solve, zeros, Mat,
};
use crate::control::plant::{expm, Complex, TransferFunction};
use pkmc::config::{LqgGains, LQG_STATES};
use serde::Deserialize;

/// A servo joint's LQG settings (`lqg = { ... }` in a machine file). The regulator
/// weights set how hard the loop works (only their ratios matter); the noise levels
/// set how much the estimator trusts the model against the encoder (only their ratio
/// matters). Rules of thumb, from the continuous-time limit on a plant that
/// integrates, y' = b·u (b the velocity gain, counts/s per c.u.): the integral gain
/// is ki ≈ √(integral_weight / command_weight) c.u. per (count·s), the proportional
/// gain k ≈ √(position_weight / command_weight + 2·ki/b) c.u. per count, and the
/// estimator's bandwidth about b·load_noise/encoder_noise rad/s. For report B's
/// plants (seed-b) the loops that reject a 1 Hz load best within docs/contour.md's
/// PID rule put almost all the weight on the integral.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct LqgWeights {
    /// Cost of a following error, per count². ≥ 0.
    pub position_weight: f64,
    /// Cost of the following error's time integral, per (count·s)². > 0 (the
    /// integral removes steady errors under a constant load).
    pub integral_weight: f64,
    /// Cost of the command, per c.u.². > 0.
    pub command_weight: f64,
    /// Standard deviation of the load disturbance at the plant input (cutting
    /// force, friction, valve offset), c.u., white from period to period. > 0.
    pub load_noise: f64,
    /// Standard deviation of the position measurement, counts, white from period to
    /// period: 1/√12 ≈ 0.29 for the encoder's quantisation alone. > 0.
    pub encoder_noise: f64,
}

/// Why a design is refused; the message names the machine file's field.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum LqgError {
    /// The model's order is outside 1..=[`LQG_STATES`].
    #[error("plant.den: an LQG design takes a model of order 1..={LQG_STATES}, not {0}")]
    Order(usize),
    /// The numerator is not of lower order than the denominator.
    #[error(
        "plant.num: an LQG design needs a strictly proper model (num of lower order than den)"
    )]
    NotStrictlyProper,
    /// G(0) = 0: the error integral cannot be stabilised.
    #[error("plant.num: the model has a zero at s = 0 (its last coefficient is 0): the error integral is not stabilisable")]
    ZeroAtOrigin,
    /// A weight or noise level is not finite or out of its range.
    #[error("lqg.{field}: must be a finite number {rule}")]
    Weight {
        /// The field.
        field: &'static str,
        /// Its range, in words.
        rule: &'static str,
    },
    /// The joint's scale or the period is not finite and positive.
    #[error("{0}: must be a finite number > 0")]
    Scale(&'static str),
    /// A Riccati equation has no stabilising solution, or its iteration did not settle.
    #[error(
        "{fields}: the {which} Riccati equation did not converge to a stabilising solution ({why})"
    )]
    Riccati {
        /// "regulator" or "estimator".
        which: &'static str,
        /// The fields that set it.
        fields: &'static str,
        /// The likely cause.
        why: &'static str,
    },
    /// A Riccati solution's residual is too large, or a designed pole is not inside
    /// the unit circle.
    #[error("{fields}: the {which} design is not accurate or not stable (relative residual {residual:.1e}, largest pole modulus {modulus:.9}): the weights are out of range")]
    Inaccurate {
        /// "regulator" or "estimator".
        which: &'static str,
        /// The fields that set it.
        fields: &'static str,
        /// ‖residual‖/‖X‖.
        residual: f64,
        /// Largest |λ|.
        modulus: f64,
    },
    /// A gain is too large for `f32`.
    #[error("lqg: the gains do not fit single precision (weights out of range)")]
    Gains,
}

const REGULATOR_FIELDS: &str = "lqg.position_weight, lqg.integral_weight, lqg.command_weight";
const ESTIMATOR_FIELDS: &str = "lqg.load_noise, lqg.encoder_noise";

/// Largest accepted relative residual ‖res‖/‖X‖ of a Riccati solution.
pub const RESIDUAL_TOLERANCE: f64 = 1e-9;

/// A design: the core's gains and the `f64` quantities behind them, for reports.
#[derive(Clone, Debug, PartialEq)]
pub struct LqgDesign {
    /// The gains for the core, rounded to `f32`.
    pub gains: LqgGains,
    /// Period T, s.
    pub period_s: f64,
    /// ω₀, rad/s: state i is the (i−1)th derivative of the output over ω₀^(i−1).
    pub state_scale_rad_s: f64,
    /// Φ − I.
    pub phi_minus_i: Vec<Vec<f64>>,
    /// Γ.
    pub gamma: Vec<f64>,
    /// C (counts per unit of each state).
    pub c: Vec<f64>,
    /// State feedback K, c.u. per unit of each state.
    pub k: Vec<f64>,
    /// Integral gain ki, c.u. per (count·s).
    pub ki: f64,
    /// Kalman gain M (current estimator).
    pub m: Vec<f64>,
    /// Regulator Riccati solution (augmented with the integral).
    pub regulator_riccati: Vec<Vec<f64>>,
    /// Estimator Riccati solution (predicted error covariance, counts²·…).
    pub estimator_riccati: Vec<Vec<f64>>,
    /// ‖res‖/‖X‖ of the regulator DARE.
    pub regulator_residual: f64,
    /// ‖res‖/‖P‖ of the estimator DARE.
    pub estimator_residual: f64,
    /// eig(Φₐ − ΓₐKₐ), n + 1 poles.
    pub regulator_poles: Vec<Complex>,
    /// eig((I − MC)Φ), n poles.
    pub estimator_poles: Vec<Complex>,
}

impl LqgDesign {
    /// The closed loop's poles on the model: the regulator's and the estimator's
    /// (separation principle), all of modulus < 1.
    pub fn closed_loop_poles(&self) -> Vec<Complex> {
        let mut p = self.regulator_poles.clone();
        p.extend(&self.estimator_poles);
        p
    }
}

/// A model in delta form: x⁺ = x + E·x + Γ·u, y = C·x (counts).
struct Model {
    e: Mat,
    gamma: Vec<f64>,
    c: Vec<f64>,
    w0: f64,
}

fn positive(v: f64, what: &'static str) -> Result<(), LqgError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(LqgError::Scale(what))
    }
}

/// The scaled observer-form realisation of `tf`·`counts_per_unit`, discretised.
fn model(tf: &TransferFunction, counts_per_unit: f64, h: f64) -> Result<Model, LqgError> {
    positive(counts_per_unit, "steps_per_unit")?;
    positive(h, "servo period")?;
    let n = tf.order();
    if !(1..=LQG_STATES).contains(&n) {
        return Err(LqgError::Order(n));
    }
    if tf.num.len() > n {
        return Err(LqgError::NotStrictlyProper);
    }
    if tf.num[tf.num.len() - 1] == 0.0 {
        return Err(LqgError::ZeroAtOrigin);
    }
    let lead = tf.den[0];
    let a: Vec<f64> = tf.den[1..].iter().map(|x| x / lead).collect();
    let mut b = vec![0.0; n - tf.num.len()];
    b.extend(tf.num.iter().map(|x| x * counts_per_unit / lead));
    let w0 = a
        .iter()
        .enumerate()
        .map(|(i, x)| x.abs().powf(1.0 / (i + 1) as f64))
        .fold(0.0, f64::max);
    let w0 = if w0 > 0.0 && w0.is_finite() { w0 } else { 1.0 };
    // Augmented [[A, B], [0, 0]]·h of x̃ᵢ = xᵢ/ω₀ⁱ (0-based i).
    let mut aug = zeros(n + 1, n + 1);
    for i in 0..n {
        let s = w0.powi(i as i32);
        aug[i][0] = -a[i] / s * h;
        if i + 1 < n {
            aug[i][i + 1] = w0 * h;
        }
        aug[i][n] = b[i] / s * h;
    }
    let ex = expm(&aug);
    let mut e: Mat = ex[..n].iter().map(|r| r[..n].to_vec()).collect();
    for (i, row) in e.iter_mut().enumerate() {
        row[i] -= 1.0;
    }
    let mut c = vec![0.0; n];
    c[0] = 1.0;
    Ok(Model {
        e,
        gamma: ex[..n].iter().map(|r| r[n]).collect(),
        c,
        w0,
    })
}

fn check_weights(w: &LqgWeights) -> Result<(), LqgError> {
    let fields = [
        ("position_weight", w.position_weight, true),
        ("integral_weight", w.integral_weight, false),
        ("command_weight", w.command_weight, false),
        ("load_noise", w.load_noise, false),
        ("encoder_noise", w.encoder_noise, false),
    ];
    for (field, v, zero_ok) in fields {
        if !(v.is_finite() && (v > 0.0 || (zero_ok && v == 0.0))) {
            let rule = if zero_ok { ">= 0" } else { "> 0" };
            return Err(LqgError::Weight { field, rule });
        }
    }
    Ok(())
}

fn max_modulus(poles: &[Complex]) -> f64 {
    poles.iter().map(|p| p.abs()).fold(0.0, f64::max)
}

/// Solves one DARE and checks its residual and the resulting poles.
fn riccati(
    which: &'static str,
    fields: &'static str,
    why: &'static str,
    (a, b, q, r): (&Mat, &Mat, &Mat, &Mat),
) -> Result<(Mat, f64), LqgError> {
    let (x, residual) = dare(a, b, q, r).ok_or(LqgError::Riccati { which, fields, why })?;
    let accurate = residual <= RESIDUAL_TOLERANCE; // false for NaN too
    if !accurate {
        return Err(LqgError::Inaccurate {
            which,
            fields,
            residual,
            modulus: f64::NAN,
        });
    }
    Ok((x, residual))
}

/// Designs the LQG controller of a joint with plant `tf` (mm or degrees per c.u.),
/// `counts_per_unit` encoder counts per mm or degree, at `period_s`, with weights
/// `w` (see the module documentation).
pub fn design(
    tf: &TransferFunction,
    counts_per_unit: f64,
    period_s: f64,
    w: &LqgWeights,
) -> Result<LqgDesign, LqgError> {
    check_weights(w)?;
    let h = period_s;
    let md = model(tf, counts_per_unit, h)?;
    let n = md.e.len();
    // Regulator: [x; z]⁺ = [[Φ, 0], [T·C, 1]]·[x; z] + [Γ; 0]·u.
    let mut phi_a = zeros(n + 1, n + 1);
    for i in 0..n {
        for j in 0..n {
            phi_a[i][j] = md.e[i][j] + if i == j { 1.0 } else { 0.0 };
        }
        phi_a[n][i] = h * md.c[i];
    }
    phi_a[n][n] = 1.0;
    let mut gamma_a = md.gamma.clone();
    gamma_a.push(0.0);
    let gamma_a = col(&gamma_a);
    let mut q = zeros(n + 1, n + 1);
    q[0][0] = w.position_weight;
    q[n][n] = w.integral_weight;
    let r = vec![vec![w.command_weight]];
    let (x, regulator_residual) = riccati(
        "regulator",
        REGULATOR_FIELDS,
        "the model with the error integral is not stabilisable, or the weights are out of range",
        (&phi_a, &gamma_a, &q, &r),
    )?;
    let ka = lqr_gain(&phi_a, &gamma_a, &r, &x).ok_or(LqgError::Gains)?;
    let (k, ki) = (ka[0][..n].to_vec(), ka[0][n]);
    let mut e_a = add(&phi_a, -1.0, &mul(&gamma_a, &ka));
    for (i, row) in e_a.iter_mut().enumerate() {
        row[i] -= 1.0;
    }
    let regulator_poles = eigenvalues_delta(&e_a, h);
    // Estimator: the dual DARE on (Φᵀ, Cᵀ) with W = σw²·ΓΓᵀ, V = σv².
    let phi = add(&md.e, 1.0, &linalg::eye(n));
    let g = col(&md.gamma);
    let wq = mul(&g, &linalg::t(&g))
        .iter()
        .map(|r| r.iter().map(|x| x * w.load_noise * w.load_noise).collect())
        .collect();
    let v = vec![vec![w.encoder_noise * w.encoder_noise]];
    let ct = col(&md.c);
    let (p, estimator_residual) = riccati(
        "estimator",
        ESTIMATOR_FIELDS,
        "the model has cancelling poles and zeros, or the noise levels are out of range",
        (&linalg::t(&phi), &ct, &wq, &v),
    )?;
    let pct = mul(&p, &ct);
    let m = solve(&add(&v, 1.0, &mul(&linalg::t(&ct), &pct)), &linalg::t(&pct))
        .ok_or(LqgError::Gains)?[0]
        .clone();
    let mc_phi = mul(&mul(&col(&m), &vec![md.c.clone()]), &phi);
    let estimator_poles = eigenvalues_delta(&add(&md.e, -1.0, &mc_phi), h);
    for (which, fields, poles, residual) in [
        (
            "regulator",
            REGULATOR_FIELDS,
            &regulator_poles,
            regulator_residual,
        ),
        (
            "estimator",
            ESTIMATOR_FIELDS,
            &estimator_poles,
            estimator_residual,
        ),
    ] {
        let modulus = max_modulus(poles);
        let stable = modulus < 1.0; // false for NaN too
        if !stable {
            return Err(LqgError::Inaccurate {
                which,
                fields,
                residual,
                modulus,
            });
        }
    }
    let gains = to_gains(&md, &m, &k, ki * h)?;
    Ok(LqgDesign {
        gains,
        period_s: h,
        state_scale_rad_s: md.w0,
        phi_minus_i: md.e,
        gamma: md.gamma,
        c: md.c,
        k,
        ki,
        m,
        regulator_riccati: x,
        estimator_riccati: p,
        regulator_residual,
        estimator_residual,
        regulator_poles,
        estimator_poles,
    })
}

fn to_gains(md: &Model, m: &[f64], k: &[f64], ki_t: f64) -> Result<LqgGains, LqgError> {
    let mut g = LqgGains {
        order: md.e.len() as u8,
        phi_minus_i: [[0.0; LQG_STATES]; LQG_STATES],
        gamma: [0.0; LQG_STATES],
        c: [0.0; LQG_STATES],
        m: [0.0; LQG_STATES],
        k: [0.0; LQG_STATES],
        ki_t: ki_t as f32,
    };
    for (i, row) in md.e.iter().enumerate() {
        for (j, v) in row.iter().enumerate() {
            g.phi_minus_i[i][j] = *v as f32;
        }
        g.gamma[i] = md.gamma[i] as f32;
        g.c[i] = md.c[i] as f32;
        g.m[i] = m[i] as f32;
        g.k[i] = k[i] as f32;
    }
    if g.is_valid() {
        Ok(g)
    } else {
        Err(LqgError::Gains)
    }
}

/// The largest peak sensitivity max |1/(1 + L)| a tuned LQG design may have on its
/// model: |S|max ≤ 1.30 keeps the phase margin at least 2·asin(1/(2·1.30)) = 45.2° and
/// the gain margin at least 20·log10(1.30/0.30) = 12.7 dB.
pub const TUNED_MAX_SENSITIVITY: f64 = 1.30;

/// What [`raise_weights`] found: the weights, the design of them on the model and its
/// figures there.
#[derive(Clone, Debug)]
pub struct RaisedWeights {
    /// The weights: the given ones with `position_weight` and `integral_weight` both
    /// multiplied by `scale`.
    pub weights: LqgWeights,
    /// The factor, 1 when no raise kept the bounds.
    pub scale: f64,
    /// The design of `weights` on the model.
    pub design: LqgDesign,
    /// Its figures on the model.
    pub figures: LoopFigures,
}

/// The weights `w` with the regulator's position and integral weights raised together
/// by the largest factor, from 1 up to 10⁴ in steps of 10^0.1, whose design on `tf`
/// keeps its crossover at most `max_crossover_rad_s`, its peak sensitivity at most
/// [`TUNED_MAX_SENSITIVITY`] and its closed loop stable: a faster loop of the same
/// shape (the ratio of the two weights, the command's weight and the estimator's
/// noise levels kept). The search stops at the first factor that breaks a bound; when
/// factor 1 breaks one, `w` is returned as it is, designed on `tf`.
pub fn raise_weights(
    tf: &TransferFunction,
    counts_per_unit: f64,
    period_s: f64,
    w: &LqgWeights,
    max_crossover_rad_s: f64,
) -> Result<RaisedWeights, LqgError> {
    let trial = |scale: f64| -> Result<RaisedWeights, LqgError> {
        // Five significant digits, as the machine file will hold them.
        let round = |x: f64| format!("{x:.4e}").parse::<f64>().unwrap_or(x);
        let weights = LqgWeights {
            position_weight: round(w.position_weight * scale),
            integral_weight: round(w.integral_weight * scale),
            ..*w
        };
        let design = design(tf, counts_per_unit, period_s, &weights)?;
        let figures = design.loop_figures(tf, counts_per_unit)?;
        Ok(RaisedWeights {
            weights,
            scale,
            design,
            figures,
        })
    };
    let within = |r: &RaisedWeights| {
        r.figures.crossover_rad_s <= max_crossover_rad_s
            && r.figures.peak_sensitivity <= TUNED_MAX_SENSITIVITY
            && r.figures.max_pole < 1.0
    };
    let mut best = trial(1.0)?;
    if !within(&best) {
        return Ok(best);
    }
    for k in 1..=40 {
        match trial(10f64.powf(k as f64 / 10.0)) {
            Ok(r) if within(&r) => best = r,
            _ => break,
        }
    }
    Ok(best)
}

/// The weights as a TOML inline table for a machine file.
pub fn weights_toml(w: &LqgWeights) -> String {
    format!(
        "{{ position_weight = {:e}, integral_weight = {:e}, command_weight = {:e}, \
         load_noise = {:e}, encoder_noise = {:e} }}",
        w.position_weight, w.integral_weight, w.command_weight, w.load_noise, w.encoder_noise
    )
}

/// The gains as a TOML inline table for a machine file: every value printed with
/// the shortest digits that read back to the same `f32` (`{:e}`), all arrays at
/// their full size of [`LQG_STATES`].
pub fn gains_toml(g: &LqgGains) -> String {
    let list = |xs: &[f32]| {
        let items: Vec<String> = xs.iter().map(|x| format!("{x:e}")).collect();
        format!("[{}]", items.join(", "))
    };
    let rows: Vec<String> = g.phi_minus_i.iter().map(|r| list(r)).collect();
    format!(
        "{{ order = {}, phi_minus_i = [{}], gamma = {}, c = {}, m = {}, k = {}, ki_t = {:e} }}",
        g.order,
        rows.join(", "),
        list(&g.gamma),
        list(&g.c),
        list(&g.m),
        list(&g.k),
        g.ki_t
    )
}

/// A discrete compensator or plant in delta form: ξ⁺ = ξ + E·ξ + B·in,
/// out = C·ξ + D·in.
struct Discrete {
    e: Mat,
    b: Vec<f64>,
    c: Vec<f64>,
    d: f64,
}

/// How a loop behaves on a plant (the judgement of docs/contour.md's PID rule).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoopFigures {
    /// max |S| = max |1/(1 + L)| over 0.1 rad/s to Nyquist.
    pub peak_sensitivity: f64,
    /// The highest frequency where |L| falls through 1, rad/s.
    pub crossover_rad_s: f64,
    /// |P·S| at 1 Hz: following error per unit of load at the plant input, counts
    /// per c.u. (µm per c.u. at 1 µm per count).
    pub load_response_1hz: f64,
    /// The closed loop's largest pole modulus (< 1: stable).
    pub max_pole: f64,
}

impl LqgDesign {
    /// The compensator from δy (counts) to δu (c.u.), unsaturated, with the state
    /// [x̂ predicted; z]: the core's update in state-space form.
    fn compensator(&self) -> Discrete {
        let n = self.c.len();
        let h = self.period_s;
        let phi = add(&self.phi_minus_i, 1.0, &linalg::eye(n));
        let gk = mul(&col(&self.gamma), &vec![self.k.clone()]);
        let phi_cl = add(&phi, -1.0, &gk); // Φ − ΓK
        let mc = mul(&col(&self.m), &vec![self.c.clone()]);
        // (Φ − ΓK)(I − MC) − I = E − ΓK − (Φ − ΓK)MC.
        let top = add(&add(&self.phi_minus_i, -1.0, &gk), -1.0, &mul(&phi_cl, &mc));
        let mut e = zeros(n + 1, n + 1);
        for i in 0..n {
            e[i][..n].copy_from_slice(&top[i][..n]);
            e[i][n] = -self.gamma[i] * self.ki;
        }
        let mut b: Vec<f64> = mul(&phi_cl, &col(&self.m)).iter().map(|r| r[0]).collect();
        b.push(h);
        let k_imc = mul(&vec![self.k.clone()], &add(&linalg::eye(n), -1.0, &mc));
        let mut c: Vec<f64> = k_imc[0].iter().map(|x| -x).collect();
        c.push(-self.ki);
        let d = -self.k.iter().zip(&self.m).map(|(k, m)| k * m).sum::<f64>();
        Discrete { e, b, c, d }
    }

    /// [`LoopFigures`] of this design on `plant` (mm or degrees per c.u., the model or
    /// a mismatched one), measured and commanded as the core runs it.
    pub fn loop_figures(
        &self,
        plant: &TransferFunction,
        counts_per_unit: f64,
    ) -> Result<LoopFigures, LqgError> {
        let p = model(plant, counts_per_unit, self.period_s)?;
        Ok(figures(&self.compensator(), &p, self.period_s))
    }
}

/// [`LoopFigures`] of the core's PID loop (docs/contour.md; gains per count as in
/// `ServoGains`) on `plant`: I accumulates ki·T·e including this period's error,
/// the derivative is the difference of errors over T.
pub fn pid_loop_figures(
    plant: &TransferFunction,
    counts_per_unit: f64,
    period_s: f64,
    [kp, ki, kd]: [f64; 3],
) -> Result<LoopFigures, LqgError> {
    let p = model(plant, counts_per_unit, period_s)?;
    Ok(figures(&pid(period_s, [kp, ki, kd]), &p, period_s))
}

/// The core's PID as a compensator from y to u (gains per count, period `h` s).
fn pid(h: f64, [kp, ki, kd]: [f64; 3]) -> Discrete {
    // State [I of the last period; e of the last period], e = −y.
    Discrete {
        e: vec![vec![0.0, 0.0], vec![0.0, -1.0]],
        b: vec![-ki * h, -1.0],
        c: vec![1.0, -kd / h],
        d: -(kp + kd / h + ki * h),
    }
}

/// The frequency responses behind [`pid_loop_figures`] at each of `ws` rad/s: the
/// plant P(z) as the core sees it (`plant` held over each period, sampled at its end:
/// encoder counts per c.u.) and the loop gain L(z) = C(z)·P(z) of the core's PID
/// (z = e^{jωT}, T = `period_s`).
pub fn pid_loop_response(
    plant: &TransferFunction,
    counts_per_unit: f64,
    period_s: f64,
    gains: [f64; 3],
    ws: &[f64],
) -> Result<Vec<(Complex, Complex)>, LqgError> {
    let p = model(plant, counts_per_unit, period_s)?;
    let k = pid(period_s, gains);
    Ok(ws
        .iter()
        .map(|&w| {
            let pz = response(&p.e, &p.gamma, &p.c, 0.0, w, period_s);
            let kz = response(&k.e, &k.b, &k.c, k.d, w, period_s);
            let l = Complex {
                re: -(kz.re * pz.re - kz.im * pz.im),
                im: -(kz.re * pz.im + kz.im * pz.re),
            };
            (pz, l)
        })
        .collect())
}

fn figures(k: &Discrete, p: &Model, h: f64) -> LoopFigures {
    let plant = Discrete {
        e: p.e.clone(),
        b: p.gamma.clone(),
        c: p.c.clone(),
        d: 0.0,
    };
    let at = |w: f64| {
        let pz = response(&plant.e, &plant.b, &plant.c, 0.0, w, h);
        let kz = response(&k.e, &k.b, &k.c, k.d, w, h);
        // L = −K(z)·P(z) (the compensator maps y to u).
        let l = Complex {
            re: -(kz.re * pz.re - kz.im * pz.im),
            im: -(kz.re * pz.im + kz.im * pz.re),
        };
        (pz, l)
    };
    let (mut peak, mut crossover, mut above) = (0.0f64, 0.0f64, false);
    let top = (0.95 * std::f64::consts::PI / h).log10();
    for i in 0..=4000 {
        let w = 10f64.powf(-1.0 + (top + 1.0) * i as f64 / 4000.0);
        let (_, l) = at(w);
        let one_plus = Complex {
            re: 1.0 + l.re,
            im: l.im,
        };
        peak = peak.max(1.0 / one_plus.abs());
        let over = l.abs() > 1.0;
        if above && !over {
            crossover = w;
        }
        above = over;
    }
    let (pz, l) = at(std::f64::consts::TAU);
    let one_plus = Complex {
        re: 1.0 + l.re,
        im: l.im,
    };
    LoopFigures {
        peak_sensitivity: peak,
        crossover_rad_s: crossover,
        load_response_1hz: pz.abs() / one_plus.abs(),
        max_pole: max_modulus(&closed_loop_poles(k, &plant, h)),
    }
}

/// Poles of plant and compensator in feedback: y = C_p·x_p, u = C_k·ξ + D_k·y.
fn closed_loop_poles(k: &Discrete, p: &Discrete, h: f64) -> Vec<Complex> {
    let (np, nk) = (p.e.len(), k.e.len());
    let mut e = zeros(np + nk, np + nk);
    for i in 0..np {
        for j in 0..np {
            e[i][j] = p.e[i][j] + p.b[i] * k.d * p.c[j];
        }
        for j in 0..nk {
            e[i][np + j] = p.b[i] * k.c[j];
        }
    }
    for i in 0..nk {
        for j in 0..np {
            e[np + i][j] = k.b[i] * p.c[j];
        }
        e[np + i][np..].copy_from_slice(&k.e[i]);
    }
    eigenvalues_delta(&e, h)
}
