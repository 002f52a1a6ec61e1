//! Hexapod carrying the workpiece under a tool on an X-Y table: the machine of the
//! Stewart-platform report (`seeds-digest.md` B), with the table of a CNC machine
//! extending the platform's small workspace.
//!
//! Geometry: [`HexapodXyGeometry`]. Joints q1..q6 are the legs (as [`super::hexapod`]),
//! q7 and q8 the table's X and Y (nm). The tool points straight down; its tip is at
//! `T = (q7, q8, tool_z)` in the machine frame.
//!
//! **Program coordinates.** X Y Z A B are workpiece coordinates (the tool-centre point
//! idea of the H-4's rolling table): the point X Y Z of the workpiece is brought under
//! the tool tip, with the tool axis, in workpiece coordinates, along
//! `Rx(A)·Ry(B)·ẑ`. The workpiece is fixed to the platform; its coordinates are those of
//! the machine frame when the platform is at `platform_home` and level. C is not used
//! (the tool turns about its own axis).
//!
//! **Split rule** (deterministic, continuous): the platform turns the workpiece by
//! `R = Ry(−B)·Rx(−A)` about the platform origin, which brings the programmed tool axis
//! to vertical. The rotated point sits at `v' = R·(w − home)` from the platform origin.
//! The **table** takes the X-Y travel: `t = home_xy + v'_xy`, clamped to the table's
//! travel (joints q7, q8); the **platform** takes the orientation, all of Z
//! (`p_z = tool_z − v'_z`) and any X-Y remainder the table cannot reach
//! (`p_xy = t − v'_xy`, which is `home_xy` while the table is within its travel). Each
//! joint is a continuous function of the pose (the clamp is continuous; the joint
//! rates jump where the table reaches its end). Where the legs cannot follow, the
//! checked inverse refuses the pose with the leg (`JointLimit`), and the pre-flight
//! names the NC line.
//!
//! **Fixed point.** R in Q31 from [`crate::math::sincos`]; `R·v` with 64-bit products
//! (each below 2^62, summed after a 2-bit shift, rounded once to the nm): ≤ 0.5 nm
//! plus R's 2.4e-9 relative error (≤ 0.7 nm at 300 mm); then the hexapod's own inverse
//! (≤ 1.4 nm measured). Forward kinematics: the hexapod's Newton iteration for the
//! platform pose, then `w = home + Rᵀ·(T − p)` in the same arithmetic. The Jacobian is
//! the hexapod's chained with the split's derivatives, in `f32`.

// Matrix arithmetic over index-addressed rows and columns reads best with an index.
#![allow(clippy::needless_range_loop)]

use super::hexapod::Hexapod;
use super::{Jacobian, Joints, Pose, Unreachable};
use crate::config::{HexapodXyGeometry, JointConfig, AXES, MAX_JOINTS};
use crate::math::{i64_to_f32, sincos, ONE_Q31};

/// Radians per n°, as `f32`.
const RAD_PER_NDEG: f32 = core::f32::consts::PI / 180e9;

/// The machine, precomputed from [`HexapodXyGeometry`] and the table's travel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HexapodXy {
    pub(super) hexapod: Hexapod,
    /// Platform origin at home, nm.
    pub(super) home: [i64; 3],
    /// Tool tip height, nm.
    pub(super) tool_z: i64,
    /// Travel of the table's X and Y joints: `[min, max]`, nm.
    table: [[i64; 2]; 2],
    /// Largest |X|, |Y|, |Z| taken, nm: keeps `w − home` inside 31 bits.
    p_max: u64,
}

/// The split of a pose: the platform's pose, the table's X Y and the platform's Q31
/// rotation.
type Split = (Pose, [i64; 2], [[i32; 3]; 3]);

/// Q31 rotation `Ry(b)·Rx(a)` from n° (`rotation(a, b, 0)` without the third angle).
fn rotation_ab(a: i64, b: i64) -> [[i32; 3]; 3] {
    let (sa, ca) = sincos(a);
    let (sb, cb) = sincos(b);
    let m = |u: i32, v: i32| u as i64 * v as i64;
    let q = |v: i64| ((v + (1 << 30)) >> 31).clamp(-(i32::MAX as i64), i32::MAX as i64) as i32;
    [
        [cb, q(m(sb, sa)), q(m(sb, ca))],
        [0, ca, -sa],
        [-sb, q(m(cb, sa)), q(m(cb, ca))],
    ]
}

/// d(R·v)/d(X Y Z A B) for R = Ry(b)·Rx(a) with a = −A, b = −B (sines and cosines
/// given): R's columns, then −dR/da·v and −dR/db·v, the angle columns per
/// `per_angle` radians (a pose unit of angle).
pub(super) fn turned_derivatives(
    sa: f32,
    ca: f32,
    sb: f32,
    cb: f32,
    v: [f32; 3],
    per_angle: f32,
) -> [[f32; 5]; 3] {
    let r = [
        [cb, sb * sa, sb * ca],
        [0.0, ca, -sa],
        [-sb, cb * sa, cb * ca],
    ];
    let dr_da = [
        [0.0, sb * ca, -sb * sa],
        [0.0, -sa, -ca],
        [0.0, cb * ca, -cb * sa],
    ];
    let dr_db = [
        [-sb, cb * sa, cb * ca],
        [0.0, 0.0, 0.0],
        [-cb, -sb * sa, -sb * ca],
    ];
    let mv = |m: &[[f32; 3]; 3], k: usize| m[k][0] * v[0] + m[k][1] * v[1] + m[k][2] * v[2];
    [0, 1, 2].map(|k| {
        [
            r[k][0],
            r[k][1],
            r[k][2],
            -mv(&dr_da, k) * per_angle,
            -mv(&dr_db, k) * per_angle,
        ]
    })
}

/// `Σ_j r_j·v_j` for a Q31 row and |v_j| < 2^31 nm, rounded to the nm.
#[inline(always)]
fn dot(r: [i32; 3], v: &[i64; 3]) -> i64 {
    let s = ((r[0] as i64 * v[0]) >> 2) + ((r[1] as i64 * v[1]) >> 2) + ((r[2] as i64 * v[2]) >> 2);
    (s + (1 << 28)) >> 29
}

/// `R·v`.
fn rotate(r: &[[i32; 3]; 3], v: &[i64; 3]) -> [i64; 3] {
    r.map(|row| dot(row, v))
}

/// `Rᵀ·v`.
fn rotate_back(r: &[[i32; 3]; 3], v: &[i64; 3]) -> [i64; 3] {
    [0, 1, 2].map(|k| dot([r[0][k], r[1][k], r[2][k]], v))
}

impl HexapodXy {
    /// Precomputes `g` with the table's travel from `joints` q7, q8 (validated by
    /// [`crate::config::MachineConfig::validate`]).
    pub fn new(g: &HexapodXyGeometry, joints: &[JointConfig]) -> Self {
        let travel = |j: usize| joints.get(j).map_or([0, 0], |c| [c.min, c.max]);
        Self {
            hexapod: Hexapod::new(&g.hexapod),
            home: g.platform_home,
            tool_z: g.tool_z,
            table: [travel(6), travel(7)],
            p_max: (1u64 << 30) - 1,
        }
    }

    /// The platform's pose (X Y Z A B C of [`super::hexapod`]) and the table's X Y for
    /// the program pose `pose`, by the split rule.
    pub fn split(&self, pose: &Pose) -> Result<(Pose, [i64; 2]), Unreachable> {
        self.split_rotated(pose).map(|(p, t, _)| (p, t))
    }

    /// [`HexapodXy::split`] and the platform's rotation R = Ry(−B)·Rx(−A), Q31.
    pub(super) fn split_rotated(&self, pose: &Pose) -> Result<Split, Unreachable> {
        let [x, y, z, a, b, _] = *pose;
        if [x, y, z].iter().any(|c| c.unsigned_abs() > self.p_max)
            || [a, b].iter().any(|c| c.unsigned_abs() > 1 << 40)
        {
            return Err(Unreachable::OutOfReach);
        }
        let r = rotation_ab(-a, -b);
        let v = [x - self.home[0], y - self.home[1], z - self.home[2]];
        let rv = rotate(&r, &v);
        let t = [0, 1].map(|k| {
            let [lo, hi] = self.table[k];
            (self.home[k] + rv[k]).clamp(lo, hi)
        });
        let platform = [t[0] - rv[0], t[1] - rv[1], self.tool_z - rv[2], -a, -b, 0];
        Ok((platform, t, r))
    }

    /// Is the table at an end of its travel (X, Y)? There the platform
    /// takes the remainder.
    pub(super) fn clamped(&self, t: &[i64; 2]) -> [bool; 2] {
        [0, 1].map(|k| t[k] == self.table[k][0] || t[k] == self.table[k][1])
    }

    /// Joints of `pose`.
    pub fn inverse(&self, pose: &Pose, joints: &mut Joints) -> Result<(), Unreachable> {
        let (platform, t, r) = self.split_rotated(pose)?;
        let p = [platform[0], platform[1], platform[2]];
        self.hexapod.inverse_rotated(p, &r, joints)?;
        joints[6] = t[0];
        joints[7] = t[1];
        Ok(())
    }

    /// Pose of `joints` from the nearby pose `guess`: the platform by the hexapod's
    /// Newton iteration, then the workpiece point under the tool. Returns the
    /// iterations used.
    pub fn forward(
        &self,
        joints: &Joints,
        guess: &Pose,
        pose: &mut Pose,
    ) -> Result<u8, Unreachable> {
        let (platform_guess, _) = self.split(guess)?;
        let mut platform = [0; AXES];
        let it = self
            .hexapod
            .forward(joints, &platform_guess, &mut platform)?;
        let [px, py, pz, a, b, c] = platform;
        let (r, _) = super::hexapod::rotation_fine(a, b, c);
        let d = [joints[6] - px, joints[7] - py, self.tool_z - pz];
        if d.iter().any(|v| v.unsigned_abs() >= 1 << 31) {
            return Err(Unreachable::OutOfReach);
        }
        let v = rotate_back(&r, &d);
        *pose = [
            self.home[0] + v[0],
            self.home[1] + v[1],
            self.home[2] + v[2],
            -a,
            -b,
            0,
        ];
        Ok(it)
    }

    /// The analytic Jacobian ∂q/∂p (see [`super::Jacobian`]): the hexapod's at the
    /// platform pose times the split's derivatives (column C is 0: the inverse does not
    /// use it).
    pub fn jacobian(&self, pose: &Pose, jac: &mut Jacobian) -> Result<(), Unreachable> {
        let (platform, t) = self.split(pose)?;
        let mut hex = [[0.0f32; AXES]; MAX_JOINTS];
        self.hexapod.jacobian(&platform, &mut hex)?;
        let clamped = self.clamped(&t);
        // R = Ry(b)·Rx(a) with a = −A, b = −B, and its derivatives, in f32.
        let unit = |(s, c): (i32, i32)| (s as f32 / ONE_Q31, c as f32 / ONE_Q31);
        let (sa, ca) = unit(sincos(-pose[3]));
        let (sb, cb) = unit(sincos(-pose[4]));
        let v = [0, 1, 2].map(|k| i64_to_f32(pose[k] - self.home[k]));
        // d(R·v)/d(X Y Z A B), the angle columns per n°.
        let d = turned_derivatives(sa, ca, sb, cb, v, RAD_PER_NDEG);
        // The platform pose's derivatives: p_xy = t − (R·v)_xy (0 while the table
        // follows), p_z = tool_z − (R·v)_z; a = −A, b = −B.
        let mut dp = [[0.0f32; 5]; 6];
        for k in 0..2 {
            if clamped[k] {
                dp[k] = d[k].map(|x| -x);
            }
        }
        dp[2] = d[2].map(|x| -x);
        dp[3][3] = -1.0;
        dp[4][4] = -1.0;
        *jac = [[0.0; AXES]; MAX_JOINTS];
        for (row, h) in jac.iter_mut().zip(&hex).take(6) {
            for (k, out) in row.iter_mut().enumerate().take(5) {
                *out = (0..6).map(|m| h[m] * dp[m][k]).sum();
            }
        }
        for k in 0..2 {
            if !clamped[k] {
                jac[6 + k][..5].copy_from_slice(&d[k]);
            }
        }
        Ok(())
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use crate::config::MachineConfig;
    use crate::kinematics::{reference as re, MachineKinematics};

    pub(crate) const MM: i64 = 1_000_000;
    pub(crate) const DEG: i64 = 1_000_000_000;

    /// The built-in hexapod-xy and its kinematics.
    pub(crate) fn machine() -> (MachineConfig, HexapodXy) {
        let m = MachineConfig::hexapod_xy();
        let MachineKinematics::HexapodXy(k) = MachineKinematics::new(&m) else {
            unreachable!()
        };
        (m, k)
    }

    #[test]
    fn the_table_takes_x_y_and_the_platform_stays_centred_within_the_tables_travel() {
        let (_, k) = machine();
        let (platform, t) = k.split(&[30 * MM, -20 * MM, 275 * MM, 0, 0, 0]).unwrap();
        assert_eq!(t, [30 * MM, -20 * MM]);
        assert_eq!(platform, [0, 0, 260 * MM, 0, 0, 0]);
        // Z is the platform's: the point 10 mm higher on the workpiece needs the
        // platform 10 mm lower.
        let (platform, _) = k.split(&[0, 0, 285 * MM, 0, 0, 0]).unwrap();
        assert_eq!(platform[2], 250 * MM);
    }

    #[test]
    fn beyond_the_tables_travel_the_platform_takes_the_remainder() {
        let (m, k) = machine();
        let pose = [58 * MM, 0, 275 * MM, 0, 0, 0];
        let (platform, t) = k.split(&pose).unwrap();
        assert_eq!(t, [50 * MM, 0]);
        assert_eq!(platform[..3], [-8 * MM, 0, 260 * MM]);
        let mut q = [0; MAX_JOINTS];
        k.inverse(&pose, &mut q).unwrap();
        let kin = MachineKinematics::new(&m);
        assert!(kin.inverse_checked(&pose, &m.joints, &mut q).is_ok());
        // The Jacobian there: X moves the platform (the legs), not the table.
        let mut jac = [[0.0; AXES]; MAX_JOINTS];
        k.jacobian(&pose, &mut jac).unwrap();
        assert_eq!(jac[6][0], 0.0);
        let want = re::inverse(&m, &re::real(&[pose[0] + 1000, 0, 275 * MM, 0, 0, 0])).unwrap();
        let at = re::inverse(&m, &re::real(&pose)).unwrap();
        for leg in 0..6 {
            let d = (want[leg] - at[leg]) as f32 / 1000.0;
            assert!(
                (jac[leg][0] - d).abs() < 1e-4,
                "leg {leg}: {} vs {d}",
                jac[leg][0]
            );
        }
    }

    #[test]
    fn the_platform_turns_the_programmed_tool_axis_to_vertical() {
        // The tool axis in workpiece coordinates Rx(A)·Ry(B)·ẑ, turned by the
        // platform's R = Ry(−B)·Rx(−A), is ẑ: checked in f64 from the platform angles
        // the split gives.
        let (_, k) = machine();
        let (a, b) = (7 * DEG, -4 * DEG);
        let (platform, _) = k.split(&[5 * MM, 3 * MM, 270 * MM, a, b, 0]).unwrap();
        let rad = |v: i64| (v as f64 / 1e9).to_radians();
        let (pa, pb) = (rad(platform[3]), rad(platform[4]));
        let (sa, ca) = rad(a).sin_cos();
        let (sb, cb) = rad(b).sin_cos();
        // Rx(A)·Ry(B)·ẑ
        let d = [sb, -sa * cb, ca * cb];
        // Rx(pa) then Ry(pb).
        let d = [
            d[0],
            pa.cos() * d[1] - pa.sin() * d[2],
            pa.sin() * d[1] + pa.cos() * d[2],
        ];
        let d = [
            pb.cos() * d[0] + pb.sin() * d[2],
            d[1],
            -pb.sin() * d[0] + pb.cos() * d[2],
        ];
        assert!(
            d[0].abs() < 1e-9 && d[1].abs() < 1e-9 && (d[2] - 1.0).abs() < 1e-9,
            "{d:?}"
        );
    }

    #[test]
    fn forward_kinematics_returns_the_programmed_pose() {
        let (_, k) = machine();
        let pose = [12 * MM, -7 * MM, 290 * MM, 6 * DEG, -9 * DEG, 0];
        let mut q = [0; MAX_JOINTS];
        k.inverse(&pose, &mut q).unwrap();
        let mut guess = pose;
        guess[0] += 100_000;
        guess[3] -= 50_000_000;
        let mut out = [0; AXES];
        k.forward(&q, &guess, &mut out).unwrap();
        for i in 0..5 {
            assert!(
                (out[i] - pose[i]).abs() <= if i < 3 { 3 } else { 400 },
                "{out:?}"
            );
        }
    }

    #[test]
    fn the_contour_map_is_the_jacobian_and_the_forward_kinematics_linearised() {
        let (_, k) = machine();
        for pose in [
            [0, 0, 275 * MM, 0, 0, 0],
            [8 * MM, -6 * MM, 282 * MM, 9 * DEG, -7 * DEG, 0],
            [58 * MM, 3 * MM, 265 * MM, -4 * DEG, 6 * DEG, 0],
        ] {
            let map = k.contour_map(&pose).unwrap();
            // ∂q/∂pose against the fixed-point suite's Jacobian (per nm and n°).
            let mut jac = [[0.0; AXES]; MAX_JOINTS];
            k.jacobian(&pose, &mut jac).unwrap();
            for j in 0..8 {
                for a in 0..5 {
                    let want = jac[j][a] * if a < 3 { 1.0 } else { 1e9 / 1e6 };
                    assert!(
                        (map.to_joint[j][a] - want).abs() < 2e-4 * want.abs().max(1.0),
                        "{pose:?} q{} {a}: {} vs {want}",
                        j + 1,
                        map.to_joint[j][a]
                    );
                }
            }
            // ∂pose/∂q against the forward kinematics of joints moved by 2 µm.
            let mut q = [0; MAX_JOINTS];
            k.inverse(&pose, &mut q).unwrap();
            for j in 0..8 {
                let mut moved = q;
                moved[j] += 2_000;
                let mut out = [0; AXES];
                k.forward(&moved, &pose, &mut out).unwrap();
                for a in 0..5 {
                    let scale = if a < 3 { 1e-6 } else { 1e-9 };
                    let d = (out[a] - pose[a]) as f32 * scale / 2e-3;
                    let tol = if a < 3 { 3e-3 } else { 0.2e-3 };
                    assert!(
                        (map.to_pose[a][j] - d).abs() < tol * d.abs().max(1.0),
                        "{pose:?} q{} axis {a}: {} vs {d}",
                        j + 1,
                        map.to_pose[a][j]
                    );
                }
            }
            // And the two are inverses on the pose.
            for a in 0..5 {
                for b in 0..5 {
                    let s: f32 = (0..8).map(|j| map.to_pose[a][j] * map.to_joint[j][b]).sum();
                    let want = if a == b { 1.0 } else { 0.0 };
                    assert!((s - want).abs() < 1e-4, "{pose:?} ({a}, {b}): {s}");
                }
            }
        }
    }
}
