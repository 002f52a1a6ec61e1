//! `f64` reference kinematics for the tests (never on the controller): the same
//! conventions written as directly as possible, in nm and radians, so the fixed-point
//! code is checked against an independent formulation.
#![allow(clippy::needless_range_loop)]

use super::Pose;
use crate::config::{
    H4TableGeometry, HexapodGeometry, HexapodXyGeometry, KinematicsConfig, MachineConfig,
    MAX_JOINTS,
};

const NDEG: f64 = 1e9;

fn rad(ndeg: i64) -> f64 {
    (ndeg as f64 / NDEG).to_radians()
}

/// Rx(a)·v.
fn rot_x(a: f64, v: [f64; 3]) -> [f64; 3] {
    let (s, c) = a.sin_cos();
    [v[0], c * v[1] - s * v[2], s * v[1] + c * v[2]]
}

/// H-4 inverse in real numbers: q1..q4 (nm), q5 (n°); `None` when out of reach or
/// flatter than the minimum elevation.
pub fn h4_inverse(g: &H4TableGeometry, pose: &[f64; 6]) -> Option<[f64; 5]> {
    let r = g.table_pivot.map(|c| c as f64);
    let a = (pose[3] / NDEG).to_radians();
    let th = (pose[5] / NDEG).to_radians();
    let d = rot_x(a, [pose[0] - r[0], pose[1] - r[1], pose[2] - r[2]]);
    let t = [r[0] + d[0], r[1] + d[1], r[2] + d[2]];
    let e = [t[0], t[1], t[2] + g.tool_length as f64];
    let l = g.forearm as f64;
    let min_h = l * (g.min_elevation as f64 / NDEG).to_radians().sin();
    let mut q = [0.0; 5];
    for i in 0..4 {
        let s = g.sides[i] as f64 * g.bar_half as f64;
        let p = [
            e[0] + s * th.cos() + g.attach[i][0] as f64,
            e[1] + s * th.sin() + g.attach[i][1] as f64,
            e[2] + g.attach[i][2] as f64,
        ];
        let dx = p[0] - g.rails[i][0] as f64;
        let dy = p[1] - g.rails[i][1] as f64;
        let h2 = l * l - dx * dx - dy * dy;
        if h2 < min_h * min_h {
            return None;
        }
        q[i] = p[2] + h2.sqrt();
    }
    q[4] = pose[3];
    Some(q)
}

/// Hexapod leg lengths in real numbers, nm.
pub fn hexapod_inverse(g: &HexapodGeometry, pose: &[f64; 6]) -> [f64; 6] {
    let (a, b, c) = (
        (pose[3] / NDEG).to_radians(),
        (pose[4] / NDEG).to_radians(),
        (pose[5] / NDEG).to_radians(),
    );
    let mut q = [0.0; 6];
    for i in 0..6 {
        let v = g.platform[i].map(|c| c as f64);
        let v = rot_x(a, v);
        let (sb, cb) = b.sin_cos();
        let v = [cb * v[0] + sb * v[2], v[1], -sb * v[0] + cb * v[2]];
        let (sc, cc) = c.sin_cos();
        let v = [cc * v[0] - sc * v[1], sc * v[0] + cc * v[1], v[2]];
        let w = [
            pose[0] + v[0] - g.base[i][0] as f64,
            pose[1] + v[1] - g.base[i][1] as f64,
            pose[2] + v[2] - g.base[i][2] as f64,
        ];
        q[i] = (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
    }
    q
}

/// Hexapod under an X-Y table's tool in real numbers: legs and table X Y, nm, with
/// the table's travel `table` ([min, max] of X and Y). Written from the geometry: the
/// platform turns the workpiece by Ry(−B)·Rx(−A) about its origin; the table goes
/// over the turned point (within its travel) and the platform moves the rest, so the
/// point meets the tool tip.
pub fn hexapod_xy_inverse(
    g: &HexapodXyGeometry,
    table: [[f64; 2]; 2],
    pose: &[f64; 6],
) -> [f64; 8] {
    let h = g.platform_home.map(|c| c as f64);
    let (a, b) = (
        -(pose[3] / NDEG).to_radians(),
        -(pose[4] / NDEG).to_radians(),
    );
    let v = rot_x(a, [pose[0] - h[0], pose[1] - h[1], pose[2] - h[2]]);
    let (sb, cb) = b.sin_cos();
    let v = [cb * v[0] + sb * v[2], v[1], -sb * v[0] + cb * v[2]];
    let t = [
        (h[0] + v[0]).clamp(table[0][0], table[0][1]),
        (h[1] + v[1]).clamp(table[1][0], table[1][1]),
    ];
    let platform = [
        t[0] - v[0],
        t[1] - v[1],
        g.tool_z as f64 - v[2],
        -pose[3],
        -pose[4],
        0.0,
    ];
    let legs = hexapod_inverse(&g.hexapod, &platform);
    let mut q = [0.0; 8];
    q[..6].copy_from_slice(&legs);
    q[6..].copy_from_slice(&t);
    q
}

/// Solves `f(x) = target` for the unknown axes `free` of `x` by Gauss–Newton with a
/// central-difference Jacobian, all in `f64` (to ~1e-6 nm): every value of `target`
/// is matched (least squares when there are more joints than unknowns, as the
/// hexapod-xy's eight joints for five axes; exact when the joints fit a pose).
pub fn newton(f: impl Fn(&[f64; 6]) -> Vec<f64>, target: &[f64], x: &mut [f64; 6], free: &[usize]) {
    let (n, m) = (free.len(), target.len());
    for _ in 0..50 {
        let y = f(x);
        let r: Vec<f64> = (0..m).map(|i| target[i] - y[i]).collect();
        if r.iter().all(|v| v.abs() < 1e-6) {
            return;
        }
        let mut jac = vec![vec![0.0; n]; m];
        for (k, &ax) in free.iter().enumerate() {
            let h = if ax >= 3 { 1e3 } else { 1.0 };
            let (mut xp, mut xm) = (*x, *x);
            xp[ax] += h;
            xm[ax] -= h;
            let (yp, ym) = (f(&xp), f(&xm));
            for i in 0..m {
                jac[i][k] = (yp[i] - ym[i]) / (2.0 * h);
            }
        }
        // Normal equations JᵀJ·dx = Jᵀr, by Gaussian elimination with partial pivoting.
        let mut a = vec![vec![0.0; n + 1]; n];
        for k in 0..n {
            for l in 0..n {
                a[k][l] = (0..m).map(|i| jac[i][k] * jac[i][l]).sum();
            }
            a[k][n] = (0..m).map(|i| jac[i][k] * r[i]).sum();
        }
        for k in 0..n {
            let p = (k..n)
                .max_by(|&u, &v| a[u][k].abs().total_cmp(&a[v][k].abs()))
                .unwrap();
            a.swap(k, p);
            for i in k + 1..n {
                let q = a[i][k] / a[k][k];
                for j in k..=n {
                    a[i][j] -= q * a[k][j];
                }
            }
        }
        let mut dx = vec![0.0; n];
        for k in (0..n).rev() {
            let s: f64 = (k + 1..n).map(|j| a[k][j] * dx[j]).sum();
            dx[k] = (a[k][n] - s) / a[k][k];
        }
        for (k, &ax) in free.iter().enumerate() {
            x[ax] += dx[k];
        }
        // Converged: steps below 1e-6 nm, and 1e-3 n° (a femtoradian) on the angles,
        // where the normal equations' rounding leaves ~1e-5 n° of noise.
        if free
            .iter()
            .zip(&dx)
            .all(|(&ax, v)| v.abs() < if ax >= 3 { 1e-3 } else { 1e-6 })
        {
            return;
        }
    }
    panic!("reference Newton did not converge");
}

/// The joints of `pose` in real numbers for the machine `m`, in joint units; `None`
/// when out of reach (H-4: flatter than the minimum elevation). Cartesian: each joint
/// is its axis.
pub fn inverse(m: &MachineConfig, pose: &[f64; 6]) -> Option<[f64; MAX_JOINTS]> {
    let mut q = [0.0; MAX_JOINTS];
    match &m.kinematics {
        KinematicsConfig::Cartesian { axis_of_joint } => {
            for j in 0..m.joints.len() {
                q[j] = pose[axis_of_joint[j] as usize];
            }
        }
        KinematicsConfig::H4Table(g) => q[..5].copy_from_slice(&h4_inverse(g, pose)?),
        KinematicsConfig::Hexapod(g) => q[..6].copy_from_slice(&hexapod_inverse(g, pose)),
        KinematicsConfig::HexapodXy(g) => {
            let travel = |j: usize| [m.joints[j].min as f64, m.joints[j].max as f64];
            q[..8].copy_from_slice(&hexapod_xy_inverse(g, [travel(6), travel(7)], pose));
        }
    }
    Some(q)
}

/// Next uniform number in [0, 1) of a 64-bit linear congruential generator (Knuth's
/// MMIX constants): reproducible random poses for the tests.
pub fn lcg(state: &mut u64) -> f64 {
    *state = state
        .wrapping_mul(6_364_136_223_846_793_005)
        .wrapping_add(1_442_695_040_888_963_407);
    (*state >> 11) as f64 / (1u64 << 53) as f64
}

/// Integer pose as `f64`.
pub fn real(p: &Pose) -> [f64; 6] {
    p.map(|v| v as f64)
}

/// Pose with the H-4 head point E (mm), θ and A (degrees): the workpiece pose whose
/// tool tip lies at E − tool, rounded to nm / n°.
pub fn h4_pose_from_head(g: &H4TableGeometry, e_mm: [f64; 3], theta_deg: f64, a_deg: f64) -> Pose {
    let r = g.table_pivot.map(|c| c as f64);
    let t = [
        e_mm[0] * 1e6,
        e_mm[1] * 1e6,
        e_mm[2] * 1e6 - g.tool_length as f64,
    ];
    let a = rad((a_deg * NDEG).round() as i64);
    let d = rot_x(-a, [t[0] - r[0], t[1] - r[1], t[2] - r[2]]);
    [
        (r[0] + d[0]).round() as i64,
        (r[1] + d[1]).round() as i64,
        (r[2] + d[2]).round() as i64,
        (a_deg * NDEG).round() as i64,
        0,
        (theta_deg * NDEG).round() as i64,
    ]
}

/// Forward-kinematics statistics over many cases.
#[derive(Default)]
pub struct FkStats {
    /// Cases by iterations used.
    pub hist: [u32; 9],
    /// Largest X Y Z error against the `f64` solution for the same joints, nm.
    pub lin: f64,
    /// Largest angle error against the `f64` solution, n°.
    pub ang: f64,
    /// Largest X Y Z difference from the pose the joints came from, nm.
    pub round_trip: i64,
    /// Largest X Y Z difference from the answer started at that pose (Newton's fixed
    /// point of the same equations), nm.
    pub conv_lin: i64,
    /// Largest angle difference from that answer, n°.
    pub conv_ang: i64,
}

impl FkStats {
    /// Adds a case: `out` from the previous period's guess, `at` from the true pose `p`,
    /// `want` the `f64` solution; `angles` the pose axes the machine turns.
    pub fn add(
        &mut self,
        it: u8,
        out: &Pose,
        at: &Pose,
        p: &Pose,
        want: &[f64; 6],
        angles: &[usize],
    ) {
        self.hist[it as usize] += 1;
        for i in 0..3 {
            self.lin = self.lin.max((out[i] as f64 - want[i]).abs());
            self.round_trip = self.round_trip.max((out[i] - p[i]).abs());
            self.conv_lin = self.conv_lin.max((out[i] - at[i]).abs());
        }
        for &i in angles {
            self.ang = self.ang.max((out[i] as f64 - want[i]).abs());
            self.conv_ang = self.conv_ang.max((out[i] - at[i]).abs());
        }
    }

    /// Largest iteration count seen.
    pub fn max_iterations(&self) -> usize {
        self.hist.iter().rposition(|&n| n > 0).unwrap_or(0)
    }
}
