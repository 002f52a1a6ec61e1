//! The stall guard: against a simulator on this host, a controller that says it is
//! moving but makes no progress for [`super::STALL_TICKS`] of simulated time (plus the
//! dwell it executes) is stalled (see the module documentation of [`crate::link`]).

use pkmc::config::{AXES, MAX_JOINTS};
use pkmc::motion::block::{Block, Motion};
use pkmc::wire::{State, Status};

/// What a status shows of a controller's progress.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Mark {
    state: State,
    blocks_done: u32,
    pose: [i64; AXES],
    joints: [i64; MAX_JOINTS],
}

/// The stall guard's memory: the last progress seen and when, in simulated ticks.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct StallGuard {
    mark: Option<Mark>,
    since: u64,
}

impl StallGuard {
    /// Takes status `s`, seen at simulated tick `now`; returns the ticks the controller
    /// has been moving without progress.
    pub(super) fn observe(&mut self, s: &Status, now: u64) -> u64 {
        let mark = Mark {
            state: s.state,
            blocks_done: s.blocks_done,
            pose: s.pose,
            joints: s.joints,
        };
        // Idle, starved (its queue run out, stopped on the path) or in alarm: waiting
        // for the host (a simulator runs free meanwhile, so a host resending after a
        // damaged frame is seconds late in simulated time). Held: braking (the pose
        // changes) or waiting for the operator (a pause, a tool change, a feed hold).
        // The reported speed is no sign of progress: it is not zeroed during a dwell.
        let at_rest = matches!(
            s.state,
            State::Idle | State::Starved | State::Alarm | State::EStop | State::Hold
        );
        if at_rest || self.mark != Some(mark) {
            self.mark = Some(mark);
            self.since = now;
        }
        now.saturating_sub(self.since)
    }
}

/// Ticks of the dwell a job is executing when status `s` arrives (0 if none): the
/// stall guard adds them to [`super::STALL_TICKS`].
pub(super) fn dwell_ticks(
    blocks: &super::trail::Trail<Block>,
    done_before: u32,
    s: &Status,
) -> u64 {
    let executing = s.blocks_done.wrapping_sub(done_before) as usize;
    match blocks.get(executing).map(|b| b.motion) {
        Some(Motion::Dwell(ms)) => ms as u64 * pkmc::units::TICK_HZ as u64 / 1000,
        _ => 0,
    }
}
