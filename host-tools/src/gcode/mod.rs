//! G-code front end: a parser and modal interpreter for the RS-274/NGC dialect that
//! LinuxCNC and CAM post-processors produce, turning a program into canonical machining
//! commands ([`Canon`]).
//!
//! The program is handled one line at a time, without a syntax tree: [`lexer`] splits a
//! line into words and evaluates `[expressions]` and parameter reads on the fly (into a
//! buffer reused for every line, so the hot loop allocates nothing per word), and
//! [`interp`] applies the words to the modal state in LinuxCNC's order of execution and
//! emits [`Canon`] commands; [`cycles`] expands canned drilling cycles into rapids, feeds
//! and dwells, [`arcs`] computes arc centres and checks arc ends, [`params`] holds the
//! numbered and named parameters and [`tools`] the tool table. [`flow`] indexes the
//! program's O-word lines (subroutines, branches, loops) before it runs and then
//! decides which line runs next; plain lines are executed as they come.
//!
//! Invariants:
//! - Every position in the output is absolute, in axis units (nm for X Y Z, n° for
//!   A B C), after work offsets (G54–G59.3, G92) and the tool length offset (G43).
//! - Literal numbers convert to axis units exactly, with one rounding to the nearest unit
//!   (`X10.0001` is 10 000 100 nm; `G20 X1` is 25 400 000 nm); values computed by
//!   expressions are evaluated in `f64` as LinuxCNC does and rounded once.
//! - No input makes [`compile`] panic: user numbers go through checked arithmetic, every
//!   axis value is bounded by [`MAX_AXIS_UNITS`], lines by [`MAX_LINE`], bracket nesting
//!   by [`MAX_NESTING`] and the commands one line may expand into by
//!   [`MAX_CYCLE_REPEATS`] and [`MAX_PECKS`]; no input makes it hang: subroutine calls
//!   nest at most [`flow::MAX_CALL_DEPTH`] deep and a run executes at most
//!   [`flow::MAX_REPEATED_LINES`] lines beyond the program's length.
//! - Every error names `file:line:col` and what is wrong; the whole program is checked
//!   (at most one error per line, then the next line; with O-words, every line that
//!   runs, once the blocks match up), and a program with any error
//!   yields no commands. Legal LinuxCNC features that are not implemented are refused by
//!   name with a message starting `unsupported: `.
//!
//! Source: the LinuxCNC G-code reference (overview, G codes, M codes, O codes) and
//! the RS-274/NGC interpreter's order of execution. The dialect as implemented is
//! described in `docs/gcode.md`.

pub mod arcs;
pub mod blocks;
pub mod canon;
pub mod compress;
pub mod cycles;
pub mod flow;
pub mod interp;
pub mod kind;
pub mod lexer;
pub mod params;
mod session;
pub mod tools;

pub use interp::state::Offsets;
pub use kind::ErrorKind;
pub use session::LineSession;
pub use tools::{Tool, ToolTable};

use crate::gcode::canon::Canon;
use pkmc::config::AXES;
use std::fmt;

/// Longest line accepted, characters (without the line break).
pub const MAX_LINE: usize = 256;
/// Deepest nesting of `[ ]`, unary signs and parameter indirection (`##1`) in one value.
pub const MAX_NESTING: usize = 32;
/// Largest magnitude of any position, offset or distance, axis units (1e17 nm is
/// 100 000 km; 1e17 n° is 10⁸ degrees). Sums of a few such values cannot overflow `i64`.
pub const MAX_AXIS_UNITS: i64 = 100_000_000_000_000_000;
/// Most repeats (L) of one canned-cycle line (bounds what one line expands into).
pub const MAX_CYCLE_REPEATS: i64 = 1_000;
/// Most pecks one G73/G83 line expands into, over all its repeats.
pub const MAX_PECKS: i64 = 10_000;
/// Default arc tolerance, nm: how far an arc's end may lie off the circle through its
/// start (0.002 mm).
pub const DEFAULT_ARC_TOLERANCE_NM: i64 = 2_000;

/// What the interpreter needs besides the program text.
#[derive(Clone, Debug)]
pub struct Options {
    /// Skip lines that start with `/` (the operator's block-delete switch).
    pub block_delete: bool,
    /// Tool lengths and diameters, for G43 and parameters #5400–#5410.
    pub tools: ToolTable,
    /// How far, nm, an arc's end may lie off the circle through its start (centre
    /// format), and how much too short an R-format radius may be; default
    /// [`DEFAULT_ARC_TOLERANCE_NM`].
    pub arc_tolerance_nm: i64,
    /// Pose the machine is at when the program starts (axis units, machine frame).
    pub start: [i64; AXES],
    /// The axes the machine has (X Y Z A B C, in that order): an axis word for any
    /// other is an error at its column, since the machine could never move there.
    /// Default: all six.
    pub axes: [bool; AXES],
    /// Keep the parameters that hold lengths (work, G92 and tool offsets, stored
    /// positions, #5081–#5086, #5401–#5410) in inches, as a LinuxCNC machine
    /// configured in inches does (its INI `LINEAR_UNITS`); default false: millimetres.
    /// Whatever this is, G20/G21 only change how the program's words are read.
    pub inch_parameters: bool,
    /// Most lines a run may execute beyond the program's own length (loops and
    /// subroutine calls) before it is stopped as endless; default
    /// [`flow::MAX_REPEATED_LINES`].
    pub repeated_lines: usize,
    /// The outcomes of the program's first probing moves (G38.2–G38.5), in order: a
    /// run takes them as the moves' results and stops at the first move past them
    /// ([`interp::Interp::waiting`]). Default: none.
    pub probes: Vec<interp::probe::ProbeOutcome>,
    /// The caller runs probing moves (G38.2–G38.5) as such (nc-send's program runs);
    /// otherwise they are refused by name. Default: false.
    pub probing: bool,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            block_delete: false,
            tools: ToolTable::default(),
            arc_tolerance_nm: DEFAULT_ARC_TOLERANCE_NM,
            start: [0; AXES],
            axes: [true; AXES],
            inch_parameters: false,
            repeated_lines: flow::MAX_REPEATED_LINES,
            probes: Vec::new(),
            probing: false,
        }
    }
}

/// A located error.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Diagnostic {
    /// File name as given.
    pub file: String,
    /// Line, 1-based.
    pub line: usize,
    /// Column, 1-based, in characters.
    pub col: usize,
    /// What kind of fault it is, set where it was found.
    pub kind: ErrorKind,
    /// What is wrong.
    pub message: String,
}

impl fmt::Display for Diagnostic {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}:{}:{}: {}",
            self.file, self.line, self.col, self.message
        )
    }
}

/// Prefix of every refusal of a legal but unimplemented feature.
pub const UNSUPPORTED: &str = "unsupported: ";

/// The message refusing `feature` by name.
pub(crate) fn unsupported(feature: &str) -> String {
    format!("{UNSUPPORTED}{feature}")
}

/// Compiles a whole program; returns its canonical commands, or every error found
/// (the same as [`compile_canon`]).
pub fn compile(source: &str, file: &str, options: &Options) -> Result<Vec<Canon>, Vec<Diagnostic>> {
    compile_canon(source, file, options)
}

/// Compiles a whole program with `options` into canonical commands.
pub fn compile_canon(
    source: &str,
    file: &str,
    options: &Options,
) -> Result<Vec<Canon>, Vec<Diagnostic>> {
    let mut interp = interp::Interp::new(options);
    let program = flow::Program::index(source, options.block_delete, &interp.params);
    let mut out = Vec::with_capacity(source.len() / 24);
    let mut errors = Vec::new();
    for (line, col, kind, message) in &program.errors {
        let text = program.text_of(source, *line);
        errors.push(Diagnostic {
            file: file.to_string(),
            line: *line as usize,
            col: lexer::char_col(text, *col),
            kind: *kind,
            message: message.clone(),
        });
    }
    if !program.broken {
        flow::run(&program, source, file, &mut interp, &mut out, &mut errors);
        // Stopped at a probing move, the run is not over: the rest is run once its
        // outcome is known.
        let finished = match interp.waiting() {
            true => Ok(()),
            false => interp.finish(&mut out),
        };
        if let Err(e) = finished {
            let line = program.lines.len().max(1);
            errors.push(Diagnostic {
                file: file.to_string(),
                line,
                col: e.col as usize,
                kind: e.kind,
                message: e.message,
            });
        }
    }
    if let Some(open) = program.opening_percent {
        if !program.closed && !interp.ended() && !interp.waiting() {
            errors.push(Diagnostic {
                file: file.to_string(),
                line: open,
                col: 1,
                kind: ErrorKind::Flow,
                message: "program opened with '%' is never closed by a '%' line".into(),
            });
        }
    }
    // Subroutines and loops run lines out of order: report in line order.
    errors.sort_by_key(|d| (d.line, d.col));
    if errors.is_empty() {
        Ok(out)
    } else {
        Err(errors)
    }
}
