//! `nc-send calibrate plan --sphere …`: the touches of a probing run, chosen for
//! conditioning, written as a G-code probing program and as a touch list.
//!
//! A candidate touch is a sphere, a machine orientation drawn from the workspace box
//! ([`super::plan::workspace`]) and a point of the sphere's upper half that the stylus
//! can reach at that orientation (its normal at least 15° above the plane across the
//! tool axis). The probe starts `standoff` mm out along the normal and moves in towards
//! the centre, `overtravel` mm past the nominal surface at most; it reaches the start
//! from a clearance point out along the tool axis. The candidate is kept only if the
//! clearance point, the start, the nominal touch and the end of the probing move are
//! all usable ([`super::plan::Usable`]: within every joint's travel, singularity margin
//! at least half the home pose's). From the candidates, touches are added greedily
//! for the determinant of the information matrix of the identifiable parameters
//! (machine and spheres' centres), as the pose plan does.
#![allow(clippy::needless_range_loop)]

use super::data::format_number;
use super::fit::{identifiability, Identifiability, Residual};
use super::model::{Kind, Model};
use super::plan::{condition, d_optimal, workspace, Usable};
use super::sphere::{extend, Probing, Sphere, Touch};
use super::truth::Rng;
use crate::control::linalg::Mat;
use pkmc::config::MachineConfig;

/// The artefact and the probe.
#[derive(Clone, Debug)]
pub struct Setup {
    /// The spheres (centres approximate, radii known).
    pub spheres: Vec<Sphere>,
    /// The probe tip's radius, mm.
    pub tip: f64,
    /// Where a probing move starts, mm out from the nominal surface.
    pub standoff: f64,
    /// How far past the nominal surface a probing move may go, mm.
    pub overtravel: f64,
    /// The probe's noise along the surface normal, mm.
    pub noise: f64,
}

/// One planned touch.
#[derive(Clone, Debug)]
pub struct Planned {
    /// The sphere.
    pub sphere: usize,
    /// The nominal touch pose (tool tip on the surface), mm and degrees.
    pub pose: [f64; 6],
    /// The sphere's outward normal there; the probe moves along its opposite.
    pub normal: [f64; 3],
    /// The nominal joints and internal pose at the touch.
    pub q: Vec<f64>,
    /// The internal pose.
    pub x: Vec<f64>,
}

impl Planned {
    /// The pose `d` mm out along the normal from the nominal touch.
    pub fn along(&self, d: f64) -> [f64; 6] {
        let mut p = self.pose;
        for k in 0..3 {
            p[k] += d * self.normal[k];
        }
        p
    }
}

/// The tool axis (from the tip towards the holder) in the programmed frame at `pose`.
pub fn tool_axis(model: &Model, pose: &[f64; 6]) -> [f64; 3] {
    let r = pose.map(f64::to_radians);
    match model.kind {
        // The tool is vertical; the workpiece frame turns with the table (A about X).
        Kind::H4 { .. } => [0.0, r[3].sin(), r[3].cos()],
        // The stylus hangs below the platform along its z axis.
        Kind::Hexapod => super::model::rot_zyx([r[3], r[4], r[5]], [0.0, 0.0, 1.0]),
        // The tool axis as the measurement's A B give it.
        Kind::HexapodXy { .. } => [
            r[4].sin(),
            -r[3].sin() * r[4].cos(),
            r[3].cos() * r[4].cos(),
        ],
    }
}

/// The clearance point before and after a touch: the start pushed out along the tool
/// axis by the sphere's radius, the tip's and the standoff.
pub fn clearance(model: &Model, setup: &Setup, t: &Planned) -> [f64; 6] {
    let rho = setup.spheres[t.sphere].radius + setup.tip + setup.standoff;
    let mut p = t.along(setup.standoff);
    let a = tool_axis(model, &t.pose);
    for k in 0..3 {
        p[k] += rho * a[k];
    }
    p
}

fn candidate(
    model: &Model,
    usable: &Usable<'_>,
    setup: &Setup,
    sphere: usize,
    rng: &mut Rng,
) -> Option<Planned> {
    let ws = workspace(model);
    let th = model.nominal();
    let s = &setup.spheres[sphere];
    for _ in 0..20_000 {
        let mut pose = [0.0; 6];
        for k in 3..6 {
            pose[k] = rng.range(ws[k][0], ws[k][1]);
        }
        let n = [rng.normal(), rng.normal(), rng.normal()];
        let len = n.iter().map(|v| v * v).sum::<f64>().sqrt();
        let n = n.map(|v| v / len);
        let a = tool_axis(model, &pose);
        if n[2] < 0.0 || n[0] * a[0] + n[1] * a[1] + n[2] * a[2] < 0.26 {
            continue;
        }
        for k in 0..3 {
            pose[k] = s.centre[k] + (s.radius + setup.tip) * n[k];
        }
        let Some((q, x)) = model.inverse(&th, &pose) else {
            continue;
        };
        let t = Planned {
            sphere,
            pose,
            normal: n,
            q,
            x,
        };
        let path = [
            clearance(model, setup, &t),
            t.along(setup.standoff),
            pose,
            t.along(-setup.overtravel),
        ];
        if path
            .iter()
            .all(|p| usable.check(p) && model.inverse(&th, p).is_some())
        {
            return Some(t);
        }
    }
    None
}

/// A probing plan.
pub struct SpherePlan {
    /// The touches, in the order to probe them.
    pub touches: Vec<Planned>,
    /// The model with the spheres' centres among its parameters.
    pub model: Model,
    /// Identifiability over all the candidates.
    pub ident: Identifiability,
    /// Condition number of the scaled Jacobian of the free parameters at the plan.
    pub condition: f64,
    /// The same for the first candidates (a random plan of the same size).
    pub random_condition: f64,
}

/// The whitened Jacobian row of each touch at the nominal parameters of the extended
/// model `ext`.
fn rows(ext: &Model, setup: &Setup, touches: &[Planned], machine: usize) -> Option<Vec<Mat>> {
    let th = ext.nominal();
    let mut p = Probing {
        touches: touches
            .iter()
            .map(|t| Touch {
                q: t.q.clone(),
                sphere: t.sphere,
                approach: None,
                guess: t.x.clone(),
            })
            .collect(),
        radii: setup.spheres.iter().map(|s| s.radius).collect(),
        tip: setup.tip,
        noise: setup.noise,
        machine_params: machine,
    };
    let (_, jac) = p.evaluate(ext, &th, true)?;
    Some(jac.into_iter().map(|r| vec![r]).collect())
}

/// Chooses `n` touches from `candidates` random ones (seeded by `seed`), the spheres
/// taken in turn.
pub fn plan(
    config: &MachineConfig,
    model: &Model,
    setup: &Setup,
    n: usize,
    candidates: usize,
    seed: u64,
) -> Result<SpherePlan, String> {
    if setup.spheres.is_empty() {
        return Err("probing needs at least one sphere (--sphere X,Y,Z,R)".into());
    }
    let usable = Usable::new(config);
    let mut rng = Rng::new(seed);
    let mut cand = Vec::new();
    for i in 0..candidates.max(n) {
        let k = i % setup.spheres.len();
        let t = candidate(model, &usable, setup, k, &mut rng).ok_or(format!(
            "sphere {k} ({}): no touch of it is usable (reach, travel, singularity margin)",
            setup.spheres[k].text()
        ))?;
        cand.push(t);
    }
    let ext = extend(model, &setup.spheres);
    let rows = rows(&ext, setup, &cand, model.params.len())
        .ok_or("a candidate touch has no forward kinematics")?;
    let all: Mat = rows.iter().flatten().cloned().collect();
    let ident = identifiability(&ext, &all, 1e-6, &[]);
    let rows: Vec<Mat> = rows
        .iter()
        .map(|j| {
            j.iter()
                .map(|r| {
                    let f = ident.free.iter();
                    f.map(|&c| r[c] * ext.params[c].scale).collect()
                })
                .collect()
        })
        .collect();
    let mut pick = d_optimal(&rows, n)?;
    let first: Vec<usize> = (0..n.min(cand.len())).collect();
    let (condition, random_condition) = (condition(&rows, &pick), condition(&rows, &first));
    // Probe sphere by sphere, each sphere's touches by orientation.
    pick.sort_by(|&a, &b| {
        let key = |i: usize| (cand[i].sphere, cand[i].pose[3], cand[i].pose[4]);
        key(a)
            .partial_cmp(&key(b))
            .unwrap_or(std::cmp::Ordering::Equal)
    });
    Ok(SpherePlan {
        touches: pick.iter().map(|&i| cand[i].clone()).collect(),
        model: ext,
        ident,
        condition,
        random_condition,
    })
}

fn words(p: &[f64; 6], axes: &[usize]) -> String {
    axes.iter()
        .map(|&a| format!("{}{:.4}", ["X", "Y", "Z", "A", "B", "C"][a], p[a]))
        .collect::<Vec<_>>()
        .join(" ")
}

/// The plan as a G-code probing program: for each touch, to its clearance point and
/// its start (`G1` at `feed`), then `G38.2` in towards the sphere's centre at
/// `probe_feed` (stops on contact, an error without one; the latched position lands in
/// #5061–#5066), back out to the start and the clearance point. `axes`: the pose axes
/// the machine programs. The touches' sphere and approach are in the comments.
pub fn gcode(
    model: &Model,
    setup: &Setup,
    plan: &SpherePlan,
    axes: &[usize],
    feed: f64,
    probe_feed: f64,
) -> String {
    let mut out = String::from("(sphere probing for calibration, from nc-send calibrate plan)\n");
    for (k, s) in setup.spheres.iter().enumerate() {
        out += &format!(
            "(sphere {k} = {}; tip radius {})\n",
            s.text(),
            format_number(setup.tip)
        );
    }
    out += "(record for each G38.2 the latched joints, or #5061-#5066, with its touch's sphere)\n";
    out += "G90 G21 G94\n";
    for (i, t) in plan.touches.iter().enumerate() {
        let end = t.along(-setup.overtravel);
        let xyz: Vec<String> = (0..3)
            .map(|k| format!("{}{:.4}", ["X", "Y", "Z"][k], end[k]))
            .collect();
        let d = t.normal.map(|v| format_number(-v));
        out += &format!(
            "(touch {}: sphere {}, approach {}, {}, {})\n",
            i + 1,
            t.sphere,
            d[0],
            d[1],
            d[2]
        );
        let clear = words(&clearance(model, setup, t), axes);
        out += &format!("G1 {clear} F{feed}\n");
        out += &format!("G1 {} F{feed}\n", words(&t.along(setup.standoff), axes));
        out += &format!("G38.2 {} F{probe_feed}\n", xyz.join(" "));
        out += &format!("G1 {} F{feed}\n", words(&t.along(setup.standoff), axes));
        out += &format!("G1 {clear} F{feed}\n");
    }
    out + "M2\n"
}

/// The touch list (CSV): the spheres and the tip in its comments (as the fit reads
/// them), then per touch the commanded touch pose `cmd_*`, its joints `q*` (with
/// `latched`: the joints latched instead), the sphere and the approach direction.
pub fn csv(model: &Model, setup: &Setup, plan: &[Planned], latched: Option<&[Vec<f64>]>) -> String {
    let mut out = String::new();
    for (k, s) in setup.spheres.iter().enumerate() {
        out += &format!("# sphere {k} = {}\n", s.text());
    }
    out += &format!("# tip_radius = {}\n", format_number(setup.tip));
    let mut head: Vec<String> = ["X", "Y", "Z", "A", "B", "C"]
        .iter()
        .map(|a| format!("cmd_{a}"))
        .collect();
    head.extend((1..=model.joints()).map(|j| format!("q{j}")));
    head.extend(["sphere", "dir_x", "dir_y", "dir_z"].map(String::from));
    out += &(head.join(",") + "\n");
    for (i, t) in plan.iter().enumerate() {
        let q = latched.map_or(&t.q, |l| &l[i]);
        let mut row: Vec<String> = t.pose.iter().map(|v| format_number(*v)).collect();
        row.extend(q.iter().map(|v| format_number(*v)));
        row.push(t.sphere.to_string());
        row.extend(t.normal.iter().map(|v| format_number(-v)));
        out += &(row.join(",") + "\n");
    }
    out
}
