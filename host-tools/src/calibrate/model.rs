//! The parameterised kinematics of each machine kind in `f64` (mm, degrees outside,
//! radians inside), written once over [`Scalar`] so that the same equations give the
//! analytic derivatives ([`super::dual`]).
//!
//! Every machine splits its joints in two: the *loop* joints close the parallel
//! mechanism (the H-4's four carriages, the hexapods' six legs) and fix an internal
//! pose `x` (the H-4's head point E and bar angle, the platform's pose); the other
//! joints (the rolling table's A, the hexapod-xy's table X Y) enter the measured tool
//! pose directly. Each joint reads `q = physical − offset`: the offsets are the joints'
//! zero errors (the KMITL parameter file's "length error (offset)").
#![allow(clippy::needless_range_loop)]

use super::dual::Scalar;
use pkmc::config::{KinematicsConfig, MachineConfig};

/// One parameter of a model.
#[derive(Clone, Debug)]
pub struct Param {
    /// Its name, as the report prints it (e.g. `rails[2].y`).
    pub name: String,
    /// Nominal value (the machine file's), mm or degrees.
    pub value: f64,
    /// Typical size of its error, mm or degrees: the column scale of the Jacobian.
    pub scale: f64,
    /// Prefer to hold this one when the data cannot tell it from others (a point's
    /// coordinate over a joint's zero, a convention over a dimension).
    pub hold_first: bool,
    /// Hold this one only where nothing else can be: the data's own unknowns (a
    /// probed sphere's centre), so that the machine file keeps the conventions.
    pub hold_last: bool,
}

/// The machine kind and the constants that are not parameters.
#[derive(Clone, Debug)]
pub enum Kind {
    /// H-4 with rolling table: the bar ends' sides and the lowest forearm elevation.
    H4 {
        /// −1 or +1 per arm pair.
        sides: [f64; 4],
        /// Degrees.
        min_elevation: f64,
    },
    /// Hexapod.
    Hexapod,
    /// Hexapod under an X-Y table's tool: the table's travel.
    HexapodXy {
        /// [min, max] of table X and Y, mm.
        travel: [[f64; 2]; 2],
    },
}

/// A calibration model: kind, parameters, joint limits.
#[derive(Clone, Debug)]
pub struct Model {
    /// The kind.
    pub kind: Kind,
    /// The parameters with their nominal values.
    pub params: Vec<Param>,
    /// Each joint's [min, max], mm or degrees.
    pub limits: Vec<[f64; 2]>,
    /// The machine's home pose, mm and degrees.
    pub home: [f64; 6],
}

const MM: f64 = 1e-6;
const DEG: f64 = 1e-9;

fn push(p: &mut Vec<Param>, name: String, value: f64, hold_first: bool) {
    p.push(Param {
        name,
        value,
        scale: 0.5,
        hold_first,
        hold_last: false,
    });
}

fn push_points(p: &mut Vec<Param>, what: &str, pts: &[[i64; 3]], hold: bool) {
    for (i, pt) in pts.iter().enumerate() {
        for (k, c) in pt.iter().enumerate() {
            push(
                p,
                format!("{what}[{i}].{}", ["x", "y", "z"][k]),
                *c as f64 * MM,
                hold,
            );
        }
    }
}

fn push_offsets(p: &mut Vec<Param>, m: &MachineConfig, joints: std::ops::Range<usize>) {
    for j in joints {
        let rotary = m.joints[j].rotary;
        p.push(Param {
            name: format!("offset[q{}]", j + 1),
            value: 0.0,
            scale: if rotary { 0.3 } else { 0.5 },
            hold_first: false,
            hold_last: false,
        });
    }
}

impl Model {
    /// The model of a parallel machine; `None` for a Cartesian one.
    pub fn from_config(m: &MachineConfig) -> Option<Model> {
        let mut p = Vec::new();
        let kind = match &m.kinematics {
            KinematicsConfig::Cartesian { .. } => return None,
            KinematicsConfig::H4Table(g) => {
                for (k, c) in g.table_pivot.iter().enumerate() {
                    let name = format!("table_pivot.{}", ["x", "y", "z"][k]);
                    push(&mut p, name, *c as f64 * MM, true);
                }
                push(
                    &mut p,
                    "tool_length".into(),
                    g.tool_length as f64 * MM,
                    true,
                );
                push_points(&mut p, "attach", &g.attach, true);
                for (i, r) in g.rails.iter().enumerate() {
                    push(&mut p, format!("rails[{i}].x"), r[0] as f64 * MM, false);
                    push(&mut p, format!("rails[{i}].y"), r[1] as f64 * MM, false);
                }
                push(&mut p, "forearm".into(), g.forearm as f64 * MM, false);
                push(&mut p, "bar_half".into(), g.bar_half as f64 * MM, false);
                push_offsets(&mut p, m, 0..5);
                Kind::H4 {
                    sides: g.sides.map(f64::from),
                    min_elevation: g.min_elevation as f64 * DEG,
                }
            }
            KinematicsConfig::Hexapod(g) => {
                push_points(&mut p, "base", &g.base, false);
                push_points(&mut p, "platform", &g.platform, false);
                push_offsets(&mut p, m, 0..6);
                Kind::Hexapod
            }
            KinematicsConfig::HexapodXy(g) => {
                for (k, c) in g.platform_home.iter().enumerate() {
                    let name = format!("platform_home.{}", ["x", "y", "z"][k]);
                    push(&mut p, name, *c as f64 * MM, true);
                }
                push(&mut p, "tool_z".into(), g.tool_z as f64 * MM, true);
                push_offsets(&mut p, m, 6..8);
                p[4].hold_first = true;
                p[5].hold_first = true;
                push_points(&mut p, "base", &g.hexapod.base, false);
                push_points(&mut p, "platform", &g.hexapod.platform, false);
                push_offsets(&mut p, m, 0..6);
                let t = |j: usize| [m.joints[j].min as f64 * MM, m.joints[j].max as f64 * MM];
                Kind::HexapodXy {
                    travel: [t(6), t(7)],
                }
            }
        };
        let limits = m
            .joints
            .iter()
            .map(|j| {
                let u = if j.rotary { DEG } else { MM };
                [j.min as f64 * u, j.max as f64 * u]
            })
            .collect();
        let mut home = [0.0; 6];
        for k in 0..6 {
            home[k] = m.home[k] as f64 * if k < 3 { MM } else { DEG };
        }
        Some(Model {
            kind,
            params: p,
            limits,
            home,
        })
    }

    /// The nominal parameter values.
    pub fn nominal(&self) -> Vec<f64> {
        self.params.iter().map(|p| p.value).collect()
    }

    /// The size of the internal pose (the loop joints' count).
    pub fn loop_dim(&self) -> usize {
        match self.kind {
            Kind::H4 { .. } => 4,
            _ => 6,
        }
    }

    /// The joints' count.
    pub fn joints(&self) -> usize {
        self.limits.len()
    }

    /// The pose axes measured, in the order of a measurement (X Y Z first).
    pub fn measured_axes(&self) -> &'static [usize] {
        match self.kind {
            Kind::H4 { .. } => &[0, 1, 2, 3, 5],
            Kind::Hexapod => &[0, 1, 2, 3, 4, 5],
            Kind::HexapodXy { .. } => &[0, 1, 2, 3, 4],
        }
    }

    /// The loop joints at internal pose `x` (mm, radians).
    pub fn loop_joints<T: Scalar>(&self, th: &[T], x: &[T]) -> Vec<T> {
        match &self.kind {
            Kind::H4 { sides, .. } => (0..4).map(|i| h4_carriage(th, x, sides[i], i).0).collect(),
            Kind::Hexapod => legs(th, 0, x),
            Kind::HexapodXy { .. } => legs(th, 6, x),
        }
    }

    /// The measured tool pose (mm, degrees; [`Model::measured_axes`]) at internal pose
    /// `x` with joints `q`.
    pub fn measure<T: Scalar>(&self, th: &[T], x: &[T], q: &[f64]) -> Vec<T> {
        let deg = |v: T| v * T::c(180.0 / std::f64::consts::PI);
        match &self.kind {
            Kind::H4 { .. } => {
                let a = (T::c(q[4]) + th[30]) * T::c(std::f64::consts::PI / 180.0);
                let pivot = [th[0], th[1], th[2]];
                let d = [x[0] - pivot[0], x[1] - pivot[1], x[2] - th[3] - pivot[2]];
                let w = rot_x(-a, d);
                vec![
                    pivot[0] + w[0],
                    pivot[1] + w[1],
                    pivot[2] + w[2],
                    deg(a),
                    deg(x[3]),
                ]
            }
            Kind::Hexapod => {
                vec![x[0], x[1], x[2], deg(x[3]), deg(x[4]), deg(x[5])]
            }
            Kind::HexapodXy { .. } => {
                let t = [T::c(q[6]) + th[4], T::c(q[7]) + th[5], th[3]];
                let ang = [x[3], x[4], x[5]];
                let d = [t[0] - x[0], t[1] - x[1], t[2] - x[2]];
                let p = rot_zyx_t(ang, d);
                let u = rot_zyx_t(ang, [T::c(0.0), T::c(0.0), T::c(1.0)]);
                let a = (-u[1]).atan2(u[2]);
                let b = u[0].asin();
                vec![th[0] + p[0], th[1] + p[1], th[2] + p[2], deg(a), deg(b)]
            }
        }
    }

    /// Joints (mm, degrees) and internal pose commanding `pose` (mm, degrees: X Y Z A B
    /// C) under parameters `th`; `None` when out of reach, flatter than the H-4's
    /// minimum elevation, or past a joint's travel.
    pub fn inverse(&self, th: &[f64], pose: &[f64; 6]) -> Option<(Vec<f64>, Vec<f64>)> {
        let r = pose.map(f64::to_radians);
        let (q, x) = match &self.kind {
            Kind::H4 {
                sides,
                min_elevation,
            } => {
                let pivot = [th[0], th[1], th[2]];
                let d = rot_x(
                    r[3],
                    [pose[0] - pivot[0], pose[1] - pivot[1], pose[2] - pivot[2]],
                );
                let x = vec![
                    pivot[0] + d[0],
                    pivot[1] + d[1],
                    pivot[2] + d[2] + th[3],
                    r[5],
                ];
                let min_h = th[24] * min_elevation.to_radians().sin();
                let mut q = Vec::with_capacity(5);
                for i in 0..4 {
                    let (qi, h2) = h4_carriage(th, &x, sides[i], i);
                    if h2.is_nan() || h2 < min_h * min_h {
                        return None;
                    }
                    q.push(qi);
                }
                q.push(pose[3] - th[30]);
                (q, x)
            }
            Kind::Hexapod => {
                let x = vec![pose[0], pose[1], pose[2], r[3], r[4], r[5]];
                (legs(th, 0, &x), x)
            }
            Kind::HexapodXy { travel } => {
                let h = [th[0], th[1], th[2]];
                let v = [pose[0] - h[0], pose[1] - h[1], pose[2] - h[2]];
                let ang = [-r[3], -r[4], 0.0];
                let v = rot_zyx(ang, v);
                let t = [
                    (h[0] + v[0]).clamp(travel[0][0], travel[0][1]),
                    (h[1] + v[1]).clamp(travel[1][0], travel[1][1]),
                ];
                let x = vec![t[0] - v[0], t[1] - v[1], th[3] - v[2], ang[0], ang[1], 0.0];
                let mut q = legs(th, 6, &x);
                q.push(t[0] - th[4]);
                q.push(t[1] - th[5]);
                (q, x)
            }
        };
        let inside = q
            .iter()
            .zip(&self.limits)
            .all(|(v, l)| *v >= l[0] - 1e-9 && *v <= l[1] + 1e-9);
        inside.then_some((q, x))
    }
}

/// Carriage height of the H-4's arm `i` and the square of its forearm's height.
fn h4_carriage<T: Scalar>(th: &[T], x: &[T], side: f64, i: usize) -> (T, T) {
    let (s, c) = x[3].sin_cos();
    let bar = th[25] * T::c(side);
    let at = |k: usize| th[4 + 3 * i + k];
    let p = [x[0] + bar * c + at(0), x[1] + bar * s + at(1), x[2] + at(2)];
    let dx = p[0] - th[16 + 2 * i];
    let dy = p[1] - th[17 + 2 * i];
    let h2 = th[24] * th[24] - dx * dx - dy * dy;
    (p[2] + h2.sqrt() - th[26 + i], h2)
}

/// The six legs' readings at platform pose `x`, the parameters from `at`: base
/// joints, platform joints, offsets.
fn legs<T: Scalar>(th: &[T], at: usize, x: &[T]) -> Vec<T> {
    (0..6)
        .map(|i| {
            let a = |k| th[at + 3 * i + k];
            let b = [
                th[at + 18 + 3 * i],
                th[at + 19 + 3 * i],
                th[at + 20 + 3 * i],
            ];
            let v = rot_zyx([x[3], x[4], x[5]], b);
            let w = [x[0] + v[0] - a(0), x[1] + v[1] - a(1), x[2] + v[2] - a(2)];
            (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt() - th[at + 36 + i]
        })
        .collect()
}

/// Rx(a)·v.
pub fn rot_x<T: Scalar>(a: T, v: [T; 3]) -> [T; 3] {
    let (s, c) = a.sin_cos();
    [v[0], c * v[1] - s * v[2], s * v[1] + c * v[2]]
}

/// Rz(c)·Ry(b)·Rx(a)·v, `ang` = [a, b, c].
pub fn rot_zyx<T: Scalar>(ang: [T; 3], v: [T; 3]) -> [T; 3] {
    let v = rot_x(ang[0], v);
    let (sb, cb) = ang[1].sin_cos();
    let v = [cb * v[0] + sb * v[2], v[1], cb * v[2] - sb * v[0]];
    let (sc, cc) = ang[2].sin_cos();
    [cc * v[0] - sc * v[1], sc * v[0] + cc * v[1], v[2]]
}

/// (Rz(c)·Ry(b)·Rx(a))ᵀ·v.
pub fn rot_zyx_t<T: Scalar>(ang: [T; 3], v: [T; 3]) -> [T; 3] {
    let (sc, cc) = ang[2].sin_cos();
    let v = [cc * v[0] + sc * v[1], cc * v[1] - sc * v[0], v[2]];
    let (sb, cb) = ang[1].sin_cos();
    let v = [cb * v[0] - sb * v[2], v[1], sb * v[0] + cb * v[2]];
    rot_x(-ang[0], v)
}
