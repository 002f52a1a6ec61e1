//! What the client counts: frames, resends, `Nak`s by reason, the round trip, the
//! motion the controller held; the job report carries them (`link`).

use serde::Serialize;

/// Negative acknowledgements received, by reason.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct NakCounts {
    /// Damaged frame.
    pub corrupt: u64,
    /// A frame went missing.
    pub gap: u64,
    /// Queue full.
    pub queue_full: u64,
    /// Version, no session, bad block or a reason this client does not know.
    pub other: u64,
}

/// Link statistics seen by the client.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct ClientStats {
    /// Frames sent (including resends, control commands and status requests).
    pub frames_sent: u64,
    /// Bytes sent.
    pub bytes_sent: u64,
    /// Blocks sent for the first time.
    pub blocks_sent: u64,
    /// Blocks sent again after a `Nak` or a timeout.
    pub resent: u64,
    /// Rewinds of the block stream (go-back-N).
    pub rewinds: u64,
    /// Rewinds because nothing was acknowledged in time.
    pub timeouts: u64,
    /// `Nak`s received (all reasons).
    pub naks: u64,
    /// `Nak`s by reason.
    pub nak_reasons: NakCounts,
    /// `Nak`s ignored because a rewind already covered them.
    pub naks_ignored: u64,
    /// Control commands sent (first time).
    pub controls: u64,
    /// Control commands sent again, unacknowledged.
    pub controls_resent: u64,
    /// Status requests sent.
    pub status_requests: u64,
    /// Frames received that decoded.
    pub frames_received: u64,
    /// Received frames that failed to decode (damaged on the way).
    pub corrupt_received: u64,
    /// Gaps in the client's own loop longer than [`super::OWN_GAP`] (the process was
    /// stopped or starved of CPU): each restarted the silence timers.
    pub own_gaps: u64,
    /// The longest of them, s.
    pub own_gap_max_s: f64,
    /// Times the port went away mid-job (a cable pulled) and this host reconnected and
    /// took its job over (`job::replug`); the other counts are the whole job's.
    pub reconnects: u64,
    /// Times the controller held this job because this host had been silent longer
    /// than the job's host timeout, and this host, back, resumed it.
    pub host_timeout_resumes: u64,
    /// Motion time of the last job as planned on the host with unlimited look-ahead,
    /// s: what an ideal controller under the same limits takes (jerk smoothing not
    /// counted).
    pub plan_time_s: f64,
    /// Motion the controller held while the last job streamed (see [`Buffered`]).
    pub buffered: Buffered,
    /// The last job's smoothed round trip of a block (written to its `Ack`), ms; 0:
    /// not measured.
    pub rtt_ms: f64,
    /// The retransmission timeout it gave at the job's end, ms.
    pub rto_ms: f64,
    /// Extra copies of block frames sent on a damaged line.
    pub copies: u64,
    /// The largest share of frames to the controller estimated damaged (0 to 1).
    pub frame_damage_max: f64,
    /// Times the operator was told the line is bad.
    pub line_warnings: u64,
}

/// The motion a controller held (its status's `buffered_ms`) while the host still
/// had blocks of the job to send and the machine ran, from [`Buffered::SETTLE_MS`] of
/// motion on (the start fills the queue first): what the stream kept in hand in the
/// steady part of a job. Zero samples for a job too short to have one.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct Buffered {
    /// Status reports counted.
    pub samples: u64,
    /// Least buffered, ms.
    pub min_ms: u32,
    /// Tenth percentile, ms.
    pub p10_ms: u32,
    /// Median, ms.
    pub median_ms: u32,
}

impl Buffered {
    /// Motion after which the queue counts as filled, ms.
    pub const SETTLE_MS: u64 = 500;

    /// The figures of `samples` (ms).
    pub fn of(samples: &mut [u32]) -> Self {
        samples.sort_unstable();
        let at = |q: f64| samples[((samples.len() - 1) as f64 * q) as usize];
        if samples.is_empty() {
            return Self::default();
        }
        Self {
            samples: samples.len() as u64,
            min_ms: samples[0],
            p10_ms: at(0.1),
            median_ms: at(0.5),
        }
    }
}
