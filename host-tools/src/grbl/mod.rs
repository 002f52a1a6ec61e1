//! The Grbl bridge (`nc-send grbl`): Grbl 1.1's text protocol for the senders
//! machinists use (CNCjs, UGS, bCNC, gSender), served on a pseudo-terminal and a
//! local TCP port, in front of the controller's binary link (CRC, credits, resends).
//!
//! Every line a sender writes is read by our own G-code front end with its modal
//! state kept across lines ([`crate::job::LinePipeline`]), checked against the
//! machine's reach (pre-flight), and its blocks are fed into a running job
//! ([`crate::link::JobHooks::feed`]), planned as they come. `ok` means the line was
//! accepted into the bridge's buffer ([`words::BLOCK_BUFFER`] blocks ahead of the
//! controller; lines wait unanswered while it is full, which is how a sender is held
//! back). Real-time bytes act at once. See `docs/senders.md`.

mod bridge;
mod commands;
mod input;
mod merge;
mod ports;
mod probe;
mod words;

pub use input::{Input, Item, RealTime};

use crate::gcode;
use crate::job::{exit, state_text, Failure, RunOptions, Target};
use crate::link::{JobEnd, Link, Transport};
use bridge::{Bridge, Needs};
use pkmc::config::MachineConfig;
use pkmc::wire::{Alarm, Control};
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// What the bridge did, printed when it stops.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub(super) struct Counts {
    /// Lines answered `ok`.
    pub(super) ok: u64,
    /// Lines answered `error:N`.
    pub(super) errors: u64,
    /// Blocks fed to the controller.
    pub(super) blocks: u64,
    /// Blocks the controller reported executed.
    pub(super) executed: u64,
}

/// Where the bridge listens.
#[derive(Clone, Debug, Default)]
pub struct BridgeOptions {
    /// Also link the pseudo-terminal at this path.
    pub link: Option<PathBuf>,
    /// Listen on this TCP address (`127.0.0.1:23` …); `None`: no TCP.
    pub tcp: Option<String>,
    /// Tool table for G43 and cutter compensation.
    pub tools: gcode::ToolTable,
    /// M6 holds the machine for a manual tool change (until `~`) instead of being
    /// refused with `error:20` as Grbl 1.1 refuses it.
    pub tool_change: bool,
    /// Merge a sender's runs of short moves as nc-send does ([`merge`]); `None`: each
    /// line's blocks go as they are (nc-send passes its own settings).
    pub compress: Option<gcode::compress::Settings>,
}

/// How often the bridge asks the controller for its status between jobs.
const IDLE_STATUS: Duration = Duration::from_millis(50);
/// How often it asks during a job (the link's keepalive).
const STATUS_AGE: Duration = Duration::from_millis(20);

/// `nc-send grbl`: connects to the controller as `run` says (`--sim`, `--port`, or
/// the board on USB), prints where senders connect on stdout (`pty PATH`, and
/// `tcp ADDRESS`), and serves until `stop` says so (Ctrl-C).
pub fn run(
    machine: &MachineConfig,
    run: &RunOptions<'_>,
    opts: &BridgeOptions,
    stop: &dyn Fn() -> bool,
) -> Result<i32, Failure> {
    let mut link_opts = run.clone();
    // A `?` is answered from the last status: while a job streams, one is asked
    // every 20 ms (besides the controller's own), so a report is at most that old.
    link_opts.link.keepalive = STATUS_AGE;
    let run = &link_opts;
    crate::job::with_link(machine, run, |link| {
        if matches!(run.target, Target::Sim) {
            // A fresh simulator is locked after its reset: unlock it where it stands.
            crate::job::prepare(link, false, true, &mut crate::link::NoHooks)?;
        }
        let mut announce = |pty: &str, tcp: Option<std::net::SocketAddr>| {
            use std::io::Write;
            let mut out = std::io::stdout().lock();
            let _ = writeln!(out, "pty {pty}");
            if let Some(a) = tcp {
                let _ = writeln!(out, "tcp {a}");
            }
            let _ = out.flush();
        };
        serve(link, machine, opts, stop, &mut announce)?;
        Ok(exit::OK)
    })
}

/// Serves senders until `stop` says so. `announce` receives the pseudo-terminal's
/// path and the TCP address once they are open.
pub fn serve<T: Transport>(
    link: &mut Link<T>,
    machine: &MachineConfig,
    opts: &BridgeOptions,
    stop: &dyn Fn() -> bool,
    announce: &mut dyn FnMut(&str, Option<std::net::SocketAddr>),
) -> Result<(), Failure> {
    let ports = ports::Ports::open(opts.link.as_deref(), opts.tcp.as_deref())
        .map_err(|m| Failure::new(exit::LINK, m))?;
    announce(&ports.pty_path, ports.tcp_addr);
    let start = link.request_status()?;
    let mut options = crate::job::front_end_options(machine, start.pose, &opts.tools);
    // G38 runs here, a line at a time (`probe`).
    options.probing = true;
    let pipeline = crate::job::LinePipeline::new(&options, machine, "sender");
    let mut b = Bridge::new(machine, ports, pipeline, stop);
    b.tool_change = opts.tool_change;
    // Runs of short moves merged as nc-send merges them (its --no-compress and
    // --corner-deg apply here too).
    b.merge = merge::Merger::new(
        opts.compress
            .as_ref()
            .map(|s| crate::job::compress_for_machine(s, machine)),
        b.pipeline.interp().pos,
    );
    b.status = Some(start);
    let mut asked = Instant::now();
    while !stop() {
        b.poll(Duration::from_millis(5));
        while let Some(cmd) = b.controls.pop_front() {
            // Between jobs: hold and resume of nothing, overrides kept for the next
            // job, a reset or jog cancel of nothing.
            if !matches!(cmd, Control::Abort) {
                link.control(cmd)?;
            }
        }
        if b.reset {
            soft_reset(&mut b, link)?;
        }
        if asked.elapsed() >= IDLE_STATUS {
            let s = link.request_status()?;
            // An alarm raised between jobs (the e-stop pressed at rest) is pushed to
            // the sender as Grbl pushes it.
            match s.alarm {
                Some(a) if b.alarm_told != Some(a) => report_alarm(&mut b, &a),
                None => b.alarm_told = None,
                _ => {}
            }
            b.status = Some(s);
            asked = Instant::now();
        }
        next_line(&mut b, link)?;
    }
    let s = link.request_status()?;
    let summary = serde_json::json!({
        "lines": b.line_no,
        "ok": b.counts.ok,
        "errors": b.counts.errors,
        "blocks_fed": b.counts.blocks,
        "moves_merged": b.merge.merged.0,
        "curves_made": b.merge.merged.1,
        "blocks_executed": b.counts.executed,
        "link": link.stats,
        "status": crate::job::status_json(&s, machine, "served"),
    });
    println!("summary {summary}");
    Ok(())
}

/// Takes the next queued line between jobs: a G-code line with motion starts a job
/// (which then takes the lines that follow); `$` lines are answered.
fn next_line<T: Transport>(b: &mut Bridge<'_>, link: &mut Link<T>) -> Result<(), Failure> {
    let Some((item, _)) = b.lines.pop_front() else {
        return Ok(());
    };
    let text = match item {
        input::Item::Refused { code, why } => {
            b.line_no += 1;
            let n = b.line_no;
            b.refuse(code, &format!("sender:{n}: {why}"));
            return Ok(());
        }
        input::Item::RealTime(_) => return Ok(()),
        input::Item::Line(t) => t,
    };
    if text.trim_start().starts_with('$') {
        b.line_no += 1;
        return if commands::needs(&text) == Needs::Link {
            commands::run_link(b, link, &text)
        } else {
            let phase = b.phase(false);
            commands::answer_local(b, &text, phase);
            Ok(())
        };
    }
    if b.locked() {
        b.line_no += 1;
        b.refuse(
            9,
            "G-code is locked out during an alarm: $X unlocks, $H homes",
        );
        return Ok(());
    }
    let Some(blocks) = b.compile(&text) else {
        return Ok(());
    };
    if blocks.is_empty() {
        return run_probe(b, link);
    }
    b.set_job(Some((blocks.len(), 0)));
    // The job's first line goes as it is; merging starts with the lines after it.
    b.merge.restart_at(b.pipeline.interp().pos);
    let end = link.run_job(&blocks, b);
    // Whatever is still held goes with the job (an alarm or a reset ended it).
    b.merge.restart_at(b.pipeline.interp().pos);
    if matches!(end, Ok(JobEnd::Done)) {
        b.job_done();
    }
    b.set_job(None);
    let end = end?;
    let s = link.request_status()?;
    b.status = Some(s.clone());
    if let JobEnd::Alarm(a) = end {
        report_alarm(b, &a);
    }
    if b.pipeline.interp().pos != s.pose && !b.reset {
        // Stopped short (an alarm): the next line starts where the machine is.
        b.pipeline.set_position(s.pose);
    }
    match end {
        JobEnd::Done => run_probe(b, link),
        _ => {
            // The probing move the job ran out for does not run after an alarm (a
            // reset drops its line unanswered).
            if b.probe.take().is_some() {
                b.pipeline.set_position(s.pose);
                if !b.reset {
                    b.refuse(
                        9,
                        "the probing move did not run: the motion before it ended in an alarm",
                    );
                }
            }
            Ok(())
        }
    }
}

/// The probing move a line ended in, once the motion before it has ended.
fn run_probe<T: Transport>(b: &mut Bridge<'_>, link: &mut Link<T>) -> Result<(), Failure> {
    let Some(p) = b.probe.take() else {
        return Ok(());
    };
    if b.reset || b.stopping {
        // Ctrl-X drops the line unanswered; Ctrl-C takes no more motion.
        let pose = link.request_status()?.pose;
        b.pipeline.set_position(pose);
        return Ok(());
    }
    probe::run(b, link, p)
}

/// `ALARM:N` and our cause, joint and line in the core's words.
fn report_alarm(b: &mut Bridge<'_>, a: &Alarm) {
    b.alarm_told = Some(*a);
    b.say(&format!("ALARM:{}", words::alarm_code(a.cause)));
    let view = crate::link::view::AlarmView::new(a);
    b.say(&format!("[MSG:{}]", view.words));
}

/// Ctrl-X: motion was stopped (the job aborted); lines not yet answered are dropped
/// as a Grbl board drops its serial buffer; the modal state starts afresh; the banner
/// and the start-up lines follow.
fn soft_reset<T: Transport>(b: &mut Bridge<'_>, link: &mut Link<T>) -> Result<(), Failure> {
    b.reset = false;
    b.mode.jogging = false;
    // Grbl's reset returns to Idle (or Alarm): check mode ends with it.
    b.mode.check = false;
    b.lines.clear();
    let mut s = link.request_status()?;
    if s.state == pkmc::wire::State::Hold && s.speed == 0 {
        // A feed hold with nothing under it (`!` while idle): a reset ends it.
        link.control(Control::Resume)?;
        s = link.request_status()?;
    }
    b.pipeline.restart(s.pose);
    b.merge.restart_at(s.pose);
    b.status = Some(s.clone());
    b.say(&words::banner());
    if b.locked() {
        let why = match b.mode.alarm {
            true => "a probing move found nothing (ALARM:5)".to_string(),
            false => format!("the controller is {}", state_text(&s)),
        };
        b.say(&format!("[MSG:'$H'|'$X' to unlock: {why}]"));
        return Ok(());
    }
    for i in 0..2 {
        let line = b.startup[i].clone();
        if line.trim().is_empty() {
            continue;
        }
        // Grbl echoes a start-up line and its answer on one line (`>G55:ok`), so
        // that the answer is not taken for one to a streamed line.
        let blocks = match b.compile_line(&line) {
            Ok(_) if b.probe.is_some() => {
                // Grbl would run it; here a probe is a sender's line of its own.
                b.probe = None;
                let pos = b.pipeline.interp().pos;
                b.pipeline.set_position(pos);
                b.counts.errors += 1;
                b.say("[MSG:a start-up line does not probe: send G38 as a line]");
                b.say(&format!(">{line}:error:20"));
                continue;
            }
            Ok(blocks) => {
                b.counts.ok += 1;
                b.say(&format!(">{line}:ok"));
                blocks
            }
            Err((code, why)) => {
                b.counts.errors += 1;
                b.say(&format!("[MSG:{why}]"));
                b.say(&format!(">{line}:error:{code}"));
                continue;
            }
        };
        if !blocks.is_empty() {
            b.set_job(Some((blocks.len(), 0)));
            let end = link.run_job(&blocks, &mut NoFeed(b));
            b.set_job(None);
            if let JobEnd::Alarm(a) = end? {
                report_alarm(b, &a);
            }
        }
    }
    Ok(())
}

/// Hooks for a start-up line's job: status kept, no lines taken.
struct NoFeed<'a, 'o>(&'a mut Bridge<'o>);

impl crate::link::JobHooks for NoFeed<'_, '_> {
    fn status(&mut self, s: &pkmc::wire::Status) {
        self.0.status = Some(s.clone());
    }
}
