//! The measured round trip of a block: from writing its frame to the `Ack` that
//! accepts it, smoothed as TCP smooths it (RFC 6298: `srtt`, `rttvar`, Karn's rule:
//! only blocks sent once are measured). The retransmission timeout and the time in
//! which a rewind's stale `Nak`s can still arrive are based on it, so that a lost
//! block on a fast link costs a few milliseconds, not a fixed 200.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// Shortest retransmission timeout: above a board's USB polling and a loaded PC's
/// scheduling delay, so that a late acknowledgement is rarely taken for a loss (a
/// spurious resend costs only bytes: the controller acknowledges duplicates).
pub const MIN_RTO: Duration = Duration::from_millis(10);

/// The round-trip estimate and the blocks in flight it is measured on.
#[derive(Debug)]
pub(super) struct Rtt {
    /// Smoothed round trip, s (none before the first sample).
    srtt: Option<f64>,
    /// Its mean deviation, s.
    rttvar: f64,
    /// Blocks in flight in the order sent: index, when written, sent for the first
    /// time (only those are measured).
    flights: VecDeque<(usize, Instant, bool)>,
    /// Samples taken.
    pub(super) samples: u64,
}

impl Default for Rtt {
    fn default() -> Self {
        Self {
            srtt: None,
            rttvar: 0.0,
            flights: VecDeque::new(),
            samples: 0,
        }
    }
}

impl Rtt {
    /// Block `index` was written at `at`; `first`: never sent before.
    pub(super) fn sent(&mut self, index: usize, at: Instant, first: bool) {
        self.flights.push_back((index, at, first));
    }

    /// The stream went back to `index`: what was in flight from there on will be sent
    /// again (and is not measured).
    pub(super) fn rewound(&mut self, index: usize) {
        while self.flights.back().is_some_and(|f| f.0 >= index) {
            self.flights.pop_back();
        }
    }

    /// Blocks before `acked` are accepted; `answer`: by an `Ack` arriving now (a
    /// measurement when its last block was sent once), else by a status or a `Nak`.
    pub(super) fn acked(&mut self, acked: usize, answer: bool) {
        let mut last = None;
        while self.flights.front().is_some_and(|f| f.0 < acked) {
            last = self.flights.pop_front();
        }
        if let Some((i, at, true)) = last.filter(|_| answer) {
            if i + 1 == acked {
                self.sample(at.elapsed().as_secs_f64());
            }
        }
    }

    fn sample(&mut self, r: f64) {
        self.samples += 1;
        match self.srtt {
            None => {
                self.srtt = Some(r);
                self.rttvar = r / 2.0;
            }
            Some(s) => {
                self.rttvar = 0.75 * self.rttvar + 0.25 * (s - r).abs();
                self.srtt = Some(0.875 * s + 0.125 * r);
            }
        }
    }

    /// Smoothed round trip (none measured yet).
    pub(super) fn srtt(&self) -> Option<Duration> {
        self.srtt.map(Duration::from_secs_f64)
    }

    /// The retransmission timeout: `srtt + 4 rttvar`, at least [`MIN_RTO`], at most
    /// `max` (also what it is before the first measurement).
    pub(super) fn rto(&self, max: Duration) -> Duration {
        match self.srtt {
            None => max,
            Some(s) => Duration::from_secs_f64(s + 4.0 * self.rttvar).clamp(MIN_RTO.min(max), max),
        }
    }

    /// How long after a rewind a `Nak` for the block it went back to can still be an
    /// answer to a frame sent before the rewind: a round trip and its deviation twice
    /// (before the first measurement, `max`).
    pub(super) fn stale_window(&self, max: Duration) -> Duration {
        match self.srtt {
            None => max,
            Some(s) => Duration::from_secs_f64(s + 2.0 * self.rttvar).min(max),
        }
    }
}

/// Most copies of a block frame sent back to back on a damaged line.
pub const MAX_COPIES: usize = 4;
/// The share of block frames lost (every copy damaged) that copies aim at.
const COPIES_AIM: f64 = 0.01;
/// Below this share of frames damaged, each block is sent once.
const COPIES_FROM: f64 = 0.04;
/// Weight of one frame in the damage estimate that sets the copies (about the last
/// 128 frames count: it follows a line that gets worse within a few dozen blocks).
const DAMAGE_WEIGHT: f64 = 1.0 / 128.0;
/// ... and in the steadier one the operator is told (about the last 1024 frames).
const STEADY_WEIGHT: f64 = 1.0 / 1024.0;

/// The share of the frames written to the controller that arrive damaged, estimated
/// from its `Nak(Corrupt)` answers (each damaged frame draws one; a `Nak` lost on the
/// way back makes it an underestimate) as a moving average over the frames sent.
#[derive(Debug, Default)]
pub(super) struct Damage {
    rate: f64,
    steady: f64,
    /// Frames counted (the estimate means little before some hundred).
    pub(super) frames: u64,
}

impl Damage {
    /// A frame was written.
    pub(super) fn sent(&mut self) {
        self.frames += 1;
        self.rate *= 1.0 - DAMAGE_WEIGHT;
        self.steady *= 1.0 - STEADY_WEIGHT;
    }

    /// A `Nak(Corrupt)` came: a frame arrived damaged.
    pub(super) fn damaged(&mut self) {
        self.rate = (self.rate + DAMAGE_WEIGHT).min(1.0);
        self.steady = (self.steady + STEADY_WEIGHT).min(1.0);
    }

    /// The estimated share of frames damaged, over the last thousand or so (the
    /// average's start from zero corrected for).
    pub(super) fn rate(&self) -> f64 {
        let weight = 1.0 - (1.0 - STEADY_WEIGHT).powf(self.frames as f64);
        if weight > 0.0 {
            (self.steady / weight).min(1.0)
        } else {
            0.0
        }
    }

    /// Copies of each block frame to send back to back: one on a sound line; on a
    /// damaged one as many as make losing all of them rare ([`COPIES_AIM`]), at most
    /// [`MAX_COPIES`]. The controller accepts the first copy that arrives whole and
    /// acknowledges the others without decoding them: a copy is cheap, a lost block
    /// costs a round trip and every block sent behind it (go-back-N).
    pub(super) fn copies(&self) -> usize {
        if self.rate < COPIES_FROM {
            return 1;
        }
        let mut k = 1;
        while k < MAX_COPIES && self.rate.powi(k as i32) > COPIES_AIM {
            k += 1;
        }
        k
    }

    /// The byte fault rate that damages a share `rate` of frames of `len` bytes.
    pub(super) fn byte_rate(rate: f64, len: f64) -> f64 {
        1.0 - (1.0 - rate.min(0.999)).powf(1.0 / len.max(1.0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn copies_follow_the_damage() {
        let mut d = Damage::default();
        for _ in 0..1000 {
            d.sent();
        }
        assert_eq!(d.copies(), 1);
        // Every other frame damaged: four copies (0.5^4 = 6 %, the most allowed).
        for i in 0..8000 {
            d.sent();
            if i % 2 == 0 {
                d.damaged();
            }
        }
        assert!((d.rate() - 0.5).abs() < 0.05, "{}", d.rate());
        assert_eq!(d.copies(), MAX_COPIES);
        // One in fifteen: two copies.
        for i in 0..12000 {
            d.sent();
            if i % 15 == 0 {
                d.damaged();
            }
        }
        assert_eq!(d.copies(), 2, "{}", d.rate());
        let b = Damage::byte_rate(0.49, 67.0);
        assert!((b - 0.01).abs() < 0.001, "{b}");
    }

    #[test]
    fn only_blocks_sent_once_are_measured_and_the_timeout_follows_them() {
        let mut rtt = Rtt::default();
        let max = Duration::from_millis(200);
        assert_eq!(rtt.rto(max), max, "nothing measured yet");
        let t = Instant::now() - Duration::from_millis(2);
        rtt.sent(0, t, true);
        rtt.sent(1, t, true);
        rtt.acked(2, true);
        assert_eq!(rtt.samples, 1);
        let s = rtt.srtt().unwrap();
        assert!(s >= Duration::from_millis(2) && s < Duration::from_millis(100));
        assert!(rtt.rto(max) >= MIN_RTO && rtt.rto(max) < max);
        // A resent block is not measured (Karn), nor one accepted by a status.
        rtt.sent(2, t, false);
        rtt.acked(3, true);
        rtt.sent(3, t, true);
        rtt.acked(4, false);
        assert_eq!(rtt.samples, 1);
        // A rewind forgets what will be sent again.
        rtt.sent(4, t, true);
        rtt.sent(5, t, true);
        rtt.rewound(5);
        rtt.sent(5, t, false);
        rtt.acked(6, true);
        assert_eq!(rtt.samples, 1);
    }
}
