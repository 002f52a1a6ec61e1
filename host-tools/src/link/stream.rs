//! Streaming a job: the credit window, go-back-N, the operator's controls while it
//! runs, the stall guard, and the job's end (see the module documentation of
//! [`crate::link`]).

use super::client::{JobEnd, JobHooks, LinkView, PendingControl};
use super::stall::dwell_ticks;
use super::window::{Ending, Guard, JobState};
use super::{Link, LinkError, Transport, CONTROL_RESEND_AFTER, READ_WAIT};
use pkmc::geometry::Path;
use pkmc::kinematics::MachineKinematics;
use pkmc::planner::{plan_into, PlanBlock};
use pkmc::protocol::{
    Block, Control, CtrlMsg, HostMsg, Motion, NakReason, PlannedBlock, State, Status,
};
use std::time::{Duration, Instant};

/// Estimated duration of `b` starting from pose `from`, ms, at its feed (rapids at
/// the slowest axis's `axis_vmax`, units/s), ignoring acceleration: a lower bound
/// of what the controller will report buffered for it. The length of a line or an
/// arc is the core's own ([`Path`]: what the controller executes). Dwells count their
/// time, auxiliary functions nothing.
pub fn estimate_ms(from: &[i64; 6], b: &Block, axis_vmax: &[i64; 6]) -> f64 {
    match b.motion {
        Motion::Rapid => {
            (0..6)
                .filter(|&i| axis_vmax[i] > 0)
                .map(|i| (b.target[i] - from[i]).unsigned_abs() as f64 / axis_vmax[i] as f64)
                .fold(0.0, f64::max)
                * 1000.0
        }
        Motion::Linear | Motion::Arc { .. } if b.feed > 0 => {
            Path::new(b, from).map_or(0.0, |p| p.length as f64 / b.feed as f64 * 1000.0)
        }
        Motion::Linear | Motion::Arc { .. } => 0.0,
        Motion::Dwell(ms) => ms as f64,
        Motion::Aux(_) => 0.0,
    }
}

impl<T: Transport> Link<T> {
    /// Streams `blocks` and waits until they have all executed, the controller raises
    /// an alarm, or the operator's abort or stop has taken effect; on a simulator, a
    /// controller moving without progress is an error ([`LinkError::Stalled`]).
    pub fn run_job(
        &mut self,
        blocks: &[Block],
        hooks: &mut dyn JobHooks,
    ) -> Result<JobEnd, LinkError> {
        self.refuse_if_held()?;
        let start_status = self.request_status()?;
        hooks.status(&start_status);
        if matches!(start_status.state, State::Alarm | State::EStop) {
            if let Some(a) = start_status.alarm {
                return Ok(JobEnd::Alarm(a));
            }
        }
        let planned = self.plan(blocks, start_status.pose)?;
        let mut job = JobState::new(self.next_seq, self.capacity, &start_status);
        // Cumulative estimated motion, ms: `planned_ms[i]` covers blocks before `i`.
        let mut from = start_status.pose;
        job.planned_ms = Vec::with_capacity(blocks.len() + 1);
        job.planned_ms.push(0.0);
        job.arcs_before = Vec::with_capacity(blocks.len() + 1);
        job.arcs_before.push(0);
        for b in blocks {
            let arcs = job.arcs_before.last().copied().unwrap_or(0);
            job.arcs_before
                .push(arcs + matches!(b.motion, Motion::Arc { .. }) as usize);
            let total = job.planned_ms.last().copied().unwrap_or(0.0);
            job.planned_ms
                .push(total + estimate_ms(&from, b, &self.axis_vmax));
            if !matches!(b.motion, Motion::Dwell(_) | Motion::Aux(_)) {
                from = b.target;
            }
        }
        let result = self.job_loop(blocks, &planned, hooks, &mut job);
        self.next_seq = job.seq_of(job.acked.max(job.high));
        result
    }

    /// Plans `blocks` from `start` with the whole job in view: the core's planner, as
    /// the controller would with unlimited look-ahead ([`pkmc::planner::plan_into`]).
    pub(super) fn plan(
        &mut self,
        blocks: &[Block],
        start: [i64; 6],
    ) -> Result<Vec<PlannedBlock>, LinkError> {
        let kin = MachineKinematics::new(&self.machine);
        let mut out = vec![PlanBlock::default(); blocks.len()];
        let window = pkmc::interp::window_of(self.machine.motion.smoothing_ticks as u32);
        plan_into(blocks, start, &self.machine, &kin, window, &mut out).map_err(|(i, _)| {
            LinkError::BadBlock {
                port: self.port(),
                line: blocks[i].line,
            }
        })?;
        self.stats.plan_time_s =
            pkmc::planner::planned_ticks(&out) * pkmc::units::TICK_NS as f64 * 1e-9;
        Ok(blocks
            .iter()
            .zip(&out)
            .map(|(b, p)| PlannedBlock {
                block: *b,
                plan: p.plan(),
            })
            .collect())
    }

    pub(super) fn job_loop(
        &mut self,
        blocks: &[Block],
        planned: &[PlannedBlock],
        hooks: &mut dyn JobHooks,
        job: &mut JobState,
    ) -> Result<JobEnd, LinkError> {
        let total = blocks.len();
        loop {
            let now = Instant::now();
            // Operator commands.
            let view = LinkView {
                status: self.status.clone(),
                acked: job.acked,
                total,
                control_pending: self.control.is_some() || !self.controls.is_empty(),
            };
            if let Some(cmd) = hooks.control(&view) {
                self.controls.push_back(cmd);
            }
            if job.acked == total && !job.end_sent && job.ending.is_none() {
                // Every block is on the controller: the job is complete there (a host
                // lost before this leaves an unfinished job, an alarm).
                job.end_sent = true;
                self.controls.push_back(Control::EndJob);
            }
            self.service_controls(now, job)?;
            // Blocks, within credits and the buffered-motion limit.
            if job.ending.is_none() && self.tx.is_empty() {
                while job.sent < total
                    && job.sent - job.acked < job.free.min(job.window)
                    && job.bend_free_for(job.sent)
                    && job.buffered_ms < self.opts.max_buffered_ms
                    && (job.sent == job.acked
                        || job.buffered_ms as f64 + job.in_flight_ms()
                            < self.opts.max_buffered_ms as f64)
                {
                    let seq = job.seq_of(job.sent);
                    self.queue(seq, &HostMsg::Block(planned[job.sent]))?;
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
            }
            // Heartbeat: a status request every `keepalive`, so the controller hears
            // the host (it stops after 1 s of silence while moving) and the host hears
            // the controller.
            if self.last_request.elapsed() > self.opts.keepalive {
                self.queue(0, &HostMsg::StatusRequest)?;
                self.stats.status_requests += 1;
                self.last_request = now;
            }
            self.flush_some()?;
            let wait = if self.tx.is_empty() {
                READ_WAIT
            } else {
                Duration::ZERO
            };
            for m in self.pump(wait)? {
                if let Some(end) = self.handle(m, blocks, hooks, job)? {
                    return Ok(end);
                }
            }
            // Retransmission timeout.
            if job.sent > job.acked && job.last_progress.elapsed() > self.opts.resend_after {
                self.stats.timeouts += 1;
                job.rewind_to(job.acked, &mut self.stats);
                job.guard = None;
                job.last_progress = Instant::now();
            }
            if self.last_heard.elapsed() > self.opts.link_timeout {
                return Err(self.lost(
                    if job.acked < total {
                        "streaming blocks"
                    } else {
                        "waiting for the end of the job"
                    },
                    self.last_heard,
                ));
            }
        }
    }

    pub(super) fn service_controls(
        &mut self,
        now: Instant,
        job: &mut JobState,
    ) -> Result<(), LinkError> {
        if self.control.is_none() {
            if let Some(cmd) = self.controls.pop_front() {
                let id = self.fresh_control_id();
                self.control = Some(PendingControl {
                    id,
                    cmd,
                    sent_at: None,
                });
                // An immediate stop overrides a controlled one still under way.
                let ends = match cmd {
                    Control::Stop => true,
                    Control::Abort => job.ending.is_none(),
                    _ => false,
                };
                if ends {
                    job.ending = Some(Ending {
                        cmd,
                        id,
                        acked: false,
                    });
                }
            }
        }
        if let Some(pc) = self.control.as_mut() {
            let due = pc
                .sent_at
                .is_none_or(|t| now.duration_since(t) > CONTROL_RESEND_AFTER);
            if due {
                if pc.sent_at.is_some() {
                    self.stats.controls_resent += 1;
                } else {
                    self.stats.controls += 1;
                }
                pc.sent_at = Some(now);
                let (id, cmd) = (pc.id, pc.cmd);
                self.queue(0, &HostMsg::Control { id, cmd })?;
            }
        }
        Ok(())
    }

    pub(super) fn handle(
        &mut self,
        m: CtrlMsg,
        blocks: &[Block],
        hooks: &mut dyn JobHooks,
        job: &mut JobState,
    ) -> Result<Option<JobEnd>, LinkError> {
        match m {
            CtrlMsg::Ack {
                seq,
                free_slots,
                free_bends,
                buffered_ms,
            } => {
                if let Some(done) = job.index_after(seq) {
                    if done > job.acked {
                        job.advance(done);
                    }
                    job.free = free_slots as usize;
                    job.free_bends = free_bends as usize;
                    job.buffered_ms = buffered_ms;
                }
            }
            CtrlMsg::Nak { expected, reason } => self.on_nak(expected, reason, blocks, job)?,
            CtrlMsg::ControlAck { id } => {
                if self.control.is_some_and(|pc| pc.id == id) {
                    self.control = None;
                }
                if let Some(e) = job.ending.as_mut() {
                    if e.id == id {
                        e.acked = true;
                    }
                }
            }
            CtrlMsg::Status(s) => return self.on_status(&s, blocks, hooks, job),
            CtrlMsg::HelloAck { .. }
            | CtrlMsg::MachineLoaded { .. }
            | CtrlMsg::MachineRefused { .. } => {}
        }
        Ok(None)
    }

    /// A `Nak`: counted by reason; refusals no resend can cure end the job; otherwise
    /// the stream goes back to the block the controller expects, once per loss (the
    /// `Nak`s the blocks behind the lost one draw are ignored).
    fn on_nak(
        &mut self,
        expected: u16,
        reason: NakReason,
        blocks: &[Block],
        job: &mut JobState,
    ) -> Result<(), LinkError> {
        self.stats.naks += 1;
        match reason {
            NakReason::Corrupt => self.stats.nak_reasons.corrupt += 1,
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
            NakReason::JobHeld => {
                return Err(LinkError::JobHeld {
                    port: self.port(),
                    job: self.held.unwrap_or(pkmc::protocol::HeldJob {
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
        if let Some(at) = at {
            if job.ending.is_none() && at < job.sent {
                match job.guard.as_mut() {
                    Some(g) if g.at == at && g.stale_left > 0 => {
                        g.stale_left -= 1;
                        self.stats.naks_ignored += 1;
                    }
                    _ => {
                        let stale = job.sent - at - 1;
                        job.rewind_to(at, &mut self.stats);
                        job.guard = Some(Guard {
                            at,
                            stale_left: stale,
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

    /// A status: acknowledges what it shows executed, updates the credits, and ends
    /// the job when it shows the end (done, alarm, abort or stop taken effect, or a
    /// pause nobody here can resume); feeds the stall guard.
    fn on_status(
        &mut self,
        s: &Status,
        blocks: &[Block],
        hooks: &mut dyn JobHooks,
        job: &mut JobState,
    ) -> Result<Option<JobEnd>, LinkError> {
        let total = blocks.len();
        // Blocks executed were accepted: a lost final `Ack` need not be waited for.
        let executed = s.blocks_done.wrapping_sub(job.done_before) as usize;
        if executed > job.acked && executed <= job.high {
            job.advance(executed);
        }
        job.free = s.free_slots as usize;
        job.free_bends = s.free_bends as usize;
        job.buffered_ms = s.buffered_ms;
        hooks.status(s);
        if s.state == State::Hold
            && s.speed == 0
            && job.ending.is_none()
            && self.control.is_none()
            && hooks.ends_at_pause()
        {
            // Held at a pause with nobody here to resume it: the job stays
            // held on the controller for `nc-send resume`.
            return Ok(Some(JobEnd::Paused(s.line)));
        }
        // A fault stops on the path first: the job ends once at rest.
        if matches!(s.state, State::Alarm | State::EStop) && s.speed == 0 {
            if job
                .ending
                .is_some_and(|e| e.acked && e.cmd == Control::Stop)
            {
                return Ok(Some(JobEnd::Stopped));
            }
            if let Some(a) = s.alarm {
                return Ok(Some(JobEnd::Alarm(a)));
            }
        }
        if let Some(e) = job.ending.filter(|e| e.acked) {
            if e.cmd == Control::Abort && s.state == State::Idle && s.speed == 0 {
                return Ok(Some(JobEnd::Aborted));
            }
        }
        if job.ending.is_none()
            && job.acked == total
            && job.end_sent
            && self.control.is_none()
            && self.controls.is_empty()
            && s.state == State::Idle
            && s.blocks_done >= job.done_before.wrapping_add(total as u32)
        {
            return Ok(Some(JobEnd::Done));
        }
        let dwell = dwell_ticks(blocks, job.done_before, s);
        self.check_stall(&mut job.stall, s, dwell)?;
        Ok(None)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn block(motion: Motion, target: [i64; 6], feed_mm_s: i64) -> Block {
        Block {
            line: 1,
            motion,
            target,
            feed: feed_mm_s * 1_000_000,
            tolerance_nm: 0,
        }
    }

    #[test]
    fn motion_estimates_follow_feed_rapid_limits_arcs_and_dwells() {
        let vmax = [100_000_000; 6];
        let at = [0; 6];
        let mm = 1_000_000;
        let line = block(Motion::Linear, [30 * mm, 40 * mm, 0, 0, 0, 0], 10);
        assert!((estimate_ms(&at, &line, &vmax) - 5000.0).abs() < 1e-6);
        let rapid = block(Motion::Rapid, [50 * mm, 10 * mm, 0, 0, 0, 0], 0);
        assert!((estimate_ms(&at, &rapid, &vmax) - 500.0).abs() < 1e-6);
        // A half circle of radius 10 mm at 10 mm/s: 10π mm in π s.
        let half = block(
            Motion::Arc {
                center: [10 * mm, 0],
                plane: pkmc::protocol::Plane::Xy,
                clockwise: true,
                turns: 0,
            },
            [20 * mm, 0, 0, 0, 0, 0],
            10,
        );
        let ms = estimate_ms(&at, &half, &vmax);
        assert!((ms - std::f64::consts::PI * 1000.0).abs() < 1e-3, "{ms}");
        // The other way round with one extra turn: three half circles.
        let long = block(
            Motion::Arc {
                center: [10 * mm, 0],
                plane: pkmc::protocol::Plane::Xy,
                clockwise: false,
                turns: 1,
            },
            [20 * mm, 0, 0, 0, 0, 0],
            10,
        );
        let ms = estimate_ms(&at, &long, &vmax);
        assert!(
            (ms - 3.0 * std::f64::consts::PI * 1000.0).abs() < 1e-3,
            "{ms}"
        );
        assert_eq!(
            estimate_ms(&at, &block(Motion::Dwell(250), at, 0), &vmax),
            250.0
        );
    }
}
