//! A port that goes away in the middle of a job (a board's USB cable pulled, the
//! simulator's pseudo-terminal closed): `nc-send` waits for the same device to come
//! back — the same path given with `--port`, or for a board found on USB, the same USB
//! serial number under whatever port name it comes back with — reconnects, takes its
//! own job over (the controller held it, with the program's mark, while its host was
//! away) and streams the rest. It gives up after [`REPLUG_WAIT`] and says how to resume.

use super::{exit, Failure, RunOptions, Target};
use crate::link::{ClientStats, JobEnd, JobHooks, Link, LinkError, PortTransport};
use pkmc::config::MachineConfig;
use pkmc::motion::block::Block;
use pkmc::wire::Status;
use std::path::Path;
use std::time::{Duration, Instant};

/// How long `nc-send` waits for a port that went away mid-job to come back.
pub const REPLUG_WAIT: Duration = Duration::from_secs(60);

/// Does `e` say the port went away, in a job that can be taken over after a replug
/// (a program with its mark, on a port)?
pub fn applies(e: &LinkError, opts: &RunOptions<'_>, path: &str) -> bool {
    let port = matches!(opts.target, Target::Port(_) | Target::Board { .. });
    let marked = opts.link.mark.program != 0 && port;
    let gone = match e {
        LinkError::Io { .. } => true,
        LinkError::Lost { .. } => !Path::new(path).exists(),
        _ => false,
    };
    marked && gone
}

/// The job a port's loss interrupted: its blocks (the first starting at `pose`) and
/// the counts of the link that streamed them (the report adds every link's).
pub struct Interrupted<'b> {
    /// The job's blocks.
    pub blocks: &'b [Block],
    /// Where the first starts.
    pub pose: [i64; 6],
    /// The lost link's counts.
    pub stats: ClientStats,
}

/// Where the device that went away is now, if it is back: the same path, or for a
/// board known by its USB serial number, the port of the board with that number.
fn locate(opts: &RunOptions<'_>, path: &str) -> Option<String> {
    match opts.target {
        Target::Board { serial, .. } => crate::link::usb::port_of(serial),
        _ => Path::new(path).exists().then(|| path.to_string()),
    }
}

/// What the device is waited for as, in words.
fn device(opts: &RunOptions<'_>, path: &str) -> String {
    match opts.target {
        Target::Board { serial, .. } => format!("the board with USB serial number {serial}"),
        _ => path.to_string(),
    }
}

/// Waits for the port at `path` to come back, reconnects, and continues `job` from
/// the first block the controller never received.
pub fn rejoin(
    why: LinkError,
    path: &str,
    machine: &MachineConfig,
    opts: &RunOptions<'_>,
    job: Interrupted<'_>,
    hooks: &mut dyn JobHooks,
) -> Result<(JobEnd, Status, ClientStats), Failure> {
    let Interrupted {
        blocks,
        pose,
        stats: mut earlier,
    } = job;
    hooks.note(&format!(
        "{why}: the port went away; waiting up to {} s for {} to come back",
        REPLUG_WAIT.as_secs(),
        device(opts, path)
    ));
    let mut path = path.to_string();
    let resume = match opts.target {
        Target::Board { .. } => "nc-send resume PROGRAM".to_string(),
        _ => format!("nc-send --port {path} resume PROGRAM"),
    };
    let mut since = Instant::now();
    loop {
        if since.elapsed() > REPLUG_WAIT {
            return Err(Failure::new(
                exit::LINK,
                format!(
                    "{path}: the port went away in the middle of the job and {} did not come \
                     back within {} s; the controller keeps the job (held after its host \
                     timeout): once the port is back, `{resume}` (the same program and \
                     options) continues it to the end, `nc-send abort` drops it",
                    device(opts, &path),
                    REPLUG_WAIT.as_secs()
                ),
            ));
        }
        std::thread::sleep(Duration::from_millis(200));
        let Some(now) = locate(opts, &path) else {
            continue;
        };
        let Ok(io) = PortTransport::open(&now) else {
            continue;
        };
        if now != path {
            hooks.note(&format!("{}: back as {now}", device(opts, &path)));
            path = now;
        }
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
        let received = k as u64;
        // A job fed a piece at a time gives its blocks from `k` on again; one whose
        // blocks are all in hand continues from them.
        let (rest, start) = match hooks.rewind(k) {
            Some(Ok((rest, start))) => (std::borrow::Cow::Owned(rest), start),
            Some(Err(e)) => return Err(Failure::new(exit::BAD_INPUT, e)),
            None => {
                let k = k.min(blocks.len());
                let start = super::pose_after(&blocks[..k], pose);
                (std::borrow::Cow::Borrowed(&blocks[k..]), start)
            }
        };
        let total = (opts.link.mark.total_blocks as usize).max(blocks.len());
        hooks.note(&format!(
            "{path}: the port is back; taking the job over at block {} of {total}",
            k + 1,
        ));
        // The controller counts executed blocks from each session's Hello; the held
        // job's earlier sessions' count comes with it (`HeldJob::done`).
        let done_before = link.held().map_or(0, |h| h.done);
        match link.continue_job(held, &rest, start, hooks) {
            Ok(end) => {
                let mut status = link.request_status()?;
                status.blocks_done = status.blocks_done.wrapping_add(done_before);
                let mut stats = link.stats;
                with_earlier(&mut stats, &earlier, received);
                return Ok((end, status, stats));
            }
            // Gone again: wait again.
            Err(e) if applies(&e, opts, &path) => {
                let mut stats = link.stats;
                with_earlier(&mut stats, &earlier, received);
                earlier = stats;
                since = Instant::now();
            }
            Err(e) => return Err(e.into()),
        }
    }
}

/// `stats` (a link opened after a replug, which sent the job from block `received` on)
/// made the whole job's: the earlier links' counts added, and the blocks they sent
/// that the controller never had (lost with the port) counted as sent again, not as
/// sent twice.
fn with_earlier(stats: &mut ClientStats, earlier: &ClientStats, received: u64) {
    let lost = earlier.blocks_sent.saturating_sub(received);
    let e = earlier;
    stats.frames_sent += e.frames_sent;
    stats.bytes_sent += e.bytes_sent;
    stats.blocks_sent += e.blocks_sent - lost;
    stats.resent += e.resent + lost;
    stats.rewinds += e.rewinds;
    stats.timeouts += e.timeouts;
    stats.naks += e.naks;
    let (n, m) = (&mut stats.nak_reasons, &e.nak_reasons);
    n.corrupt += m.corrupt;
    n.gap += m.gap;
    n.queue_full += m.queue_full;
    n.other += m.other;
    stats.naks_ignored += e.naks_ignored;
    stats.controls += e.controls;
    stats.controls_resent += e.controls_resent;
    stats.status_requests += e.status_requests;
    stats.frames_received += e.frames_received;
    stats.corrupt_received += e.corrupt_received;
    stats.own_gaps += e.own_gaps;
    stats.own_gap_max_s = stats.own_gap_max_s.max(e.own_gap_max_s);
    stats.host_timeout_resumes += e.host_timeout_resumes;
    // The first link planned the whole job; a later one only its rest.
    stats.plan_time_s = stats.plan_time_s.max(e.plan_time_s);
    stats.copies += e.copies;
    stats.line_warnings += e.line_warnings;
    stats.frame_damage_max = stats.frame_damage_max.max(e.frame_damage_max);
    stats.reconnects += e.reconnects + 1;
}
