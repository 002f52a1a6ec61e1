//! Cutter radius compensation, by its defining property: on an outline the tool can
//! follow without gouging, the compensated path keeps the tool centre exactly one tool
//! radius from the part everywhere (never closer: no gouge; never farther: no corner
//! left uncut).
//!
//! Random parts, each cut outside with G41, clockwise:
//! - convex outlines: vertices on a circle, each edge a straight line or an arc of that
//!   circle (G2), so corners are convex (corner arcs) or tangent (nothing);
//! - rectangles with a rectangular notch wider than the tool and deeper than its radius
//!   (concave corners: the moves are cut back where the offset lines meet).
//!
//! Every compensated move between the entry and the exit is sampled (lines at 9
//! points, arcs at 17), and each sample's distance to the part's outline must be the
//! tool radius within [`TOLERANCE_NM`], except that a join turning by less than
//! LinuxCNC's 0.05 rad counts as tangent (no corner arc, no cut-back, as there), which
//! may bring the tool closer by up to r·(1 − cos 0.05) ≈ 0.00125·r (7.5 µm for a 12 mm
//! tool). Every compensated program must compile.
//!
//! And compensation commutes with the G10 L2 R rotation of the coordinate system: a
//! part cut in a system turned by 37° is the unturned cut, turned.

use pkmc_host::gcode::canon::Canon;
use pkmc_host::gcode::{compile_canon, Options};
use proptest::prelude::*;
use std::f64::consts::TAU;

/// How far a sample may be from one radius off the part, nm: the end points and
/// centres are rounded to 1 nm.
const TOLERANCE_NM: f64 = 10.0;

/// The join angle below which a corner is tangent, rad (LinuxCNC's
/// `TOLERANCE_CONCAVE_CORNER`).
const TANGENT_RAD: f64 = 0.05;

/// A piece of the part's outline, nm.
#[derive(Clone, Copy, Debug)]
enum Edge {
    Line([f64; 2], [f64; 2]),
    /// Clockwise arc about the origin of radius `r` from angle `from` to `to`.
    Arc {
        r: f64,
        from: f64,
        to: f64,
    },
}

fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

fn to_segment(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let len2 = dx * dx + dy * dy;
    let t = (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / len2).clamp(0.0, 1.0);
    dist(p, [a[0] + t * dx, a[1] + t * dy])
}

/// Clockwise sweep from angle `from` to angle `to`, in (0, 2π].
fn cw_sweep(from: f64, to: f64) -> f64 {
    let s = (from - to).rem_euclid(TAU);
    if s == 0.0 {
        TAU
    } else {
        s
    }
}

impl Edge {
    fn distance(&self, p: [f64; 2]) -> f64 {
        match *self {
            Edge::Line(a, b) => to_segment(p, a, b),
            Edge::Arc { r, from, to } => {
                let at = |a: f64| [r * a.cos(), r * a.sin()];
                let angle = p[1].atan2(p[0]);
                if cw_sweep(from, angle) <= cw_sweep(from, to) {
                    (p[0].hypot(p[1]) - r).abs()
                } else {
                    dist(p, at(from)).min(dist(p, at(to)))
                }
            }
        }
    }
}

/// The part, its program (`G41 D1` with tool 1 of diameter `2·tool`), and the lines
/// whose moves must stay one radius off it.
struct Case {
    edges: Vec<Edge>,
    program: String,
    lines: std::ops::RangeInclusive<u32>,
    tool_nm: f64,
}

fn mm(v: f64) -> String {
    format!("{:.6}", v / 1e6)
}

/// The program cutting `outline` (start vertex, then each next vertex with its G code
/// and, for arcs, its centre offset), entering from `start`.
fn program(start: [f64; 2], first: [f64; 2], moves: &[String], tool_nm: f64) -> (String, u32) {
    let mut p = format!(
        "G21 G17 G90 G94 F600\nG10 L1 P1 R{}\nT1 M6\nG0 X{} Y{} Z-1\nG41 D1 G1 X{} Y{}\n",
        mm(tool_nm),
        mm(start[0]),
        mm(start[1]),
        mm(first[0]),
        mm(first[1])
    );
    for m in moves {
        p.push_str(m);
        p.push('\n');
    }
    // Lines 1–5 are the set-up and the entry; the outline is lines 6 to 5 + moves.
    let last = 5 + moves.len() as u32;
    p.push_str(&format!("G40 G1 X{} Y{}\nM2\n", mm(start[0]), mm(start[1])));
    (p, last)
}

fn convex_case(angles: &[f64], arcs: &[bool], radius_mm: f64, tool_mm: f64) -> Case {
    let r = radius_mm * 1e6;
    let mut a: Vec<f64> = angles.to_vec();
    // Clockwise: decreasing angles.
    a.sort_by(|x, y| y.partial_cmp(x).unwrap());
    let v: Vec<[f64; 2]> = a.iter().map(|t| [r * t.cos(), r * t.sin()]).collect();
    let n = v.len();
    let mut edges = Vec::new();
    let mut moves = Vec::new();
    // The outline closes, then goes on along the first edge again so the closing
    // corner is joined too; the extra edge's move is the exit's held move.
    for k in 0..=n {
        let (i, j) = (k % n, (k + 1) % n);
        let arc = arcs[i % arcs.len()];
        if arc {
            edges.push(Edge::Arc {
                r,
                from: a[i],
                to: a[j],
            });
            moves.push(format!(
                "G2 X{} Y{} I{} J{}",
                mm(v[j][0]),
                mm(v[j][1]),
                mm(-v[i][0]),
                mm(-v[i][1])
            ));
        } else {
            edges.push(Edge::Line(v[i], v[j]));
            moves.push(format!("G1 X{} Y{}", mm(v[j][0]), mm(v[j][1])));
        }
    }
    // Enter along the first edge's line, from 20 mm before its start (outside the
    // part, which is convex): the entry joins the outline tangentially.
    let (dx, dy) = (v[1][0] - v[0][0], v[1][1] - v[0][1]);
    let len = dx.hypot(dy);
    let start = [v[0][0] - 20e6 * dx / len, v[0][1] - 20e6 * dy / len];
    let tool_nm = tool_mm * 1e6;
    let (program, last) = program(start, v[0], &moves, tool_nm);
    // The last edge (the first again) ends where the exit leaves: not checked.
    Case {
        edges,
        program,
        lines: 6..=last - 1,
        tool_nm,
    }
}

fn notch_case(w: f64, h: f64, notch: [f64; 3], tool_mm: f64) -> Case {
    let s = 1e6;
    // Clockwise from the bottom left corner: up, right, down the right side, then the
    // bottom with a notch (x0..x1, depth d) cut up into the part.
    let (x0, x1, d) = (notch[0] * s, notch[1] * s, notch[2] * s);
    let (w, h) = (w * s, h * s);
    let v = [
        [0.0, 0.0],
        [0.0, h],
        [w, h],
        [w, 0.0],
        [x1, 0.0],
        [x1, d],
        [x0, d],
        [x0, 0.0],
        [0.0, 0.0],
        [0.0, h],
    ];
    let edges: Vec<Edge> = v.windows(2).map(|p| Edge::Line(p[0], p[1])).collect();
    let moves: Vec<String> = v[1..]
        .iter()
        .map(|p| format!("G1 X{} Y{}", mm(p[0]), mm(p[1])))
        .collect();
    let tool_nm = tool_mm * 1e6;
    let (program, last) = program([-20.0 * s, -20.0 * s], v[0], &moves, tool_nm);
    Case {
        edges,
        program,
        lines: 6..=last - 1,
        tool_nm,
    }
}

/// Samples of every move of lines `lines`, from the end of the move before each.
fn samples(canon: &[Canon], lines: &std::ops::RangeInclusive<u32>) -> Vec<([f64; 2], u32)> {
    let mut out = Vec::new();
    let mut at = [0.0f64; 2];
    for c in canon {
        let Some(t) = c.target() else { continue };
        let end = [t[0] as f64, t[1] as f64];
        if lines.contains(&c.line()) {
            match c {
                Canon::Arc {
                    center, clockwise, ..
                } => {
                    let cc = [center[0] as f64, center[1] as f64];
                    let radius = dist(at, cc);
                    let a0 = (at[1] - cc[1]).atan2(at[0] - cc[0]);
                    let a1 = (end[1] - cc[1]).atan2(end[0] - cc[0]);
                    let sweep = if *clockwise {
                        -cw_sweep(a0, a1)
                    } else {
                        cw_sweep(a1, a0)
                    };
                    for k in 0..=16 {
                        let a = a0 + sweep * f64::from(k) / 16.0;
                        out.push((
                            [cc[0] + radius * a.cos(), cc[1] + radius * a.sin()],
                            c.line(),
                        ));
                    }
                }
                _ => {
                    for k in 0..=8 {
                        let t = f64::from(k) / 8.0;
                        let p = [at[0] + t * (end[0] - at[0]), at[1] + t * (end[1] - at[1])];
                        out.push((p, c.line()));
                    }
                }
            }
        }
        at = end;
    }
    out
}

fn check(case: &Case) -> Result<(), TestCaseError> {
    let canon = compile_canon(&case.program, "comp.ngc", &Options::default())
        .map_err(|e| TestCaseError::fail(format!("{}\n{}", e[0], case.program)))?;
    let pts = samples(&canon, &case.lines);
    prop_assert!(!pts.is_empty());
    for (p, line) in pts {
        let d = case
            .edges
            .iter()
            .map(|e| e.distance(p))
            .fold(f64::INFINITY, f64::min);
        let closest = case.tool_nm * TANGENT_RAD.cos() - TOLERANCE_NM;
        prop_assert!(
            d >= closest && d <= case.tool_nm + TOLERANCE_NM,
            "line {line}: the tool centre at ({:.6}, {:.6}) mm is {:.6} mm from the part, \
             not the radius {:.6} mm\n{}",
            p[0] / 1e6,
            p[1] / 1e6,
            d / 1e6,
            case.tool_nm / 1e6,
            case.program
        );
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: 96,
        rng_seed: if std::env::var_os("CI").is_some() {
            proptest::test_runner::RngSeed::Fixed(0x41)
        } else {
            proptest::test_runner::RngSeed::Random
        },
        ..ProptestConfig::default()
    })]

    #[test]
    fn on_convex_outlines_the_tool_centre_stays_one_radius_off_the_part(
        n in 3usize..9,
        seed_angles in proptest::collection::vec(0.0f64..1.0, 9),
        arcs in proptest::collection::vec(any::<bool>(), 9),
        radius_mm in 10.0f64..80.0,
        tool_mm in 0.5f64..6.0,
    ) {
        // n vertices at least 15° apart: cumulative gaps, scaled round the circle.
        let gaps: Vec<f64> = seed_angles[..n].iter().map(|g| 0.3 + g).collect();
        let total: f64 = gaps.iter().sum();
        let mut t = 0.0;
        let angles: Vec<f64> = gaps.iter().map(|g| { t += g / total * TAU; t }).collect();
        prop_assume!(gaps.iter().all(|g| g / total * TAU > 15f64.to_radians()));
        check(&convex_case(&angles, &arcs, radius_mm, tool_mm))?;
    }

    #[test]
    fn in_a_notch_wider_than_the_tool_the_inside_corners_are_cut_back_exactly(
        w in 60.0f64..120.0,
        h in 20.0f64..60.0,
        x0 in 10.0f64..30.0,
        width in 0.0f64..20.0,
        d in 3.0f64..15.0,
        tool_mm in 0.5f64..4.0,
    ) {
        let x1 = x0 + 2.0 * tool_mm + 1.0 + width;
        // Deeper than the radius: a shallower notch's walls are shorter than the
        // cut-back their corners need (an error, tested by the fixtures).
        prop_assume!(x1 < w - 10.0 && d > tool_mm + 0.5 && d < h - 2.0 * tool_mm - 1.0);
        check(&notch_case(w, h, [x0, x1, d], tool_mm))?;
    }
}

/// A part of lines and arcs with convex and concave corners, cut with G41 (the
/// fixture's outline); `{rot}` is the rotation of G54.
const OUTLINE: &str = "G21 G17 G90 G94 F300\nG10 L1 P1 R3\nT1 M6\nG10 L2 P1 R{rot}\n\
    G0 X-10 Y-10 Z5\nG1 Z-1\nG41 D1 G1 X0 Y0\nY20\nX30\nG2 X40 Y10 R10\nG1 Y0\nX20\nY5\n\
    X10\nY0\nX0\nG40\nG1 X-10 Y-10\nM2\n";

#[test]
fn compensation_in_a_rotated_coordinate_system_is_the_rotated_compensation() {
    let compile = |rot: f64| {
        let text = OUTLINE.replace("{rot}", &rot.to_string());
        compile_canon(&text, "rot.ngc", &Options::default()).expect("compiles")
    };
    let (plain, turned) = (compile(0.0), compile(37.0));
    assert_eq!(plain.len(), turned.len());
    let (s, c) = 37f64.to_radians().sin_cos();
    let rot = |x: i64, y: i64| {
        let (x, y) = (x as f64, y as f64);
        [c * x - s * y, s * x + c * y]
    };
    let mut compared = 0;
    for (a, b) in plain.iter().zip(&turned) {
        let (Some(ta), Some(tb)) = (a.target(), b.target()) else {
            continue;
        };
        let want = rot(ta[0], ta[1]);
        for k in 0..2 {
            assert!(
                (want[k] - tb[k] as f64).abs() <= 2.0,
                "line {}: {:?} turned is {want:?}, got {:?}",
                a.line(),
                &ta[..2],
                &tb[..2]
            );
        }
        assert_eq!(ta[2], tb[2]);
        if let (Canon::Arc { center: ca, .. }, Canon::Arc { center: cb, .. }) = (a, b) {
            let want = rot(ca[0], ca[1]);
            assert!((want[0] - cb[0] as f64).abs() <= 2.0 && (want[1] - cb[1] as f64).abs() <= 2.0);
        }
        compared += 1;
    }
    assert!(compared > 15, "{compared} moves compared");
}
