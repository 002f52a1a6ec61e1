//! A program file compiled a piece at a time, with state bounded by a piece and not by
//! the program (issue 33, bounded memory): the file is read in pieces of whole lines
//! (each checked as [`crate::input::read_text`] checks a whole file: no NUL byte,
//! UTF-8, the size limit), run through the front end with its state carried
//! ([`gcode::flow::chunked`]), made into blocks ([`gcode::blocks::Converter`]) and
//! merged into curves with the last run of short moves held over to the next piece
//! ([`gcode::compress::last_run_start`]) and the last blendable block held over for
//! the corner's blend ([`gcode::compress::blend::Blender`]), so the blocks are those
//! of the whole program compiled at once (a piece's `programmed` may then hold the
//! programmed moves of a block handed out with the next piece). [`check_file`] is the first pass over a file: every line
//! and the pre-flight of every block, keeping only counts and findings.
//!
//! A program with O-words (subroutines, branches, loops) runs only as a whole: it is
//! compiled as before ([`Stop::NeedsWhole`]).

use super::{exit, Failure};
use crate::analysis::preflight::{Accumulator, Chords, Preflight};
use crate::gcode::{self, blocks::Converter, canon::Canon, flow::chunked::Chunked};
use pkmc::config::{MachineConfig, AXES};
use pkmc::motion::block::{Block, Motion};
use std::io::Read;
use std::ops::Range;
use std::path::Path;

/// Bytes read at a time.
pub const PIECE_BYTES: usize = 1 << 18;
/// Most programmed blocks held over for one run of short moves still open at a
/// piece's end; a longer run is cut there (its curves may then differ from those of
/// the program compressed at once).
pub const MAX_HELD: usize = 1 << 18;

/// Why the pieces stop.
#[derive(Debug)]
pub enum Stop {
    /// The file could not be read as a program (the message names it).
    Read(Failure),
    /// The program has O-words: compile it whole.
    NeedsWhole,
}

/// A program file read in pieces of whole lines.
struct Lines {
    file: std::io::Take<std::fs::File>,
    name: String,
    limit: u64,
    piece_bytes: usize,
    /// Bytes read and not yet handed out: they start at a line's start.
    carry: Vec<u8>,
    /// Lines handed out before `carry`.
    line: usize,
    total: u64,
    done: bool,
}

impl Lines {
    fn open(path: &Path, limit: u64, piece_bytes: usize) -> Result<Self, Failure> {
        let name = path.display().to_string();
        let file = std::fs::File::open(path)
            .map_err(|e| Failure::new(exit::BAD_INPUT, format!("{name}: cannot read: {e}")))?;
        Ok(Self {
            file: file.take(limit + 1),
            name,
            limit,
            piece_bytes,
            carry: Vec::new(),
            line: 0,
            total: 0,
            done: false,
        })
    }

    /// Line and column (1-based) of byte `at` of `carry`.
    fn place(&self, at: usize) -> (usize, usize) {
        let before = &self.carry[..at];
        let line = self.line + before.iter().filter(|&&b| b == b'\n').count() + 1;
        let col = at
            - before
                .iter()
                .rposition(|&b| b == b'\n')
                .map_or(0, |p| p + 1)
            + 1;
        (line, col)
    }

    fn fail(&self, what: String) -> Failure {
        Failure::new(exit::BAD_INPUT, what)
    }

    /// The next piece of whole lines (the last one is the rest of the file), and
    /// whether it is the last.
    fn next(&mut self) -> Result<Option<(String, bool)>, Failure> {
        if self.done {
            return Ok(None);
        }
        let mut chunk = vec![0u8; self.piece_bytes.max(1)];
        let cut = loop {
            let n = match self.file.read(&mut chunk) {
                Ok(n) => n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(self.fail(format!("{}: cannot read: {e}", self.name))),
            };
            if let Some(i) = chunk[..n].iter().position(|&b| b == 0) {
                let at = self.carry.len() + i;
                self.carry.extend_from_slice(&chunk[..i]);
                let (line, col) = self.place(at);
                let what = format!(
                    "{}:{line}:{col}: NUL byte (binary data, not text)",
                    self.name
                );
                return Err(self.fail(what));
            }
            self.total += n as u64;
            if self.total > self.limit {
                let what = format!(
                    "{}: larger than {} MiB: refused",
                    self.name,
                    self.limit >> 20
                );
                return Err(self.fail(what));
            }
            let from = self.carry.len();
            self.carry.extend_from_slice(&chunk[..n]);
            if n == 0 {
                self.done = true;
                break self.carry.len();
            }
            if let Some(p) = self.carry[from..].iter().rposition(|&b| b == b'\n') {
                break from + p + 1;
            }
        };
        let rest = self.carry.split_off(cut);
        let piece = std::mem::replace(&mut self.carry, rest);
        match String::from_utf8(piece) {
            Ok(text) => {
                self.line += text.bytes().filter(|&b| b == b'\n').count();
                Ok(Some((text, self.done)))
            }
            Err(e) => {
                let at = e.utf8_error().valid_up_to();
                let piece = e.into_bytes();
                self.carry = piece; // the rest is dropped: reading stops here
                let (line, col) = self.place(at);
                let what = format!("{}:{line}:{col}: not text (invalid UTF-8)", self.name);
                Err(self.fail(what))
            }
        }
    }
}

/// Blocks of one piece of a program.
#[derive(Clone, Debug, Default)]
pub struct Piece {
    /// The blocks to stream.
    pub blocks: Vec<Block>,
    /// The programmed blocks they stand for.
    pub programmed: Vec<Block>,
    /// For each block, the programmed blocks it stands for (indices in the whole
    /// program).
    pub source: Vec<Range<usize>>,
    /// Where the first block starts.
    pub start: [i64; AXES],
    /// The program index of `programmed[0]`.
    pub programmed_first: usize,
    /// Where `programmed[0]` starts.
    pub programmed_start: [i64; AXES],
}

/// A program file compiled a piece at a time.
pub struct Pieces<'o> {
    lines: Lines,
    front: Chunked<'o>,
    conv: Converter,
    compress: Option<gcode::compress::Settings>,
    /// Corners blended across pieces: the last blendable block of a piece waits for
    /// the next piece's first.
    blender: Option<gcode::compress::blend::Blender>,
    /// Programmed blocks not yet handed out (an open run of short moves).
    held: Vec<Block>,
    /// Where `held` starts, and how many programmed blocks came before it.
    held_start: [i64; AXES],
    held_index: usize,
    canon: Vec<Canon>,
    ended: bool,
}

impl<'o> Pieces<'o> {
    /// The program at `path` for `machine` with the front end's `options` (which
    /// start it at `options.start`), merged into curves with `compress`.
    pub fn open(
        path: &Path,
        options: &'o gcode::Options,
        machine: &MachineConfig,
        compress: Option<&gcode::compress::Settings>,
        piece_bytes: usize,
    ) -> Result<Self, Failure> {
        let lines = Lines::open(path, crate::input::MAX_PROGRAM_BYTES, piece_bytes)?;
        let front = Chunked::new(options, &lines.name);
        let compress = compress.map(|s| super::compile::for_machine(s, machine));
        Ok(Self {
            lines,
            front,
            conv: Converter::new(options.start),
            blender: compress
                .as_ref()
                .map(|s| gcode::compress::blend::Blender::new(s, options.start)),
            compress,
            held: Vec::new(),
            held_start: options.start,
            held_index: 0,
            canon: Vec::new(),
            ended: false,
        })
    }

    /// Errors of the front end so far, in line order once the pieces are out.
    pub fn errors(&self) -> &[gcode::Diagnostic] {
        &self.front.errors
    }

    /// The next piece of blocks (empty while a run is held over), or `None` at the
    /// end. Once the front end has found an error, no more blocks come (the lines
    /// are still checked).
    pub fn next_piece(&mut self) -> Result<Option<Piece>, Stop> {
        if self.ended {
            return Ok(None);
        }
        self.canon.clear();
        let last = match self.lines.next().map_err(Stop::Read)? {
            Some((text, last)) => {
                self.front
                    .feed(&text, last, &mut self.canon)
                    .map_err(|_| Stop::NeedsWhole)?;
                last
            }
            None => true,
        };
        if last {
            self.ended = true;
            self.front.finish(&mut self.canon);
        }
        if !self.front.errors.is_empty() {
            return Ok(Some(Piece::default()));
        }
        let mut program = gcode::blocks::Program::default();
        self.conv.push(&self.canon, &mut program);
        self.held.extend(program.blocks);
        Ok(Some(self.hand_out(last)))
    }

    /// The held blocks up to the last run (all of them at the end), compressed.
    fn hand_out(&mut self, last: bool) -> Piece {
        let (cut, pose) = match &self.compress {
            Some(s) if !last && self.held.len() <= MAX_HELD => {
                gcode::compress::last_run_start(&self.held, self.held_start, s)
            }
            _ => (self.held.len(), self.conv.pose()),
        };
        let rest = self.held.split_off(cut);
        let programmed = std::mem::replace(&mut self.held, rest);
        let mut start = self.held_start;
        let programmed_start = start;
        let first = self.held_index;
        self.held_start = pose;
        self.held_index += programmed.len();
        let (blocks, source) = match (&self.compress, &mut self.blender) {
            (Some(s), Some(blender)) => {
                // Compressed as the whole would be; its corners blended as the
                // whole's, the last blendable block held for the next piece.
                let c = gcode::compress::compress_runs(&programmed, start, s);
                let mut out = gcode::compress::Compressed::default();
                start = blender.emitted();
                blender.push(&programmed, &c, first, &mut out);
                if last {
                    blender.finish(&mut out);
                }
                (out.blocks, out.source)
            }
            _ => (
                programmed.clone(),
                (first..first + programmed.len())
                    .map(|i| i..i + 1)
                    .collect(),
            ),
        };
        Piece {
            blocks,
            programmed,
            source,
            start,
            programmed_first: first,
            programmed_start,
        }
    }
}

/// What the first pass found in a program file.
#[derive(Clone, Debug, Default)]
pub struct FirstPass {
    /// The pre-flight of every block to stream.
    pub preflight: Preflight,
    /// Blocks to stream.
    pub blocks: usize,
    /// Blocks as programmed.
    pub programmed: usize,
    /// Curves among the blocks to stream.
    pub curves: usize,
    /// The program's mark ([`super::resume::program_mark`] of every block).
    pub mark: pkmc::wire::JobMark,
}

/// The first pass over the program at `path` for `machine`: every line through the
/// front end and every block through the pre-flight, a piece at a time, keeping
/// counts and findings. `Ok(None)`: the program has O-words (compile it whole).
/// Fails as [`super::compile_job`] does: the front end's errors, or the pre-flight's
/// findings.
pub fn check_file(
    path: &Path,
    machine: &MachineConfig,
    tools: &gcode::ToolTable,
    compress: Option<&gcode::compress::Settings>,
    piece_bytes: usize,
) -> Result<Option<FirstPass>, Failure> {
    check_file_from(path, machine, tools, compress, piece_bytes, None)
}

/// [`check_file`] of a restart (`nc-send --from`): the pre-flight covers the restart's
/// approach from the program's start and the blocks from the restart on.
pub fn check_file_from(
    path: &Path,
    machine: &MachineConfig,
    tools: &gcode::ToolTable,
    compress: Option<&gcode::compress::Settings>,
    piece_bytes: usize,
    restart: Option<&super::from_line::Restart>,
) -> Result<Option<FirstPass>, Failure> {
    let options = super::pipeline::front_end_options(machine, machine.home, tools);
    let mut pieces = Pieces::open(path, &options, machine, compress, piece_bytes)?;
    let mut out = FirstPass::default();
    let mut acc = Accumulator::new(machine);
    let mut mark = super::resume::MarkHasher::default();
    // Blocks before this one are not pre-flighted (those before a restart).
    let from = restart.map_or(0, |r| r.index);
    if let Some(r) = restart {
        let approach = r.approach(machine.home);
        let paths = crate::analysis::preflight::paths(&approach, machine.home);
        acc.add(&approach, &paths, machine.home, None, &mut out.preflight);
    }
    let mut before: Option<Piece> = None;
    loop {
        let piece = match pieces.next_piece() {
            Ok(Some(p)) => p,
            Ok(None) => break,
            Err(Stop::NeedsWhole) => return Ok(None),
            Err(Stop::Read(f)) => return Err(f),
        };
        let k = from.saturating_sub(out.blocks).min(piece.blocks.len());
        let start = super::pose_after(&piece.blocks[..k], piece.start);
        let checked = &piece.blocks[k..];
        let paths = crate::analysis::preflight::paths(checked, start);
        // The programmed moves of this piece and the one before (a corner's blend
        // holds a piece's last block over to the next).
        let (first, chords_start) = match &before {
            Some(p) => (p.programmed_first, p.programmed_start),
            None => (piece.programmed_first, piece.programmed_start),
        };
        let mut programmed = before.take().map_or_else(Vec::new, |p| p.programmed);
        programmed.extend_from_slice(&piece.programmed);
        let chords = Chords {
            programmed: &programmed,
            first,
            start: chords_start,
            source: &piece.source[k..],
        };
        acc.add(checked, &paths, start, Some(&chords), &mut out.preflight);
        mark.add(&piece.blocks);
        out.blocks += piece.blocks.len();
        out.programmed += piece.programmed.len();
        out.curves += piece
            .blocks
            .iter()
            .filter(|b| matches!(b.motion, Motion::Cubic { .. }))
            .count();
        before = Some(piece);
    }
    if !pieces.errors().is_empty() {
        return Err(super::compile::refused(pieces.errors()));
    }
    let name = path.display().to_string();
    super::compile::refuse_findings(&name, out.preflight.clone())?;
    out.mark = mark.mark(super::resume::program_lines(path));
    Ok(Some(out))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A wavy path of short moves (merged into curves) with corners, a rapid, a
    /// dwell and a spindle command between runs.
    fn wavy() -> String {
        let mut t = String::from("G21 G90 G64 P0.01\nG0 X0 Y0 Z5\nG1 Z0 F1200\n");
        for k in 0..1500 {
            let x = k as f64 * 0.05;
            let y = 10.0 * (x / 7.0).sin();
            t.push_str(&format!("G1 X{x:.4} Y{y:.4}\n"));
            if k % 400 == 399 {
                t.push_str("G4 P0.1\nM3 S1000\nG1 X0 Y0\n");
            }
        }
        t.push_str("G0 Z5\nM2\n");
        t
    }

    fn compare(name: &str, text: &str, machine: &MachineConfig) {
        let path = std::env::temp_dir().join(format!("pkmc-pieces-{}-{name}", std::process::id()));
        std::fs::write(&path, text).unwrap();
        let tools = gcode::ToolTable::new();
        let settings = gcode::compress::Settings::default();
        for compress in [None, Some(&settings)] {
            let (whole, pre) =
                super::super::compile_located(text, "p", machine, machine.home, &tools, compress)
                    .unwrap();
            for piece_bytes in [7, 100, 4096, PIECE_BYTES] {
                let options = super::super::front_end_options(machine, machine.home, &tools);
                let mut p = Pieces::open(&path, &options, machine, compress, piece_bytes).unwrap();
                let (mut blocks, mut programmed, mut source) = (vec![], vec![], vec![]);
                while let Some(piece) = p.next_piece().unwrap() {
                    blocks.extend(piece.blocks);
                    programmed.extend(piece.programmed);
                    source.extend(piece.source);
                }
                let at = format!(
                    "{name}, compress {}, pieces of {piece_bytes}",
                    compress.is_some()
                );
                assert_eq!(blocks, whole.blocks, "{at}");
                assert_eq!(programmed, whole.programmed, "{at}");
                assert_eq!(source, whole.source, "{at}");
                let first = check_file(&path, machine, &tools, compress, piece_bytes)
                    .unwrap()
                    .unwrap();
                assert_eq!(first.preflight, pre, "{at}");
                assert_eq!(first.blocks, whole.blocks.len(), "{at}");
                assert_eq!(first.curves, whole.curves(), "{at}");
                let lines = super::super::resume::program_lines(&path);
                let mark = super::super::resume::program_mark(&whole.blocks, lines);
                assert_eq!(first.mark, mark, "{at}");
            }
        }
        std::fs::remove_file(&path).unwrap();
    }

    #[test]
    fn a_program_compiled_in_pieces_is_the_program_compiled_at_once() {
        let examples = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples");
        let square = std::fs::read_to_string(examples.join("square.ngc")).unwrap();
        compare("square", &square, &MachineConfig::cartesian_xyz());
        let tilt = std::fs::read_to_string(examples.join("h4-table-tilt.ngc")).unwrap();
        compare("tilt", &tilt, &MachineConfig::h4_table());
        compare("wavy", &wavy(), &MachineConfig::cartesian_xyz());
    }

    #[test]
    fn a_merged_run_that_leaves_the_travel_is_named_at_the_move_that_leaves_it() {
        // 0.05 mm moves along a gentle wave from X95 on; X's travel ends at 100.
        let mut text = String::from("G21 G90 G64 P0.01\nG0 X95 Y0 Z0\n");
        let mut leaving = None;
        for k in 1..=200 {
            let x = 95.0 + k as f64 * 0.05;
            let y = 2.0 * (x / 3.0).sin();
            text.push_str(&format!("G1 X{x:.2} Y{y:.4} F1200\n"));
            if x > 100.0 && leaving.is_none() {
                leaving = Some(k as u32 + 2);
            }
        }
        let leaving = leaving.unwrap();
        let m = MachineConfig::cartesian_xyz();
        let tools = gcode::ToolTable::new();
        let settings = gcode::compress::Settings::default();
        let path = std::env::temp_dir().join(format!("pkmc-pieces-{}-out", std::process::id()));
        std::fs::write(&path, &text).unwrap();
        for compress in [None, Some(&settings)] {
            let (whole, pre) =
                super::super::compile_located(&text, "p", &m, m.home, &tools, compress).unwrap();
            let at = format!("compress {}", compress.is_some());
            if compress.is_some() {
                assert!(
                    whole.blocks.len() * 10 < whole.programmed.len(),
                    "{at}: merged"
                );
            }
            let lines: Vec<u32> = pre.findings.iter().map(|f| f.line).collect();
            assert_eq!(lines.first(), Some(&leaving), "{at}: {:?}", pre.findings);
            assert!(lines.iter().all(|l| *l >= leaving), "{at}: {lines:?}");
            // Compiled in pieces, the same refusal (a corner's blend held over).
            let whole = super::super::compile_job(&path, &m, &tools, compress).unwrap_err();
            assert!(
                whole.message.contains(&format!(":{leaving}: joint q1")),
                "{at}: {}",
                whole.message
            );
            for piece_bytes in [300, 4096] {
                let first = check_file(&path, &m, &tools, compress, piece_bytes).unwrap_err();
                assert_eq!(
                    first.message, whole.message,
                    "{at}, pieces of {piece_bytes}"
                );
            }
        }
        std::fs::remove_file(&path).unwrap();
    }

    #[test]
    fn errors_and_findings_are_those_of_the_whole_and_o_words_need_the_whole() {
        let m = MachineConfig::cartesian_xyz();
        let tools = gcode::ToolTable::new();
        let path = std::env::temp_dir().join(format!("pkmc-pieces-{}-bad", std::process::id()));
        let cases = [
            "G1 X1 F100\nG1 X2 Q1\nG1 X3\nG1 X4 Y\n",
            "G1 X1 F100\nG1 X500\nG1 X0\nG1 Z90\n",
        ];
        for text in cases {
            std::fs::write(&path, text).unwrap();
            let whole = super::super::compile_job(&path, &m, &tools, None).unwrap_err();
            for piece_bytes in [5, 4096] {
                let first = check_file(&path, &m, &tools, None, piece_bytes).unwrap_err();
                assert_eq!((first.code, &first.message), (whole.code, &whole.message));
            }
        }
        std::fs::write(&path, "G1 X1 F100\nO100 sub\nG1 X2\nO100 endsub\nM2\n").unwrap();
        assert!(check_file(&path, &m, &tools, None, 8).unwrap().is_none());
        std::fs::write(&path, "G1 X1 F100\n(caf\u{e9})\nG1 X2\n").unwrap();
        let mut bytes = std::fs::read(&path).unwrap();
        bytes[17] = 0xff;
        std::fs::write(&path, &bytes).unwrap();
        let whole = super::super::compile_job(&path, &m, &tools, None).unwrap_err();
        let first = check_file(&path, &m, &tools, None, 4).unwrap_err();
        assert_eq!(first.message, whole.message);
        std::fs::remove_file(&path).unwrap();
    }
}
