//! Small dense `f64` linear algebra, the crate's one copy: products, a pivoted solve;
//! for the LQG design the discrete algebraic Riccati equation by structured doubling,
//! eigenvalues of matrices close to the identity, and frequency responses of discrete
//! state-space models written in delta form; for calibration the Gram matrix, the
//! one-sided Jacobi SVD and the Cholesky inverse.

// Matrix code reads best with its indices.
#![allow(clippy::needless_range_loop)]

use crate::control::plant::{roots, Complex};

/// A dense matrix, rows of equal length.
pub type Mat = Vec<Vec<f64>>;

/// An `r`×`c` matrix of zeros.
pub fn zeros(r: usize, c: usize) -> Mat {
    vec![vec![0.0; c]; r]
}

/// The `n`×`n` identity.
pub fn eye(n: usize) -> Mat {
    let mut m = zeros(n, n);
    for (i, row) in m.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    m
}

/// `a·b`.
pub fn mul(a: &Mat, b: &Mat) -> Mat {
    let mut out = zeros(a.len(), b[0].len());
    for (o, ar) in out.iter_mut().zip(a) {
        for (aik, br) in ar.iter().zip(b) {
            for (oj, bkj) in o.iter_mut().zip(br) {
                *oj += aik * bkj;
            }
        }
    }
    out
}

/// `aᵀ`.
pub fn t(a: &Mat) -> Mat {
    (0..a[0].len())
        .map(|j| a.iter().map(|r| r[j]).collect())
        .collect()
}

/// `a + s·b`.
pub fn add(a: &Mat, s: f64, b: &Mat) -> Mat {
    a.iter()
        .zip(b)
        .map(|(ra, rb)| ra.iter().zip(rb).map(|(x, y)| x + s * y).collect())
        .collect()
}

/// A column vector as a matrix.
pub fn col(v: &[f64]) -> Mat {
    v.iter().map(|x| vec![*x]).collect()
}

/// Largest absolute entry.
pub fn max_abs(a: &Mat) -> f64 {
    a.iter().flatten().fold(0.0, |m, x| m.max(x.abs()))
}

/// X with a·X = b, by Gaussian elimination with partial pivoting; `None` when `a`
/// is singular to working precision.
pub fn solve(a: &Mat, b: &Mat) -> Option<Mat> {
    let n = a.len();
    let scale = max_abs(a);
    let mut m: Mat = a
        .iter()
        .zip(b)
        .map(|(ra, rb)| ra.iter().chain(rb).copied().collect())
        .collect();
    for k in 0..n {
        let p = (k..n).max_by(|&i, &j| m[i][k].abs().total_cmp(&m[j][k].abs()))?;
        let regular = m[p][k].abs() > scale * 1e-14; // false for NaN too
        if !regular {
            return None;
        }
        m.swap(k, p);
        let pivot = m[k].clone();
        for row in m.iter_mut().skip(k + 1) {
            let f = row[k] / pivot[k];
            for (x, y) in row.iter_mut().zip(&pivot).skip(k) {
                *x -= f * y;
            }
        }
    }
    let w = b[0].len();
    let mut x = zeros(n, w);
    for i in (0..n).rev() {
        for j in 0..w {
            let s: f64 = (i + 1..n).map(|k| m[i][k] * x[k][j]).sum();
            x[i][j] = (m[i][n + j] - s) / m[i][i];
        }
    }
    Some(x)
}

/// x with a·x = b for a vector `b` ([`solve`] of one column).
pub fn solve_vec(a: Mat, b: Vec<f64>) -> Option<Vec<f64>> {
    if b.is_empty() {
        return Some(Vec::new());
    }
    let x = solve(&a, &col(&b))?;
    Some(x.into_iter().map(|r| r[0]).collect())
}

/// The stabilising solution X of the discrete algebraic Riccati equation
///
/// ```text
/// X = AᵀXA − AᵀXB(R + BᵀXB)⁻¹BᵀXA + Q
/// ```
///
/// (Q symmetric ≥ 0, R > 0), by the structured doubling algorithm (Chu, Fan, Lin and
/// Wang, 2004): with G = BR⁻¹Bᵀ, Aₖ₊₁ = Aₖ(I + GₖHₖ)⁻¹Aₖ,
/// Gₖ₊₁ = Gₖ + Aₖ(I + GₖHₖ)⁻¹GₖAₖᵀ, Hₖ₊₁ = Hₖ + AₖᵀHₖ(I + GₖHₖ)⁻¹Aₖ from
/// (A, G, Q); Hₖ → X quadratically, the error shrinking as ρ^(2ᵏ), ρ the largest
/// closed-loop pole modulus. Stops when an iteration changes H by less than 1e-13 of
/// its size; returns X and the relative residual ‖res‖/‖X‖ (max-abs norms), or `None`
/// when the iteration meets a singular matrix, a non-finite value or does not settle
/// in 200 steps (no stabilising solution: unstabilisable or undetectable).
pub fn dare(a: &Mat, b: &Mat, q: &Mat, r: &Mat) -> Option<(Mat, f64)> {
    let n = a.len();
    let rinv_bt = solve(r, &t(b))?;
    let (mut ak, mut gk, mut hk) = (a.clone(), mul(b, &rinv_bt), q.clone());
    for _ in 0..200 {
        let w = add(&eye(n), 1.0, &mul(&gk, &hk));
        let w_a = solve(&w, &ak)?; // (I + GH)⁻¹A
        let w_g = solve(&w, &gk)?; // (I + GH)⁻¹G
        let h_next = add(&hk, 1.0, &mul(&mul(&t(&ak), &hk), &w_a));
        let g_next = add(&gk, 1.0, &mul(&mul(&ak, &w_g), &t(&ak)));
        ak = mul(&ak, &w_a);
        let change = max_abs(&add(&h_next, -1.0, &hk));
        let size = max_abs(&h_next);
        if !size.is_finite() {
            return None;
        }
        hk = symmetric(&h_next);
        gk = symmetric(&g_next);
        if change <= 1e-13 * size {
            let res = residual(a, b, q, r, &hk)?;
            return Some((hk, res));
        }
    }
    None
}

fn symmetric(a: &Mat) -> Mat {
    add(a, 1.0, &t(a))
        .iter()
        .map(|r| r.iter().map(|x| 0.5 * x).collect())
        .collect()
}

/// ‖AᵀXA − AᵀXB(R + BᵀXB)⁻¹BᵀXA + Q − X‖ / ‖X‖.
pub fn residual(a: &Mat, b: &Mat, q: &Mat, r: &Mat, x: &Mat) -> Option<f64> {
    let gain = lqr_gain(a, b, r, x)?;
    let at_x = mul(&t(a), x);
    let rhs = add(
        &add(&mul(&at_x, a), -1.0, &mul(&mul(&at_x, b), &gain)),
        1.0,
        q,
    );
    Some(max_abs(&add(&rhs, -1.0, x)) / max_abs(x))
}

/// K = (R + BᵀXB)⁻¹BᵀXA, the optimal feedback u = −Kx of the DARE's solution X.
pub fn lqr_gain(a: &Mat, b: &Mat, r: &Mat, x: &Mat) -> Option<Mat> {
    let bt_x = mul(&t(b), x);
    solve(&add(r, 1.0, &mul(&bt_x, b)), &mul(&bt_x, a))
}

/// Characteristic polynomial of `a` (highest power first) by the Faddeev–LeVerrier
/// recursion.
fn charpoly(a: &Mat) -> Vec<f64> {
    let n = a.len();
    let mut coef = vec![1.0];
    let mut m = zeros(n, n);
    for k in 1..=n {
        let last = *coef.last().unwrap_or(&1.0);
        m = add(&m, last, &eye(n));
        let am = mul(a, &m);
        let trace: f64 = (0..n).map(|i| am[i][i]).sum();
        coef.push(-trace / k as f64);
        m = am;
    }
    coef
}

/// Eigenvalues λ of a discrete system matrix given in delta form, E = Φ − I, at
/// period `h`: the roots μ of det(sI − E/h) (spread over the loop's rates, rad/s,
/// where the λ cluster near 1 and their polynomial's roots would be ill-conditioned),
/// then λ = 1 + h·μ.
pub fn eigenvalues_delta(e: &Mat, h: f64) -> Vec<Complex> {
    let scaled: Mat = e
        .iter()
        .map(|r| r.iter().map(|x| x / h).collect())
        .collect();
    roots(&charpoly(&scaled))
        .into_iter()
        .map(|mu| Complex {
            re: 1.0 + h * mu.re,
            im: h * mu.im,
        })
        .collect()
}

/// Frequency response c·(zI − Φ)⁻¹·b + d at z = e^{jωh} of the discrete model with
/// E = Φ − I, from the real form of (z − 1)I − E (z − 1 without cancellation);
/// infinite at a pole.
pub fn response(e: &Mat, b: &[f64], c: &[f64], d: f64, w: f64, h: f64) -> Complex {
    let n = e.len();
    let half = (0.5 * w * h).sin();
    let (alpha, beta) = (-2.0 * half * half, (w * h).sin());
    let mut m = zeros(2 * n, 2 * n);
    for i in 0..n {
        for j in 0..n {
            let diag = if i == j { alpha } else { 0.0 };
            m[i][j] = diag - e[i][j];
            m[n + i][n + j] = diag - e[i][j];
        }
        m[i][n + i] = -beta;
        m[n + i][i] = beta;
    }
    let mut rhs = col(b);
    rhs.extend(std::iter::repeat_n(vec![0.0], n));
    let Some(v) = solve(&m, &rhs) else {
        // z is a pole of the model.
        return Complex {
            re: f64::INFINITY,
            im: 0.0,
        };
    };
    let dot = |off: usize| (0..n).map(|i| c[i] * v[off + i][0]).sum::<f64>();
    Complex {
        re: dot(0) + d,
        im: dot(n),
    }
}

/// `aᵀ·a`.
pub fn gram(a: &Mat, cols: usize) -> Mat {
    let mut g = vec![vec![0.0; cols]; cols];
    for row in a {
        for i in 0..cols {
            if row[i] == 0.0 {
                continue;
            }
            for j in i..cols {
                g[i][j] += row[i] * row[j];
            }
        }
    }
    for i in 0..cols {
        for j in 0..i {
            g[i][j] = g[j][i];
        }
    }
    g
}

/// `aᵀ·r`.
pub fn at_r(a: &Mat, r: &[f64], cols: usize) -> Vec<f64> {
    let mut out = vec![0.0; cols];
    for (row, ri) in a.iter().zip(r) {
        for j in 0..cols {
            out[j] += row[j] * ri;
        }
    }
    out
}

/// Singular values (descending) and right singular vectors (`v[k]` the k-th, as a
/// row) of `a` (rows × `cols`), by one-sided Jacobi rotations of its columns.
pub fn svd(a: &Mat, cols: usize) -> (Vec<f64>, Mat) {
    // Columns of a as vectors; rotate pairs until all are orthogonal.
    let m = a.len();
    let mut u: Mat = (0..cols)
        .map(|j| (0..m).map(|i| a[i][j]).collect())
        .collect();
    let mut v: Mat = (0..cols)
        .map(|j| (0..cols).map(|i| f64::from(u8::from(i == j))).collect())
        .collect();
    for _sweep in 0..60 {
        let mut rotated = false;
        for p in 0..cols {
            for q in p + 1..cols {
                let alpha: f64 = u[p].iter().map(|x| x * x).sum();
                let beta: f64 = u[q].iter().map(|x| x * x).sum();
                let gamma: f64 = u[p].iter().zip(&u[q]).map(|(x, y)| x * y).sum();
                if gamma.abs() <= 1e-15 * (alpha * beta).sqrt() || gamma == 0.0 {
                    continue;
                }
                rotated = true;
                let zeta = (beta - alpha) / (2.0 * gamma);
                let t = zeta.signum() / (zeta.abs() + (1.0 + zeta * zeta).sqrt());
                let t = if zeta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (1.0 + t * t).sqrt();
                let s = c * t;
                for (vecs, len) in [(&mut u, m), (&mut v, cols)] {
                    for k in 0..len {
                        let (x, y) = (vecs[p][k], vecs[q][k]);
                        vecs[p][k] = c * x - s * y;
                        vecs[q][k] = s * x + c * y;
                    }
                }
            }
        }
        if !rotated {
            break;
        }
    }
    let mut order: Vec<(f64, usize)> = (0..cols)
        .map(|j| (u[j].iter().map(|x| x * x).sum::<f64>().sqrt(), j))
        .collect();
    order.sort_by(|a, b| b.0.total_cmp(&a.0));
    (
        order.iter().map(|o| o.0).collect(),
        order.iter().map(|o| v[o.1].clone()).collect(),
    )
}

/// log det of the symmetric positive definite `a` and its inverse, by Cholesky;
/// `None` when `a` is not positive definite.
pub fn chol_inverse(a: &Mat) -> Option<(f64, Mat)> {
    let n = a.len();
    let mut l = vec![vec![0.0; n]; n];
    for i in 0..n {
        for j in 0..=i {
            let s: f64 = a[i][j] - (0..j).map(|k| l[i][k] * l[j][k]).sum::<f64>();
            if i == j {
                if s <= 0.0 {
                    return None;
                }
                l[i][i] = s.sqrt();
            } else {
                l[i][j] = s / l[j][j];
            }
        }
    }
    let logdet = 2.0 * (0..n).map(|i| l[i][i].ln()).sum::<f64>();
    // Columns of L⁻¹ by forward substitution, then A⁻¹ = L⁻ᵀ·L⁻¹.
    let mut li = vec![vec![0.0; n]; n];
    for c in 0..n {
        for i in c..n {
            let s: f64 =
                f64::from(u8::from(i == c)) - (c..i).map(|k| l[i][k] * li[k][c]).sum::<f64>();
            li[i][c] = s / l[i][i];
        }
    }
    let mut inv = vec![vec![0.0; n]; n];
    for i in 0..n {
        for j in 0..=i {
            let s: f64 = (i..n).map(|k| li[k][i] * li[k][j]).sum();
            inv[i][j] = s;
            inv[j][i] = s;
        }
    }
    Some((logdet, inv))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn svd_of_a_known_matrix() {
        // Columns 0 and 2 equal: rank 2, one singular value 0.
        let a = vec![
            vec![1.0, 2.0, 1.0],
            vec![0.0, 1.0, 0.0],
            vec![3.0, 0.0, 3.0],
        ];
        let (s, v) = svd(&a, 3);
        assert!(s[2] < 1e-12, "{s:?}");
        // The null vector is ±(1, 0, −1)/√2.
        assert!((v[2][0] + v[2][2]).abs() < 1e-12 && v[2][1].abs() < 1e-12);
        let g = gram(&a, 3);
        let trace: f64 = (0..3).map(|i| g[i][i]).sum();
        assert!((s.iter().map(|x| x * x).sum::<f64>() - trace).abs() < 1e-9);
    }

    #[test]
    fn cholesky_inverse_and_solve() {
        let a = vec![vec![4.0, 1.0], vec![1.0, 3.0]];
        let (ld, inv) = chol_inverse(&a).unwrap();
        assert!((ld - 11f64.ln()).abs() < 1e-12);
        assert!((inv[0][0] - 3.0 / 11.0).abs() < 1e-12 && (inv[0][1] + 1.0 / 11.0).abs() < 1e-12);
        let x = solve_vec(a, vec![1.0, 2.0]).unwrap();
        assert!((4.0 * x[0] + x[1] - 1.0).abs() < 1e-12 && (x[0] + 3.0 * x[1] - 2.0).abs() < 1e-12);
    }
}
