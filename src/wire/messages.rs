//! The messages: the host's (`HostMsg`, `Control`, `JobMark`) and the controller's
//! (`CtrlMsg`, `Status`, `State`, `Alarm`, `HeldJob`), the protocol version and the
//! frame size bounds.

use crate::config::{AXES, MAX_JOINTS};
use crate::drive::probe::{ProbeMode, ProbeResult};
use crate::drive::recorder::REPLY_HEADER;
use crate::motion::block::PlannedBlock;
use serde::{Deserialize, Serialize};

/// Protocol version, exchanged in the handshake; both sides must agree.
pub const PROTOCOL_VERSION: u16 = 14;
/// Largest unencoded frame body (sequence number, message and CRC), bytes: a planned
/// helix with every field at its widest fits.
pub const MAX_BODY: usize = 384;
/// Largest encoded frame including its delimiter, bytes.
pub const MAX_FRAME: usize = crate::wire::cobs::max_encoded_len(MAX_BODY) + 1;

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
    /// (its target clipped to the joint travel, [`crate::motion::planner::jog_target`]) or the
    /// move to the home pose of a machine without home switches
    /// ([`crate::motion::planner::plan_move`]). Acted on only when idle with nothing queued, and
    /// only if it starts where the controller stands (checked like any block); the
    /// controller plans nothing itself, so a command never costs more than a block.
    Jog(PlannedBlock),
    /// Home the machine: every joint with a home switch searches it (then its encoder
    /// index where configured), and all joints go to the home pose ([`crate::drive::homing`]).
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
    /// A probing move (G38.2–G38.5; protocol 12): a move the host planned from the
    /// controller's pose, from rest to rest, acted on as a `Jog` is (idle, or
    /// starved in a streamed job, with nothing queued; it must start where the
    /// controller stands). It watches the touch probe: at the change `mode` seeks
    /// it latches every joint and stops on the path; at its end without one it
    /// reports no contact (`Status::probe`, [`crate::drive::probe`]). A probe
    /// already in the sought state raises alarm `ProbeAtStart`, and nothing moves.
    Probe {
        /// The move.
        planned: PlannedBlock,
        /// What it waits for.
        mode: ProbeMode,
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
        /// Identity ([`crate::wire::store::identity`]) of the machine the host means to run;
        /// the controller refuses to move while it differs from its own.
        machine: u32,
        /// Who the host is (`nc-send` sends its process id): named to a later host
        /// that finds this one's job held ([`HeldJob::host`]).
        host: u32,
    },
    /// One chunk of a machine configuration ([`crate::wire::store`]); answered by
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
        data: heapless::Vec<u8, { crate::wire::store::CHUNK_BYTES }>,
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
    /// The recorder (protocol 13); `req`'s first byte says what.
    /// * [`RECORD_READ`] and a byte offset (u32, little-endian): where the recorder is
    ///   and, once its capture is done, the capture's bytes from the offset (answered
    ///   by `CtrlMsg::Record`). Outside the block sequence, like a status request: it
    ///   neither waits for blocks nor delays them; `id` is not looked at.
    /// * [`RECORD_ARM`] and the request (`drive::recorder::Setup::pack`): arms the
    ///   recorder, dropping any capture it holds. A control: acknowledged by
    ///   `ControlAck { id }`, acted on once per id; a refusal is answered by
    ///   `CtrlMsg::Record` with the error.
    /// * [`RECORD_DISARM`]: stops the recorder and drops its capture (a control).
    Record {
        /// The control's id.
        id: u16,
        /// What, and its argument.
        req: heapless::Vec<u8, { crate::wire::store::CHUNK_BYTES }>,
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
    /// A probing move found the probe already in the state it seeks (touching for
    /// G38.2/G38.3, clear for G38.4/G38.5): nothing moved (protocol 12).
    ProbeAtStart,
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
    /// ring of [`crate::motion::planner::BEND_CAPACITY`]).
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
    /// The touch probe's input (debounced), active when touching.
    pub probe_input: bool,
    /// Probing moves ended (`Control::Probe`; wrapping): each result is sent once as
    /// [`CtrlMsg::Probe`] when taken, and again after the status that answers a
    /// `StatusRequest`.
    pub probes: u16,
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
        error: crate::wire::store::StoreError,
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
    /// The last probing move's result (protocol 12; see `Status::probes`).
    Probe(ProbeResult),
    /// The recorder's answer to `HostMsg::RecordRead` or to a refused
    /// `Control::RecordArm` (protocol 13).
    /// (`drive::recorder::Reply::pack`, then up to [`RECORD_CHUNK`] bytes of the
    /// capture).
    Record(heapless::Vec<u8, { crate::wire::store::CHUNK_BYTES }>),
}

/// `HostMsg::Record`: read the recorder.
pub const RECORD_READ: u8 = 0;
/// `HostMsg::Record`: arm the recorder.
pub const RECORD_ARM: u8 = 1;
/// `HostMsg::Record`: stop the recorder (and a test signal).
pub const RECORD_DISARM: u8 = 2;
/// `HostMsg::Record`: start a test signal on a servo joint (`drive::excite::Excite`;
/// a control, refused by `CtrlMsg::Record` naming why).
pub const RECORD_EXCITE: u8 = 3;

/// Bytes of a capture one `CtrlMsg::Record` carries.
pub const RECORD_CHUNK: usize = crate::wire::store::CHUNK_BYTES - REPLY_HEADER;
