//! Streaming a job: the credit window, go-back-N, the operator's controls while it
//! runs, the stall guard, and the job's end (see the module documentation of
//! [`crate::link`]).

use super::client::PendingControl;
use super::hooks::{JobEnd, JobHooks, LinkView};
use super::plans::{Derived, Plans, DROP_EVERY};
use super::stall::dwell_ticks;
use super::trail::Trail;
use super::window::{Ending, JobState};
use super::{Link, LinkError, Transport, CONTROL_RESEND_AFTER, READ_WAIT};
use pkmc::kinematics::MachineKinematics;
use pkmc::motion::block::{Block, Motion};
use pkmc::motion::geometry::Path;
use pkmc::wire::{AlarmCause, Control, CtrlMsg, HostMsg, State, Status};
use std::time::{Duration, Instant};

/// While a job is fed, the last block known is sent without its successor once no
/// block has come for this long.
pub const TAIL_AFTER: Duration = Duration::from_millis(40);
/// ... or once the controller holds less motion than this, ms (with the blocks in
/// flight): better a stop at the next corner than running dry before it.
const LOW_WATER_MS: f64 = 150.0;
/// While blocks are planned, the link is kept alive and the job's hooks are called
/// ([`JobHooks::meanwhile`]) at most this often.
const ALIVE_EVERY: Duration = Duration::from_millis(2);

/// Estimated duration of `b` starting from pose `from`, ms, at its feed (rapids at
/// the slowest axis's `axis_vmax`, units/s), ignoring acceleration: a lower bound
/// of what the controller will report buffered for it. The length of a line or an
/// arc is the core's own ([`Path`]: what the controller executes). Dwells count their
/// time, auxiliary functions nothing.
pub fn estimate_ms(from: &[i64; 6], b: &Block, axis_vmax: &[i64; 6]) -> f64 {
    estimate_on(from, b, Path::new(b, from).ok().as_ref(), axis_vmax)
}

/// [`estimate_ms`] of `b` whose path from `from` is derived already (`None`: malformed).
fn estimate_on(from: &[i64; 6], b: &Block, path: Option<&Path>, axis_vmax: &[i64; 6]) -> f64 {
    match b.motion {
        Motion::Rapid => {
            (0..6)
                .filter(|&i| axis_vmax[i] > 0)
                .map(|i| (b.target[i] - from[i]).unsigned_abs() as f64 / axis_vmax[i] as f64)
                .fold(0.0, f64::max)
                * 1000.0
        }
        Motion::Linear | Motion::Arc { .. } | Motion::Cubic { .. } | Motion::Quadratic { .. }
            if b.feed > 0 =>
        {
            path.map_or(0.0, |p| p.length as f64 / b.feed as f64 * 1000.0)
        }
        Motion::Linear | Motion::Arc { .. } | Motion::Cubic { .. } | Motion::Quadratic { .. } => {
            0.0
        }
        Motion::Dwell(ms) => ms as f64,
        Motion::Aux(_) => 0.0,
    }
}

/// A job's first blocks: the first starts at `pose`, and their paths may be derived
/// already.
struct Fresh<'a> {
    blocks: &'a [Block],
    derived: Option<Derived<'a>>,
    pose: [i64; 6],
}

/// A job's blocks as they are known: all of them at the start, or more fed while it
/// runs ([`JobHooks::feed`]).
pub(super) struct Fed {
    /// The blocks from the first the controller may still ask for (executing or not
    /// yet acknowledged) on.
    pub(super) blocks: Trail<Block>,
    pub(super) plans: Plans,
    kin: MachineKinematics,
    /// More blocks may come.
    pub(super) open: bool,
    /// When blocks last came.
    last_fed: Instant,
}

impl Fed {
    /// Drops what the controller can no longer ask for: the blocks before the first
    /// executing or not yet acknowledged, with their plans and running sums (in
    /// steps of [`DROP_EVERY`], so a shorter job keeps everything).
    fn drop_done(&mut self, job: &mut JobState, status: Option<&Status>) {
        let executed = status.map_or(0, |s| s.blocks_done.wrapping_sub(job.done_before) as usize);
        let keep = job.acked.min(executed).min(job.high.saturating_sub(1));
        if keep < self.blocks.base() + DROP_EVERY {
            return;
        }
        self.plans.drop_before(keep);
        self.blocks.drop_before(keep);
        job.planned_ms.drop_before(keep);
        job.arcs_before.drop_before(keep);
    }
}

impl<T: Transport> Link<T> {
    /// Streams `blocks` and waits until they have all executed, the controller raises
    /// an alarm, or the operator's abort or stop has taken effect; on a simulator, a
    /// controller moving without progress is an error ([`LinkError::Stalled`]).
    /// [`JobHooks::feed`] may add blocks while the job runs: the job then ends when
    /// the feed is closed and every block has executed.
    pub fn run_job(
        &mut self,
        blocks: &[Block],
        hooks: &mut dyn JobHooks,
    ) -> Result<JobEnd, LinkError> {
        self.run_job_on(blocks, None, hooks)
    }

    /// [`Link::run_job`] of blocks whose paths are `derived` already (the compile's):
    /// the link plans on them rather than deriving them again.
    pub fn run_job_on(
        &mut self,
        blocks: &[Block],
        derived: Option<Derived<'_>>,
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
        self.begin_job(self.opts.mark)?;
        let pose = start_status.pose;
        let done = start_status.blocks_done;
        let job = Fresh {
            blocks,
            derived,
            pose,
        };
        self.stream_job(job, &start_status, done, hooks)
    }

    /// Takes over the held job of an earlier host whose program is `mark` (as the
    /// controller reported it: `next_block` the first block it never received) and
    /// streams the rest of it, `rest` (the program's blocks from `next_block` on,
    /// the first starting at `start`), to the end: the held job is adopted
    /// (`BeginJob` with its mark), resumed, and fed on.
    pub fn continue_job(
        &mut self,
        mark: pkmc::wire::JobMark,
        rest: &[Block],
        start: [i64; 6],
        hooks: &mut dyn JobHooks,
    ) -> Result<JobEnd, LinkError> {
        let queued = self.held.map_or(0, |h| h.queued as u32);
        self.begin_job(mark)?;
        let s = self.request_status()?;
        if s.orphan {
            return Err(LinkError::JobHeld {
                port: self.port(),
                job: self.held.unwrap_or(pkmc::wire::HeldJob {
                    host: 0,
                    line: s.line,
                    done: 0,
                    queued: 0,
                    state: s.state,
                }),
            });
        }
        self.release_held();
        hooks.status(&s);
        self.control(Control::Resume)?;
        // The earlier host's blocks still queued complete first: they count in
        // `blocks_done` (from 0 at this session's `Hello`) before this job's.
        let job = Fresh {
            blocks: rest,
            derived: None,
            pose: start,
        };
        self.stream_job(job, &s, queued, hooks)
    }

    /// `Control::BeginJob` for a streamed program (with the host timeout set).
    fn begin_job(&mut self, mark: pkmc::wire::JobMark) -> Result<(), LinkError> {
        if let Some(t) = self.opts.host_timeout {
            // A streamed program: host silence starves it, and holds it only after
            // `t` (the short watch stays for MDI and the bridge's lines).
            let ms = t.as_millis().clamp(1, u32::MAX as u128) as u32;
            self.control(Control::BeginJob {
                host_timeout_ms: ms,
                mark,
            })?;
        }
        Ok(())
    }

    /// Streams `job` as a job whose status at the start is `start_status`; the
    /// controller's `blocks_done` is `done_before` when the first of them starts.
    fn stream_job(
        &mut self,
        job: Fresh<'_>,
        start_status: &Status,
        done_before: u32,
        hooks: &mut dyn JobHooks,
    ) -> Result<JobEnd, LinkError> {
        let Fresh {
            blocks,
            derived,
            pose,
        } = job;
        // Nothing another job's planning read is left for this one's loop.
        let left = std::mem::take(&mut self.stashed);
        self.absorb(&left);
        let mut job = JobState::new(self.next_seq, self.capacity, start_status);
        job.done_before = done_before;
        job.planned_ms.push(0.0);
        job.arcs_before.push(0);
        let mut fed = Fed {
            blocks: Trail::default(),
            plans: Plans::new(pose, &self.machine),
            kin: MachineKinematics::new(&self.machine),
            open: true,
            last_fed: Instant::now(),
        };
        self.append(&mut fed, &mut job, blocks, derived, hooks)?;
        let result = self.job_loop(&mut fed, hooks, &mut job);
        self.stats.plan_time_s = fed.plans.time_s();
        self.stats.buffered = super::Buffered::of(&mut job.buffered_samples);
        self.stats.rtt_ms = job.rtt.srtt().map_or(0.0, |d| d.as_secs_f64() * 1e3);
        self.stats.rto_ms = job.rtt.rto(self.opts.resend_after).as_secs_f64() * 1e3;
        self.next_seq = job.seq_of(job.acked.max(job.high));
        result
    }

    /// Adds `new` (whose paths may be `derived` already) to the job: plans (the blocks
    /// not yet sent are planned again with the new ones in view), then each block's
    /// motion estimate and arcs, its length read from the path the planner holds.
    fn append(
        &mut self,
        fed: &mut Fed,
        job: &mut JobState,
        new: &[Block],
        derived: Option<Derived<'_>>,
        hooks: &mut dyn JobHooks,
    ) -> Result<(), LinkError> {
        let first = fed.blocks.len();
        let machine = self.machine.clone();
        // A large program takes seconds to plan: the link is kept alive meanwhile, and
        // the hooks answer their clients.
        let mut last = Instant::now();
        fed.plans
            .extend(new, derived, job.high, &machine, &fed.kin, &mut || {
                if last.elapsed() >= ALIVE_EVERY {
                    self.keep_alive();
                    hooks.meanwhile();
                    last = Instant::now();
                }
            })
            .map_err(|i| LinkError::BadBlock {
                port: self.port(),
                line: new[i - first].line,
            })?;
        for (i, b) in new.iter().enumerate() {
            let (from, path) = fed.plans.path(first + i);
            let arcs = job.arcs_before.last().copied().unwrap_or(0);
            job.arcs_before.push(arcs + b.motion.curved() as usize);
            let total = job.planned_ms.last().copied().unwrap_or(0.0);
            job.planned_ms
                .push(total + estimate_on(&from, b, Some(path), &self.axis_vmax));
        }
        fed.blocks.extend_from_slice(new);
        fed.last_fed = Instant::now();
        Ok(())
    }

    /// How many of the job's blocks may be sent now: all of them, but while the feed
    /// is open the last one known waits for its successor (so that the corner between
    /// them can be blended) unless the feed has been quiet for [`TAIL_AFTER`] or the
    /// controller is about to run out of motion.
    fn sendable(&self, fed: &Fed, job: &JobState) -> usize {
        let total = fed.blocks.len();
        if !fed.open || total == 0 {
            return total;
        }
        let low = (job.buffered_ms as f64 + job.in_flight_ms()) < LOW_WATER_MS;
        if low || fed.last_fed.elapsed() >= TAIL_AFTER {
            total
        } else {
            total - 1
        }
    }

    pub(super) fn job_loop(
        &mut self,
        fed: &mut Fed,
        hooks: &mut dyn JobHooks,
        job: &mut JobState,
    ) -> Result<JobEnd, LinkError> {
        let mut new = Vec::new();
        self.arming_forget();
        loop {
            let now = Instant::now();
            // Operator commands, and blocks fed while the job runs.
            let view = LinkView {
                status: self.status.clone(),
                acked: job.acked,
                total: fed.blocks.len(),
                executed: self
                    .status
                    .as_ref()
                    .map_or(0, |s| s.blocks_done.wrapping_sub(job.done_before) as usize),
                control_pending: self.control.is_some() || !self.controls.is_empty(),
            };
            if let Some(cmd) = hooks.control(&view) {
                self.controls.push_back(cmd);
            }
            hooks.recorded(&mut self.streamed);
            if let Some(offset) = hooks.record_ask() {
                self.ask_recorder(offset)?;
            }
            self.service_arming(now, hooks)?;
            if fed.open && job.ending.is_none() {
                new.clear();
                fed.open = hooks.feed(&view, &mut new);
                if !new.is_empty() {
                    self.append(fed, job, &new, None, hooks)?;
                }
            }
            let total = fed.blocks.len();
            if !fed.open && job.acked == total && !job.end_sent && job.ending.is_none() {
                // Every block is on the controller: the job is complete there (a host
                // lost before this leaves an unfinished job, an alarm).
                job.end_sent = true;
                self.controls.push_back(Control::EndJob);
            }
            self.service_controls(now, job)?;
            // Blocks, within credits and the buffered-motion limit.
            if job.ending.is_none() && self.tx.is_empty() {
                let sendable = self.sendable(fed, job);
                self.send_blocks(fed, job, sendable, now)?;
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
            // What arrived while blocks were planned first, then what is here now.
            let mut msgs = std::mem::take(&mut self.stashed);
            let wait = if self.tx.is_empty() && msgs.is_empty() {
                READ_WAIT
            } else {
                Duration::ZERO
            };
            msgs.extend(self.pump(wait)?);
            for m in msgs {
                if let Some(end) = self.handle(m, fed, hooks, job)? {
                    return Ok(end);
                }
            }
            fed.drop_done(job, self.status.as_ref());
            self.judge_line(job, hooks);
            self.resend_if_late(job);
            // Lost by the same rule as a request: silent for the link timeout, or,
            // while damaged frames keep arriving, ten times it.
            if self.given_up(self.last_heard) {
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
        fed: &Fed,
        hooks: &mut dyn JobHooks,
        job: &mut JobState,
    ) -> Result<Option<JobEnd>, LinkError> {
        let blocks = &fed.blocks;
        match m {
            CtrlMsg::Ack {
                seq,
                free_slots,
                free_bends,
                buffered_ms,
            } => {
                if let Some(done) = job.index_after(seq) {
                    job.rtt.acked(done, true);
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
                self.arming_acked(id, hooks);
                if let Some(e) = job.ending.as_mut() {
                    if e.id == id {
                        e.acked = true;
                    }
                }
            }
            CtrlMsg::Status(s) => return self.on_status(&s, fed, hooks, job),
            // We said no `Hello` since the job began: another program on the port did.
            CtrlMsg::HelloAck { .. } => return Err(self.superseded("its HelloAck")),
            // A job of blocks sends no probing move: a result is an earlier one's.
            CtrlMsg::MachineLoaded { .. } | CtrlMsg::MachineRefused { .. } | CtrlMsg::Probe(_) => {}
            // The recorder streaming beside the job: kept for whoever reads it.
            CtrlMsg::Record(bytes) => {
                self.keep_streamed(&bytes);
                // A read asked by the hooks beside the job: theirs.
                if let Some((reply, data)) = pkmc::drive::recorder::Reply::unpack(&bytes) {
                    if !reply.streamed {
                        self.arming_answer(&reply);
                        hooks.record_answer(&reply, data);
                    }
                }
            }
        }
        Ok(None)
    }

    /// A status: acknowledges what it shows executed, updates the credits, and ends
    /// the job when it shows the end (done, alarm, abort or stop taken effect, or a
    /// pause nobody here can resume); feeds the stall guard.
    fn on_status(
        &mut self,
        s: &Status,
        fed: &Fed,
        hooks: &mut dyn JobHooks,
        job: &mut JobState,
    ) -> Result<Option<JobEnd>, LinkError> {
        let (blocks, total) = (&fed.blocks, fed.blocks.len());
        // Blocks executed were accepted: a lost final `Ack` need not be waited for.
        let executed = s.blocks_done.wrapping_sub(job.done_before) as usize;
        if executed > job.acked && executed <= job.high {
            job.advance(executed);
        }
        job.free = s.free_slots as usize;
        job.free_bends = s.free_bends as usize;
        job.buffered_ms = s.buffered_ms;
        if job.sent < total
            && s.state == State::Running
            && s.motion_ticks * 1000 >= super::Buffered::SETTLE_MS * pkmc::units::TICK_HZ as u64
        {
            job.buffered_samples.push(s.buffered_ms);
        }
        hooks.status(s);
        if s.orphan {
            return Err(self.superseded("a status naming the job another host's"));
        }
        if s.state == State::Hold
            && s.alarm.is_some_and(|a| a.cause == AlarmCause::HostTimeout)
            && job.ending.is_none()
        {
            // Held because this host was silent past the job's host timeout (stopped,
            // starved of CPU): back, it resumes its own job and streams on.
            let asked = self.control.is_some_and(|pc| pc.cmd == Control::Resume)
                || self.controls.contains(&Control::Resume);
            if !asked {
                self.stats.host_timeout_resumes += 1;
                hooks.note(&format!(
                    "the controller held the job at line {} after this host had been \
                     silent past its host timeout (stopped or starved of CPU); resuming it",
                    s.line
                ));
                self.controls.push_back(Control::Resume);
            }
            return Ok(None);
        }
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
            && !fed.open
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
                plane: pkmc::motion::block::Plane::Xy,
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
                plane: pkmc::motion::block::Plane::Xy,
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
