//! H-4 head with rolling table: inverse kinematics in fixed point, forward kinematics
//! by Newton iteration.
//!
//! Geometry and conventions: [`H4TableGeometry`]. Pose X Y Z = tool tip in workpiece
//! coordinates (nm), C = head rotation θ, A = table angle (n°), B unused (forward keeps
//! the guess's B). Joints q1..q4 carriage heights (nm), q5 = A (n°).
//!
//! Inverse, per call: sin/cos of A and θ (Q31, [`fixed::sincos`]); Rx(A)(p − r) as
//! 32 × 32-bit products summed in 64 bits and rounded once to half nanometres (hn);
//! the bar ends d·(cos θ, sin θ) likewise; per arm the horizontal offsets dx, dy of the
//! bar end from the rail (hn, 32-bit sums with per-arm constants that fold in the table
//! axis, the attachment and the rail), ρ² = dx² + dy² exact in 64 bits, N = (2L)² − ρ²,
//! q = P_z + √N with the integer root of [`fixed::isqrt`], rounded to nm. Out of reach
//! when ρ > L; too near the singularity when the forearm is flatter than
//! `min_elevation` (ρ² above (2L)²·cos² e, tested on the exact ρ²). The 32-bit sums
//! cannot overflow because poses beyond |X| ≤ 2^30 nm − |attachment − rail| − d, or
//! farther than (2^30 nm − |offsets| − d)/√2 from the table axis in Y or Z, are refused
//! as out of reach first (763 mm and 575 mm for the default machine, both far beyond
//! every arm's reach).
//!
//! Error budget (each joint, against exact arithmetic on the same integer pose):
//! sin/cos ≤ 7.0e-10 each, times |p − r| ≤ 0.25 m: ≤ 0.25 nm on each component of E,
//! and ≤ 0.06 nm on the bar term (d = 60 mm); hn roundings ≤ 0.25 nm per term, so the
//! horizontal error |δP_h| ≤ 0.9 nm and the vertical ≤ 0.5 nm. The joint gains
//! ρ/h = cot(elevation) ≤ cot 25° = 2.14 on the horizontal part: ≤ 1.9 + 0.5 + 0.26
//! (root) + 0.5 (final rounding) ≈ 3.2 nm worst case, typically far less; measured
//! 1.39 nm over 100 000 poses (`docs/performance.md`; ≤ 5 nm required).
//!
//! Forward: A = q5; X Y Z C by Newton from the guess. Each iteration evaluates the
//! inverse in 1/16 nm (`eval_fine`: the same steps with 128-bit squares, so the
//! residual is smooth to ~0.1 nm), builds the 4 × 4 analytic Jacobian in `f32` from
//! the same intermediate values (rows
//! (−dx/h, −dy/h, 1)·Rx(A) for X Y Z and the bar lever term for θ, scaled to nm at the
//! lever d), solves it with partial pivoting and applies the rounded step, and stops
//! after a step of at most [`FINAL_STEP`](super::FINAL_STEP): 2 iterations from the
//! pose of the previous 1 ms period ([`super::solve::newton`]).
//!
//! Jacobian ([`H4Table::jacobian`], for the planner's joint rates): the same rows, θ
//! rescaled to n°, plus the A column (E turns with the table) and q5 = A.

use super::fixed::{round_f32, NDEG_PER_RAD};
use super::solve::newton;
use super::{Joints, Pose, Unreachable};
use crate::config::{H4TableGeometry, AXES, MAX_JOINTS};
use crate::math::{i64_to_f32, isqrt, isqrt_wide, sincos, ONE_Q31};

/// Sub-nanometre bits of the intermediate positions: half nanometres.
const SUB: u32 = 1;
/// Fraction bits of a Q31 × nm product, less [`SUB`]: the shift back to hn.
const TO_HN: u32 = 31 - SUB;
/// Sub-nanometre bits of the forward kinematics' residuals: 1/16 nm.
const FINE: u32 = 4;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Arm {
    /// X: attachment minus rail; Y: table axis plus attachment minus rail; hn.
    offset: [i32; 2],
    /// Table axis Z plus tool length plus attachment Z, hn, plus the final rounding's
    /// half.
    z: i32,
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
    /// (2L)², hn².
    reach_sq: u64,
    /// Largest ρ² allowed, hn²: (2L)² − (2L·sin(min elevation))².
    rho_sq_max: u64,
    /// Largest |X| taken, nm.
    x_max: u64,
    /// Largest |Y − pivot Y|, |Z − pivot Z| taken, nm.
    yz_max: u64,
}

impl H4Table {
    /// Precomputes `g` (validated by [`crate::config::MachineConfig::validate`]).
    pub fn new(g: &H4TableGeometry) -> Self {
        let [_, py, pz] = g.table_pivot;
        let arm = |i: usize| Arm {
            offset: [
                ((g.attach[i][0] - g.rails[i][0]) << SUB) as i32,
                ((py + g.attach[i][1] - g.rails[i][1]) << SUB) as i32,
            ],
            z: (((pz + g.tool_length + g.attach[i][2]) << SUB) + 1) as i32,
            side: g.sides[i],
        };
        let arms = [arm(0), arm(1), arm(2), arm(3)];
        let reach = (g.forearm << SUB) as u64;
        let (s, _) = sincos(g.min_elevation);
        let near = (reach * s as u64 + (1 << 30)) >> 31;
        // Pose range keeping every per-arm sum inside 32 bits (hn): |X| + |offset X| + d
        // and √2·max(|Y − pivot Y|, |Z − pivot Z|) + |offset Y or Z| + d below 2^30 nm.
        let room = |o: fn(&Arm) -> i32| {
            let worst = arms
                .iter()
                .map(|a| (o(a).unsigned_abs() / 2 + 1) as u64)
                .max();
            ((1u64 << 30) - 64).saturating_sub(worst.unwrap_or(0) + g.bar_half as u64)
        };
        let x_room = room(|a| a.offset[0]);
        let yz_room = room(|a| a.offset[1]).min(room(|a| a.z));
        Self {
            arms,
            bar_half: g.bar_half as i32,
            pivot: [py, pz],
            reach_sq: reach * reach,
            rho_sq_max: reach * reach - near * near,
            x_max: x_room,
            yz_max: (yz_room * 46_340) >> 16, // / √2
        }
    }

    /// Y and Z of `pose` from the table axis, nm; out of reach beyond the pose range
    /// (see the module doc).
    #[inline(always)]
    fn relative_to_pivot(&self, pose: &Pose) -> Result<(i64, i64), Unreachable> {
        let [x, y, z, ..] = *pose;
        let (py, pz) = (y.wrapping_sub(self.pivot[0]), z.wrapping_sub(self.pivot[1]));
        if x.unsigned_abs() > self.x_max
            || py.unsigned_abs() > self.yz_max
            || pz.unsigned_abs() > self.yz_max
        {
            return Err(Unreachable::OutOfReach);
        }
        Ok((py, pz))
    }

    /// Joints of `pose`.
    pub fn inverse(&self, pose: &Pose, joints: &mut Joints) -> Result<(), Unreachable> {
        let [x, _, _, a, _, theta] = *pose;
        let (py, pz) = self.relative_to_pivot(pose)?;
        let (sa, ca) = sincos(a);
        let (st, ct) = sincos(theta);
        // Rx(A)(p − r) and the bar ends d·(cos θ, sin θ), hn; the products are nm·2^31.
        // Within the pose range every sum below fits in 32 bits.
        let (py, pz) = (py as i32 as i64, pz as i32 as i64);
        let half = 1i64 << (TO_HN - 1);
        let ey = ((ca as i64 * py - sa as i64 * pz + half) >> TO_HN) as i32;
        let ez = ((sa as i64 * py + ca as i64 * pz + half) >> TO_HN) as i32;
        let ex = (x << SUB) as i32;
        let dc = ((self.bar_half as i64 * ct as i64 + half) >> TO_HN) as i32;
        let ds = ((self.bar_half as i64 * st as i64 + half) >> TO_HN) as i32;
        for (q, m) in joints.iter_mut().zip(&self.arms) {
            let (bx, by) = if m.side > 0 { (dc, ds) } else { (-dc, -ds) };
            let dx = ex.wrapping_add(m.offset[0]).wrapping_add(bx);
            let dy = ey.wrapping_add(m.offset[1]).wrapping_add(by);
            let rho_sq = (dx as i64 * dx as i64) as u64 + (dy as i64 * dy as i64) as u64;
            if rho_sq > self.rho_sq_max {
                return Err(if rho_sq > self.reach_sq {
                    Unreachable::OutOfReach
                } else {
                    Unreachable::Singular
                });
            }
            let h = isqrt(self.reach_sq - rho_sq);
            let qq = ez.wrapping_add(m.z) as i64 + h as i64;
            *q = qq >> SUB;
        }
        joints[4] = a;
        Ok(())
    }

    /// The inverse kinematics in 1/16 nm for the forward kinematics' residuals: the same
    /// steps as [`Self::inverse`] (and the same range and reach checks) with every length
    /// in 1/16 nm, squares in 128 bits and [`fixed::isqrt_wide`], so the residual is
    /// smooth to ~0.1 nm instead of the inverse's half-nm roundings. Reports per arm
    /// (dx, dy, h, q), 1/16 nm; returns (sin A, cos A, sin θ, cos θ), Q31.
    #[inline(always)]
    fn eval_fine(
        &self,
        pose: &Pose,
        mut arm: impl FnMut(usize, [i64; 4]),
    ) -> Result<[i32; 4], Unreachable> {
        let [x, _, _, a, _, theta] = *pose;
        let (py, pz) = self.relative_to_pivot(pose)?;
        let (sa, ca) = sincos(a);
        let (st, ct) = sincos(theta);
        const SH: u32 = 31 - FINE;
        let half = 1i64 << (SH - 1);
        let ey = (ca as i64 * py - sa as i64 * pz + half) >> SH;
        let ez = (sa as i64 * py + ca as i64 * pz + half) >> SH;
        let ex = x << FINE;
        let dc = (self.bar_half as i64 * ct as i64 + half) >> SH;
        let ds = (self.bar_half as i64 * st as i64 + half) >> SH;
        let scale = 1u128 << (2 * (FINE - SUB));
        let reach_sq = self.reach_sq as u128 * scale;
        for (i, m) in self.arms.iter().enumerate() {
            let (bx, by) = if m.side > 0 { (dc, ds) } else { (-dc, -ds) };
            let dx = ex + ((m.offset[0] as i64) << (FINE - SUB)) + bx;
            let dy = ey + ((m.offset[1] as i64) << (FINE - SUB)) + by;
            let rho_sq = (dx as i128 * dx as i128 + dy as i128 * dy as i128) as u128;
            if rho_sq > self.rho_sq_max as u128 * scale {
                return Err(if rho_sq > reach_sq {
                    Unreachable::OutOfReach
                } else {
                    Unreachable::Singular
                });
            }
            let h = isqrt_wide(reach_sq - rho_sq) as i64;
            let q = ez + (((m.z - 1) as i64) << (FINE - SUB)) + h;
            arm(i, [dx, dy, h, q]);
        }
        Ok([sa, ca, st, ct])
    }

    /// One Newton system at `p`: `jac` the analytic Jacobian of carriages q1..q4 over
    /// X Y Z (nm/nm) and θ (nm per nm of arc at the bar end), `r` the residual
    /// `joints − q(p)`, nm, from [`Self::eval_fine`]. Returns (sin A, cos A, sin θ,
    /// cos θ) and per arm ∂q/∂E_x, ∂q/∂E_y (−dx/h, −dy/h).
    #[inline(always)]
    fn linearize(
        &self,
        p: &Pose,
        joints: &Joints,
        jac: &mut [[f32; 4]; 4],
        r: &mut [f32; 4],
    ) -> Result<([f32; 4], [[f32; 2]; 4]), Unreachable> {
        let unit = 1.0 / (1u32 << FINE) as f32;
        let mut g = [[0.0f32; 2]; 4];
        let trig = self.eval_fine(p, |i, [dx, dy, h, q]| {
            let h = i64_to_f32(h);
            g[i] = [-i64_to_f32(dx) / h, -i64_to_f32(dy) / h];
            let target = joints[i].wrapping_shl(FINE);
            r[i] = i64_to_f32(target.wrapping_sub(q)) * unit;
        })?;
        let [sa, ca, st, ct] = trig.map(|v| v as f32 / ONE_Q31);
        for ((row, [gx, gy]), arm) in jac.iter_mut().zip(g).zip(&self.arms) {
            // ∂q/∂E = (gx, gy, 1); ∂E/∂p = Rx(A); ∂q/∂(dθ) per nm at the bar end.
            *row = [
                gx,
                gy * ca + sa,
                ca - gy * sa,
                arm.side as f32 * (gy * ct - gx * st),
            ];
        }
        Ok(([sa, ca, st, ct], g))
    }

    /// The analytic Jacobian ∂q/∂p at `pose` (see [`super::Jacobian`]): the forward
    /// kinematics' rows, θ scaled from the bar end to n°, and the A column: E moves by
    /// ∂(Rx(A)(p − r))/∂A = (0, −E_z, E_y) (E from the table axis) per radian; q5 = A.
    pub fn jacobian(&self, pose: &Pose, jac: &mut super::Jacobian) -> Result<(), Unreachable> {
        let (py, pz) = self.relative_to_pivot(pose)?;
        let (mut rows, mut r) = ([[0.0f32; 4]; 4], [0.0f32; 4]);
        let ([sa, ca, ..], g) = self.linearize(pose, &[0; MAX_JOINTS], &mut rows, &mut r)?;
        let (py, pz) = (i64_to_f32(py), i64_to_f32(pz));
        let (ey, ez) = (ca * py - sa * pz, sa * py + ca * pz);
        let per_rad = 1.0 / NDEG_PER_RAD as f32;
        let theta_per_ndeg = self.bar_half as f32 * per_rad;
        *jac = [[0.0; AXES]; MAX_JOINTS];
        for ((j, row), [_, gy]) in jac.iter_mut().zip(rows).zip(g) {
            *j = [
                row[0],
                row[1],
                row[2],
                (ey - gy * ez) * per_rad,
                0.0,
                row[3] * theta_per_ndeg,
            ];
        }
        jac[4][3] = 1.0;
        Ok(())
    }

    /// Pose of `joints` by Newton iteration from `guess`; returns the iterations used.
    pub fn forward(
        &self,
        joints: &Joints,
        guess: &Pose,
        pose: &mut Pose,
    ) -> Result<u8, Unreachable> {
        let mut start = *guess;
        start[3] = joints[4];
        let ndeg_per_nm = NDEG_PER_RAD as f32 / self.bar_half as f32;
        newton(
            &start,
            pose,
            |p, jac, r| self.linearize(p, joints, jac, r).map(|_| ()),
            |p, r| {
                p[0] += round_f32(r[0]);
                p[1] += round_f32(r[1]);
                p[2] += round_f32(r[2]);
                p[5] += round_f32(r[3] * ndeg_per_nm);
            },
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{MachineConfig, MAX_JOINTS};
    use crate::kinematics::reference::{self as re, real};
    use crate::kinematics::suite;
    use proptest::prelude::*;

    fn geometry() -> H4TableGeometry {
        suite::h4_geometry(&MachineConfig::h4_table())
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(20_000))]
        /// Workpiece poses over the box in every table angle: some leave the machine's
        /// reach; the fixed point must agree with the reference on which.
        #[test]
        fn reach_agrees_with_the_reference_over_the_workpiece_box(
            x in -100_000_000i64..100_000_000, y in -100_000_000i64..100_000_000,
            z in -130_000_000i64..-30_000_000, theta in -45_000_000_000i64..45_000_000_000,
            a in 0i64..90_000_000_000,
        ) {
            let g = geometry();
            let k = H4Table::new(&g);
            let p = [x, y, z, a, 0, theta];
            let mut q = [0; MAX_JOINTS];
            match (re::h4_inverse(&g, &real(&p)), k.inverse(&p, &mut q)) {
                (Some(want), Ok(())) => {
                    for i in 0..4 {
                        prop_assert!((q[i] as f64 - want[i]).abs() <= 5.0);
                    }
                }
                (None, Err(_)) => {}
                (want, got) => {
                    // Only within a hair of the 25° limit may they disagree.
                    let mut near = g;
                    near.min_elevation -= 1_000;
                    let loose = re::h4_inverse(&near, &real(&p)).is_some();
                    near.min_elevation += 2_000;
                    let tight = re::h4_inverse(&near, &real(&p)).is_some();
                    prop_assert!(loose != tight, "{p:?}: {want:?} vs {got:?}");
                }
            }
        }
    }

    #[test]
    fn poses_beyond_the_fixed_point_range_are_out_of_reach_without_overflow() {
        let g = geometry();
        let k = H4Table::new(&g);
        let (xm, yzm) = (k.x_max as i64, k.yz_max as i64);
        assert!(xm > 700_000_000 && yzm > 550_000_000, "{xm} {yzm}");
        let (py, pz) = (g.table_pivot[1], g.table_pivot[2]);
        let mut q = [0; MAX_JOINTS];
        for (x, y, z) in [
            (xm, py, pz),
            (-xm, py + yzm, pz - yzm),
            (0, py - yzm, pz + yzm),
        ] {
            for angle in [0, 45_000_000_000, -135_000_000_000, 90_000_000_000] {
                // At the range limit: computed without overflow (and out of reach).
                let r = k.inverse(&[x, y, z, angle, 0, angle], &mut q);
                assert!(r.is_err());
            }
        }
        for p in [
            [xm + 1, 0, 0, 0, 0, 0],
            [0, py + yzm + 1, pz, 0, 0, 0],
            [0, py, pz - yzm - 1, 0, 0, 0],
        ] {
            assert_eq!(k.inverse(&p, &mut q), Err(Unreachable::OutOfReach));
        }
    }

    #[test]
    fn whole_turns_of_the_angles_change_nothing() {
        let g = geometry();
        let k = H4Table::new(&g);
        let p = re::h4_pose_from_head(&g, [20.0, -30.0, 10.0], 30.0, 40.0);
        let (mut q1, mut q2) = ([0; MAX_JOINTS], [0; MAX_JOINTS]);
        k.inverse(&p, &mut q1).unwrap();
        let turns = 3 * 360 * 1_000_000_000;
        k.inverse(&[p[0], p[1], p[2], p[3], 0, p[5] - turns], &mut q2)
            .unwrap();
        assert_eq!(q1, q2);
    }
}
