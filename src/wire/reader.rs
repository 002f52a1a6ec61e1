//! Splitting a byte stream into frames, and the controller's incremental frame
//! decoder.

use super::frame::{FrameError, WHITEN};
use super::messages::{MAX_BODY, MAX_FRAME};

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

/// A frame read by [`FrameDecoder::feed`]: its sequence number and message bytes, or
/// why it was refused.
pub type Frame<'a> = Result<(u16, &'a [u8]), FrameError>;

/// Reads frames off a byte stream in one pass: each byte is COBS-decoded and flipped
/// back ([`WHITEN`]) into the frame's body and added to its CRC as it arrives (the
/// controller's receive path: no copy of the encoded frame, no second and third pass
/// over it). Accepts and refuses
/// exactly what [`FrameReader`] then [`decode_frame`] accept and refuse (tested): a
/// body longer than [`MAX_BODY`] is refused, and so is every frame longer than
/// [`MAX_FRAME`], whose body is always longer.
#[derive(Debug)]
pub struct FrameDecoder {
    body: [u8; MAX_BODY],
    /// Body bytes decoded so far.
    len: usize,
    /// Data bytes still to come in the current COBS block (0: a code byte is next).
    left: u8,
    /// The current COBS block ends with a zero (its code is below 0xFF), written when
    /// the next block starts.
    zero: bool,
    /// A byte other than the delimiter since the last delimiter.
    started: bool,
    /// The body outgrew [`MAX_BODY`].
    overflow: bool,
    /// CRC register over the body so far ([`crate::wire::crc::update`]).
    crc: u32,
}

impl Default for FrameDecoder {
    fn default() -> Self {
        Self::new()
    }
}

impl FrameDecoder {
    /// A decoder expecting the start of a frame.
    pub const fn new() -> Self {
        Self {
            body: [0; MAX_BODY],
            len: 0,
            left: 0,
            zero: false,
            started: false,
            overflow: false,
            crc: crate::wire::crc::INIT,
        }
    }

    /// Takes bytes from the start of `bytes` up to and including the first delimiter
    /// that ends a frame (empty frames are skipped), or all of them; returns how many
    /// it took and, when a frame ended, its sequence number and message bytes (or why
    /// it was refused).
    #[inline(never)]
    pub fn feed(&mut self, bytes: &[u8]) -> (usize, Option<Frame<'_>>) {
        let (mut len, mut left, mut zero, mut crc) = (self.len, self.left, self.zero, self.crc);
        let (mut started, mut overflow) = (self.started, self.overflow);
        let mut at = 0;
        let mut ended = false;
        while at < bytes.len() {
            if left == 0 {
                // A code byte, or the delimiter.
                let b = bytes[at];
                at += 1;
                if b == 0 {
                    if started {
                        ended = true;
                        break;
                    }
                    continue;
                }
                started = true;
                if core::mem::replace(&mut zero, b != 0xFF) {
                    if len < MAX_BODY {
                        self.body[len] = WHITEN;
                        len += 1;
                        crc = crate::wire::crc::update(crc, WHITEN);
                    } else {
                        overflow = true;
                    }
                }
                left = b - 1;
                continue;
            }
            // A run of data bytes: copied and added to the CRC in one tight loop, up
            // to the end of the block, of `bytes` or of the room left.
            let run = (left as usize).min(bytes.len() - at);
            let src = &bytes[at..at + run];
            let room = MAX_BODY - len;
            let dst = &mut self.body[len..len + run.min(room)];
            let mut n = 0;
            // Four bytes at a time while none of them is a zero (a delimiter inside
            // the block: left to the byte loop below).
            let m = dst.len();
            for (d, s) in dst.chunks_exact_mut(4).zip(src[..m].chunks_exact(4)) {
                let w = u32::from_le_bytes([s[0], s[1], s[2], s[3]]);
                if w.wrapping_sub(0x0101_0101) & !w & 0x8080_8080 != 0 {
                    break;
                }
                let w = w ^ u32::from_ne_bytes([WHITEN; 4]);
                d.copy_from_slice(&w.to_le_bytes());
                crc = crate::wire::crc::update_word(crc, w);
                n += 4;
            }
            for (d, &b) in dst[n..].iter_mut().zip(&src[n..]) {
                if b == 0 {
                    break;
                }
                let b = b ^ WHITEN;
                *d = b;
                crc = crate::wire::crc::update(crc, b);
                n += 1;
            }
            len += n;
            if n < run && src[n] != 0 {
                // No room for the rest of the run: skip it up to a delimiter.
                overflow = true;
                n += src[n..].iter().take_while(|&&b| b != 0).count();
            }
            at += n;
            left -= n as u8;
            if n < run {
                // The delimiter, inside a block: a truncated frame.
                at += 1;
                ended = true;
                break;
            }
        }
        let taken = at;
        if !ended {
            (self.len, self.left, self.zero, self.crc) = (len, left, zero, crc);
            (self.started, self.overflow) = (started, overflow);
            return (taken, None);
        }
        (self.len, self.left, self.zero, self.crc) = (0, 0, false, crate::wire::crc::INIT);
        (self.started, self.overflow) = (false, false);
        let result = if overflow || left != 0 {
            Err(FrameError::Cobs)
        } else if len < 6 {
            Err(FrameError::Short)
        } else if crc != crate::wire::crc::RESIDUE {
            Err(FrameError::Crc)
        } else {
            Ok((
                u16::from_le_bytes([self.body[0], self.body[1]]),
                &self.body[2..len - 4],
            ))
        };
        (taken, Some(result))
    }
}
