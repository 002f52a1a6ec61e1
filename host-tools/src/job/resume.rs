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
use pkmc::motion::block::{Block, Motion};
use pkmc::wire::{Control, JobMark, State};
use std::path::Path;

/// The mark of a program compiled to `blocks` whose text has `lines` lines: what
/// `BeginJob` sends with its first block.
pub fn program_mark(blocks: &[Block], lines: u32) -> JobMark {
    // FNV-1a, 64 bits, over each block's fields as they are streamed.
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |bytes: &[u8]| {
        for &b in bytes {
            h ^= b as u64;
            h = h.wrapping_mul(0x0000_0100_0000_01b3);
        }
    };
    for b in blocks {
        eat(format!("{b:?}").as_bytes());
    }
    JobMark {
        program: h.max(1),
        next_block: 0,
        total_blocks: blocks.len() as u32,
        last_line: 0,
        total_lines: lines.max(blocks.iter().map(|b| b.line).max().unwrap_or(0)),
    }
}

/// Lines of the program's text (for the mark).
pub fn program_lines(path: &Path) -> u32 {
    std::fs::read(path).map_or(0, |t| {
        let n = t.iter().filter(|&&c| c == b'\n').count();
        (n + (!t.is_empty() && !t.ends_with(b"\n")) as usize) as u32
    })
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
    let compiled = super::compile_job(path, machine, &opts.tools, opts.compress.as_ref())?;
    let blocks = &compiled.blocks;
    let ours = program_mark(blocks, program_lines(path));
    if ours.program != held.program || ours.total_blocks != held.total_blocks {
        return Err(Failure::new(
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
        ));
    }
    let from = held.next_block as usize;
    let start = blocks[..from]
        .iter()
        .rev()
        .find(|b| !matches!(b.motion, Motion::Dwell(_) | Motion::Aux(_)))
        .map_or(compiled.start, |b| b.target);
    let mark = JobMark { ..held };
    let rest = &blocks[from..];
    let end = link.continue_job(mark, rest, start, hooks)?;
    Ok(Resumed {
        end,
        blocks_sent: Some(rest.len()),
        incomplete: None,
    })
}
