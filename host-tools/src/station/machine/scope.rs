//! The scope panel's part of the machine thread: the recorder armed and stopped as
//! the page asks, its streamed pieces handed to the hub as they come (between jobs
//! here; while a job or a move runs, by the job's hooks), and a triggered capture
//! read out once it is done (between jobs here; while a program, an MDI line or the
//! teach list streams, by the job's hooks beside its blocks; a jog's or a probing
//! move's end is waited for).

use super::super::hub::{lock, Hub};
use super::super::scope::{check, Mode, PendingArm};
use super::super::Request;
use super::{Cmd, Hooks, Machine};
use crate::job::{self, Failure};
use crate::link::{Link, LinkError, Read, Readout, Transport};
use pkmc::drive::recorder::Reply;
use std::time::{Duration, Instant};

/// How often an armed capture is asked whether it is done.
const ASK_EVERY: Duration = Duration::from_millis(100);

/// A refusal of the recorder is the request's fault, not the link's (the station
/// goes on); any other error is the link's.
fn refused(e: LinkError) -> Failure {
    match e {
        LinkError::Recorder { error, .. } => Failure::new(
            job::exit::BAD_INPUT,
            format!("the controller's recorder refused the request: {error}"),
        ),
        e => e.into(),
    }
}

impl Machine<'_> {
    /// Arm or Stop from the panel, between jobs.
    pub(super) fn scope_command<T: Transport>(
        &mut self,
        link: &mut Link<T>,
        cmd: Cmd,
    ) -> Result<Option<String>, Failure> {
        let bad = |m: String| Failure::new(job::exit::BAD_INPUT, m);
        match cmd {
            Cmd::ScopeArm {
                signals,
                trigger,
                pre,
                decimate,
            } => {
                let setup = check(&signals, &trigger, pre, decimate).map_err(bad)?;
                link.record_take();
                if let Err(e) = link.record_arm(&setup) {
                    let f = refused(e);
                    lock(&self.hub.scope).error = Some(f.message.clone());
                    self.hub.publish_scope();
                    return Err(f);
                }
                let live = {
                    let mut s = lock(&self.hub.scope);
                    s.armed(&signals, &trigger, &setup);
                    s.mode == Mode::Live
                };
                self.hub.publish_scope();
                Ok(Some(if live { "live" } else { "armed" }.into()))
            }
            _ => {
                link.record_disarm()?;
                link.record_listen(Duration::from_millis(20))?;
                self.scope_pieces(link.record_take());
                self.scope_off();
                Ok(Some("scope stopped".into()))
            }
        }
    }

    /// The recorder's mode set to off (its samples stay), told to the pages.
    pub(super) fn scope_off(&self) {
        {
            let mut s = lock(&self.hub.scope);
            if s.mode != Mode::Done {
                s.mode = Mode::Off;
            }
            s.version += 1;
        }
        self.hub.publish_scope();
    }

    /// Streamed pieces to the panel (kept while it is live).
    pub(super) fn scope_pieces(&self, pieces: Vec<crate::link::Piece>) {
        if lock(&self.hub.scope).add(pieces) {
            self.hub.publish_scope();
        }
    }

    /// Between commands: a stop asked during a job carried out, the streamed pieces
    /// taken, an armed capture asked for now and then and read out when done.
    pub(super) fn scope_poll<T: Transport>(&mut self, link: &mut Link<T>) -> Result<(), Failure> {
        // Arm or Live pressed during a job that ended before the controller took it:
        // armed now.
        let pending = lock(&self.hub.scope).pending.take();
        if let Some(a) = pending {
            let cmd = Cmd::ScopeArm {
                signals: a.signals,
                trigger: a.trigger,
                pre: a.setup.pre as f64,
                decimate: a.setup.decimate as f64,
            };
            match self.scope_command(link, cmd) {
                Ok(text) => self.hub.reply(a.page, a.id, Ok(text.unwrap_or_default())),
                Err(f) if f.code == job::exit::LINK => return Err(f),
                Err(f) => self.hub.reply(a.page, a.id, Err(f.message)),
            }
        }
        let (mode, disarm, asked) = {
            let s = lock(&self.hub.scope);
            (s.mode, s.disarm, s.asked)
        };
        if disarm {
            lock(&self.hub.scope).disarm = false;
            link.record_disarm()?;
            link.record_take();
            return Ok(());
        }
        let pieces = link.record_take();
        match mode {
            Mode::Live => self.scope_pieces(pieces),
            Mode::Armed if asked.is_none_or(|t| t.elapsed() >= ASK_EVERY) => {
                lock(&self.hub.scope).asked = Some(Instant::now());
                if let Some(rec) = link.record_read()? {
                    let mut s = lock(&self.hub.scope);
                    if s.mode == Mode::Armed {
                        s.captured(&rec);
                    }
                    drop(s);
                    self.hub.publish_scope();
                }
            }
            _ => {}
        }
        Ok(())
    }
}

impl Hooks<'_, '_> {
    /// Arm or Live pressed while a job runs: checked, then sent beside the job
    /// ([`crate::link::JobHooks::record_arm`]); the page hears once it is armed.
    pub(super) fn arm_during(&mut self, req: Request) {
        let hub = self.m.hub;
        let Cmd::ScopeArm {
            signals,
            trigger,
            pre,
            decimate,
        } = req.cmd
        else {
            return;
        };
        let refuse = |why: String| {
            lock(&hub.scope).error = Some(why.clone());
            hub.publish_scope();
            hub.reply(req.page, req.id, Err(why));
        };
        if self.info.kind == "tune" {
            return refuse(
                "busy: a tune runs and uses the recorder; Arm and Live wait until it ends".into(),
            );
        }
        let setup = match check(&signals, &trigger, pre, decimate) {
            Ok(s) => s,
            Err(why) => return refuse(why),
        };
        let mut s = lock(&hub.scope);
        if s.pending.as_ref().is_some_and(|a| a.sent) {
            drop(s);
            return refuse("the last Arm or Live is still on its way: press again".into());
        }
        s.pending = Some(PendingArm {
            page: req.page,
            id: req.id,
            signals,
            trigger,
            setup,
            sent: false,
        });
    }

    /// The request to send beside the job now, if one waits.
    pub(super) fn arm_now(&mut self) -> Option<pkmc::drive::recorder::Setup> {
        let mut s = lock(&self.m.hub.scope);
        let a = s.pending.as_mut().filter(|a| !a.sent)?;
        a.sent = true;
        Some(a.setup)
    }

    /// The controller acknowledged the request: the panel armed (live or waiting
    /// for its trigger, the capture then read out beside the job), or its refusal.
    pub(super) fn armed(&mut self, refused: Option<String>) {
        let hub = self.m.hub;
        let mut s = lock(&hub.scope);
        let Some(a) = s.pending.take() else {
            return;
        };
        let reply = match refused {
            Some(e) => {
                let why = format!("the controller's recorder refused the request: {e}");
                s.error = Some(why.clone());
                Err(why)
            }
            None => {
                s.armed(&a.signals, &a.trigger, &a.setup);
                self.info.scope = Reading::default();
                Ok(if s.mode == Mode::Live {
                    "live"
                } else {
                    "armed"
                }
                .to_string())
            }
        };
        drop(s);
        hub.publish_scope();
        hub.reply(a.page, a.id, reply);
    }
}

/// A capture read out while a job runs: the job's hooks ask for its pieces beside the
/// job's blocks ([`crate::link::JobHooks::record_ask`]) and take the answers in.
#[derive(Clone, Debug, Default)]
pub(super) struct Reading {
    readout: Readout,
    /// When the last question went.
    asked: Option<Instant>,
}

/// A question not answered within this long is asked again.
const ASK_AGAIN: Duration = Duration::from_millis(200);

impl Reading {
    /// The offset to ask for now, if any: while a capture is armed, whether it is done
    /// every [`ASK_EVERY`], then its pieces one after the other.
    pub(super) fn ask(&mut self, hub: &Hub) -> Option<u32> {
        if lock(&hub.scope).mode != Mode::Armed {
            return None;
        }
        let wait = if self.readout.offset() == 0 {
            ASK_EVERY
        } else {
            ASK_AGAIN
        };
        if self.asked.is_some_and(|t| t.elapsed() < wait) {
            return None;
        }
        self.asked = Some(Instant::now());
        Some(self.readout.offset())
    }

    /// An answer: the next piece is asked for at once; a whole capture goes to the
    /// panel.
    pub(super) fn answer(&mut self, hub: &Hub, reply: &Reply, data: &[u8]) {
        match self.readout.answer(reply, data) {
            Read::More => self.asked = None,
            Read::NotDone => {}
            Read::Done(rec) => {
                let mut s = lock(&hub.scope);
                if s.mode == Mode::Armed {
                    s.captured(&rec);
                }
                drop(s);
                hub.publish_scope();
            }
        }
    }
}
