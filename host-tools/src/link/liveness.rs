//! The client's liveness beyond the heartbeat: its own stalls (a stopped process, a
//! starved CPU) told apart from the controller's silence, the heartbeat while it plans,
//! and another program's session on the port in the middle of a job.

use super::{Link, LinkError, Transport};
use pkmc::wire::HostMsg;
use std::time::{Duration, Instant};

impl<T: Transport> Link<T> {
    /// A gap of `gap` in the client's own loop: when longer than [`super::OWN_GAP`],
    /// the silence timers start again and a status is asked for at once.
    pub(super) fn own_gap(&mut self, gap: Duration) -> Result<(), LinkError> {
        if gap <= super::OWN_GAP {
            return Ok(());
        }
        let now = Instant::now();
        self.last_gap_end = now;
        self.stats.own_gaps += 1;
        self.stats.own_gap_max_s = self.stats.own_gap_max_s.max(gap.as_secs_f64());
        self.last_heard = now;
        self.last_bytes = now;
        self.queue(0, &HostMsg::StatusRequest)?;
        self.stats.status_requests += 1;
        self.last_request = now;
        self.flush_some()
    }

    /// The heartbeat while a job's blocks are planned: a status request every
    /// keep-alive period, and what has arrived read and kept (acknowledgements of
    /// blocks, statuses, recorder pieces) for the job's loop, which handles it before
    /// it reads again. Errors are left for the next real read to find.
    pub(super) fn keep_alive(&mut self) {
        if self.last_request.elapsed() > self.opts.keepalive
            && self.queue(0, &HostMsg::StatusRequest).is_ok()
        {
            self.stats.status_requests += 1;
            self.last_request = Instant::now();
        }
        let _ = self.flush_some();
        if let Ok(msgs) = self.pump(Duration::ZERO) {
            self.stashed.extend(msgs);
        }
    }

    /// Another program opened a session on the port in the middle of our job (`seen`:
    /// how we know).
    pub(super) fn superseded(&self, seen: &'static str) -> LinkError {
        LinkError::Superseded {
            port: self.port(),
            seen,
        }
    }
}
