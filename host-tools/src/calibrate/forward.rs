//! Forward kinematics of a model (Newton on its loop equations) and the analytic
//! Jacobian of the measured tool pose with respect to the parameters, through the
//! implicit function theorem: with the loop equations `c(θ, x) = q`,
//! `∂x/∂θ = −(∂c/∂x)⁻¹·∂c/∂θ` and `∂y/∂θ = ∂y/∂θ|ₓ + ∂y/∂x·∂x/∂θ`.
#![allow(clippy::needless_range_loop)]

use super::dual::{Dual, Scalar};
use super::model::Model;
use crate::control::linalg::{solve_vec, Mat};

fn seeded(th: &[f64], x: &[f64], seed_params: bool) -> (Vec<Dual>, Vec<Dual>) {
    let p = th.len();
    let t = th
        .iter()
        .enumerate()
        .map(|(j, v)| {
            if seed_params {
                Dual::var(*v, j)
            } else {
                Dual::c(*v)
            }
        })
        .collect();
    let x = x
        .iter()
        .enumerate()
        .map(|(k, v)| Dual::var(*v, p + k))
        .collect();
    (t, x)
}

/// The internal pose (mm, radians) at which the loop joints read `q`, by Newton's
/// method from `guess`; `None` when it does not converge (out of reach, singular).
pub fn forward(model: &Model, th: &[f64], q: &[f64], guess: &[f64]) -> Option<Vec<f64>> {
    let (p, d) = (th.len(), model.loop_dim());
    let mut x = guess.to_vec();
    for _ in 0..40 {
        let (t, xs) = seeded(th, &x, false);
        let c = model.loop_joints(&t, &xs);
        let jac: Mat = c.iter().map(|ci| ci.d[p..p + d].to_vec()).collect();
        let r: Vec<f64> = (0..d).map(|i| q[i] - c[i].v).collect();
        if r.iter().any(|v| !v.is_finite()) {
            return None;
        }
        let step = solve_vec(jac, r)?;
        for k in 0..d {
            x[k] += step[k];
        }
        if step.iter().all(|s| s.abs() < 1e-11) {
            return Some(x);
        }
    }
    None
}

/// The measured pose model at joints `q` and internal pose `x` (already solved), and
/// its Jacobian with respect to every parameter (rows: measured axes, columns:
/// parameters); `None` at a singular pose.
pub fn measure_jacobian(
    model: &Model,
    th: &[f64],
    q: &[f64],
    x: &[f64],
) -> Option<(Vec<f64>, Mat)> {
    let (p, d) = (th.len(), model.loop_dim());
    let (t, xs) = seeded(th, x, true);
    let c = model.loop_joints(&t, &xs);
    let y = model.measure(&t, &xs, q);
    // (∂c/∂x)⁻¹ column by column.
    let cx: Mat = c.iter().map(|ci| ci.d[p..p + d].to_vec()).collect();
    let mut inv = vec![vec![0.0; d]; d];
    for k in 0..d {
        let e: Vec<f64> = (0..d).map(|i| f64::from(u8::from(i == k))).collect();
        let col = solve_vec(cx.clone(), e)?;
        for i in 0..d {
            inv[i][k] = col[i];
        }
    }
    // ∂x/∂θ = −(∂c/∂x)⁻¹·∂c/∂θ.
    let mut dx = vec![vec![0.0; p]; d];
    for i in 0..d {
        for k in 0..d {
            let f = inv[i][k];
            if f == 0.0 {
                continue;
            }
            for j in 0..p {
                dx[i][j] -= f * c[k].d[j];
            }
        }
    }
    let jac = y
        .iter()
        .map(|yi| {
            (0..p)
                .map(|j| yi.d[j] + (0..d).map(|k| yi.d[p + k] * dx[k][j]).sum::<f64>())
                .collect()
        })
        .collect();
    Some((y.iter().map(|v| v.v).collect(), jac))
}

/// The measured pose at joints `q` (forward kinematics then the measurement), and the
/// internal pose; `None` where forward kinematics fails.
pub fn predict(
    model: &Model,
    th: &[f64],
    q: &[f64],
    guess: &[f64],
) -> Option<(Vec<f64>, Vec<f64>)> {
    let x = forward(model, th, q, guess)?;
    let y = model.measure(th, &x, q);
    Some((y, x))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::machine_file;

    fn model(name: &str) -> Model {
        let path = format!(
            "{}/../examples/machines/{name}.toml",
            env!("CARGO_MANIFEST_DIR")
        );
        Model::from_config(&machine_file::load(std::path::Path::new(&path)).unwrap()).unwrap()
    }

    /// The analytic Jacobian of the measurement (through forward kinematics) against
    /// central differences of the whole chain, every parameter, on each machine kind.
    #[test]
    fn jacobian_matches_finite_differences() {
        for (name, pose) in [
            ("h4-table", [20.0, -15.0, -60.0, 25.0, 0.0, 10.0]),
            ("hexapod", [15.0, -10.0, 470.0, 4.0, -3.0, 6.0]),
            ("hexapod-xy", [30.0, -20.0, 280.0, 5.0, -4.0, 0.0]),
        ] {
            let m = model(name);
            let th = m.nominal();
            let (q, x) = m.inverse(&th, &pose).expect(name);
            let (y, jac) = measure_jacobian(&m, &th, &q, &x).unwrap();
            // Round trip: forward kinematics returns the commanded pose.
            let (y2, _) = predict(&m, &th, &q, &m.inverse(&th, &m.home).unwrap().1).unwrap();
            for (k, &ax) in m.measured_axes().iter().enumerate() {
                assert!(
                    (y[k] - pose[ax]).abs() < 1e-9,
                    "{name} {k}: {} {}",
                    y[k],
                    pose[ax]
                );
                assert!(
                    (y2[k] - pose[ax]).abs() < 1e-9,
                    "{name} {k}: {} {}",
                    y2[k],
                    pose[ax]
                );
            }
            let mut worst = 0.0f64;
            for j in 0..th.len() {
                let h = 1e-5;
                let (mut tp, mut tm) = (th.clone(), th.clone());
                tp[j] += h;
                tm[j] -= h;
                let yp = predict(&m, &tp, &q, &x).unwrap().0;
                let ym = predict(&m, &tm, &q, &x).unwrap().0;
                for k in 0..y.len() {
                    let fd = (yp[k] - ym[k]) / (2.0 * h);
                    let err = (jac[k][j] - fd).abs();
                    worst = worst.max(err);
                    assert!(
                        err < 1e-6,
                        "{name} {}: row {k}: {} vs {fd}",
                        m.params[j].name,
                        jac[k][j]
                    );
                }
            }
            // And the test can fail: a wrong column is seen.
            let mut bad = jac.clone();
            bad[0][0] += 1e-3;
            assert!((bad[0][0] - jac[0][0]).abs() > 1e-6, "{worst}");
        }
    }
}
