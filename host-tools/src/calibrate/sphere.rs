//! Calibration from probing spheres: every probed point must lie on its sphere.
//!
//! A touch is the joints latched when the probe triggered against one of the
//! spheres. The model's tool tip at those joints ([`Model::measure`]'s X Y Z: the tool
//! tip in workpiece coordinates on the H-4 and the hexapod-xy, the platform's origin
//! on the hexapod) must lie at the sphere's radius plus the probe tip's radius from
//! the sphere's centre. The residual of a touch is that distance minus the model's,
//! divided by the probe's noise along the surface normal. The unknowns are the
//! machine's parameters and each sphere's centre (3 each, appended to the model's
//! parameters as `sphere[k].x` …); the radii are known.
//!
//! No probing sees where the machine stands against the artefact: a rigid motion of
//! the whole mechanism moves every sphere's centre with it. The identifiability
//! analysis finds these combinations and holds a machine parameter of each (the
//! centres are held last: [`super::model::Param::hold_last`]).
#![allow(clippy::needless_range_loop)]

use super::data::{self, Table};
use super::fit::Residual;
use super::forward::{forward, measure_jacobian};
use super::model::{Model, Param};
use crate::control::linalg::{svd, Mat};

/// A sphere of the artefact: its centre (approximate, fitted) and radius (known), mm.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sphere {
    /// Centre, mm, in the frame the machine's poses are programmed in.
    pub centre: [f64; 3],
    /// Radius, mm.
    pub radius: f64,
}

impl Sphere {
    /// Parses `X,Y,Z,R` (mm).
    pub fn parse(text: &str) -> Result<Sphere, String> {
        let v: Vec<f64> = text
            .split(',')
            .map(|f| f.trim().parse::<f64>().ok().filter(|v| v.is_finite()))
            .collect::<Option<_>>()
            .ok_or(format!("`{text}`: a sphere is X,Y,Z,R in mm"))?;
        if v.len() != 4 || v[3] <= 0.0 {
            return Err(format!(
                "`{text}`: a sphere is X,Y,Z,R in mm, with R positive"
            ));
        }
        Ok(Sphere {
            centre: [v[0], v[1], v[2]],
            radius: v[3],
        })
    }

    /// As [`Sphere::parse`] reads it.
    pub fn text(&self) -> String {
        let n = data::format_number;
        format!(
            "{},{},{},{}",
            n(self.centre[0]),
            n(self.centre[1]),
            n(self.centre[2]),
            n(self.radius)
        )
    }
}

/// One touch: the latched joints, the sphere touched, the commanded approach.
#[derive(Clone, Debug)]
pub struct Touch {
    /// Joints at the probe's trigger, mm or degrees.
    pub q: Vec<f64>,
    /// Which sphere (0-based).
    pub sphere: usize,
    /// The commanded approach direction (unit), if given.
    pub approach: Option<[f64; 3]>,
    /// Where forward kinematics starts (the last solution).
    pub guess: Vec<f64>,
}

/// The touches of a probing run against the model with the spheres' centres appended
/// to its parameters ([`extend`]).
pub struct Probing {
    /// The touches.
    pub touches: Vec<Touch>,
    /// Each sphere's radius, mm.
    pub radii: Vec<f64>,
    /// The probe tip's radius, mm.
    pub tip: f64,
    /// The probe's noise along the surface normal, mm.
    pub noise: f64,
    /// The machine's own parameters' count (the spheres' centres come after).
    pub machine_params: usize,
}

/// `model` with the centre of every sphere of `spheres` appended to its parameters
/// (`sphere[k].x/y/z`, nominal at the given centre, held last).
pub fn extend(model: &Model, spheres: &[Sphere]) -> Model {
    let mut m = model.clone();
    for (k, s) in spheres.iter().enumerate() {
        for (i, c) in s.centre.iter().enumerate() {
            m.params.push(Param {
                name: format!("sphere[{k}].{}", ["x", "y", "z"][i]),
                value: *c,
                scale: 0.5,
                hold_first: false,
                hold_last: true,
            });
        }
    }
    m
}

/// The spheres of an extended model's parameters `th` (radii from `radii`).
pub fn spheres_of(th: &[f64], machine_params: usize, radii: &[f64]) -> Vec<Sphere> {
    radii
        .iter()
        .enumerate()
        .map(|(k, r)| {
            let c = &th[machine_params + 3 * k..machine_params + 3 * k + 3];
            Sphere {
                centre: [c[0], c[1], c[2]],
                radius: *r,
            }
        })
        .collect()
}

impl Probing {
    /// Each touch's distance from its sphere's surface (the model's tool tip to the
    /// centre, minus the radius and the tip's), mm; `None` where forward kinematics
    /// fails.
    pub fn gaps(&mut self, model: &Model, th: &[f64]) -> Option<Vec<f64>> {
        let r = self.evaluate(model, th, false)?.0;
        Some(r.iter().map(|v| -v * self.noise).collect())
    }
}

impl Residual for Probing {
    fn evaluate(&mut self, model: &Model, th: &[f64], jacobian: bool) -> Option<(Vec<f64>, Mat)> {
        let m = self.machine_params;
        let machine = &th[..m];
        let (mut r, mut jac) = (Vec::new(), Vec::new());
        let w = 1.0 / self.noise;
        for t in &mut self.touches {
            let x = forward(model, machine, &t.q, &t.guess)?;
            t.guess.clone_from(&x);
            let c = &th[m + 3 * t.sphere..m + 3 * t.sphere + 3];
            let (y, dy) = if jacobian {
                let (y, j) = measure_jacobian(model, machine, &t.q, &x)?;
                (y, Some(j))
            } else {
                (model.measure(machine, &x, &t.q), None)
            };
            let d: Vec<f64> = (0..3).map(|k| y[k] - c[k]).collect();
            let len = d.iter().map(|v| v * v).sum::<f64>().sqrt();
            let u: Vec<f64> = d.iter().map(|v| v / len).collect();
            r.push((self.radii[t.sphere] + self.tip - len) * w);
            if let Some(j) = dy {
                let mut row = vec![0.0; th.len()];
                for p in 0..m {
                    row[p] = (0..3).map(|k| u[k] * j[k][p]).sum::<f64>() * w;
                }
                for k in 0..3 {
                    row[m + 3 * t.sphere + k] = -u[k] * w;
                }
                jac.push(row);
            }
        }
        Some((r, jac))
    }
}

/// RMS and largest absolute value, in µm, of distances in mm.
pub fn rms_max_um(v: &[f64]) -> (f64, f64) {
    let rms = (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt();
    let max = v.iter().fold(0.0f64, |a, x| a.max(x.abs()));
    (rms * 1e3, max * 1e3)
}

/// The spheres and the probe tip's radius a probing file's comments give:
/// `# sphere K = X,Y,Z,R` and `# tip_radius = R`. Errors name file:line:column.
pub fn header(text: &str, origin: &str) -> Result<(Vec<Sphere>, Option<f64>), String> {
    let (mut spheres, mut tip) = (Vec::new(), None);
    for (n, line) in text.lines().enumerate() {
        let Some(body) = line.trim_start().strip_prefix('#') else {
            continue;
        };
        let col = line.len() - body.len() + 1;
        let body_t = body.trim_start();
        let col = col + body.len() - body_t.len();
        let Some((key, value)) = body_t.split_once('=') else {
            continue;
        };
        let at = col + key.len() + 1 + value.len() - value.trim_start().len();
        let place = |e: String| format!("{origin}:{}:{at}: {e}", n + 1);
        let words: Vec<&str> = key.split_whitespace().collect();
        match words.as_slice() {
            ["sphere", k] => {
                let k: usize = k.parse().map_err(|_| {
                    format!(
                        "{origin}:{}:{col}: `sphere {k}`: the sphere's number",
                        n + 1
                    )
                })?;
                if k != spheres.len() {
                    return Err(format!(
                        "{origin}:{}:{col}: sphere {k} where sphere {} was expected",
                        n + 1,
                        spheres.len()
                    ));
                }
                spheres.push(Sphere::parse(value.trim()).map_err(place)?);
            }
            ["tip_radius"] => {
                let v = value.trim().parse::<f64>().ok().filter(|v| *v >= 0.0);
                tip = Some(v.ok_or(place(format!("`{}`: a radius in mm", value.trim())))?);
            }
            _ => {}
        }
    }
    Ok((spheres, tip))
}

/// The touches of a probing table: the joints (`q1…`, or the latched pose `cmd_X…` the
/// nominal inverse kinematics turns back into joints), the sphere's number `sphere`
/// (below `spheres`) and optionally the approach `dir_x dir_y dir_z`.
pub fn touches(t: &Table, model: &Model, spheres: usize) -> Result<Vec<Touch>, String> {
    let sc = t.require("sphere")?;
    let dirs = ["dir_x", "dir_y", "dir_z"].map(|d| t.column(d));
    let dirs = if dirs.iter().all(Option::is_some) {
        Some(dirs.map(Option::unwrap))
    } else if let Some(c) = dirs.iter().flatten().next() {
        return Err(format!(
            "{}: an approach is dir_x, dir_y and dir_z together",
            t.place(0, *c)
        ));
    } else {
        None
    };
    let joints = data::joints(t, model)?;
    let mut out = Vec::new();
    for (r, (q, guess)) in joints.into_iter().enumerate() {
        let s = t.number(r, sc)?;
        if s.fract() != 0.0 || s < 0.0 || s as usize >= spheres {
            return Err(format!(
                "{}: sphere `{s}`: the spheres are 0 to {} (--sphere or `# sphere K = X,Y,Z,R`)",
                t.place(r, sc),
                spheres as i64 - 1
            ));
        }
        let approach = match dirs {
            Some(c) => {
                let v = [t.number(r, c[0])?, t.number(r, c[1])?, t.number(r, c[2])?];
                let n = v.iter().map(|x| x * x).sum::<f64>().sqrt();
                if n < 1e-9 {
                    return Err(format!("{}: the approach is zero", t.place(r, c[0])));
                }
                Some(v.map(|x| x / n))
            }
            None => None,
        };
        out.push(Touch {
            q,
            sphere: s as usize,
            approach,
            guess,
        });
    }
    if out.is_empty() {
        return Err(format!("{}: no touches", t.origin()));
    }
    Ok(out)
}

/// The largest angle, degrees, between a touch's approach and the surface's inward
/// normal where the model puts its tip (a touch listed under the wrong sphere shows
/// here); `None` when no touch carries its approach.
pub fn worst_approach(p: &Probing, model: &Model, th: &[f64]) -> Option<f64> {
    let m = p.machine_params;
    let mut worst: Option<f64> = None;
    for t in &p.touches {
        let Some(a) = t.approach else { continue };
        let y = model.measure(&th[..m], &t.guess, &t.q);
        let c = &th[m + 3 * t.sphere..m + 3 * t.sphere + 3];
        let d: Vec<f64> = (0..3).map(|k| c[k] - y[k]).collect();
        let len = d.iter().map(|v| v * v).sum::<f64>().sqrt();
        let cos = (0..3).map(|k| a[k] * d[k] / len).sum::<f64>();
        let ang = cos.clamp(-1.0, 1.0).acos().to_degrees();
        worst = Some(worst.map_or(ang, |w: f64| w.max(ang)));
    }
    worst
}

/// The rigid motion (rotation matrix, translation) that best carries the points
/// `from` onto `to` (least squares; Horn's quaternion method).
pub fn rigid(from: &[[f64; 3]], to: &[[f64; 3]]) -> ([[f64; 3]; 3], [f64; 3]) {
    let n = from.len().max(1) as f64;
    let mean = |p: &[[f64; 3]]| {
        let mut m = [0.0; 3];
        for v in p {
            for k in 0..3 {
                m[k] += v[k] / n;
            }
        }
        m
    };
    let (ca, cb) = (mean(from), mean(to));
    let mut s = [[0.0; 3]; 3];
    for (a, b) in from.iter().zip(to) {
        for i in 0..3 {
            for j in 0..3 {
                s[i][j] += (a[i] - ca[i]) * (b[j] - cb[j]);
            }
        }
    }
    let nm = [
        [
            s[0][0] + s[1][1] + s[2][2],
            s[1][2] - s[2][1],
            s[2][0] - s[0][2],
            s[0][1] - s[1][0],
        ],
        [
            s[1][2] - s[2][1],
            s[0][0] - s[1][1] - s[2][2],
            s[0][1] + s[1][0],
            s[2][0] + s[0][2],
        ],
        [
            s[2][0] - s[0][2],
            s[0][1] + s[1][0],
            -s[0][0] + s[1][1] - s[2][2],
            s[1][2] + s[2][1],
        ],
        [
            s[0][1] - s[1][0],
            s[2][0] + s[0][2],
            s[1][2] + s[2][1],
            -s[0][0] - s[1][1] + s[2][2],
        ],
    ];
    // The eigenvector of the largest eigenvalue: shifted to positive definite, the
    // largest singular vector.
    let shift: f64 = nm.iter().flatten().map(|v| v.abs()).sum::<f64>() + 1e-12;
    let shifted: Mat = (0..4)
        .map(|i| {
            (0..4)
                .map(|j| nm[i][j] + if i == j { shift } else { 0.0 })
                .collect()
        })
        .collect();
    let (_, v) = svd(&shifted, 4);
    let q = &v[0];
    let (w, x, y, z) = (q[0], q[1], q[2], q[3]);
    let r = [
        [
            w * w + x * x - y * y - z * z,
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            w * w - x * x + y * y - z * z,
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            w * w - x * x - y * y + z * z,
        ],
    ];
    let rc = apply(&r, [0.0; 3], ca);
    (r, [cb[0] - rc[0], cb[1] - rc[1], cb[2] - rc[2]])
}

/// `r·p + t`.
pub fn apply(r: &[[f64; 3]; 3], t: [f64; 3], p: [f64; 3]) -> [f64; 3] {
    let mut o = t;
    for i in 0..3 {
        for j in 0..3 {
            o[i] += r[i][j] * p[j];
        }
    }
    o
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The touch residual's Jacobian (the machine's through forward kinematics, the
    /// centres by hand) against central differences, every parameter, on each kind.
    #[test]
    fn jacobian_matches_finite_differences() {
        for (name, pose, c) in [
            (
                "h4-table",
                [20.0, -15.0, -60.0, 25.0, 0.0, 10.0],
                [25.0, -5.0, -70.0],
            ),
            (
                "hexapod",
                [15.0, -10.0, 470.0, 4.0, -3.0, 6.0],
                [5.0, -12.0, 460.0],
            ),
            (
                "hexapod-xy",
                [30.0, -20.0, 280.0, 5.0, -4.0, 0.0],
                [20.0, -25.0, 270.0],
            ),
        ] {
            let path = format!(
                "{}/../examples/machines/{name}.toml",
                env!("CARGO_MANIFEST_DIR")
            );
            let config = crate::machine_file::load(std::path::Path::new(&path)).unwrap();
            let model = Model::from_config(&config).unwrap();
            let sphere = Sphere {
                centre: c,
                radius: 10.0,
            };
            let ext = extend(&model, &[sphere, sphere]);
            let (q, x) = model.inverse(&model.nominal(), &pose).unwrap();
            let mut p = Probing {
                touches: vec![Touch {
                    q,
                    sphere: 1,
                    approach: None,
                    guess: x,
                }],
                radii: vec![10.0, 10.0],
                tip: 1.0,
                noise: 0.001,
                machine_params: model.params.len(),
            };
            let th = ext.nominal();
            let (_, jac) = p.evaluate(&ext, &th, true).unwrap();
            for j in 0..th.len() {
                let h = 1e-5;
                let (mut tp, mut tm) = (th.clone(), th.clone());
                tp[j] += h;
                tm[j] -= h;
                let rp = p.evaluate(&ext, &tp, false).unwrap().0[0];
                let rm = p.evaluate(&ext, &tm, false).unwrap().0[0];
                // r = (measured − model)/σ: the Jacobian is the model's, −∂r.
                let fd = -(rp - rm) / (2.0 * h);
                let err = (jac[0][j] - fd).abs();
                assert!(
                    err < 1e-3 * (1.0 + fd.abs()),
                    "{name} {}: {} vs {fd}",
                    ext.params[j].name,
                    jac[0][j]
                );
            }
            assert!(jac[0][..3].iter().any(|v| v.abs() > 1.0), "{name}");
        }
    }

    #[test]
    fn rigid_motion_is_recovered() {
        let from = [
            [10.0, 0.0, 0.0],
            [0.0, 20.0, 5.0],
            [-3.0, 4.0, 30.0],
            [7.0, -8.0, 1.0],
        ];
        let (s, c) = 0.3f64.sin_cos();
        let r = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]];
        let t = [1.0, -2.0, 0.5];
        let to: Vec<[f64; 3]> = from.iter().map(|p| apply(&r, t, *p)).collect();
        let (rr, tt) = rigid(&from, &to);
        for (a, b) in from.iter().zip(&to) {
            let m = apply(&rr, tt, *a);
            for k in 0..3 {
                assert!((m[k] - b[k]).abs() < 1e-9, "{m:?} {b:?}");
            }
        }
    }

    #[test]
    fn probing_file_errors_name_file_line_and_column() {
        let e = header("# sphere 0 = 1,2,3\nq1\n", "p.csv").unwrap_err();
        assert!(e.starts_with("p.csv:1:14: `1,2,3`"), "{e}");
        let e = header("# sphere 1 = 1,2,3,4\n", "p.csv").unwrap_err();
        assert!(e.starts_with("p.csv:1:3: sphere 1 where sphere 0"), "{e}");
        let e = header("  # tip_radius =  x\n", "p.csv").unwrap_err();
        assert_eq!(e, "p.csv:1:19: `x`: a radius in mm");
        let (s, tip) = header("# sphere 0 = 1,2,3,4\n# tip_radius = 1.5\n", "p.csv").unwrap();
        assert_eq!(s[0].centre, [1.0, 2.0, 3.0]);
        assert_eq!(tip, Some(1.5));
    }
}
