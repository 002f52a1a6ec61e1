//! Reading what LinuxCNC's standalone interpreter (`rs274 -g`) prints — its canonical
//! machining commands — into machine positions, and comparing them with our canonical
//! commands. Shared by the tests against LinuxCNC's stored expected output
//! (`linuxcnc_tests.rs`) and against a live `rs274` (`rs274_oracle.rs`).
//!
//! Positions are printed in program units and program coordinates: machine position =
//! rotate(value + G92, XY rotation) + G5x + tool offset (LinuxCNC's `emccanon`
//! `rotate_and_offset_pos`), each term × 25.4 when it was printed after
//! `USE_LENGTH_UNITS(CANON_UNITS_INCHES)`. `ARC_FEED(first_end, second_end, c1, c2,
//! rot, axis_end, a, b, c)` is (x, y, z) in XY, (z, x, y) in XZ and (y, z, x) in YZ;
//! its centre (c1, c2) goes through the same transformation (with the end's
//! coordinate along the helix axis).
//!
//! A printed number carries its rounding (4 decimals: half a unit in the last place,
//! 0.05 µm in mm, 1.27 µm in inches) as a tolerance, added to the 1 µm (10⁻⁶° for
//! A B C) every comparison allows.

// Each test file uses its own subset of these helpers.
#![allow(dead_code)]

use pkmc::config::AXES;
use pkmc::units::{NDEG_PER_DEG, NM_PER_MM};
use pkmc_host::gcode::canon::Canon;

/// A value LinuxCNC printed, in mm or degrees, with how far it may be from the exact
/// value through the rounding of what was printed.
#[derive(Clone, Copy, Debug)]
pub struct Approx {
    pub v: f64,
    pub tol: f64,
}

impl Approx {
    pub const ZERO: Approx = Approx { v: 0.0, tol: 0.0 };

    /// Parses a printed number; `scale` converts it to mm (or degrees).
    pub fn parse(text: &str, scale: f64) -> Option<Approx> {
        let t = text.trim();
        let v: f64 = t.parse().ok()?;
        let decimals = t.split_once('.').map_or(0, |(_, f)| f.len()) as i32;
        Some(Approx {
            v: v * scale,
            tol: 0.5 * 10f64.powi(-decimals) * scale,
        })
    }

    pub fn add(self, o: Approx) -> Approx {
        Approx {
            v: self.v + o.v,
            tol: self.tol + o.tol,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    Traverse,
    Feed,
    Arc,
}

/// One move of the reference: its kind, machine end pose, and where it was printed.
pub struct RefMove {
    pub kind: Kind,
    pub end: [Approx; AXES],
    /// An arc's centre in machine coordinates, in the plane's axes (first, second).
    pub center: Option<[Approx; 2]>,
    pub line: usize,
    pub text: String,
}

/// One run of `rs274` as read from its printed trace.
#[derive(Default)]
pub struct Run {
    pub moves: Vec<RefMove>,
    /// It ended with PROGRAM_END or FINISH (otherwise the interpreter stopped on an
    /// error).
    pub completed: bool,
    /// Motion we have no counterpart for (RIGID_TAP, STRAIGHT_PROBE, …), first one.
    pub other_motion: Option<String>,
    /// Operator messages (MESSAGE: MSG and DEBUG comments), text and trace line.
    pub messages: Vec<(String, usize)>,
    /// The test's script kept only its messages: the moves are not known.
    pub moves_filtered: bool,
}

/// State of LinuxCNC's canon while reading a trace.
pub struct CanonState {
    pub scale: f64,
    g5x: [Approx; AXES],
    g92: [Approx; AXES],
    pub tool: [Approx; AXES],
    pub rotation: Approx,
    pub plane: u8,
}

impl Default for CanonState {
    fn default() -> Self {
        CanonState {
            scale: 1.0,
            g5x: [Approx::ZERO; AXES],
            g92: [Approx::ZERO; AXES],
            tool: [Approx::ZERO; AXES],
            rotation: Approx::ZERO,
            plane: 17,
        }
    }
}

impl CanonState {
    /// Axis values printed in program units (X Y Z scaled, A B C as they are).
    fn axes(&self, vals: &[&str]) -> Option<[Approx; AXES]> {
        let mut out = [Approx::ZERO; AXES];
        for (i, o) in out.iter_mut().enumerate() {
            let scale = if i < 3 { self.scale } else { 1.0 };
            *o = Approx::parse(vals.get(i)?, scale)?;
        }
        Some(out)
    }

    /// Program position to machine position (`emccanon`'s `rotate_and_offset_pos`).
    fn machine(&self, p: [Approx; AXES]) -> [Approx; AXES] {
        let mut q: [Approx; AXES] = std::array::from_fn(|i| p[i].add(self.g92[i]));
        if self.rotation.v != 0.0 {
            let t = self.rotation.v.to_radians();
            let (s, c) = t.sin_cos();
            let (x, y) = (q[0], q[1]);
            let r = x.v.hypot(y.v);
            let tol = x.tol + y.tol + r * self.rotation.tol.to_radians();
            q[0] = Approx {
                v: x.v * c - y.v * s,
                tol,
            };
            q[1] = Approx {
                v: x.v * s + y.v * c,
                tol,
            };
        }
        std::array::from_fn(|i| q[i].add(self.g5x[i]).add(self.tool[i]))
    }
}

/// The call and its arguments of one printed line (` N..... NAME(args)`, possibly with
/// a line counter before it); `None` for other lines (error text, PRINT output).
pub fn call(line: &str) -> Option<(&str, &str)> {
    let mut rest = line.trim_start();
    if let Some(after) = rest.strip_prefix(|c: char| c.is_ascii_digit()) {
        let after = after.trim_start_matches(|c: char| c.is_ascii_digit());
        rest = after.strip_prefix(' ')?.trim_start();
    }
    let rest = rest.strip_prefix('N')?;
    let (n, rest) = rest.split_once(' ')?;
    if !n.chars().all(|c| c == '.' || c.is_ascii_digit()) {
        return None;
    }
    let rest = rest.trim_start();
    let open = rest.find('(')?;
    let name = &rest[..open];
    if name.is_empty()
        || !name
            .chars()
            .all(|c| c.is_ascii_uppercase() || c == '_' || c == '.' || c.is_ascii_digit())
    {
        return None;
    }
    let args = rest[open + 1..].trim_end().strip_suffix(')')?;
    Some((name, args))
}

/// The runs in a trace file (a new run starts at each `USE_LENGTH_UNITS` that follows
/// the end of a run); a file of messages only (a test script that keeps only them, and
/// fails when the program does) is one completed run whose moves are unknown; `None`
/// when the file is neither.
pub fn read_trace(text: &str) -> Option<Vec<Run>> {
    let mut runs: Vec<Run> = Vec::new();
    let mut st = CanonState::default();
    let mut seen_units = false;
    let mut loose_messages = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let Some((name, args)) = call(line) else {
            continue;
        };
        if name == "MESSAGE" {
            let message = args.trim().trim_matches('"').trim().to_string();
            match runs.last_mut() {
                Some(run) => run.messages.push((message, n + 1)),
                None => loose_messages.push((message, n + 1)),
            }
            continue;
        }
        let list: Vec<&str> = args.split(',').map(str::trim).collect();
        if name == "USE_LENGTH_UNITS" {
            if !seen_units || runs.last().is_some_and(|r| r.completed) {
                runs.push(Run::default());
                st = CanonState::default();
            }
            seen_units = true;
        }
        let Some(run) = runs.last_mut() else {
            continue;
        };
        match name {
            "USE_LENGTH_UNITS" => {
                st.scale = match args {
                    "CANON_UNITS_INCHES" => 25.4,
                    "CANON_UNITS_MM" => 1.0,
                    "CANON_UNITS_CM" => 10.0,
                    _ => unreadable(n, line),
                }
            }
            "SET_G5X_OFFSET" => st.g5x = st.axes(&list[1..]).unwrap_or_else(|| unreadable(n, line)),
            "SET_G92_OFFSET" => st.g92 = st.axes(&list).unwrap_or_else(|| unreadable(n, line)),
            "SET_XY_ROTATION" => {
                st.rotation = Approx::parse(args, 1.0).unwrap_or_else(|| unreadable(n, line))
            }
            "USE_TOOL_LENGTH_OFFSET" => {
                // `x y z, a b c, u v w`
                let v: Vec<&str> = args.split([',', ' ']).filter(|s| !s.is_empty()).collect();
                st.tool = st.axes(&v).unwrap_or_else(|| unreadable(n, line));
            }
            "SELECT_PLANE" => {
                st.plane = match args {
                    "CANON_PLANE_XY" => 17,
                    "CANON_PLANE_XZ" => 18,
                    "CANON_PLANE_YZ" => 19,
                    _ => 0, // UV, UW, VW: no counterpart
                }
            }
            "STRAIGHT_TRAVERSE" | "STRAIGHT_FEED" => {
                let p = st.axes(&list).unwrap_or_else(|| unreadable(n, line));
                run.moves.push(RefMove {
                    kind: if name == "STRAIGHT_FEED" {
                        Kind::Feed
                    } else {
                        Kind::Traverse
                    },
                    end: st.machine(p),
                    center: None,
                    line: n + 1,
                    text: line.trim().to_string(),
                });
            }
            "ARC_FEED" => {
                // first_end, second_end, c1, c2, rot, axis_end, a, b, c
                let (first, second, axis) = match st.plane {
                    17 => (0, 1, 2),
                    18 => (2, 0, 1),
                    19 => (1, 2, 0),
                    _ => {
                        run.other_motion.get_or_insert(line.trim().to_string());
                        continue;
                    }
                };
                let mut p = [Approx::ZERO; AXES];
                for (slot, arg) in [(first, 0), (second, 1), (axis, 5)] {
                    p[slot] = Approx::parse(
                        list.get(arg)
                            .copied()
                            .unwrap_or_else(|| unreadable(n, line)),
                        st.scale,
                    )
                    .unwrap_or_else(|| unreadable(n, line));
                }
                for (i, slot) in p.iter_mut().enumerate().skip(3) {
                    *slot = Approx::parse(
                        list.get(i + 3)
                            .copied()
                            .unwrap_or_else(|| unreadable(n, line)),
                        1.0,
                    )
                    .unwrap_or_else(|| unreadable(n, line));
                }
                // The centre: the end with its in-plane coordinates replaced.
                let mut c = p;
                for (slot, arg) in [(first, 2), (second, 3)] {
                    c[slot] = Approx::parse(
                        list.get(arg)
                            .copied()
                            .unwrap_or_else(|| unreadable(n, line)),
                        st.scale,
                    )
                    .unwrap_or_else(|| unreadable(n, line));
                }
                let c = st.machine(c);
                run.moves.push(RefMove {
                    kind: Kind::Arc,
                    end: st.machine(p),
                    center: Some([c[first], c[second]]),
                    line: n + 1,
                    text: line.trim().to_string(),
                });
            }
            "STRAIGHT_PROBE" | "RIGID_TAP" | "NURBS_FEED" | "SPLINE_FEED" | "NURBS_G5_FEED"
            | "NURBS_G6_FEED" => {
                run.other_motion.get_or_insert(line.trim().to_string());
            }
            "PROGRAM_END" | "FINISH" => run.completed = true,
            _ => {}
        }
    }
    if !seen_units && !loose_messages.is_empty() {
        return Some(vec![Run {
            completed: true,
            messages: loose_messages,
            moves_filtered: true,
            ..Run::default()
        }]);
    }
    seen_units.then_some(runs)
}

pub fn unreadable<T>(n: usize, line: &str) -> T {
    panic!("trace line {}: cannot read {line:?}", n + 1)
}

/// One of our moves.
pub struct OurMove {
    pub kind: Kind,
    pub end: [i64; AXES],
    /// An arc's centre, in the plane's axes (first, second), nm.
    pub center: Option<[i64; 2]>,
    pub line: u32,
}

pub fn our_moves(canon: &[Canon]) -> Vec<OurMove> {
    canon
        .iter()
        .filter_map(|c| {
            let kind = match c {
                Canon::Rapid { .. } => Kind::Traverse,
                Canon::Linear { .. } => Kind::Feed,
                Canon::Arc { .. } => Kind::Arc,
                // LinuxCNC prints G5/G5.1 as NURBS_G5_FEED, a run the reader does not
                // compare (`other_motion`); no test of the corpus has one.
                Canon::Cubic { .. } | Canon::Quadratic { .. } => return None,
                _ => return None,
            };
            let center = match c {
                Canon::Arc { center, .. } => Some(*center),
                _ => None,
            };
            Some(OurMove {
                kind,
                end: *c.target()?,
                center,
                line: c.line(),
            })
        })
        .collect()
}

pub fn pose_text(p: &[i64; AXES]) -> String {
    let mm = NM_PER_MM as f64;
    let deg = NDEG_PER_DEG as f64;
    format!(
        "X{:.6} Y{:.6} Z{:.6} A{:.6} B{:.6} C{:.6}",
        p[0] as f64 / mm,
        p[1] as f64 / mm,
        p[2] as f64 / mm,
        p[3] as f64 / deg,
        p[4] as f64 / deg,
        p[5] as f64 / deg
    )
}

pub fn ref_text(p: &[Approx; AXES]) -> String {
    format!(
        "X{:.6} Y{:.6} Z{:.6} A{:.6} B{:.6} C{:.6}",
        p[0].v, p[1].v, p[2].v, p[3].v, p[4].v, p[5].v
    )
}

/// The first axis where `ours` is off `reference` by more than 1 µm / 10⁻⁶° plus the
/// reference's printing precision.
pub fn off(ours: &[i64; AXES], reference: &[Approx; AXES]) -> Option<String> {
    for i in 0..AXES {
        let (unit, margin) = if i < 3 {
            (NM_PER_MM as f64, 1e-3)
        } else {
            (NDEG_PER_DEG as f64, 1e-6)
        };
        let v = ours[i] as f64 / unit;
        let d = (v - reference[i].v).abs();
        if d > margin + reference[i].tol {
            return Some(format!(
                "{} differs by {d:.6} (allowed {:.6})",
                ["X", "Y", "Z", "A", "B", "C"][i],
                margin + reference[i].tol
            ));
        }
    }
    None
}

/// Compares our messages (`(MSG, …)`, `(DEBUG, …)`) with a reference run's, in order
/// (runs of blanks count as one): `None` when they agree.
pub fn compare_messages(ours: &[&str], run: &Run) -> Option<String> {
    for (k, (o, (r, line))) in ours.iter().zip(&run.messages).enumerate() {
        // The tests' scripts pass the trace through awk, which joins words with one
        // blank.
        let words = |t: &str| t.split_whitespace().collect::<Vec<_>>().join(" ");
        if words(o) != words(r) {
            return Some(format!(
                "message {}: ours `{o}`, LinuxCNC (trace line {line}) `{r}`",
                k + 1
            ));
        }
    }
    (ours.len() != run.messages.len())
        .then(|| format!("{} messages, LinuxCNC {}", ours.len(), run.messages.len()))
}

/// How far our arc's centre is off LinuxCNC's, when more than 1 µm plus the
/// printout's rounding.
fn off_centre(ours: Option<[i64; 2]>, reference: Option<[Approx; 2]>) -> Option<String> {
    let (ours, reference) = (ours?, reference?);
    for k in 0..2 {
        let v = ours[k] as f64 / NM_PER_MM as f64;
        let d = (v - reference[k].v).abs();
        if d > 1e-3 + reference[k].tol {
            return Some(format!(
                "centre ({:.6}, {:.6}) where LinuxCNC has ({:.6}, {:.6}): its {} coordinate \
                 differs by {d:.6} (allowed {:.6})",
                ours[0] as f64 / NM_PER_MM as f64,
                ours[1] as f64 / NM_PER_MM as f64,
                reference[0].v,
                reference[1].v,
                ["first", "second"][k],
                1e-3 + reference[k].tol
            ));
        }
    }
    None
}

/// Compares our moves with one reference run: `None` when they agree.
pub fn compare(ours: &[OurMove], run: &Run) -> Option<String> {
    if run.moves_filtered {
        return None;
    }
    if let Some(m) = &run.other_motion {
        return Some(format!(
            "LinuxCNC moves with `{m}`, which we have no counterpart for"
        ));
    }
    for (k, (o, r)) in ours.iter().zip(&run.moves).enumerate() {
        let what = if o.kind != r.kind {
            Some(format!("{:?} where LinuxCNC has {:?}", o.kind, r.kind))
        } else {
            off(&o.end, &r.end).or_else(|| off_centre(o.center, r.center))
        };
        if let Some(what) = what {
            return Some(format!(
                "move {} (our NC line {}): ours {:?} to {}, LinuxCNC (trace line {}: `{}`) to {}: {what}",
                k + 1,
                o.line,
                o.kind,
                pose_text(&o.end),
                r.line,
                r.text,
                ref_text(&r.end)
            ));
        }
    }
    if ours.len() != run.moves.len() {
        let k = ours.len().min(run.moves.len());
        return Some(match (ours.get(k), run.moves.get(k)) {
            (Some(o), _) => format!(
                "{} moves, LinuxCNC {}: our move {} (NC line {}, {:?} to {}) is extra",
                ours.len(),
                run.moves.len(),
                k + 1,
                o.line,
                o.kind,
                pose_text(&o.end)
            ),
            (_, Some(r)) => format!(
                "{} moves, LinuxCNC {}: its move {} (trace line {}: `{}`) is missing",
                ours.len(),
                run.moves.len(),
                k + 1,
                r.line,
                r.text
            ),
            _ => unreachable!(),
        });
    }
    // Final position (also where neither side moved: the start, 0).
    let ours_final = ours.last().map_or([0; AXES], |m| m.end);
    let ref_final = run.moves.last().map_or([Approx::ZERO; AXES], |m| m.end);
    off(&ours_final, &ref_final).map(|what| format!("final position: {what}"))
}

/// Every file under `dir`, in name order, recursively (`ext`: only those with that
/// extension).
pub fn files_under(dir: &std::path::Path, ext: Option<&str>, out: &mut Vec<std::path::PathBuf>) {
    let mut entries: Vec<std::path::PathBuf> = std::fs::read_dir(dir)
        .expect("corpus folder readable")
        .map(|e| e.expect("corpus entry").path())
        .collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            files_under(&p, ext, out);
        } else if ext.is_none_or(|x| p.extension().is_some_and(|e| e == x)) {
            out.push(p);
        }
    }
}
