//! LinuxCNC's interpreter as a live oracle (issue 34): every `.ngc` of the shared
//! corpus (`shared/corpus/`, beside the repository, read in place: LinuxCNC's sample
//! programs and its own interpreter tests) and some 1 400 seeded random programs
//! (`oracle_gen`: arcs in three planes, offsets, units, cycles, cutter compensation,
//! parameters, O-words; valid ones and ones with a fault) run through LinuxCNC's
//! standalone interpreter `rs274 -g` and through our `compile_canon`, with the same
//! tool table. For each program:
//!
//! - the accept/refuse answers agree (`rs274`'s exit status; our `Result`), and
//! - when both accept, every move (STRAIGHT_TRAVERSE, STRAIGHT_FEED, ARC_FEED: in
//!   order, of the same kind) ends at the same machine position and every arc has the
//!   same centre, within 1 µm (10⁻⁶° for A B C) plus the rounding of what `rs274`
//!   printed (4 decimals of program units; how its output is read: `lcnc/mod.rs`).
//!
//! Otherwise the difference must be one of `DOCUMENTED`: a refusal (we refuse what
//! LinuxCNC accepts; recognised by our diagnostic), a leniency (we accept what it
//! refuses; by its error) or a bug of LinuxCNC 2.9 (moves that differ; by the
//! program), each named in `docs/gcode.md` ("LinuxCNC's interpreter as an oracle"),
//! which the test checks. It prints the counts — programs, generated cases,
//! agreements, documented differences, unexplained ones — and fails on any unexplained
//! difference.
//!
//! `rs274` comes with LinuxCNC (Debian: `linuxcnc-uspace`). Where it is not installed
//! the build script marks the test ignored, saying so; under CI it must be there.
//! `PKMC_ORACLE_SEED` and `PKMC_ORACLE_CASES` change the generated set.
//!
//! `cargo test -p pkmc-host --test rs274_oracle -- --nocapture`

mod lcnc;
mod oracle_gen;

use lcnc::{compare, our_moves, read_trace, Run};
use pkmc_host::gcode::{compile_canon, Options, ToolTable};
use std::collections::BTreeMap;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// The tool table both interpreters get: number, length (Z) and diameter, inches (the
/// standalone `rs274` reads its table in inches). T1–T4 are the diameters of
/// LinuxCNC's cutter compensation tests' `test.tbl`; T5–T8 have lengths for G43;
/// T9–T99 are zero.
const TOOLS: [(u32, f64, f64); 8] = [
    (1, 0.0, 0.0625),
    (2, 0.0, 0.125),
    (3, 0.0, 0.25),
    (4, 0.0, 1.0),
    (5, 1.0, 0.25),
    (6, -0.5, 0.5),
    (7, 2.25, 0.125),
    (8, 0.3937, 0.0),
];

fn tool(t: u32) -> (f64, f64) {
    TOOLS
        .iter()
        .find(|(n, _, _)| *n == t)
        .map_or((0.0, 0.0), |&(_, z, d)| (z, d))
}

/// The tool file, in inches for `rs274` or in mm for us.
fn tool_file(inches: bool) -> String {
    let k = if inches { 1.0 } else { 25.4 };
    (1..100)
        .map(|t| {
            let (z, d) = tool(t);
            format!("T{t} P{t} Z{} D{}\n", z * k, d * k)
        })
        .collect()
}

fn options() -> Options {
    Options {
        tools: ToolTable::parse(&tool_file(false), "tools").expect("tool table"),
        // The standalone interpreter keeps its parameters in inches.
        inch_parameters: true,
        ..Options::default()
    }
}

/// Why a difference is allowed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Allowed {
    /// We refuse what LinuxCNC accepts; recognised by our first diagnostic.
    Refusal,
    /// We accept what LinuxCNC refuses; recognised by its error.
    Leniency,
    /// Both accept and the moves differ: LinuxCNC 2.9 is wrong (by its own
    /// documentation, or fixed after 2.9); recognised by the program's text.
    Bug,
}

/// A documented difference: its name in `docs/gcode.md`, its kind, and what
/// recognises it (our diagnostic, LinuxCNC's error or the program's text, by kind).
struct Documented {
    name: &'static str,
    allowed: Allowed,
    recognise: fn(&str) -> bool,
}

/// The lines of `text`, lower-cased and trimmed.
fn lines(text: &str) -> impl Iterator<Item = String> + '_ {
    text.lines().map(|l| l.trim().to_ascii_lowercase())
}

/// Where the first line `o… <keyword>` is.
fn keyword_at(text: &str, keyword: &str) -> Option<usize> {
    lines(text).position(|l| l.starts_with('o') && l.split_whitespace().nth(1) == Some(keyword))
}

/// LinuxCNC 2.9's loops go wrong after a `break` it skipped (a later do-while loop
/// runs once) and after a loop left through `continue` (a later `break` does
/// nothing): a program with a `break` before a `do`, or with both `break` and
/// `continue`.
fn break_continue(text: &str) -> bool {
    let (b, c, d) = (
        keyword_at(text, "break"),
        keyword_at(text, "continue"),
        keyword_at(text, "do"),
    );
    (b.is_some() && c.is_some()) || b.zip(d).is_some_and(|(b, d)| b < d)
}

/// Every difference between LinuxCNC 2.9's interpreter and ours that the oracle
/// allows. Each is named in `docs/gcode.md`'s oracle table with its reason.
const DOCUMENTED: &[Documented] = &[
    Documented {
        name: "G74/G84 tapping",
        allowed: Allowed::Refusal,
        recognise: |e| e.contains("unsupported: G74/G84 tapping"),
    },
    Documented {
        name: "G86–G88 boring",
        allowed: Allowed::Refusal,
        recognise: |e| e.contains("unsupported: G86"),
    },
    Documented {
        name: "G33 spindle-synchronised motion",
        allowed: Allowed::Refusal,
        recognise: |e| e.contains("unsupported: G33"),
    },
    Documented {
        name: "M19 spindle orientation",
        allowed: Allowed::Refusal,
        recognise: |e| e.contains("unsupported: M19"),
    },
    Documented {
        name: "M98/M99 subprograms",
        allowed: Allowed::Refusal,
        recognise: |e| e.contains("unsupported: M98/M99"),
    },
    Documented {
        name: "cutter compensation in the XZ plane",
        allowed: Allowed::Refusal,
        recognise: |e| e.contains("unsupported: cutter compensation in the XZ plane"),
    },
    Documented {
        name: "spiral arcs over 0.08 mm",
        allowed: Allowed::Refusal,
        recognise: |e| e.contains("unsupported: spiral arcs"),
    },
    Documented {
        name: "setting an INI parameter",
        allowed: Allowed::Refusal,
        recognise: |e| e.contains("#<_ini[") && e.contains("is read-only"),
    },
    Documented {
        name: "a block never closed",
        allowed: Allowed::Refusal,
        recognise: |e| e.contains("opened here is never closed"),
    },
    Documented {
        name: "program without M2",
        allowed: Allowed::Leniency,
        recognise: |e| e.contains("File ended with no percent sign or program end"),
    },
    Documented {
        name: "a program name line",
        allowed: Allowed::Leniency,
        recognise: |e| e.starts_with("Unknown word where unary operation could be / O"),
    },
    Documented {
        name: "an O-word label reused",
        allowed: Allowed::Leniency,
        recognise: |e| e.contains("duplicate O-word label"),
    },
    Documented {
        name: "G53 and G28 with rotary tool offsets",
        allowed: Allowed::Bug,
        recognise: |text| {
            let t = text.to_ascii_lowercase();
            t.contains("g43.1") && (t.contains("g53") || t.contains("g28"))
        },
    },
    Documented {
        name: "break and continue in later loops",
        allowed: Allowed::Bug,
        recognise: break_continue,
    },
];

/// What one side says about a program.
enum Answer {
    Accepts(Run),
    Refuses(String),
}

/// The outcome of one program.
enum Verdict {
    Agree,
    Documented(&'static str),
    Unexplained(String),
}

/// A scratch folder, removed at the end: the generated programs, and a folder per
/// worker for `rs274` (its HOME and working directory: it keeps its tool data in a
/// `.tool.mmap` there, which two runs at once must not share).
struct Scratch(PathBuf);

impl Scratch {
    fn new() -> Scratch {
        let dir = std::env::temp_dir().join(format!("pkmc-rs274-oracle-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("scratch folder");
        Scratch(dir)
    }

    /// Worker `k`'s folder for `rs274`, with the tool table.
    fn worker(&self, k: usize) -> PathBuf {
        let dir = self.0.join(format!("worker-{k}"));
        std::fs::create_dir_all(&dir).expect("scratch folder");
        std::fs::write(dir.join("tool.tbl"), tool_file(true)).expect("tool table written");
        dir
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn find_rs274() -> Option<PathBuf> {
    let paths = std::env::var_os("PATH")?;
    std::env::split_paths(&paths)
        .map(|d| d.join("rs274"))
        .find(|p| p.is_file())
}

/// Runs `rs274 -g` in the folder `dir` on the program at `path`: its answer and
/// printed trace. Nothing is carried from one run to the next: the tool data is made
/// again from the table, and without `-v` no parameter file is read or written.
fn rs274(exe: &Path, dir: &Path, path: &Path) -> Answer {
    let _ = std::fs::remove_file(dir.join(".tool.mmap"));
    let mut child = Command::new(exe)
        .arg("-g")
        .arg("-t")
        .arg(dir.join("tool.tbl"))
        .arg(path)
        .current_dir(dir)
        .env("HOME", dir)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("rs274 runs");
    let mut out = child.stdout.take().expect("stdout");
    let mut err = child.stderr.take().expect("stderr");
    let reader = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = err.read_to_string(&mut s);
        s
    });
    let mut stdout = Vec::new();
    out.read_to_end(&mut stdout).expect("rs274's output");
    let start = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().expect("rs274 waited for") {
            break s;
        }
        if start.elapsed() > Duration::from_secs(60) {
            let _ = child.kill();
            panic!("rs274 did not finish {} within 60 s", path.display());
        }
        std::thread::sleep(Duration::from_millis(2));
    };
    let stderr = reader.join().expect("stderr reader");
    if status.success() {
        let text = String::from_utf8_lossy(&stdout);
        let runs = read_trace(&text).unwrap_or_default();
        match runs.into_iter().next() {
            Some(run) => Answer::Accepts(run),
            None => panic!("rs274 accepted {} but printed no trace", path.display()),
        }
    } else {
        let lines: Vec<&str> = stderr
            .lines()
            .map(str::trim)
            .filter(|l| !l.is_empty() && *l != "executing")
            .collect();
        Answer::Refuses(lines.join(" / "))
    }
}

/// Our answer: the moves, or our first diagnostic.
fn ours(text: &str, name: &str, options: &Options) -> Result<Vec<lcnc::OurMove>, String> {
    match compile_canon(text, name, options) {
        Ok(canon) => Ok(our_moves(&canon)),
        Err(e) => Err(format!("{}:{}: {}", e[0].line, e[0].col, e[0].message)),
    }
}

/// The verdict on `program` from both answers.
fn judge(program: &str, theirs: &Answer, ours: &Result<Vec<lcnc::OurMove>, String>) -> Verdict {
    let documented = |allowed: Allowed, text: &str| {
        DOCUMENTED
            .iter()
            .find(|d| d.allowed == allowed && (d.recognise)(text))
            .map(|d| d.name)
    };
    match (theirs, ours) {
        (Answer::Refuses(_), Err(_)) => Verdict::Agree,
        (Answer::Accepts(run), Ok(moves)) => match compare(moves, run) {
            None => Verdict::Agree,
            Some(diff) => match documented(Allowed::Bug, program) {
                Some(name) => Verdict::Documented(name),
                None => Verdict::Unexplained(format!("both accept; {diff}")),
            },
        },
        (Answer::Accepts(_), Err(e)) => match documented(Allowed::Refusal, e) {
            Some(name) => Verdict::Documented(name),
            None => Verdict::Unexplained(format!("LinuxCNC accepts; we refuse: {e}")),
        },
        (Answer::Refuses(e), Ok(_)) => match documented(Allowed::Leniency, e) {
            Some(name) => Verdict::Documented(name),
            None => Verdict::Unexplained(format!("LinuxCNC refuses ({e}); we accept")),
        },
    }
}

/// One program to run: its name, where its text is, and the text.
struct Program {
    name: String,
    path: PathBuf,
    text: String,
    generated: bool,
}

fn corpus() -> Option<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/corpus");
    dir.is_dir().then_some(dir)
}

fn env_number(name: &str, default: u64) -> u64 {
    std::env::var(name).map_or(default, |v| {
        v.parse()
            .unwrap_or_else(|_| panic!("{name}={v}: not a number"))
    })
}

/// The results, per program, in the programs' order.
struct Results {
    verdicts: Vec<Option<(Verdict, bool)>>,
}

/// Runs every program through both sides, on two threads.
fn run_all(exe: &Path, scratch: &Scratch, programs: &[Program]) -> Results {
    let options = options();
    let next = AtomicUsize::new(0);
    let verdicts = Mutex::new((0..programs.len()).map(|_| None).collect::<Vec<_>>());
    std::thread::scope(|s| {
        for worker in 0..2 {
            let dir = scratch.worker(worker);
            let (next, verdicts, options) = (&next, &verdicts, &options);
            s.spawn(move || loop {
                let k = next.fetch_add(1, Ordering::Relaxed);
                let Some(p) = programs.get(k) else { break };
                let theirs = rs274(exe, &dir, &p.path);
                let accepted = matches!(theirs, Answer::Accepts(_));
                let verdict = judge(&p.text, &theirs, &ours(&p.text, &p.name, options));
                verdicts.lock().unwrap()[k] = Some((verdict, accepted));
            });
        }
    });
    Results {
        verdicts: verdicts.into_inner().unwrap(),
    }
}

#[test]
#[cfg_attr(
    pkmc_no_rs274,
    ignore = "needs LinuxCNC's rs274 on PATH (Debian: apt-get install linuxcnc-uspace)"
)]
fn linuxcnc_interpreter_agrees_or_the_difference_is_documented() {
    let exe = find_rs274().expect("rs274 not on PATH (Debian: apt-get install linuxcnc-uspace)");
    let scratch = Scratch::new();
    let mut programs = Vec::new();
    match corpus() {
        Some(root) => {
            let mut files = Vec::new();
            lcnc::files_under(&root, Some("ngc"), &mut files);
            assert!(!files.is_empty(), "no .ngc programs in shared/corpus");
            for f in files {
                let bytes = std::fs::read(&f).expect("program readable");
                programs.push(Program {
                    name: f
                        .strip_prefix(&root)
                        .unwrap()
                        .to_string_lossy()
                        .into_owned(),
                    text: String::from_utf8_lossy(&bytes).into_owned(),
                    path: f,
                    generated: false,
                });
            }
        }
        None => println!(
            "note: the corpus folder shared/corpus (beside the repository) is absent: \
             only generated programs run"
        ),
    }
    let corpus_count = programs.len();
    let seed = env_number("PKMC_ORACLE_SEED", 34);
    let cases = env_number("PKMC_ORACLE_CASES", 1400) as usize;
    // PKMC_ORACLE_KEEP=DIR keeps the generated programs there, to run them again.
    let gen_dir = std::env::var_os("PKMC_ORACLE_KEEP")
        .map_or_else(|| scratch.0.join("generated"), PathBuf::from);
    std::fs::create_dir_all(&gen_dir).expect("scratch folder");
    for g in oracle_gen::generate(seed, cases) {
        let path = gen_dir.join(format!("{}.ngc", g.name));
        std::fs::write(&path, &g.text).expect("generated program written");
        programs.push(Program {
            name: g.name,
            path,
            text: g.text,
            generated: true,
        });
    }
    let started = Instant::now();
    let results = run_all(&exe, &scratch, &programs);
    report(&programs, &results, corpus_count, seed, started.elapsed());
}

/// Prints the counts and the differences, and fails on an unexplained one.
fn report(programs: &[Program], results: &Results, corpus: usize, seed: u64, took: Duration) {
    let docs =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/gcode.md"))
            .expect("docs/gcode.md readable");
    let section = docs
        .split_once("## LinuxCNC's interpreter as an oracle")
        .map(|(_, s)| s.split("\n## ").next().unwrap_or(""))
        .expect("docs/gcode.md has a section \"LinuxCNC's interpreter as an oracle\"");
    let (mut agree, mut unexplained) = (0, Vec::new());
    let mut documented: BTreeMap<&str, Vec<&str>> = BTreeMap::new();
    let mut accepted = [0usize; 2];
    for (p, v) in programs.iter().zip(&results.verdicts) {
        let (verdict, ok) = v.as_ref().expect("every program judged");
        if p.generated {
            accepted[usize::from(!*ok)] += 1;
        }
        match verdict {
            Verdict::Agree => agree += 1,
            Verdict::Documented(name) => documented.entry(name).or_default().push(&p.name),
            Verdict::Unexplained(why) => unexplained.push((p, why)),
        }
    }
    let generated = programs.len() - corpus;
    println!(
        "rs274 oracle: {corpus} programs of the corpus and {generated} generated cases \
         (seed {seed}; LinuxCNC accepts {} and refuses {} of them), in {:.1} s",
        accepted[0],
        accepted[1],
        took.as_secs_f64()
    );
    let mut topics: BTreeMap<&str, [usize; 2]> = BTreeMap::new();
    for (p, v) in programs.iter().zip(&results.verdicts) {
        if let (true, Some((_, ok))) = (p.generated, v) {
            let topic = p.name.split('-').nth(2).unwrap_or("?");
            topics.entry(topic).or_default()[usize::from(!*ok)] += 1;
        }
    }
    let per_topic: Vec<String> = topics
        .iter()
        .map(|(t, [a, r])| format!("{t} {a}/{r}"))
        .collect();
    println!(
        "generated, accepted/refused by LinuxCNC: {}",
        per_topic.join(", ")
    );
    let n_doc: usize = documented.values().map(Vec::len).sum();
    println!(
        "{agree} agreements, {n_doc} documented differences, {} unexplained",
        unexplained.len()
    );
    for d in DOCUMENTED {
        let who = documented.get(d.name).map_or(&[][..], Vec::as_slice);
        let shown: Vec<&str> = who.iter().take(3).copied().collect();
        let more = if who.len() > 3 { ", …" } else { "" };
        println!(
            "  {:?} `{}`: {} ({}{more})",
            d.allowed,
            d.name,
            who.len(),
            shown.join(", ")
        );
    }
    let generated_first = unexplained.iter().filter(|(p, _)| p.generated);
    for (p, _) in generated_first.take(3) {
        println!("{}:\n{}", p.name, p.text);
    }
    for (p, why) in &unexplained {
        println!("UNEXPLAINED {}: {why}", p.name);
    }
    for d in DOCUMENTED {
        assert!(
            section.contains(&format!("| {} |", d.name)),
            "docs/gcode.md's oracle table does not name the difference `{}`",
            d.name
        );
    }
    assert!(
        unexplained.is_empty(),
        "{} unexplained difference(s) with LinuxCNC's interpreter (listed above)",
        unexplained.len()
    );
    if generated >= 100 {
        // The generator must give both kinds of program.
        for (k, what) in ["accepts", "refuses"].iter().enumerate() {
            assert!(
                accepted[k] * 10 >= generated,
                "LinuxCNC {what} only {} of {generated} generated cases",
                accepted[k]
            );
        }
    }
}
