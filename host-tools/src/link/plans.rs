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
//! The pass sequence is the core's own ([`pkmc::motion::planner::replan_from`], which
//! [`pkmc::motion::planner::plan_into`] runs too): fed all at once, this is `plan_into` exactly.

use pkmc::config::{MachineConfig, AXES};
use pkmc::kinematics::MachineKinematics;
use pkmc::motion::block::{Block, PlannedBlock};
use pkmc::motion::geometry::Path;
use pkmc::motion::planner::{replan_from, Lookahead, PlanBlock};

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
    /// `frozen` (the first never sent) on, with the core's pass sequence
    /// ([`replan_from`]). Fails with the index of a block whose geometry is malformed.
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
        replan_from(&mut self.work, frozen, self.start, machine, kin, alive);
        for (i, p) in self.work.iter().enumerate().skip(frozen) {
            self.planned[i].plan = p.plan();
        }
        Ok(())
    }

    /// Block `i`'s path as the planner derived it, and where it starts (the block's
    /// geometry is derived once, here, and read by whoever needs it).
    pub(super) fn path(&self, i: usize) -> ([i64; AXES], &Path) {
        let from = i
            .checked_sub(1)
            .map_or(self.start, |p| self.work[p].path.end);
        (from, &self.work[i].path)
    }

    /// Motion time of everything planned at 100 % feed, s.
    pub(super) fn time_s(&self) -> f64 {
        pkmc::motion::planner::planned_ticks(&self.work) * pkmc::units::TICK_NS as f64 * 1e-9
    }
}
