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

use super::from_line::{Restart, RestartScan};
use super::pieces::{self, Pieces, Stop};
use super::resume::Resumed;
use super::{exit, CompressionSummary, Failure, PreflightSummary, Report, RunOptions, RunResult};
use crate::link::{JobHooks, Link, LinkView, Rewound, Transport};
use pkmc::config::MachineConfig;
use pkmc::motion::block::Block;
use pkmc::wire::{Control, JobMark, Status};
use std::cell::Cell;
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

/// Where the pieces come from: the file and how it is compiled.
#[derive(Clone, Copy)]
pub struct Source<'o> {
    path: &'o Path,
    options: &'o crate::gcode::Options,
    machine: &'o MachineConfig,
    compress: Option<&'o crate::gcode::compress::Settings>,
}

impl<'o> Source<'o> {
    /// The program at `path`, compiled with the front end's `options`, for `machine`
    /// as `opts` say (their merging options).
    fn new(
        path: &'o Path,
        options: &'o crate::gcode::Options,
        machine: &'o MachineConfig,
        opts: &'o RunOptions<'_>,
    ) -> Self {
        Source {
            path,
            options,
            machine,
            compress: opts.compress.as_ref(),
        }
    }

    /// The pieces from the program's start.
    fn open(&self) -> Result<Pieces<'o>, Failure> {
        let bytes = pieces::PIECE_BYTES;
        Pieces::open(self.path, self.options, self.machine, self.compress, bytes)
    }

    /// The pieces from block `to` on: the blocks from `to` to at least [`FEED_AHEAD`]
    /// further, where block `to` starts, and the pieces after them.
    fn open_at(&self, to: usize) -> Result<(Vec<Block>, [i64; 6], Pieces<'o>), Failure> {
        let mut pieces = self.open()?;
        let (mut seen, mut pose) = (0, self.options.start);
        let mut first = Vec::new();
        while seen < to {
            let Some(p) = next(&mut pieces)? else { break };
            let k = (to - seen).min(p.blocks.len());
            pose = super::pose_after(&p.blocks[..k], pose);
            seen += k;
            first.extend_from_slice(&p.blocks[k..]);
        }
        first.extend(first_blocks(&mut pieces)?);
        Ok((first, pose, pieces))
    }
}

/// The next piece, or why the pieces stopped.
fn next(pieces: &mut Pieces<'_>) -> Result<Option<pieces::Piece>, Failure> {
    match pieces.next_piece() {
        Ok(p) => Ok(p),
        Err(Stop::Read(f)) => Err(f),
        Err(Stop::NeedsWhole) => Err(Failure::new(
            exit::BAD_INPUT,
            "the program changed (it has O-words now)",
        )),
    }
}

/// The job's hooks, feeding the program's pieces while it runs.
pub struct Feeder<'h, 'o> {
    inner: &'h mut dyn JobHooks,
    source: Source<'o>,
    pieces: Pieces<'o>,
    /// A restart's (`--from`): the job's first blocks are its approach from where the
    /// machine stood when the job began, then the program's from the restart on.
    restart: Option<(&'o Restart, &'o Cell<[i64; 6]>)>,

    /// Why the pieces stopped early (the second pass found what the first did not:
    /// the file changed between them).
    pub failed: Option<Failure>,
}

impl<'h, 'o> Feeder<'h, 'o> {
    /// The first blocks of the program at `source` and the hooks that feed the rest.
    fn start(
        source: Source<'o>,
        inner: &'h mut dyn JobHooks,
    ) -> Result<(Vec<Block>, Self), Failure> {
        let mut pieces = source.open()?;
        let first = first_blocks(&mut pieces)?;
        let feeder = Feeder {
            inner,
            source,
            pieces,
            restart: None,
            failed: None,
        };
        Ok((first, feeder))
    }
}

impl Feeder<'_, '_> {
    /// The job's blocks from its block `to` on, and where that block starts
    /// ([`JobHooks::rewind`]); the pieces then go on after them.
    fn rewound(&mut self, to: usize) -> Result<(Vec<Block>, [i64; 6]), Failure> {
        let Some((r, began)) = self.restart else {
            let (first, pose, pieces) = self.source.open_at(to)?;
            self.pieces = pieces;
            return Ok((first, pose));
        };
        // After a restart the job's first blocks are its approach.
        let approach = r.approach(began.get());
        let n = approach.len();
        let (first, pose, pieces) = self.source.open_at(r.index + to.saturating_sub(n))?;
        self.pieces = pieces;
        if to >= n {
            return Ok((first, pose));
        }
        let at = super::pose_after(&approach[..to], began.get());
        let mut blocks = approach[to..].to_vec();
        blocks.extend(first);
        Ok((blocks, at))
    }
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
    fn rewind(&mut self, to: usize) -> Option<Rewound> {
        Some(self.rewound(to).map_err(|f| f.message))
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

/// The first pass over the program at `path` ([`pieces::check_file_from`]; from
/// `restart`'s approach when given); `None`: it has O-words.
fn first_pass(
    machine: &MachineConfig,
    path: &Path,
    opts: &RunOptions<'_>,
    restart: Option<&Restart>,
) -> Result<Option<pieces::FirstPass>, Failure> {
    let (tools, compress) = (&opts.tools, opts.compress.as_ref());
    pieces::check_file_from(path, machine, tools, compress, pieces::PIECE_BYTES, restart)
}

/// The first pieces of the second pass: blocks to start the job with.
fn first_blocks(pieces: &mut Pieces<'_>) -> Result<Vec<Block>, Failure> {
    let mut blocks = Vec::new();
    while blocks.len() < FEED_AHEAD {
        match next(pieces)? {
            Some(p) => blocks.extend(p.blocks),
            None => break,
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
    let Some(first) = first_pass(machine, path, opts, None)? else {
        return Ok(None);
    };
    let options = super::front_end_options(machine, machine.home, &opts.tools);
    let source = Source::new(path, &options, machine, opts);
    let (start, mut feeder) = Feeder::start(source, hooks)?;
    checked(
        machine,
        path,
        (&first, first.blocks),
        &start,
        opts,
        &mut feeder,
    )
    .map(Some)
}

/// The in-process run of a `--check` that starts with `blocks`, `feeder` feeding the
/// rest (`total` blocks in all), and its report (`first`: what the first pass found).
fn checked(
    machine: &MachineConfig,
    path: &Path,
    (first, total): (&pieces::FirstPass, usize),
    blocks: &[Block],
    opts: &RunOptions<'_>,
    feeder: &mut Feeder<'_, '_>,
) -> Result<RunResult, Failure> {
    let (end, status, stats, outcome) =
        super::run_in_process(machine, blocks, None, None, opts, feeder)?;
    if let Some(f) = feeder.failed.take() {
        return Err(f);
    }
    let name = path.display().to_string();
    let mut report = Report::new(machine, &name, total, &end, &status, Some(&outcome), stats);
    let pre = &first.preflight;
    report.preflight = Some(PreflightSummary {
        samples: pre.samples,
        min_singularity_margin: pre.min_margin.map(|(m, _)| m),
        min_margin_line: pre.min_margin.map(|(_, l)| l),
    });
    report.compression = Some(summary(first));
    Ok(RunResult {
        report,
        sim: Some(outcome),
    })
}

/// The compression summary of a program run a piece at a time (the deviation of its
/// curves is not measured: the meter needs the whole program).
fn summary(first: &pieces::FirstPass) -> CompressionSummary {
    CompressionSummary {
        blocks_programmed: first.programmed,
        blocks_streamed: first.blocks,
        curves: first.curves,
        deviation: None,
    }
}

/// [`check`] when `check`, else [`run`]; from a line (`nc-send --from`) with
/// `from` ([`restart`]).
pub fn check_or_run(
    machine: &MachineConfig,
    path: &Path,
    opts: &RunOptions<'_>,
    check: bool,
    from: Option<Restarting>,
    hooks: &mut dyn JobHooks,
) -> Result<Option<RunResult>, Failure> {
    match from {
        Some(from) => restart(machine, path, opts, from, check, hooks),
        None if check => self::check(machine, path, opts, hooks),
        None => run(machine, path, opts, hooks),
    }
}

/// A run of the program at `path` (over a port or on `--sim`) a piece at a time;
/// `Ok(None)`: it has O-words, run it whole. The job carries the program's mark (from
/// the first pass): a replugged port, or `resume PROGRAM` after a pause with nobody at
/// a terminal, continues it ([`JobHooks::rewind`], [`continue_program`]).
pub fn run(
    machine: &MachineConfig,
    path: &Path,
    opts: &RunOptions<'_>,
    hooks: &mut dyn JobHooks,
) -> Result<Option<RunResult>, Failure> {
    let Some(first) = first_pass(machine, path, opts, None)? else {
        return Ok(None);
    };
    let options = super::front_end_options(machine, machine.home, &opts.tools);
    let source = Source::new(path, &options, machine, opts);
    let (start, mut feeder) = Feeder::start(source, hooks)?;
    let at = |_| start.as_slice().into();
    let total = (&first, first.blocks);
    ran(machine, path, total, first.mark, &at, opts, &mut feeder).map(Some)
}

/// The run of a job that starts with the blocks `at` gives for the pose where the
/// machine stands, `feeder` feeding the rest (`total` blocks in all), with the
/// program's `mark`, and its report.
fn ran<'b>(
    machine: &MachineConfig,
    path: &Path,
    (first, total): (&pieces::FirstPass, usize),
    mark: JobMark,
    at: &dyn Fn([i64; 6]) -> std::borrow::Cow<'b, [Block]>,
    opts: &RunOptions<'_>,
    feeder: &mut Feeder<'_, '_>,
) -> Result<RunResult, Failure> {
    let mut opts = opts.clone();
    opts.sim.deviation = None;
    // The controller keeps it with the job: a replug or `resume PROGRAM` continues it.
    opts.link.mark = mark;
    let name = path.display().to_string();
    let mut result = super::run_blocks_at(machine, &name, at, None, &opts, feeder)?;
    if let Some(f) = feeder.failed.take() {
        return Err(f);
    }
    result.report.blocks_sent = total;
    result.report.compression = Some(summary(first));
    Ok(result)
}

/// `nc-send --from LINE` (said on stderr with `say`).
#[derive(Clone, Copy, Debug)]
pub struct Restarting {
    /// The line.
    pub line: u32,
    /// Say what the restart does.
    pub say: bool,
}

impl Restarting {
    /// `--from line`, if given.
    pub fn at(line: Option<u32>, say: bool) -> Option<Self> {
        line.map(|line| Self { line, say })
    }
}

/// `--from LINE` of the program at `path` a piece at a time: the pieces are read up
/// to the restart ([`RestartScan`]), the first pass pre-flights the approach and the
/// blocks from the restart on, and the job is the approach from where the machine
/// stands, then the program's pieces from the restart on ([`crate::job::from_line`]).
/// `Ok(None)`: it has O-words (restart it whole).
fn restart(
    machine: &MachineConfig,
    path: &Path,
    opts: &RunOptions<'_>,
    from: Restarting,
    check: bool,
    hooks: &mut dyn JobHooks,
) -> Result<Option<RunResult>, Failure> {
    let options = super::front_end_options(machine, machine.home, &opts.tools);
    let source = Source::new(path, &options, machine, opts);
    let name = path.display().to_string();
    let mut scan = RestartScan::new(from.line, machine.home)?;
    let mut pieces = source.open()?;
    loop {
        match pieces.next_piece() {
            Ok(Some(p)) if scan.add(&p.blocks) => break,
            Ok(Some(_)) => {}
            Ok(None) => break,
            Err(Stop::NeedsWhole) => return Ok(None),
            Err(Stop::Read(f)) => return Err(f),
        }
    }
    if !pieces.errors().is_empty() {
        return Err(super::compile::refused(pieces.errors()));
    }
    drop(pieces);
    let restart = scan.finish(&name)?;
    let Some(first) = first_pass(machine, path, opts, Some(&restart))? else {
        return Ok(None);
    };
    if from.say {
        eprintln!("{}", restart.describe(&name));
    }
    let began = Cell::new(machine.home);
    let (rest, _, pieces) = source.open_at(restart.index)?;
    let total = restart.approach_len() + first.blocks - restart.index;
    let mut feeder = Feeder {
        inner: hooks,
        source,
        pieces,
        restart: Some((&restart, &began)),
        failed: None,
    };
    let with_approach = |pose| {
        began.set(pose);
        let mut blocks = restart.approach(pose);
        blocks.extend_from_slice(&rest);
        blocks
    };
    if check {
        let blocks = with_approach(machine.home);
        let total = (&first, total);
        return checked(machine, path, total, &blocks, opts, &mut feeder).map(Some);
    }
    // The controller's count reaches the restart's block after the approach.
    let mut mark = first.mark;
    let n = restart.approach_len() as u32;
    mark.next_block = (restart.index as u32).wrapping_sub(n);
    let at = |pose| with_approach(pose).into();
    let total = (&first, total);
    ran(machine, path, total, mark, &at, opts, &mut feeder).map(Some)
}

/// `resume PROGRAM` of a held job whose program is run a piece at a time: the first
/// pass checks the program and its mark against the held job's, then its pieces are
/// fed from the first block the controller never received. `Ok(None)`: it has O-words
/// (continue it whole).
pub fn continue_program<T: Transport>(
    link: &mut Link<T>,
    held: JobMark,
    path: &Path,
    machine: &MachineConfig,
    opts: &RunOptions<'_>,
    hooks: &mut dyn JobHooks,
) -> Result<Option<Resumed>, Failure> {
    let Some(first) = first_pass(machine, path, opts, None)? else {
        return Ok(None);
    };
    super::resume::same_program(path, &first.mark, &held)?;
    let options = super::front_end_options(machine, machine.home, &opts.tools);
    let source = Source::new(path, &options, machine, opts);
    let (rest, start, pieces) = source.open_at(held.next_block as usize)?;
    let mut feeder = Feeder {
        inner: hooks,
        source,
        pieces,
        restart: None,
        failed: None,
    };
    let end = link.continue_job(held, &rest, start, &mut feeder)?;
    if let Some(f) = feeder.failed {
        return Err(f);
    }
    Ok(Some(Resumed {
        end,
        blocks_sent: Some(first.blocks.saturating_sub(held.next_block as usize)),
        incomplete: None,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use pkmc::motion::block::Motion;

    /// Blocks fed from block `to` on ([`Source::open_at`], then the pieces after it)
    /// are the program's from `to` on, and start where block `to - 1` ends.
    #[test]
    fn a_program_taken_up_again_at_a_block_goes_on_with_the_same_blocks_from_there() {
        let machine = MachineConfig::cartesian_xyz();
        let mut text = String::from("G21 G90 G64 P0.01\nG0 X0 Y0 Z5\nG1 Z0 F1200\n");
        for k in 0..70_000 {
            let x = (k % 1000) as f64 * 0.05;
            let y = (k / 1000) as f64 + 0.2 * (x * 0.7).sin();
            text += &format!("X{x:.3} Y{y:.3}\n");
            if k % 7000 == 6999 {
                text += "G4 P0.1\nM3 S1000\nG1 X0 Y0\n";
            }
        }
        text += "G0 Z5\nM2\n";
        let path = std::env::temp_dir().join(format!("pkmc-streamed-{}.ngc", std::process::id()));
        std::fs::write(&path, &text).unwrap();
        let tools = crate::gcode::ToolTable::new();
        let settings = crate::gcode::compress::Settings::default();
        for compress in [None, Some(&settings)] {
            let (whole, _) =
                super::super::compile_located(&text, "p", &machine, machine.home, &tools, compress)
                    .unwrap();
            let options = super::super::front_end_options(&machine, machine.home, &tools);
            let source = Source {
                path: &path,
                options: &options,
                machine: &machine,
                compress,
            };
            let n = whole.blocks.len();
            assert!(n > 2 * FEED_AHEAD || compress.is_some(), "{n} blocks");
            for to in [1, (n / 2 + 777).min(n - 1), n] {
                let (mut blocks, pose, mut pieces) = source.open_at(to).unwrap();
                while let Some(p) = next(&mut pieces).unwrap() {
                    blocks.extend(p.blocks);
                }
                assert_eq!(blocks, whole.blocks[to..], "from block {to}");
                let before = whole.blocks[..to]
                    .iter()
                    .rev()
                    .find(|b| !matches!(b.motion, Motion::Dwell(_) | Motion::Aux(_)))
                    .map_or(machine.home, |b| b.target);
                assert_eq!(pose, before, "from block {to}");
            }
        }
        std::fs::remove_file(&path).unwrap();
    }
}
