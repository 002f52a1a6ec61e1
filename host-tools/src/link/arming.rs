//! The recorder armed beside a running job: a page presses Arm or Live while a
//! program, an MDI line or a move runs. The request ([`JobHooks::record_arm`]) goes
//! out as the control it is (`HostMsg::Record` with `RECORD_ARM`), beside the job's
//! blocks, and is sent again until the controller acknowledges it; a refusal (its
//! answer just before the acknowledgement) and the acknowledgement go to
//! [`JobHooks::record_armed`]. Streamed pieces received before the acknowledgement
//! are the old request's and are dropped.

use super::{JobHooks, Link, Transport};
use super::{LinkError, CONTROL_RESEND_AFTER};
use pkmc::drive::recorder::{Reply, Setup};
use pkmc::wire::{HostMsg, RECORD_ARM};
use std::time::Instant;

/// An arm request on its way.
#[derive(Clone, Debug)]
pub(super) struct Arming {
    id: u16,
    setup: Setup,
    sent_at: Option<Instant>,
    /// The controller's refusal, read before its acknowledgement.
    refused: Option<String>,
}

impl<T: Transport> Link<T> {
    /// In a job's loop: takes a new request from `hooks` when none is on its way, and
    /// sends the one on its way (again, when its acknowledgement is late).
    pub(super) fn service_arming(
        &mut self,
        now: Instant,
        hooks: &mut dyn JobHooks,
    ) -> Result<(), LinkError> {
        if self.arming.is_none() {
            if let Some(setup) = hooks.record_arm() {
                let id = self.fresh_control_id();
                self.arming = Some(Arming {
                    id,
                    setup,
                    sent_at: None,
                    refused: None,
                });
            }
        }
        let Some(a) = self.arming.as_mut() else {
            return Ok(());
        };
        if a.sent_at
            .is_some_and(|t| now.duration_since(t) <= CONTROL_RESEND_AFTER)
        {
            return Ok(());
        }
        if a.sent_at.is_some() {
            self.stats.controls_resent += 1;
        } else {
            self.stats.controls += 1;
        }
        a.sent_at = Some(now);
        let mut req = heapless::Vec::new();
        let _ = req.push(RECORD_ARM);
        let _ = req.extend_from_slice(&a.setup.pack());
        let id = a.id;
        self.queue(0, &HostMsg::Record { id, req })
    }

    /// A recorder answer (not a streamed piece) while a request is on its way: its
    /// refusal, if it carries one.
    pub(super) fn arming_answer(&mut self, reply: &Reply) {
        if let (Some(a), Some(e)) = (self.arming.as_mut(), reply.refused) {
            if a.sent_at.is_some() {
                a.refused = Some(e.to_string());
            }
        }
    }

    /// A control acknowledged: if it is the request on its way, the hooks hear how it
    /// went and the pieces of the old request go.
    pub(super) fn arming_acked(&mut self, id: u16, hooks: &mut dyn JobHooks) {
        if self.arming.as_ref().is_some_and(|a| a.id == id) {
            let a = self.arming.take().expect("checked");
            self.streamed.clear();
            hooks.record_armed(a.refused);
        }
    }

    /// A request still on its way when its job ends is forgotten (the hooks arm it
    /// again between jobs).
    pub(super) fn arming_forget(&mut self) {
        self.arming = None;
    }
}
