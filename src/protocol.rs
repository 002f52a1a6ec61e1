//! The wire protocol between `nc-send` and the controller, defined once for both sides.
//!
//! A frame on the byte stream is `COBS(seq_le16 ‖ postcard(message) ‖ crc32_le(seq ‖
//! message)) ‖ 0x00`. The sequence number orders host messages: the controller accepts
//! exactly the next one, acknowledges cumulatively (`Ack { seq }` covers every message
//! up to `seq`), re-acknowledges a duplicate without acting on it, and answers a gap or
//! a damaged frame with a `Nak` naming the sequence number it expects. Flow control is
//! by credits: every `Ack` carries the free block-queue slots and the milliseconds of
//! motion already buffered, and the host never has more blocks in flight than slots.

use crate::config::{AXES, MAX_JOINTS};
use serde::{Deserialize, Serialize};

/// Protocol version, exchanged in the handshake; both sides must agree.
pub const PROTOCOL_VERSION: u16 = 1;
/// Largest unencoded frame body (sequence number, message and CRC), bytes.
pub const MAX_BODY: usize = 240;
/// Largest encoded frame including its delimiter, bytes.
pub const MAX_FRAME: usize = crate::cobs::max_encoded_len(MAX_BODY) + 1;

/// Kind of motion of a block.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Motion {
    /// Rapid positioning at the machine's limits (G0).
    Rapid,
    /// Straight feed move at the block's feed (G1).
    Linear,
}

/// One canonical motion block, in absolute machine pose (axis units, see
/// [`crate::units`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Block {
    /// NC program line the block came from (1-based; 0 for none).
    pub line: u32,
    /// Motion kind.
    pub motion: Motion,
    /// End pose X Y Z (nm) A B C (n°).
    pub target: [i64; AXES],
    /// Path feed, nm/s along XYZ (or n°/s when only rotary axes move); ignored for
    /// rapids.
    pub feed: i64,
}

/// Messages from the host to the controller.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum HostMsg {
    /// Opens a session; resets sequence numbering to the frame's `seq + 1`.
    Hello {
        /// The host's [`PROTOCOL_VERSION`].
        version: u16,
    },
    /// Queues a motion block.
    Block(Block),
    /// Asks for a [`Status`] now (bypasses the queue).
    StatusRequest,
    /// Stops motion and drops the queue (bypasses the queue).
    Abort,
}

/// Controller state.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum State {
    /// Not moving, queue empty.
    Idle,
    /// Executing blocks.
    Running,
    /// Stopped by a fault; see the alarm.
    Alarm,
}

/// Why the controller raised an alarm.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[non_exhaustive]
pub enum Alarm {
    /// A block's pose is outside the machine's reach (joint index, or 255 for none).
    Unreachable {
        /// NC line of the block.
        line: u32,
        /// Joint whose limit the pose breaks, if one.
        joint: u8,
    },
    /// The host aborted the job.
    Aborted,
}

/// Why a frame was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[non_exhaustive]
pub enum NakReason {
    /// CRC mismatch, bad COBS, or an undecodable message.
    Corrupt,
    /// Sequence number ahead of the expected one (a frame was lost).
    Gap,
    /// The block queue is full (the host ignored its credits).
    QueueFull,
    /// Protocol version mismatch.
    Version,
    /// The message came before the handshake.
    NoSession,
}

/// Periodic and requested controller status.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Status {
    /// Current state.
    pub state: State,
    /// NC line of the executing (or last executed) block.
    pub line: u32,
    /// Blocks completed since the session started.
    pub blocks_done: u32,
    /// Interpolation ticks run while moving since the session started.
    pub motion_ticks: u64,
    /// Commanded pose, axis units.
    pub pose: [i64; AXES],
    /// Commanded joint positions, axis units.
    pub joints: [i64; MAX_JOINTS],
    /// Motion buffered in the queue and the executing block, ms.
    pub buffered_ms: u32,
    /// Free block-queue slots.
    pub free_slots: u16,
    /// Active alarm, if any.
    pub alarm: Option<Alarm>,
}

/// Messages from the controller to the host.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum CtrlMsg {
    /// Answers `Hello`.
    HelloAck {
        /// The controller's [`PROTOCOL_VERSION`].
        version: u16,
        /// Block-queue capacity (initial credits).
        queue_capacity: u16,
    },
    /// Every host message up to and including `seq` was accepted.
    Ack {
        /// Highest accepted sequence number.
        seq: u16,
        /// Free block-queue slots after it.
        free_slots: u16,
        /// Motion buffered, ms.
        buffered_ms: u32,
    },
    /// A frame was refused; the controller expects `expected` next.
    Nak {
        /// Next sequence number the controller will accept.
        expected: u16,
        /// Why.
        reason: NakReason,
    },
    /// Controller status.
    Status(Status),
}

/// Why a frame could not be built or read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum FrameError {
    /// The message does not fit in [`MAX_BODY`].
    TooLong,
    /// COBS decoding failed.
    Cobs,
    /// Shorter than a sequence number and a CRC.
    Short,
    /// CRC mismatch.
    Crc,
    /// The body is not a valid message.
    Message,
}

/// Encodes `msg` with sequence number `seq` into `out` as a complete frame including
/// the 0x00 delimiter; returns its length.
pub fn encode_frame<M: Serialize>(
    seq: u16,
    msg: &M,
    out: &mut [u8; MAX_FRAME],
) -> Result<usize, FrameError> {
    let mut body = [0u8; MAX_BODY];
    body[..2].copy_from_slice(&seq.to_le_bytes());
    let used = postcard::to_slice(msg, &mut body[2..MAX_BODY - 4])
        .map_err(|_| FrameError::TooLong)?
        .len();
    let n = 2 + used;
    let crc = crate::crc::crc32(&body[..n]);
    body[n..n + 4].copy_from_slice(&crc.to_le_bytes());
    let len = crate::cobs::encode(&body[..n + 4], &mut out[..MAX_FRAME - 1])
        .ok_or(FrameError::TooLong)?;
    out[len] = 0;
    Ok(len + 1)
}

/// Decodes one frame's bytes (between delimiters, without the 0x00) into its sequence
/// number and message.
pub fn decode_frame<'de, M: Deserialize<'de>>(
    encoded: &[u8],
    body: &'de mut [u8; MAX_BODY],
) -> Result<(u16, M), FrameError> {
    let n = crate::cobs::decode(encoded, body).map_err(|_| FrameError::Cobs)?;
    if n < 6 {
        return Err(FrameError::Short);
    }
    let (data, crc) = body[..n].split_at(n - 4);
    let want = u32::from_le_bytes([crc[0], crc[1], crc[2], crc[3]]);
    if crate::crc::crc32(data) != want {
        return Err(FrameError::Crc);
    }
    let seq = u16::from_le_bytes([data[0], data[1]]);
    let msg = postcard::from_bytes(&body[2..n - 4]).map_err(|_| FrameError::Message)?;
    Ok((seq, msg))
}

/// Splits a byte stream into frames at 0x00 delimiters. A frame longer than
/// [`MAX_FRAME`] is discarded up to its delimiter and reported as overlong.
#[derive(Debug)]
pub struct FrameReader {
    buf: [u8; MAX_FRAME],
    len: usize,
    overflow: bool,
}

/// What [`FrameReader::push`] found.
#[derive(Debug, PartialEq, Eq)]
pub enum Pushed<'a> {
    /// No complete frame yet.
    Pending,
    /// A complete frame (COBS-encoded, without its delimiter).
    Frame(&'a [u8]),
    /// A frame too long to be valid ended here.
    Overlong,
}

impl Default for FrameReader {
    fn default() -> Self {
        Self::new()
    }
}

impl FrameReader {
    /// An empty reader.
    pub const fn new() -> Self {
        Self {
            buf: [0; MAX_FRAME],
            len: 0,
            overflow: false,
        }
    }

    /// Feeds one byte.
    pub fn push(&mut self, byte: u8) -> Pushed<'_> {
        if byte == 0 {
            let len = core::mem::replace(&mut self.len, 0);
            if core::mem::replace(&mut self.overflow, false) {
                return Pushed::Overlong;
            }
            if len == 0 {
                return Pushed::Pending;
            }
            return Pushed::Frame(&self.buf[..len]);
        }
        if self.len < self.buf.len() {
            self.buf[self.len] = byte;
            self.len += 1;
        } else {
            self.overflow = true;
        }
        Pushed::Pending
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample_block() -> HostMsg {
        HostMsg::Block(Block {
            line: 12,
            motion: Motion::Linear,
            target: [10_000_000, -5, i64::MAX, i64::MIN, 0, 1],
            feed: 16_666_666,
        })
    }

    #[test]
    fn a_frame_round_trips_through_the_reader() {
        let mut frame = [0u8; MAX_FRAME];
        let n = encode_frame(7, &sample_block(), &mut frame).unwrap();
        assert_eq!(frame[n - 1], 0);
        let mut reader = FrameReader::new();
        let mut got = None;
        for &b in &frame[..n] {
            if let Pushed::Frame(f) = reader.push(b) {
                let mut body = [0u8; MAX_BODY];
                got = Some(decode_frame::<HostMsg>(f, &mut body).unwrap());
            }
        }
        assert_eq!(got, Some((7, sample_block())));
    }

    #[test]
    fn the_largest_status_fits_in_a_frame() {
        let s = CtrlMsg::Status(Status {
            state: State::Running,
            line: u32::MAX,
            blocks_done: u32::MAX,
            motion_ticks: u64::MAX,
            pose: [i64::MIN; AXES],
            joints: [i64::MIN; MAX_JOINTS],
            buffered_ms: u32::MAX,
            free_slots: u16::MAX,
            alarm: Some(Alarm::Unreachable {
                line: u32::MAX,
                joint: 255,
            }),
        });
        let mut frame = [0u8; MAX_FRAME];
        assert!(encode_frame(u16::MAX, &s, &mut frame).is_ok());
    }

    #[test]
    fn every_single_bit_flip_is_detected() {
        let mut frame = [0u8; MAX_FRAME];
        let n = encode_frame(3, &sample_block(), &mut frame).unwrap();
        for i in 0..n - 1 {
            for bit in 0..8 {
                let mut f = frame;
                f[i] ^= 1 << bit;
                if f[i] == 0 {
                    continue; // becomes a delimiter: the reader splits the frame instead
                }
                let mut body = [0u8; MAX_BODY];
                assert!(
                    decode_frame::<HostMsg>(&f[..n - 1], &mut body).is_err(),
                    "flip of byte {i} bit {bit} went unnoticed"
                );
            }
        }
    }
}
