//! The recorder's requests and answers as bytes, packed by hand (serde's derives of
//! these types cost the firmware more flash than it has): the host and the controller
//! both use these functions, so they stay in step. Little-endian throughout.
//!
//! A request ([`Setup::pack`], [`SETUP_BYTES`]): the signal count, eight signal ids
//! (those past the count unused), servo (0 or 1), decimation (u16), pre-trigger
//! samples (u16), the trigger's kind (0 now, 1 job start, 2 NC line, 3 any alarm, 4
//! rising level, 5 falling level, 6 continuous), its signal number (u8) and its line or level (u32
//! or i32): 20 bytes.
//!
//! An answer ([`Reply`]): a header of [`REPLY_HEADER`] bytes (phase, samples, pre,
//! width, servo, decimation, the refusal's code and two arguments, the signal count,
//! eight signal ids, the data's offset) and the capture's bytes from that offset. A
//! streamed piece (phase streaming) has the same header: `samples` is the number of
//! samples it carries, `offset` the first one's number since arming, and bit 1 of
//! the servo byte is set.

use super::{Capture, Phase, RecorderError, Setup, Trigger, MAX_SIGNALS};

/// Bytes of an answer's header.
pub const REPLY_HEADER: usize = 28;

/// Bytes of a packed request ([`Setup::pack`]).
pub const SETUP_BYTES: usize = 20;

impl Setup {
    /// The request's bytes.
    pub fn pack(&self) -> [u8; SETUP_BYTES] {
        let (kind, signal, arg) = match self.trigger {
            Trigger::Now => (0, 0, 0),
            Trigger::JobStart => (1, 0, 0),
            Trigger::Line(l) => (2, 0, l),
            Trigger::Alarm => (3, 0, 0),
            Trigger::Stream => (6, 0, 0),
            Trigger::Level {
                signal,
                level,
                rising,
            } => (if rising { 4 } else { 5 }, signal, level as u32),
        };
        let mut out = [0; SETUP_BYTES];
        out[0] = self.count;
        out[1..9].copy_from_slice(&self.signals);
        out[9] = self.servo as u8;
        out[10..12].copy_from_slice(&self.decimate.to_le_bytes());
        out[12..14].copy_from_slice(&self.pre.to_le_bytes());
        out[14] = kind;
        out[15] = signal;
        out[16..20].copy_from_slice(&arg.to_le_bytes());
        out
    }

    /// The request packed in `b`; the error names the first bad byte. The signals
    /// themselves are checked by [`super::Recorder::arm`].
    pub fn unpack(b: &[u8]) -> Result<Self, RecorderError> {
        let Ok(b) = <&[u8; SETUP_BYTES]>::try_from(b) else {
            return Err(RecorderError::Malformed {
                at: b.len().min(SETUP_BYTES) as u8,
            });
        };
        let servo = match b[9] {
            0 => false,
            1 => true,
            _ => return Err(RecorderError::Malformed { at: 9 }),
        };
        let arg = u32::from_le_bytes([b[16], b[17], b[18], b[19]]);
        let trigger = match b[14] {
            0 => Trigger::Now,
            1 => Trigger::JobStart,
            2 => Trigger::Line(arg),
            3 => Trigger::Alarm,
            6 => Trigger::Stream,
            k @ (4 | 5) => Trigger::Level {
                signal: b[15],
                level: arg as i32,
                rising: k == 4,
            },
            _ => return Err(RecorderError::Malformed { at: 14 }),
        };
        let mut signals = [0; MAX_SIGNALS];
        signals.copy_from_slice(&b[1..9]);
        Ok(Self {
            signals,
            count: b[0],
            servo,
            decimate: u16::from_le_bytes([b[10], b[11]]),
            trigger,
            pre: u16::from_le_bytes([b[12], b[13]]),
        })
    }
}

/// The controller's answer about its recorder: where the capture is, what it holds,
/// and (after the header) a piece of its bytes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Reply {
    /// Where the capture is.
    pub capture: Capture,
    /// The signals' wire ids; `count` of them.
    pub signals: [u8; MAX_SIGNALS],
    /// Signals in the capture.
    pub count: u8,
    /// Sampled every servo period (else every tick).
    pub servo: bool,
    /// Periods or ticks between samples.
    pub decimate: u16,
    /// Why the last arm request was refused.
    pub refused: Option<RecorderError>,
    /// Where the data after the header starts in the capture, bytes; in a streamed
    /// piece, the number of its first sample.
    pub offset: u32,
    /// A piece of the continuous stream (sent unasked), not an answer to a read.
    pub streamed: bool,
}

impl Reply {
    /// The header into `out`.
    pub fn pack(&self, out: &mut [u8; REPLY_HEADER]) {
        let c = &self.capture;
        out[0] = c.phase as u8;
        out[1..3].copy_from_slice(&c.samples.to_le_bytes());
        out[3..5].copy_from_slice(&c.pre.to_le_bytes());
        out[5..7].copy_from_slice(&c.width.to_le_bytes());
        out[7] = self.servo as u8 | (self.streamed as u8) << 1;
        out[8..10].copy_from_slice(&self.decimate.to_le_bytes());
        let (code, a, b) = match self.refused {
            None => (0, 0, 0),
            Some(RecorderError::BadSignal { index, id }) => (1, index as u16, id as u16),
            Some(RecorderError::SignalCount { count }) => (2, count as u16, 0),
            Some(RecorderError::Decimation) => (3, 0, 0),
            Some(RecorderError::TriggerSignal { index }) => (4, index as u16, 0),
            Some(RecorderError::PreTrigger { pre, capacity }) => (5, pre, capacity),
            Some(RecorderError::Malformed { at }) => (6, at as u16, 0),
            Some(RecorderError::ExciteBusy) => (8, 0, 0),
            Some(RecorderError::ExciteJoint { joint }) => (9, joint as u16, 0),
            Some(RecorderError::ExciteAmplitude { joint, limit }) => (10, joint as u16, limit),
            Some(RecorderError::ExciteTravel { joint }) => (11, joint as u16, 0),
        };
        out[10] = code;
        out[11..13].copy_from_slice(&a.to_le_bytes());
        out[13..15].copy_from_slice(&b.to_le_bytes());
        out[15] = self.count;
        out[16..24].copy_from_slice(&self.signals);
        out[24..28].copy_from_slice(&self.offset.to_le_bytes());
    }

    /// An answer's header and its data; `None` when `b` is not one.
    pub fn unpack(b: &[u8]) -> Option<(Self, &[u8])> {
        let h = b.get(..REPLY_HEADER)?;
        let u16_of = |at: usize| u16::from_le_bytes([h[at], h[at + 1]]);
        let phase = match h[0] {
            0 => Phase::Off,
            1 => Phase::Armed,
            2 => Phase::Triggered,
            3 => Phase::Done,
            4 => Phase::Streaming,
            _ => return None,
        };
        let (a, b2) = (u16_of(11), u16_of(13));
        let refused = match h[10] {
            0 => None,
            1 => Some(RecorderError::BadSignal {
                index: a as u8,
                id: b2 as u8,
            }),
            2 => Some(RecorderError::SignalCount { count: a as u8 }),
            3 => Some(RecorderError::Decimation),
            4 => Some(RecorderError::TriggerSignal { index: a as u8 }),
            5 => Some(RecorderError::PreTrigger {
                pre: a,
                capacity: b2,
            }),
            6 => Some(RecorderError::Malformed { at: a as u8 }),
            8 => Some(RecorderError::ExciteBusy),
            9 => Some(RecorderError::ExciteJoint { joint: a as u8 }),
            10 => Some(RecorderError::ExciteAmplitude {
                joint: a as u8,
                limit: b2,
            }),
            11 => Some(RecorderError::ExciteTravel { joint: a as u8 }),
            _ => return None,
        };
        let count = h[15];
        if count as usize > MAX_SIGNALS {
            return None;
        }
        let mut signals = [0; MAX_SIGNALS];
        signals.copy_from_slice(&h[16..24]);
        let reply = Self {
            capture: Capture {
                phase,
                samples: u16_of(1),
                pre: u16_of(3),
                width: u16_of(5),
            },
            signals,
            count,
            servo: h[7] & 1 == 1,
            streamed: h[7] & 2 == 2,
            decimate: u16_of(8),
            refused,
            offset: u32::from_le_bytes([h[24], h[25], h[26], h[27]]),
        };
        Some((reply, &b[REPLY_HEADER..]))
    }
}
