//! How far the tool truly is from the path the controller commanded, from a simulated
//! run's trace (`--sim --trace`): the pose where the joints truly are (the trace's `tq`
//! columns: a servo plant's position before its encoder rounds it), by this room's
//! forward kinematics in `f64` ([`super::forward`]); its distance from the polyline of
//! the commanded tick poses near it; and the angle between its tool axis and the
//! commanded one at the nearest point.
//!
//! The controller's own contour estimate (the recorder's `contour` and `direction`) is
//! made from encoder counts: on the hexapod-xy a count of the table's 1 µm scales moves
//! it by up to a micrometre from one servo period to the next, whatever the gains.
//! This is what the part gets, for the simulator's plants; it has no such rounding.
//! Tick poses are 1 ms apart, 20 µm at 20 mm/s: the chord between two of them strays
//! from the curve the drives follow by (20 µm)²/(8r), 0.5 nm on a 100 mm radius.

use super::forward::forward;
use super::model::Model;
use crate::analysis::direction::{angle_deg, tool_axis};
use crate::gcode::compress::space::on_segment;
use pkmc::config::{MachineConfig, AXES, MAX_JOINTS};
use pkmc::kinematics::MachineKinematics;
use pkmc::units::units_per_user;

/// The true errors at one tick of the trace.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrueError {
    /// End of the tick, s.
    pub t_s: f64,
    /// Distance of the tool point from the commanded path, mm.
    pub path_mm: f64,
    /// Angle between the tool axis and the commanded one at the nearest point, degrees
    /// (tool axes along Rx(A)·Ry(B)·ẑ, as the programs of five-axis machines give A, B).
    pub direction_deg: f64,
    /// The commanded pose moved into or out of this tick.
    pub moving: bool,
}

/// Ticks either side of a row searched for the nearest commanded point: 50 ms, far
/// more than any lag or lead of a loop that does not trip.
const WINDOW: usize = 50;

/// The true errors of every row of `trace` (the CSV `--trace` writes) on the machine
/// `config`. Errors name the column or the row.
pub fn true_errors(config: &MachineConfig, trace: &str) -> Result<Vec<TrueError>, String> {
    let mut lines = trace.lines();
    let header: Vec<&str> = lines.next().ok_or("trace: empty")?.split(',').collect();
    let col = |name: &str| {
        header
            .iter()
            .position(|h| *h == name)
            .ok_or_else(|| format!("trace: no column `{name}` (a trace of this version?)"))
    };
    let pose_cols = [col("x")?, col("y")?, col("z")?, col("a")?, col("b")?];
    let n = config.joints.len().min(MAX_JOINTS);
    let truth_cols = (1..=n)
        .map(|j| col(&format!("tq{j}")))
        .collect::<Result<Vec<_>, _>>()?;
    let t_col = col("t_s")?;
    let mut rows = Vec::new();
    for (k, l) in lines.enumerate() {
        let v = l
            .split(',')
            .map(|x| x.parse::<f64>())
            .collect::<Result<Vec<_>, _>>()
            .map_err(|e| format!("trace row {}: {e}", k + 2))?;
        if v.len() != header.len() {
            return Err(format!(
                "trace row {}: {} fields, the header has {}",
                k + 2,
                v.len(),
                header.len()
            ));
        }
        rows.push(v);
    }
    let pose_of = TruePose::new(config);
    let commanded: Vec<[f64; 5]> = rows.iter().map(|r| pose_cols.map(|c| r[c])).collect();
    let mut out = Vec::with_capacity(rows.len());
    for (i, r) in rows.iter().enumerate() {
        let q: Vec<f64> = truth_cols.iter().map(|c| r[*c]).collect();
        let at = pose_of
            .at(&q, &commanded[i])
            .ok_or_else(|| format!("trace row {}: no pose for the true joints {q:?}", i + 2))?;
        let y = [at[0], at[1], at[2]];
        let (seg, s, d) = nearest(&commanded, i, y);
        let (p, q2) = (
            &commanded[seg],
            &commanded[(seg + 1).min(commanded.len() - 1)],
        );
        let want = tool_axis(p[3] + s * (q2[3] - p[3]), p[4] + s * (q2[4] - p[4]));
        let have = tool_axis(at[3], at[4]);
        let moved = |a: usize, b: usize| b < commanded.len() && commanded[a] != commanded[b];
        out.push(TrueError {
            t_s: r[t_col],
            path_mm: d,
            direction_deg: angle_deg(have, want),
            moving: (i > 0 && moved(i - 1, i)) || moved(i, i + 1),
        });
    }
    Ok(out)
}

/// The pose at given joints, exactly: by Newton's method on the machine's model in
/// `f64` ([`crate::calibrate::forward`]) for a parallel machine; a Cartesian machine's
/// joints are its axes.
enum TruePose {
    Parallel { model: Model, th: Vec<f64> },
    Cartesian(MachineKinematics, Vec<bool>),
}

impl TruePose {
    fn new(config: &MachineConfig) -> Self {
        match Model::from_config(config) {
            Some(model) => {
                let th = model.nominal();
                Self::Parallel { model, th }
            }
            None => Self::Cartesian(
                MachineKinematics::new(config),
                config.joints.iter().map(|j| j.rotary).collect(),
            ),
        }
    }

    /// The pose X Y Z A B (mm, degrees) at joints `q` (mm, degrees), from near
    /// `guess`; `None` out of reach.
    fn at(&self, q: &[f64], guess: &[f64; 5]) -> Option<[f64; 5]> {
        match self {
            Self::Parallel { model, th } => {
                let g = [guess[0], guess[1], guess[2], guess[3], guess[4], 0.0];
                let (_, x0) = model.inverse(th, &g)?;
                let x = forward(model, th, q, &x0)?;
                let m = model.measure(th, &x, q);
                let mut pose = [0.0; 5];
                for (k, &axis) in model.measured_axes().iter().enumerate() {
                    if axis < 5 {
                        pose[axis] = m[k];
                    }
                }
                Some(pose)
            }
            Self::Cartesian(kin, rotary) => {
                let mut joints = [0i64; MAX_JOINTS];
                for (j, v) in q.iter().enumerate().take(MAX_JOINTS) {
                    joints[j] = (v * units_per_user(rotary[j]) as f64).round() as i64;
                }
                let mut at = [0i64; AXES];
                kin.forward_counted(&joints, &[0; AXES], &mut at).ok()?;
                Some(core::array::from_fn(|k| {
                    at[k] as f64 / units_per_user(k >= 3) as f64
                }))
            }
        }
    }
}

/// The nearest point to `y` on the commanded polyline within [`WINDOW`] rows of row
/// `i`: its segment, the fraction along it and the distance, mm. Of points as near
/// (within 1 pm), the one nearest row `i`.
fn nearest(path: &[[f64; 5]], i: usize, y: [f64; 3]) -> (usize, f64, f64) {
    let lo = i.saturating_sub(WINDOW);
    let hi = (i + WINDOW).min(path.len() - 1);
    let mut best = (i, 0.0, f64::INFINITY);
    for k in lo..=hi {
        let (a, b) = (&path[k], &path[(k + 1).min(hi)]);
        let (s, d) = on_segment(&y, &[a[0], a[1], a[2]], &[b[0], b[1], b[2]]);
        // Where the path stands in X Y Z (a turn in place), the row nearest in time.
        let tie = (d - best.2).abs() <= 1e-9 && k.abs_diff(i) < best.0.abs_diff(i);
        if d < best.2 - 1e-9 || tie {
            best = (k, s, d);
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A trace of `rows` (commanded pose, true joints) on a machine of `n` joints.
    fn trace(n: usize, rows: &[([f64; 5], Vec<f64>)]) -> String {
        let mut t = String::from("t_s,line,x,y,z,a,b,c");
        for prefix in ["q", "fb", "tq"] {
            for j in 1..=n {
                t += &format!(",{prefix}{j}");
            }
        }
        t += "\n";
        for (k, (p, q)) in rows.iter().enumerate() {
            t += &format!(
                "{:.6},1,{},{},{},{},{},0",
                (k + 1) as f64 * 1e-3,
                p[0],
                p[1],
                p[2],
                p[3],
                p[4]
            );
            // Commanded, feedback and true joints alike.
            for _ in 0..3 {
                for v in q {
                    t += &format!(",{v:.9}");
                }
            }
            t += "\n";
        }
        t
    }

    #[test]
    fn a_cartesian_tool_off_its_line_is_off_by_that_much_whatever_its_lag() {
        let config = MachineConfig::cartesian_xyz();
        let rows: Vec<_> = (0..20)
            .map(|k| {
                let x = k as f64 * 0.02;
                // 10 µm behind along X, 2 µm off in Y.
                ([x, 0.0, 0.0, 0.0, 0.0], vec![x - 0.01, 0.002, 0.0])
            })
            .collect();
        let e = true_errors(&config, &trace(3, &rows)).unwrap();
        assert_eq!(e.len(), 20);
        for r in &e[1..] {
            assert!((r.path_mm - 0.002).abs() < 1e-9, "{r:?}");
            assert!(r.moving && r.direction_deg == 0.0);
        }
    }

    #[test]
    fn a_hexapod_xy_tool_moved_and_tilted_off_its_path_is_measured_exactly() {
        let config = MachineConfig::hexapod_xy();
        let model = Model::from_config(&config).unwrap();
        let th = model.nominal();
        let rows: Vec<_> = (0..20)
            .map(|k| {
                let x = k as f64 * 0.02;
                // 3 µm off in Y and 2 µ° of B from the commanded pose.
                let (q, _) = model
                    .inverse(&th, &[x, 0.003, 275.0, 0.0, 2e-6, 0.0])
                    .unwrap();
                ([x, 0.0, 275.0, 0.0, 0.0], q)
            })
            .collect();
        let e = true_errors(&config, &trace(8, &rows)).unwrap();
        for r in &e {
            // The joints' 9 decimals (1 pm) bound what is left.
            assert!((r.path_mm - 0.003).abs() < 1e-7, "{r:?}");
            assert!((r.direction_deg - 2e-6).abs() < 2e-8, "{r:?}");
        }
    }

    #[test]
    fn a_trace_without_true_joints_or_with_a_short_row_is_refused_by_name() {
        let config = MachineConfig::cartesian_xyz();
        let old = "t_s,line,x,y,z,a,b,c,q1,q2,q3,fb1,fb2,fb3\n";
        let e = true_errors(&config, old).unwrap_err();
        assert!(e.contains("`tq1`"), "{e}");
        let mut t = trace(3, &[([0.0; 5], vec![0.0; 3])]);
        t += "0.002,1,0,0\n";
        let e = true_errors(&config, &t).unwrap_err();
        assert!(e.contains("trace row 3") && e.contains("4 fields"), "{e}");
    }

    #[test]
    fn the_distance_is_to_the_nearest_segment_and_the_point_along_it() {
        let path = [
            [0.0, 0.0, 0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0, 0.0, 0.0],
            [1.0, 1.0, 0.0, 0.0, 0.0],
        ];
        let (k, s, d) = nearest(&path, 0, [0.25, 0.003, 0.0]);
        assert_eq!(k, 0);
        assert!((s - 0.25).abs() < 1e-12 && (d - 0.003).abs() < 1e-12);
        let (k, s, d) = nearest(&path, 0, [1.004, 0.5, 0.0]);
        assert_eq!(k, 1);
        assert!((s - 0.5).abs() < 1e-12 && (d - 0.004).abs() < 1e-12);
    }
}
