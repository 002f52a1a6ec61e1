//! Hexapod (Gough–Stewart platform): leg lengths in fixed point, forward kinematics by
//! Newton iteration.
//!
//! Geometry: [`HexapodGeometry`]. Pose X Y Z = platform origin (nm), A B C (n°) with
//! R = Rz(C)·Ry(B)·Rx(A); joint i = |p + R·b_i − a_i| (nm).
//!
//! Inverse, per call: three sin/cos pairs (Q31, [`fixed::sincos`]); the nine entries of
//! R as Q31 (one or two `SMMULR` products each); per leg and axis the component
//! v = 2(p − a_i) + R·(4b_i)/2^32 in half nanometres (hn), all in 32 bits: the
//! platform joints are stored in quarter nanometres, so each term is one `SMMLAR`
//! rounding to the hn. |v|² is exact in `u64`, then the integer root of
//! [`fixed::isqrt`] and a final rounding to nm. 32 bits suffice because the pose is
//! refused beyond |X|, |Y|, |Z| ≤ 2^30 nm − max|a| − max|b| (623 mm for the thesis
//! machine; the configuration keeps |a| < 537 mm and |b| < 268 mm): then every
//! partial sum stays below 2^31 hn. Within that the inverse has no reach test: the
//! joints' travel bounds the workspace (`inverse_checked`), and forward kinematics
//! reports singular poses.
//!
//! Error budget (each leg, against exact arithmetic on the same integer pose): each R
//! entry ≤ 2.4e-9 (two sin/cos errors of 7.0e-10 and the Q31 roundings), times
//! |b| = 150 mm: ≤ 0.36 nm per term of R·b, plus 0.25 nm rounding per term; the leg
//! length moves by at most |δv|, the sum of those over the three terms of the three
//! components (worst case ≈ 3 nm, in practice the errors do not align), plus 0.25 nm
//! root and 0.5 nm final rounding; measured 1.39 nm over 100 000 poses
//! (`docs/performance.md`; ≤ 5 nm required).
//!
//! Forward: Newton from the guess on all six axes. Each iteration evaluates the leg
//! lengths in 1/16 nm (`eval_fine`: one rounding per component, 128-bit squares, so
//! the residual is smooth to ~0.1 nm), builds the 6 × 6 Jacobian in `f32`
//! (row i: the leg direction n_i and (R·b_i × n_i)·u_k for the rotation axes
//! u_A = R·x̂, u_B = Rz(C)·ŷ, u_C = ẑ, divided by the lever |b|max so all columns are
//! nm), solves with partial pivoting, applies the rounded step and stops after a step of
//! at most [`FINAL_STEP`](super::FINAL_STEP): 2 iterations from the pose of the
//! previous 1 ms period ([`super::solve::newton`]). [`Hexapod::jacobian`] (for the
//! planner's joint rates) gives the same rows with the angle columns in nm/n°.

use super::fixed::{self, round_f32, NDEG_PER_RAD};
use super::solve::newton;
use super::{Joints, Pose, Unreachable};
use crate::config::{HexapodGeometry, AXES, MAX_JOINTS};
use crate::math::{i64_to_f32, isqrt, isqrt_wide, mulhr, sincos};

/// Sub-nanometre bits of the leg vectors: half nanometres.
const SUB: u32 = 1;
/// Sub-nanometre bits of the forward kinematics' residuals: 1/16 nm.
const FINE: u32 = 4;

/// Hexapod, precomputed from [`HexapodGeometry`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Hexapod {
    /// Base joints, hn.
    base: [[i32; 3]; 6],
    /// Platform joints, quarter nm.
    platform: [[i32; 3]; 6],
    /// Largest |X|, |Y|, |Z| taken, nm.
    p_max: u64,
    /// Largest |b_i|, nm: the lever the angles are scaled by.
    lever: i64,
}

/// Q31 rotation `Rz(c)·Ry(b)·Rx(a)` from n°, each entry rounded once from 64-bit
/// products (the forward kinematics' residuals and the hexapod-xy's split use it), and
/// (sin C, cos C), Q31.
pub(super) fn rotation_fine(a: i64, b: i64, c: i64) -> ([[i32; 3]; 3], [i32; 2]) {
    let (sa, ca) = sincos(a);
    let (sb, cb) = sincos(b);
    let (sc, cc) = sincos(c);
    let m = |u: i32, v: i32| u as i64 * v as i64;
    let q31 = |v: i64| ((v + (1 << 30)) >> 31).clamp(-(i32::MAX as i64), i32::MAX as i64) as i32;
    let (sbsa, sbca) = (q31(m(sb, sa)), q31(m(sb, ca)));
    let r = [
        [
            q31(m(cc, cb)),
            q31(m(cc, sbsa) - m(sc, ca)),
            q31(m(cc, sbca) + m(sc, sa)),
        ],
        [
            q31(m(sc, cb)),
            q31(m(sc, sbsa) + m(cc, ca)),
            q31(m(sc, sbca) - m(cc, sa)),
        ],
        [-sb, q31(m(cb, sa)), q31(m(cb, ca))],
    ];
    (r, [sc, cc])
}

/// A Q30 value (|v| ≤ 1 + rounding) to Q31, saturated.
#[inline(always)]
fn q31(v: i32) -> i32 {
    v.clamp(-(1 << 30), (1 << 30) - 1) << 1
}

/// One leg-vector component, hn: `base + Σ_j r_j·b_j / 2^32` (b in quarter nm).
#[inline(always)]
fn component(base: i32, r: &[i32; 3], b: &[i32; 3]) -> i32 {
    base.wrapping_add(mulhr(r[0], b[0]))
        .wrapping_add(mulhr(r[1], b[1]))
        .wrapping_add(mulhr(r[2], b[2]))
}

impl Hexapod {
    /// Precomputes `g` (validated by [`crate::config::MachineConfig::validate`]).
    pub fn new(g: &HexapodGeometry) -> Self {
        let mut lever = 1;
        for b in &g.platform {
            let sq: u64 = b.iter().map(|c| c.unsigned_abs().pow(2)).sum();
            lever = lever.max(isqrt(sq) as i64 + 1);
        }
        let a_max = g
            .base
            .iter()
            .flatten()
            .map(|c| c.unsigned_abs())
            .max()
            .unwrap_or(0);
        Self {
            base: g.base.map(|a| a.map(|c| (c << SUB) as i32)),
            platform: g.platform.map(|b| b.map(|c| (c << 2) as i32)),
            p_max: (1u64 << 30) - 16 - a_max - lever as u64,
            lever,
        }
    }

    /// Out of reach beyond the pose range (see the module doc).
    #[inline(always)]
    fn in_range(&self, pose: &Pose) -> Result<(), Unreachable> {
        let [x, y, z, ..] = *pose;
        if x.unsigned_abs() > self.p_max
            || y.unsigned_abs() > self.p_max
            || z.unsigned_abs() > self.p_max
        {
            return Err(Unreachable::OutOfReach);
        }
        Ok(())
    }

    /// Joints of `pose`.
    pub fn inverse(&self, pose: &Pose, joints: &mut Joints) -> Result<(), Unreachable> {
        self.in_range(pose)?;
        let [x, y, z, a, b, c] = *pose;
        let (sa, ca) = sincos(a);
        let (sb, cb) = sincos(b);
        let (sc, cc) = sincos(c);
        // Q31 × Q31 → Q30 in one SMMULR, back to Q31.
        let sbsa = mulhr(sb, sa) << 1;
        let sbca = mulhr(sb, ca) << 1;
        let r = [
            [
                mulhr(cc, cb) << 1,
                q31(mulhr(cc, sbsa) - mulhr(sc, ca)),
                q31(mulhr(cc, sbca) + mulhr(sc, sa)),
            ],
            [
                mulhr(sc, cb) << 1,
                q31(mulhr(sc, sbsa) + mulhr(cc, ca)),
                q31(mulhr(sc, sbca) - mulhr(cc, sa)),
            ],
            [-sb, mulhr(cb, sa) << 1, mulhr(cb, ca) << 1],
        ];
        self.legs(x, y, z, &r, joints);
        Ok(())
    }

    /// Joints of the platform at `p` (nm) turned by the Q31 rotation `r` (computed by
    /// the caller, as the hexapod-xy's split does), with the range check of
    /// [`Hexapod::inverse`].
    pub fn inverse_rotated(
        &self,
        p: [i64; 3],
        r: &[[i32; 3]; 3],
        joints: &mut Joints,
    ) -> Result<(), Unreachable> {
        self.in_range(&[p[0], p[1], p[2], 0, 0, 0])?;
        self.legs(p[0], p[1], p[2], r, joints);
        Ok(())
    }

    /// The six leg lengths (see the module documentation) for an in-range position.
    #[inline(always)]
    fn legs(&self, x: i64, y: i64, z: i64, r: &[[i32; 3]; 3], joints: &mut Joints) {
        let (px, py, pz) = ((x << SUB) as i32, (y << SUB) as i32, (z << SUB) as i32);
        for (q, (ai, bi)) in joints.iter_mut().zip(self.base.iter().zip(&self.platform)) {
            // Written out (no arrays or iterators) so that it compiles to straight
            // SMMLAR chains at opt-level "s".
            let v0 = component(px - ai[0], &r[0], bi);
            let v1 = component(py - ai[1], &r[1], bi);
            let v2 = component(pz - ai[2], &r[2], bi);
            let sq = ((v0 as i64 * v0 as i64) as u64)
                .wrapping_add((v1 as i64 * v1 as i64) as u64)
                .wrapping_add((v2 as i64 * v2 as i64) as u64);
            let len = isqrt(sq);
            *q = ((len + 1) >> SUB) as i64;
        }
    }

    /// The leg lengths in 1/16 nm for the forward kinematics' residuals: R in Q31 with
    /// one rounding per entry (64-bit sums), each component p − a + R·b summed in 64
    /// bits and rounded once to 1/16 nm, squares in 128 bits and
    /// [`fixed::isqrt_wide`], so the residual is smooth to ~0.1 nm instead of the
    /// inverse's per-term half-nm roundings. Reports per leg (v, len), 1/16 nm; returns R
    /// and (sin C, cos C), Q31.
    fn eval_fine(
        &self,
        pose: &Pose,
        mut leg: impl FnMut(usize, [i64; 3], i64),
    ) -> Result<([[i32; 3]; 3], [i32; 2]), Unreachable> {
        self.in_range(pose)?;
        let [x, y, z, a, b, c] = *pose;
        let (r, [sc, cc]) = rotation_fine(a, b, c);
        let m = |u: i32, v: i32| u as i64 * v as i64;
        const SH: u32 = 31 - FINE;
        let p = [x, y, z];
        for (i, (ai, bi)) in self.base.iter().zip(&self.platform).enumerate() {
            // Base stored in hn, platform in quarter nm: both exact in nm.
            let b = bi.map(|c| c >> 2);
            let v = [0, 1, 2].map(|k| {
                let acc = ((p[k] - (ai[k] >> SUB) as i64) << 31)
                    + m(r[k][0], b[0])
                    + m(r[k][1], b[1])
                    + m(r[k][2], b[2]);
                (acc + (1 << (SH - 1))) >> SH
            });
            let sq: i128 = v.iter().map(|&c| c as i128 * c as i128).sum();
            leg(i, v, isqrt_wide(sq as u128) as i64);
        }
        Ok((r, [sc, cc]))
    }

    /// One Newton system at `p`: `rows` the analytic Jacobian of the legs over X Y Z
    /// (nm/nm) and A B C (nm per nm of arc at the lever |b|max), `res` the residual
    /// `joints − q(p)`, nm, from [`Self::eval_fine`].
    #[inline(always)]
    fn linearize(
        &self,
        p: &Pose,
        joints: &Joints,
        rows: &mut [[f32; 6]; 6],
        res: &mut [f32; 6],
    ) -> Result<(), Unreachable> {
        let lever = self.lever as f32;
        let unit = 1.0 / (1u32 << FINE) as f32;
        let (rq, [sc, cc]) = self.eval_fine(p, |i, v, len| {
            let inv = 1.0 / i64_to_f32(len);
            rows[i][..3].copy_from_slice(&v.map(|c| i64_to_f32(c) * inv));
            let t = joints[i].wrapping_shl(FINE).wrapping_sub(len);
            res[i] = i64_to_f32(t) * unit;
        })?;
        let rf = rq.map(|row| row.map(|v| v as f32 / fixed::ONE_Q31));
        let (sc, cc) = (sc as f32 / fixed::ONE_Q31, cc as f32 / fixed::ONE_Q31);
        for (row, b) in rows.iter_mut().zip(&self.platform) {
            // R·b / lever (b is stored in quarter nm), then m = (R·b × n); row =
            // (n, m·u_A, m·u_B, m·u_C) with u_A = R x̂, u_B = Rz(C) ŷ =
            // (−sin C, cos C, 0), u_C = ẑ.
            let bf = b.map(|c| c as f32 / (4.0 * lever));
            let rb = rf.map(|r| r[0] * bf[0] + r[1] * bf[1] + r[2] * bf[2]);
            let n = [row[0], row[1], row[2]];
            let m = [
                rb[1] * n[2] - rb[2] * n[1],
                rb[2] * n[0] - rb[0] * n[2],
                rb[0] * n[1] - rb[1] * n[0],
            ];
            row[3] = m[0] * rf[0][0] + m[1] * rf[1][0] + m[2] * rf[2][0];
            row[4] = m[1] * cc - m[0] * sc;
            row[5] = m[2];
        }
        Ok(())
    }

    /// The analytic Jacobian ∂q/∂p at `pose` (see [`super::Jacobian`]): the forward
    /// kinematics' rows with the angle columns scaled from arc length at the lever to n°.
    pub fn jacobian(&self, pose: &Pose, jac: &mut super::Jacobian) -> Result<(), Unreachable> {
        let (mut rows, mut res) = ([[0.0f32; 6]; 6], [0.0f32; 6]);
        self.linearize(pose, &[0; MAX_JOINTS], &mut rows, &mut res)?;
        let nm_per_ndeg = self.lever as f32 / NDEG_PER_RAD as f32;
        *jac = [[0.0; AXES]; MAX_JOINTS];
        for (j, row) in jac.iter_mut().zip(rows) {
            *j = [
                row[0],
                row[1],
                row[2],
                row[3] * nm_per_ndeg,
                row[4] * nm_per_ndeg,
                row[5] * nm_per_ndeg,
            ];
        }
        Ok(())
    }

    /// The legs' rows for small motions, in `f32` for the contour controller: with the
    /// platform origin at `p` (mm) and its rotation `r`, row i is (n_i, (R·b_i) × n_i),
    /// n_i the leg's unit vector, so that δl_i = n_i·δp + ((R·b_i) × n_i)·ω for a
    /// small translation δp (mm) and rotation ω (rad, machine frame).
    pub fn rows_f32(&self, p: &[f32; 3], r: &[[f32; 3]; 3]) -> [[f32; 6]; 6] {
        let mut rows = [[0.0f32; 6]; 6];
        for (row, (a, b)) in rows.iter_mut().zip(self.base.iter().zip(&self.platform)) {
            let b = b.map(|c| c as f32 * 0.25e-6);
            let rb = r.map(|ri| ri[0] * b[0] + ri[1] * b[1] + ri[2] * b[2]);
            let d = [0, 1, 2].map(|k| p[k] + rb[k] - a[k] as f32 * 0.5e-6);
            let inv = 1.0 / crate::math::sqrt_f32(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
            let n = d.map(|c| c * inv);
            *row = [
                n[0],
                n[1],
                n[2],
                rb[1] * n[2] - rb[2] * n[1],
                rb[2] * n[0] - rb[0] * n[2],
                rb[0] * n[1] - rb[1] * n[0],
            ];
        }
        rows
    }

    /// Pose of `joints` by Newton iteration from `guess`; returns the iterations used.
    pub fn forward(
        &self,
        joints: &Joints,
        guess: &Pose,
        pose: &mut Pose,
    ) -> Result<u8, Unreachable> {
        let ndeg_per_nm = NDEG_PER_RAD as f32 / self.lever as f32;
        newton(
            guess,
            pose,
            |p, rows, res| self.linearize(p, joints, rows, res),
            |p, res| {
                for k in 0..3 {
                    p[k] += round_f32(res[k]);
                    p[k + 3] += round_f32(res[k + 3] * ndeg_per_nm);
                }
            },
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{MachineConfig, MAX_JOINTS};
    use crate::kinematics::{suite, MachineKinematics};

    #[test]
    fn poses_at_the_fixed_point_range_are_exact_and_beyond_it_out_of_reach() {
        let machine = MachineConfig::hexapod();
        let kin = MachineKinematics::new(&machine);
        let MachineKinematics::Hexapod(k) = kin else {
            unreachable!()
        };
        let m = k.p_max as i64;
        assert!(m > 600_000_000, "{m}");
        let deg = 1_000_000_000;
        let mut worst = 0.0f64;
        for p in [
            [m, m, m, 180 * deg, 90 * deg, -180 * deg],
            [-m, m, -m, 45 * deg, -30 * deg, 120 * deg],
            [0, -m, m, -90 * deg, 0, 7 * deg],
        ] {
            worst = worst.max(suite::ik_error(&machine, &kin, &p));
        }
        assert!(worst <= 5.0, "{worst}");
        let mut q = [0; MAX_JOINTS];
        for p in [
            [m + 1, 0, 0, 0, 0, 0],
            [0, -m - 1, 0, 0, 0, 0],
            [0, 0, i64::MIN, 0, 0, 0],
        ] {
            assert_eq!(k.inverse(&p, &mut q), Err(Unreachable::OutOfReach));
        }
    }
}
