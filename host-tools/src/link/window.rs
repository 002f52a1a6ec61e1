//! The window of a job's blocks in flight: sequence numbers to block indices across
//! the `u16` wrap, credits (free slots, free bends, motion buffered), the congestion
//! window (halved on a rewind, grown by acknowledgements) and the go-back-N guard.

use super::rtt::{Damage, Rtt};
use super::stall::StallGuard;
use super::trail::Trail;
use super::{ClientStats, MIN_WINDOW};
use pkmc::wire::{Control, Status};
use std::time::Instant;

#[derive(Clone, Copy, Debug)]
pub(super) struct Guard {
    /// Index the stream was rewound to.
    pub(super) at: usize,
    /// `Nak`s for the same index still expected from frames sent before the rewind.
    pub(super) stale_left: usize,
    /// When the stream went back: after a round trip ([`Rtt::stale_window`]) a `Nak`
    /// for the same index answers a frame sent since, and is acted on.
    pub(super) since: Instant,
}

#[derive(Clone, Copy, Debug)]
pub(super) struct Ending {
    pub(super) cmd: Control,
    pub(super) id: u16,
    pub(super) acked: bool,
}

/// Book-keeping of one streamed job: indices into the job's blocks.
pub(super) struct JobState {
    pub(super) base_seq: u16,
    /// `buffered_ms` of the statuses of the steady part ([`super::Buffered`]).
    pub(super) buffered_samples: Vec<u32>,
    /// Blocks accepted (cumulatively acknowledged).
    pub(super) acked: usize,
    /// Next block to send.
    pub(super) sent: usize,
    /// One past the highest block ever sent.
    pub(super) high: usize,
    pub(super) free: usize,
    /// `Control::EndJob` has been queued.
    pub(super) end_sent: bool,
    /// Free bends (arcs the controller can take) after the last acknowledged block.
    pub(super) free_bends: usize,
    /// `arcs_before[i]`: arcs among the blocks before `i`.
    pub(super) arcs_before: Trail<usize>,
    pub(super) buffered_ms: u32,
    pub(super) window: usize,
    pub(super) capacity: usize,
    pub(super) guard: Option<Guard>,
    pub(super) last_progress: Instant,
    pub(super) done_before: u32,
    pub(super) ending: Option<Ending>,
    pub(super) planned_ms: Trail<f64>,
    pub(super) stall: StallGuard,
    /// The measured round trip (retransmission timeout, stale `Nak`s).
    pub(super) rtt: Rtt,
    /// The share of frames the line damages, and the copies of each block sent.
    pub(super) damage: Damage,
    pub(super) copies: usize,
    /// The damage the operator was last told of (0: not told).
    pub(super) warned_at: f64,
}

impl JobState {
    pub(super) fn new(base_seq: u16, capacity: u16, status: &Status) -> Self {
        Self {
            base_seq,
            acked: 0,
            sent: 0,
            high: 0,
            free: status.free_slots as usize,
            end_sent: false,
            free_bends: status.free_bends as usize,
            arcs_before: Trail::default(),
            buffered_samples: Vec::new(),
            buffered_ms: status.buffered_ms,
            window: (capacity as usize).max(MIN_WINDOW),
            capacity: (capacity as usize).max(MIN_WINDOW),
            guard: None,
            last_progress: Instant::now(),
            done_before: status.blocks_done,
            ending: None,
            planned_ms: Trail::default(),
            stall: StallGuard::default(),
            rtt: Rtt::default(),
            damage: Damage::default(),
            copies: 1,
            warned_at: 0.0,
        }
    }

    /// May block `i` be sent as far as bends go? Lines always; an arc while the arcs
    /// in flight before it leave the controller a free bend.
    pub(super) fn bend_free_for(&self, i: usize) -> bool {
        match (self.arcs_before.get(i), self.arcs_before.get(i + 1)) {
            (Some(a), Some(b)) if b > a => {
                a - self.arcs_before.get(self.acked).copied().unwrap_or(0) < self.free_bends
            }
            _ => true,
        }
    }

    /// Estimated motion of the blocks in flight, ms.
    pub(super) fn in_flight_ms(&self) -> f64 {
        match (
            self.planned_ms.get(self.sent),
            self.planned_ms.get(self.acked),
        ) {
            (Some(s), Some(a)) => s - a,
            _ => 0.0,
        }
    }

    pub(super) fn seq_of(&self, index: usize) -> u16 {
        self.base_seq.wrapping_add(index as u16)
    }

    /// Index of the block with sequence number `seq`, if it is within what was sent
    /// (or one past it).
    pub(super) fn index_at(&self, seq: u16) -> Option<usize> {
        let d = seq.wrapping_sub(self.seq_of(self.acked)) as i16 as i64;
        let i = self.acked as i64 + d;
        (i >= 0 && i as usize <= self.high).then_some(i as usize)
    }

    /// Number of blocks accepted if block `seq` is the last one accepted.
    pub(super) fn index_after(&self, seq: u16) -> Option<usize> {
        let d = seq.wrapping_sub(self.seq_of(self.acked)) as i16 as i64;
        let n = self.acked as i64 + d + 1;
        (n >= 0 && n as usize <= self.high).then_some(n as usize)
    }

    pub(super) fn advance(&mut self, acked: usize) {
        let k = acked - self.acked;
        self.acked = acked;
        self.sent = self.sent.max(acked);
        self.rtt.acked(acked, false);
        self.window = (self.window + k.min(4)).min(self.capacity);
        self.last_progress = Instant::now();
        if self.guard.is_some_and(|g| g.at < acked) {
            self.guard = None;
        }
    }

    pub(super) fn rewind_to(&mut self, at: usize, stats: &mut ClientStats) {
        // Never behind what the controller accepted (a `Nak` of another session's
        // numbering, after a foreign `Hello`, may name an earlier block).
        let at = at.max(self.acked);
        if at >= self.sent {
            return;
        }
        stats.rewinds += 1;
        self.sent = at;
        self.rtt.rewound(at);
        self.window = (self.window / 2).max(MIN_WINDOW);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use pkmc::wire::State;

    fn status() -> Status {
        Status {
            state: State::Idle,
            line: 0,
            blocks_done: 0,
            motion_ticks: 0,
            pose: [0; 6],
            joints: [0; pkmc::config::MAX_JOINTS],
            measured: [0; pkmc::config::MAX_JOINTS],
            speed: 0,
            buffered_ms: 0,
            free_slots: 64,
            free_bends: 64,
            feed_override: 100,
            alarm: None,
            homed: false,
            orphan: false,
            probe_input: false,
            probes: 0,
        }
    }

    #[test]
    fn sequence_numbers_map_to_block_indices_across_the_wrap() {
        let mut job = JobState::new(u16::MAX - 2, 64, &status());
        job.high = 8;
        job.advance(5);
        assert_eq!(job.seq_of(5), 2);
        assert_eq!(job.index_at(2), Some(5));
        assert_eq!(job.index_after(2), Some(6));
        assert_eq!(job.index_after(u16::MAX), Some(3));
        assert_eq!(job.index_at(9), None, "beyond what was sent");
    }

    #[test]
    fn a_rewind_halves_the_window_and_acknowledgements_grow_it_back() {
        let mut job = JobState::new(1, 64, &status());
        let mut stats = ClientStats::default();
        job.sent = 40;
        job.high = 40;
        job.rewind_to(10, &mut stats);
        assert_eq!((job.sent, job.window, stats.rewinds), (10, 32, 1));
        job.advance(2);
        assert_eq!(job.window, 34, "grown by the blocks acknowledged");
        job.advance(12);
        assert_eq!(job.window, 38, "by at most four per acknowledgement");
    }
}
