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
use pkmc::motion::block::{Block, Motion, PlannedBlock};
use pkmc::motion::geometry::Path;
use pkmc::motion::planner::{planned_ticks, replan_from, Lookahead, PlanBlock};

/// Blocks sent and acknowledged that are kept before they are dropped together (a
/// job shorter than this keeps every plan).
pub(super) const DROP_EVERY: usize = 1 << 14;

/// Paths derived already for a job's blocks (by the compile, for its pre-flight):
/// `paths[i]` is block `i`'s path from the end of block `i - 1`, the first's from
/// `start`. The link plans on them instead of deriving them again, for every block that
/// starts where the compile had it start (the first may not: the controller reports
/// where the job starts).
#[derive(Clone, Copy, Debug)]
pub struct Derived<'a> {
    /// Where the first block starts.
    pub start: [i64; AXES],
    /// One path per block.
    pub paths: &'a [Path],
}

impl Derived<'_> {
    /// Block `k`'s path, if it starts at `from` and ends where `block` does (so a
    /// path of another block is never taken for it).
    fn path_from(&self, k: usize, block: &Block, from: &[i64; AXES]) -> Option<Path> {
        let path = self.paths.get(k)?;
        let start = match k.checked_sub(1) {
            Some(j) => &self.paths[j].end,
            None => &self.start,
        };
        let end = match block.motion {
            Motion::Dwell(_) | Motion::Aux(_) => from,
            _ => &block.target,
        };
        (start == from && &path.end == end).then_some(*path)
    }
}

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

    /// Plans `blocks` after those already planned (on their paths in `derived` where
    /// those apply), then plans again every block from `frozen` (the first never sent)
    /// on, with the core's pass sequence ([`replan_from`]). Fails with the index of a
    /// block whose geometry is malformed. `alive` is called before each block is
    /// planned and between the passes (it keeps its own pace).
    pub(super) fn extend(
        &mut self,
        blocks: &[Block],
        derived: Option<Derived<'_>>,
        frozen: usize,
        machine: &MachineConfig,
        kin: &MachineKinematics,
        alive: &mut dyn FnMut(),
    ) -> Result<(), usize> {
        for (k, b) in blocks.iter().enumerate() {
            alive();
            let i = self.work.len();
            // The block before, unless it is sent (its acceleration is final).
            let prev = match i.checked_sub(1) {
                Some(p) if p >= frozen => self.work.get_mut(p),
                _ => None,
            };
            let p = match derived.and_then(|d| d.path_from(k, b, &self.la.end)) {
                Some(path) => self.la.plan_path(b, path, prev, machine, kin),
                None => self.la.plan(b, prev, machine, kin).map_err(|_| i)?,
            };
            self.work.push(p);
            self.planned.push(PlannedBlock {
                block: *b,
                plan: p.plan(),
            });
        }
        let frozen = frozen.min(self.work.len()).max(self.work.base());
        let base = self.work.base();
        let work = self.work.kept_mut();
        replan_from(
            work,
            frozen - base,
            self.base_start,
            self.la.smoothing,
            machine,
            kin,
            alive,
        );
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gcode;

    /// A program on the H-4 with a run of short moves (merged into curves), an arc and
    /// corners, from the machine's home.
    fn compiled() -> (MachineConfig, crate::job::Compiled) {
        let machine = MachineConfig::h4_table();
        let mut text = String::from("G64 P0.01\nG91 G1 F1500\n");
        for i in 1..=80 {
            let dy = 2.0 * ((i as f64 * 0.1).sin() - ((i - 1) as f64 * 0.1).sin());
            text.push_str(&format!("X0.25 Y{dy:.4}\n"));
        }
        text.push_str("G2 X10 Y0 I5 J0\nG1 Y-5\nX-5 Z-2\nG0 Z2\nM2\n");
        let tools = gcode::ToolTable::new();
        let settings = gcode::compress::Settings::default();
        let compress = Some(&settings);
        let (c, pre) =
            crate::job::compile_located(&text, "p", &machine, machine.home, &tools, compress)
                .unwrap();
        assert!(pre.findings.is_empty(), "{:?}", pre.findings);
        (machine, c)
    }

    fn planned(
        machine: &MachineConfig,
        start: [i64; AXES],
        blocks: &[Block],
        derived: Option<Derived<'_>>,
    ) -> Vec<PlannedBlock> {
        let kin = MachineKinematics::new(machine);
        let mut plans = Plans::new(start, machine);
        plans
            .extend(blocks, derived, 0, machine, &kin, &mut || {})
            .unwrap();
        plans.planned.kept().to_vec()
    }

    #[test]
    fn the_compiles_paths_plan_as_paths_derived_again_would() {
        let (machine, c) = compiled();
        assert_eq!(c.paths.len(), c.blocks.len());
        assert!(c.curves() > 0 && c.blocks.iter().any(|b| b.motion.curved()));
        let again = planned(&machine, c.start, &c.blocks, None);
        assert_eq!(planned(&machine, c.start, &c.blocks, c.derived()), again);
    }

    #[test]
    fn the_link_plans_on_the_paths_it_is_given_and_derives_the_first_where_the_job_starts_elsewhere(
    ) {
        let (machine, c) = compiled();
        let again = planned(&machine, c.start, &c.blocks, None);
        // A path marked (one block's length doubled) shows which paths the link took.
        let k = c
            .blocks
            .iter()
            .rposition(|b| b.motion == pkmc::motion::block::Motion::Linear);
        let k = k.unwrap();
        let mut marked = c.paths.clone();
        marked[k].course.length *= 2;
        let on_marked = planned(
            &machine,
            c.start,
            &c.blocks,
            Some(Derived {
                start: c.start,
                paths: &marked,
            }),
        );
        assert_ne!(
            on_marked[k].plan, again[k].plan,
            "the given path was not taken"
        );
        // A job that starts elsewhere: the first block's path is derived again from
        // there (a marked first path is not taken), the rest are the compile's.
        let mut elsewhere = c.start;
        elsewhere[0] += 1_000;
        let mut marked = c.paths.clone();
        marked[0].course.length *= 2;
        marked[k].course.length *= 2;
        let given = Derived {
            start: c.start,
            paths: &marked,
        };
        let moved = planned(&machine, elsewhere, &c.blocks, Some(given));
        let moved_again = planned(&machine, elsewhere, &c.blocks, None);
        assert_eq!(moved[0], moved_again[0]);
        assert_ne!(moved[k].plan, moved_again[k].plan);
        // Paths of other blocks (shifted by one) are never taken.
        let shifted = Derived {
            start: c.start,
            paths: &c.paths[1..],
        };
        assert_eq!(planned(&machine, c.start, &c.blocks, Some(shifted)), again);
    }
}
