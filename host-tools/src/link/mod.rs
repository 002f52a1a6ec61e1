//! The client end of the serial link: [`Link`] is `nc-send`'s client, used unchanged
//! for a board, the simulator on a pseudo-terminal and the in-process simulator of
//! `--check`: each is only a [`Transport`] that moves bytes. Nothing here knows the
//! simulator; it is reached through its bytes like a board (`crate::sim::serve`).
//!
//! Client protocol (see `pkmc::wire`):
//!
//! * Handshake: `Hello` with sequence number 0 and the identity of the host's machine,
//!   repeated until `HelloAck`; blocks then carry consecutive sequence numbers from 1
//!   (wrapping at `u16`). When the controller's machine differs, the host sends its
//!   machine configuration in chunks (each resent until acknowledged, like a control
//!   command) and waits for `MachineLoaded`.
//! * Credits: a block is sent only while the blocks in flight (sent, not yet
//!   acknowledged) are fewer than the free queue slots last reported (by `Ack` or
//!   `Status`) and the motion the controller reports buffered, plus the estimated
//!   motion of the blocks in flight ([`estimate_ms`]), is below
//!   [`LinkOptions::max_buffered_ms`] ([`MAX_BUFFERED_MS`] by default); a block is
//!   always sent when nothing is in flight and the controller is below the limit, so a
//!   single block longer than the limit cannot stall the stream. A congestion
//!   window, halved on every loss and grown again by one per acknowledgement, keeps a
//!   noisy line from being flooded with resends.
//! * Acknowledgement is cumulative: `Ack { seq }` and `Nak { expected }` both mean every
//!   block before them was accepted.
//! * Go-back-N: a `Nak` for a corrupt frame, a gap or a full queue rewinds the stream
//!   to the block the controller expects; the `Nak`s that the blocks already in flight
//!   behind the lost one will draw for the same reason are then ignored (counted, not
//!   acted on) for a round trip. With blocks in flight and no acknowledgement for the
//!   retransmission timeout (the measured round trip's `srtt + 4 rttvar`, 10 ms at
//!   least, [`LinkOptions::resend_after`] at most), the stream rewinds to the first
//!   unacknowledged block. On a line that damages many frames each block goes in
//!   copies (up to four, back to back; [`resend`]). The controller re-acknowledges
//!   duplicates and copies without executing them, so a block is never executed twice
//!   and never skipped.
//! * `Nak` reasons that no resend can cure end the job with a typed [`LinkError`]:
//!   `Version`, `NoSession` (the controller restarted: the blocks it had are gone) and
//!   `BadBlock` (naming the NC line).
//! * Control commands bypass the queue: one at a time, each with a fresh id, resent
//!   with the same id every [`CONTROL_RESEND_AFTER`] until its `ControlAck` arrives
//!   (the controller remembers only the last id, so two may never be outstanding).
//! * Liveness: the controller sends status every 50 ms while moving; the client asks
//!   for one every [`LinkOptions::keepalive`], which is also its heartbeat: the
//!   controller stops on the path and raises `LinkLoss` after
//!   [`pkmc::controller::LINK_LOSS_TICKS`] (1 s) without a valid frame while moving.
//!   Silence for [`LinkOptions::link_timeout`] is a lost link ([`LinkError::Lost`]).
//!
//! A job ends when every block is acknowledged and a status shows the controller idle
//! with all of them executed, when it reports an alarm, or when the operator's abort
//! or immediate stop (from [`JobHooks::control`]) has taken effect.
//!
//! Stall guard: against a simulator on this host ([`Transport::sim_ticks`]: `--check`
//! and `--sim`, where no operator watches), a job, homing or jog whose controller says
//! it is moving (running or homing) but makes no progress (no block ends; pose, joints
//! and state unchanged) for [`STALL_TICKS`] of simulated time, plus the time of the
//! dwell it is executing, ends with [`LinkError::Stalled`] naming the NC line. Time at
//! rest (idle, an alarm, a pause or hold waiting for the operator) never counts.
//!
//! Rooms: [`transport`] (bytes), [`client`] (frames, handshake, controls, status),
//! [`stream`] (a job's blocks), [`resend`] (credits, copies, `Nak`s, the timeout),
//! [`rtt`] (the measured round trip and damage), [`error`], [`view`] (the status as
//! every face shows it: user units, the core's words).

mod arming;
mod client;
mod error;
mod hooks;
mod liveness;
mod plans;
mod record;
mod resend;
mod rtt;
mod stall;
mod stats;
mod stream;
mod trail;
mod transport;
pub mod usb;
pub mod view;
mod window;

use client::PendingControl;
pub use error::LinkError;
pub use hooks::{JobEnd, JobHooks, LinkView, NoHooks, Rewound};
pub use plans::Derived;
pub use record::{Piece, Read, Readout, Recording};
pub use stats::{Buffered, ClientStats, NakCounts};
pub use stream::{estimate_ms, TAIL_AFTER};
pub use transport::{is_timeout, PortTransport, SimClock, Transport};

use pkmc::config::MachineConfig;
use pkmc::wire::{Control, CtrlMsg, FrameReader, Status};
use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// Default limit of motion buffered in the controller, ms: no block is sent while the
/// controller reports this much or more.
pub const MAX_BUFFERED_MS: u32 = 2000;
/// Default longest time without an acknowledgement, blocks in flight, before
/// resending (the timeout before the round trip is measured).
pub const RESEND_AFTER: Duration = Duration::from_millis(200);
/// Default silence after which the link is declared lost.
pub const LINK_TIMEOUT: Duration = Duration::from_secs(3);
/// Default silence after which the client asks for a status.
pub const KEEPALIVE: Duration = Duration::from_millis(100);
/// A gap this long between two reads of the client's own loop means the client
/// itself was stopped (SIGSTOP, a starved CPU, a laptop's sleep): its silence timers
/// start again and the controller is asked at once, rather than the link being
/// declared dead because the client's own clock jumped. The loop reads every few
/// milliseconds.
pub const OWN_GAP: Duration = Duration::from_millis(500);
/// Time after which an unacknowledged control command is sent again (same id).
pub const CONTROL_RESEND_AFTER: Duration = Duration::from_millis(100);
/// Shortest time after a status request before it is repeated because a damaged
/// frame arrived (perhaps its answer); otherwise it is repeated every keepalive.
pub const REASK_AFTER_DAMAGE: Duration = Duration::from_millis(20);
/// Time the handshake waits for `HelloAck` before sending `Hello` again.
pub const HELLO_RESEND_AFTER: Duration = Duration::from_millis(300);
/// Smallest congestion window, blocks.
pub const MIN_WINDOW: usize = 2;
/// Longest wait in one read while nothing else is due.
const READ_WAIT: Duration = Duration::from_millis(5);
/// Simulated time, ticks (10 s), that a simulated controller may say it is moving
/// without progress before the job is stopped as stalled. The longest legitimate
/// standstill while moving is about 1 s (the slowest feed, 1 nm/s, moves the pose one
/// nm a second); a dwell's own time is added to this; servo settling happens at rest.
pub const STALL_TICKS: u64 = 10 * pkmc::units::TICK_HZ as u64;

/// Tunables of the client.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LinkOptions {
    /// Send no block while the controller reports this much motion buffered, ms.
    pub max_buffered_ms: u32,
    /// Resend unacknowledged blocks after this long without an acknowledgement at most
    /// (and before the round trip is measured); measured, after `srtt + 4 rttvar`.
    pub resend_after: Duration,
    /// Declare the link lost after this long without a valid frame.
    pub link_timeout: Duration,
    /// Ask for a status after this long without a valid frame.
    pub keepalive: Duration,
    /// A job is a streamed program with this host timeout (`Control::BeginJob`): the
    /// controller starves on host silence and holds the job after this long. `None`:
    /// the short link-loss watch (MDI, the bridge's lines).
    pub host_timeout: Option<Duration>,
    /// The program's identity and first block, sent with `Control::BeginJob` and kept
    /// by the controller with the job (`program` 0: none; see `nc-send resume`).
    pub mark: pkmc::wire::JobMark,
}

impl Default for LinkOptions {
    fn default() -> Self {
        Self {
            max_buffered_ms: MAX_BUFFERED_MS,
            resend_after: RESEND_AFTER,
            link_timeout: LINK_TIMEOUT,
            keepalive: KEEPALIVE,
            host_timeout: None,
            mark: pkmc::wire::JobMark {
                program: 0,
                next_block: 0,
                total_blocks: 0,
                last_line: 0,
                total_lines: 0,
            },
        }
    }
}

/// `nc-send`'s end of the link.
pub struct Link<T: Transport> {
    io: T,
    opts: LinkOptions,
    reader: FrameReader,
    rx: Vec<u8>,
    tx: Vec<u8>,
    next_seq: u16,
    capacity: u16,
    last_heard: Instant,
    /// When bytes last arrived, valid or not.
    last_bytes: Instant,
    /// When the client's loop last read the port (see [`OWN_GAP`]).
    last_pump: Instant,
    /// When the client's last gap of its own ended (see [`OWN_GAP`]): waits count
    /// from then at the earliest.
    last_gap_end: Instant,
    last_request: Instant,
    next_control_id: u16,
    controls: VecDeque<Control>,
    control: Option<PendingControl>,
    acked_control: Option<u16>,
    machine_answer: Option<CtrlMsg>,
    /// The last probing move's result the controller sent ([`CtrlMsg::Probe`]).
    probe_result: Option<pkmc::drive::probe::ProbeResult>,
    /// The recorder's streamed pieces not taken yet ([`Link::record_take`]).
    streamed: Vec<record::Piece>,
    /// A recorder request armed beside a running job, on its way ([`arming`]).
    arming: Option<arming::Arming>,
    /// Messages read while a job's blocks were planned ([`Link::keep_alive`]),
    /// for the job's loop to handle before it reads again.
    stashed: Vec<CtrlMsg>,
    /// Last status received.
    pub status: Option<Status>,
    /// Counters.
    pub stats: ClientStats,
    their_machine: u32,
    /// An earlier session's job the controller holds (from `HelloAck`).
    held: Option<pkmc::wire::HeldJob>,
    /// The held job's program mark (from `HelloAck`).
    held_mark: Option<pkmc::wire::JobMark>,
    axis_vmax: [i64; 6],
    /// The machine, for planning the blocks before they are streamed.
    machine: MachineConfig,
}
