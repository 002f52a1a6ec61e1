//! The wire protocol between `nc-send` and the controller, defined once for both sides.
//!
//! A frame on the byte stream is `COBS(W(seq_le16 ‖ postcard(message) ‖ crc32_le(seq ‖
//! message))) ‖ 0x00`, where W XORs every byte with 0xA5 ([`WHITEN`]). Postcard
//! writes zeros, small numbers and flags as 0x00 and nearby bytes, and round
//! coordinates (whole millimetres in nm are multiples of 64) start their varints with
//! 0x80: left as they are, or with only the top bit flipped, a block message has a
//! zero every few bytes, and each zero starts a COBS block (a code byte and its
//! bookkeeping on the controller's receive path). With 0xA5 zero bytes are rare and
//! COBS blocks long, which the controller decodes four bytes at a time.
//!
//! The sequence number orders host messages: the controller accepts exactly the next
//! one, acknowledges cumulatively (`Ack { seq }` covers every message up to `seq`),
//! re-acknowledges a duplicate without acting on it, and answers a gap or a damaged
//! frame with a `Nak` naming the sequence number it expects. Flow control is
//! by credits: every `Ack` carries the free block-queue slots and the milliseconds of
//! motion already buffered, and the host never has more blocks in flight than slots.

pub mod cobs;
pub mod crc;
mod decode;
mod frame;
mod messages;
mod reader;
pub mod ring;
pub mod store;
#[cfg(test)]
mod tests;

pub use decode::{
    decode_block, decode_block_into, decode_planned_control_into, is_block, PlannedControl,
};
pub use frame::{
    decode_body, decode_frame, encode_ack, encode_frame, encode_frame_with, encode_record,
    encode_status, FrameError, WHITEN,
};
pub use messages::*;
pub use reader::{Frame, FrameDecoder, FrameReader, Pushed};
