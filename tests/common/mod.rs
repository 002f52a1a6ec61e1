//! Shared by the core's integration tests: what the host does before streaming.

use pkmc::config::{MachineConfig, AXES};
use pkmc::kinematics::MachineKinematics;
use pkmc::motion::block::{Block, PlannedBlock};
use pkmc::motion::planner::{plan_into, PlanBlock};

/// Plans `blocks` from `start` as the host does (unlimited look-ahead, the controller's
/// smoothing window `window` in ticks), ready to stream.
pub fn planned(
    machine: &MachineConfig,
    start: [i64; AXES],
    window: u32,
    blocks: &[Block],
) -> Vec<PlannedBlock> {
    let kin = MachineKinematics::new(machine);
    let mut out = vec![PlanBlock::default(); blocks.len()];
    plan_into(
        blocks,
        start,
        machine,
        &kin,
        pkmc::motion::interp::window_of(window),
        &mut out,
    )
    .expect("well-formed blocks");
    blocks
        .iter()
        .zip(&out)
        .map(|(b, p)| PlannedBlock {
            block: *b,
            plan: p.plan(),
        })
        .collect()
}
