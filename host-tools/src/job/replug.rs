//! A port that goes away in the middle of a job (a board's USB cable pulled, the
//! simulator's pseudo-terminal closed): `nc-send` waits for the same port to come
//! back (the same path given with `--port`), reconnects, takes its own job over (the
//! controller held it, with the program's mark, while its host was away) and streams
//! the rest. It gives up after [`REPLUG_WAIT`] and says how to resume.

use super::{exit, Failure, RunOptions, Target};
use crate::link::{ClientStats, JobEnd, JobHooks, Link, LinkError, PortTransport};
use pkmc::config::MachineConfig;
use pkmc::motion::block::{Block, Motion};
use pkmc::wire::Status;
use std::path::Path;
use std::time::{Duration, Instant};

/// How long `nc-send` waits for a port that went away mid-job to come back.
pub const REPLUG_WAIT: Duration = Duration::from_secs(60);

/// Does `e` say the port went away, in a job that can be taken over after a replug
/// (a program with its mark, on a port)?
pub fn applies(e: &LinkError, opts: &RunOptions<'_>, path: &str) -> bool {
    let marked = opts.link.mark.program != 0 && matches!(opts.target, Target::Port(_));
    let gone = match e {
        LinkError::Io { .. } => true,
        LinkError::Lost { .. } => !Path::new(path).exists(),
        _ => false,
    };
    marked && gone
}

/// Waits for the port at `path` to come back, reconnects, and continues the job
/// whose blocks are `blocks` (the first starting at `pose`) from the first block the
/// controller never received.
pub fn rejoin(
    why: LinkError,
    path: &str,
    machine: &MachineConfig,
    opts: &RunOptions<'_>,
    blocks: &[Block],
    pose: [i64; 6],
    hooks: &mut dyn JobHooks,
) -> Result<(JobEnd, Status, ClientStats), Failure> {
    hooks.note(&format!(
        "{why}: the port went away; waiting up to {} s for it to come back",
        REPLUG_WAIT.as_secs()
    ));
    let mut since = Instant::now();
    loop {
        if since.elapsed() > REPLUG_WAIT {
            return Err(Failure::new(
                exit::LINK,
                format!(
                    "{path}: the port went away in the middle of the job and did not come \
                     back within {} s; the controller keeps the job (held after its host \
                     timeout): once the port is back, `nc-send --port {path} resume PROGRAM` \
                     (the same program and options) continues it to the end, `nc-send abort` \
                     drops it",
                    REPLUG_WAIT.as_secs()
                ),
            ));
        }
        std::thread::sleep(Duration::from_millis(200));
        if !Path::new(path).exists() {
            continue;
        }
        let Ok(io) = PortTransport::open(path) else {
            continue;
        };
        let Ok(mut link) = Link::connect(io, machine, opts.link) else {
            continue;
        };
        let Some(held) = link
            .held_mark()
            .filter(|m| m.program == opts.link.mark.program)
        else {
            return Err(Failure::new(
                exit::LINK,
                format!(
                    "{path}: the port is back, but the controller holds no job of this \
                     program (it restarted, or the job ended or was dropped meanwhile); \
                     `nc-send status` shows where it stands"
                ),
            ));
        };
        let k = held.next_block.wrapping_sub(opts.link.mark.next_block) as usize;
        let k = k.min(blocks.len());
        let start = blocks[..k]
            .iter()
            .rev()
            .find(|b| !matches!(b.motion, Motion::Dwell(_) | Motion::Aux(_)))
            .map_or(pose, |b| b.target);
        hooks.note(&format!(
            "{path}: the port is back; taking the job over at block {} of {}",
            k + 1,
            blocks.len()
        ));
        match link.continue_job(held, &blocks[k..], start, hooks) {
            Ok(end) => {
                let status = link.request_status()?;
                return Ok((end, status, link.stats));
            }
            // Gone again: wait again.
            Err(e) if applies(&e, opts, path) => since = Instant::now(),
            Err(e) => return Err(e.into()),
        }
    }
}
