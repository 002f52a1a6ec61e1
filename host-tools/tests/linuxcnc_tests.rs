//! LinuxCNC's own interpreter tests (`shared/corpus/linuxcnc-tests`, beside the
//! repository, read in place; skipped with a note when absent) run through our front
//! end and compared with LinuxCNC's expected canonical output.
//!
//! Each test is one program and what LinuxCNC's `rs274 -g` printed for it (`expected`,
//! `*.ngc.expected`, `rs274.res`), or a program of `interp/bad/`, which LinuxCNC must
//! refuse (its `test.sh` there fails when the interpreter accepts one). A test is:
//!
//! - **pass**: we compile it, and every move end point (STRAIGHT_TRAVERSE, STRAIGHT_FEED,
//!   ARC_FEED, in order, of the same kind), every arc's centre and the final position
//!   equal LinuxCNC's within 1 µm (X Y Z) or 10⁻⁶° (A B C), plus the rounding of the numbers LinuxCNC
//!   printed (4 decimals of program units: half a unit in the last printed place of each
//!   term, so 1.27 µm per term in inches);
//! - **refused by name**: our first diagnostic starts `unsupported: ` (a legal LinuxCNC
//!   feature the front end does not implement);
//! - **expected error**: LinuxCNC fails on the program (an `interp/bad/` program, or an
//!   expected trace that stops without PROGRAM_END or FINISH) and so do we;
//! - **mismatch** (anything else): a defect. The test fails when there is one.
//!
//! How the expected output is read: `lcnc/mod.rs`. The programs run on a six-axis
//! Cartesian machine with ±1000 mm of travel (`machine`), starting at 0, with tools 1–99 in the table at zero length
//! (LinuxCNC's tests bring their own tool tables, which the corpus omits; every
//! USE_TOOL_LENGTH_OFFSET before a G10 L1/L10/L11 in the expected output is zero) and
//! the diameters of the cutter compensation tests' table (`TEST_TBL_DIAMETERS_MM`).
//!
//! `cargo test -p pkmc-host --test linuxcnc_tests -- --nocapture` prints the table that
//! `docs/gcode.md` ("LinuxCNC's interpreter tests") holds.

mod lcnc;

use lcnc::{compare, compare_messages, our_moves, read_trace};
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

fn rel(root: &Path, p: &Path) -> String {
    p.strip_prefix(root)
        .expect("under the corpus")
        .to_string_lossy()
        .replace('\\', "/")
}

/// Every test of the corpus, in path order.
fn cases(root: &Path) -> Vec<Case> {
    let mut files = Vec::new();
    lcnc::files_under(root, None, &mut files);
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
