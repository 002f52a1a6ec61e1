//! Plant models for simulation: a transfer function G(s) = N(s)/D(s) (polynomials in s,
//! highest power first) turned into a discrete state-space model at the servo period
//! and stepped under a held input.
//!
//! * Realisation: controllable canonical form of the monic denominator
//!   D(s) = sⁿ + a₁sⁿ⁻¹ + … + aₙ, with N(s) split into its strictly proper part and a
//!   direct term d (the leading coefficient when deg N = deg D).
//! * Discretisation: exact zero-order hold at the period h,
//!   Φ = e^{Ah}, Γ = ∫₀ʰ e^{Aτ}dτ·B, both read off the exponential of the augmented
//!   matrix [[A, B], [0, 0]]·h (scaling and squaring of a 20-term Taylor series, in f64).
//! * Stepping: x ← Φx + Γu, y = Cx + du, with u constant over the period (a DAC holds
//!   its value).
//!
//! A machine file gives a servo joint its plant as
//! `plant = { num = [...], den = [...], input_per_count = 0.1 }`: the model's input is
//! in command units (c.u., the servo loop's output unit), one DAC count above mid-scale
//! being `input_per_count` c.u.; its output is the joint's displacement in mm (or
//! degrees) from where it started (identified models describe motion about an
//! operating point).
//!
//! [`Mismatch`] makes the "true" plant of a robustness study from a model: a gain
//! factor, and every lightly damped pole pair moved to another natural frequency at
//! the same damping ratio, normalised so the low-frequency response changes by the
//! gain factor alone.

use serde::Deserialize;

/// Why a transfer function is refused; each message names its field of the machine
/// file's `plant` table.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum PlantError {
    /// A coefficient is NaN or infinite.
    #[error("plant: coefficients must be finite numbers")]
    NotFinite,
    /// The denominator's order is 0 or above [`MAX_ORDER`].
    #[error("plant.den: order must be 1..={MAX_ORDER}")]
    Order,
    /// The numerator is zero or of higher order than the denominator.
    #[error("plant.num: must be non-zero and of order at most the denominator's")]
    Numerator,
}

/// A servo joint's `plant = { ... }` table in a machine file.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PlantFile {
    /// Numerator coefficients, highest power of s first.
    pub num: Vec<f64>,
    /// Denominator coefficients, highest power of s first.
    pub den: Vec<f64>,
    /// Command units per DAC count above mid-scale.
    pub input_per_count: f64,
    /// Simulator only: the standard deviation of a Gaussian noise added to the
    /// encoder's reading before it is rounded to whole counts, counts (0: none; seeded
    /// by the channel, so that runs repeat).
    #[serde(default)]
    pub encoder_noise: f64,
}

/// Highest model order accepted.
pub const MAX_ORDER: usize = 8;

/// G(s) = num(s)/den(s), coefficients highest power first.
#[derive(Clone, Debug, PartialEq)]
pub struct TransferFunction {
    /// Numerator.
    pub num: Vec<f64>,
    /// Denominator.
    pub den: Vec<f64>,
}

/// A complex number, for poles.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Complex {
    /// Real part.
    pub re: f64,
    /// Imaginary part.
    pub im: f64,
}

impl Complex {
    /// re + j·im.
    pub const fn new(re: f64, im: f64) -> Complex {
        Complex { re, im }
    }
    /// e^{jθ}.
    pub fn expj(theta: f64) -> Complex {
        Complex {
            re: theta.cos(),
            im: theta.sin(),
        }
    }
    /// Times a real number.
    pub fn scale(self, k: f64) -> Complex {
        Complex {
            re: self.re * k,
            im: self.im * k,
        }
    }
    /// Argument, rad, in (−π, π].
    pub fn arg(self) -> f64 {
        self.im.atan2(self.re)
    }
    fn mul(self, o: Complex) -> Complex {
        Complex {
            re: self.re * o.re - self.im * o.im,
            im: self.re * o.im + self.im * o.re,
        }
    }
    fn sub(self, o: Complex) -> Complex {
        Complex {
            re: self.re - o.re,
            im: self.im - o.im,
        }
    }
    fn div(self, o: Complex) -> Complex {
        let d = o.re * o.re + o.im * o.im;
        Complex {
            re: (self.re * o.re + self.im * o.im) / d,
            im: (self.im * o.re - self.re * o.im) / d,
        }
    }
    /// Magnitude.
    pub fn abs(self) -> f64 {
        self.re.hypot(self.im)
    }
}

impl std::ops::Add for Complex {
    type Output = Complex;
    fn add(self, o: Complex) -> Complex {
        Complex::new(self.re + o.re, self.im + o.im)
    }
}

impl std::ops::Sub for Complex {
    type Output = Complex;
    fn sub(self, o: Complex) -> Complex {
        Complex::sub(self, o)
    }
}

impl std::ops::Mul for Complex {
    type Output = Complex;
    fn mul(self, o: Complex) -> Complex {
        Complex::mul(self, o)
    }
}

impl std::ops::Div for Complex {
    type Output = Complex;
    fn div(self, o: Complex) -> Complex {
        Complex::div(self, o)
    }
}

fn trim(p: &[f64]) -> Vec<f64> {
    let first = p.iter().position(|&c| c != 0.0).unwrap_or(p.len());
    p[first..].to_vec()
}

/// Evaluates polynomial `p` (highest power first) at `s`.
pub fn polyval(p: &[f64], s: Complex) -> Complex {
    let mut acc = Complex { re: 0.0, im: 0.0 };
    for &c in p {
        acc = acc.mul(s);
        acc.re += c;
    }
    acc
}

/// Roots of `p` (highest power first, degree ≥ 1) by the Durand–Kerner iteration.
pub fn roots(p: &[f64]) -> Vec<Complex> {
    let p = trim(p);
    let n = p.len() - 1;
    let monic: Vec<f64> = p.iter().map(|c| c / p[0]).collect();
    let radius = 1.0 + monic[1..].iter().fold(0.0f64, |m, c| m.max(c.abs()));
    let mut z: Vec<Complex> = (0..n)
        .map(|k| {
            let a = 0.4 + std::f64::consts::TAU * k as f64 / n as f64;
            Complex {
                re: radius * a.cos(),
                im: radius * a.sin(),
            }
        })
        .collect();
    for _ in 0..2000 {
        let mut moved = 0.0f64;
        for i in 0..n {
            let mut den = Complex { re: 1.0, im: 0.0 };
            for j in 0..n {
                if i != j {
                    den = den.mul(z[i].sub(z[j]));
                }
            }
            let step = polyval(&monic, z[i]).div(den);
            z[i] = z[i].sub(step);
            moved = moved.max(step.abs() / (1.0 + z[i].abs()));
        }
        if moved < 1e-15 {
            break;
        }
    }
    for r in &mut z {
        if r.im.abs() < 1e-9 * (1.0 + r.re.abs()) {
            r.im = 0.0;
        }
    }
    z
}

/// Multiplies two polynomials.
pub fn polymul(a: &[f64], b: &[f64]) -> Vec<f64> {
    let mut out = vec![0.0; a.len() + b.len() - 1];
    for (i, x) in a.iter().enumerate() {
        for (j, y) in b.iter().enumerate() {
            out[i + j] += x * y;
        }
    }
    out
}

/// How a study's "true" plant differs from the model the controller uses.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Mismatch {
    /// Factor on the plant gain.
    pub gain: f64,
    /// Factor on the natural frequency of every complex pole pair (damping kept).
    pub resonance: f64,
}

impl Mismatch {
    /// The model itself.
    pub const NONE: Mismatch = Mismatch {
        gain: 1.0,
        resonance: 1.0,
    };
}

impl TransferFunction {
    /// Checks the coefficients: finite, a non-zero denominator of order 1..=
    /// [`MAX_ORDER`], and a proper numerator.
    pub fn new(num: &[f64], den: &[f64]) -> Result<Self, PlantError> {
        if num.iter().chain(den).any(|c| !c.is_finite()) {
            return Err(PlantError::NotFinite);
        }
        let (num, den) = (trim(num), trim(den));
        if den.len() < 2 || den.len() > MAX_ORDER + 1 {
            return Err(PlantError::Order);
        }
        if num.is_empty() || num.len() > den.len() {
            return Err(PlantError::Numerator);
        }
        Ok(Self { num, den })
    }

    /// Order (degree of the denominator).
    pub fn order(&self) -> usize {
        self.den.len() - 1
    }

    /// Frequency response at ω rad/s.
    pub fn at(&self, w: f64) -> Complex {
        let s = Complex { re: 0.0, im: w };
        polyval(&self.num, s).div(polyval(&self.den, s))
    }

    /// Poles.
    pub fn poles(&self) -> Vec<Complex> {
        roots(&self.den)
    }

    /// The plant with `m` applied (see [`Mismatch`]).
    pub fn perturbed(&self, m: Mismatch) -> Self {
        let mut den = vec![self.den[0]];
        let mut num: Vec<f64> = self.num.iter().map(|c| c * m.gain).collect();
        for p in self.poles() {
            if p.im > 0.0 {
                // (s² + 2ζωs + ω²)/ω²  →  (s² + 2ζω's + ω'²)/ω'².
                let w = p.abs();
                let zeta = -p.re / w;
                let w2 = w * m.resonance;
                den = polymul(&den, &[1.0, 2.0 * zeta * w2, w2 * w2]);
                num = num.iter().map(|c| c * (w2 * w2) / (w * w)).collect();
            } else if p.im == 0.0 {
                den = polymul(&den, &[1.0, -p.re]);
            }
        }
        Self { num, den }
    }

    /// Low-frequency velocity gain (output rate per unit input) of a plant that
    /// behaves as an integrator above its slowest pole: num(0)/den's s¹ coefficient.
    pub fn velocity_gain(&self) -> f64 {
        let n = self.den.len();
        self.num[self.num.len() - 1] / self.den[n - 2]
    }

    /// Feed-forward that inverts the model at low frequency for a ramp-like reference:
    /// the coefficients (c₁, c₂) of u ≈ c₀·r + c₁·ṙ + c₂·r̈ from the series of
    /// 1/G(s) = D(s)/N(s) around s = 0 (c₀ returned first).
    pub fn inverse_series(&self) -> [f64; 3] {
        let b: Vec<f64> = self.num.iter().rev().cloned().collect(); // b0 + b1 s + …
        let a: Vec<f64> = self.den.iter().rev().cloned().collect();
        let get = |v: &Vec<f64>, i: usize| v.get(i).copied().unwrap_or(0.0);
        let c0 = get(&a, 0) / b[0];
        let c1 = (get(&a, 1) - get(&b, 1) * c0) / b[0];
        let c2 = (get(&a, 2) - get(&b, 1) * c1 - get(&b, 2) * c0) / b[0];
        [c0, c1, c2]
    }

    /// The discrete model at period `h` seconds (see the module documentation).
    pub fn discretize(&self, h: f64) -> DiscretePlant {
        let n = self.order();
        let lead = self.den[0];
        let a: Vec<f64> = self.den.iter().map(|c| c / lead).collect();
        let mut b: Vec<f64> = vec![0.0; n + 1 - self.num.len()];
        b.extend(self.num.iter().map(|c| c / lead));
        let d = b[0];
        // Strictly proper part: b_i − d·a_i, i = 1..n (powers s^{n−i}).
        let c: Vec<f64> = (1..=n).rev().map(|i| b[i] - d * a[i]).collect();
        // Controllable canonical form: ẋ_i = x_{i+1}, ẋ_n = −Σ a_{n−i} x_{i+1} + u,
        // y = Σ c_i x_{i+1} (c ordered from s⁰ to s^{n−1}).
        let m = n + 1;
        let mut aug = vec![vec![0.0; m]; m];
        for i in 0..n - 1 {
            aug[i][i + 1] = h;
        }
        for j in 0..n {
            aug[n - 1][j] = -a[n - j] * h;
        }
        aug[n - 1][n] = h;
        let e = expm(&aug);
        DiscretePlant {
            phi: (0..n).map(|i| e[i][..n].to_vec()).collect(),
            gamma: (0..n).map(|i| e[i][n]).collect(),
            c,
            d,
            x: vec![0.0; n],
        }
    }
}

fn matmul(a: &[Vec<f64>], b: &[Vec<f64>]) -> Vec<Vec<f64>> {
    let n = a.len();
    let mut out = vec![vec![0.0; n]; n];
    for i in 0..n {
        for k in 0..n {
            let aik = a[i][k];
            if aik != 0.0 {
                for j in 0..n {
                    out[i][j] += aik * b[k][j];
                }
            }
        }
    }
    out
}

/// Matrix exponential by scaling and squaring a 20-term Taylor series.
pub(crate) fn expm(m: &[Vec<f64>]) -> Vec<Vec<f64>> {
    let n = m.len();
    let norm = m
        .iter()
        .map(|r| r.iter().map(|v| v.abs()).sum::<f64>())
        .fold(0.0, f64::max);
    let mut squarings = 0;
    let mut scale = 1.0;
    while norm * scale > 0.5 {
        scale *= 0.5;
        squarings += 1;
    }
    let a: Vec<Vec<f64>> = m
        .iter()
        .map(|r| r.iter().map(|v| v * scale).collect())
        .collect();
    let mut sum: Vec<Vec<f64>> = (0..n)
        .map(|i| (0..n).map(|j| if i == j { 1.0 } else { 0.0 }).collect())
        .collect();
    let mut term = sum.clone();
    for k in 1..=20 {
        term = matmul(&term, &a);
        for row in &mut term {
            for v in row.iter_mut() {
                *v /= k as f64;
            }
        }
        for i in 0..n {
            for j in 0..n {
                sum[i][j] += term[i][j];
            }
        }
    }
    for _ in 0..squarings {
        sum = matmul(&sum, &sum);
    }
    sum
}

/// A discretised plant with its state.
#[derive(Clone, Debug, PartialEq)]
pub struct DiscretePlant {
    phi: Vec<Vec<f64>>,
    gamma: Vec<f64>,
    c: Vec<f64>,
    d: f64,
    x: Vec<f64>,
}

impl DiscretePlant {
    /// Output under input `u` (the direct term uses the input being applied).
    pub fn output(&self, u: f64) -> f64 {
        self.c.iter().zip(&self.x).map(|(c, x)| c * x).sum::<f64>() + self.d * u
    }

    /// Advances one period with `u` held.
    pub fn step(&mut self, u: f64) {
        let x: Vec<f64> = self
            .phi
            .iter()
            .zip(&self.gamma)
            .map(|(row, g)| row.iter().zip(&self.x).map(|(p, x)| p * x).sum::<f64>() + g * u)
            .collect();
        self.x = x;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_first_order_lag_matches_its_exact_step_response() {
        // G = 2/(0.5 s + 1): y(t) = 2(1 − e^{−2t}).
        let g = TransferFunction::new(&[2.0], &[0.5, 1.0]).unwrap();
        let mut p = g.discretize(1e-3);
        for _ in 0..500 {
            p.step(1.0);
        }
        let want = 2.0 * (1.0 - (-1.0f64).exp());
        assert!((p.output(1.0) - want).abs() < 1e-12, "{}", p.output(1.0));
    }

    #[test]
    fn a_double_integrator_under_a_held_input_is_exact() {
        // 1/s²: a unit input for 1 s moves 0.5.
        let g = TransferFunction::new(&[1.0], &[1.0, 0.0, 0.0]).unwrap();
        let mut p = g.discretize(0.01);
        for _ in 0..100 {
            p.step(1.0);
        }
        assert!((p.output(0.0) - 0.5).abs() < 1e-12);
    }

    #[test]
    fn a_biproper_plant_passes_its_direct_term() {
        // (s + 3)/(s + 1) = 1 + 2/(s + 1).
        let g = TransferFunction::new(&[1.0, 3.0], &[1.0, 1.0]).unwrap();
        let p = g.discretize(1e-3);
        assert_eq!(p.output(1.0), 1.0);
    }

    #[test]
    fn roots_of_the_report_s_table_x_model_are_found() {
        let g =
            TransferFunction::new(&[0.237, 9.691, 462.2], &[1.0, 12.79, 2526.0, 43.27]).unwrap();
        let mut p = g.poles();
        p.sort_by(|a, b| a.im.partial_cmp(&b.im).unwrap());
        assert!((p[1].re + 0.017131).abs() < 1e-5 && p[1].im == 0.0, "{p:?}");
        assert!((p[2].re + 6.386434).abs() < 1e-5 && (p[2].im - 49.849721).abs() < 1e-5);
    }

    #[test]
    fn a_mismatch_moves_the_resonance_and_scales_the_low_frequency_gain_only() {
        let g =
            TransferFunction::new(&[0.237, 9.691, 462.2], &[1.0, 12.79, 2526.0, 43.27]).unwrap();
        let t = g.perturbed(Mismatch {
            gain: 1.1,
            resonance: 0.9,
        });
        let ratio = t.at(0.5).abs() / g.at(0.5).abs();
        assert!((ratio - 1.1).abs() < 2e-3, "{ratio}");
        let w = |tf: &TransferFunction| {
            tf.poles()
                .iter()
                .filter(|p| p.im > 0.0)
                .map(|p| p.abs())
                .next()
                .unwrap()
        };
        assert!((w(&t) / w(&g) - 0.9).abs() < 1e-9);
    }

    #[test]
    fn an_improper_or_empty_model_is_refused() {
        assert!(TransferFunction::new(&[1.0, 0.0, 0.0], &[1.0, 1.0]).is_err());
        assert!(TransferFunction::new(&[1.0], &[3.0]).is_err());
        assert!(TransferFunction::new(&[f64::NAN], &[1.0, 1.0]).is_err());
    }
}
