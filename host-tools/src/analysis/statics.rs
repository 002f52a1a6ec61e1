//! Statics: the joint forces that hold a cutting load, along the whole program.
//!
//! A wrench — force F (N) and moment M (N·m) about the tool point (the pose's X Y Z) —
//! acts on the tool. In equilibrium the joints' forces do the opposite work for every
//! small motion (virtual work): with J = ∂q/∂p the kinematics' Jacobian
//! ([`Kinematics::jacobian`], the one the planner and the pre-flight use) taken to SI
//! units, Jᵀ·f = −Q, where Q is the generalised force of the wrench on each pose
//! coordinate: F along X Y Z, and M·u for an angle whose rotation axis is u (the pose's
//! R = Rz(C)·Ry(B)·Rx(A): u_A = R·x̂, u_B = Rz(C)·ŷ, u_C = ẑ). So f = −J⁻ᵀ·Q — the
//! report's f = J⁻ᵀF mapping — solved at every pose the pre-flight samples (at least
//! every [`super::preflight::SAMPLE_NM`]). A joint's force is positive when it pushes
//! (a leg in compression, a carriage pushed along its travel), in N (N·m for a rotary
//! joint).
//!
//! The wrench is constant (`--wrench`), or given per NC line in a side file
//! (`--wrench-file`: from each listed line on, until the next). Each joint's largest
//! force and where it occurs are reported; a joint with a force limit in the machine
//! file (`force_limit`, or `cylinder_area` × `supply_pressure` for a hydraulic leg) that
//! the program exceeds is refused, with the line, before anything runs.
//!
//! Machines: those whose joints all act on the tool through J with as many joints as
//! the pose axes they use (Cartesian machines, the hexapod). The H-4 with its rolling
//! table carries the workpiece on a joint of its own and is refused by name.
//!
//! Source: the Stewart-platform report (seeds-digest B: leg forces f = J⁻¹F through
//! the platform Jacobian); virtual work as in any statics text.

use pkmc::config::{axis_is_rotary, KinematicsConfig, MachineConfig, AXES, MAX_JOINTS};
use pkmc::kinematics::{Jacobian, Kinematics, MachineKinematics};
use pkmc::motion::block::Block;
use pkmc::motion::geometry::{GeometryError, Path};
use pkmc::units::NDEG_PER_DEG;

/// A wrench on the tool: Fx Fy Fz (N), Mx My Mz (N·m) about the tool point, machine
/// frame.
pub type Wrench = [f64; 6];

/// The loads of a program: a wrench from each NC line on.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Loads {
    /// (first NC line, wrench), in line order; before the first entry, no load.
    pub from_line: Vec<(u32, Wrench)>,
}

impl Loads {
    /// The same wrench everywhere.
    pub fn constant(w: Wrench) -> Self {
        Loads {
            from_line: vec![(0, w)],
        }
    }

    /// The wrench in force on NC line `line`.
    pub fn at(&self, line: u32) -> Wrench {
        let k = self.from_line.partition_point(|(l, _)| *l <= line);
        k.checked_sub(1).map_or([0.0; 6], |k| self.from_line[k].1)
    }

    /// Reads a wrench: three forces, or three forces and three moments, separated by
    /// commas or blanks.
    pub fn parse_wrench(text: &str) -> Result<Wrench, String> {
        let parts: Vec<&str> = text
            .split(|c: char| c == ',' || c.is_whitespace())
            .filter(|s| !s.is_empty())
            .collect();
        if parts.len() != 3 && parts.len() != 6 {
            return Err(format!(
                "a wrench is Fx,Fy,Fz (N) or Fx,Fy,Fz,Mx,My,Mz (N, N·m): got {} value(s)",
                parts.len()
            ));
        }
        let mut w = [0.0; 6];
        for (k, p) in parts.iter().enumerate() {
            let v: f64 = p
                .parse()
                .map_err(|_| format!("value {} `{p}` is not a number", k + 1))?;
            if !v.is_finite() || v.abs() > 1e9 {
                return Err(format!("value {} `{p}` is out of range", k + 1));
            }
            w[k] = v;
        }
        Ok(w)
    }

    /// Reads a loads file: one entry per line, `LINE Fx Fy Fz [Mx My Mz]` (the wrench
    /// from NC line LINE on); blank lines and `#` comments skipped; NC lines increasing.
    /// Errors name `origin:line:col`.
    pub fn parse_file(text: &str, origin: &str) -> Result<Loads, String> {
        let mut loads = Loads::default();
        for (n, raw) in text.lines().enumerate() {
            let body = raw.split('#').next().unwrap_or("");
            let Some(first) = body.split_whitespace().next() else {
                continue;
            };
            let col = body.find(first).unwrap_or(0) + 1;
            let at = |c: usize, m: String| format!("{origin}:{}:{c}: {m}", n + 1);
            let line: u32 = first
                .parse()
                .map_err(|_| at(col, format!("`{first}` is not an NC line number")))?;
            if loads.from_line.last().is_some_and(|(l, _)| *l >= line) {
                return Err(at(
                    col,
                    format!("NC line {line} is not after the entry before"),
                ));
            }
            let rest = &body[col - 1 + first.len()..];
            let w = Loads::parse_wrench(rest).map_err(|m| at(col + first.len() + 1, m))?;
            loads.from_line.push((line, w));
        }
        if loads.from_line.is_empty() {
            return Err(format!("{origin}: no loads in the file"));
        }
        Ok(loads)
    }
}

/// The largest force of one joint.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct JointPeak {
    /// Joint, 0-based.
    pub joint: usize,
    /// Force, N (N·m for a rotary joint), signed: positive pushes.
    pub force: f64,
    /// NC line where it is met.
    pub line: u32,
    /// The joint's limit, if the machine file gives one.
    pub limit: Option<f64>,
}

/// The statics of a program.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct Statics {
    /// Poses evaluated.
    pub samples: usize,
    /// Each joint's largest force (by magnitude).
    pub peaks: Vec<JointPeak>,
    /// Poses where the joints cannot hold the load (singular), first line.
    pub singular_at: Option<u32>,
}

impl Statics {
    /// The joints whose largest force exceeds their limit.
    pub fn over_limit(&self) -> impl Iterator<Item = &JointPeak> {
        self.peaks
            .iter()
            .filter(|p| p.limit.is_some_and(|l| p.force.abs() > l))
    }
}

/// Refuses machines statics does not cover.
fn covered(machine: &MachineConfig, axes: &[usize]) -> Result<(), String> {
    match machine.kinematics {
        KinematicsConfig::H4Table(_) => {
            return Err(
                "unsupported: statics for the H-4 with its rolling table (the table \
                    carries the workpiece on a joint of its own)"
                    .into(),
            )
        }
        KinematicsConfig::HexapodXy(_) => return Ok(()),
        _ => {}
    }
    if axes.len() != machine.joints.len() {
        return Err(format!(
            "unsupported: statics for a machine with {} joints on {} pose axes (the \
             joint forces are not determined by the load)",
            machine.joints.len(),
            axes.len()
        ));
    }
    Ok(())
}

/// Rotation axes u_A, u_B, u_C of the pose angles at `pose` (R = Rz(C)·Ry(B)·Rx(A)).
fn rotation_axes(pose: &[i64; AXES]) -> [[f64; 3]; 3] {
    let ang = |i: usize| (pose[i] as f64 / NDEG_PER_DEG as f64).to_radians();
    let (sb, cb) = ang(4).sin_cos();
    let (sc, cc) = ang(5).sin_cos();
    // R·x̂ = Rz(C)·Ry(B)·x̂; Rz(C)·ŷ; ẑ.
    [[cc * cb, sc * cb, -sb], [-sc, cc, 0.0], [0.0, 0.0, 1.0]]
}

/// Joint forces holding wrench `w` at `pose`: f = −J⁻ᵀ·Q over the axes the machine
/// uses (`axes`); `None` where the kinematics fail or J is singular.
///
/// The hexapod under an X-Y table's tool: the tool carries `w` and the workpiece its
/// reaction. The legs hold the platform against −F at the tool tip T and −M, i.e. the
/// wrench (−F, −M − (T − p) × F) about the platform origin p, through the hexapod's
/// own Jacobian at the platform pose of the split; the table's X and Y joints push
/// back −F_x and −F_y.
pub fn joint_forces(
    pose: &[i64; AXES],
    w: &Wrench,
    machine: &MachineConfig,
    kin: &MachineKinematics,
    axes: &[usize],
) -> Option<[f64; MAX_JOINTS]> {
    if let MachineKinematics::HexapodXy(k) = kin {
        let KinematicsConfig::HexapodXy(g) = &machine.kinematics else {
            return None;
        };
        let (platform, t) = k.split(pose).ok()?;
        let tip = [t[0], t[1], g.tool_z];
        let arm: [f64; 3] = std::array::from_fn(|c| (tip[c] - platform[c]) as f64 * 1e-9);
        let on_platform = [
            -w[0],
            -w[1],
            -w[2],
            -w[3] - (arm[1] * w[2] - arm[2] * w[1]),
            -w[4] - (arm[2] * w[0] - arm[0] * w[2]),
            -w[5] - (arm[0] * w[1] - arm[1] * w[0]),
        ];
        let legs = MachineKinematics::Hexapod(pkmc::kinematics::hexapod::Hexapod::new(&g.hexapod));
        let mut f = forces_through(
            &platform,
            &on_platform,
            &machine.joints[..6],
            &legs,
            &[0, 1, 2, 3, 4, 5],
        )?;
        f[6] = -w[0];
        f[7] = -w[1];
        return Some(f);
    }
    forces_through(pose, w, &machine.joints, kin, axes)
}

/// f = −J⁻ᵀ·Q for the joints `joints` of `kin` at `pose` over `axes`.
fn forces_through(
    pose: &[i64; AXES],
    w: &Wrench,
    joints: &[pkmc::config::JointConfig],
    kin: &MachineKinematics,
    axes: &[usize],
) -> Option<[f64; MAX_JOINTS]> {
    let mut dq: Jacobian = [[0.0; AXES]; MAX_JOINTS];
    kin.jacobian(pose, &mut dq).ok()?;
    let n = axes.len();
    let u = rotation_axes(pose);
    // Per SI unit of each quantity: m per nm, rad per n°.
    let si = |rotary: bool| {
        if rotary {
            1e-9_f64.to_radians()
        } else {
            1e-9
        }
    };
    // A = Jᵀ in SI (rows: axes, columns: joints); b = −Q.
    let mut a = vec![vec![0.0f64; n + 1]; n];
    for (r, &k) in axes.iter().enumerate() {
        for j in 0..n {
            let sq = si(joints[j].rotary);
            a[r][j] = dq[j][k] as f64 * sq / si(axis_is_rotary(k));
        }
        let q = if k < 3 {
            w[k]
        } else {
            (0..3).map(|c| w[3 + c] * u[k - 3][c]).sum()
        };
        a[r][n] = -q;
    }
    let f = solve(a)?;
    let mut out = [0.0; MAX_JOINTS];
    out[..n].copy_from_slice(&f);
    Some(out)
}

/// Solves the augmented n × (n + 1) system by Gaussian elimination with partial
/// pivoting; `None` when singular.
fn solve(mut a: Vec<Vec<f64>>) -> Option<Vec<f64>> {
    let n = a.len();
    let scale = a
        .iter()
        .flat_map(|r| r[..n].iter())
        .fold(0.0f64, |m, v| m.max(v.abs()));
    for c in 0..n {
        let p = (c..n).max_by(|&x, &y| a[x][c].abs().total_cmp(&a[y][c].abs()))?;
        if a[p][c].abs() <= 1e-9 * scale {
            return None;
        }
        a.swap(c, p);
        let pivot = a[c].clone();
        for (r, row) in a.iter_mut().enumerate() {
            if r != c {
                let k = row[c] / pivot[c];
                for (x, p) in row[c..].iter_mut().zip(&pivot[c..]) {
                    *x -= k * p;
                }
            }
        }
    }
    Some((0..n).map(|r| a[r][n] / a[r][r]).collect())
}

/// The statics of `blocks` from `start` under `loads`, with the joints' `limits`.
pub fn check(
    blocks: &[Block],
    machine: &MachineConfig,
    start: [i64; AXES],
    loads: &Loads,
    limits: &[Option<f64>],
) -> Result<Statics, String> {
    let paths = super::preflight::paths(blocks, start);
    check_paths(blocks, &paths, machine, start, loads, limits)
}

/// [`check`] of `blocks` whose paths are derived already
/// ([`super::preflight::paths`]).
pub fn check_paths(
    blocks: &[Block],
    paths: &[Result<Path, GeometryError>],
    machine: &MachineConfig,
    start: [i64; AXES],
    loads: &Loads,
    limits: &[Option<f64>],
) -> Result<Statics, String> {
    let axes: Vec<usize> = (0..AXES)
        .filter(|&i| machine.axes[i].max_velocity > 0)
        .collect();
    covered(machine, &axes)?;
    let kin = MachineKinematics::new(machine);
    let n = machine.joints.len();
    let mut out = Statics {
        peaks: (0..n)
            .map(|j| JointPeak {
                joint: j,
                force: 0.0,
                line: 0,
                limit: limits.get(j).copied().flatten(),
            })
            .collect(),
        ..Statics::default()
    };
    let mut from = start;
    for (b, path) in blocks.iter().zip(paths) {
        let Ok(path) = path else {
            continue; // the pre-flight reports it
        };
        let w = loads.at(b.line);
        let len = path.length.max(0);
        let steps = (len / super::preflight::SAMPLE_NM + 1).clamp(1, 100_000);
        for k in 0..=steps {
            let s = ((len as i128) << 16) * k as i128 / steps as i128;
            let mut pose = [0i64; AXES];
            path.pose_at(&from, s as i64, &mut pose);
            out.samples += 1;
            match joint_forces(&pose, &w, machine, &kin, &axes) {
                Some(f) => {
                    for (peak, &fj) in out.peaks.iter_mut().zip(&f[..n]) {
                        if fj.abs() > peak.force.abs() {
                            (peak.force, peak.line) = (fj, b.line);
                        }
                    }
                }
                None => {
                    out.singular_at.get_or_insert(b.line);
                }
            }
        }
        from = path.end;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use pkmc::motion::block::Motion;

    #[test]
    fn a_wrench_file_reads_entries_and_names_its_mistakes() {
        let l = Loads::parse_file("# loads\n10 0 0 -500\n20 100,0,-500 0 0 5\n", "w.txt").unwrap();
        assert_eq!(l.at(5), [0.0; 6]);
        assert_eq!(l.at(10), [0.0, 0.0, -500.0, 0.0, 0.0, 0.0]);
        assert_eq!(l.at(19)[2], -500.0);
        assert_eq!(l.at(400), [100.0, 0.0, -500.0, 0.0, 0.0, 5.0]);
        let e = Loads::parse_file("10 1 2 3\n5 1 2 3\n", "w.txt").unwrap_err();
        assert_eq!(e, "w.txt:2:1: NC line 5 is not after the entry before");
        let e = Loads::parse_file("10 1 2\n", "w.txt").unwrap_err();
        assert!(e.starts_with("w.txt:1:4: a wrench is"), "{e}");
        let e = Loads::parse_file("  x 1 2 3\n", "w.txt").unwrap_err();
        assert!(e.starts_with("w.txt:1:3: `x` is not an NC line"), "{e}");
    }

    #[test]
    fn on_a_cartesian_machine_each_axis_pushes_against_its_own_force() {
        let m = MachineConfig::cartesian_xyz();
        let kin = MachineKinematics::new(&m);
        let f = joint_forces(
            &[0; AXES],
            &[10.0, -20.0, 30.0, 0.0, 0.0, 0.0],
            &m,
            &kin,
            &[0, 1, 2],
        )
        .unwrap();
        assert!(
            (f[0] + 10.0).abs() < 1e-3 && (f[1] - 20.0).abs() < 1e-3 && (f[2] + 30.0).abs() < 1e-3
        );
    }

    /// The hexapod's leg forces from the legs' geometry alone (an independent f64
    /// computation): Σ f_i n_i + F = 0 and Σ f_i (R b_i × n_i) + M = 0, with n_i the
    /// unit vector from base joint a_i to platform joint p + R b_i.
    #[allow(clippy::needless_range_loop)]
    fn hexapod_by_geometry(
        g: &pkmc::config::HexapodGeometry,
        pose: [f64; 6],
        w: Wrench,
    ) -> [f64; 6] {
        let (a, b, c) = (
            pose[3].to_radians(),
            pose[4].to_radians(),
            pose[5].to_radians(),
        );
        let rx = [
            [1.0, 0.0, 0.0],
            [0.0, a.cos(), -a.sin()],
            [0.0, a.sin(), a.cos()],
        ];
        let ry = [
            [b.cos(), 0.0, b.sin()],
            [0.0, 1.0, 0.0],
            [-b.sin(), 0.0, b.cos()],
        ];
        let rz = [
            [c.cos(), -c.sin(), 0.0],
            [c.sin(), c.cos(), 0.0],
            [0.0, 0.0, 1.0],
        ];
        let mul = |x: [[f64; 3]; 3], y: [[f64; 3]; 3]| {
            let mut o = [[0.0; 3]; 3];
            for i in 0..3 {
                for j in 0..3 {
                    o[i][j] = (0..3).map(|k| x[i][k] * y[k][j]).sum();
                }
            }
            o
        };
        let r = mul(mul(rz, ry), rx);
        let mut sys = vec![vec![0.0; 7]; 6];
        for i in 0..6 {
            let bi: [f64; 3] = std::array::from_fn(|k| g.platform[i][k] as f64 * 1e-9);
            let rb: [f64; 3] = std::array::from_fn(|k| (0..3).map(|l| r[k][l] * bi[l]).sum());
            let ai: [f64; 3] = std::array::from_fn(|k| g.base[i][k] as f64 * 1e-9);
            let d: [f64; 3] = std::array::from_fn(|k| pose[k] * 1e-3 + rb[k] - ai[k]);
            let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            let nv = d.map(|v| v / len);
            let mo = [
                rb[1] * nv[2] - rb[2] * nv[1],
                rb[2] * nv[0] - rb[0] * nv[2],
                rb[0] * nv[1] - rb[1] * nv[0],
            ];
            for k in 0..3 {
                sys[k][i] = nv[k];
                sys[3 + k][i] = mo[k];
            }
        }
        for k in 0..6 {
            sys[k][6] = -w[k];
        }
        let f = solve(sys).unwrap();
        std::array::from_fn(|i| f[i])
    }

    #[test]
    fn hexapod_leg_forces_agree_with_the_legs_geometry() {
        let m = MachineConfig::hexapod();
        let kin = MachineKinematics::new(&m);
        let axes = [0, 1, 2, 3, 4, 5];
        let poses: [[f64; 6]; 3] = [
            [0.0, 0.0, 450.0, 0.0, 0.0, 0.0],
            [30.0, -20.0, 430.0, 5.0, -4.0, 10.0],
            [-40.0, 25.0, 480.0, -8.0, 6.0, -15.0],
        ];
        let wrenches = [
            [0.0, 0.0, -1000.0, 0.0, 0.0, 0.0],
            [200.0, -150.0, -800.0, 5.0, -3.0, 12.0],
        ];
        for p in poses {
            let pose: [i64; AXES] = std::array::from_fn(|i| {
                if i < 3 {
                    (p[i] * 1e6).round() as i64
                } else {
                    (p[i] * 1e9).round() as i64
                }
            });
            for w in wrenches {
                let ours = joint_forces(&pose, &w, &m, &kin, &axes).unwrap();
                let KinematicsConfig::Hexapod(g) = &m.kinematics else {
                    unreachable!()
                };
                let reference = hexapod_by_geometry(g, p, w);
                for i in 0..6 {
                    let tol = 1e-4 * reference.iter().fold(1.0f64, |a, v| a.max(v.abs()));
                    assert!(
                        (ours[i] - reference[i]).abs() <= tol,
                        "pose {p:?} wrench {w:?} leg {}: ours {} N, geometry {} N",
                        i + 1,
                        ours[i],
                        reference[i]
                    );
                }
            }
        }
    }

    /// Report B's helix (x = t cos t, y = t sin t, z = 3t + 260 mm, t = 0..10 s) on the
    /// hexapod-xy, level and with the tool axis tilting ±10°, under a cutting force of
    /// (120, −80, −400) N and 2 N·m about the tool: every joint's force against an
    /// independent f64 computation — the platform pose from the geometry (the table
    /// over the turned point, the platform making up Z), the reaction on the
    /// workpiece moved to the platform origin, and the legs' equilibrium from their
    /// directions ([`hexapod_by_geometry`]).
    #[test]
    fn hexapod_xy_joint_forces_along_the_reports_helix_agree_with_an_independent_computation() {
        let m = MachineConfig::hexapod_xy();
        let kin = MachineKinematics::new(&m);
        let KinematicsConfig::HexapodXy(g) = &m.kinematics else {
            unreachable!()
        };
        let w: Wrench = [120.0, -80.0, -400.0, 0.0, 0.0, 2.0];
        let h = g.platform_home.map(|c| c as f64 * 1e-6);
        let tool_z = g.tool_z as f64 * 1e-6;
        let mut largest = [0.0f64; 8];
        for tilt in [0.0, 10.0] {
            for k in 0..=200 {
                let t = k as f64 * 0.05;
                let (a, b) = (
                    tilt * (std::f64::consts::PI * t / 5.0).sin(),
                    tilt * (std::f64::consts::PI * t / 10.0).sin(),
                );
                let wp = [t * t.cos(), t * t.sin(), 3.0 * t + 260.0];
                // R = Ry(−B)·Rx(−A) applied to w − home.
                let (sa, ca) = (-a).to_radians().sin_cos();
                let (sb, cb) = (-b).to_radians().sin_cos();
                let v = [wp[0] - h[0], wp[1] - h[1], wp[2] - h[2]];
                let v = [v[0], ca * v[1] - sa * v[2], sa * v[1] + ca * v[2]];
                let rv = [cb * v[0] + sb * v[2], v[1], -sb * v[0] + cb * v[2]];
                let tip = [h[0] + rv[0], h[1] + rv[1], tool_z];
                let p = [tip[0] - rv[0], tip[1] - rv[1], tip[2] - rv[2]];
                let arm = [
                    (tip[0] - p[0]) * 1e-3,
                    (tip[1] - p[1]) * 1e-3,
                    (tip[2] - p[2]) * 1e-3,
                ];
                let cross = [
                    arm[1] * w[2] - arm[2] * w[1],
                    arm[2] * w[0] - arm[0] * w[2],
                    arm[0] * w[1] - arm[1] * w[0],
                ];
                let on_platform = [
                    -w[0],
                    -w[1],
                    -w[2],
                    -w[3] - cross[0],
                    -w[4] - cross[1],
                    -w[5] - cross[2],
                ];
                let legs =
                    hexapod_by_geometry(&g.hexapod, [p[0], p[1], p[2], -a, -b, 0.0], on_platform);
                let pose: [i64; AXES] = [
                    (wp[0] * 1e6).round() as i64,
                    (wp[1] * 1e6).round() as i64,
                    (wp[2] * 1e6).round() as i64,
                    (a * 1e9).round() as i64,
                    (b * 1e9).round() as i64,
                    0,
                ];
                let ours = joint_forces(&pose, &w, &m, &kin, &[0, 1, 2, 3, 4]).unwrap();
                let tol = 1e-4 * legs.iter().fold(1.0f64, |s, v| s.max(v.abs()));
                for i in 0..6 {
                    assert!(
                        (ours[i] - legs[i]).abs() <= tol,
                        "t {t} tilt {tilt} leg {}: ours {} N, geometry {} N",
                        i + 1,
                        ours[i],
                        legs[i]
                    );
                    largest[i] = largest[i].max(ours[i].abs());
                }
                assert_eq!((ours[6], ours[7]), (-w[0], -w[1]));
            }
        }
        eprintln!("largest joint forces along the helix, N: {largest:.1?}");
    }

    #[test]
    fn the_largest_force_of_each_leg_is_found_with_its_line_and_checked_against_its_limit() {
        let m = MachineConfig::hexapod();
        let mm = 1_000_000i64;
        let start = m.home;
        let mut to = start;
        to[0] += 40 * mm;
        let blocks = [Block {
            line: 7,
            motion: Motion::Linear,
            target: to,
            feed: 10 * mm,
            tolerance_nm: 0,
        }];
        let limits = vec![Some(200.0); 6];
        let s = check(
            &blocks,
            &m,
            start,
            &Loads::constant([0.0, 0.0, -1000.0, 0.0, 0.0, 0.0]),
            &limits,
        )
        .unwrap();
        assert_eq!(s.peaks.len(), 6);
        assert!(s.samples >= 41);
        // 1000 N down shared by six legs: each more than 1000/6 N, all at line 7.
        assert!(
            s.peaks
                .iter()
                .all(|p| p.force > 1000.0 / 6.0 && p.line == 7),
            "{s:?}"
        );
        let over: Vec<usize> = s.over_limit().map(|p| p.joint).collect();
        assert_eq!(over, [0, 1, 3, 4], "{s:?}");
        let h4 = MachineConfig::h4_table();
        let e = check(&[], &h4, h4.home, &Loads::default(), &[]).unwrap_err();
        assert!(e.starts_with("unsupported: statics for the H-4"), "{e}");
    }
}
