//! Parsing speed: our `compile` (parser *and* modal interpreter, producing canonical
//! commands) against the `gcode` crate's syntax-only push parser (0.7, every word
//! consumed through its visitor API), on two LinuxCNC corpus programs read in place
//! from `shared/corpus/linuxcnc` beside the repository.
//!
//! Run: `cargo bench -p pkmc-host --bench parse`. Prints MB/s for both and the ratio
//! (ours / theirs); skips with a message when the corpus is absent.
//! `PARSE_BENCH_PROFILE=arcspiral.ngc` runs only our compile on that file for about
//! three seconds, for a profiler. Each figure is the
//! best of several timed rounds (interleaved between the two parsers) of many repetitions (at least `MIN_ROUND` each).

use gcode::core::{
    BlockVisitor, CommandVisitor, ControlFlow, Diagnostics, Number, ProgramVisitor, Span,
    TokenType, Value,
};
use pkmc_host::gcode::{compile, Options};
use std::hint::black_box;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// Shortest timed round.
const MIN_ROUND: Duration = Duration::from_millis(300);
/// Rounds per measurement (the best is kept).
const ROUNDS: usize = 7;
/// The programs compared.
const FILES: [&str; 2] = ["arcspiral.ngc", "3D_Chips.ngc"];

/// Consumes every word the `gcode` crate reports, and counts its diagnostics.
#[derive(Default)]
struct Sink {
    words: u64,
    sum: f64,
    diagnostics: u64,
}

impl Diagnostics for Sink {
    fn emit_unknown_content(&mut self, _text: &str, _span: Span) {
        self.diagnostics += 1;
    }
    fn emit_unexpected(&mut self, _actual: &str, _expected: &[TokenType], _span: Span) {
        self.diagnostics += 1;
    }
}

impl Sink {
    fn take(&mut self, value: Value<'_>) {
        self.words += 1;
        if let Value::Literal(v) = value {
            self.sum += f64::from(v);
        }
    }
}

impl ProgramVisitor for Sink {
    fn start_block(&mut self) -> ControlFlow<impl BlockVisitor + '_> {
        ControlFlow::Continue(Block(self))
    }
}

struct Block<'a>(&'a mut Sink);

impl gcode::core::HasDiagnostics for Block<'_> {
    fn diagnostics(&mut self) -> &mut dyn Diagnostics {
        &mut *self.0
    }
}

impl BlockVisitor for Block<'_> {
    fn line_number(&mut self, n: u32, _span: Span) {
        self.0.words += 1;
        self.0.sum += f64::from(n);
    }
    fn word_address(&mut self, _letter: char, value: Value<'_>, _span: Span) {
        self.0.take(value);
    }
    fn start_general_code(&mut self, number: Number) -> ControlFlow<impl CommandVisitor + '_> {
        self.0.words += 1;
        self.0.sum += f64::from(number.major());
        ControlFlow::Continue(Command(&mut *self.0))
    }
    fn start_miscellaneous_code(
        &mut self,
        number: Number,
    ) -> ControlFlow<impl CommandVisitor + '_> {
        self.0.words += 1;
        self.0.sum += f64::from(number.major());
        ControlFlow::Continue(Command(&mut *self.0))
    }
    fn start_tool_change_code(&mut self, number: Number) -> ControlFlow<impl CommandVisitor + '_> {
        self.0.words += 1;
        self.0.sum += f64::from(number.major());
        ControlFlow::Continue(Command(&mut *self.0))
    }
}

struct Command<'a>(&'a mut Sink);

impl gcode::core::HasDiagnostics for Command<'_> {
    fn diagnostics(&mut self) -> &mut dyn Diagnostics {
        &mut *self.0
    }
}

impl CommandVisitor for Command<'_> {
    fn argument(&mut self, _letter: char, value: Value<'_>, _span: Span) {
        self.0.take(value);
    }
}

/// Repetitions of `f` that take about a quarter of [`MIN_ROUND`] (after warming up).
fn calibrate(f: &mut impl FnMut()) -> u32 {
    let mut reps = 1u32;
    loop {
        let t = Instant::now();
        for _ in 0..reps {
            f();
        }
        if t.elapsed() >= MIN_ROUND / 4 || reps >= 1 << 24 {
            return reps * 4;
        }
        reps *= 2;
    }
}

/// Time of one call of `f`, from a round of `reps` calls.
fn round(reps: u32, f: &mut impl FnMut()) -> Duration {
    let t = Instant::now();
    for _ in 0..reps {
        f();
    }
    t.elapsed() / reps
}

/// Best throughputs of `a` and `b` on `bytes` bytes, MB/s (10⁶ bytes per second), their
/// rounds interleaved so that a busy machine slows both alike.
fn throughputs(bytes: usize, mut a: impl FnMut(), mut b: impl FnMut()) -> (f64, f64) {
    let (ra, rb) = (calibrate(&mut a), calibrate(&mut b));
    let (mut ta, mut tb) = (Duration::MAX, Duration::MAX);
    for _ in 0..ROUNDS {
        ta = ta.min(round(ra, &mut a));
        tb = tb.min(round(rb, &mut b));
    }
    let mbs = |t: Duration| bytes as f64 / t.as_secs_f64() / 1e6;
    (mbs(ta), mbs(tb))
}

fn main() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/corpus/linuxcnc");
    if !dir.is_dir() {
        println!(
            "parse bench: corpus folder {} not found; skipped",
            dir.display()
        );
        return;
    }
    let options = Options::default();
    if let Ok(name) = std::env::var("PARSE_BENCH_PROFILE") {
        // For a profiler: only our compile, on one file, for about three seconds.
        let text = std::fs::read_to_string(dir.join(&name)).expect("corpus file readable");
        let t = Instant::now();
        let mut n = 0u64;
        while t.elapsed() < Duration::from_secs(3) {
            black_box(
                compile(black_box(&text), &name, &options)
                    .map(|c| c.len())
                    .ok(),
            );
            n += 1;
        }
        let mbs = (text.len() as f64 * n as f64) / t.elapsed().as_secs_f64() / 1e6;
        println!("{name}: {n} compiles, {mbs:.1} MB/s");
        return;
    }
    println!(
        "{:<15} {:>9} {:>12} {:>12} {:>7}  notes",
        "file", "bytes", "ours MB/s", "gcode MB/s", "ratio"
    );
    for name in FILES {
        let text = match std::fs::read_to_string(dir.join(name)) {
            Ok(t) => t,
            Err(e) => {
                println!("{name:<15} cannot read: {e}; skipped");
                continue;
            }
        };
        let ours = compile(&text, name, &options);
        let mut notes = match &ours {
            Ok(c) => format!("ours: {} commands", c.len()),
            Err(e) => format!("ours: {} errors (first: {})", e.len(), e[0]),
        };
        let mut probe = Sink::default();
        gcode::core::parse(&text, &mut probe);
        if probe.diagnostics > 0 {
            notes += &format!(
                "; gcode crate cannot read it ({} diagnostics: no expressions or parameters)",
                probe.diagnostics
            );
        } else {
            notes += &format!("; gcode: {} words", probe.words);
        }
        let (ours_mbs, theirs_mbs) = throughputs(
            text.len(),
            || {
                black_box(
                    compile(black_box(&text), name, &options)
                        .map(|c| c.len())
                        .ok(),
                );
            },
            || {
                let mut sink = Sink::default();
                gcode::core::parse(black_box(&text), &mut sink);
                black_box((sink.words, sink.sum));
            },
        );
        println!(
            "{name:<15} {:>9} {ours_mbs:>12.1} {theirs_mbs:>12.1} {:>7.2}  {notes}",
            text.len(),
            ours_mbs / theirs_mbs
        );
    }
}
