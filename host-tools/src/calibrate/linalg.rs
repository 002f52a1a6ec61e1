//! Small dense linear algebra in `f64`: Gaussian elimination, Cholesky, and the
//! one-sided Jacobi SVD the identifiability analysis and the covariance use.
#![allow(clippy::needless_range_loop)]

/// A dense matrix as rows.
pub type Mat = Vec<Vec<f64>>;

/// Solves the square system `a·x = b` by Gaussian elimination with partial pivoting;
/// `None` when `a` is singular to working precision.
pub fn solve(mut a: Mat, mut b: Vec<f64>) -> Option<Vec<f64>> {
    let n = b.len();
    let scale = a.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    for k in 0..n {
        let p = (k..n).max_by(|&u, &v| a[u][k].abs().total_cmp(&a[v][k].abs()))?;
        if a[p][k].abs() <= 1e-14 * scale {
            return None;
        }
        a.swap(k, p);
        b.swap(k, p);
        for i in k + 1..n {
            let f = a[i][k] / a[k][k];
            for j in k..n {
                a[i][j] -= f * a[k][j];
            }
            b[i] -= f * b[k];
        }
    }
    let mut x = vec![0.0; n];
    for k in (0..n).rev() {
        let s: f64 = (k + 1..n).map(|j| a[k][j] * x[j]).sum();
        x[k] = (b[k] - s) / a[k][k];
    }
    Some(x)
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
        let x = solve(a, vec![1.0, 2.0]).unwrap();
        assert!((4.0 * x[0] + x[1] - 1.0).abs() < 1e-12 && (x[0] + 3.0 * x[1] - 2.0).abs() < 1e-12);
    }
}
