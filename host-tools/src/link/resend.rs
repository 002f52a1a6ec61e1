//! Resending: the blocks sent within the credits (in copies on a damaged line), the
//! `Nak`s that send the stream back (go-back-N, once per loss), the retransmission
//! timeout on the measured round trip, and the operator told when the line is bad.
//!
//! A lost block costs the time until its loss is known plus every block sent behind
//! it (the controller takes blocks only in order). So: the controller answers a
//! damaged frame at once (`Nak(Corrupt)`) and every block that arrives early
//! (`Nak(Gap)`); the client goes back on the first `Nak` of a loss and ignores the
//! ones the blocks already behind it draw, for a round trip at most ([`super::rtt::Rtt`]); a
//! silence resends after the measured round trip (`srtt + 4 rttvar`, at least
//! [`super::rtt::MIN_RTO`]), not a fixed 200 ms; and on a line that damages many
//! frames each block goes in copies ([`super::rtt::Damage::copies`]), so that
//! losing a block, every copy of it, is rare. The controller accepts exactly the next
//! block and acknowledges every copy or resend of one it has: nothing is lost, nothing
//! runs twice.

use super::hooks::JobHooks;
use super::rtt::Damage;
use super::stream::Fed;
use super::trail::Trail;
use super::window::{Guard, JobState};
use super::{Link, LinkError, Transport};
use pkmc::motion::block::Block;
use pkmc::wire::{HostMsg, NakReason, State};
use std::time::Instant;

/// Frames counted before the line's damage is judged.
const JUDGE_AFTER_FRAMES: u64 = 300;
/// A share of frames damaged from which the operator is told (motion then slows:
/// the queue drains while blocks are resent).
const WARN_DAMAGE: f64 = 0.2;

impl<T: Transport> Link<T> {
    /// Sends the job's blocks up to `sendable` while the credits allow (free slots and
    /// bends, the congestion window, the motion buffered), each in as many copies as
    /// the line's damage calls for.
    pub(super) fn send_blocks(
        &mut self,
        fed: &Fed,
        job: &mut JobState,
        sendable: usize,
        now: Instant,
    ) -> Result<(), LinkError> {
        job.copies = job.damage.copies();
        while job.sent < sendable
            && job.sent - job.acked < job.free.min(job.window)
            && job.bend_free_for(job.sent)
            && job.buffered_ms < self.opts.max_buffered_ms
            && (job.sent == job.acked
                || job.buffered_ms as f64 + job.in_flight_ms() < self.opts.max_buffered_ms as f64)
        {
            let seq = job.seq_of(job.sent);
            let start = self.tx.len();
            self.queue(seq, &HostMsg::Block(fed.plans.planned[job.sent]))?;
            let frame = self.tx.len() - start;
            for _ in 1..job.copies {
                self.tx.extend_from_within(start..start + frame);
                self.stats.frames_sent += 1;
                self.stats.bytes_sent += frame as u64;
                self.stats.copies += 1;
            }
            for _ in 0..job.copies {
                job.damage.sent();
            }
            job.rtt.sent(job.sent, Instant::now(), job.sent >= job.high);
            if job.sent < job.high {
                self.stats.resent += 1;
            } else {
                self.stats.blocks_sent += 1;
            }
            job.sent += 1;
            job.high = job.high.max(job.sent);
            if job.sent - job.acked == 1 {
                job.last_progress = now;
            }
        }
        Ok(())
    }

    /// Retransmission timeout: blocks in flight and nothing acknowledged for the
    /// measured round trip's timeout (a gap of the client's own not counted).
    pub(super) fn resend_if_late(&mut self, job: &mut JobState) {
        job.last_progress = self.since(job.last_progress);
        let rto = job.rtt.rto(self.opts.resend_after);
        if job.sent > job.acked && job.last_progress.elapsed() > rto {
            self.stats.timeouts += 1;
            job.rewind_to(job.acked, &mut self.stats);
            job.guard = None;
            job.last_progress = Instant::now();
        }
    }

    /// Tells the operator, once, and again if it gets twice as bad, that the line
    /// damages so many frames that motion slows down; keeps the worst estimate for the
    /// report.
    pub(super) fn judge_line(&mut self, job: &mut JobState, hooks: &mut dyn JobHooks) {
        if job.damage.frames < JUDGE_AFTER_FRAMES {
            return;
        }
        let rate = job.damage.rate();
        self.stats.frame_damage_max = self.stats.frame_damage_max.max(rate);
        if rate < WARN_DAMAGE.max(2.0 * job.warned_at) {
            return;
        }
        job.warned_at = rate;
        let len = self.stats.bytes_sent as f64 / self.stats.frames_sent.max(1) as f64;
        let bytes = Damage::byte_rate(rate, len);
        self.stats.line_warnings += 1;
        hooks.warn(&format!(
            "the line to the controller damages about {:.0} % of the frames sent to it (a \
             byte fault rate of about {:.1} %): each block now goes in {} copies and lost \
             ones are resent; the machine may slow down, or stop on the path, while they \
             are. Check the cable, its shielding and the port",
            rate * 100.0,
            bytes * 100.0,
            job.copies,
        ));
    }

    /// A `Nak`: counted by reason; refusals no resend can cure end the job; otherwise
    /// the stream goes back to the block the controller expects, once per loss (the
    /// `Nak`s the blocks behind the lost one draw are ignored).
    pub(super) fn on_nak(
        &mut self,
        expected: u16,
        reason: NakReason,
        blocks: &Trail<Block>,
        job: &mut JobState,
    ) -> Result<(), LinkError> {
        self.stats.naks += 1;
        match reason {
            NakReason::Corrupt => {
                self.stats.nak_reasons.corrupt += 1;
                job.damage.damaged();
            }
            NakReason::Gap => self.stats.nak_reasons.gap += 1,
            NakReason::QueueFull => self.stats.nak_reasons.queue_full += 1,
            _ => self.stats.nak_reasons.other += 1,
        }
        let at = job.index_at(expected);
        if let Some(at) = at {
            if at > job.acked {
                job.advance(at);
            }
        }
        match reason {
            NakReason::Version => {
                return Err(LinkError::Version {
                    port: self.port(),
                    theirs: None,
                })
            }
            NakReason::NoSession => return Err(LinkError::SessionLost { port: self.port() }),
            NakReason::MachineMismatch => {
                return Err(LinkError::MachineMismatch { port: self.port() })
            }
            // The job was ours when it began (`run_job` refuses a held one): now it is
            // held as an earlier host's, so another program said `Hello`.
            NakReason::JobHeld if job.high > 0 => {
                return Err(self.superseded("Nak(JobHeld) of our blocks"))
            }
            NakReason::JobHeld => {
                return Err(LinkError::JobHeld {
                    port: self.port(),
                    job: self.held.unwrap_or(pkmc::wire::HeldJob {
                        host: 0,
                        line: self.status.as_ref().map_or(0, |s| s.line),
                        done: 0,
                        queued: 0,
                        state: self.status.as_ref().map_or(State::Hold, |s| s.state),
                    }),
                })
            }
            NakReason::BadBlock => {
                let line = at.and_then(|i| blocks.get(i)).map_or(0, |b| b.line);
                return Err(LinkError::BadBlock {
                    port: self.port(),
                    line,
                });
            }
            NakReason::QueueFull => job.free = 0,
            _ => {}
        }
        if reason == NakReason::Corrupt && job.copies > 1 {
            // Sent in copies, a damaged frame may be a copy of a block accepted
            // already: a lost block shows as a `Gap` (a later block arrived before it)
            // or, the last one sent, by the timeout.
            self.stats.naks_ignored += 1;
            return Ok(());
        }
        if let Some(at) = at {
            if job.ending.is_none() && at < job.sent {
                let window = job.rtt.stale_window(self.opts.resend_after);
                match job.guard.as_mut() {
                    Some(g) if g.at == at && g.stale_left > 0 && g.since.elapsed() < window => {
                        g.stale_left -= 1;
                        self.stats.naks_ignored += 1;
                    }
                    _ => {
                        // Each frame sent behind the lost one, each copy, draws one.
                        let stale = (job.sent - at) * job.copies;
                        job.rewind_to(at, &mut self.stats);
                        job.guard = Some(Guard {
                            at,
                            stale_left: stale,
                            since: Instant::now(),
                        });
                        job.last_progress = Instant::now();
                    }
                }
            } else {
                self.stats.naks_ignored += 1;
            }
        }
        Ok(())
    }
}
