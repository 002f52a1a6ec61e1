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

use super::trail::Trail;
use pkmc::config::{MachineConfig, AXES};
use pkmc::kinematics::MachineKinematics;
use pkmc::motion::block::{Block, PlannedBlock};
use pkmc::motion::geometry::Path;
use pkmc::motion::planner::{planned_ticks, replan_from, Lookahead, PlanBlock};

/// Blocks planned between two calls of the keep-alive (some milliseconds).
const ALIVE_EVERY: usize = 4096;
/// Blocks sent and acknowledged that are kept before they are dropped together (a
/// job shorter than this keeps every plan).
pub(super) const DROP_EVERY: usize = 1 << 14;

pub(super) struct Plans {
    la: Lookahead,
    /// Where the first block kept starts.
    base_start: [i64; AXES],
    /// One per block, as the passes leave them (those before the first kept are
    /// final, their time is in `ticks_before`).
    work: Trail<PlanBlock>,
    /// What is (or will be) streamed: `planned[i]` is fixed once block `i` was sent.
    pub(super) planned: Trail<PlannedBlock>,
    /// Planned ticks of the blocks dropped.
    ticks_before: f64,
}

impl Plans {
    pub(super) fn new(start: [i64; AXES], machine: &MachineConfig) -> Self {
        let smoothing = pkmc::motion::interp::window_of(machine.motion.smoothing_ticks as u32);
        Self {
            la: Lookahead::new(start, smoothing),
            base_start: start,
            work: Trail::default(),
            planned: Trail::default(),
            ticks_before: 0.0,
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
        let frozen = frozen.min(self.work.len()).max(self.work.base());
        let base = self.work.base();
        let work = self.work.kept_mut();
        replan_from(work, frozen - base, self.base_start, machine, kin, alive);
        for (k, p) in self.work.kept().iter().enumerate().skip(frozen - base) {
            self.planned[base + k].plan = p.plan();
        }
        Ok(())
    }

    /// Drops the plans before block `keep` (which must be sent, with the block
    /// before it) once [`DROP_EVERY`] of them are behind: their time is kept.
    pub(super) fn drop_before(&mut self, keep: usize) {
        let base = self.work.base();
        if keep < base + DROP_EVERY || keep >= self.work.len() {
            return;
        }
        let kept = self.work.kept();
        let k = keep - base;
        // The blocks before `keep`, each with its exit into the next.
        self.ticks_before += planned_ticks(&kept[..=k]) - planned_ticks(&kept[k..=k]);
        self.base_start = kept[k - 1].path.end;
        self.work.drop_before(keep);
        self.planned.drop_before(keep);
    }

    /// Block `i`'s path as the planner derived it, and where it starts (the block's
    /// geometry is derived once, here, and read by whoever needs it).
    pub(super) fn path(&self, i: usize) -> ([i64; AXES], &Path) {
        let from = match i.checked_sub(1) {
            Some(p) if i > self.work.base() => self.work[p].path.end,
            _ => self.base_start,
        };
        (from, &self.work[i].path)
    }

    /// Motion time of everything planned at 100 % feed, s.
    pub(super) fn time_s(&self) -> f64 {
        (self.ticks_before + planned_ticks(self.work.kept())) * pkmc::units::TICK_NS as f64 * 1e-9
    }
}
