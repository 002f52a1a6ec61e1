//! `nc-send resume [PROGRAM]`: a job held on the controller (paused with nobody at a
//! terminal, or left by a host that has gone) continued to the program's end.
//!
//! A program is streamed with its mark ([`JobMark`], `Control::BeginJob`): a 64-bit
//! hash of the blocks it compiles to (so of its text, the machine, the tool table and
//! the merging options), its block and line counts. The controller counts the blocks
//! it accepts and reports the mark with a held job. Given the program, `resume`
//! compiles it again, checks the hash and streams the blocks the controller never
//! received; without it, it says how much of the program was never sent, and runs
//! only what is queued when asked to (`--queued-only`), never reporting that `done`.

use super::{exit, Failure, RunOptions};
use crate::link::{JobEnd, JobHooks, Link, Transport};
use pkmc::config::MachineConfig;
use pkmc::motion::block::Block;
use pkmc::wire::{Control, JobMark, State};
use std::path::Path;

/// The mark of a program compiled to `blocks` whose text has `lines` lines: what
/// `BeginJob` sends with its first block.
pub fn program_mark(blocks: &[Block], lines: u32) -> JobMark {
    let mut m = MarkHasher::default();
    m.add(blocks);
    m.mark(lines)
}

/// [`program_mark`] a piece of the program at a time (a program streamed a piece at a
/// time: [`super::streamed`]).
#[derive(Clone, Debug)]
pub struct MarkHasher {
    /// FNV-1a, 64 bits, over each block's fields as they are streamed.
    h: u64,
    blocks: u32,
    max_line: u32,
}

impl Default for MarkHasher {
    fn default() -> Self {
        Self {
            h: 0xcbf2_9ce4_8422_2325,
            blocks: 0,
            max_line: 0,
        }
    }
}

impl MarkHasher {
    /// The next blocks of the program.
    pub fn add(&mut self, blocks: &[Block]) {
        for b in blocks {
            for &c in format!("{b:?}").as_bytes() {
                self.h ^= c as u64;
                self.h = self.h.wrapping_mul(0x0000_0100_0000_01b3);
            }
            self.max_line = self.max_line.max(b.line);
        }
        self.blocks = self.blocks.wrapping_add(blocks.len() as u32);
    }

    /// The mark of the blocks added, for a text of `lines` lines.
    pub fn mark(&self, lines: u32) -> JobMark {
        JobMark {
            program: self.h.max(1),
            next_block: 0,
            total_blocks: self.blocks,
            last_line: 0,
            total_lines: lines.max(self.max_line),
        }
    }
}

/// Lines of the program's text (for the mark), read a megabyte at a time.
pub fn program_lines(path: &Path) -> u32 {
    use std::io::Read;
    let Ok(mut f) = std::fs::File::open(path) else {
        return 0;
    };
    let mut buf = vec![0u8; 1 << 20];
    let (mut n, mut last) = (0usize, b'\n');
    loop {
        match f.read(&mut buf) {
            Ok(0) => break,
            Ok(k) => {
                n += buf[..k].iter().filter(|&&c| c == b'\n').count();
                last = buf[k - 1];
            }
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(_) => return 0,
        }
    }
    (n + (last != b'\n') as usize) as u32
}

/// What of a held job's program the controller never received, in words.
pub fn missing_text(m: &JobMark) -> String {
    let blocks = m.total_blocks.saturating_sub(m.next_block);
    let lines = m.total_lines.saturating_sub(m.last_line);
    format!(
        "{blocks} of the program's {} blocks were never sent to the controller: it \
         has the program up to line {}, lines {}..{} ({lines} lines) are missing",
        m.total_blocks,
        m.last_line,
        m.last_line + 1,
        m.total_lines
    )
}

/// Refuses `path`, whose mark is `ours`, unless it is the program of the held job
/// whose mark is `held`.
pub(super) fn same_program(path: &Path, ours: &JobMark, held: &JobMark) -> Result<(), Failure> {
    if ours.program == held.program && ours.total_blocks == held.total_blocks {
        return Ok(());
    }
    Err(Failure::new(
        exit::BAD_INPUT,
        format!(
            "{}: not the held job's program: its blocks differ ({} blocks, hash {:016x}; \
             the held job's: {} blocks, hash {:016x}). Give the same file with the same \
             machine file, tool table and merging options as the run that was paused; \
             nothing was sent",
            path.display(),
            ours.total_blocks,
            ours.program,
            held.total_blocks,
            held.program
        ),
    ))
}

/// How a resume ended.
pub struct Resumed {
    /// The job's end.
    pub end: JobEnd,
    /// Blocks this host streamed (the rest of the program), if any.
    pub blocks_sent: Option<usize>,
    /// The program was left unfinished: only what was queued ran (`--queued-only`).
    pub incomplete: Option<JobMark>,
}

/// `resume [PROGRAM] [--queued-only]`: continues the held job on `link`.
pub fn resume<T: Transport>(
    link: &mut Link<T>,
    program: Option<&Path>,
    queued_only: bool,
    machine: &MachineConfig,
    opts: &RunOptions<'_>,
    hooks: &mut dyn JobHooks,
) -> Result<Resumed, Failure> {
    let port = link.transport().name().to_string();
    let s = link.request_status()?;
    // A held job, or another host's job still running out its queue.
    let orphan_moving = matches!(s.state, State::Running | State::Starved) && link.held().is_some();
    if s.state != State::Hold && !orphan_moving {
        return Err(Failure::new(
            exit::ALARM,
            format!(
                "{port}: nothing to resume: the controller is {}",
                super::state_text(&s)
            ),
        ));
    }
    let missing = link.held_mark().filter(|m| m.next_block < m.total_blocks);
    match (missing, program) {
        (Some(m), Some(p)) => return continue_program(link, m, p, machine, opts, hooks),
        (Some(m), None) if !queued_only => {
            return Err(Failure::new(
                exit::HELD,
                format!(
                    "{port}: the held job is unfinished: {}. `nc-send resume PROGRAM` (the same \
                     file, machine, tool table and merging options) sends the rest and runs \
                     it to the end; `nc-send resume --queued-only` runs only what is queued; \
                     `nc-send abort` drops the job. Nothing was resumed",
                    missing_text(&m)
                ),
            ))
        }
        _ => {}
    }
    link.control(Control::Resume)?;
    link.release_held();
    let end = link.wait_resumed(hooks)?;
    if end == JobEnd::Done {
        // What was queued has run: the job is over on the controller.
        link.control(Control::EndJob)?;
    }
    Ok(Resumed {
        end,
        blocks_sent: None,
        incomplete: missing,
    })
}

/// Compiles `path`, checks it is the held job's program, and streams its blocks from
/// the first the controller never received.
fn continue_program<T: Transport>(
    link: &mut Link<T>,
    held: JobMark,
    path: &Path,
    machine: &MachineConfig,
    opts: &RunOptions<'_>,
    hooks: &mut dyn JobHooks,
) -> Result<Resumed, Failure> {
    if super::streamed::applies(path, opts) {
        if let Some(r) = super::streamed::continue_program(link, held, path, machine, opts, hooks)?
        {
            return Ok(r);
        }
    }
    let compiled = super::compile_job(path, machine, &opts.tools, opts.compress.as_ref())?;
    let blocks = &compiled.blocks;
    same_program(path, &program_mark(blocks, program_lines(path)), &held)?;
    let from = held.next_block as usize;
    let start = super::pose_after(&blocks[..from], compiled.start);
    let mark = JobMark { ..held };
    let rest = &blocks[from..];
    let end = link.continue_job(mark, rest, start, hooks)?;
    Ok(Resumed {
        end,
        blocks_sent: Some(rest.len()),
        incomplete: None,
    })
}
