//! The hand-written decoder of the one message the controller decodes on its hot
//! path: a planned block, read as `postcard::from_bytes` would read it.

use super::frame::FrameError;
use crate::motion::block::{Aux, Dip, Motion, Plane, PlannedBlock, Shape};

/// Variant index of [`HostMsg::Block`] in the message encoding.
const HOST_MSG_BLOCK: u32 = 2;

/// The low seven bits of up to four varint bytes, in one word (constant shifts), and
/// how many bytes up to and including the last one (0: the varint goes on).
#[inline(always)]
fn group4(w: [u8; 4]) -> (u32, usize) {
    let mut bits = (w[0] & 0x7F) as u32;
    if w[0] < 0x80 {
        return (bits, 1);
    }
    bits |= ((w[1] & 0x7F) as u32) << 7;
    if w[1] < 0x80 {
        return (bits, 2);
    }
    bits |= ((w[2] & 0x7F) as u32) << 14;
    if w[2] < 0x80 {
        return (bits, 3);
    }
    bits |= ((w[3] & 0x7F) as u32) << 21;
    if w[3] < 0x80 {
        return (bits, 4);
    }
    (bits, 0)
}

/// Reads a postcard message the way `postcard::from_bytes` does, for the one message
/// the controller decodes by hand ([`decode_block`]). A read past the end or of an
/// invalid encoding marks the message bad (and reads zeros from then on): one check
/// at the end instead of one per field, and every value returned in registers.
struct Cursor<'a> {
    bytes: &'a [u8],
    at: usize,
    bad: bool,
}

impl Cursor<'_> {
    fn fail<T: Default>(&mut self) -> T {
        self.bad = true;
        self.at = self.bytes.len();
        T::default()
    }

    fn byte(&mut self) -> u8 {
        match self.bytes.get(self.at) {
            Some(&b) => {
                self.at += 1;
                b
            }
            None => self.fail(),
        }
    }

    /// A varint of at most `max` (3 to 10) bytes whose last byte, when there are
    /// `max`, is at most `last` (postcard's rule for an integer of that width); bits
    /// beyond 64 are dropped (as postcard drops what its type does not hold). A
    /// one-byte varint (tags, flags, zeros: half of a block's fields) is read inline.
    #[inline(always)]
    fn varint(&mut self, max: usize, last: u8) -> u64 {
        if let Some(&b) = self.bytes.get(self.at) {
            if b < 0x80 {
                self.at += 1;
                return b as u64;
            }
        }
        self.varint_long(max, last)
    }

    /// [`Cursor::varint`] of two bytes or more.
    #[inline(never)]
    fn varint_long(&mut self, max: usize, last: u8) -> u64 {
        let Some(w) = self.bytes[self.at..].first_chunk::<12>() else {
            return self.varint_near_end(max, last);
        };
        // Four bytes at a time, with constant shifts.
        let (low, n) = group4([w[0], w[1], w[2], w[3]]);
        let mut v = low as u64;
        let mut n = n;
        if n == 0 {
            let (mid, m) = group4([w[4], w[5], w[6], w[7]]);
            v |= (mid as u64) << 28;
            n = if m == 0 {
                let (high, h) = group4([w[8], w[9], w[10], w[11]]);
                v |= (high as u64) << 56;
                if h == 0 {
                    return self.fail();
                }
                8 + h
            } else {
                4 + m
            };
        }
        if n > max || (n == max && w[n - 1] > last) {
            return self.fail();
        }
        self.at += n;
        v
    }

    /// [`Cursor::varint`] within the last twelve bytes of the message.
    #[inline(never)]
    fn varint_near_end(&mut self, max: usize, last: u8) -> u64 {
        let mut v = 0u64;
        for i in 0..max {
            let b = self.byte();
            v |= ((b & 0x7F) as u64) << (7 * i);
            if b < 0x80 {
                return if i + 1 == max && b > last {
                    self.fail()
                } else {
                    v
                };
            }
        }
        self.fail()
    }

    /// Inline: an arc's turns read it (and a dip's speeds), and called it cost more
    /// than it does.
    #[inline(always)]
    fn u16(&mut self) -> u16 {
        self.varint(3, 0x03) as u16
    }

    fn u32(&mut self) -> u32 {
        self.varint(5, 0x0F) as u32
    }

    fn u64(&mut self) -> u64 {
        self.varint(10, 0x01)
    }

    fn i64(&mut self) -> i64 {
        let v = self.u64();
        (v >> 1) as i64 ^ -((v & 1) as i64)
    }

    fn i64s<const N: usize>(&mut self) -> [i64; N] {
        core::array::from_fn(|_| self.i64())
    }

    /// A fixed-width little-endian `u64` (8 bytes).
    fn u64_le(&mut self) -> u64 {
        match self.bytes.get(self.at..self.at + 8) {
            Some(b) => {
                self.at += 8;
                u64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]])
            }
            None => self.fail(),
        }
    }

    /// A fixed-width little-endian `i128` (16 bytes).
    fn i128_le(&mut self) -> i128 {
        let lo = self.u64_le();
        let hi = self.u64_le();
        ((hi as u128) << 64 | lo as u128) as i128
    }

    fn f32(&mut self) -> f32 {
        match self.bytes.get(self.at..self.at + 4) {
            Some(b) => {
                self.at += 4;
                f32::from_le_bytes([b[0], b[1], b[2], b[3]])
            }
            None => self.fail(),
        }
    }

    fn bool(&mut self) -> bool {
        match self.byte() {
            0 => false,
            1 => true,
            _ => self.fail(),
        }
    }

    /// An `Option<Dip>`: postcard's tag byte (0 or 1), then the dip's byte and its
    /// two `u16` varints. Inline: nearly every block has none, one byte.
    #[inline(always)]
    fn dip(&mut self) -> Option<Dip> {
        match self.byte() {
            0 => None,
            1 => Some(Dip {
                at: self.byte(),
                speed: self.u16(),
                after: self.u16(),
            }),
            _ => self.fail(),
        }
    }

    fn plane(&mut self) -> Plane {
        match self.u32() {
            0 => Plane::Xy,
            1 => Plane::Zx,
            2 => Plane::Yz,
            _ => {
                self.fail::<()>();
                Plane::Xy
            }
        }
    }

    fn aux(&mut self) -> Aux {
        match self.u32() {
            0 => Aux::SpindleOff,
            1 => Aux::SpindleCw(self.u32()),
            2 => Aux::SpindleCcw(self.u32()),
            3 => Aux::Mist,
            4 => Aux::Flood,
            5 => Aux::CoolantOff,
            6 => Aux::ToolChange(self.u32()),
            7 => Aux::Pause(self.bool()),
            _ => {
                self.fail::<()>();
                Aux::SpindleOff
            }
        }
    }

    fn motion(&mut self) -> Motion {
        match self.u32() {
            0 => Motion::Rapid,
            1 => Motion::Linear,
            2 => Motion::Arc {
                center: self.i64s(),
                plane: self.plane(),
                clockwise: self.bool(),
                turns: self.u16(),
            },
            3 => Motion::Dwell(self.u32()),
            4 => Motion::Aux(self.aux()),
            5 => Motion::Cubic {
                c1: self.i64s(),
                c2: self.i64s(),
            },
            6 => Motion::Quadratic { c: self.i64s() },
            _ => {
                self.fail::<()>();
                Motion::Rapid
            }
        }
    }

    fn shape(&mut self) -> Shape {
        match self.u32() {
            0 => Shape::Line { unit: self.i64s() },
            1 => Shape::Arc {
                plane: crate::motion::block::Plane::Xy,
                center: [0; 2],
                r0: self.i64(),
                dr: self.i64(),
                phi0: self.u64_le(),
                phi_rate: self.i128_le(),
                r_rate: self.i64(),
                unit: self.i64s(),
            },
            2 => Shape::Point,
            3 => Shape::Spline {
                rate: self.u64_le(),
                dip: self.dip(),
            },
            _ => {
                self.fail::<()>();
                Shape::Point
            }
        }
    }
}

/// Decodes a [`HostMsg::Block`] message (a frame's message bytes) without serde, whose
/// generic code moves the 250-byte message around several times on its way out: `None`
/// when `message` is not a block message (decode it with `postcard::from_bytes`),
/// else the block, or `FrameError::Message` exactly where `postcard::from_bytes`
/// fails (tested).
pub fn decode_block(message: &[u8]) -> Option<Result<PlannedBlock, FrameError>> {
    let mut slot = core::mem::MaybeUninit::uninit();
    decode_block_into(message, &mut slot).map(|r| r.copied())
}

/// Is `message` (a frame's body) a block? Read from its first byte only, without
/// decoding it: the controller skips the decoding of a copy of a block it has.
#[inline(always)]
pub fn is_block(message: &[u8]) -> bool {
    message.first() == Some(&(HOST_MSG_BLOCK as u8))
}

/// [`decode_block`] written field by field into `slot` (the controller's receive path:
/// no temporary of the block, no copy of it); the block, by reference, when it decoded.
pub fn decode_block_into<'a>(
    message: &[u8],
    slot: &'a mut core::mem::MaybeUninit<PlannedBlock>,
) -> Option<Result<&'a PlannedBlock, FrameError>> {
    let mut c = Cursor {
        bytes: message,
        at: 0,
        bad: false,
    };
    if c.u32() != HOST_MSG_BLOCK || c.bad {
        return None;
    }
    Some(planned_into(&mut c, slot))
}

/// The planned block at `c` into `slot`; the block, by reference, when it decoded.
#[inline(always)]
fn planned_into<'a>(
    c: &mut Cursor<'_>,
    slot: &'a mut core::mem::MaybeUninit<PlannedBlock>,
) -> Result<&'a PlannedBlock, FrameError> {
    use core::ptr::addr_of_mut as at;
    let p = slot.as_mut_ptr();
    // SAFETY: every write is to a field of the slot, in bounds and aligned; every field
    // is written (a read that fails yields a default and marks the cursor bad), so the
    // slot is initialised when it is handed out below.
    unsafe {
        let b = at!((*p).block);
        at!((*b).line).write(c.u32());
        at!((*b).motion).write(c.motion());
        at!((*b).target).write(c.i64s());
        at!((*b).feed).write(c.i64());
        at!((*b).tolerance_nm).write(c.u32());
        let q = at!((*p).plan);
        at!((*q).length).write(c.i64());
        at!((*q).shape).write(c.shape());
        at!((*q).v_limit).write(c.f32());
        at!((*q).accel).write(c.f32());
        at!((*q).entry).write(c.f32());
        at!((*q).stop).write(c.bool());
    }
    if c.bad {
        return Err(FrameError::Message);
    }
    // SAFETY: initialised above.
    Ok(unsafe { slot.assume_init_ref() })
}

/// Variant index of `HostMsg::Control` in the message encoding.
const HOST_MSG_CONTROL: u32 = 4;
/// Variant indices of `Control::Jog` and `Control::Probe`.
const CONTROL_JOG: u32 = 5;
const CONTROL_PROBE: u32 = 10;

/// A control command that carries a planned move ([`decode_planned_control_into`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PlannedControl {
    /// `Control::Jog`.
    Jog,
    /// `Control::Probe` with its mode.
    Probe(crate::drive::probe::ProbeMode),
}

/// Decodes a `HostMsg::Control` whose command carries a planned move (`Jog`, `Probe`)
/// without serde, as [`decode_block_into`] decodes a block: `None` when `message` is
/// another message, else its id, which command, and the move in `slot` (or
/// `FrameError::Message` where `postcard::from_bytes` fails).
pub fn decode_planned_control_into<'a>(
    message: &[u8],
    slot: &'a mut core::mem::MaybeUninit<PlannedBlock>,
) -> Option<Result<(u16, PlannedControl, &'a PlannedBlock), FrameError>> {
    let mut c = Cursor {
        bytes: message,
        at: 0,
        bad: false,
    };
    if c.u32() != HOST_MSG_CONTROL || c.bad {
        return None;
    }
    let id = c.u32();
    let kind = c.u32();
    if c.bad || id > u16::MAX as u32 || !(kind == CONTROL_JOG || kind == CONTROL_PROBE) {
        return None;
    }
    let planned = match planned_into(&mut c, slot) {
        Ok(p) => p,
        Err(e) => return Some(Err(e)),
    };
    let what = match kind {
        CONTROL_JOG => PlannedControl::Jog,
        _ => match c.u32() {
            0 => PlannedControl::Probe(crate::drive::probe::ProbeMode::Touch),
            1 => PlannedControl::Probe(crate::drive::probe::ProbeMode::Release),
            _ => return Some(Err(FrameError::Message)),
        },
    };
    if c.bad {
        return Some(Err(FrameError::Message));
    }
    Some(Ok((id as u16, what, planned)))
}
