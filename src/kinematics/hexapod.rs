//! Hexapod (Gough–Stewart platform): leg lengths in fixed point, forward kinematics by
//! Newton iteration.
//!
//! Geometry: [`HexapodGeometry`]. Pose X Y Z = platform origin (nm), A B C (n°) with
//! R = Rz(C)·Ry(B)·Rx(A); joint i = |p + R·b_i − a_i| (nm).
//!
//! Inverse, per call: three sin/cos pairs (Q30, [`fixed::sincos`]); the nine entries of
//! R as Q30, each from 32 × 32-bit products summed in 64 bits and rounded once; per leg
//! R·b_i summed in 64 bits (Q30·nm) and rounded once to half nanometres (hn); the leg
//! vector v = 2p + R·b − 2a (hn, exact integers) with each component below 2^31 hn
//! (1.07 m, else out of reach), |v|² exact in `u64`, the correctly rounded integer root
//! and a final rounding to nm. The inverse has no reach test beyond that range: the
//! joints' travel bounds the workspace (`inverse_checked`), and forward kinematics
//! reports singular poses.
//!
//! Error budget (each leg, against exact arithmetic on the same integer pose): each R
//! entry ≤ 3 · 1.0e-9 (sin/cos errors and product roundings), times |b| = 150 mm:
//! ≤ 0.45 nm per term of R·b, ≤ 0.25 nm hn rounding per component; the leg length
//! moves by at most |δv| ≤ 1.0 nm, plus 0.25 nm root and 0.5 nm final rounding:
//! ≈ 1.8 nm worst case; measured: see `docs/performance.md` (≤ 5 nm required).
//!
//! Forward: Newton from the guess on all six axes. Each iteration evaluates the
//! fixed-point inverse (exact residual to the hn), builds the 6 × 6 Jacobian in `f32`
//! (row i: the leg direction n_i and (R·b_i × n_i)·u_k for the rotation axes
//! u_A = R·x̂, u_B = Rz(C)·ŷ, u_C = ẑ, divided by the lever |b|max so all columns are
//! nm), solves with partial pivoting and applies the rounded step; it stops after the
//! first step of at most 1 nm on X Y Z and at most the rotation moving a platform joint
//! by 1 nm on A B C.

use super::fixed::{self, i64_to_f32, isqrt_round, round_f32, shr_round, sincos, NDEG_PER_RAD};
use super::solve::solve;
use super::{Joints, Pose, Unreachable, FINAL_STEP, MAX_ITERATIONS};
use crate::config::{HexapodGeometry, GEOMETRY_MAX};

/// Sub-nanometre bits of the leg vectors: half nanometres.
const SUB: u32 = 1;
/// Largest leg-vector component, hn.
const V_MAX: u64 = 1 << 31;

/// Hexapod, precomputed from [`HexapodGeometry`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Hexapod {
    /// Base joints, hn.
    base: [[i64; 3]; 6],
    /// Platform joints, nm.
    platform: [[i32; 3]; 6],
    /// Largest |b_i|, nm: the lever the angles are scaled by.
    lever: i64,
}

/// Per-leg values the forward kinematics' Jacobian is built from.
struct LegState {
    /// Leg vector, hn.
    v: [i64; 3],
    /// R·b, nm·2^30.
    rb: [i64; 3],
    /// Unrounded length, hn.
    len: u64,
}

fn in_range(v: i64) -> bool {
    v.unsigned_abs() < GEOMETRY_MAX as u64
}

/// Rounded Q30 product of two Q30 values.
#[inline(always)]
fn mul30(a: i32, b: i32) -> i32 {
    shr_round(a as i64 * b as i64, 30) as i32
}

impl Hexapod {
    /// Precomputes `g` (validated by [`crate::config::MachineConfig::validate`]).
    pub fn new(g: &HexapodGeometry) -> Self {
        let mut lever = 1;
        for b in &g.platform {
            let sq: u64 = b.iter().map(|c| c.unsigned_abs().pow(2)).sum();
            lever = lever.max(isqrt_round(sq) as i64);
        }
        Self {
            base: g.base.map(|a| a.map(|c| c << SUB)),
            platform: g.platform.map(|b| b.map(|c| c as i32)),
            lever,
        }
    }

    /// The inverse kinematics, reporting each leg's intermediate values to `leg`;
    /// returns R and (sin C, cos C), Q30.
    #[inline(always)]
    fn eval(
        &self,
        pose: &Pose,
        joints: &mut Joints,
        mut leg: impl FnMut(usize, LegState),
    ) -> Result<([[i32; 3]; 3], [i32; 2]), Unreachable> {
        let [x, y, z, a, b, c] = *pose;
        if !(in_range(x) && in_range(y) && in_range(z)) {
            return Err(Unreachable::OutOfReach);
        }
        let (sa, ca) = sincos(a);
        let (sb, cb) = sincos(b);
        let (sc, cc) = sincos(c);
        let p2 = |u: i32, v: i32, w: i32, t: i32| {
            shr_round(u as i64 * v as i64 + w as i64 * t as i64, 30) as i32
        };
        let sbsa = mul30(sb, sa);
        let sbca = mul30(sb, ca);
        let r = [
            [mul30(cc, cb), p2(cc, sbsa, -sc, ca), p2(cc, sbca, sc, sa)],
            [mul30(sc, cb), p2(sc, sbsa, cc, ca), p2(sc, sbca, -cc, sa)],
            [-sb, mul30(cb, sa), mul30(cb, ca)],
        ];
        let p = [x << SUB, y << SUB, z << SUB];
        for (i, ((q, bi), ai)) in joints
            .iter_mut()
            .zip(&self.platform)
            .zip(&self.base)
            .enumerate()
        {
            let mut v = [0i64; 3];
            let mut rb = [0i64; 3];
            let mut sq = 0u64;
            for k in 0..3 {
                let w = r[k][0] as i64 * bi[0] as i64
                    + r[k][1] as i64 * bi[1] as i64
                    + r[k][2] as i64 * bi[2] as i64;
                rb[k] = w;
                v[k] = p[k] + shr_round(w, 30 - SUB) - ai[k];
                let m = v[k].unsigned_abs();
                if m >= V_MAX {
                    return Err(Unreachable::OutOfReach);
                }
                sq += m * m;
            }
            let len = isqrt_round(sq);
            *q = shr_round(len as i64, SUB);
            leg(i, LegState { v, rb, len });
        }
        Ok((r, [sc, cc]))
    }

    /// Joints of `pose`.
    pub fn inverse(&self, pose: &Pose, joints: &mut Joints) -> Result<(), Unreachable> {
        self.eval(pose, joints, |_, _| {}).map(|_| ())
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
        let one = fixed::ONE_Q30 as f32;
        for it in 1..=MAX_ITERATIONS {
            let mut q = [0; super::MAX_JOINTS];
            let mut rows = [[0.0f32; 6]; 6];
            let mut res = [0.0f32; 6];
            let (rq, [sc, cc]) = self.eval(&p, &mut q, |i, s| {
                let inv = 1.0 / i64_to_f32(s.len as i64);
                let n = s.v.map(|c| i64_to_f32(c) * inv);
                let rb = s.rb.map(|c| i64_to_f32(c) / (one * lever));
                // m = (R·b × n) / lever; row = (n, m·u_A, m·u_B, m·u_C).
                rows[i][..3].copy_from_slice(&n);
                rows[i][3..].copy_from_slice(&[
                    rb[1] * n[2] - rb[2] * n[1],
                    rb[2] * n[0] - rb[0] * n[2],
                    rb[0] * n[1] - rb[1] * n[0],
                ]);
                let t = joints[i].wrapping_shl(SUB).wrapping_sub(s.len as i64);
                res[i] = i64_to_f32(t) * 0.5;
            })?;
            // Column A: m·(R x̂); B: m·(Rz(C) ŷ) = m·(−sin C, cos C, 0); C: m·ẑ.
            let (sc, cc) = (sc as f32 / one, cc as f32 / one);
            let ua = [rq[0][0], rq[1][0], rq[2][0]].map(|v| v as f32 / one);
            for row in rows.iter_mut() {
                let m = [row[3], row[4], row[5]];
                row[3] = m[0] * ua[0] + m[1] * ua[1] + m[2] * ua[2];
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
    use crate::kinematics::reference::{self as re, real};
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

    fn lcg(state: &mut u64) -> f64 {
        *state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (*state >> 11) as f64 / (1u64 << 53) as f64
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

    fn fk_case(g: &HexapodGeometry, k: &Hexapod, s: &mut u64) -> (u8, f64, f64, f64) {
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
        let mut out = [0; 6];
        let it = match k.forward(&q, &guess, &mut out) {
            Ok(it) => it,
            Err(e) => panic!("{e:?}: p {p:?} guess {guess:?}"),
        };
        let mut want = real(&p);
        let target: [f64; 6] = std::array::from_fn(|i| q[i] as f64);
        re::newton(
            |x| re::hexapod_inverse(g, x),
            &target,
            &mut want,
            [0, 1, 2, 3, 4, 5],
        );
        let lin = (0..3)
            .map(|i| (out[i] as f64 - want[i]).abs())
            .fold(0.0, f64::max);
        let ang = (3..6)
            .map(|i| (out[i] as f64 - want[i]).abs())
            .fold(0.0, f64::max);
        let rt = (0..3)
            .map(|i| (out[i] - p[i]).abs() as f64)
            .fold(0.0, f64::max);
        (it, lin, ang, rt)
    }

    #[test]
    fn forward_converges_in_3_iterations_from_the_previous_period() {
        let g = geometry();
        let k = Hexapod::new(&g);
        let mut seed = 9;
        let (mut it_max, mut lin_max, mut ang_max, mut rt_max) = (0, 0.0f64, 0.0f64, 0.0f64);
        let mut hist = [0u32; MAX_ITERATIONS as usize + 1];
        let n = 5_000;
        for _ in 0..n {
            let (it, lin, ang, rt) = fk_case(&g, &k, &mut seed);
            hist[it as usize] += 1;
            it_max = it_max.max(it);
            lin_max = lin_max.max(lin);
            ang_max = ang_max.max(ang);
            rt_max = rt_max.max(rt);
        }
        eprintln!(
            "hexapod forward: iterations histogram {hist:?}; vs f64 solution: \
             max {lin_max:.3} nm on X Y Z, {ang_max:.0} n° on A B C; round trip max {rt_max} nm ({n} cases)"
        );
        assert!(it_max <= 3);
        // The inverse's error (≤ 0.75 nm before its final rounding) through the
        // Jacobian, plus the rounding of the result to whole nm.
        assert!(lin_max <= 2.5, "{lin_max}");
        assert!(ang_max <= 1_000.0, "{ang_max}");
    }
}
