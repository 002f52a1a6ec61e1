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
//! at most [`FINAL_STEP`]: 2 iterations from the pose of the previous 1 ms period.

use super::fixed::{self, round_f32, NDEG_PER_RAD};
use super::solve::solve;
use super::{Joints, Pose, Unreachable, FINAL_STEP, MAX_ITERATIONS};
use crate::config::HexapodGeometry;
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

    /// Joints of `pose`.
    pub fn inverse(&self, pose: &Pose, joints: &mut Joints) -> Result<(), Unreachable> {
        let [x, y, z, a, b, c] = *pose;
        if x.unsigned_abs() > self.p_max
            || y.unsigned_abs() > self.p_max
            || z.unsigned_abs() > self.p_max
        {
            return Err(Unreachable::OutOfReach);
        }
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
        Ok(())
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
        let [x, y, z, a, b, c] = *pose;
        if x.unsigned_abs() > self.p_max
            || y.unsigned_abs() > self.p_max
            || z.unsigned_abs() > self.p_max
        {
            return Err(Unreachable::OutOfReach);
        }
        let (sa, ca) = sincos(a);
        let (sb, cb) = sincos(b);
        let (sc, cc) = sincos(c);
        let m = |u: i32, v: i32| u as i64 * v as i64;
        let q31 =
            |v: i64| ((v + (1 << 30)) >> 31).clamp(-(i32::MAX as i64), i32::MAX as i64) as i32;
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

    /// Pose of `joints` by Newton iteration from `guess`; returns the iterations used.
    pub fn forward(
        &self,
        joints: &Joints,
        guess: &Pose,
        pose: &mut Pose,
    ) -> Result<u8, Unreachable> {
        let mut p = *guess;
        let lever = self.lever as f32;
        let ndeg_per_nm = NDEG_PER_RAD as f32 / lever;
        let unit = 1.0 / (1u32 << FINE) as f32;
        for it in 1..=MAX_ITERATIONS {
            let mut rows = [[0.0f32; 6]; 6];
            let mut res = [0.0f32; 6];
            let (rq, [sc, cc]) = self.eval_fine(&p, |i, v, len| {
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
            solve(&mut rows, &mut res)?;
            for k in 0..3 {
                p[k] += round_f32(res[k]);
                p[k + 3] += round_f32(res[k + 3] * ndeg_per_nm);
            }
            if res.iter().all(|s| s.abs() <= FINAL_STEP) {
                *pose = p;
                return Ok(it);
            }
        }
        Err(Unreachable::NoConvergence)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{KinematicsConfig, MachineConfig, MAX_JOINTS};
    use crate::kinematics::reference::{self as re, lcg, real};
    use proptest::prelude::*;

    fn geometry() -> HexapodGeometry {
        match MachineConfig::hexapod().kinematics {
            KinematicsConfig::Hexapod(g) => g,
            _ => unreachable!(),
        }
    }

    fn ik_error(g: &HexapodGeometry, k: &Hexapod, pose: &Pose) -> f64 {
        let want = re::hexapod_inverse(g, &real(pose));
        let mut q = [0; MAX_JOINTS];
        k.inverse(pose, &mut q).expect("reachable");
        (0..6)
            .map(|i| (q[i] as f64 - want[i]).abs())
            .fold(0.0, f64::max)
    }

    /// Random pose: translations within ±50 mm of home (0, 0, 450 mm), A B C ±10°.
    fn random_pose(s: &mut u64) -> Pose {
        let mut u = |half: f64, scale: f64| ((lcg(s) * 2.0 - 1.0) * half * scale).round() as i64;
        [
            u(50.0, 1e6),
            u(50.0, 1e6),
            450_000_000 + u(50.0, 1e6),
            u(10.0, 1e9),
            u(10.0, 1e9),
            u(10.0, 1e9),
        ]
    }

    #[test]
    fn home_legs_match_the_geometry() {
        let m = MachineConfig::hexapod();
        let k = Hexapod::new(&geometry());
        let mut q = [0; MAX_JOINTS];
        k.inverse(&m.home, &mut q).unwrap();
        // |(0, 0, 450) + b_1 − a_1| = 492.126… mm, the same for all six legs.
        let want = re::hexapod_inverse(&geometry(), &real(&m.home));
        for i in 0..6 {
            assert!((q[i] as f64 - want[i]).abs() <= 1.0);
            assert!((q[i] - 492_126_000).abs() < 1_000, "{q:?}");
        }
    }

    #[test]
    fn the_inverse_is_within_5_nm_of_the_reference_over_the_workspace() {
        let g = geometry();
        let k = Hexapod::new(&g);
        let mut seed = 3;
        let mut worst = 0.0f64;
        let n = 100_000;
        for _ in 0..n {
            worst = worst.max(ik_error(&g, &k, &random_pose(&mut seed)));
        }
        eprintln!("hexapod inverse: max joint error {worst:.3} nm over {n} poses");
        assert!(worst <= 5.0, "{worst} nm");
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(20_000))]
        #[test]
        fn inverse_error_is_at_most_5_nm(
            x in -50_000_000i64..50_000_000, y in -50_000_000i64..50_000_000,
            z in 400_000_000i64..500_000_000,
            a in -10_000_000_000i64..10_000_000_000, b in -10_000_000_000i64..10_000_000_000,
            c in -10_000_000_000i64..10_000_000_000,
        ) {
            let g = geometry();
            prop_assert!(ik_error(&g, &Hexapod::new(&g), &[x, y, z, a, b, c]) <= 5.0);
        }
    }

    #[test]
    fn poses_at_the_fixed_point_range_are_exact_and_beyond_it_out_of_reach() {
        let g = geometry();
        let k = Hexapod::new(&g);
        let m = k.p_max as i64;
        assert!(m > 600_000_000, "{m}");
        let deg = 1_000_000_000;
        let mut worst = 0.0f64;
        for p in [
            [m, m, m, 180 * deg, 90 * deg, -180 * deg],
            [-m, m, -m, 45 * deg, -30 * deg, 120 * deg],
            [0, -m, m, -90 * deg, 0, 7 * deg],
        ] {
            worst = worst.max(ik_error(&g, &k, &p));
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

    fn fk_case(g: &HexapodGeometry, k: &Hexapod, s: &mut u64, stats: &mut re::FkStats) {
        let p = random_pose(s);
        let mut q = [0; MAX_JOINTS];
        k.inverse(&p, &mut q).unwrap();
        let dir = [lcg(s) - 0.5, lcg(s) - 0.5, lcg(s) - 0.5];
        let norm = (dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]).sqrt();
        let mut guess = p;
        for i in 0..3 {
            guess[i] -= (200_000.0 * dir[i] / norm).round() as i64;
            guess[i + 3] -= ((lcg(s) * 2.0 - 1.0) * 90_000_000.0).round() as i64;
        }
        let (mut out, mut at) = ([0; 6], [0; 6]);
        let it = match k.forward(&q, &guess, &mut out) {
            Ok(it) => it,
            Err(e) => panic!("{e:?}: p {p:?} guess {guess:?}"),
        };
        k.forward(&q, &p, &mut at).unwrap();
        let mut want = real(&p);
        let target: [f64; 6] = std::array::from_fn(|i| q[i] as f64);
        re::newton(
            |x| re::hexapod_inverse(g, x),
            &target,
            &mut want,
            [0, 1, 2, 3, 4, 5],
        );
        stats.add(it, &out, &at, &p, &want, &[3, 4, 5]);
    }

    #[test]
    fn forward_converges_in_3_iterations_from_the_previous_period() {
        let g = geometry();
        let k = Hexapod::new(&g);
        let mut seed = 9;
        let mut st = re::FkStats::default();
        let n = 5_000;
        for _ in 0..n {
            fk_case(&g, &k, &mut seed, &mut st);
        }
        eprintln!(
            "hexapod forward ({n} cases): iterations histogram {:?}; converged to within \
             {} nm, {} n° of the answer started at the true pose; against the f64 solution \
             {:.3} nm, {:.0} n°; round trip {} nm",
            st.hist, st.conv_lin, st.conv_ang, st.lin, st.ang, st.round_trip
        );
        assert!(st.max_iterations() <= 3);
        // Within 1 nm of the answer from any nearby start, and of the exact solution
        // (angles: 382 n° moves a platform joint by 1 nm).
        assert!(
            st.conv_lin <= 1 && st.conv_ang <= 382,
            "{} {}",
            st.conv_lin,
            st.conv_ang
        );
        assert!(st.lin <= 1.0 && st.ang <= 382.0, "{} {}", st.lin, st.ang);
    }
}
