//! LinuxCNC's own interpreter tests (`shared/corpus/linuxcnc-tests`, beside the
//! repository, read in place; skipped with a note when absent) run through our front
//! end and compared with LinuxCNC's expected canonical output.
//!
//! Each test is one program and what LinuxCNC's `rs274 -g` printed for it (`expected`,
//! `*.ngc.expected`, `rs274.res`), or a program of `interp/bad/`, which LinuxCNC must
//! refuse (its `test.sh` there fails when the interpreter accepts one). A test is:
//!
//! - **pass**: we compile it, and every move end point (STRAIGHT_TRAVERSE, STRAIGHT_FEED,
//!   ARC_FEED, in order, of the same kind) and the final position equal LinuxCNC's
//!   within 1 µm (X Y Z) or 10⁻⁶° (A B C), plus the rounding of the numbers LinuxCNC
//!   printed (4 decimals of program units: half a unit in the last printed place of each
//!   term, so 1.27 µm per term in inches);
//! - **refused by name**: our first diagnostic starts `unsupported: ` (a legal LinuxCNC
//!   feature the front end does not implement);
//! - **expected error**: LinuxCNC fails on the program (an `interp/bad/` program, or an
//!   expected trace that stops without PROGRAM_END or FINISH) and so do we;
//! - **mismatch** (anything else): a defect. The test fails when there is one.
//!
//! Reading the expected output (the corpus README): positions are in program units and
//! program coordinates; machine position = rotate(value + G92, XY rotation) + G5x +
//! tool offset (LinuxCNC's `emccanon` `rotate_and_offset_pos`), each term × 25.4 when it
//! was printed after `USE_LENGTH_UNITS(CANON_UNITS_INCHES)`. `ARC_FEED(first_end,
//! second_end, c1, c2, rot, axis_end, a, b, c)` is (x, y, z) in XY, (z, x, y) in XZ and
//! (y, z, x) in YZ. The programs run on a six-axis Cartesian machine with ±1000 mm of
//! travel (`machine`), starting at 0, with tools 1–99 in the table at zero length
//! (LinuxCNC's tests bring their own tool tables, which the corpus omits; every
//! USE_TOOL_LENGTH_OFFSET before a G10 L1/L10/L11 in the expected output is zero) and
//! the diameters of the cutter compensation tests' table (`TEST_TBL_DIAMETERS_MM`).
//!
//! `cargo test -p pkmc-host --test linuxcnc_tests -- --nocapture` prints the table that
//! `docs/gcode.md` ("LinuxCNC's interpreter tests") holds.

use pkmc::config::{
    Drive, Homing, JointConfig, KinematicsConfig, Limits, MachineConfig, Scale, AXES,
};
use pkmc::units::{NDEG_PER_DEG, NM_PER_MM};
use pkmc_host::gcode::canon::Canon;
use pkmc_host::gcode::{compile_canon, Diagnostic, Options, ToolTable, UNSUPPORTED};
use pkmc_host::job::machine_axes;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

fn corpus() -> Option<PathBuf> {
    let dir = PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../shared/corpus/linuxcnc-tests"
    ));
    dir.is_dir().then_some(dir)
}

/// A six-axis Cartesian machine with the travel LinuxCNC's tests need (they move up to
/// 812 mm): X Y Z ±1000 mm, A B C ±100 000°.
fn machine() -> MachineConfig {
    let mm = NM_PER_MM;
    let deg = NDEG_PER_DEG;
    let mut m = MachineConfig::cartesian_xyz();
    for j in m.joints.iter_mut() {
        j.min = -1000 * mm;
        j.max = 1000 * mm;
        j.homing.switch_at = j.max;
    }
    let rotary = Limits {
        max_velocity: 360 * deg,
        max_accel: 3600 * deg,
    };
    let template = m.joints[0];
    for c in 3..6u8 {
        let joint = JointConfig {
            drive: match template.drive {
                Drive::Stepper {
                    timing, invert_dir, ..
                } => Drive::Stepper {
                    channel: c,
                    timing,
                    invert_dir,
                },
                other => other,
            },
            scale: Scale::new(50, deg as u64),
            rotary: true,
            min: -100_000 * deg,
            max: 100_000 * deg,
            limits: rotary,
            homing: Homing {
                switch_at: 100_000 * deg,
                search_velocity: 20 * deg,
                latch_velocity: deg,
                use_index: false,
            },
        };
        m.joints.push(joint).expect("room for six joints");
    }
    if let KinematicsConfig::Cartesian { axis_of_joint } = &mut m.kinematics {
        axis_of_joint[..6].copy_from_slice(&[0, 1, 2, 3, 4, 5]);
    }
    m.axes[3..].fill(rotary);
    m
}

/// Tool diameters of the tool table LinuxCNC's cutter compensation tests use
/// (`tests/ccomp/*/test.tbl` and `tests/interp/cam-nisley/test.tbl`: T1 D0.0625,
/// T2 D0.125, T3 D0.25, T4 D1.0, in inches, the standalone interpreter's units), mm.
const TEST_TBL_DIAMETERS_MM: [(u32, f64); 4] = [(1, 1.5875), (2, 3.175), (3, 6.35), (4, 25.4)];

fn options(machine: &MachineConfig) -> Options {
    let diameter = |t: u32| {
        TEST_TBL_DIAMETERS_MM
            .iter()
            .find(|(n, _)| *n == t)
            .map_or(0.0, |(_, d)| *d)
    };
    let table: String = (1..100)
        .map(|t| format!("T{t} P{t} Z0 D{}\n", diameter(t)))
        .collect();
    Options {
        tools: ToolTable::parse(&table, "tools").expect("tool table"),
        start: [0; AXES],
        axes: machine_axes(machine),
        // LinuxCNC's standalone interpreter keeps parameters in inches (its external
        // length units), and the tests print them.
        inch_parameters: true,
        ..Options::default()
    }
}

/// What LinuxCNC says about a program.
enum Reference {
    /// The canonical output it printed (possibly several runs, one after another).
    Trace(PathBuf),
    /// A program of `interp/bad/`: LinuxCNC refuses it.
    Refused,
}

struct Case {
    name: String,
    program: PathBuf,
    reference: Reference,
}

fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
    let mut entries: Vec<PathBuf> = std::fs::read_dir(dir)
        .expect("corpus folder readable")
        .map(|e| e.expect("corpus entry").path())
        .collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            walk(&p, out);
        } else {
            out.push(p);
        }
    }
}

fn rel(root: &Path, p: &Path) -> String {
    p.strip_prefix(root)
        .expect("under the corpus")
        .to_string_lossy()
        .replace('\\', "/")
}

/// Every test of the corpus, in path order.
fn cases(root: &Path) -> Vec<Case> {
    let mut files = Vec::new();
    walk(root, &mut files);
    let mut cases = Vec::new();
    for f in &files {
        let name = f.file_name().unwrap().to_string_lossy().into_owned();
        let dir = f.parent().unwrap();
        let in_bad = rel(root, dir) == "interp/bad";
        if in_bad && name.ends_with(".ngc") {
            cases.push(Case {
                name: rel(root, f),
                program: f.clone(),
                reference: Reference::Refused,
            });
        } else if let Some(program) = name.strip_suffix(".expected") {
            cases.push(Case {
                name: rel(root, &dir.join(program)),
                program: dir.join(program),
                reference: Reference::Trace(f.clone()),
            });
        } else if name == "expected" || name.ends_with(".res") {
            let programs: Vec<&PathBuf> = files
                .iter()
                .filter(|p| p.parent() == Some(dir) && p.extension().is_some_and(|e| e == "ngc"))
                .collect();
            assert_eq!(
                programs.len(),
                1,
                "{}: expected one program beside it",
                rel(root, f)
            );
            cases.push(Case {
                name: rel(root, dir),
                program: programs[0].clone(),
                reference: Reference::Trace(f.clone()),
            });
        }
    }
    cases
}

/// A value LinuxCNC printed, in mm or degrees, with how far it may be from the exact
/// value through the rounding of what was printed.
#[derive(Clone, Copy, Debug)]
struct Approx {
    v: f64,
    tol: f64,
}

impl Approx {
    const ZERO: Approx = Approx { v: 0.0, tol: 0.0 };

    /// Parses a printed number; `scale` converts it to mm (or degrees).
    fn parse(text: &str, scale: f64) -> Option<Approx> {
        let t = text.trim();
        let v: f64 = t.parse().ok()?;
        let decimals = t.split_once('.').map_or(0, |(_, f)| f.len()) as i32;
        Some(Approx {
            v: v * scale,
            tol: 0.5 * 10f64.powi(-decimals) * scale,
        })
    }

    fn add(self, o: Approx) -> Approx {
        Approx {
            v: self.v + o.v,
            tol: self.tol + o.tol,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Traverse,
    Feed,
    Arc,
}

/// One move of the reference: its kind, machine end pose, and where it was printed.
struct RefMove {
    kind: Kind,
    end: [Approx; AXES],
    line: usize,
    text: String,
}

/// One run of `rs274` as read from its printed trace.
#[derive(Default)]
struct Run {
    moves: Vec<RefMove>,
    /// It ended with PROGRAM_END or FINISH (otherwise the interpreter stopped on an
    /// error).
    completed: bool,
    /// Motion we have no counterpart for (RIGID_TAP, STRAIGHT_PROBE, …), first one.
    other_motion: Option<String>,
    /// Operator messages (MESSAGE: MSG and DEBUG comments), text and trace line.
    messages: Vec<(String, usize)>,
    /// The test's script kept only its messages: the moves are not known.
    moves_filtered: bool,
}

/// State of LinuxCNC's canon while reading a trace.
struct CanonState {
    scale: f64,
    g5x: [Approx; AXES],
    g92: [Approx; AXES],
    tool: [Approx; AXES],
    rotation: Approx,
    plane: u8,
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
fn call(line: &str) -> Option<(&str, &str)> {
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
fn read_trace(text: &str) -> Option<Vec<Run>> {
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
                run.moves.push(RefMove {
                    kind: Kind::Arc,
                    end: st.machine(p),
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

fn unreadable<T>(n: usize, line: &str) -> T {
    panic!("trace line {}: cannot read {line:?}", n + 1)
}

/// One of our moves.
struct OurMove {
    kind: Kind,
    end: [i64; AXES],
    line: u32,
}

fn our_moves(canon: &[Canon]) -> Vec<OurMove> {
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
            Some(OurMove {
                kind,
                end: *c.target()?,
                line: c.line(),
            })
        })
        .collect()
}

fn pose_text(p: &[i64; AXES]) -> String {
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

fn ref_text(p: &[Approx; AXES]) -> String {
    format!(
        "X{:.6} Y{:.6} Z{:.6} A{:.6} B{:.6} C{:.6}",
        p[0].v, p[1].v, p[2].v, p[3].v, p[4].v, p[5].v
    )
}

/// The first axis where `ours` is off `reference` by more than 1 µm / 10⁻⁶° plus the
/// reference's printing precision.
fn off(ours: &[i64; AXES], reference: &[Approx; AXES]) -> Option<String> {
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
fn compare_messages(ours: &[&str], run: &Run) -> Option<String> {
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

/// Compares our moves with one reference run: `None` when they agree.
fn compare(ours: &[OurMove], run: &Run) -> Option<String> {
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
            off(&o.end, &r.end)
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

#[derive(Debug)]
enum Outcome {
    /// Moves and messages compared (`None` moves: the expected output holds only
    /// messages).
    Pass(Option<usize>, usize),
    Refused(String),
    ExpectedError(String),
    Mismatch(String),
}

fn first_line(d: &Diagnostic) -> String {
    format!("{}:{}: {}", d.line, d.col, d.message)
}

fn run_case(case: &Case, options: &Options) -> Outcome {
    let bytes = std::fs::read(&case.program).expect("program readable");
    let text = String::from_utf8_lossy(&bytes);
    let result = compile_canon(&text, &case.name, options);
    let runs = match &case.reference {
        Reference::Refused => None,
        Reference::Trace(path) => {
            let trace = std::fs::read_to_string(path).expect("trace readable");
            match read_trace(&trace) {
                Some(runs) => Some(runs),
                None => {
                    return match result {
                        Err(e) if e[0].message.starts_with(UNSUPPORTED) => {
                            Outcome::Refused(e[0].message.clone())
                        }
                        _ => Outcome::Mismatch(
                            "the expected output is not a canonical trace (filtered by its \
                             test script); nothing to compare with"
                                .into(),
                        ),
                    };
                }
            }
        }
    };
    let linuxcnc_fails = runs
        .as_ref()
        .is_none_or(|runs| runs.iter().any(|r| !r.completed));
    match result {
        Err(e) if linuxcnc_fails => Outcome::ExpectedError(first_line(&e[0])),
        Err(e) if e[0].message.starts_with(UNSUPPORTED) => Outcome::Refused(e[0].message.clone()),
        Err(e) => Outcome::Mismatch(format!("we refuse it: {}", first_line(&e[0]))),
        Ok(_) if linuxcnc_fails => {
            Outcome::Mismatch("LinuxCNC stops on an error; we compile it".into())
        }
        Ok(canon) => {
            let ours = our_moves(&canon);
            let messages: Vec<&str> = canon
                .iter()
                .filter_map(|c| match c {
                    Canon::Message { text, .. } => Some(text.as_str()),
                    _ => None,
                })
                .collect();
            for (i, run) in runs.iter().flatten().enumerate() {
                let diff = compare(&ours, run).or_else(|| compare_messages(&messages, run));
                if let Some(diff) = diff {
                    let which = if runs.as_ref().is_some_and(|r| r.len() > 1) {
                        format!("run {}: ", i + 1)
                    } else {
                        String::new()
                    };
                    return Outcome::Mismatch(format!("{which}{diff}"));
                }
            }
            let filtered = runs.iter().flatten().any(|r| r.moves_filtered);
            Outcome::Pass((!filtered).then_some(ours.len()), messages.len())
        }
    }
}

#[test]
fn linuxcnc_interpreter_tests_pass_or_are_refused_by_name() {
    let Some(root) = corpus() else {
        eprintln!("note: corpus folder shared/corpus/linuxcnc-tests not found; skipped");
        return;
    };
    let machine = machine();
    machine.validate().expect("the test machine is valid");
    let options = options(&machine);
    let cases = cases(&root);
    assert!(!cases.is_empty(), "no tests found in the corpus");
    let mut table = String::from("| test | result | reason |\n| --- | --- | --- |\n");
    let mut counts = [0usize; 4];
    let mut mismatches = Vec::new();
    for case in &cases {
        let outcome = run_case(case, &options);
        let (result, reason) = match &outcome {
            Outcome::Pass(n, m) => {
                counts[0] += 1;
                let moves = match n {
                    None => "moves not in its expected output".to_string(),
                    Some(n) => format!("{n} move{}", if *n == 1 { "" } else { "s" }),
                };
                let messages = match m {
                    0 => String::new(),
                    1 => ", 1 message".to_string(),
                    m => format!(", {m} messages"),
                };
                ("pass".to_string(), format!("{moves}{messages}"))
            }
            Outcome::Refused(m) => {
                counts[1] += 1;
                ("refused by name".to_string(), m.clone())
            }
            Outcome::ExpectedError(m) => {
                counts[2] += 1;
                ("expected error".to_string(), format!("ours: {m}"))
            }
            Outcome::Mismatch(m) => {
                counts[3] += 1;
                mismatches.push(format!("{}: {m}", case.name));
                ("**mismatch**".to_string(), m.clone())
            }
        };
        let reason = reason.replace('|', "\\|");
        writeln!(table, "| {} | {result} | {reason} |", case.name).unwrap();
    }
    println!("{table}");
    println!(
        "{} tests: {} pass, {} refused by name, {} expected errors, {} mismatches",
        cases.len(),
        counts[0],
        counts[1],
        counts[2],
        counts[3]
    );
    assert!(
        mismatches.is_empty(),
        "{} mismatch(es):\n{}",
        mismatches.len(),
        mismatches.join("\n")
    );
}
