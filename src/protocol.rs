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
pub const PROTOCOL_VERSION: u16 = 4;
/// Largest unencoded frame body (sequence number, message and CRC), bytes: a planned
/// helix with every field at its widest fits.
pub const MAX_BODY: usize = 384;
/// Largest encoded frame including its delimiter, bytes.
pub const MAX_FRAME: usize = crate::cobs::max_encoded_len(MAX_BODY) + 1;

/// Arc plane: the in-plane axes are XY, ZX or YZ and the helix axis Z, Y or X.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Plane {
    /// G17.
    Xy,
    /// G18.
    Zx,
    /// G19.
    Yz,
}

impl Plane {
    /// Pose indices of the first and second in-plane axes and of the helix axis.
    pub const fn axes(self) -> (usize, usize, usize) {
        match self {
            Plane::Xy => (0, 1, 2),
            Plane::Zx => (2, 0, 1),
            Plane::Yz => (1, 2, 0),
        }
    }
}

/// Auxiliary functions executed in program order (they wait for motion before them).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Aux {
    /// Spindle off (M5).
    SpindleOff,
    /// Spindle clockwise at rpm (M3).
    SpindleCw(u32),
    /// Spindle counter-clockwise at rpm (M4).
    SpindleCcw(u32),
    /// Mist coolant (M7).
    Mist,
    /// Flood coolant (M8).
    Flood,
    /// Coolant off (M9).
    CoolantOff,
    /// Tool change to tool n (M6); the controller holds until resumed.
    ToolChange(u32),
    /// Program pause (M0, or M1 when `true`); the controller holds until resumed.
    Pause(bool),
}

/// What a block does.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Motion {
    /// Rapid positioning at the machine's limits (G0).
    Rapid,
    /// Straight feed move (G1).
    Linear,
    /// Circular or helical feed move (G2/G3) about `center` in `plane`.
    Arc {
        /// Centre, in-plane coordinates (first, second axis of the plane), nm.
        center: [i64; 2],
        /// Plane.
        plane: Plane,
        /// G2 (clockwise seen from the positive helix axis).
        clockwise: bool,
        /// Extra full turns (P − 1).
        turns: u16,
    },
    /// Dwell (G4), ms; `target` must equal the current pose.
    Dwell(u32),
    /// Auxiliary function; `target` must equal the current pose.
    Aux(Aux),
}

/// One canonical block, in absolute workpiece pose (axis units, see
/// [`crate::units`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Block {
    /// NC program line the block came from (1-based; 0 for none).
    pub line: u32,
    /// Motion kind.
    pub motion: Motion,
    /// End pose X Y Z (nm) A B C (n°).
    pub target: [i64; AXES],
    /// Path feed, nm/s along XYZ (or µ°/s when only rotary axes move); ignored for
    /// rapids, dwells and auxiliary functions.
    pub feed: i64,
    /// Largest deviation allowed when blending into the next block, nm (G64 P);
    /// 0 stops exactly at the block's end (G61), `u32::MAX` blends as the limits allow.
    pub tolerance_nm: u32,
}

/// The host's plan of a motion block, made with the whole program in view by the
/// core's own planner ([`crate::planner::plan_into`]) on the host: the geometry, the
/// speed and acceleration limits sampled along the block through the kinematics, and
/// the entry speed of unlimited look-ahead. The controller checks the geometry against
/// the block ([`crate::geometry::Path::from_plan`]) and the target against the joint
/// travel, and never runs faster than the plan nor than it can stop within what it has
/// buffered ([`crate::planner`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Plan {
    /// Path length, nm (n° for a move of rotary axes only).
    pub length: i64,
    /// Geometry.
    pub shape: crate::geometry::Shape,
    /// Hard speed limit along the block, nm/tick.
    pub v_limit: f32,
    /// Acceleration of the block's profile, nm/tick².
    pub accel: f32,
    /// Planned entry speed, nm/tick.
    pub entry: f32,
    /// The block must be entered at rest (exact stop, or a corner not blended).
    pub stop: bool,
}

/// A block with its plan: what the host streams.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PlannedBlock {
    /// The block.
    pub block: Block,
    /// Its plan.
    pub plan: Plan,
}

/// Commands that bypass the block queue. Each is idempotent.
// No allocator in the core: a jog carries its planned move inline.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum Control {
    /// Feed hold: decelerate on the path and stop; position kept.
    Hold,
    /// Resume after a hold, a pause or a tool change.
    Resume,
    /// Stop (decelerating on the path) and drop the queue.
    Abort,
    /// Clear an alarm once its cause is gone; the controller stays still. Clearing
    /// `Unhomed` unlocks the controller at the position it believes it is at.
    AlarmReset,
    /// Feed override, percent (1..=200).
    FeedOverride(u16),
    /// A move the host planned from the controller's pose, from rest to rest: a jog
    /// (its target clipped to the joint travel, [`crate::planner::jog_target`]) or the
    /// move to the home pose of a machine without home switches
    /// ([`crate::planner::plan_move`]). Acted on only when idle with nothing queued, and
    /// only if it starts where the controller stands (checked like any block); the
    /// controller plans nothing itself, so a command never costs more than a block.
    Jog(PlannedBlock),
    /// Home the machine: every joint with a home switch searches it (then its encoder
    /// index where configured), and all joints go to the home pose ([`crate::homing`]).
    /// Allowed when idle or locked after a reset (alarm `Unhomed`). A machine without
    /// home switches goes home by a `Jog` the host plans.
    Home,
    /// Immediate stop: motion ends now, without deceleration, and the controller
    /// enters `Alarm` (cause `Aborted`), position kept.
    Stop,
}

/// Messages from the host to the controller.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum HostMsg {
    /// Opens a session; resets sequence numbering to the frame's `seq + 1`.
    Hello {
        /// The host's [`PROTOCOL_VERSION`].
        version: u16,
        /// Identity ([`crate::store::identity`]) of the machine the host means to run;
        /// the controller refuses to move while it differs from its own.
        machine: u32,
    },
    /// One chunk of a machine configuration ([`crate::store`]); answered by
    /// `ControlAck { id }`, then by `MachineLoaded` or `MachineRefused` once complete.
    Machine {
        /// Host-chosen identifier, as for controls.
        id: u16,
        /// Offset of this chunk in the payload, bytes.
        offset: u16,
        /// Payload length, bytes.
        total: u16,
        /// CRC-32 of the whole payload (the machine's identity).
        crc: u32,
        /// The chunk.
        data: heapless::Vec<u8, { crate::store::CHUNK_BYTES }>,
    },
    /// Queues a planned motion block (sequenced).
    Block(PlannedBlock),
    /// Asks for a [`Status`] now (bypasses the queue).
    StatusRequest,
    /// A control command (bypasses the queue); answered by `ControlAck { id }`. The
    /// host resends it with the same `id` until acknowledged; a repeated `id` is
    /// acknowledged again but not acted on twice.
    Control {
        /// Host-chosen identifier.
        id: u16,
        /// The command.
        cmd: Control,
    },
}

/// Controller state.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum State {
    /// Not moving, queue empty.
    Idle,
    /// Executing blocks.
    Running,
    /// Feed hold, pause or tool change: stopping or stopped on the path.
    Hold,
    /// Homing.
    Homing,
    /// Stopped by a fault; see the alarm.
    Alarm,
    /// Emergency stop input active.
    EStop,
}

/// What raised an alarm.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[non_exhaustive]
pub enum AlarmCause {
    /// A pose outside the machine's reach.
    Unreachable,
    /// A joint would leave its travel (the joints' soft limits: jogs stop at them,
    /// program motion that would cross them raises this).
    JointLimit,
    /// A pose too near a singularity.
    Singularity,
    /// The host aborted the job.
    Aborted,
    /// Emergency stop.
    EStop,
    /// A limit switch tripped.
    LimitSwitch,
    /// A drive reported a fault.
    DriveFault,
    /// Following error beyond its limit.
    FollowingError,
    /// The link went silent while moving.
    LinkLoss,
    /// The firmware watchdog fired.
    Watchdog,
    /// Host and controller disagree about the machine.
    MachineMismatch,
    /// After a reset or a new machine: the controller does not know where the joints
    /// are; it moves again once homed (`Home`) or unlocked (`AlarmReset`).
    Unhomed,
    /// Homing found no switch (or no index pulse) within the joint's travel.
    HomingFailed,
}

/// An alarm: its cause, the joint concerned (`NO_JOINT` if none) and the NC line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Alarm {
    /// Cause.
    pub cause: AlarmCause,
    /// Joint index (0-based), or [`NO_JOINT`].
    pub joint: u8,
    /// NC line executing when it was raised (0 for none).
    pub line: u32,
}

/// `Alarm::joint` when no joint is concerned.
pub const NO_JOINT: u8 = u8::MAX;

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
    /// The block is malformed (e.g. an arc whose end is off its circle).
    BadBlock,
    /// Host and controller disagree about the machine: send it first.
    MachineMismatch,
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
    /// Path speed now, nm/s (µ°/s for rotary-only moves).
    pub speed: i64,
    /// Motion buffered in the queue and the executing block, ms.
    pub buffered_ms: u32,
    /// Free block-queue slots.
    pub free_slots: u16,
    /// Feed override, percent.
    pub feed_override: u16,
    /// Active alarm, if any.
    pub alarm: Option<Alarm>,
    /// Every joint with a home switch has been homed since the last reset.
    pub homed: bool,
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
        /// Identity of the controller's machine configuration.
        machine: u32,
    },
    /// A machine configuration sent by the host was validated, adopted (the
    /// controller restarts at the new machine's home pose) and stored.
    MachineLoaded {
        /// Its identity.
        machine: u32,
    },
    /// A machine configuration sent by the host was refused.
    MachineRefused {
        /// Why.
        error: crate::store::StoreError,
    },
    /// Every block up to and including `seq` was accepted.
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
    /// A control command was received (and acted on, the first time).
    ControlAck {
        /// The command's id.
        id: u16,
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
        HostMsg::Block(PlannedBlock {
            block: Block {
                line: 12,
                motion: Motion::Arc {
                    center: [i64::MIN, i64::MAX],
                    plane: Plane::Zx,
                    clockwise: true,
                    turns: u16::MAX,
                },
                target: [10_000_000, -5, i64::MAX, i64::MIN, 0, 1],
                feed: 16_666_666,
                tolerance_nm: u32::MAX,
            },
            // Every field at its widest: the largest block message there is.
            plan: Plan {
                length: i64::MIN,
                shape: crate::geometry::Shape::Arc {
                    plane: Plane::Zx,
                    center: [i64::MIN, i64::MAX],
                    r0: i64::MIN,
                    dr: i64::MIN,
                    phi0: u64::MAX,
                    sweep: i128::MIN,
                    phi_rate: i128::MIN,
                    r_rate: i64::MIN,
                    unit: [i64::MIN; AXES],
                },
                v_limit: f32::MAX,
                accel: f32::MIN,
                entry: f32::INFINITY,
                stop: true,
            },
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
            speed: i64::MIN,
            buffered_ms: u32::MAX,
            free_slots: u16::MAX,
            feed_override: u16::MAX,
            alarm: Some(Alarm {
                cause: AlarmCause::FollowingError,
                joint: 255,
                line: u32::MAX,
            }),
            homed: true,
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
