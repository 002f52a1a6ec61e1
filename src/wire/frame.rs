//! Sealing and opening a frame (sequence number, message, CRC-32, whitening, COBS),
//! and the hand-written writer of the two messages the controller sends most.

use super::messages::{Status, MAX_BODY, MAX_FRAME};
use crate::config::{AXES, MAX_JOINTS};
use serde::{Deserialize, Serialize};

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
    encode_frame_with(seq, msg, &mut [0u8; MAX_BODY], out)
}

/// [`encode_frame`] with the caller's scratch `body` (its contents do not matter; no
/// buffer is cleared, for the controller's transmit path).
pub fn encode_frame_with<M: Serialize>(
    seq: u16,
    msg: &M,
    body: &mut [u8; MAX_BODY],
    out: &mut [u8; MAX_FRAME],
) -> Result<usize, FrameError> {
    body[..2].copy_from_slice(&seq.to_le_bytes());
    let used = postcard::to_slice(msg, &mut body[2..MAX_BODY - 4])
        .map_err(|_| FrameError::TooLong)?
        .len();
    Ok(seal(body, 0, 2 + used, out))
}

/// The byte mask of W in the module doc (W is its own inverse).
pub const WHITEN: u8 = 0xA5;

/// Completes a frame: its data `body[start..end]` (sequence number and message; `end`
/// at most `MAX_BODY - 4`) followed by their CRC, which is written into the body at
/// `end`, COBS-encoded with each byte flipped ([`WHITEN`]), then the delimiter,
/// written into `out`; returns its length.
///
/// The controller seals every frame it sends (a status is some 110 bytes), so the
/// common case goes four bytes at a time: the CRC by words ([`crc::update_word`]),
/// and the encoding copies a flipped word whole unless one of its bytes flips to
/// zero. Byte by byte, a status cost about 13 instructions a byte on the M4.
///
/// [`crc::update_word`]: crate::wire::crc::update_word
pub(super) fn seal(
    body: &mut [u8; MAX_BODY],
    start: usize,
    end: usize,
    out: &mut [u8; MAX_FRAME],
) -> usize {
    let end = end.min(MAX_BODY - 4);
    let mut crc = crate::wire::crc::INIT;
    let mut words = body[start.min(end)..end].chunks_exact(4);
    for w in &mut words {
        crc = crate::wire::crc::update_word(crc, u32::from_le_bytes([w[0], w[1], w[2], w[3]]));
    }
    for &b in words.remainder() {
        crc = crate::wire::crc::update(crc, b);
    }
    body[end..end + 4].copy_from_slice(&(!crc).to_le_bytes());
    let framed = &body[start.min(end)..end + 4];
    let (mut code_at, mut at) = (0, 1);
    if framed.len() < 0xFE {
        // No run of 254 non-zero bytes fits: only zeros end a block.
        #[inline(always)]
        fn put(b: u8, out: &mut [u8; MAX_FRAME], code_at: &mut usize, at: &mut usize) {
            let b = b ^ WHITEN;
            if b == 0 {
                out[*code_at] = (*at - *code_at) as u8;
                *code_at = *at;
            } else {
                out[*at] = b;
            }
            *at += 1;
        }
        let mut words = framed.chunks_exact(4);
        for w in &mut words {
            let w = [w[0], w[1], w[2], w[3]];
            let x = u32::from_le_bytes(w) ^ u32::from_ne_bytes([WHITEN; 4]);
            match out.get_mut(at..at + 4) {
                // No byte of the word is zero once flipped.
                Some(o) if x.wrapping_sub(0x0101_0101) & !x & 0x8080_8080 == 0 => {
                    o.copy_from_slice(&x.to_le_bytes());
                    at += 4;
                }
                _ => w.iter().for_each(|&b| put(b, out, &mut code_at, &mut at)),
            }
        }
        for &b in words.remainder() {
            put(b, out, &mut code_at, &mut at);
        }
    } else {
        for &b in framed {
            let b = b ^ WHITEN;
            if b == 0 {
                out[code_at] = (at - code_at) as u8;
                code_at = at;
                at += 1;
            } else {
                out[at] = b;
                at += 1;
                if at - code_at == 0xFF {
                    out[code_at] = 0xFF;
                    code_at = at;
                    at += 1;
                }
            }
        }
    }
    out[code_at] = (at - code_at) as u8;
    out[at] = 0;
    at + 1
}

/// Variant indices of [`CtrlMsg`] in the message encoding.
const CTRL_MSG_ACK: u8 = 3;
const CTRL_MSG_STATUS: u8 = 6;
const CTRL_MSG_RECORD: u8 = 8;

/// Writes a message in postcard's encoding, for the two messages the controller sends
/// most ([`encode_ack`], [`encode_status`]): what `postcard::to_slice` writes (tested),
/// without serde's generic code.
struct Writer<'a> {
    buf: &'a mut [u8; MAX_BODY],
    len: usize,
}

impl Writer<'_> {
    fn byte(&mut self, b: u8) {
        self.buf[self.len] = b;
        self.len += 1;
    }

    /// A varint: one byte inline; longer ones written whole, their first four bytes as one word (seven bits each,
    /// shifted into place, with the continuation bits of its length) and the fifth
    /// byte, though only its length counts (the bytes beyond are scratch, overwritten
    /// by the next field). Byte by byte, the varints of a status cost about 40
    /// instructions each on the M4.
    #[inline(always)]
    fn u32(&mut self, v: u32) {
        if v < 0x80 {
            self.byte(v as u8);
        } else {
            self.u32_long(v);
        }
    }

    /// [`Writer::u32`] of two bytes or more.
    #[inline(never)]
    fn u32_long(&mut self, v: u32) {
        /// The varint's length by the value's leading zeros.
        const LEN: [u8; 33] = {
            let mut t = [0u8; 33];
            let mut z = 0;
            while z <= 32 {
                let bits = 32 - z;
                t[z] = if bits == 0 { 1 } else { bits.div_ceil(7) as u8 };
                z += 1;
            }
            t
        };
        /// The continuation bits of a varint of `n` bytes in its first word.
        const MORE: [u32; 8] = [0, 0, 0x80, 0x8080, 0x80_8080, 0x8080_8080, 0, 0];
        let n = LEN[v.leading_zeros() as usize] as usize;
        let at = self.len;
        let Some(o) = self.buf.get_mut(at..at + 5) else {
            return self.u32_bytes(v);
        };
        let low = (v & 0x7F) | (v << 1 & 0x7F00) | (v << 2 & 0x7F_0000) | (v << 3 & 0x7F00_0000);
        o[..4].copy_from_slice(&(low | MORE[n & 7]).to_le_bytes());
        o[4] = (v >> 28) as u8;
        self.len = at + n;
    }

    /// [`Writer::u32`] a byte at a time (within five bytes of the end).
    fn u32_bytes(&mut self, mut v: u32) {
        while v >= 0x80 {
            self.byte(v as u8 | 0x80);
            v >>= 7;
        }
        self.byte(v as u8);
    }

    fn u64(&mut self, v: u64) {
        if v >> 32 == 0 {
            return self.u32(v as u32);
        }
        // Four groups of seven bits from the low word, then the rest.
        let low = v as u32;
        for i in 0..4 {
            self.byte((low >> (7 * i)) as u8 | 0x80);
        }
        let mut v = v >> 28;
        while v >= 0x80 {
            self.byte(v as u8 | 0x80);
            v >>= 7;
        }
        self.byte(v as u8);
    }

    fn i64(&mut self, v: i64) {
        self.u64(((v << 1) ^ (v >> 63)) as u64);
    }
}

/// Encodes `CtrlMsg::Ack { seq: acked, free_slots, free_bends, buffered_ms }` with sequence number
/// `seq` as a complete frame (as [`encode_frame_with`] does); returns its length.
pub fn encode_ack(
    seq: u16,
    acked: u16,
    free_slots: u16,
    free_bends: u16,
    buffered_ms: u32,
    body: &mut [u8; MAX_BODY],
    out: &mut [u8; MAX_FRAME],
) -> usize {
    let mut w = Writer { buf: body, len: 0 };
    for b in seq.to_le_bytes() {
        w.byte(b);
    }
    w.byte(CTRL_MSG_ACK);
    w.u32(acked as u32);
    w.u32(free_slots as u32);
    w.u32(free_bends as u32);
    w.u32(buffered_ms);
    let n = w.len;
    seal(body, 0, n, out)
}

/// Encodes `CtrlMsg::Record` of `len` bytes, which `fill` writes into the slice it is
/// given (exactly `len` bytes, in the frame's scratch body: no copy of them is made),
/// with sequence number `seq` as a complete frame (as [`encode_frame_with`] does);
/// returns its length, or `None` when `len` is beyond the message's
/// [`CHUNK_BYTES`](crate::wire::store::CHUNK_BYTES). For the recorder's streamed
/// pieces, sent every few ticks beside a job.
pub fn encode_record(
    seq: u16,
    len: usize,
    fill: impl FnOnce(&mut [u8]),
    body: &mut [u8; MAX_BODY],
    out: &mut [u8; MAX_FRAME],
) -> Option<usize> {
    const AT: usize = 5;
    const _: () = assert!(AT + crate::wire::store::CHUNK_BYTES + 4 <= MAX_BODY);
    if len > crate::wire::store::CHUNK_BYTES {
        return None;
    }
    fill(&mut body[AT..AT + len]);
    // The prefix ends right before the bytes: sequence number, variant, and the length
    // as a varint of one byte (below 128) or two.
    let start = if len < 0x80 {
        body[AT - 1] = len as u8;
        1
    } else {
        body[AT - 2] = len as u8 | 0x80;
        body[AT - 1] = (len >> 7) as u8;
        0
    };
    body[start..start + 2].copy_from_slice(&seq.to_le_bytes());
    body[start + 2] = CTRL_MSG_RECORD;
    Some(seal(body, start, AT + len, out))
}

/// Encodes `CtrlMsg::Status(s)` with sequence number `seq` as a complete frame (as
/// [`encode_frame_with`] does); returns its length.
pub fn encode_status(
    seq: u16,
    s: &Status,
    body: &mut [u8; MAX_BODY],
    out: &mut [u8; MAX_FRAME],
) -> usize {
    // The widest status (every varint at its longest) fits with its CRC.
    const WIDEST: usize = 2
        + 1
        + 1
        + 5
        + 5
        + 10 * (1 + AXES + 2 * MAX_JOINTS + 1)
        + 5
        + 3
        + 3
        + 3
        + 8
        + 1
        + 1
        + 1
        + 3;
    const _: () = assert!(WIDEST + 4 <= MAX_BODY);
    let mut w = Writer { buf: body, len: 0 };
    for b in seq.to_le_bytes() {
        w.byte(b);
    }
    w.byte(CTRL_MSG_STATUS);
    w.u32(s.state as u32);
    w.u32(s.line);
    w.u32(s.blocks_done);
    w.u64(s.motion_ticks);
    for &p in &s.pose {
        w.i64(p);
    }
    for &q in &s.joints {
        w.i64(q);
    }
    for &m in &s.measured {
        w.i64(m);
    }
    w.i64(s.speed);
    w.u32(s.buffered_ms);
    w.u32(s.free_slots as u32);
    w.u32(s.free_bends as u32);
    w.u32(s.feed_override as u32);
    match s.alarm {
        None => w.byte(0),
        Some(a) => {
            w.byte(1);
            w.u32(a.cause as u32);
            w.byte(a.joint);
            w.u32(a.line);
        }
    }
    w.byte(s.homed as u8);
    w.byte(s.orphan as u8);
    w.byte(s.probe_input as u8);
    w.u32(s.probes as u32);
    let n = w.len;
    seal(body, 0, n, out)
}

/// Decodes one frame's bytes (between delimiters, without the 0x00) into its sequence
/// number and message.
pub fn decode_frame<'de, M: Deserialize<'de>>(
    encoded: &[u8],
    body: &'de mut [u8; MAX_BODY],
) -> Result<(u16, M), FrameError> {
    let (seq, message) = decode_body(encoded, body)?;
    let msg = postcard::from_bytes(message).map_err(|_| FrameError::Message)?;
    Ok((seq, msg))
}

/// Decodes one frame's bytes (between delimiters, without the 0x00) into its sequence
/// number and message bytes, checking its COBS encoding, length and CRC.
pub fn decode_body<'b>(
    encoded: &[u8],
    body: &'b mut [u8; MAX_BODY],
) -> Result<(u16, &'b [u8]), FrameError> {
    let n = crate::wire::cobs::decode(encoded, body).map_err(|_| FrameError::Cobs)?;
    for b in &mut body[..n] {
        *b ^= WHITEN;
    }
    if n < 6 {
        return Err(FrameError::Short);
    }
    let (data, crc) = body[..n].split_at(n - 4);
    let want = u32::from_le_bytes([crc[0], crc[1], crc[2], crc[3]]);
    if crate::wire::crc::crc32(data) != want {
        return Err(FrameError::Crc);
    }
    let seq = u16::from_le_bytes([data[0], data[1]]);
    Ok((seq, &body[2..n - 4]))
}
