//! G38.2–G38.5 from a sender, answered as Grbl 1.1 answers them (its
//! `mc_probe_cycle` in `grbl/motion_control.c` of github.com/gnea/grbl, version 1.1h):
//!
//! - the probing move waits for the motion before it to end (Grbl synchronises the
//!   planner first): the bridge stops feeding the job at the G38 line, the job runs
//!   out, and the lines after it wait unanswered;
//! - the move runs on the controller as `nc-send FILE` runs one
//!   ([`crate::job::probing::probe`]); the front end is then given what it found
//!   ([`crate::job::LinePipeline::probed`]), so #5061–#5070 hold it for the lines after;
//! - `[PRB:x,y,z:1]` (machine position, mm: `$13=0`) follows the move, `:0` when the
//!   probe did not change; then `ok`;
//! - a G38.2 or G38.4 that ends without the change is `ALARM:5` before the
//!   `[PRB:…:0]` (which repeats the last probe's position, as Grbl's does), and the
//!   bridge stays in the alarm (G-code locked out) until `$X` or `$H`;
//! - a probe already in the state sought is the controller's alarm `ProbeAtStart`,
//!   `ALARM:4`, and nothing moves.

use super::bridge::Bridge;
use super::words;
use crate::gcode::interp::probe::{ProbeOutcome, Probing};
use crate::job::{exit, probing, Failure};
use crate::link::{JobEnd, Link, Transport};
use pkmc::config::AXES;
use pkmc::motion::block::Block;

/// A probing move accepted from a sender, to run once the motion before it has ended.
#[derive(Clone, Copy, Debug)]
pub(super) struct Pending {
    /// Its feed move.
    pub(super) block: Block,
    /// Which G38.
    pub(super) probing: Probing,
    /// The sender's line number.
    pub(super) line: u32,
}

/// The last probe's result, as `[PRB:…]` and `$#` show it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(super) struct Last {
    /// Machine position, axis units.
    pub(super) at: [i64; AXES],
    /// The probe changed as sought.
    pub(super) contact: bool,
}

impl Last {
    /// `[PRB:x,y,z:c]` with `n` axes.
    pub(super) fn line(&self, n: usize) -> String {
        format!(
            "[PRB:{}:{}]",
            words::list(&self.at, n),
            u8::from(self.contact)
        )
    }
}

/// In check mode (`$C`) nothing moves: Grbl answers a probing move `ok` at once. The
/// front end goes on as if the probe had touched at the end of the move.
pub(super) fn checked(b: &mut Bridge<'_>, block: &Block, line: u32) {
    let o = ProbeOutcome {
        changed: true,
        probed: block.target,
        stopped: block.target,
    };
    let _ = b.pipeline.probed(&o, line);
}

/// Runs the probing move `p` (the motion before it has ended) and answers its line.
pub(super) fn run<T: Transport>(
    b: &mut Bridge<'_>,
    link: &mut Link<T>,
    p: Pending,
) -> Result<(), Failure> {
    let machine = b.machine;
    b.set_job(Some((1, 0)));
    let ran = probing::probe(link, machine, &p.block, p.probing, b);
    b.set_job(None);
    let s = link.request_status()?;
    b.status = Some(s.clone());
    let (found, end) = match ran {
        // A move the planner cannot make from where the machine stands.
        Err(f) if f.code == exit::BAD_INPUT => {
            b.pipeline.set_position(s.pose);
            b.refuse(33, &format!("sender:{}: {}", p.line, f.message));
            return Ok(());
        }
        r => r?,
    };
    let Some((outcome, _)) = found else {
        b.pipeline.set_position(s.pose);
        if let JobEnd::Alarm(a) = end {
            // ALARM:4 (the probe already in the state sought) or an alarm during the
            // move; Grbl answers the line `ok` after it.
            super::report_alarm(b, &a);
            b.ok();
        }
        // A reset (Ctrl-X) drops the line unanswered, as it drops every line.
        return Ok(());
    };
    let refused = b.pipeline.probed(&outcome, p.line).err();
    if outcome.changed || !p.probing.must_change {
        b.last_probe = Last {
            at: outcome.probed,
            contact: outcome.changed,
        };
    } else {
        // Grbl keeps the last probe's position and reports it failed.
        b.last_probe.contact = false;
    }
    if let Some(why) = refused {
        b.mode.alarm = true;
        b.say("ALARM:5");
        b.say(&format!("[MSG:{why}]"));
    }
    let n = words::reported_axes(b.machine);
    let prb = b.last_probe.line(n);
    b.say(&prb);
    b.ok();
    Ok(())
}
