//! The touch probe (G38.2–G38.5): a probing move watches one input, latches every
//! joint's actuator position at the instant the input changes as sought, and ends the
//! move once the change is confirmed.
//!
//! **Confirmation.** The input is debounced like the limit and home switches
//! ([`crate::drive::debounce::SWITCH`]: three equal samples, one per tick): a contact
//! shorter than that is a bounce and is not taken. The move starts its stop at the
//! confirming sample, two ticks after the first one read.
//!
//! **The instant.** The latch is not the confirming sample's position but the first
//! sample's, taken back to the edge: the board's timer captures when the input
//! changed within the last tick (`edge_us`, microseconds after that tick's start;
//! the simulator computes it), and the position is interpolated between the
//! actuators' positions at the start of that tick and of this one. An actuator's
//! position is what the hardware holds at a tick's start: a servo's encoder as read
//! at the tick edge, a stepper's steps emitted two ticks before (a tick's step train
//! runs during the tick after the one that computed it).
//! So the latch's time uncertainty is the capture's (1 µs on the board) plus the
//! straight-line interpolation over one tick; without a capture (`edge_us` unknown)
//! it is one tick (1 ms: 5 µm at 300 mm/min). A bounce before confirmation drops the
//! latch, and the next sought sample latches again.
//!
//! **Results.** A move that ends without the change (its end reached) reports no
//! contact with the actuators at the move's end. Each result is numbered
//! (`ProbeResult::count`), so that a host sees a new one.
//!
//! Invariants: pure logic, no time source: one call is one tick; positions are
//! actuator units (steps or counts from the joint's zero) × 2^[`LATCH_FRAC_BITS`].

use crate::config::MAX_JOINTS;
use serde::{Deserialize, Serialize};

/// Fraction bits of a latched actuator position.
pub const LATCH_FRAC_BITS: u32 = 8;
/// Microseconds per tick (the range of an edge time).
const TICK_US: u32 = 1_000_000 / crate::units::TICK_HZ;

/// What a probing move waits for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum ProbeMode {
    /// Contact made (G38.2, G38.3): the probe must be clear at the start.
    Touch,
    /// Contact lost (G38.4, G38.5): the probe must be touching at the start.
    Release,
}

impl ProbeMode {
    /// The input level the move seeks (true: touching).
    pub const fn sought(self) -> bool {
        matches!(self, ProbeMode::Touch)
    }
}

/// The result of a probing move (reported in every status after it).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct ProbeResult {
    /// Probing moves ended since power-up (wrapping): a new value is a new result.
    pub count: u16,
    /// The input changed as sought.
    pub contact: bool,
    /// Each joint's actuator at the change (or at the move's end without one): steps
    /// or encoder counts from the joint's zero, × 2^[`LATCH_FRAC_BITS`].
    pub at: [i64; MAX_JOINTS],
}

/// The latch of a probing move. See the module documentation.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ProbeLatch {
    /// The move under way, if any.
    mode: Option<ProbeMode>,
    /// Actuator positions at the start of the last tick.
    before: [i64; MAX_JOINTS],
    /// Armed and not yet ticked: `before` is taken at the first tick.
    fresh: bool,
    /// Latched at the first sought sample, not yet confirmed.
    pending: Option<[i64; MAX_JOINTS]>,
    result: Option<ProbeResult>,
}

impl ProbeLatch {
    /// Nothing armed, no result.
    pub const fn new() -> Self {
        Self {
            mode: None,
            before: [0; MAX_JOINTS],
            fresh: false,
            pending: None,
            result: None,
        }
    }

    /// A probing move in `mode` starts (the machine at rest: the first tick takes
    /// where the actuators stand).
    pub fn arm(&mut self, mode: ProbeMode) {
        self.mode = Some(mode);
        self.fresh = true;
        self.pending = None;
    }

    /// A probing move is under way.
    pub fn armed(&self) -> bool {
        self.mode.is_some()
    }

    /// The last result.
    pub fn result(&self) -> Option<ProbeResult> {
        self.result
    }

    /// One tick of an armed move: the actuators at this tick's start `now`, the input
    /// as sampled (`raw`), when it last changed within the last tick (`edge_us`), and
    /// debounced (`active`). True once the sought change is confirmed: the result is
    /// taken and the move must stop.
    pub fn tick(
        &mut self,
        now: &[i64; MAX_JOINTS],
        raw: bool,
        edge_us: Option<u16>,
        active: bool,
    ) -> bool {
        let Some(mode) = self.mode else {
            return false;
        };
        let sought = mode.sought();
        if self.fresh {
            self.before = *now;
            self.fresh = false;
        }
        if raw != sought {
            self.pending = None;
        } else if self.pending.is_none() {
            // The edge's share of the tick, Q16 (a 32-bit division: the M4 has it; a
            // 64-bit one would be a library routine in the tick).
            let f = edge_us.map_or(TICK_US, |e| (e as u32).min(TICK_US));
            let share = (((f << 16) + TICK_US / 2) / TICK_US) as i64;
            let before = &self.before;
            self.pending = Some(core::array::from_fn(|j| {
                before[j] + (((now[j] - before[j]) * share + (1 << 15)) >> 16)
            }));
        }
        self.before = *now;
        if active == sought {
            let at = self.pending.unwrap_or(*now);
            self.finish(true, &at);
            return true;
        }
        false
    }

    /// Ends the move: `contact`, with the actuators at `at`.
    pub fn finish(&mut self, contact: bool, at: &[i64; MAX_JOINTS]) {
        let count = self.result.map_or(0, |r| r.count).wrapping_add(1);
        self.result = Some(ProbeResult {
            count,
            contact,
            at: *at,
        });
        self.mode = None;
        self.pending = None;
    }

    /// Ends the move without a result (an alarm or an abort ended it).
    pub fn disarm(&mut self) {
        self.mode = None;
        self.pending = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pos(x: i64) -> [i64; MAX_JOINTS] {
        let mut p = [0; MAX_JOINTS];
        p[0] = x;
        p[1] = -x;
        p
    }

    #[test]
    fn the_latch_is_taken_back_to_the_edge_and_confirmed_at_the_third_sample() {
        let mut l = ProbeLatch::new();
        l.arm(ProbeMode::Touch);
        l.tick(&pos(0), false, None, false);
        assert!(!l.tick(&pos(1000), false, None, false));
        // The edge 250 µs into the tick from 1000 to 2000.
        assert!(!l.tick(&pos(2000), true, Some(250), false));
        assert!(!l.tick(&pos(3000), true, None, false));
        assert!(l.tick(&pos(4000), true, None, true));
        let r = l.result().unwrap();
        assert_eq!((r.count, r.contact, r.at), (1, true, pos(1250)));
        assert!(!l.armed());
    }

    #[test]
    fn a_bounce_drops_the_latch_and_the_next_contact_latches_again() {
        let mut l = ProbeLatch::new();
        l.arm(ProbeMode::Touch);
        l.tick(&pos(0), false, None, false);
        l.tick(&pos(100), true, Some(500), false);
        l.tick(&pos(200), false, Some(10), false);
        l.tick(&pos(300), true, Some(900), false);
        l.tick(&pos(400), true, None, false);
        assert!(l.tick(&pos(500), true, None, true));
        assert_eq!(l.result().unwrap().at, pos(290));
    }

    #[test]
    fn release_seeks_the_contact_lost_and_without_an_edge_time_latches_the_sample() {
        let mut l = ProbeLatch::new();
        l.arm(ProbeMode::Release);
        l.tick(&pos(0), true, None, true);
        assert!(!l.tick(&pos(10), true, None, true));
        l.tick(&pos(20), false, None, true);
        l.tick(&pos(30), false, None, true);
        assert!(l.tick(&pos(40), false, None, false));
        assert_eq!(l.result().unwrap().at, pos(20));
    }

    #[test]
    fn results_are_numbered_and_a_disarmed_move_leaves_none() {
        let mut l = ProbeLatch::new();
        l.arm(ProbeMode::Touch);
        l.tick(&pos(0), false, None, false);
        l.finish(false, &pos(7));
        l.arm(ProbeMode::Touch);
        l.disarm();
        assert!(!l.armed());
        let r = l.result().unwrap();
        assert_eq!((r.count, r.contact, r.at), (1, false, pos(7)));
        assert!(!l.tick(&pos(9), true, None, true), "not armed");
    }
}
