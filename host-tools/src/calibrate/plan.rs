//! `nc-send calibrate plan`: measurement poses that make the identifiable parameters
//! well conditioned.
//!
//! Candidates are drawn at random from the machine's usable workspace and kept only if
//! the controller's own kinematics reaches them within every joint's travel
//! (`MachineKinematics::inverse_checked`) and their singularity margin (the
//! pre-flight check's, `analysis::preflight::margin`) is at least half the home
//! pose's. From these, poses are added one at a time, each the one that most increases
//! the determinant of the information matrix of the free parameters (greedy
//! D-optimal design).
#![allow(clippy::needless_range_loop)]

use super::fit::{identifiability, Identifiability, Noise, PoseMeasurements, Residual, Sample};
use super::model::{Kind, Model};
use super::truth::Rng;
use crate::analysis::preflight::margin;
use crate::control::linalg::{chol_inverse, svd, Mat};
use pkmc::config::{MachineConfig, AXES, MAX_JOINTS};
use pkmc::kinematics::MachineKinematics;

/// The box random poses are drawn from, mm and degrees, per pose axis.
pub fn workspace(model: &Model) -> [[f64; 2]; 6] {
    let h = model.home;
    match model.kind {
        Kind::H4 { .. } => [
            [-150.0, 150.0],
            [-150.0, 150.0],
            [h[2] - 100.0, h[2] + 60.0],
            [0.0, 60.0],
            [0.0, 0.0],
            [-30.0, 30.0],
        ],
        Kind::Hexapod => [
            [-60.0, 60.0],
            [-60.0, 60.0],
            [h[2] - 50.0, h[2] + 60.0],
            [-8.0, 8.0],
            [-8.0, 8.0],
            [-15.0, 15.0],
        ],
        Kind::HexapodXy { .. } => [
            [-70.0, 70.0],
            [-70.0, 70.0],
            [h[2] - 20.0, h[2] + 20.0],
            [-8.0, 8.0],
            [-8.0, 8.0],
            [0.0, 0.0],
        ],
    }
}

/// Usable poses for the controller: within every joint's travel, and with a
/// singularity margin at least `min_margin`.
pub struct Usable<'a> {
    config: &'a MachineConfig,
    kin: MachineKinematics,
    min_margin: f64,
}

impl<'a> Usable<'a> {
    /// The checks of `config`; the margin required is half the home pose's.
    pub fn new(config: &'a MachineConfig) -> Usable<'a> {
        let kin = MachineKinematics::new(config);
        let home = margin(&config.home, config, &kin).unwrap_or(0.0);
        Usable {
            config,
            kin,
            min_margin: 0.5 * home,
        }
    }

    /// Is `pose` (mm, degrees) usable?
    pub fn check(&self, pose: &[f64; 6]) -> bool {
        let mut p = [0i64; AXES];
        for k in 0..AXES {
            p[k] = (pose[k] * if k < 3 { 1e6 } else { 1e9 }).round() as i64;
        }
        let mut q = [0i64; MAX_JOINTS];
        self.kin
            .inverse_checked(&p, &self.config.joints, &mut q)
            .is_ok()
            && margin(&p, self.config, &self.kin).is_some_and(|m| m >= self.min_margin)
    }
}

/// A random usable pose with its nominal joints and internal pose; `None` when a
/// hundred thousand draws found none.
pub fn random_pose(model: &Model, usable: &Usable<'_>, rng: &mut Rng) -> Option<Pose> {
    let ws = workspace(model);
    let th = model.nominal();
    for _ in 0..100_000 {
        let mut pose = [0.0; 6];
        for k in 0..6 {
            pose[k] = rng.range(ws[k][0], ws[k][1]);
        }
        if !usable.check(&pose) {
            continue;
        }
        if let Some((q, x)) = model.inverse(&th, &pose) {
            return Some((pose, q, x));
        }
    }
    None
}

/// A pose (mm, degrees), its nominal joints and internal pose.
pub type Pose = ([f64; 6], Vec<f64>, Vec<f64>);

/// A plan: poses, their joints, the conditioning they give.
pub struct Plan {
    /// Commanded poses, mm and degrees.
    pub poses: Vec<[f64; 6]>,
    /// Their nominal joints.
    pub joints: Vec<Vec<f64>>,
    /// Identifiability over all the candidates (what any plan can identify).
    pub ident: Identifiability,
    /// Condition number of the scaled Jacobian of the free parameters at the plan.
    pub condition: f64,
    /// The same for the first `n` candidates (a random plan), for comparison.
    pub random_condition: f64,
}

/// Condition number of the rows of the candidates `pick`, stacked.
pub fn condition(rows: &[Mat], pick: &[usize]) -> f64 {
    let stacked: Mat = pick.iter().flat_map(|&i| rows[i].iter().cloned()).collect();
    let cols = stacked.first().map_or(0, Vec::len);
    let (s, _) = svd(&stacked, cols);
    s[0] / s[cols - 1]
}

/// Chooses `n` poses from `candidates` random usable ones (seeded by `seed`).
pub fn plan(
    config: &MachineConfig,
    model: &Model,
    n: usize,
    candidates: usize,
    seed: u64,
    noise: Noise,
) -> Result<Plan, String> {
    let usable = Usable::new(config);
    let mut rng = Rng::new(seed);
    let th = model.nominal();
    let mut cand = Vec::new();
    let mut rows: Vec<Mat> = Vec::new();
    for _ in 0..candidates.max(n) {
        let (pose, q, x) =
            random_pose(model, &usable, &mut rng).ok_or("no usable pose in the workspace")?;
        let measured = vec![0.0; model.measured_axes().len()];
        let mut one = PoseMeasurements {
            samples: vec![Sample {
                q: q.clone(),
                measured,
                guess: x,
            }],
            noise,
        };
        let Some((_, jac)) = one.evaluate(model, &th, true) else {
            continue;
        };
        cand.push((pose, q));
        rows.push(jac);
    }
    let all: Mat = rows.iter().flatten().cloned().collect();
    let ident = identifiability(model, &all, 1e-6, &[]);
    // Free columns, scaled: the information matrix is in the parameters' scales.
    let rows: Vec<Mat> = rows
        .iter()
        .map(|j| {
            j.iter()
                .map(|r| {
                    ident
                        .free
                        .iter()
                        .map(|&c| r[c] * model.params[c].scale)
                        .collect()
                })
                .collect()
        })
        .collect();
    let pick = d_optimal(&rows, n)?;
    let first: Vec<usize> = (0..n.min(cand.len())).collect();
    Ok(Plan {
        condition: condition(&rows, &pick),
        random_condition: condition(&rows, &first),
        poses: pick.iter().map(|&i| cand[i].0).collect(),
        joints: pick.iter().map(|&i| cand[i].1.clone()).collect(),
        ident,
    })
}

/// Greedy D-optimal design: `n` of the candidates (each its rows of the scaled
/// Jacobian of the free parameters), each added the one that most increases log det
/// of the information matrix.
pub fn d_optimal(rows: &[Mat], n: usize) -> Result<Vec<usize>, String> {
    let nf = rows.iter().flatten().next().map_or(0, Vec::len);
    let reg = 1e-6 * rows.iter().flatten().flatten().map(|v| v * v).sum::<f64>()
        / (rows.len() * nf).max(1) as f64;
    let mut info: Mat = (0..nf)
        .map(|i| (0..nf).map(|j| if i == j { reg } else { 0.0 }).collect())
        .collect();
    let mut pick: Vec<usize> = Vec::new();
    for _ in 0..n.min(rows.len()) {
        let (_, inv) = chol_inverse(&info).ok_or("information matrix not positive")?;
        let best = (0..rows.len())
            .filter(|i| !pick.contains(i))
            .map(|i| (gain(&rows[i], &inv), i))
            .max_by(|a, b| a.0.total_cmp(&b.0))
            .ok_or("no candidates")?
            .1;
        for r in &rows[best] {
            for a in 0..nf {
                for b in 0..nf {
                    info[a][b] += r[a] * r[b];
                }
            }
        }
        pick.push(best);
    }
    Ok(pick)
}

/// log det(I + J·M⁻¹·Jᵀ): how much a pose with rows `j` adds to log det M.
fn gain(j: &Mat, inv: &Mat) -> f64 {
    let m = j.len();
    let nf = inv.len();
    let jm: Mat = j
        .iter()
        .map(|r| {
            (0..nf)
                .map(|b| (0..nf).map(|a| r[a] * inv[a][b]).sum())
                .collect()
        })
        .collect();
    let mut s: Mat = (0..m)
        .map(|i| {
            (0..m)
                .map(|k| jm[i].iter().zip(&j[k]).map(|(x, y)| x * y).sum())
                .collect()
        })
        .collect();
    for i in 0..m {
        s[i][i] += 1.0;
    }
    chol_inverse(&s).map_or(f64::NEG_INFINITY, |(ld, _)| ld)
}

/// The plan as a G-code program visiting each pose in turn and dwelling there for
/// the measurement (`axes`: the pose axes the machine programs).
pub fn gcode(plan: &Plan, axes: &[usize], dwell_s: f64, feed: f64) -> String {
    let mut out = String::from("(calibration poses from nc-send calibrate plan)\nG90 G21 G94\n");
    for (k, p) in plan.poses.iter().enumerate() {
        let words: Vec<String> = axes
            .iter()
            .map(|&a| format!("{}{:.4}", ["X", "Y", "Z", "A", "B", "C"][a], p[a]))
            .collect();
        out += &format!(
            "(pose {})\nG1 {} F{feed}\nG4 P{dwell_s}\n",
            k + 1,
            words.join(" ")
        );
    }
    out + "M2\n"
}
