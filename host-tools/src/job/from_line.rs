//! `nc-send --from LINE`: a program restarted from a line, as LinuxCNC's run-from-line
//! does: the whole program is interpreted from its first line (so every modal group,
//! offset, unit, feed, tool and parameter is what it would be at LINE), the blocks
//! before LINE are not run, and the machine is brought to where LINE starts by a
//! move planned safely from wherever it stands:
//!
//! 1. straight up (Z only, rapid) to the clearance: the highest Z of the present pose,
//!    of LINE's start, and of every block end before LINE;
//! 2. across at the clearance (rapid) to LINE's start in X Y A B C;
//! 3. the spindle and coolant as the program had set them before LINE (the last M3,
//!    M4 or M5 with its speed; M7 and M8 on unless an M9 followed); the tool is the
//!    program's last tool change before LINE, which is not repeated (it is named);
//! 4. down to LINE's start at the feed of the first feed move from LINE on (a rapid if
//!    there is none), as the program would have entered it.
//!
//! The pre-flight covers those moves and the rest of the program from LINE, not what
//! comes before it.

use super::{exit, moves, Compiled, Failure};
use pkmc::config::AXES;
use pkmc::motion::block::{Aux, Block, Motion};

/// Where a program restarts, and what to set up before it.
#[derive(Clone, Debug)]
pub struct Restart {
    /// The line asked for.
    pub line: u32,
    /// Index of the first block run (the first at or after `line`).
    pub index: usize,
    /// Pose where that block starts.
    pub start: [i64; AXES],
    /// The clearance height before the approach (the highest Z so far).
    pub clearance: i64,
    /// Spindle and coolant blocks to restore, in order.
    pub aux: Vec<Block>,
    /// The tool the program loaded last before `line` (0: none).
    pub tool: u32,
    /// Feed of the plunge to `start`, nm/s (0: a rapid).
    pub feed: i64,
}

/// Finds the restart at `line` in `compiled` (named `name`).
pub fn restart_at(compiled: &Compiled, line: u32, name: &str) -> Result<Restart, Failure> {
    let mut scan = RestartScan::new(line, compiled.start)?;
    scan.add(&compiled.blocks);
    scan.finish(name)
}

/// The restart at a line, found as the program's blocks come (the whole program, or
/// its pieces: [`super::streamed`]): the state the blocks before it leave, and the
/// feed of the first feed move from it on.
pub struct RestartScan {
    line: u32,
    origin: [i64; AXES],
    /// Blocks seen.
    seen: usize,
    /// The first block at or after `line`, once seen.
    index: Option<usize>,
    start: [i64; AXES],
    clearance: i64,
    spindle: Option<Block>,
    mist: Option<Block>,
    flood: Option<Block>,
    tool: u32,
    feed: Option<i64>,
    last_line: u32,
}

impl RestartScan {
    /// A scan for `line` of a program that starts at `origin`.
    pub fn new(line: u32, origin: [i64; AXES]) -> Result<Self, Failure> {
        if line == 0 {
            return Err(Failure::new(
                exit::BAD_INPUT,
                "--from 0: lines count from 1",
            ));
        }
        Ok(Self {
            line,
            origin,
            seen: 0,
            index: None,
            start: origin,
            clearance: origin[2],
            spindle: None,
            mist: None,
            flood: None,
            tool: 0,
            feed: None,
            last_line: 0,
        })
    }

    /// The next of the program's blocks; true once the restart is known (the rest
    /// need not be given).
    pub fn add(&mut self, blocks: &[Block]) -> bool {
        for b in blocks {
            if self.feed.is_some() {
                break;
            }
            self.last_line = self.last_line.max(b.line);
            if self.index.is_none() && b.line >= self.line {
                self.index = Some(self.seen);
            }
            self.seen += 1;
            if self.index.is_some() {
                if b.motion != Motion::Rapid && moves(b) {
                    self.feed = Some(b.feed);
                }
                continue;
            }
            match b.motion {
                Motion::Aux(Aux::SpindleOff | Aux::SpindleCw(_) | Aux::SpindleCcw(_)) => {
                    self.spindle = Some(*b)
                }
                Motion::Aux(Aux::Mist) => self.mist = Some(*b),
                Motion::Aux(Aux::Flood) => self.flood = Some(*b),
                Motion::Aux(Aux::CoolantOff) => (self.mist, self.flood) = (None, None),
                Motion::Aux(Aux::ToolChange(t)) => self.tool = t,
                _ if moves(b) => {
                    self.start = b.target;
                    self.clearance = self.clearance.max(b.target[2]);
                }
                _ => {}
            }
        }
        self.feed.is_some()
    }

    /// The restart, once the program's blocks (up to [`RestartScan::add`]'s true) were
    /// given; an error names the program (`name`) and its last line when it has no
    /// block at or after the line.
    pub fn finish(self, name: &str) -> Result<Restart, Failure> {
        let Some(index) = self.index else {
            let (line, last) = (self.line, self.last_line);
            return Err(Failure::new(
                exit::BAD_INPUT,
                format!("--from {line}: {name} has no block at or after line {line} (its last is line {last})"),
            ));
        };
        let aux = [self.spindle, self.mist, self.flood]
            .into_iter()
            .flatten()
            .collect();
        Ok(Restart {
            line: self.line,
            index,
            start: self.start,
            clearance: self.clearance.max(self.origin[2]),
            aux,
            tool: self.tool,
            feed: self.feed.unwrap_or(0),
        })
    }
}

impl Restart {
    /// The approach from `pose` to the restart's start, then the program's blocks
    /// from the restart on (see the module documentation).
    pub fn blocks_from(&self, pose: [i64; AXES], blocks: &[Block]) -> Vec<Block> {
        let mut out = self.approach(pose);
        out.extend_from_slice(&blocks[self.index..]);
        out
    }

    /// The approach from `pose` to the restart's start.
    pub fn approach(&self, pose: [i64; AXES]) -> Vec<Block> {
        let z = self.clearance.max(pose[2]);
        let at = |motion, target, feed| Block {
            line: self.line,
            motion,
            target,
            feed,
            tolerance_nm: 0,
        };
        let mut up = pose;
        up[2] = z;
        let mut across = self.start;
        across[2] = z;
        let mut out = vec![at(Motion::Rapid, up, 0), at(Motion::Rapid, across, 0)];
        out.extend(self.aux.iter().map(|b| Block {
            line: self.line,
            ..*b
        }));
        let down = if self.feed > 0 {
            Motion::Linear
        } else {
            Motion::Rapid
        };
        out.push(at(down, self.start, self.feed));
        out
    }

    /// Blocks of the approach (before the program's own).
    pub fn approach_len(&self) -> usize {
        3 + self.aux.len()
    }

    /// What the restart does, in words (for stderr).
    pub fn describe(&self, name: &str) -> String {
        let tool = match self.tool {
            0 => String::new(),
            t => format!(
                "; the tool must be T{t} (the program's last tool change before it, not repeated)"
            ),
        };
        format!(
            "{name}: from line {} (block {}): up to Z{:.4}, across to X{:.4} Y{:.4}, {} \
             spindle/coolant block(s) restored, down to Z{:.4}{tool}",
            self.line,
            self.index + 1,
            self.clearance as f64 / 1e6,
            self.start[0] as f64 / 1e6,
            self.start[1] as f64 / 1e6,
            self.aux.len(),
            self.start[2] as f64 / 1e6
        )
    }
}

/// Compiles `path` for a restart at `line` (said on stderr with `say`): the program interpreted from its start,
/// its pre-flight from the restart on (the approach from the program's start pose,
/// then the rest). Returns the whole program and the restart.
pub fn compile_from(
    path: &std::path::Path,
    machine: &pkmc::config::MachineConfig,
    opts: &super::RunOptions<'_>,
    line: u32,
    say: bool,
) -> Result<(Compiled, Restart), Failure> {
    let text = crate::input::read_text(path, crate::input::MAX_PROGRAM_BYTES)
        .map_err(|m| Failure::new(exit::BAD_INPUT, m))?;
    let name = path.display().to_string();
    let compress = opts.compress.as_ref();
    let (compiled, _) =
        super::compile_located(&text, &name, machine, machine.home, &opts.tools, compress)
            .map_err(|errs| super::compile::refused(&errs))?;
    let restart = restart_at(&compiled, line, &name)?;
    let run = restart.blocks_from(compiled.start, &compiled.blocks);
    // The approach stands for no programmed move; the rest for what they stood for.
    let mut source = vec![0..0; restart.approach_len()];
    source.extend_from_slice(&compiled.source[restart.index..]);
    let chords = crate::analysis::preflight::Chords {
        source: &source,
        ..compiled.chords()
    };
    let paths = crate::analysis::preflight::paths(&run, compiled.start);
    let pre = crate::analysis::preflight::check_paths(
        &run,
        &paths,
        machine,
        compiled.start,
        Some(&chords),
    );
    if !pre.findings.is_empty() {
        // As the whole program's refusal words them: a stretch of lines in one.
        let lines = super::compile::findings_text(&name, &pre.findings);
        return Err(Failure::new(
            exit::PREFLIGHT,
            format!(
                "{}\n{} pre-flight problem(s) from line {line} on; nothing was sent",
                lines.join("\n"),
                pre.findings.len()
            ),
        ));
    }
    if say {
        eprintln!("{}", restart.describe(&name));
    }
    Ok((compiled, restart))
}

/// The blocks to stream when the machine stands at `pose`: the program, or the
/// restart's approach and the rest.
pub fn blocks_at<'b>(
    blocks: &'b [Block],
    restart: Option<&Restart>,
    pose: [i64; AXES],
) -> std::borrow::Cow<'b, [Block]> {
    match restart {
        Some(r) => r.blocks_from(pose, blocks).into(),
        None => blocks.into(),
    }
}

/// `compiled` as it runs from `restart` when the machine stands at `pose`: the
/// approach and the rest, each block standing for itself.
pub fn restarted(compiled: &Compiled, restart: &Restart, pose: [i64; AXES]) -> Compiled {
    let blocks = restart.blocks_from(pose, &compiled.blocks);
    let n = restart.approach_len();
    // The approach stands for itself; the rest for the programmed moves it merged.
    let first = compiled.source[restart.index].start;
    let mut programmed = blocks[..n].to_vec();
    programmed.extend_from_slice(&compiled.programmed[first..]);
    let mut source: Vec<_> = (0..n).map(|i| i..i + 1).collect();
    source.extend(
        compiled.source[restart.index..]
            .iter()
            .map(|r| r.start - first + n..r.end - first + n),
    );
    Compiled {
        blocks,
        programmed,
        source,
        start: pose,
        ..Compiled::default()
    }
}

/// The program's mark for a run of `compiled` (from its start, or from `restart`:
/// the controller's count of blocks reaches the restart's block after the approach).
pub fn mark_for(
    compiled: &Compiled,
    restart: Option<&Restart>,
    path: &std::path::Path,
) -> pkmc::wire::JobMark {
    let mut mark = super::program_mark(&compiled.blocks, super::program_lines(path));
    if let Some(r) = restart {
        let approach = r.approach_len() as u32;
        mark.next_block = (r.index as u32).wrapping_sub(approach);
    }
    mark
}
