//! A faulty serial line for the simulator: corrupts, drops and duplicates bytes at a
//! given rate, in both directions, and checks that no damaged frame got through.
//!
//! [`FaultyLine`] sits in the simulator's server thread between the pseudo-terminal
//! and the controller ([`crate::sim::serve::serve`]). Each byte entering either direction is
//! hit with probability `rate`; a hit is one of three faults, chosen with equal odds:
//! the byte is replaced by another value (XOR with a random non-zero byte), dropped,
//! or sent twice. The random number generator is seeded, so a run is repeatable for a
//! given seed and byte stream.
//!
//! Invariant checked here: every frame the receiver accepts (that passes COBS, CRC-32
//! and message decoding, exactly as `pkmc::wire::decode_frame` does on both ends)
//! is byte-identical to a frame the sender put on the line. The layer splits the clean
//! input into frames (what was sent) and decodes the faulty output with the same
//! decoder as the receiver (what is accepted); an accepted frame that was never sent
//! is counted as `undetected`, which must stay 0.

use pkmc::wire::{decode_frame, CtrlMsg, FrameReader, HostMsg, Pushed, MAX_BODY};
use serde::Serialize;
use std::collections::HashSet;

/// Parses a per-byte fault rate (`--link-faults RATE`): a number from 0 to 1.
pub fn parse_rate(s: &str) -> Result<f64, String> {
    let r: f64 = s.parse().map_err(|e| format!("{s}: {e}"))?;
    if (0.0..=1.0).contains(&r) {
        Ok(r)
    } else {
        Err(format!("{s}: a rate is between 0 and 1"))
    }
}

/// What to inject.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FaultConfig {
    /// Probability that a byte is hit, 0..=1 (per byte, each direction).
    pub rate: f64,
    /// Seed of the random number generator.
    pub seed: u64,
    /// After this many bytes towards the host the line goes dead in both directions
    /// (a pulled cable), for link-loss tests; `None` never.
    pub cut_after_bytes: Option<u64>,
}

impl FaultConfig {
    /// Faults at `rate` with `seed`, the line never cut.
    pub fn new(rate: f64, seed: u64) -> Self {
        Self {
            rate,
            seed,
            cut_after_bytes: None,
        }
    }
}

/// SplitMix64: small, fast and good enough to choose faults.
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    /// A generator from `seed`.
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }
}

/// Counters of one direction of the line.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct DirectionCounts {
    /// Bytes that entered the line.
    pub bytes: u64,
    /// Bytes replaced by another value.
    pub corrupted: u64,
    /// Bytes dropped.
    pub dropped: u64,
    /// Bytes sent twice.
    pub duplicated: u64,
    /// Frames that entered the line.
    pub frames_sent: u64,
    /// Frames sent with at least one byte hit.
    pub frames_damaged: u64,
    /// Frames the receiver accepted (they decode).
    pub frames_accepted: u64,
    /// Frames the receiver refused (bad COBS, CRC or message, or overlong).
    pub frames_refused: u64,
    /// Accepted frames that are not byte-identical to any frame sent: damage that got
    /// through. Must be 0.
    pub undetected: u64,
}

/// One direction of the line.
pub struct FaultyDirection {
    rate: f64,
    rng: Rng,
    decodes: fn(&[u8]) -> bool,
    clean: FrameReader,
    hit_in_frame: bool,
    sent: HashSet<Vec<u8>>,
    delivered: FrameReader,
    /// Counters so far.
    pub counts: DirectionCounts,
}

impl FaultyDirection {
    fn new(rate: f64, seed: u64, decodes: fn(&[u8]) -> bool) -> Self {
        Self {
            rate,
            rng: Rng::new(seed),
            decodes,
            clean: FrameReader::new(),
            hit_in_frame: false,
            sent: HashSet::new(),
            delivered: FrameReader::new(),
            counts: DirectionCounts::default(),
        }
    }

    /// Passes `input` through the line, appending what comes out to `out`.
    pub fn pass(&mut self, input: &[u8], out: &mut Vec<u8>) {
        let start = out.len();
        for &b in input {
            self.counts.bytes += 1;
            if let Pushed::Frame(f) = self.clean.push(b) {
                self.counts.frames_sent += 1;
                self.sent.insert(f.to_vec());
            }
            if b == 0 && std::mem::take(&mut self.hit_in_frame) {
                self.counts.frames_damaged += 1;
            }
            if self.rate <= 0.0 || self.rng.unit() >= self.rate {
                out.push(b);
                continue;
            }
            if b != 0 {
                self.hit_in_frame = true;
            } else {
                // The delimiter itself was hit: both frames around it suffer.
                self.counts.frames_damaged += 1;
                self.hit_in_frame = true;
            }
            match self.rng.next_u64() % 3 {
                0 => {
                    self.counts.corrupted += 1;
                    let x = (self.rng.next_u64() % 255 + 1) as u8;
                    out.push(b ^ x);
                }
                1 => self.counts.dropped += 1,
                _ => {
                    self.counts.duplicated += 1;
                    out.extend_from_slice(&[b, b]);
                }
            }
        }
        for &b in &out[start..] {
            match self.delivered.push(b) {
                Pushed::Pending => {}
                Pushed::Overlong => self.counts.frames_refused += 1,
                Pushed::Frame(f) => {
                    if (self.decodes)(f) {
                        self.counts.frames_accepted += 1;
                        if !self.sent.contains(f) {
                            self.counts.undetected += 1;
                        }
                    } else {
                        self.counts.frames_refused += 1;
                    }
                }
            }
        }
    }
}

fn host_msg_decodes(f: &[u8]) -> bool {
    let mut body = [0u8; MAX_BODY];
    decode_frame::<HostMsg>(f, &mut body).is_ok()
}

fn ctrl_msg_decodes(f: &[u8]) -> bool {
    let mut body = [0u8; MAX_BODY];
    decode_frame::<CtrlMsg>(f, &mut body).is_ok()
}

/// Both directions of a faulty line.
pub struct FaultyLine {
    /// Host → controller.
    pub to_controller: FaultyDirection,
    /// Controller → host.
    pub to_host: FaultyDirection,
    cut_after_bytes: Option<u64>,
}

/// What a faulty line did, for the job report.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct FaultReport {
    /// Probability that a byte was hit.
    pub rate: f64,
    /// Seed of the random number generator.
    pub seed: u64,
    /// Host → controller.
    pub to_controller: DirectionCounts,
    /// Controller → host.
    pub to_host: DirectionCounts,
    /// Whether the line was cut (see [`FaultConfig::cut_after_bytes`]).
    pub cut: bool,
}

impl FaultyLine {
    /// A line injecting `config`'s faults; the two directions draw from independent
    /// generators derived from the seed.
    pub fn new(config: FaultConfig) -> Self {
        let mut seeds = Rng::new(config.seed);
        Self {
            to_controller: FaultyDirection::new(config.rate, seeds.next_u64(), host_msg_decodes),
            to_host: FaultyDirection::new(config.rate, seeds.next_u64(), ctrl_msg_decodes),
            cut_after_bytes: config.cut_after_bytes,
        }
    }

    /// Has the line been cut?
    pub fn is_cut(&self) -> bool {
        self.cut_after_bytes
            .is_some_and(|n| self.to_host.counts.bytes >= n)
    }

    /// Host bytes in, controller bytes out (nothing once cut).
    pub fn towards_controller(&mut self, input: &[u8], out: &mut Vec<u8>) {
        if !self.is_cut() {
            self.to_controller.pass(input, out);
        }
    }

    /// Controller bytes in, host bytes out (nothing once cut).
    pub fn towards_host(&mut self, input: &[u8], out: &mut Vec<u8>) {
        if !self.is_cut() {
            self.to_host.pass(input, out);
        }
    }

    /// The counters, with the configuration that produced them.
    pub fn report(&self, config: &FaultConfig) -> FaultReport {
        FaultReport {
            rate: config.rate,
            seed: config.seed,
            to_controller: self.to_controller.counts,
            to_host: self.to_host.counts,
            cut: self.is_cut(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use pkmc::wire::{encode_frame, MAX_FRAME, PROTOCOL_VERSION};

    fn hello_frames(n: u16) -> Vec<u8> {
        let mut bytes = Vec::new();
        for seq in 0..n {
            let mut f = [0u8; MAX_FRAME];
            let msg = HostMsg::Hello {
                version: PROTOCOL_VERSION,
                machine: 7,
                host: 1,
            };
            let len = encode_frame(seq, &msg, &mut f).unwrap();
            bytes.extend_from_slice(&f[..len]);
        }
        bytes
    }

    #[test]
    fn a_clean_line_delivers_every_frame_unchanged() {
        let mut line = FaultyLine::new(FaultConfig::new(0.0, 1));
        let input = hello_frames(100);
        let mut out = Vec::new();
        line.towards_controller(&input, &mut out);
        assert_eq!(out, input);
        let c = line.to_controller.counts;
        assert_eq!(
            (c.frames_sent, c.frames_accepted, c.undetected),
            (100, 100, 0)
        );
    }

    #[test]
    fn a_faulty_line_hits_about_the_rate_and_lets_no_damage_through() {
        let mut line = FaultyLine::new(FaultConfig::new(0.05, 7));
        let input = hello_frames(2000);
        let mut out = Vec::new();
        line.towards_controller(&input, &mut out);
        let c = line.to_controller.counts;
        let hits = (c.corrupted + c.dropped + c.duplicated) as f64 / c.bytes as f64;
        assert!((hits - 0.05).abs() < 0.01, "hit rate {hits}");
        assert!(c.corrupted > 0 && c.dropped > 0 && c.duplicated > 0);
        assert!(c.frames_damaged > 100);
        assert!(c.frames_accepted + c.frames_damaged >= c.frames_sent);
        assert_eq!(c.undetected, 0);
    }

    #[test]
    fn the_same_seed_gives_the_same_faults() {
        let input = hello_frames(200);
        let run = || {
            let mut line = FaultyLine::new(FaultConfig::new(0.02, 42));
            let mut out = Vec::new();
            line.towards_host(&input, &mut out);
            out
        };
        assert_eq!(run(), run());
    }

    #[test]
    fn a_cut_line_goes_silent_in_both_directions() {
        let mut line = FaultyLine::new(FaultConfig {
            cut_after_bytes: Some(10),
            ..FaultConfig::new(0.0, 1)
        });
        let mut out = Vec::new();
        line.towards_host(&[1; 10], &mut out);
        assert_eq!(out.len(), 10);
        line.towards_host(&[1; 10], &mut out);
        line.towards_controller(&[1; 10], &mut out);
        assert_eq!(out.len(), 10);
        assert!(line.is_cut());
    }
}
