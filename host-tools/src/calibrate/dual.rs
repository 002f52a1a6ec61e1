//! Forward-mode differentiation: a number with its exact first derivatives.
//!
//! The calibration models are written once over [`Scalar`]; evaluated in `f64` they
//! give values, evaluated in [`Dual`] they give the same values and, by the chain rule
//! applied operation by operation, the analytic partial derivatives with respect to
//! every seeded variable (the parameters and the mechanism's internal pose). No step
//! size, no truncation error: the derivatives are exact to rounding.

use std::ops::{Add, Div, Mul, Neg, Sub};

/// Most variables a [`Dual`] carries: the largest model's parameters (48, the
/// hexapod-xy) and its internal pose (6).
pub const N: usize = 56;

/// The arithmetic the models need.
pub trait Scalar:
    Copy
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
{
    /// A constant.
    fn c(v: f64) -> Self;
    /// The value.
    fn v(self) -> f64;
    /// sin and cos.
    fn sin_cos(self) -> (Self, Self);
    /// Square root.
    fn sqrt(self) -> Self;
    /// atan2(self, x).
    fn atan2(self, x: Self) -> Self;
    /// asin.
    fn asin(self) -> Self;
}

impl Scalar for f64 {
    fn c(v: f64) -> Self {
        v
    }
    fn v(self) -> f64 {
        self
    }
    fn sin_cos(self) -> (Self, Self) {
        f64::sin_cos(self)
    }
    fn sqrt(self) -> Self {
        f64::sqrt(self)
    }
    fn atan2(self, x: Self) -> Self {
        f64::atan2(self, x)
    }
    fn asin(self) -> Self {
        f64::asin(self)
    }
}

/// A value and its gradient with respect to up to [`N`] variables.
#[derive(Clone, Copy, Debug)]
pub struct Dual {
    /// The value.
    pub v: f64,
    /// ∂value/∂variable k.
    pub d: [f64; N],
}

impl Dual {
    /// Variable number `k` at value `v`.
    pub fn var(v: f64, k: usize) -> Self {
        let mut d = [0.0; N];
        d[k] = 1.0;
        Dual { v, d }
    }

    /// The value with gradient `g·self.d` (the chain rule for a function of one
    /// argument whose derivative is `g`).
    fn chain(self, v: f64, g: f64) -> Self {
        let mut d = self.d;
        for x in &mut d {
            *x *= g;
        }
        Dual { v, d }
    }
}

impl Add for Dual {
    type Output = Dual;
    fn add(mut self, o: Dual) -> Dual {
        self.v += o.v;
        for (a, b) in self.d.iter_mut().zip(&o.d) {
            *a += b;
        }
        self
    }
}

impl Sub for Dual {
    type Output = Dual;
    fn sub(mut self, o: Dual) -> Dual {
        self.v -= o.v;
        for (a, b) in self.d.iter_mut().zip(&o.d) {
            *a -= b;
        }
        self
    }
}

impl Mul for Dual {
    type Output = Dual;
    fn mul(mut self, o: Dual) -> Dual {
        for (a, b) in self.d.iter_mut().zip(&o.d) {
            *a = *a * o.v + self.v * b;
        }
        self.v *= o.v;
        self
    }
}

impl Div for Dual {
    type Output = Dual;
    fn div(mut self, o: Dual) -> Dual {
        let inv = 1.0 / o.v;
        let q = self.v * inv;
        for (a, b) in self.d.iter_mut().zip(&o.d) {
            *a = (*a - q * b) * inv;
        }
        self.v = q;
        self
    }
}

impl Neg for Dual {
    type Output = Dual;
    fn neg(self) -> Dual {
        self.chain(-self.v, -1.0)
    }
}

impl Scalar for Dual {
    fn c(v: f64) -> Self {
        Dual { v, d: [0.0; N] }
    }
    fn v(self) -> f64 {
        self.v
    }
    fn sin_cos(self) -> (Self, Self) {
        let (s, c) = self.v.sin_cos();
        (self.chain(s, c), self.chain(c, -s))
    }
    fn sqrt(self) -> Self {
        let r = self.v.sqrt();
        self.chain(r, 0.5 / r)
    }
    fn atan2(self, x: Self) -> Self {
        // d atan2(y, x) = (x dy − y dx) / (x² + y²)
        let (y0, x0) = (self.v, x.v);
        let r2 = x0 * x0 + y0 * y0;
        let mut d = [0.0; N];
        for (k, o) in d.iter_mut().enumerate() {
            *o = (x0 * self.d[k] - y0 * x.d[k]) / r2;
        }
        Dual { v: y0.atan2(x0), d }
    }
    fn asin(self) -> Self {
        self.chain(self.v.asin(), 1.0 / (1.0 - self.v * self.v).sqrt())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn derivatives_match_central_differences() {
        let f = |x: Dual, y: Dual| {
            let (s, c) = (x * y).sin_cos();
            (s * x + c).sqrt() / (y + Dual::c(2.0)) + (x / Dual::c(3.0)).asin() + y.atan2(x)
        };
        let (x, y) = (0.7, 0.4);
        let out = f(Dual::var(x, 0), Dual::var(y, 1));
        let h = 1e-6;
        let fx = |x: f64, y: f64| f(Dual::c(x), Dual::c(y)).v;
        let dx = (fx(x + h, y) - fx(x - h, y)) / (2.0 * h);
        let dy = (fx(x, y + h) - fx(x, y - h)) / (2.0 * h);
        assert!((out.d[0] - dx).abs() < 1e-8, "{} {}", out.d[0], dx);
        assert!((out.d[1] - dy).abs() < 1e-8, "{} {}", out.d[1], dy);
    }
}
