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

use crate::config::{AXES, MAX_JOINTS};
use serde::{Deserialize, Serialize};

/// Shape of a path, as the wire carries it: computed by the host
/// ([`crate::geometry::Path::new`]) and sent with each block; the controller checks it
/// against the block ([`crate::geometry::Path::from_plan`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Shape {
    /// Straight line; `unit[i]` = Δᵢ/S in Q20.44.
    Line {
        /// Direction per axis, Q20.44.
        unit: [i64; AXES],
    },
    /// Arc or helix.
    Arc {
        /// Plane. Not sent: the block has it ([`crate::geometry::Path::from_plan`] takes
        /// it from there).
        #[serde(skip)]
        plane: Plane,
        /// Centre (first, second in-plane axis), nm. Not sent, as `plane`.
        #[serde(skip)]
        center: [i64; 2],
        /// Start radius, nm.
        r0: i64,
        /// End radius minus start radius, nm.
        dr: i64,
        /// Start angle, turns Q64 (wrapping). Sent as 8 bytes (its varint would be 10,
        /// and slower to read).
        #[serde(with = "fixed_width::u64_le")]
        phi0: u64,
        /// Angle per path distance: sweep·2¹⁶ / length (sweep: the signed angle, turns
        /// Q64, more than one turn for multi-turn arcs), so that φ(s) = φ₀ + (k·s) ≫ 32
        /// for s in nm Q16 (no division per tick). The sweep itself is not stored: it
        /// is (k·length) ≫ 16 to within length/2¹⁶ + 1 units of 2⁻⁶⁴ turn.
        #[serde(with = "fixed_width::i128_le")]
        phi_rate: i128,
        /// Radius change per path distance: (dr·2⁴⁰) / length, used as (k·s) ≫ 56 (fine
        /// enough that the radius lands within a nanometre of the end on any arc).
        r_rate: i64,
        /// Per-axis direction of the linear part (helix axis and A B C), Q20.44;
        /// in-plane entries are 0.
        unit: [i64; AXES],
    },
    /// No motion (dwell, auxiliary function, zero-length move).
    Point,
    /// Cubic or quadratic spline ([`Motion::Cubic`], [`Motion::Quadratic`]): the
    /// curve itself follows from the block; the parameter advances linearly with path
    /// distance, u = s / length, where `length` is the largest |dP/du| over X Y Z (so
    /// the tool never moves faster than the path speed).
    Spline {
        /// ⌊2⁶⁴ / length⌋, so that u (Q32) = (s·rate) ≫ 48 for s in nm Q16 (no
        /// division per tick). Sent as 8 bytes.
        #[serde(with = "fixed_width::u64_le")]
        rate: u64,
    },
}

/// Little-endian fixed-width encodings for fields whose varint is long (random bits):
/// cheaper for the controller to read than their varints.
mod fixed_width {
    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    pub mod u64_le {
        use super::*;
        pub fn serialize<S: Serializer>(v: &u64, s: S) -> Result<S::Ok, S::Error> {
            v.to_le_bytes().serialize(s)
        }
        pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<u64, D::Error> {
            <[u8; 8]>::deserialize(d).map(u64::from_le_bytes)
        }
    }

    pub mod i128_le {
        use super::*;
        pub fn serialize<S: Serializer>(v: &i128, s: S) -> Result<S::Ok, S::Error> {
            v.to_le_bytes().serialize(s)
        }
        pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<i128, D::Error> {
            <[u8; 16]>::deserialize(d).map(i128::from_le_bytes)
        }
    }
}

/// Protocol version, exchanged in the handshake; both sides must agree.
pub const PROTOCOL_VERSION: u16 = 11;
/// Largest unencoded frame body (sequence number, message and CRC), bytes: a planned
/// helix with every field at its widest fits.
pub const MAX_BODY: usize = 384;
/// Largest encoded frame including its delimiter, bytes.
pub const MAX_FRAME: usize = crate::cobs::max_encoded_len(MAX_BODY) + 1;

/// Arc plane: the in-plane axes are XY, ZX or YZ and the helix axis Z, Y or X.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum Plane {
    /// G17.
    #[default]
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
    /// Cubic Bézier feed move (G5, and runs of short moves the host merged into one
    /// curve): from the start through the control points start + `c1` and `target` +
    /// `c2` to `target` (axis units; offsets, so that they are short on the wire).
    Cubic {
        /// First control point minus the start.
        c1: [i64; AXES],
        /// Second control point minus the target.
        c2: [i64; AXES],
    },
    /// Quadratic (parabolic) Bézier feed move (G5.1): from the start through the
    /// control point start + `c` to `target`.
    Quadratic {
        /// Control point minus the start.
        c: [i64; AXES],
    },
}

impl Motion {
    /// Does the controller keep a bend for this motion (arcs and splines: their
    /// curved part is held apart from the queue's line-sized slots)?
    pub const fn curved(&self) -> bool {
        matches!(
            self,
            Motion::Arc { .. } | Motion::Cubic { .. } | Motion::Quadratic { .. }
        )
    }
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
    pub shape: Shape,
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
    /// Every block of the job has been sent (and acknowledged): the job is complete
    /// on the controller. Until then a host that goes silent for the link-loss time
    /// leaves an unfinished job, an alarm (`LinkLoss`) even when the queue has run dry
    /// at rest, so that an interrupted job is never taken for a finished one.
    EndJob,
    /// The job now starting is a streamed program: when its host is silent, the
    /// controller runs out what is queued and waits for more (`State::Starved`)
    /// instead of raising `LinkLoss` after [`crate::controller::LINK_LOSS_TICKS`];
    /// only after `host_timeout_ms` of silence does it hold the job for take-over
    /// (a controlled stop if still moving, alarm `HostTimeout`, job kept). 0: the
    /// short watch (MDI, and any job of a host that does not send this). Valid until
    /// the job ends (protocol 10).
    ///
    /// `mark` names the program and where the job starts in it (protocol 11): the
    /// controller counts the blocks it accepts from there and reports the mark with a
    /// held job (`HelloAck::mark`), so that a new host can send the rest. A `BeginJob`
    /// whose mark continues a held job (same program, `first_block` the next block
    /// the controller never received) adopts that job for the new host, which then
    /// streams the rest of it.
    BeginJob {
        /// Host silence after which the job is held, ms
        /// ([`crate::controller::MIN_HOST_TIMEOUT_MS`] ..=
        /// [`crate::controller::MAX_HOST_TIMEOUT_MS`], clamped into that range).
        host_timeout_ms: u32,
        /// The program and the job's first block in it (`program` 0: none).
        mark: JobMark,
    },
}

/// A streamed program's identity and how far the controller has received it
/// (`Control::BeginJob`, `HelloAck::mark`; protocol 11). Kept by the controller with
/// its job: 24 bytes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct JobMark {
    /// A 64-bit hash of the program and of what shaped its blocks (0: none).
    pub program: u64,
    /// Index in the program of the next block the controller has not received (in
    /// `BeginJob`: the job's first block).
    pub next_block: u32,
    /// The program's blocks.
    pub total_blocks: u32,
    /// NC line of the last block received (in `BeginJob`: 0).
    pub last_line: u32,
    /// The program's last NC line.
    pub total_lines: u32,
}

/// Messages from the host to the controller.
pub type HostMsg = HostMsgOf<PlannedBlock>;

/// [`HostMsg`] with the payload of its `Block` variant as a parameter: the controller
/// decodes blocks by hand ([`decode_block`]) and every other message as
/// `HostMsgOf<NotBlock>`, which leaves serde's code for blocks out of the firmware.
/// The encoding is the same (one definition).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum HostMsgOf<B> {
    /// Opens a session; resets sequence numbering to the frame's `seq + 1`.
    Hello {
        /// The host's [`PROTOCOL_VERSION`].
        version: u16,
        /// Identity ([`crate::store::identity`]) of the machine the host means to run;
        /// the controller refuses to move while it differs from its own.
        machine: u32,
        /// Who the host is (`nc-send` sends its process id): named to a later host
        /// that finds this one's job held ([`HeldJob::host`]).
        host: u32,
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
    Block(B),
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

/// No block: the `Block` payload of the messages the controller decodes with serde
/// (it decodes blocks by hand); a block message fails to decode as one.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum NotBlock {}

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
    /// A streamed job whose queue ran dry before the host said it was complete
    /// (`Control::EndJob`): stopped on the path at the end of what was queued, as
    /// planned, waiting for blocks; it runs on as soon as they come (protocol 10).
    Starved,
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
    /// The per-period guard: a joint's setpoint would have moved more in one period
    /// than its maximum velocity allows (plus [`crate::controller::GUARD_MARGIN_PERCENT`]),
    /// or its drive could not take the steps within its timing. The setpoint is not
    /// applied: the controller's position stays the drives'.
    JointSpeed,
    /// The host of a streamed job was silent longer than the job's host timeout
    /// (`Control::BeginJob`): the job is held (state `Hold`, queue kept) for its host
    /// or a new one to resume or abort (protocol 10).
    HostTimeout,
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
    /// An earlier session's job is held ([`HeldJob`]): `Resume` or `Abort` it first.
    JobHeld,
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
    /// Where each joint's actuator is, steps or encoder counts from the joint's zero
    /// (its homing offset taken off): a servo's encoder as last read, a stepper's steps
    /// emitted (open loop). The host scales them to axis units with the machine file.
    pub measured: [i64; MAX_JOINTS],
    /// Path speed now, nm/s (µ°/s for rotary-only moves).
    pub speed: i64,
    /// Motion buffered in the queue and the executing block, ms.
    pub buffered_ms: u32,
    /// Free block-queue slots.
    pub free_slots: u16,
    /// How many of them may hold arcs (arcs keep their in-plane part apart, in a
    /// ring of [`crate::planner::BEND_CAPACITY`]).
    pub free_bends: u16,
    /// Feed override, percent.
    pub feed_override: u16,
    /// Active alarm, if any.
    pub alarm: Option<Alarm>,
    /// Every joint with a home switch has been homed since the last reset.
    pub homed: bool,
    /// The job queued or held is an earlier session's, whose host has gone
    /// ([`HeldJob`]): blocks are refused (`JobHeld`) until `Resume` adopts it or
    /// `Abort` drops it.
    pub orphan: bool,
}

/// An unfinished job of an earlier session, reported to the host that opens a new
/// one (`HelloAck`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct HeldJob {
    /// The earlier host's `Hello::host`.
    pub host: u32,
    /// NC line where the job stands.
    pub line: u32,
    /// Blocks it completed.
    pub done: u32,
    /// Blocks still queued (the executing one included).
    pub queued: u16,
    /// The controller's state then.
    pub state: State,
}

/// Messages from the controller to the host.
// A status is the largest message by far, and the one sent most: boxing it is not an
// option without an allocator, and the others are built in place.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum CtrlMsg {
    /// Answers `Hello`.
    HelloAck {
        /// The controller's [`PROTOCOL_VERSION`].
        version: u16,
        /// Block-queue capacity (initial credits).
        queue_capacity: u16,
        /// An earlier session's unfinished job, if one is queued or held.
        held: Option<HeldJob>,
        /// The held job's program and how far it was received (`Control::BeginJob`),
        /// if it was streamed with one (protocol 11).
        mark: Option<JobMark>,
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
        /// How many of them may hold arcs.
        free_bends: u16,
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
    Ok(seal(&body[..2 + used], out))
}

/// The byte mask of W in the module doc (W is its own inverse).
pub const WHITEN: u8 = 0xA5;

/// Completes a frame: the COBS encoding of `data` (sequence number and message, at
/// most `MAX_BODY - 4` bytes) and of its CRC, each byte flipped ([`WHITEN`]), then the
/// delimiter, written into `out` in one pass; returns its length.
fn seal(data: &[u8], out: &mut [u8; MAX_FRAME]) -> usize {
    let mut crc = crate::crc::INIT;
    let (mut code_at, mut at) = (0, 1);
    if data.len() + 4 < 0xFE {
        // No run of 254 non-zero bytes fits: only zeros end a block.
        let mut put = |b: u8| {
            let b = b ^ WHITEN;
            if b == 0 {
                out[code_at] = (at - code_at) as u8;
                code_at = at;
            } else {
                out[at] = b;
            }
            at += 1;
        };
        for &b in data {
            crc = crate::crc::update(crc, b);
            put(b);
        }
        for b in (!crc).to_le_bytes() {
            put(b);
        }
    } else {
        let mut put = |b: u8| {
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
        };
        for &b in data {
            crc = crate::crc::update(crc, b);
            put(b);
        }
        for b in (!crc).to_le_bytes() {
            put(b);
        }
    }
    out[code_at] = (at - code_at) as u8;
    out[at] = 0;
    at + 1
}

/// Variant indices of [`CtrlMsg`] in the message encoding.
const CTRL_MSG_ACK: u8 = 3;
const CTRL_MSG_STATUS: u8 = 6;

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

    fn u32(&mut self, mut v: u32) {
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
    seal(&body[..n], out)
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
    const WIDEST: usize =
        2 + 1 + 1 + 5 + 5 + 10 * (1 + AXES + 2 * MAX_JOINTS + 1) + 5 + 3 + 3 + 3 + 8 + 1 + 1;
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
    let n = w.len;
    seal(&body[..n], out)
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
    let n = crate::cobs::decode(encoded, body).map_err(|_| FrameError::Cobs)?;
    for b in &mut body[..n] {
        *b ^= WHITEN;
    }
    if n < 6 {
        return Err(FrameError::Short);
    }
    let (data, crc) = body[..n].split_at(n - 4);
    let want = u32::from_le_bytes([crc[0], crc[1], crc[2], crc[3]]);
    if crate::crc::crc32(data) != want {
        return Err(FrameError::Crc);
    }
    let seq = u16::from_le_bytes([data[0], data[1]]);
    Ok((seq, &body[2..n - 4]))
}

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
        use Shape;
        match self.u32() {
            0 => Shape::Line { unit: self.i64s() },
            1 => Shape::Arc {
                plane: crate::protocol::Plane::Xy,
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

/// [`decode_block`] written field by field into `slot` (the controller's receive path:
/// no temporary of the block, no copy of it); the block, by reference, when it decoded.
pub fn decode_block_into<'a>(
    message: &[u8],
    slot: &'a mut core::mem::MaybeUninit<PlannedBlock>,
) -> Option<Result<&'a PlannedBlock, FrameError>> {
    use core::ptr::addr_of_mut as at;
    let mut c = Cursor {
        bytes: message,
        at: 0,
        bad: false,
    };
    if c.u32() != HOST_MSG_BLOCK || c.bad {
        return None;
    }
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
        return Some(Err(FrameError::Message));
    }
    // SAFETY: initialised above.
    Some(Ok(unsafe { slot.assume_init_ref() }))
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
    /// CRC register over the body so far ([`crate::crc::update`]).
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
            crc: crate::crc::INIT,
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
                        crc = crate::crc::update(crc, WHITEN);
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
                crc = crate::crc::update_word(crc, w);
                n += 4;
            }
            for (d, &b) in dst[n..].iter_mut().zip(&src[n..]) {
                if b == 0 {
                    break;
                }
                let b = b ^ WHITEN;
                *d = b;
                crc = crate::crc::update(crc, b);
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
        (self.len, self.left, self.zero, self.crc) = (0, 0, false, crate::crc::INIT);
        (self.started, self.overflow) = (false, false);
        let result = if overflow || left != 0 {
            Err(FrameError::Cobs)
        } else if len < 6 {
            Err(FrameError::Short)
        } else if crc != crate::crc::RESIDUE {
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
                shape: Shape::Arc {
                    // Not sent (the block has them): they decode as the defaults.
                    plane: Plane::Xy,
                    center: [0, 0],
                    r0: i64::MIN,
                    dr: i64::MIN,
                    phi0: u64::MAX,
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

    /// What [`FrameReader`] then [`decode_body`] make of `stream`: per frame, its
    /// sequence number and message bytes, or `None` when refused.
    fn read_two_pass(stream: &[u8]) -> Vec<Option<(u16, Vec<u8>)>> {
        let mut reader = FrameReader::new();
        let mut out = Vec::new();
        for &b in stream {
            match reader.push(b) {
                Pushed::Pending => {}
                Pushed::Overlong => out.push(None),
                Pushed::Frame(f) => {
                    let mut body = [0u8; MAX_BODY];
                    out.push(decode_body(f, &mut body).ok().map(|(s, m)| (s, m.to_vec())));
                }
            }
        }
        out
    }

    /// What [`FrameDecoder`] makes of `stream` fed in pieces of `chunk` bytes.
    fn read_one_pass(stream: &[u8], chunk: usize) -> Vec<Option<(u16, Vec<u8>)>> {
        let mut dec = FrameDecoder::new();
        let mut out = Vec::new();
        for piece in stream.chunks(chunk.max(1)) {
            let mut rest = piece;
            while !rest.is_empty() {
                let (n, frame) = dec.feed(rest);
                rest = &rest[n..];
                if let Some(f) = frame {
                    out.push(f.ok().map(|(s, m)| (s, m.to_vec())));
                }
            }
        }
        out
    }

    /// A frame of `message` bytes with sequence number `seq`, delimiter included.
    fn raw_frame(seq: u16, message: &[u8]) -> Vec<u8> {
        let mut body = seq.to_le_bytes().to_vec();
        body.extend_from_slice(message);
        body.extend_from_slice(&crate::crc::crc32(&body).to_le_bytes());
        body.iter_mut().for_each(|b| *b ^= WHITEN);
        let mut enc = vec![0u8; crate::cobs::max_encoded_len(body.len())];
        let n = crate::cobs::encode(&body, &mut enc).unwrap();
        enc.truncate(n);
        enc.push(0);
        enc
    }

    #[test]
    fn the_one_pass_decoder_agrees_with_the_reader_on_streams_of_damaged_frames() {
        let mut x = 0x9E37_79B9u32;
        let mut rnd = move |n: u32| {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            x % n
        };
        let (mut frames, mut refused) = (0, 0);
        for _ in 0..400 {
            let mut stream = Vec::new();
            for _ in 0..rnd(12) + 1 {
                let len = match rnd(8) {
                    0 => rnd(4) as usize,
                    1 => MAX_BODY - 6 + rnd(5) as usize, // at and past the limit
                    2 => 250 + rnd(10) as usize,         // around a 254-byte COBS block
                    _ => rnd(200) as usize,
                };
                // One byte in `every` is a zero (none with 0: runs of 254 and more).
                let every = [0, 2, 4, 40][rnd(4) as usize];
                let message: Vec<u8> = (0..len)
                    .map(|_| {
                        if every > 0 && rnd(every) == 0 {
                            0
                        } else {
                            rnd(255) as u8 + 1
                        }
                    })
                    .collect();
                let mut f = raw_frame(rnd(65536) as u16, &message);
                match rnd(10) {
                    0 => {
                        let i = rnd(f.len() as u32) as usize;
                        f[i] ^= 1 << rnd(8); // may become or stop being a delimiter
                    }
                    1 => f.truncate(rnd(f.len() as u32) as usize), // runs into the next
                    2 => f.insert(0, 0),                           // an empty frame
                    3 => f = (0..rnd(500)).map(|_| rnd(255) as u8 + 1).collect(), // garbage
                    4 => f.splice(0..0, vec![0xFF; 300]).for_each(drop), // overlong
                    _ => {}
                }
                stream.extend(f);
            }
            let want = read_two_pass(&stream);
            frames += want.iter().filter(|f| f.is_some()).count();
            refused += want.iter().filter(|f| f.is_none()).count();
            for chunk in [1, 7, 64, stream.len()] {
                assert_eq!(read_one_pass(&stream, chunk), want, "stream {stream:02x?}");
            }
        }
        assert!(
            frames > 1000 && refused > 500,
            "{frames} good, {refused} refused"
        );
    }

    /// `decode_block`, then `HostMsgOf<NotBlock>` for what is not a block, against
    /// `postcard::from_bytes::<HostMsg>` on `message`.
    fn check_block_decoder(message: &[u8]) -> bool {
        let by_serde = postcard::from_bytes::<HostMsg>(message);
        match (decode_block(message), by_serde) {
            (None, Ok(HostMsg::Block(_))) => panic!("a block missed: {message:02x?}"),
            (None, want) => {
                let got = postcard::from_bytes::<HostMsgOf<NotBlock>>(message);
                let (mut a, mut b) = ([0u8; MAX_BODY], [0u8; MAX_BODY]);
                match (got, want) {
                    (Ok(got), Ok(want)) => assert_eq!(
                        postcard::to_slice(&got, &mut a).unwrap(),
                        postcard::to_slice(&want, &mut b).unwrap(),
                        "{message:02x?}"
                    ),
                    (Err(_), Err(_)) => {}
                    (got, want) => panic!("{message:02x?}: decoded {got:?}, postcard {want:?}"),
                }
                false
            }
            (Some(Err(_)), Err(_)) => false,
            (Some(Ok(got)), Ok(HostMsg::Block(want))) => {
                // Compared through their encoding: the same bits (NaNs included).
                let (mut a, mut b) = ([0u8; MAX_BODY], [0u8; MAX_BODY]);
                assert_eq!(
                    postcard::to_slice(&got, &mut a).unwrap(),
                    postcard::to_slice(&want, &mut b).unwrap(),
                    "{message:02x?}"
                );
                true
            }
            (got, want) => panic!("{message:02x?}: decoded {got:?}, postcard {want:?}"),
        }
    }

    #[test]
    fn blocks_decode_by_hand_exactly_as_postcard_decodes_them() {
        let mut x = 0x2545_F491u32;
        let mut rnd = move |n: u32| {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            x % n
        };
        let wide = |r: &mut dyn FnMut(u32) -> u32| -> i64 {
            let v = ((r(1 << 16) as i64) << 48) ^ ((r(1 << 24) as i64) << 24) ^ r(1 << 24) as i64;
            v >> r(64)
        };
        let mut decoded = 0;
        for k in 0..3000 {
            let mut w = || wide(&mut rnd);
            let motion = match k % 9 {
                0 => Motion::Rapid,
                1 => Motion::Dwell(w() as u32),
                2 => Motion::Aux(Aux::Pause(k % 2 == 0)),
                3 => Motion::Aux(Aux::SpindleCcw(w() as u32)),
                4 | 5 => Motion::Arc {
                    center: [w(), w()],
                    plane: [Plane::Xy, Plane::Zx, Plane::Yz][k % 3],
                    clockwise: k % 2 == 1,
                    turns: w() as u16,
                },
                6 => Motion::Cubic {
                    c1: [w(), w(), w(), w(), w(), w()],
                    c2: [w(), w(), w(), w(), w(), w()],
                },
                7 if k % 2 == 0 => Motion::Quadratic {
                    c: [w(), w(), w(), w(), w(), w()],
                },
                _ => Motion::Linear,
            };
            let shape = match k % 7 {
                5 => Shape::Spline { rate: w() as u64 },
                0 => Shape::Point,
                1 | 2 => Shape::Arc {
                    plane: [Plane::Xy, Plane::Zx, Plane::Yz][k % 3],
                    center: [w(), w()],
                    r0: w(),
                    dr: w(),
                    phi0: w() as u64,
                    phi_rate: ((w() as i128) << 64) ^ w() as i128,
                    r_rate: w(),
                    unit: [w(), w(), w(), w(), w(), w()],
                },
                _ => Shape::Line {
                    unit: [w(), w(), w(), w(), w(), w()],
                },
            };
            let msg = HostMsg::Block(PlannedBlock {
                block: Block {
                    line: w() as u32,
                    motion,
                    target: [w(), w(), w(), w(), w(), w()],
                    feed: w(),
                    tolerance_nm: w() as u32,
                },
                plan: Plan {
                    length: w(),
                    shape,
                    v_limit: f32::from_bits(w() as u32),
                    accel: w() as f32,
                    entry: 1.5,
                    stop: k % 2 == 0,
                },
            });
            let mut buf = [0u8; MAX_BODY];
            let n = postcard::to_slice(&msg, &mut buf).unwrap().len();
            let good = &buf[..n];
            assert!(check_block_decoder(good));
            // Cut short anywhere, with trailing bytes, and damaged.
            for cut in 0..n {
                check_block_decoder(&good[..cut]);
            }
            let mut longer = good.to_vec();
            longer.extend([0xFF, 0x00]);
            assert!(check_block_decoder(&longer));
            for _ in 0..40 {
                let mut bad = good.to_vec();
                for _ in 0..rnd(3) + 1 {
                    let i = rnd(n as u32) as usize;
                    match rnd(6) {
                        0 => bad[i] = 0xFF,
                        1 => bad[i] = 0x80,
                        2 => bad.insert(i, 0x80), // a longer (non-canonical) varint
                        3 => bad[i] = rnd(4) as u8,
                        _ => bad[i] ^= 1 << rnd(8),
                    }
                }
                decoded += check_block_decoder(&bad) as u32;
            }
        }
        // Every value of every byte of the widest block there is (varints at their
        // longest, where postcard checks the last byte's bits).
        let mut buf = [0u8; MAX_BODY];
        let good = postcard::to_slice(&sample_block(), &mut buf)
            .unwrap()
            .to_vec();
        for i in 0..good.len() {
            for v in 0..=255 {
                let mut m = good.clone();
                m[i] = v;
                check_block_decoder(&m);
            }
        }
        // Other messages are left to postcard, as `HostMsgOf<NotBlock>`.
        for m in [
            HostMsg::StatusRequest,
            HostMsg::Control {
                id: 2,
                cmd: Control::FeedOverride(7),
            },
            HostMsg::Control {
                id: 4,
                cmd: match sample_block() {
                    HostMsg::Block(b) => Control::Jog(b),
                    _ => unreachable!(),
                },
            },
            HostMsg::Hello {
                version: PROTOCOL_VERSION,
                machine: 0xDEAD_BEEF,
                host: 1,
            },
            HostMsg::Machine {
                id: 3,
                offset: 64,
                total: 300,
                crc: 9,
                data: heapless::Vec::from_slice(&[1, 0, 2]).unwrap(),
            },
        ] {
            let mut buf = [0u8; MAX_BODY];
            let good = postcard::to_slice(&m, &mut buf).unwrap().to_vec();
            assert!(decode_block(&good).is_none());
            let got: HostMsgOf<NotBlock> = postcard::from_bytes(&good).unwrap();
            assert_eq!(format!("{got:?}"), format!("{m:?}"));
            for i in 0..good.len() {
                for v in 0..=255 {
                    let mut m = good.clone();
                    m[i] = v;
                    check_block_decoder(&m);
                }
            }
        }
        assert!(decoded > 10_000, "{decoded} damaged messages still decoded");
    }

    #[test]
    fn acks_and_statuses_encode_by_hand_exactly_as_postcard_encodes_them() {
        let mut x = 0x1357_9BDFu32;
        let mut rnd = move |n: u32| {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            x % n
        };
        let mut wide = || {
            let v =
                ((rnd(1 << 16) as i64) << 48) ^ ((rnd(1 << 24) as i64) << 24) ^ rnd(1 << 24) as i64;
            v >> rnd(64)
        };
        let (mut body, mut want, mut got) = ([0u8; MAX_BODY], [0u8; MAX_FRAME], [0u8; MAX_FRAME]);
        let causes = [
            AlarmCause::Unreachable,
            AlarmCause::JointLimit,
            AlarmCause::LinkLoss,
            AlarmCause::HomingFailed,
            AlarmCause::JointSpeed,
        ];
        let states = [State::Idle, State::Running, State::Hold, State::EStop];
        for k in 0..5000usize {
            let seq = wide() as u16;
            let (acked, free, bends, ms) =
                (wide() as u16, wide() as u16, wide() as u16, wide() as u32);
            let msg = CtrlMsg::Ack {
                seq: acked,
                free_slots: free,
                free_bends: bends,
                buffered_ms: ms,
            };
            let n = encode_frame(seq, &msg, &mut want).unwrap();
            assert_eq!(
                n,
                encode_ack(seq, acked, free, bends, ms, &mut body, &mut got)
            );
            assert_eq!(want[..n], got[..n], "{msg:?}");
            let s = Status {
                state: states[k % 4],
                line: wide() as u32,
                blocks_done: wide() as u32,
                motion_ticks: wide() as u64,
                pose: core::array::from_fn(|_| wide()),
                joints: core::array::from_fn(|_| wide()),
                measured: core::array::from_fn(|_| wide()),
                speed: wide(),
                buffered_ms: wide() as u32,
                free_slots: wide() as u16,
                free_bends: wide() as u16,
                feed_override: wide() as u16,
                alarm: (k % 3 != 0).then(|| Alarm {
                    cause: causes[k % 4],
                    joint: wide() as u8,
                    line: wide() as u32,
                }),
                homed: k % 2 == 0,
                orphan: k % 5 == 0,
            };
            let msg = CtrlMsg::Status(s.clone());
            let n = encode_frame(seq, &msg, &mut want).unwrap();
            assert_eq!(n, encode_status(seq, &s, &mut body, &mut got));
            assert_eq!(want[..n], got[..n], "{msg:?}");
        }
    }

    #[test]
    fn a_sealed_frame_is_the_cobs_encoding_of_its_body_and_crc() {
        let mut x = 0x0BAD_F00Du32;
        let mut rnd = move |n: u32| {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            x % n
        };
        for len in 0..=MAX_BODY - 4 {
            for every in [0, 2, 40] {
                // One byte in `every` is a zero once flipped (none with 0: runs of 254
                // and more).
                let data: Vec<u8> = (0..len)
                    .map(|_| {
                        if every > 0 && rnd(every) == 0 {
                            WHITEN
                        } else {
                            (rnd(255) as u8 + 1) ^ WHITEN
                        }
                    })
                    .collect();
                let mut framed = data.clone();
                framed.extend_from_slice(&crate::crc::crc32(&data).to_le_bytes());
                framed.iter_mut().for_each(|b| *b ^= WHITEN);
                let mut want = vec![0u8; crate::cobs::max_encoded_len(framed.len())];
                let m = crate::cobs::encode(&framed, &mut want).unwrap();
                let mut out = [0u8; MAX_FRAME];
                let n = seal(&data, &mut out);
                assert_eq!(out[..n - 1], want[..m], "{len} bytes");
                assert_eq!(out[n - 1], 0);
            }
        }
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
            measured: [i64::MIN; MAX_JOINTS],
            speed: i64::MIN,
            buffered_ms: u32::MAX,
            free_slots: u16::MAX,
            free_bends: u16::MAX,
            feed_override: u16::MAX,
            alarm: Some(Alarm {
                cause: AlarmCause::FollowingError,
                joint: 255,
                line: u32::MAX,
            }),
            homed: true,
            orphan: true,
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
