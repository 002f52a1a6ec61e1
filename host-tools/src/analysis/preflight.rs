//! Pre-flight: the program checked against the machine before anything moves, with
//! the same geometry and kinematics the controller uses.
//!
//! Every block's path is sampled at least every [`SAMPLE_NM`] (and at both ends);
//! each sample goes through the controller's inverse kinematics with the travel
//! check, and every failure is reported with its NC line (one finding per line and
//! reason). The singularity margin at a sample comes from the singular values of the
//! Jacobian J = ∂q/∂p of the axes the machine uses (joints per mm, rotary axes and
//! joints with 1° counted as 1 mm, the fit space of [`crate::gcode::compress::space`]):
//! the kinematics' analytic Jacobian
//! ([`Kinematics::jacobian`], the one the planner uses), and the Jacobi eigenvalue
//! method on JᵀJ: min(σ_min, 1/σ_max), which is 1 for a Cartesian machine and falls to zero at either kind of singularity. The
//! smallest margin met, and where, is reported.
//!
//! A curve the compressor merged from many programmed moves is named at the programmed
//! move nearest to where the problem was met ([`Chords`]), not at the curve's first
//! line: the line a machinist has to change.

use crate::gcode::compress::space::{on_segment, to_fit, units_per_nm};
use pkmc::config::{MachineConfig, AXES, MAX_JOINTS};
use pkmc::kinematics::{Jacobian, Kinematics, MachineKinematics, Unreachable};
use pkmc::motion::block::Block;
use pkmc::motion::geometry::{GeometryError, Path};
use std::collections::BTreeSet;
use std::ops::Range;

/// Largest distance between two samples of a path, nm.
pub const SAMPLE_NM: i64 = 1_000_000;
/// Fit-space nm per mm.
const NM_PER_MM: f64 = 1e6;

/// One problem found.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Finding {
    /// NC line.
    pub line: u32,
    /// What is wrong, in words.
    pub what: String,
    /// Pose where it was first met: X Y Z mm, A B C degrees.
    pub at: [String; AXES],
}

/// The pre-flight result.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct Preflight {
    /// Blocks checked.
    pub blocks: usize,
    /// Poses sampled.
    pub samples: usize,
    /// Every pose out of reach or joint limit broken, by line.
    pub findings: Vec<Finding>,
    /// Smallest singularity margin met (σ_min of ∂q/∂p), and its line.
    pub min_margin: Option<(f64, u32)>,
}

fn describe(why: Unreachable, machine: &MachineConfig) -> String {
    match why {
        Unreachable::JointLimit { joint } => {
            let j = joint as usize;
            match machine.joints.get(j) {
                Some(jc) => format!(
                    "joint q{} would leave its travel [{}, {}]",
                    j + 1,
                    pkmc::units::to_user(jc.min, jc.rotary),
                    pkmc::units::to_user(jc.max, jc.rotary)
                ),
                None => why.to_string(),
            }
        }
        other => other.to_string(),
    }
}

fn user_pose(p: &[i64; AXES]) -> [String; AXES] {
    std::array::from_fn(|i| {
        format!(
            "{:.4}",
            pkmc::units::to_user(p[i], pkmc::config::axis_is_rotary(i))
        )
    })
}

/// Smallest and largest eigenvalues of a symmetric matrix (Jacobi rotations).
// Index loops: the rotations read and write a[k][p] and a[p][k] pairwise, which
// iterators would only obscure.
#[allow(clippy::needless_range_loop)]
fn eigen_range(mut a: Vec<Vec<f64>>) -> (f64, f64) {
    let n = a.len();
    for _sweep in 0..50 {
        let mut off = 0.0;
        for i in 0..n {
            for j in 0..n {
                if i != j {
                    off += a[i][j] * a[i][j];
                }
            }
        }
        if off < 1e-22 {
            break;
        }
        for p in 0..n {
            for q in p + 1..n {
                if a[p][q].abs() < 1e-300 {
                    continue;
                }
                let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for k in 0..n {
                    let (akp, akq) = (a[k][p], a[k][q]);
                    a[k][p] = c * akp - s * akq;
                    a[k][q] = s * akp + c * akq;
                }
                for k in 0..n {
                    let (apk, aqk) = (a[p][k], a[q][k]);
                    a[p][k] = c * apk - s * aqk;
                    a[q][k] = s * apk + c * aqk;
                }
            }
        }
    }
    let diag = (0..n).map(|i| a[i][i]);
    (
        diag.clone().fold(f64::INFINITY, f64::min),
        diag.fold(0.0, f64::max),
    )
}

/// Singularity margin at `pose`: min(σ_min, 1/σ_max) of J = ∂q/∂p over the axes the
/// machine uses, or `None` if the neighbourhood is out of reach. σ_min → 0 where the
/// joints lose control of a pose direction (serial singularity), σ_max → ∞ where the
/// pose loses stiffness against the joints (parallel singularity, e.g. a flat H-4
/// forearm); 1 for a Cartesian machine.
pub fn margin(pose: &[i64; AXES], machine: &MachineConfig, kin: &MachineKinematics) -> Option<f64> {
    let axes: Vec<usize> = (0..AXES)
        .filter(|&i| machine.axes[i].max_velocity > 0)
        .collect();
    let n = machine.joints.len();
    // The kinematics' analytic ∂q/∂p, rescaled: columns per mm, rows in mm (of the
    // fit space, where a rotary axis's or joint's degree counts as a mm).
    let mut dq: Jacobian = [[0.0; AXES]; MAX_JOINTS];
    kin.jacobian(pose, &mut dq).ok()?;
    let mut jac = vec![vec![0.0f64; axes.len()]; n];
    for (c, &i) in axes.iter().enumerate() {
        let per_unit = NM_PER_MM * units_per_nm(pkmc::config::axis_is_rotary(i));
        for j in 0..n {
            let scale = 1.0 / (NM_PER_MM * units_per_nm(machine.joints[j].rotary));
            jac[j][c] = dq[j][i] as f64 * scale * per_unit;
        }
    }
    // JᵀJ (axes × axes); σ_min = sqrt(λ_min).
    let m = axes.len();
    let jtj: Vec<Vec<f64>> = (0..m)
        .map(|a| {
            (0..m)
                .map(|b| (0..n).map(|j| jac[j][a] * jac[j][b]).sum())
                .collect()
        })
        .collect();
    let (lo, hi) = eigen_range(jtj);
    let (s_min, s_max) = (lo.max(0.0).sqrt(), hi.max(0.0).sqrt());
    Some(s_min.min(if s_max > 0.0 { 1.0 / s_max } else { 0.0 }))
}

/// Each block's path from the end of the one before (the first from `start`), or why
/// it is malformed: derived once for a compiled program, and read by the pre-flight
/// ([`check_paths`]) and the statics ([`super::statics::check_paths`]).
pub fn paths(blocks: &[Block], start: [i64; AXES]) -> Vec<Result<Path, GeometryError>> {
    let mut from = start;
    blocks
        .iter()
        .map(|b| {
            let p = Path::new(b, &from);
            if let Ok(p) = &p {
                from = p.end;
            }
            p
        })
        .collect()
}

/// Checks `blocks`, starting at `start`, against `machine`.
pub fn check(blocks: &[Block], machine: &MachineConfig, start: [i64; AXES]) -> Preflight {
    check_paths(blocks, &paths(blocks, start), machine, start, None)
}

/// [`check`] of `blocks` whose paths are derived already ([`paths`]).
pub fn check_paths(
    blocks: &[Block],
    paths: &[Result<Path, GeometryError>],
    machine: &MachineConfig,
    start: [i64; AXES],
    chords: Option<&Chords>,
) -> Preflight {
    let mut out = Preflight::default();
    let mut acc = Accumulator::new(machine);
    acc.add(blocks, paths, start, chords, &mut out);
    out
}

/// The programmed moves that blocks stand for ([`crate::gcode::compress::Compressed`]'s
/// `source`), to name a finding on a merged curve at its programmed move.
#[derive(Clone, Copy, Debug)]
pub struct Chords<'a> {
    /// Programmed blocks; the first is the program's `first`-th.
    pub programmed: &'a [Block],
    /// The program index of `programmed[0]`.
    pub first: usize,
    /// Where `programmed[0]` starts.
    pub start: [i64; AXES],
    /// For each block checked, the programmed blocks it stands for (program indices).
    pub source: &'a [Range<usize>],
}

impl Chords<'_> {
    /// The line of the programmed move nearest `pose` among those block `k` stands
    /// for (the earlier of two as near); `None` for a block that stands for one move,
    /// or whose moves are not all in `programmed`.
    pub fn line_at(&self, k: usize, pose: &[i64; AXES]) -> Option<u32> {
        let r = self.source.get(k)?;
        if r.len() < 2 {
            return None;
        }
        let y = to_fit(pose);
        let mut best: Option<(f64, u32)> = None;
        for g in r.clone() {
            let i = g.checked_sub(self.first)?;
            let b = self.programmed.get(i)?;
            let from = match i {
                0 => self.start,
                _ => self.programmed[i - 1].target,
            };
            let d = on_segment(&y, &to_fit(&from), &to_fit(&b.target)).1;
            if best.is_none_or(|(near, _)| d < near) {
                best = Some((d, b.line));
            }
        }
        best.map(|(_, line)| line)
    }
}

/// The pre-flight's working state carried from one run of blocks to the next (the
/// kinematics, and which problems were reported on which line).
pub struct Accumulator<'m> {
    machine: &'m MachineConfig,
    kin: MachineKinematics,
    seen: BTreeSet<(u32, String)>,
}

impl<'m> Accumulator<'m> {
    /// A fresh pre-flight of a program for `machine`.
    pub fn new(machine: &'m MachineConfig) -> Self {
        Self {
            machine,
            kin: MachineKinematics::new(machine),
            seen: BTreeSet::new(),
        }
    }

    /// Checks `blocks` (with their `paths`), the first starting at `start`, into `out`;
    /// with `chords`, a finding on a merged curve is named at its programmed move.
    pub fn add(
        &mut self,
        blocks: &[Block],
        paths: &[Result<Path, GeometryError>],
        start: [i64; AXES],
        chords: Option<&Chords>,
        out: &mut Preflight,
    ) {
        let (machine, kin) = (self.machine, &self.kin);
        let seen = &mut self.seen;
        out.blocks += blocks.len();
        let mut from = start;
        let mut q = [0i64; MAX_JOINTS];
        for (index, (b, path)) in blocks.iter().zip(paths).enumerate() {
            let path = match path {
                Ok(p) => p,
                Err(e) => {
                    out.findings.push(Finding {
                        line: b.line,
                        what: format!("malformed path ({e})"),
                        at: user_pose(&from),
                    });
                    continue;
                }
            };
            let len = path.length.max(0);
            let n = (len / SAMPLE_NM + 1).clamp(1, 100_000) as i64;
            for k in 0..=n {
                let s = ((len as i128) << 16) * k as i128 / n as i128;
                let mut pose = [0i64; AXES];
                path.pose_at(&from, s as i64, &mut pose);
                out.samples += 1;
                match kin.inverse_checked(&pose, &machine.joints, &mut q) {
                    Err(why) => {
                        let what = describe(why, machine);
                        let line = chords
                            .and_then(|c| c.line_at(index, &pose))
                            .unwrap_or(b.line);
                        if seen.insert((line, what.clone())) {
                            out.findings.push(Finding {
                                line,
                                what,
                                at: user_pose(&pose),
                            });
                        }
                    }
                    Ok(()) => {
                        if let Some(m) = margin(&pose, machine, kin) {
                            if out.min_margin.is_none_or(|(best, _)| m < best) {
                                out.min_margin = Some((m, b.line));
                            }
                        }
                    }
                }
            }
            from = path.end;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use pkmc::motion::block::Motion;

    fn to(target: [i64; AXES], line: u32) -> Block {
        Block {
            line,
            motion: Motion::Linear,
            target,
            feed: 10_000_000,
            tolerance_nm: u32::MAX,
        }
    }

    #[test]
    fn every_line_that_leaves_the_travel_is_reported_not_just_the_first() {
        let m = MachineConfig::cartesian_xyz();
        let blocks = [
            to([0, 0, 50_000_000, 0, 0, 0], 3),
            to([0, 0, 0, 0, 0, 0], 4),
            to([150_000_000, 0, 0, 0, 0, 0], 7),
        ];
        let p = check(&blocks, &m, m.home);
        let lines: Vec<u32> = p.findings.iter().map(|f| f.line).collect();
        // Line 3 rises past Z's travel (and line 4 comes back from there).
        assert_eq!(lines, vec![3, 4, 7], "{:?}", p.findings);
        assert!(p.findings[2].what.contains("q1"));
    }

    #[test]
    fn a_cartesian_machine_has_unit_margin_and_the_h4_less_near_its_edge() {
        let m = MachineConfig::cartesian_xyz();
        let p = check(&[to([10_000_000, 0, 0, 0, 0, 0], 1)], &m, m.home);
        let (margin, _) = p.min_margin.unwrap();
        assert!((margin - 1.0).abs() < 1e-3, "{margin}");
        let h4 = MachineConfig::h4_table();
        let kin = MachineKinematics::new(&h4);
        let centre = margin_at(&h4, &kin, h4.home);
        let mut edge = h4.home;
        edge[0] = 95_000_000;
        let near_edge = margin_at(&h4, &kin, edge);
        assert!(near_edge < centre, "{near_edge} vs {centre}");
    }

    fn margin_at(m: &MachineConfig, kin: &MachineKinematics, p: [i64; AXES]) -> f64 {
        margin(&p, m, kin).unwrap()
    }
}
