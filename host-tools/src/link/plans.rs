//! A job's plans, extended while it runs: the blocks of a job that is fed line by line
//! (the Grbl bridge) are planned as they arrive, with the look-ahead of what is known.
//!
//! A plan once sent is never changed (a resend carries the same bytes), so only the
//! blocks not yet sent are planned again when more arrive: the reverse pass over them
//! ends at rest after the last block known, and the forward pass starts from the last
//! sent block's planned entry and what it can reach over its length. The controller
//! never leaves a block faster than it can stop within the blocks it holds
//! ([`pkmc::motion::planner::Planner::exit_target`]), so a block sent before its successor was
//! known is safe; the corner after it is planned as a stop, because a blended corner
//! takes part of the acceleration of the block before it, which is already sent.
//!
//! Fed all at once, this is [`pkmc::motion::planner::plan_into`] exactly: the same calls in the
//! same order (the passes, the second look at the splines, the passes again).

use pkmc::config::{MachineConfig, AXES};
use pkmc::kinematics::MachineKinematics;
use pkmc::math::sqrtf;
use pkmc::motion::block::{Block, PlannedBlock};
use pkmc::motion::planner::{forward_pass, refine_splines, reverse_pass, Lookahead, PlanBlock};

/// Blocks planned between two calls of the keep-alive (some milliseconds).
const ALIVE_EVERY: usize = 4096;

pub(super) struct Plans {
    la: Lookahead,
    /// Where the job starts.
    start: [i64; AXES],
    /// One per block, as the passes leave them.
    work: Vec<PlanBlock>,
    /// What is (or will be) streamed: `planned[i]` is fixed once block `i` was sent.
    pub(super) planned: Vec<PlannedBlock>,
}

impl Plans {
    pub(super) fn new(start: [i64; AXES], machine: &MachineConfig) -> Self {
        let smoothing = pkmc::motion::interp::window_of(machine.motion.smoothing_ticks as u32);
        Self {
            la: Lookahead::new(start, smoothing),
            start,
            work: Vec::new(),
            planned: Vec::new(),
        }
    }

    /// Plans `blocks` after those already planned, then plans again every block from
    /// `frozen` (the first never sent) on. Fails with the index of a block whose
    /// geometry is malformed.
    pub(super) fn extend(
        &mut self,
        blocks: &[Block],
        frozen: usize,
        machine: &MachineConfig,
        kin: &MachineKinematics,
        alive: &mut dyn FnMut(),
    ) -> Result<(), usize> {
        for (k, b) in blocks.iter().enumerate() {
            if k % ALIVE_EVERY == ALIVE_EVERY - 1 {
                alive();
            }
            let i = self.work.len();
            // The block before, unless it is sent (its acceleration is final).
            let prev = match i.checked_sub(1) {
                Some(p) if p >= frozen => self.work.get_mut(p),
                _ => None,
            };
            let p = self.la.plan(b, prev, machine, kin).map_err(|_| i)?;
            self.work.push(p);
            self.planned.push(PlannedBlock {
                block: *b,
                plan: p.plan(),
            });
        }
        let frozen = frozen.min(self.work.len());
        let first_entry = match frozen.checked_sub(1) {
            None => 0.0,
            Some(last) => {
                let sent = &self.work[last];
                let e = self.planned[last].plan.entry;
                sqrtf(e * e + 2.0 * sent.accel * sent.length())
            }
        };
        let passes = |tail: &mut [PlanBlock]| {
            reverse_pass(tail, 100, false);
            if let Some(first) = tail.first() {
                let entry = first.entry.min(first_entry);
                forward_pass(tail, entry);
            }
        };
        alive();
        passes(&mut self.work[frozen..]);
        alive();
        if refine_splines(&mut self.work, frozen, self.start, machine, kin) {
            alive();
            passes(&mut self.work[frozen..]);
        }
        alive();
        for (i, p) in self.work.iter().enumerate().skip(frozen) {
            self.planned[i].plan = p.plan();
        }
        Ok(())
    }

    /// Motion time of everything planned at 100 % feed, s.
    pub(super) fn time_s(&self) -> f64 {
        pkmc::motion::planner::planned_ticks(&self.work) * pkmc::units::TICK_NS as f64 * 1e-9
    }
}
