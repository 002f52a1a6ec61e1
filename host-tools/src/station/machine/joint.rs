//! A joint move (the thesis' Arm1…): one joint alone, the others standing.

use crate::job::{self, Failure};
use pkmc::config::MachineConfig;
use pkmc::kinematics::{Kinematics, MachineKinematics};
use pkmc::motion::block::{Block, Motion};
use pkmc::units::{to_user, units_per_user};
use pkmc::wire::Status;

/// Moves joint `joint` by `distance` (mm or degrees) alone: the straight line in
/// joint space, cut into pieces of at most half a unit each turned into a pose by the
/// forward kinematics, so the other joints stay where they are at every piece's end.
pub(super) fn joint_move(
    machine: &MachineConfig,
    s: &Status,
    joint: usize,
    distance: f64,
    feed: f64,
) -> Result<Vec<Block>, Failure> {
    let bad = |m: String| Failure::new(job::exit::BAD_INPUT, m);
    let jc = machine.joints.get(joint).ok_or_else(|| {
        bad(format!(
            "joint {}: the machine has no such joint",
            joint + 1
        ))
    })?;
    if !distance.is_finite() || !feed.is_finite() || feed <= 0.0 {
        return Err(bad(format!(
            "joint move: distance {distance}, feed {feed}: need numbers, feed positive"
        )));
    }
    let scale = units_per_user(jc.rotary) as f64;
    let from = s.joints[joint];
    let to = (from + (distance * scale).round() as i64).clamp(jc.min, jc.max);
    if to == from {
        return Err(bad(format!(
            "joint {}: at the end of its travel; nothing to move",
            joint + 1
        )));
    }
    let pieces = ((to - from).unsigned_abs() as f64 / (scale * 0.5)).ceil() as i64;
    let pieces = pieces.clamp(1, 400);
    let kin = MachineKinematics::new(machine);
    let mut pose = s.pose;
    let mut blocks = Vec::new();
    for k in 1..=pieces {
        let mut q = s.joints;
        q[joint] = from + (to - from) * k / pieces;
        let mut next = pose;
        kin.forward(&q, &pose, &mut next).map_err(|e| {
            bad(format!(
                "joint {}: no pose reaches {:.3} ({e:?})",
                joint + 1,
                to_user(q[joint], jc.rotary)
            ))
        })?;
        pose = next;
        blocks.push(Block {
            line: 0,
            motion: Motion::Linear,
            target: pose,
            feed: (feed / 60.0 * 1e6).round() as i64,
            tolerance_nm: 0,
        });
    }
    Ok(blocks)
}
