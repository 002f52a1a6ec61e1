//! Small dense linear solves in `f32` for the forward-kinematics Newton steps.
//!
//! Gaussian elimination with partial pivoting on an N × N system, N ≤ 6, in place, no
//! allocation, a fixed number of operations. The Newton residuals are exact integers, so
//! the Jacobian needs only modest precision: an `f32` solve (relative error ~1e-6 times
//! the condition number) still converges quadratically to the integer resolution.
//!
//! Invariant: the callers scale every row and column to O(1) (unit-vector leg
//! directions, angles as arc lengths at the platform's lever arm), so a fixed pivot
//! threshold [`PIVOT_MIN`] means "too near a singularity".

use super::{Pose, Unreachable, FINAL_STEP, MAX_ITERATIONS};

/// Smallest pivot accepted; below it the pose counts as too near a singularity.
pub const PIVOT_MIN: f32 = 1e-4;

/// Solves `a · x = b` in place (`b` becomes `x`); `a` is destroyed.
pub fn solve<const N: usize>(a: &mut [[f32; N]; N], b: &mut [f32; N]) -> Result<(), Unreachable> {
    for k in 0..N {
        let mut p = k;
        let mut best = a[k][k].abs();
        for (i, row) in a.iter().enumerate().skip(k + 1) {
            if row[k].abs() > best {
                best = row[k].abs();
                p = i;
            }
        }
        if best.is_nan() || best < PIVOT_MIN {
            return Err(Unreachable::Singular);
        }
        a.swap(k, p);
        b.swap(k, p);
        let pivot = a[k];
        let bk = b[k];
        for i in k + 1..N {
            let f = a[i][k] / pivot[k];
            for j in k + 1..N {
                a[i][j] -= f * pivot[j];
            }
            b[i] -= f * bk;
        }
    }
    for k in (0..N).rev() {
        let mut s = b[k];
        for j in k + 1..N {
            s -= a[k][j] * b[j];
        }
        b[k] = s / a[k][k];
    }
    Ok(())
}

/// Newton's method from `guess`: each iteration builds the system at the current pose
/// (`linearize`: Jacobian and residual, scaled as above), solves it, applies the step
/// (`step`: rounded onto the pose), and stops after a step of at most [`FINAL_STEP`]
/// on every unknown; returns the iterations used. Inlined into each caller, so each
/// machine's forward kinematics compiles to its own loop.
#[inline(always)]
pub fn newton<const N: usize>(
    guess: &Pose,
    pose: &mut Pose,
    mut linearize: impl FnMut(&Pose, &mut [[f32; N]; N], &mut [f32; N]) -> Result<(), Unreachable>,
    step: impl Fn(&mut Pose, &[f32; N]),
) -> Result<u8, Unreachable> {
    let mut p = *guess;
    for it in 1..=MAX_ITERATIONS {
        let mut jac = [[0.0f32; N]; N];
        let mut r = [0.0f32; N];
        linearize(&p, &mut jac, &mut r)?;
        solve(&mut jac, &mut r)?;
        step(&mut p, &r);
        if r.iter().all(|s| s.abs() <= FINAL_STEP) {
            *pose = p;
            return Ok(it);
        }
    }
    Err(Unreachable::NoConvergence)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_permuted_system_is_solved_with_pivoting() {
        let mut a = [[0.0, 2.0, 1.0], [1.0, 0.0, 0.0], [3.0, 1.0, 4.0]];
        let mut b = [5.0, 1.0, 16.0]; // x = (1, 1, 3)
        solve(&mut a, &mut b).unwrap();
        for (x, want) in b.iter().zip([1.0, 1.0, 3.0]) {
            assert!((x - want).abs() < 1e-5, "{b:?}");
        }
    }

    #[test]
    fn a_singular_system_is_refused() {
        let mut a = [[1.0, 2.0], [2.0, 4.0]];
        let mut b = [1.0, 2.0];
        assert_eq!(solve(&mut a, &mut b), Err(Unreachable::Singular));
    }
}
