//! A large program run with memory bounded by the look-ahead, not by the program
//! (issue 33): two passes over the file. The first ([`pieces::check_file`]) checks
//! every line and pre-flights every block, keeping counts and findings; the second
//! compiles it again a piece at a time and feeds the pieces to the running job
//! ([`Feeder`], through [`JobHooks::feed`]), keeping [`FEED_AHEAD`] blocks beyond the
//! controller's acknowledgements, while the link drops what the controller can no
//! longer ask for. Each block's path is derived once per pass: by the pre-flight in
//! the first, by the planner in the second.
//!
//! Used for programs over [`STREAM_ABOVE_BYTES`] without O-words and without a
//! cutting load (statics); others are compiled whole as before. What such a run does
//! not report: the deviation of merged curves from their chords (the meter needs
//! the whole program).

use super::pieces::{self, Pieces, Stop};
use super::{exit, CompressionSummary, Failure, PreflightSummary, Report, RunOptions, RunResult};
use crate::link::{JobHooks, LinkView};
use pkmc::config::MachineConfig;
use pkmc::motion::block::Block;
use pkmc::wire::{Control, Status};
use std::path::Path;

/// Programs larger than this, bytes, are compiled and streamed a piece at a time.
pub const STREAM_ABOVE_BYTES: u64 = 16 << 20;
/// Blocks kept planned ahead of the controller's acknowledgements: far more than any
/// stop needs, so the plans are those of the whole program.
pub const FEED_AHEAD: usize = 1 << 15;

/// Whether the program at `path` is run a piece at a time under `opts`: over
/// [`STREAM_ABOVE_BYTES`], or over the bytes the environment variable
/// `PKMC_STREAM_ABOVE_BYTES` names (to compare the two ways on a smaller program).
pub fn applies(path: &Path, opts: &RunOptions<'_>) -> bool {
    let above = std::env::var("PKMC_STREAM_ABOVE_BYTES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(STREAM_ABOVE_BYTES);
    opts.statics.is_none() && std::fs::metadata(path).is_ok_and(|m| m.is_file() && m.len() > above)
}

/// The job's hooks, feeding the program's pieces while it runs.
pub struct Feeder<'h, 'o> {
    inner: &'h mut dyn JobHooks,
    pieces: Pieces<'o>,
    /// Why the pieces stopped early (the second pass found what the first did not:
    /// the file changed between them).
    pub failed: Option<Failure>,
}

impl JobHooks for Feeder<'_, '_> {
    fn status(&mut self, status: &Status) {
        self.inner.status(status);
    }
    fn control(&mut self, link: &LinkView) -> Option<Control> {
        if self.failed.is_some() {
            return Some(Control::Abort);
        }
        self.inner.control(link)
    }
    fn ends_at_pause(&self) -> bool {
        self.inner.ends_at_pause()
    }
    fn note(&mut self, text: &str) {
        self.inner.note(text);
    }
    fn feed(&mut self, link: &LinkView, out: &mut Vec<Block>) -> bool {
        if self.failed.is_some() {
            return false;
        }
        if link.total.saturating_sub(link.acked) > FEED_AHEAD {
            return true;
        }
        match self.pieces.next_piece() {
            Ok(Some(p)) => {
                out.extend(p.blocks);
                true
            }
            Ok(None) if self.pieces.errors().is_empty() => false,
            Ok(None) => {
                self.failed = Some(super::compile::refused(self.pieces.errors()));
                false
            }
            Err(Stop::Read(f)) => {
                self.failed = Some(f);
                false
            }
            Err(Stop::NeedsWhole) => {
                self.failed = Some(Failure::new(
                    exit::BAD_INPUT,
                    "the program changed while it ran (it has O-words now)",
                ));
                false
            }
        }
    }
}

/// The first pieces of the second pass: blocks to start the job with.
fn first_blocks(pieces: &mut Pieces<'_>) -> Result<Vec<Block>, Failure> {
    let mut blocks = Vec::new();
    while blocks.len() < FEED_AHEAD {
        match pieces.next_piece() {
            Ok(Some(p)) => blocks.extend(p.blocks),
            Ok(None) => break,
            Err(Stop::Read(f)) => return Err(f),
            Err(Stop::NeedsWhole) => {
                return Err(Failure::new(
                    exit::BAD_INPUT,
                    "the program changed (O-words)",
                ))
            }
        }
    }
    Ok(blocks)
}

/// `--check` of the program at `path` a piece at a time (see the module
/// documentation); `Ok(None)`: it has O-words, check it whole.
pub fn check(
    machine: &MachineConfig,
    path: &Path,
    opts: &RunOptions<'_>,
    hooks: &mut dyn JobHooks,
) -> Result<Option<RunResult>, Failure> {
    let compress = opts.compress.as_ref();
    let bytes = pieces::PIECE_BYTES;
    let Some(first) = pieces::check_file(path, machine, &opts.tools, compress, bytes)? else {
        return Ok(None);
    };
    let options = super::front_end_options(machine, machine.home, &opts.tools);
    let mut pieces = Pieces::open(path, &options, machine, compress, bytes)?;
    let start = first_blocks(&mut pieces)?;
    let mut feeder = Feeder {
        inner: hooks,
        pieces,
        failed: None,
    };
    let (end, status, stats, outcome) =
        super::run_in_process(machine, &start, None, None, opts, &mut feeder)?;
    if let Some(f) = feeder.failed {
        return Err(f);
    }
    let name = path.display().to_string();
    let mut report = Report::new(
        machine,
        &name,
        first.blocks,
        &end,
        &status,
        Some(&outcome),
        stats,
    );
    let pre = &first.preflight;
    report.preflight = Some(PreflightSummary {
        samples: pre.samples,
        min_singularity_margin: pre.min_margin.map(|(m, _)| m),
        min_margin_line: pre.min_margin.map(|(_, l)| l),
    });
    report.compression = Some(CompressionSummary {
        blocks_programmed: first.programmed,
        blocks_streamed: first.blocks,
        curves: first.curves,
        deviation: None,
    });
    Ok(Some(RunResult {
        report,
        sim: Some(outcome),
    }))
}

/// [`check`] when `check`, else [`run`].
pub fn check_or_run(
    machine: &MachineConfig,
    path: &Path,
    opts: &RunOptions<'_>,
    check: bool,
    hooks: &mut dyn JobHooks,
) -> Result<Option<RunResult>, Failure> {
    if check {
        self::check(machine, path, opts, hooks)
    } else {
        run(machine, path, opts, hooks)
    }
}

/// A run of the program at `path` (over a port or on `--sim`) a piece at a time;
/// `Ok(None)`: it has O-words, run it whole. The job carries no program mark, so a
/// replugged port or a `resume PROGRAM` cannot continue it (they need the whole
/// program's blocks).
pub fn run(
    machine: &MachineConfig,
    path: &Path,
    opts: &RunOptions<'_>,
    hooks: &mut dyn JobHooks,
) -> Result<Option<RunResult>, Failure> {
    let compress = opts.compress.as_ref();
    let bytes = pieces::PIECE_BYTES;
    let Some(first) = pieces::check_file(path, machine, &opts.tools, compress, bytes)? else {
        return Ok(None);
    };
    let options = super::front_end_options(machine, machine.home, &opts.tools);
    let mut pieces = Pieces::open(path, &options, machine, compress, bytes)?;
    let start = first_blocks(&mut pieces)?;
    let mut feeder = Feeder {
        inner: hooks,
        pieces,
        failed: None,
    };
    let mut opts = opts.clone();
    opts.sim.deviation = None;
    opts.link.mark = pkmc::wire::JobMark::default();
    let name = path.display().to_string();
    let at = |_| start.as_slice().into();
    let mut result = super::run_blocks_at(machine, &name, &at, None, &opts, &mut feeder)?;
    if let Some(f) = feeder.failed {
        return Err(f);
    }
    result.report.blocks_sent = first.blocks;
    result.report.compression = Some(CompressionSummary {
        blocks_programmed: first.programmed,
        blocks_streamed: first.blocks,
        curves: first.curves,
        deviation: None,
    });
    Ok(Some(result))
}
