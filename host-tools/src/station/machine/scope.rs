//! The scope panel's part of the machine thread: the recorder armed and stopped as
//! the page asks, its streamed pieces handed to the hub as they come (between jobs
//! here; while a job or a move runs, by the job's hooks), and a triggered capture
//! read out once it is done (between jobs here; while a program, an MDI line or the
//! teach list streams, by the job's hooks beside its blocks; a jog's or a probing
//! move's end is waited for).

use super::super::hub::{lock, Hub};
use super::super::scope::{check, Mode};
use super::{Cmd, Machine};
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
