//! H-4 head with rolling table: inverse kinematics in fixed point, forward kinematics
//! by Newton iteration.
//!
//! Geometry and conventions: [`H4TableGeometry`]. Pose X Y Z = tool tip in workpiece
//! coordinates (nm), C = head rotation θ, A = table angle (n°), B unused (forward keeps
//! the guess's B). Joints q1..q4 carriage heights (nm), q5 = A (n°).
//!
//! Inverse, per call: sin/cos of A and θ (Q30, [`fixed::sincos`]); the table map
//! T = r + Rx(A)(p − r) as 32 × 32-bit products summed in 64 bits and rounded once to
//! quarter nanometres (qn); E = T + (0, 0, tool); per arm the horizontal offsets dx, dy
//! from the rail (qn, exact sums of rounded terms), N = (4L)² − dx² − dy² exact in
//! `u64` (qn²), then q = P_z + √N with the correctly rounded integer root, rounded to
//! nm. Out of reach when ρ > L; too near the singularity when the forearm is flatter
//! than `min_elevation` (N below (4L·sin e)², the test done on the exact N).
//!
//! Error budget (each joint, against exact arithmetic on the same integer pose):
//! sin/cos ≤ 1.0e-9 each, times |p − r| ≤ 0.25 m and d = 60 mm: ≤ 0.36 nm on T,
//! ≤ 0.06 nm on the bar term; quarter-nm roundings ≤ 0.125 nm per term: horizontal
//! error |δP_h| ≤ 0.75 nm, vertical ≤ 0.5 nm. The joint gains ρ/h = cot(elevation)
//! ≤ cot 25° = 2.14 on the horizontal part, so ≤ 1.6 + 0.5 + 0.125 (root) + 0.5 (final
//! rounding) ≈ 2.7 nm worst case; measured: see `docs/performance.md` (≤ 5 nm
//! required).
//!
//! Forward: A = q5; X Y Z C by Newton from the guess. Each iteration evaluates the
//! fixed-point inverse above (so the residual is exact to the qn), builds the 4 × 4
//! analytic Jacobian in `f32` from the same intermediate values (rows
//! (−dx/h, −dy/h, 1)·Rx(A) for X Y Z and the bar lever term for θ, scaled to nm at the
//! lever d), solves it with partial pivoting and applies the rounded step. It stops
//! after the first step of at most 1 nm on X Y Z and at most the rotation moving a bar
//! end by 1 nm on C: 3 iterations from the pose of the previous 1 ms period.

use super::fixed::{self, i64_to_f32, isqrt_round, round_f32, shr_round, sincos, NDEG_PER_RAD};
use super::solve::solve;
use super::{Joints, Pose, Unreachable, FINAL_STEP, MAX_ITERATIONS};
use crate::config::{H4TableGeometry, GEOMETRY_MAX};

/// Sub-nanometre bits of the intermediate positions: quarter nanometres.
const SUB: u32 = 2;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Arm {
    /// Attachment minus rail in X and Y, attachment Z; qn.
    offset: [i64; 3],
    /// Bar end: +1 or −1.
    side: i8,
}

/// H-4 with rolling table, precomputed from [`H4TableGeometry`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct H4Table {
    arms: [Arm; 4],
    bar_half: i32,
    /// Table axis Y Z, nm.
    pivot: [i64; 2],
    /// Table axis Y and Z + tool length, qn.
    pivot_q: [i64; 2],
    /// Forearm length, qn.
    reach: u64,
    /// (4L)², qn².
    reach_sq: u64,
    /// Smallest N = (4L)² − ρ² allowed: (4L·sin(min elevation))².
    near_sq: u64,
}

/// Per-arm values the forward kinematics' Jacobian is built from.
struct ArmState {
    dx: i64,
    dy: i64,
    h: u64,
    /// Unrounded joint, qn.
    q: i64,
}

fn in_range(v: i64) -> bool {
    v.unsigned_abs() < GEOMETRY_MAX as u64
}

impl H4Table {
    /// Precomputes `g` (validated by [`crate::config::MachineConfig::validate`]).
    pub fn new(g: &H4TableGeometry) -> Self {
        let arm = |i: usize| Arm {
            offset: [
                (g.attach[i][0] - g.rails[i][0]) << SUB,
                (g.attach[i][1] - g.rails[i][1]) << SUB,
                g.attach[i][2] << SUB,
            ],
            side: g.sides[i],
        };
        let reach = (g.forearm << SUB) as u64;
        let (s, _) = sincos(g.min_elevation);
        let near = shr_round(reach as i64 * s as i64, 30) as u64;
        Self {
            arms: [arm(0), arm(1), arm(2), arm(3)],
            bar_half: g.bar_half as i32,
            pivot: [g.table_pivot[1], g.table_pivot[2]],
            pivot_q: [
                g.table_pivot[1] << SUB,
                (g.table_pivot[2] + g.tool_length) << SUB,
            ],
            reach,
            reach_sq: reach * reach,
            near_sq: near * near,
        }
    }

    /// The inverse kinematics, reporting each arm's intermediate values to `arm`;
    /// returns (sin A, cos A, sin θ, cos θ), Q30.
    #[inline(always)]
    fn eval(
        &self,
        pose: &Pose,
        joints: &mut Joints,
        mut arm: impl FnMut(usize, ArmState),
    ) -> Result<[i32; 4], Unreachable> {
        let [x, y, z, a, _, theta] = *pose;
        if !(in_range(x) && in_range(y) && in_range(z)) {
            return Err(Unreachable::OutOfReach);
        }
        let (sa, ca) = sincos(a);
        let (st, ct) = sincos(theta);
        // Table: T = r + Rx(A)(p − r); both terms < 2^31 nm, products nm·2^30.
        let py = (y - self.pivot[0]) as i32 as i64;
        let pz = (z - self.pivot[1]) as i32 as i64;
        let ty = ca as i64 * py - sa as i64 * pz;
        let tz = sa as i64 * py + ca as i64 * pz;
        // Head point E, qn.
        let ex = x << SUB;
        let ey = self.pivot_q[0] + shr_round(ty, 30 - SUB);
        let ez = self.pivot_q[1] + shr_round(tz, 30 - SUB);
        let dc = shr_round(self.bar_half as i64 * ct as i64, 30 - SUB);
        let ds = shr_round(self.bar_half as i64 * st as i64, 30 - SUB);
        for (i, (q, m)) in joints.iter_mut().zip(&self.arms).enumerate() {
            let (bx, by) = if m.side > 0 { (dc, ds) } else { (-dc, -ds) };
            let dx = ex + bx + m.offset[0];
            let dy = ey + by + m.offset[1];
            let (ax, ay) = (dx.unsigned_abs(), dy.unsigned_abs());
            if ax > self.reach || ay > self.reach {
                return Err(Unreachable::OutOfReach);
            }
            let n = self
                .reach_sq
                .checked_sub(ax * ax)
                .and_then(|n| n.checked_sub(ay * ay))
                .ok_or(Unreachable::OutOfReach)?;
            if n < self.near_sq {
                return Err(Unreachable::Singular);
            }
            let h = isqrt_round(n);
            let qq = ez + m.offset[2] + h as i64;
            *q = shr_round(qq, SUB);
            arm(i, ArmState { dx, dy, h, q: qq });
        }
        joints[4] = a;
        Ok([sa, ca, st, ct])
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
        p[3] = joints[4];
        let ndeg_per_nm = NDEG_PER_RAD as f32 / self.bar_half as f32;
        let one = fixed::ONE_Q30 as f32;
        for it in 1..=MAX_ITERATIONS {
            let mut q = [0; super::MAX_JOINTS];
            let mut g = [[0.0f32; 2]; 4];
            let mut r = [0.0f32; 4];
            let trig = self.eval(&p, &mut q, |i, s| {
                let h = i64_to_f32(s.h as i64);
                g[i] = [-i64_to_f32(s.dx) / h, -i64_to_f32(s.dy) / h];
                r[i] = i64_to_f32(joints[i].wrapping_shl(SUB).wrapping_sub(s.q)) * 0.25;
            })?;
            let [sa, ca, st, ct] = trig.map(|v| v as f32 / one);
            let mut jac = [[0.0f32; 4]; 4];
            for ((row, [gx, gy]), arm) in jac.iter_mut().zip(g).zip(&self.arms) {
                // ∂q/∂E = (gx, gy, 1); ∂E/∂p = Rx(A); ∂q/∂(dθ) per nm at the bar end.
                *row = [
                    gx,
                    gy * ca + sa,
                    ca - gy * sa,
                    arm.side as f32 * (gy * ct - gx * st),
                ];
            }
            solve(&mut jac, &mut r)?;
            p[0] += round_f32(r[0]);
            p[1] += round_f32(r[1]);
            p[2] += round_f32(r[2]);
            p[5] += round_f32(r[3] * ndeg_per_nm);
            if r.iter().all(|s| s.abs() <= FINAL_STEP) {
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

    fn geometry() -> H4TableGeometry {
        match MachineConfig::h4_table().kinematics {
            KinematicsConfig::H4Table(g) => g,
            _ => unreachable!(),
        }
    }

    /// Largest joint error (nm) of the fixed-point inverse against the f64 reference.
    fn ik_error(g: &H4TableGeometry, k: &H4Table, pose: &Pose) -> f64 {
        let want = re::h4_inverse(g, &real(pose)).expect("reference: reachable");
        let mut q = [0; MAX_JOINTS];
        k.inverse(pose, &mut q).expect("fixed point: reachable");
        assert_eq!(q[4], pose[3]);
        (0..4)
            .map(|i| (q[i] as f64 - want[i]).abs())
            .fold(0.0, f64::max)
    }

    fn lcg(state: &mut u64) -> f64 {
        *state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (*state >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Random pose over the usable box: E within |x|, |y| ≤ 100 mm, |z| ≤ 50 mm of home,
    /// |θ| ≤ 45°, A in 0..90°.
    fn random_pose(g: &H4TableGeometry, s: &mut u64) -> Pose {
        let mut u = |lo: f64, hi: f64| lo + (hi - lo) * lcg(s);
        let e = [u(-100.0, 100.0), u(-100.0, 100.0), u(-50.0, 50.0)];
        re::h4_pose_from_head(g, e, u(-45.0, 45.0), u(0.0, 90.0))
    }

    #[test]
    fn home_puts_every_carriage_at_475_815_mm() {
        let m = MachineConfig::h4_table();
        let k = H4Table::new(&geometry());
        let mut q = [0; MAX_JOINTS];
        k.inverse(&m.home, &mut q).unwrap();
        // sqrt(550² − (190² + 200²)) mm = 475.8150901… mm
        assert_eq!(
            q[..5],
            [475_815_090, 475_815_090, 475_815_090, 475_815_090, 0]
        );
    }

    #[test]
    fn the_inverse_is_within_5_nm_of_the_reference_over_the_usable_box() {
        let g = geometry();
        let k = H4Table::new(&g);
        let mut seed = 1;
        let mut worst = 0.0f64;
        let n = 100_000;
        for _ in 0..n {
            let p = random_pose(&g, &mut seed);
            worst = worst.max(ik_error(&g, &k, &p));
        }
        eprintln!("H-4 + table inverse: max joint error {worst:.3} nm over {n} poses");
        assert!(worst <= 5.0, "{worst} nm");
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(20_000))]
        #[test]
        fn inverse_error_is_at_most_5_nm(
            x in -100.0..100.0f64, y in -100.0..100.0f64, z in -50.0..50.0f64,
            theta in -45.0..45.0f64, a in 0.0..90.0f64,
        ) {
            let g = geometry();
            let p = re::h4_pose_from_head(&g, [x, y, z], theta, a);
            prop_assert!(ik_error(&g, &H4Table::new(&g), &p) <= 5.0);
        }
    }

    #[test]
    fn a_flat_forearm_is_too_near_a_singularity_and_a_far_one_out_of_reach() {
        let g = geometry();
        let k = H4Table::new(&g);
        let mut q = [0; MAX_JOINTS];
        // E at x = +280 mm: arm 1 (rail at x −250) has ρ ≈ 511 mm: 22° elevation.
        let flat = re::h4_pose_from_head(&g, [280.0, 0.0, 0.0], 0.0, 0.0);
        assert_eq!(k.inverse(&flat, &mut q), Err(Unreachable::Singular));
        let far = re::h4_pose_from_head(&g, [400.0, 0.0, 0.0], 0.0, 0.0);
        assert_eq!(k.inverse(&far, &mut q), Err(Unreachable::OutOfReach));
        let absurd = [i64::MAX, 0, 0, 0, 0, 0];
        assert_eq!(k.inverse(&absurd, &mut q), Err(Unreachable::OutOfReach));
    }

    /// Runs forward kinematics from a guess one 1 ms period of motion away (200 mm/s in
    /// a random direction, 90 °/s on θ); returns (iterations, largest linear error of
    /// the result against the f64 solution for the same joints in nm, its θ error in
    /// n°, largest round-trip error against the original pose in nm).
    fn fk_case(g: &H4TableGeometry, k: &H4Table, s: &mut u64) -> (u8, f64, f64, f64) {
        let p = random_pose(g, s);
        let mut q = [0; MAX_JOINTS];
        k.inverse(&p, &mut q).unwrap();
        let dir = [lcg(s) - 0.5, lcg(s) - 0.5, lcg(s) - 0.5];
        let norm = (dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]).sqrt();
        let mut guess = p;
        for i in 0..3 {
            guess[i] -= (200_000.0 * dir[i] / norm).round() as i64;
        }
        guess[5] -= if lcg(s) < 0.5 {
            90_000_000
        } else {
            -90_000_000
        };
        let mut out = [0; 6];
        let it = k.forward(&q, &guess, &mut out).expect("converges");
        assert_eq!(out[3], p[3]);
        let mut want = real(&p);
        let target = [q[0], q[1], q[2], q[3]].map(|v| v as f64);
        re::newton(
            |x| re::h4_inverse(g, x).unwrap()[..4].try_into().unwrap(),
            &target,
            &mut want,
            [0, 1, 2, 5],
        );
        let lin = (0..3)
            .map(|i| (out[i] as f64 - want[i]).abs())
            .fold(0.0, f64::max);
        let rt = (0..3)
            .map(|i| (out[i] - p[i]).abs() as f64)
            .fold(0.0, f64::max);

        (it, lin, (out[5] as f64 - want[5]).abs(), rt)
    }

    #[test]
    fn forward_converges_in_3_iterations_from_the_previous_period() {
        let g = geometry();
        let k = H4Table::new(&g);
        let mut seed = 5;
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
            "H-4 + table forward: iterations histogram {hist:?}; vs f64 solution: \
             max {lin_max:.3} nm on X Y Z, {ang_max:.0} n° on C; round trip max {rt_max} nm ({n} cases)"
        );
        assert!(it_max <= 3);
        assert!(lin_max <= 1.5, "{lin_max}");
        assert!(ang_max <= 1_500.0, "{ang_max}");
    }
}
