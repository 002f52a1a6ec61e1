//! Both ends of the serial link on the host: [`serve`] runs a [`Simulator`] behind a
//! serial port (a pseudo-terminal), optionally through a [`FaultyLine`], and [`Link`]
//! is `nc-send`'s client, used unchanged for a board, the simulator on a
//! pseudo-terminal, and the in-process simulator of `--check` ([`InProcess`]).
//!
//! Client protocol (see `pkmc::protocol`):
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
//!   acted on). With blocks in flight and no acknowledgement for
//!   [`LinkOptions::resend_after`], the stream rewinds to the first unacknowledged
//!   block. The controller re-acknowledges duplicates without executing them, so a
//!   block is never executed twice and never skipped.
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
//! Simulated time in [`serve`] (the simulator behind a pseudo-terminal: `--sim`,
//! `pkmc-sim`): a board ticks at real time (1 kHz) and its host, a separate program
//! on the other end of the line, refills the queue within a millisecond or two of
//! wall time. A simulator ticking as fast as the CPU allows would drain a short
//! queue before the host's answer arrives, which no board does. So the server
//! [`ServeClock::Paced`] paces simulated time to the wall clock, one tick per
//! millisecond, while the host is streaming into a short queue: within the last
//! [`PACE_AFTER_BLOCKS`] of wall time the host queued a block or the controller's
//! queue was full (a streaming host then waits only for a free slot), **and** the
//! controller has less than [`PACE_BELOW_MS`] of motion buffered. Otherwise (long
//! moves with seconds queued, the end of a job after the host's last block, homing,
//! servo settling, a host that only polls its status or has gone quiet) it ticks as
//! fast as it can: there the host's answer cannot change the motion. Between paced ticks the server waits on the port for
//! the next tick's deadline (no spinning); a server that falls behind the wall clock
//! (a slow or loaded CPU) catches up by at most [`PACE_CATCH_UP`] and otherwise lets
//! simulated time lag, so it never runs ahead. Invariants kept: simulated time
//! passes the controller's link-loss limit only when the host has really been silent
//! that long (or the line is cut), and the stall guard, which counts simulated
//! ticks, sees the same ticks paced or not. [`ServeClock::Free`] never paces (the
//! link bench, which measures the link, not the machine).

use crate::sim::faults::FaultyLine;
use crate::sim::Simulator;
use pkmc::config::{MachineConfig, AXES, MAX_JOINTS};
use pkmc::kinematics::MachineKinematics;
use pkmc::planner::{plan_into, PlanBlock};
use pkmc::protocol::{
    decode_frame, encode_frame, Alarm, Block, Control, CtrlMsg, FrameReader, HostMsg, Motion,
    NakReason, PlannedBlock, Pushed, State, Status, MAX_BODY, MAX_FRAME, PROTOCOL_VERSION,
};
use serde::Serialize;
use serialport::SerialPort;
use std::collections::VecDeque;
use std::fmt;
use std::io::{self, ErrorKind, Read, Write};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Default limit of motion buffered in the controller, ms: no block is sent while the
/// controller reports this much or more.
pub const MAX_BUFFERED_MS: u32 = 2000;
/// Default time without an acknowledgement, blocks in flight, before resending.
pub const RESEND_AFTER: Duration = Duration::from_millis(200);
/// Default silence after which the link is declared lost.
pub const LINK_TIMEOUT: Duration = Duration::from_secs(3);
/// Default silence after which the client asks for a status.
pub const KEEPALIVE: Duration = Duration::from_millis(100);
/// Time after which an unacknowledged control command is sent again (same id).
pub const CONTROL_RESEND_AFTER: Duration = Duration::from_millis(100);
/// Time the handshake waits for `HelloAck` before sending `Hello` again.
pub const HELLO_RESEND_AFTER: Duration = Duration::from_millis(300);
/// Smallest congestion window, blocks.
pub const MIN_WINDOW: usize = 2;
/// Longest wait in one read while nothing else is due.
const READ_WAIT: Duration = Duration::from_millis(5);
/// How long after the host last queued a block, or the controller's queue was last
/// full, [`serve`] keeps simulated time paced to the wall clock (wall time): far
/// longer than the gaps between a streaming host's writes (a block per freed slot),
/// so that a host held up for a few tens of milliseconds (a loaded computer) drains
/// the queue only as a board would, in real time, rather than letting the simulator
/// run it dry at once; short enough that once the host has sent its last block the
/// rest of the job soon runs free.
pub const PACE_AFTER_BLOCKS: Duration = Duration::from_millis(50);
/// [`serve`] paces simulated time only while the controller has less than this much
/// motion buffered, ms. With more queued, the host's answer arriving a few hundred
/// ticks late (a free-running simulator covers that in a few milliseconds of wall
/// time) cannot change the motion: the queue still reaches far beyond the stopping
/// distance (at most 100 ms of motion on the example machines), and once the queue
/// has drained below this the pacing resumes.
pub const PACE_BELOW_MS: u32 = 500;
/// How far a paced [`serve`] that fell behind the wall clock catches up, ticks run
/// back to back; beyond that simulated time lags (as a slower clock would).
pub const PACE_CATCH_UP: Duration = Duration::from_millis(3);
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
    /// Resend unacknowledged blocks after this long without an acknowledgement.
    pub resend_after: Duration,
    /// Declare the link lost after this long without a valid frame.
    pub link_timeout: Duration,
    /// Ask for a status after this long without a valid frame.
    pub keepalive: Duration,
}

impl Default for LinkOptions {
    fn default() -> Self {
        Self {
            max_buffered_ms: MAX_BUFFERED_MS,
            resend_after: RESEND_AFTER,
            link_timeout: LINK_TIMEOUT,
            keepalive: KEEPALIVE,
        }
    }
}

/// Why the link failed. Every variant names the port.
#[derive(Debug)]
pub enum LinkError {
    /// The port could not be opened.
    Open {
        /// Port.
        port: String,
        /// Why.
        source: serialport::Error,
    },
    /// Reading or writing the port failed.
    Io {
        /// Port.
        port: String,
        /// "read" or "write".
        op: &'static str,
        /// Why.
        source: io::Error,
    },
    /// Nothing answered the handshake.
    NoAnswer {
        /// Port.
        port: String,
        /// How long we tried.
        waited: Duration,
    },
    /// The controller speaks another protocol version.
    Version {
        /// Port.
        port: String,
        /// The controller's version, when it said.
        theirs: Option<u16>,
    },
    /// The controller stopped answering.
    Lost {
        /// Port.
        port: String,
        /// Time since the last valid frame.
        silent: Duration,
        /// Time waited for the answer (or the progress) that never came.
        waited: Duration,
        /// What we were doing.
        during: &'static str,
    },
    /// The controller no longer knows the session (it restarted); the blocks it had
    /// queued are gone.
    SessionLost {
        /// Port.
        port: String,
    },
    /// The controller refused a block as malformed.
    BadBlock {
        /// Port.
        port: String,
        /// NC line of the block.
        line: u32,
    },
    /// The controller holds an earlier host's unfinished job: nothing new is queued
    /// behind it.
    JobHeld {
        /// Port.
        port: String,
        /// The job.
        job: pkmc::protocol::HeldJob,
    },
    /// The controller refused our machine configuration.
    MachineRefused {
        /// Port.
        port: String,
        /// Why, as the controller said.
        error: String,
    },
    /// The controller runs another machine than ours and refuses to move.
    MachineMismatch {
        /// Port.
        port: String,
    },
    /// A simulated controller said it was moving but made no progress for
    /// [`STALL_TICKS`] (plus the dwell it was executing) of simulated time.
    Stalled {
        /// Port.
        port: String,
        /// NC line it was on.
        line: u32,
        /// Its state.
        state: State,
        /// Simulated time without progress.
        still: Duration,
    },
    /// A message did not fit in a frame (a bug).
    Frame {
        /// Port.
        port: String,
        /// The message.
        what: String,
    },
}

impl fmt::Display for LinkError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LinkError::Open { port, source } => write!(f, "{port}: cannot open: {source}"),
            LinkError::Io { port, op, source } => write!(f, "{port}: {op} failed: {source}"),
            LinkError::NoAnswer { port, waited } => write!(
                f,
                "{port}: no answer to the handshake for {:.1} s: is a pkmc controller on this port?",
                waited.as_secs_f64()
            ),
            LinkError::Version { port, theirs } => match theirs {
                Some(v) => write!(
                    f,
                    "{port}: the controller speaks protocol version {v}, nc-send {PROTOCOL_VERSION}"
                ),
                None => write!(
                    f,
                    "{port}: the controller refused protocol version {PROTOCOL_VERSION}"
                ),
            },
            LinkError::Lost {
                port,
                silent,
                waited,
                during,
            } if *waited > *silent + Duration::from_millis(100) => write!(
                f,
                "{port}: link lost: waited {:.1} s while {during} (frames kept arriving, \
                 damaged or not the answer; the last valid one {:.1} s ago)",
                waited.as_secs_f64(),
                silent.as_secs_f64()
            ),
            LinkError::Lost {
                port,
                silent,
                during,
                ..
            } => write!(
                f,
                "{port}: link lost: no answer from the controller for {:.1} s while {during}",
                silent.as_secs_f64()
            ),
            LinkError::SessionLost { port } => write!(
                f,
                "{port}: the controller lost the session (did it restart?); the blocks it had queued are gone"
            ),
            LinkError::BadBlock { port, line } => write!(
                f,
                "{port}: the controller refused the block of line {line} as malformed"
            ),
            LinkError::JobHeld { port, job } => write!(
                f,
                "{port}: the controller holds an unfinished job of another host (process {}, \
                 gone): {:?} at line {}, {} blocks done, {} still queued; `nc-send resume` \
                 continues it, `nc-send abort` drops it",
                job.host, job.state, job.line, job.done, job.queued
            ),
            LinkError::MachineRefused { port, error } => write!(
                f,
                "{port}: the controller refused the machine configuration: {error}"
            ),
            LinkError::MachineMismatch { port } => write!(
                f,
                "{port}: the controller runs another machine and refuses to move"
            ),
            LinkError::Stalled {
                port,
                line,
                state,
                still,
            } => {
                write!(f, "{port}: stalled")?;
                if *line != 0 {
                    write!(f, " at line {line}")?;
                }
                write!(
                    f,
                    ": the controller has been {state:?} for {:.1} s of simulated time with no \
                     block ending and nothing moving; run stopped",
                    still.as_secs_f64()
                )
            }
            LinkError::Frame { port, what } => write!(f, "{port}: cannot frame {what}"),
        }
    }
}

impl std::error::Error for LinkError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            LinkError::Open { source, .. } => Some(source),
            LinkError::Io { source, .. } => Some(source),
            _ => None,
        }
    }
}

fn is_timeout(e: &io::Error) -> bool {
    matches!(
        e.kind(),
        ErrorKind::TimedOut | ErrorKind::WouldBlock | ErrorKind::Interrupted
    )
}

/// A byte pipe to a controller.
pub trait Transport {
    /// Name for messages (the port's path).
    fn name(&self) -> &str;
    /// Writes some of `bytes`, waiting at most `wait` for room; returns how many were
    /// taken (0 on timeout).
    fn write_some(&mut self, bytes: &[u8], wait: Duration) -> io::Result<usize>;
    /// Reads what has arrived, waiting at most `wait` for the first byte; 0 on timeout.
    fn read_some(&mut self, buf: &mut [u8], wait: Duration) -> io::Result<usize>;
    /// Simulated time at the other end, ticks, when it is a simulator on this host
    /// ([`InProcess`], or a pseudo-terminal with a [`SimClock`]): the stall guard runs
    /// on it. `None` for a board: its operator watches the machine.
    fn sim_ticks(&self) -> Option<u64> {
        None
    }
}

/// The clock of a simulator serving in another thread, read by the client's stall
/// guard: the server stores its tick count after every tick.
#[derive(Clone, Debug, Default)]
pub struct SimClock(Arc<AtomicU64>);

impl SimClock {
    /// Records the simulator's tick count.
    pub fn set(&self, ticks: u64) {
        self.0.store(ticks, Ordering::Relaxed);
    }

    /// The simulator's tick count last recorded.
    pub fn ticks(&self) -> u64 {
        self.0.load(Ordering::Relaxed)
    }
}

/// A serial port (a board's USB CDC port or a pseudo-terminal).
pub struct PortTransport {
    port: Box<dyn SerialPort>,
    name: String,
    clock: Option<SimClock>,
    /// The port's descriptor (non-blocking, see [`PortTransport::open`]).
    #[cfg(unix)]
    #[cfg_attr(not(test), allow(dead_code))]
    fd: i32,
}

impl PortTransport {
    /// Opens the port at `path`.
    pub fn open(path: &str) -> Result<Self, LinkError> {
        let open_error = |source| LinkError::Open {
            port: path.to_string(),
            source,
        };
        let port = serialport::new(path, 115_200)
            .timeout(Duration::from_millis(10))
            .open_native()
            .map_err(open_error)?;
        // Non-blocking: the port is polled with a timeout before each read, but another
        // process reading the same port can take the bytes between the poll and the
        // read, and a blocking read would then wait forever (the link timeout could
        // never fire). A read that finds nothing returns at once instead.
        #[cfg(unix)]
        let fd = {
            use std::os::fd::AsRawFd;
            let fd = port.as_raw_fd();
            // SAFETY: fcntl on a descriptor this function owns (the open port).
            let ok = unsafe {
                let flags = libc::fcntl(fd, libc::F_GETFL);
                flags >= 0 && libc::fcntl(fd, libc::F_SETFL, flags | libc::O_NONBLOCK) == 0
            };
            if !ok {
                return Err(open_error(serialport::Error::from(
                    io::Error::last_os_error(),
                )));
            }
            fd
        };
        Ok(Self {
            #[cfg(unix)]
            fd,
            port: Box::new(port),
            name: path.to_string(),
            clock: None,
        })
    }

    /// The port of a simulator whose clock is `clock`: turns the stall guard on.
    pub fn with_sim_clock(mut self, clock: SimClock) -> Self {
        self.clock = Some(clock);
        self
    }
}

impl Transport for PortTransport {
    fn name(&self) -> &str {
        &self.name
    }

    fn write_some(&mut self, bytes: &[u8], wait: Duration) -> io::Result<usize> {
        self.port.set_timeout(wait)?;
        match self.port.write(bytes) {
            Ok(n) => Ok(n),
            Err(e) if is_timeout(&e) => Ok(0),
            Err(e) => Err(e),
        }
    }

    fn read_some(&mut self, buf: &mut [u8], wait: Duration) -> io::Result<usize> {
        self.port.set_timeout(wait)?;
        match self.port.read(buf) {
            Ok(n) => Ok(n),
            Err(e) if is_timeout(&e) => Ok(0),
            Err(e) => Err(e),
        }
    }

    fn sim_ticks(&self) -> Option<u64> {
        self.clock.as_ref().map(SimClock::ticks)
    }
}

/// The simulator in this process, on its simulated clock, without a port: bytes
/// written go straight into the controller; a read runs ticks until the controller
/// has something to say or nothing left to do. Used by `nc-send --check`.
pub struct InProcess {
    /// The simulator.
    pub sim: Simulator,
    on_tick: Box<dyn FnMut(&Simulator)>,
    out: Vec<u8>,
}

/// Most ticks one [`InProcess`] read runs before returning empty-handed.
const IN_PROCESS_TICKS_PER_READ: u32 = 10_000;

impl InProcess {
    /// Wraps `sim`; `on_tick` sees the simulator after every tick.
    /// The controller's link-loss watch is turned off: host and controller share the
    /// process and the simulated clock runs far ahead of the host's heartbeat.
    pub fn new(mut sim: Simulator, on_tick: Box<dyn FnMut(&Simulator)>) -> Self {
        sim.ctrl.set_link_watch(false);
        Self {
            sim,
            on_tick,
            out: vec![0; pkmc::controller::TX_CAPACITY],
        }
    }
}

impl Transport for InProcess {
    fn name(&self) -> &str {
        "in-process simulator"
    }

    fn write_some(&mut self, bytes: &[u8], _wait: Duration) -> io::Result<usize> {
        self.sim.ctrl.receive(bytes);
        if settle(&mut self.sim).map_err(io::Error::other)? {
            (self.on_tick)(&self.sim);
        }
        Ok(bytes.len())
    }

    fn read_some(&mut self, buf: &mut [u8], _wait: Duration) -> io::Result<usize> {
        for _ in 0..IN_PROCESS_TICKS_PER_READ {
            let n = self.sim.ctrl.transmit(&mut self.out);
            if n > 0 {
                // `transmit` drained up to TX_CAPACITY; hand over what fits, keep none:
                // callers read with buffers at least that large.
                let m = n.min(buf.len());
                buf[..m].copy_from_slice(&self.out[..m]);
                return Ok(m);
            }
            if !self.sim.busy() {
                return Ok(0);
            }
            self.sim.tick().map_err(io::Error::other)?;
            (self.on_tick)(&self.sim);
        }
        Ok(0)
    }

    fn sim_ticks(&self) -> Option<u64> {
        Some(self.sim.ticks)
    }
}

/// Runs one tick when the controller is held at rest, so that a command that takes
/// effect on the next tick (an `Abort` finishing a hold) does: the simulator otherwise
/// ticks only while [`pkmc::controller::Controller::has_work`], which is false for a
/// held, stopped controller even with an abort pending. Returns whether it ticked.
fn settle(sim: &mut Simulator) -> anyhow::Result<bool> {
    if sim.ctrl.state() == State::Hold && !sim.ctrl.has_work() {
        sim.tick()?;
        return Ok(true);
    }
    Ok(false)
}

/// Estimated duration of `b` starting from pose `from`, ms, at its feed (rapids at
/// the slowest axis's `axis_vmax`, units/s), ignoring acceleration: a lower bound
/// of what the controller will report buffered for it. Dwells count their time,
/// auxiliary functions nothing.
pub fn estimate_ms(from: &[i64; 6], b: &Block, axis_vmax: &[i64; 6]) -> f64 {
    let d: Vec<f64> = (0..6).map(|i| (b.target[i] - from[i]) as f64).collect();
    let linear = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    let rotary = (d[3] * d[3] + d[4] * d[4] + d[5] * d[5]).sqrt();
    let at_feed = |len: f64| {
        if b.feed > 0 {
            len / b.feed as f64 * 1000.0
        } else {
            0.0
        }
    };
    match b.motion {
        Motion::Rapid => (0..6)
            .filter(|&i| axis_vmax[i] > 0)
            .map(|i| d[i].abs() / axis_vmax[i] as f64 * 1000.0)
            .fold(0.0, f64::max),
        Motion::Linear => at_feed(if linear > 0.0 { linear } else { rotary }),
        Motion::Arc {
            center,
            plane,
            clockwise,
            turns,
        } => {
            let (a, c, h) = plane.axes();
            let (sa, sc) = (
                from[a] as f64 - center[0] as f64,
                from[c] as f64 - center[1] as f64,
            );
            let (ea, ec) = (
                b.target[a] as f64 - center[0] as f64,
                b.target[c] as f64 - center[1] as f64,
            );
            let r = (sa * sa + sc * sc).sqrt();
            let tau = std::f64::consts::TAU;
            let mut sweep = (ec.atan2(ea) - sc.atan2(sa)).rem_euclid(tau);
            if clockwise {
                sweep = (tau - sweep).rem_euclid(tau);
            }
            if sweep == 0.0 {
                sweep = tau;
            }
            sweep += tau * turns as f64;
            let along = r * sweep;
            at_feed((along * along + d[h] * d[h]).sqrt())
        }
        Motion::Dwell(ms) => ms as f64,
        Motion::Aux(_) => 0.0,
    }
}

/// What the simulator's server loop did, besides the faults.
#[derive(Clone, Debug, Default)]
pub struct ServeStats {
    /// Bytes received from the port.
    pub bytes_in: u64,
    /// Bytes written to the port.
    pub bytes_out: u64,
}

/// How [`serve`] advances simulated time.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ServeClock {
    /// One tick per millisecond of wall time while the host streams into a short
    /// queue, as fast as possible otherwise (see the module documentation).
    #[default]
    Paced,
    /// Always as fast as possible while the controller has work (benches of the
    /// link itself).
    Free,
}

/// Serves `sim` on `port` until `stop` is set, through `faults` when given; `on_tick`
/// sees the simulator after every tick. Simulated time advances while the controller
/// has motion to execute, as `clock` says (paced to the wall clock while the host
/// streams into a short queue, see the module documentation); when idle, the loop
/// waits for bytes.
pub fn serve(
    sim: &mut Simulator,
    port: &mut dyn SerialPort,
    stop: &AtomicBool,
    mut faults: Option<&mut FaultyLine>,
    clock: ServeClock,
    on_tick: &mut dyn FnMut(&Simulator),
) -> Result<ServeStats, LinkError> {
    let name = port.name().unwrap_or_else(|| "pseudo-terminal".into());
    let io_err = |op: &'static str| {
        let port = name.clone();
        move |source: io::Error| LinkError::Io {
            port: port.clone(),
            op,
            source,
        }
    };
    let mut stats = ServeStats::default();
    let mut buf = vec![0u8; 65536];
    let mut out = vec![0u8; pkmc::controller::TX_CAPACITY];
    let mut line_out: Vec<u8> = Vec::with_capacity(65536);
    let mut pending: Vec<u8> = Vec::with_capacity(65536);
    // Wall time of the last bytes delivered to the controller, and the end of an
    // injected link cut.
    let mut delivered = Instant::now();
    // Wall time at which the host last queued a block, or the controller's queue was
    // last seen full: the host is streaming.
    let mut fed = delivered;
    let mut cut_until: Option<Instant> = None;
    let loss_wall = Duration::from_millis(pkmc::controller::LINK_LOSS_TICKS as u64);
    let tick_wall = Duration::from_nanos(pkmc::units::TICK_NS as u64);
    // Wall time at which the next paced tick is due; `None` while running free.
    let mut next_tick: Option<Instant> = None;
    while !stop.load(Ordering::Relaxed) {
        let now = Instant::now();
        if sim.take_link_cut() {
            cut_until = Some(now + crate::sim::LINK_CUT);
        }
        let cut = cut_until.is_some_and(|t| now < t);
        // Simulated time may run ahead of the host's wall clock; it may pass the
        // controller's link-loss limit only when the host has really been silent
        // that long (or the line is cut).
        let starved = sim.ctrl.link_silence_ticks() + 1 >= pkmc::controller::LINK_LOSS_TICKS
            && delivered.elapsed() < loss_wall;
        let busy = sim.busy() && !starved;
        let status = sim.ctrl.status();
        if status.free_slots == 0 || status.free_bends == 0 {
            // A full queue (or ring of arcs): a streaming host waits only for the next
            // free slot.
            fed = now;
        }
        let paced = busy
            && clock == ServeClock::Paced
            && status.buffered_ms < PACE_BELOW_MS
            && now.duration_since(fed) < PACE_AFTER_BLOCKS;
        // Paced, the tick is due at its deadline (at once when pacing starts); free,
        // at once.
        let due = if paced {
            *next_tick.get_or_insert(now)
        } else {
            next_tick = None;
            now
        };
        let tick_now = busy && now >= due;
        let ready = if tick_now {
            port.bytes_to_read().unwrap_or(0) as usize
        } else {
            1
        };
        if ready > 0 {
            // Idle: wait for bytes. Paced before the deadline: wait for bytes until it.
            let wait = if !busy {
                Duration::from_millis(5)
            } else if tick_now {
                Duration::ZERO
            } else {
                due - now
            };
            port.set_timeout(wait)
                .map_err(|e| io_err("read")(e.into()))?;
            match port.read(&mut buf) {
                Ok(_) if cut => {}
                Ok(n) => {
                    stats.bytes_in += n as u64;
                    if n > 0 {
                        delivered = Instant::now();
                    }
                    match faults.as_deref_mut() {
                        Some(line) => {
                            line_out.clear();
                            line.towards_controller(&buf[..n], &mut line_out);
                            sim.ctrl.receive(&line_out);
                        }
                        None => sim.ctrl.receive(&buf[..n]),
                    }
                    if sim.ctrl.status().free_slots < status.free_slots {
                        // Blocks queued (the queue only fills on receipt).
                        fed = Instant::now();
                    }
                    sim.persist()
                        .map_err(|e| io_err("store the machine")(io::Error::other(e)))?;
                    if settle(sim).map_err(|e| io_err("simulate")(io::Error::other(e)))? {
                        on_tick(sim);
                    }
                }
                Err(e) if is_timeout(&e) => {}
                Err(e) => return Err(io_err("read")(e)),
            }
        }
        if tick_now {
            sim.tick()
                .map_err(|e| io_err("simulate")(io::Error::other(e)))?;
            on_tick(sim);
            if let Some(t) = next_tick.as_mut() {
                // The next deadline, one tick on; a server that fell further behind
                // than it may catch up lets simulated time lag instead.
                *t += tick_wall;
                let late = Instant::now().saturating_duration_since(*t);
                if late > PACE_CATCH_UP {
                    *t += late - PACE_CATCH_UP;
                }
            }
        }
        loop {
            let n = sim.ctrl.transmit(&mut out);
            if n == 0 {
                break;
            }
            if cut {
                continue;
            }
            match faults.as_deref_mut() {
                Some(line) => line.towards_host(&out[..n], &mut pending),
                None => pending.extend_from_slice(&out[..n]),
            }
        }
        if !pending.is_empty() {
            port.set_timeout(Duration::from_millis(1))
                .map_err(|e| io_err("write")(e.into()))?;
            match port.write(&pending) {
                Ok(n) => {
                    stats.bytes_out += n as u64;
                    pending.drain(..n);
                }
                Err(e) if is_timeout(&e) => {}
                Err(e) => return Err(io_err("write")(e)),
            }
        }
    }
    // The host is done: servo joints still settling on their last targets finish
    // doing so (the controller itself has nothing left to do).
    while !sim.ctrl.has_work() && sim.busy() {
        sim.tick()
            .map_err(|e| io_err("simulate")(io::Error::other(e)))?;
        on_tick(sim);
    }
    sim.finish_trace()
        .map_err(|e| io_err("write the trace")(io::Error::other(e)))?;
    Ok(stats)
}

/// What a status shows of a controller's progress.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Mark {
    state: State,
    blocks_done: u32,
    pose: [i64; AXES],
    joints: [i64; MAX_JOINTS],
}

/// The stall guard's memory: the last progress seen and when, in simulated ticks.
#[derive(Clone, Copy, Debug, Default)]
struct StallGuard {
    mark: Option<Mark>,
    since: u64,
}

impl StallGuard {
    /// Takes status `s`, seen at simulated tick `now`; returns the ticks the controller
    /// has been moving without progress.
    fn observe(&mut self, s: &Status, now: u64) -> u64 {
        let mark = Mark {
            state: s.state,
            blocks_done: s.blocks_done,
            pose: s.pose,
            joints: s.joints,
        };
        // Idle or in alarm: waiting for the host. Held: braking (the pose changes) or
        // waiting for the operator (a pause, a tool change, a feed hold). The reported
        // speed is no sign of progress: it is not zeroed during a dwell.
        let at_rest = matches!(
            s.state,
            State::Idle | State::Alarm | State::EStop | State::Hold
        );
        if at_rest || self.mark != Some(mark) {
            self.mark = Some(mark);
            self.since = now;
        }
        now.saturating_sub(self.since)
    }
}

/// Ticks of the dwell a job is executing when status `s` arrives (0 if none): the
/// stall guard adds them to [`STALL_TICKS`].
fn dwell_ticks(blocks: &[Block], done_before: u32, s: &Status) -> u64 {
    let executing = s.blocks_done.wrapping_sub(done_before) as usize;
    match blocks.get(executing).map(|b| b.motion) {
        Some(Motion::Dwell(ms)) => ms as u64 * pkmc::units::TICK_HZ as u64 / 1000,
        _ => 0,
    }
}

/// How a job ended.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum JobEnd {
    /// Every block executed; the controller is idle.
    Done,
    /// The controller raised an alarm.
    Alarm(Alarm),
    /// The operator aborted: the controller stopped on the path and dropped its queue.
    Aborted,
    /// The operator stopped immediately: the controller is in alarm (`Aborted`).
    Stopped,
    /// A resumed job stopped at rest again in a pause or tool change (M0, M1, M6) at
    /// this NC line; `nc-send resume` continues it.
    Paused(u32),
}

/// Negative acknowledgements received, by reason.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct NakCounts {
    /// Damaged frame.
    pub corrupt: u64,
    /// A frame went missing.
    pub gap: u64,
    /// Queue full.
    pub queue_full: u64,
    /// Version, no session, bad block or a reason this client does not know.
    pub other: u64,
}

/// Link statistics seen by the client.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct ClientStats {
    /// Frames sent (including resends, control commands and status requests).
    pub frames_sent: u64,
    /// Bytes sent.
    pub bytes_sent: u64,
    /// Blocks sent for the first time.
    pub blocks_sent: u64,
    /// Blocks sent again after a `Nak` or a timeout.
    pub resent: u64,
    /// Rewinds of the block stream (go-back-N).
    pub rewinds: u64,
    /// Rewinds because nothing was acknowledged in time.
    pub timeouts: u64,
    /// `Nak`s received (all reasons).
    pub naks: u64,
    /// `Nak`s by reason.
    pub nak_reasons: NakCounts,
    /// `Nak`s ignored because a rewind already covered them.
    pub naks_ignored: u64,
    /// Control commands sent (first time).
    pub controls: u64,
    /// Control commands sent again, unacknowledged.
    pub controls_resent: u64,
    /// Status requests sent.
    pub status_requests: u64,
    /// Frames received that decoded.
    pub frames_received: u64,
    /// Received frames that failed to decode (damaged on the way).
    pub corrupt_received: u64,
    /// Motion time of the last job as planned on the host with unlimited look-ahead,
    /// s: what an ideal controller under the same limits takes (jerk smoothing not
    /// counted).
    pub plan_time_s: f64,
}

/// What the job runner tells its caller, and asks it.
pub trait JobHooks {
    /// Every status received.
    fn status(&mut self, _status: &Status) {}
    /// Asked on every turn of the loop: a control command to send now (operator keys,
    /// Ctrl-C). `Abort` and `Stop` end the job once they have taken effect.
    fn control(&mut self, _link: &LinkView) -> Option<Control> {
        None
    }
    /// Does a program pause (M0, M1, M6) end the job here, leaving it held on the
    /// controller ([`JobEnd::Paused`]), because no operator can resume it from this
    /// host? (Otherwise the job waits for [`JobHooks::control`] to resume it.)
    fn ends_at_pause(&self) -> bool {
        false
    }
}

/// Hooks that do nothing.
pub struct NoHooks;
impl JobHooks for NoHooks {}

/// What [`JobHooks::control`] may look at.
#[derive(Clone, Debug, Default)]
pub struct LinkView {
    /// Last status.
    pub status: Option<Status>,
    /// Blocks acknowledged so far in this job.
    pub acked: usize,
    /// Blocks in the job.
    pub total: usize,
    /// Is a control command still waiting for its acknowledgement?
    pub control_pending: bool,
}

#[derive(Clone, Copy, Debug)]
struct PendingControl {
    id: u16,
    cmd: Control,
    sent_at: Option<Instant>,
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
    last_request: Instant,
    next_control_id: u16,
    controls: VecDeque<Control>,
    control: Option<PendingControl>,
    acked_control: Option<u16>,
    machine_answer: Option<CtrlMsg>,
    /// Last status received.
    pub status: Option<Status>,
    /// Counters.
    pub stats: ClientStats,
    their_machine: u32,
    /// An earlier session's job the controller holds (from `HelloAck`).
    held: Option<pkmc::protocol::HeldJob>,
    axis_vmax: [i64; 6],
    /// The machine, for planning the blocks before they are streamed.
    machine: MachineConfig,
}

impl<T: Transport> Link<T> {
    /// The machine this link runs.
    pub fn machine(&self) -> &MachineConfig {
        &self.machine
    }

    /// Opens a session on `io` for `machine`: sends `Hello` until `HelloAck` arrives;
    /// when the controller has another machine, sends it ours and waits until it is
    /// loaded (the controller refuses to move until then).
    pub fn connect(io: T, machine: &MachineConfig, opts: LinkOptions) -> Result<Self, LinkError> {
        let mut link = Self::handshake(io, machine, opts)?;
        if link.their_machine != pkmc::store::identity(machine) {
            link.send_machine(machine)?;
        }
        Ok(link)
    }

    fn handshake(io: T, machine: &MachineConfig, opts: LinkOptions) -> Result<Self, LinkError> {
        let ours = pkmc::store::identity(machine);
        let now = Instant::now();
        let mut link = Link {
            io,
            opts,
            reader: FrameReader::new(),
            rx: vec![0; 65536],
            tx: Vec::with_capacity(65536),
            next_seq: 1,
            capacity: 0,
            last_heard: now,
            last_bytes: now,
            last_request: now,
            next_control_id: 1,
            controls: VecDeque::new(),
            control: None,
            acked_control: None,
            machine_answer: None,
            status: None,
            stats: ClientStats::default(),
            their_machine: 0,
            held: None,
            axis_vmax: core::array::from_fn(|i| machine.axes[i].max_velocity),
            machine: machine.clone(),
        };
        let start = Instant::now();
        while !link.given_up(start) {
            link.queue(
                0,
                &HostMsg::Hello {
                    version: PROTOCOL_VERSION,
                    machine: ours,
                    host: std::process::id(),
                },
            )?;
            link.flush()?;
            let until = Instant::now() + HELLO_RESEND_AFTER;
            while Instant::now() < until {
                for msg in link.pump(READ_WAIT)? {
                    match msg {
                        CtrlMsg::HelloAck {
                            version,
                            queue_capacity,
                            held,
                            machine,
                        } => {
                            link.held = held;
                            if version != PROTOCOL_VERSION {
                                return Err(LinkError::Version {
                                    port: link.io.name().into(),
                                    theirs: Some(version),
                                });
                            }
                            link.capacity = queue_capacity;
                            link.their_machine = machine;
                            return Ok(link);
                        }
                        CtrlMsg::Nak {
                            reason: NakReason::Version,
                            ..
                        } => {
                            return Err(LinkError::Version {
                                port: link.io.name().into(),
                                theirs: None,
                            })
                        }
                        _ => {}
                    }
                }
            }
        }
        Err(LinkError::NoAnswer {
            port: link.io.name().into(),
            waited: start.elapsed(),
        })
    }

    /// The transport (e.g. to read the in-process simulator after a check).
    pub fn transport(&self) -> &T {
        &self.io
    }

    /// Gives the transport back.
    pub fn into_transport(self) -> T {
        self.io
    }

    /// The unfinished job of an earlier host that the controller held when this link
    /// opened, if any (see `nc-send resume` and `abort`).
    pub fn held(&self) -> Option<pkmc::protocol::HeldJob> {
        self.held
    }

    /// An error naming the held job, if one is held: a new job or move is refused
    /// rather than queued behind it.
    pub fn refuse_if_held(&self) -> Result<(), LinkError> {
        match self.held {
            Some(job) => Err(LinkError::JobHeld {
                port: self.port(),
                job,
            }),
            None => Ok(()),
        }
    }

    /// Marks the held job as dealt with (resumed or aborted by this host).
    pub fn release_held(&mut self) {
        self.held = None;
    }

    /// Block-queue capacity the controller announced.
    pub fn capacity(&self) -> u16 {
        self.capacity
    }

    fn port(&self) -> String {
        self.io.name().to_string()
    }

    /// Appends a frame to the transmit buffer.
    fn queue(&mut self, seq: u16, msg: &HostMsg) -> Result<(), LinkError> {
        let mut frame = [0u8; MAX_FRAME];
        let n = encode_frame(seq, msg, &mut frame).map_err(|e| LinkError::Frame {
            port: self.port(),
            what: format!("{msg:?} ({e:?})"),
        })?;
        self.tx.extend_from_slice(&frame[..n]);
        self.stats.frames_sent += 1;
        self.stats.bytes_sent += n as u64;
        Ok(())
    }

    /// Writes what the port takes now, without blocking for long.
    fn flush_some(&mut self) -> Result<(), LinkError> {
        if self.tx.is_empty() {
            return Ok(());
        }
        let n = self
            .io
            .write_some(&self.tx, Duration::from_millis(1))
            .map_err(|source| LinkError::Io {
                port: self.port(),
                op: "write",
                source,
            })?;
        self.tx.drain(..n);
        Ok(())
    }

    /// Writes the whole transmit buffer (reading meanwhile, so neither side stalls).
    fn flush(&mut self) -> Result<(), LinkError> {
        let start = Instant::now();
        while !self.tx.is_empty() {
            self.flush_some()?;
            if !self.tx.is_empty() {
                if start.elapsed() > self.opts.link_timeout {
                    return Err(LinkError::Lost {
                        port: self.port(),
                        silent: start.elapsed(),
                        waited: start.elapsed(),
                        during: "writing",
                    });
                }
                let msgs = self.pump(Duration::ZERO)?;
                self.absorb(&msgs);
            }
        }
        Ok(())
    }

    /// Control acknowledgements and machine answers from messages read outside a job
    /// loop.
    fn absorb(&mut self, msgs: &[CtrlMsg]) {
        for m in msgs {
            match m {
                CtrlMsg::ControlAck { id } => self.acked_control = Some(*id),
                CtrlMsg::MachineLoaded { .. } | CtrlMsg::MachineRefused { .. } => {
                    self.machine_answer = Some(m.clone())
                }
                _ => {}
            }
        }
    }

    /// Sends `machine` in chunks, each resent until acknowledged, and waits for the
    /// controller to load it.
    fn send_machine(&mut self, machine: &MachineConfig) -> Result<(), LinkError> {
        let mut payload = [0u8; pkmc::store::MAX_CONFIG_BYTES];
        let n = pkmc::store::encode(machine, &mut payload).ok_or_else(|| LinkError::Frame {
            port: self.port(),
            what: "the machine configuration (too large)".into(),
        })?;
        let crc = pkmc::crc::crc32(&payload[..n]);
        self.machine_answer = None;
        for off in (0..n).step_by(pkmc::store::CHUNK_BYTES) {
            let end = (off + pkmc::store::CHUNK_BYTES).min(n);
            let id = self.fresh_control_id();
            let data =
                heapless::Vec::from_slice(&payload[off..end]).map_err(|_| LinkError::Frame {
                    port: self.port(),
                    what: "a machine chunk".into(),
                })?;
            let msg = HostMsg::Machine {
                id,
                offset: off as u16,
                total: n as u16,
                crc,
                data,
            };
            self.until_acked(id, &msg, "sending the machine configuration")?;
        }
        let start = Instant::now();
        loop {
            match self.machine_answer.take() {
                Some(CtrlMsg::MachineLoaded { machine }) if machine == crc => {
                    self.their_machine = machine;
                    return Ok(());
                }
                Some(CtrlMsg::MachineRefused { error }) => {
                    return Err(LinkError::MachineRefused {
                        port: self.port(),
                        error: format!("{error:?}"),
                    })
                }
                _ => {}
            }
            if start.elapsed() > self.opts.link_timeout {
                return Err(self.lost("waiting for the controller to load the machine", start));
            }
            let msgs = self.pump(READ_WAIT)?;
            self.absorb(&msgs);
        }
    }

    /// Sends `msg` (a control command or machine chunk carrying `id`) until
    /// `ControlAck { id }` arrives.
    fn until_acked(
        &mut self,
        id: u16,
        msg: &HostMsg,
        during: &'static str,
    ) -> Result<(), LinkError> {
        let start = Instant::now();
        let mut first = true;
        loop {
            self.queue(0, msg)?;
            if !std::mem::take(&mut first) {
                self.stats.controls_resent += 1;
            }
            self.flush()?;
            let until = Instant::now() + CONTROL_RESEND_AFTER;
            while Instant::now() < until {
                let msgs = self.pump(READ_WAIT)?;
                self.absorb(&msgs);
                if self.acked_control == Some(id) {
                    return Ok(());
                }
            }
            if self.given_up(start) {
                return Err(self.lost(during, start));
            }
        }
    }

    /// Reads what has arrived (waiting up to `wait` for it) and decodes it.
    fn pump(&mut self, wait: Duration) -> Result<Vec<CtrlMsg>, LinkError> {
        let n = self
            .io
            .read_some(&mut self.rx, wait)
            .map_err(|source| LinkError::Io {
                port: self.io.name().to_string(),
                op: "read",
                source,
            })?;
        let mut msgs = Vec::new();
        for &b in &self.rx[..n] {
            match self.reader.push(b) {
                Pushed::Pending => {}
                Pushed::Overlong => self.stats.corrupt_received += 1,
                Pushed::Frame(f) => {
                    let mut body = [0u8; MAX_BODY];
                    match decode_frame::<CtrlMsg>(f, &mut body) {
                        Ok((_, m)) => msgs.push(m),
                        Err(_) => self.stats.corrupt_received += 1,
                    }
                }
            }
        }
        if n > 0 {
            self.last_bytes = Instant::now();
        }
        if !msgs.is_empty() {
            self.last_heard = Instant::now();
            self.stats.frames_received += msgs.len() as u64;
        }
        for m in &msgs {
            if let CtrlMsg::Status(s) = m {
                self.status = Some(s.clone());
            }
        }
        Ok(msgs)
    }

    fn lost(&self, during: &'static str, since: Instant) -> LinkError {
        LinkError::Lost {
            port: self.port(),
            silent: self.last_heard.elapsed(),
            waited: since.elapsed(),
            during,
        }
    }

    /// Has a request made at `start` waited long enough? After the link timeout when
    /// nothing has arrived for that long; while bytes keep arriving (a live controller
    /// on a damaged line: the answer may get through), up to ten times it.
    fn given_up(&self, start: Instant) -> bool {
        let t = self.opts.link_timeout;
        start.elapsed() > t && (self.last_bytes.elapsed() > t || start.elapsed() > t * 10)
    }

    /// Asks for and waits for a fresh status.
    pub fn request_status(&mut self) -> Result<Status, LinkError> {
        let start = Instant::now();
        loop {
            self.queue(0, &HostMsg::StatusRequest)?;
            self.stats.status_requests += 1;
            self.flush()?;
            let until = Instant::now() + self.opts.keepalive.max(Duration::from_millis(50));
            while Instant::now() < until {
                let msgs = self.pump(READ_WAIT)?;
                self.absorb(&msgs);
                for m in msgs {
                    if let CtrlMsg::Status(s) = m {
                        return Ok(s);
                    }
                }
            }
            if self.given_up(start) {
                return Err(self.lost("waiting for a status", start));
            }
        }
    }

    /// Sends one control command and waits for its acknowledgement.
    pub fn control(&mut self, cmd: Control) -> Result<(), LinkError> {
        let id = self.fresh_control_id();
        self.stats.controls += 1;
        self.until_acked(
            id,
            &HostMsg::Control { id, cmd },
            "waiting for a control acknowledgement",
        )
    }

    fn fresh_control_id(&mut self) -> u16 {
        let id = self.next_control_id;
        self.next_control_id = self.next_control_id.wrapping_add(1).max(1);
        id
    }

    /// The stall guard on status `s` (simulators only): an error once the controller
    /// has been moving without progress for [`STALL_TICKS`] plus `allowance` ticks.
    fn check_stall(
        &self,
        guard: &mut StallGuard,
        s: &Status,
        allowance: u64,
    ) -> Result<(), LinkError> {
        let Some(now) = self.io.sim_ticks() else {
            return Ok(());
        };
        let still = guard.observe(s, now);
        if still <= STALL_TICKS + allowance {
            return Ok(());
        }
        Err(LinkError::Stalled {
            port: self.port(),
            line: s.line,
            state: s.state,
            still: Duration::from_nanos(still * pkmc::units::TICK_NS as u64),
        })
    }

    /// Waits until the controller is at rest: idle with an empty queue (`Done`), or in
    /// alarm. `hooks` sees every status.
    /// The operator's controls from `hooks` are sent on the way; after an `Abort` the
    /// end is `Aborted`, after a `Stop` it is `Stopped`. On a simulator, a controller
    /// moving without progress is an error ([`LinkError::Stalled`]).
    pub fn wait_idle(&mut self, hooks: &mut dyn JobHooks) -> Result<JobEnd, LinkError> {
        self.wait_until_idle(hooks, false)
    }

    /// Waits for a job resumed with `Resume` (no host streams it): until it ends, as
    /// [`Link::wait_idle`], or until it stops at rest in a later pause
    /// ([`JobEnd::Paused`]) instead of waiting for an operator this host does not have.
    pub fn wait_resumed(&mut self, hooks: &mut dyn JobHooks) -> Result<JobEnd, LinkError> {
        self.wait_until_idle(hooks, true)
    }

    fn wait_until_idle(
        &mut self,
        hooks: &mut dyn JobHooks,
        end_at_pause: bool,
    ) -> Result<JobEnd, LinkError> {
        let mut ended_by = None;
        let mut guard = StallGuard::default();
        loop {
            let s = self.request_status()?;
            hooks.status(&s);
            self.check_stall(&mut guard, &s, 0)?;
            let view = LinkView {
                status: Some(s.clone()),
                ..LinkView::default()
            };
            if let Some(cmd) = hooks.control(&view) {
                self.control(cmd)?;
                if matches!(cmd, Control::Abort | Control::Stop) {
                    ended_by = Some(cmd);
                }
                continue;
            }
            if matches!(s.state, State::Alarm | State::EStop) && s.speed == 0 {
                if ended_by == Some(Control::Stop) {
                    return Ok(JobEnd::Stopped);
                }
                if let Some(a) = s.alarm {
                    return Ok(JobEnd::Alarm(a));
                }
            }
            if end_at_pause && ended_by.is_none() && s.state == State::Hold && s.speed == 0 {
                return Ok(JobEnd::Paused(s.line));
            }
            if s.state == State::Idle
                && s.speed == 0
                && s.free_slots == self.capacity
                && s.buffered_ms == 0
            {
                return Ok(match ended_by {
                    Some(_) => JobEnd::Aborted,
                    None => JobEnd::Done,
                });
            }
            if self.io.sim_ticks().is_some() {
                // A simulated clock advances only while it is read: let it run to its
                // next status (an in-process controller answers a status request at
                // once, without ticking, so asking again would never move it).
                self.pump(Duration::from_millis(10))?;
            } else {
                std::thread::sleep(Duration::from_millis(10));
            }
        }
    }

    /// Streams `blocks` and waits until they have all executed, the controller raises
    /// an alarm, or the operator's abort or stop has taken effect; on a simulator, a
    /// controller moving without progress is an error ([`LinkError::Stalled`]).
    pub fn run_job(
        &mut self,
        blocks: &[Block],
        hooks: &mut dyn JobHooks,
    ) -> Result<JobEnd, LinkError> {
        self.refuse_if_held()?;
        let start_status = self.request_status()?;
        hooks.status(&start_status);
        if matches!(start_status.state, State::Alarm | State::EStop) {
            if let Some(a) = start_status.alarm {
                return Ok(JobEnd::Alarm(a));
            }
        }
        let planned = self.plan(blocks, start_status.pose)?;
        let mut job = JobState::new(self.next_seq, self.capacity, &start_status);
        // Cumulative estimated motion, ms: `planned_ms[i]` covers blocks before `i`.
        let mut from = start_status.pose;
        job.planned_ms = Vec::with_capacity(blocks.len() + 1);
        job.planned_ms.push(0.0);
        job.arcs_before = Vec::with_capacity(blocks.len() + 1);
        job.arcs_before.push(0);
        for b in blocks {
            let arcs = job.arcs_before.last().copied().unwrap_or(0);
            job.arcs_before
                .push(arcs + matches!(b.motion, Motion::Arc { .. }) as usize);
            let total = job.planned_ms.last().copied().unwrap_or(0.0);
            job.planned_ms
                .push(total + estimate_ms(&from, b, &self.axis_vmax));
            if !matches!(b.motion, Motion::Dwell(_) | Motion::Aux(_)) {
                from = b.target;
            }
        }
        let result = self.job_loop(blocks, &planned, hooks, &mut job);
        self.next_seq = job.seq_of(job.acked.max(job.high));
        result
    }

    /// Plans `blocks` from `start` with the whole job in view: the core's planner, as
    /// the controller would with unlimited look-ahead ([`pkmc::planner::plan_into`]).
    fn plan(&mut self, blocks: &[Block], start: [i64; 6]) -> Result<Vec<PlannedBlock>, LinkError> {
        let kin = MachineKinematics::new(&self.machine);
        let mut out = vec![PlanBlock::default(); blocks.len()];
        let window = pkmc::interp::window_of(self.machine.motion.smoothing_ticks as u32);
        plan_into(blocks, start, &self.machine, &kin, window, &mut out).map_err(|(i, _)| {
            LinkError::BadBlock {
                port: self.port(),
                line: blocks[i].line,
            }
        })?;
        self.stats.plan_time_s =
            pkmc::planner::planned_ticks(&out) * pkmc::units::TICK_NS as f64 * 1e-9;
        Ok(blocks
            .iter()
            .zip(&out)
            .map(|(b, p)| PlannedBlock {
                block: *b,
                plan: p.plan(),
            })
            .collect())
    }

    fn job_loop(
        &mut self,
        blocks: &[Block],
        planned: &[PlannedBlock],
        hooks: &mut dyn JobHooks,
        job: &mut JobState,
    ) -> Result<JobEnd, LinkError> {
        let total = blocks.len();
        loop {
            let now = Instant::now();
            // Operator commands.
            let view = LinkView {
                status: self.status.clone(),
                acked: job.acked,
                total,
                control_pending: self.control.is_some() || !self.controls.is_empty(),
            };
            if let Some(cmd) = hooks.control(&view) {
                self.controls.push_back(cmd);
            }
            if job.acked == total && !job.end_sent && job.ending.is_none() {
                // Every block is on the controller: the job is complete there (a host
                // lost before this leaves an unfinished job, an alarm).
                job.end_sent = true;
                self.controls.push_back(Control::EndJob);
            }
            self.service_controls(now, job)?;
            // Blocks, within credits and the buffered-motion limit.
            if job.ending.is_none() && self.tx.is_empty() {
                while job.sent < total
                    && job.sent - job.acked < job.free.min(job.window)
                    && job.bend_free_for(job.sent)
                    && job.buffered_ms < self.opts.max_buffered_ms
                    && (job.sent == job.acked
                        || job.buffered_ms as f64 + job.in_flight_ms()
                            < self.opts.max_buffered_ms as f64)
                {
                    let seq = job.seq_of(job.sent);
                    self.queue(seq, &HostMsg::Block(planned[job.sent]))?;
                    if job.sent < job.high {
                        self.stats.resent += 1;
                    } else {
                        self.stats.blocks_sent += 1;
                    }
                    job.sent += 1;
                    job.high = job.high.max(job.sent);
                    if job.sent - job.acked == 1 {
                        job.last_progress = now;
                    }
                }
            }
            // Heartbeat: a status request every `keepalive`, so the controller hears
            // the host (it stops after 1 s of silence while moving) and the host hears
            // the controller.
            if self.last_request.elapsed() > self.opts.keepalive {
                self.queue(0, &HostMsg::StatusRequest)?;
                self.stats.status_requests += 1;
                self.last_request = now;
            }
            self.flush_some()?;
            let wait = if self.tx.is_empty() {
                READ_WAIT
            } else {
                Duration::ZERO
            };
            for m in self.pump(wait)? {
                if let Some(end) = self.handle(m, blocks, hooks, job)? {
                    return Ok(end);
                }
            }
            // Retransmission timeout.
            if job.sent > job.acked && job.last_progress.elapsed() > self.opts.resend_after {
                self.stats.timeouts += 1;
                job.rewind_to(job.acked, &mut self.stats);
                job.guard = None;
                job.last_progress = Instant::now();
            }
            if self.last_heard.elapsed() > self.opts.link_timeout {
                return Err(self.lost(
                    if job.acked < total {
                        "streaming blocks"
                    } else {
                        "waiting for the end of the job"
                    },
                    self.last_heard,
                ));
            }
        }
    }

    fn service_controls(&mut self, now: Instant, job: &mut JobState) -> Result<(), LinkError> {
        if self.control.is_none() {
            if let Some(cmd) = self.controls.pop_front() {
                let id = self.fresh_control_id();
                self.control = Some(PendingControl {
                    id,
                    cmd,
                    sent_at: None,
                });
                // An immediate stop overrides a controlled one still under way.
                let ends = match cmd {
                    Control::Stop => true,
                    Control::Abort => job.ending.is_none(),
                    _ => false,
                };
                if ends {
                    job.ending = Some(Ending {
                        cmd,
                        id,
                        acked: false,
                    });
                }
            }
        }
        if let Some(pc) = self.control.as_mut() {
            let due = pc
                .sent_at
                .is_none_or(|t| now.duration_since(t) > CONTROL_RESEND_AFTER);
            if due {
                if pc.sent_at.is_some() {
                    self.stats.controls_resent += 1;
                } else {
                    self.stats.controls += 1;
                }
                pc.sent_at = Some(now);
                let (id, cmd) = (pc.id, pc.cmd);
                self.queue(0, &HostMsg::Control { id, cmd })?;
            }
        }
        Ok(())
    }

    fn handle(
        &mut self,
        m: CtrlMsg,
        blocks: &[Block],
        hooks: &mut dyn JobHooks,
        job: &mut JobState,
    ) -> Result<Option<JobEnd>, LinkError> {
        let total = blocks.len();
        match m {
            CtrlMsg::Ack {
                seq,
                free_slots,
                free_bends,
                buffered_ms,
            } => {
                if let Some(done) = job.index_after(seq) {
                    if done > job.acked {
                        job.advance(done);
                    }
                    job.free = free_slots as usize;
                    job.free_bends = free_bends as usize;
                    job.buffered_ms = buffered_ms;
                }
            }
            CtrlMsg::Nak { expected, reason } => {
                self.stats.naks += 1;
                match reason {
                    NakReason::Corrupt => self.stats.nak_reasons.corrupt += 1,
                    NakReason::Gap => self.stats.nak_reasons.gap += 1,
                    NakReason::QueueFull => self.stats.nak_reasons.queue_full += 1,
                    _ => self.stats.nak_reasons.other += 1,
                }
                let at = job.index_at(expected);
                if let Some(at) = at {
                    if at > job.acked {
                        job.advance(at);
                    }
                }
                match reason {
                    NakReason::Version => {
                        return Err(LinkError::Version {
                            port: self.port(),
                            theirs: None,
                        })
                    }
                    NakReason::NoSession => {
                        return Err(LinkError::SessionLost { port: self.port() })
                    }
                    NakReason::MachineMismatch => {
                        return Err(LinkError::MachineMismatch { port: self.port() })
                    }
                    NakReason::JobHeld => {
                        return Err(LinkError::JobHeld {
                            port: self.port(),
                            job: self.held.unwrap_or(pkmc::protocol::HeldJob {
                                host: 0,
                                line: self.status.as_ref().map_or(0, |s| s.line),
                                done: 0,
                                queued: 0,
                                state: self.status.as_ref().map_or(State::Hold, |s| s.state),
                            }),
                        })
                    }
                    NakReason::BadBlock => {
                        let line = at.and_then(|i| blocks.get(i)).map_or(0, |b| b.line);
                        return Err(LinkError::BadBlock {
                            port: self.port(),
                            line,
                        });
                    }
                    NakReason::QueueFull => job.free = 0,
                    _ => {}
                }
                if let Some(at) = at {
                    if job.ending.is_none() && at < job.sent {
                        match job.guard.as_mut() {
                            Some(g) if g.at == at && g.stale_left > 0 => {
                                g.stale_left -= 1;
                                self.stats.naks_ignored += 1;
                            }
                            _ => {
                                let stale = job.sent - at - 1;
                                job.rewind_to(at, &mut self.stats);
                                job.guard = Some(Guard {
                                    at,
                                    stale_left: stale,
                                });
                                job.last_progress = Instant::now();
                            }
                        }
                    } else {
                        self.stats.naks_ignored += 1;
                    }
                }
            }
            CtrlMsg::ControlAck { id } => {
                if self.control.is_some_and(|pc| pc.id == id) {
                    self.control = None;
                }
                if let Some(e) = job.ending.as_mut() {
                    if e.id == id {
                        e.acked = true;
                    }
                }
            }
            CtrlMsg::Status(s) => {
                // Blocks executed were accepted: a lost final `Ack` need not be waited for.
                let executed = s.blocks_done.wrapping_sub(job.done_before) as usize;
                if executed > job.acked && executed <= job.high {
                    job.advance(executed);
                }
                job.free = s.free_slots as usize;
                job.free_bends = s.free_bends as usize;
                job.buffered_ms = s.buffered_ms;
                hooks.status(&s);
                if s.state == State::Hold
                    && s.speed == 0
                    && job.ending.is_none()
                    && self.control.is_none()
                    && hooks.ends_at_pause()
                {
                    // Held at a pause with nobody here to resume it: the job stays
                    // held on the controller for `nc-send resume`.
                    return Ok(Some(JobEnd::Paused(s.line)));
                }
                // A fault stops on the path first: the job ends once at rest.
                if matches!(s.state, State::Alarm | State::EStop) && s.speed == 0 {
                    if job
                        .ending
                        .is_some_and(|e| e.acked && e.cmd == Control::Stop)
                    {
                        return Ok(Some(JobEnd::Stopped));
                    }
                    if let Some(a) = s.alarm {
                        return Ok(Some(JobEnd::Alarm(a)));
                    }
                }
                if let Some(e) = job.ending.filter(|e| e.acked) {
                    if e.cmd == Control::Abort && s.state == State::Idle && s.speed == 0 {
                        return Ok(Some(JobEnd::Aborted));
                    }
                }
                if job.ending.is_none()
                    && job.acked == total
                    && job.end_sent
                    && self.control.is_none()
                    && self.controls.is_empty()
                    && s.state == State::Idle
                    && s.blocks_done >= job.done_before.wrapping_add(total as u32)
                {
                    return Ok(Some(JobEnd::Done));
                }
                let dwell = dwell_ticks(blocks, job.done_before, &s);
                self.check_stall(&mut job.stall, &s, dwell)?;
            }
            CtrlMsg::HelloAck { .. }
            | CtrlMsg::MachineLoaded { .. }
            | CtrlMsg::MachineRefused { .. } => {}
        }
        Ok(None)
    }
}

#[derive(Clone, Copy, Debug)]
struct Guard {
    /// Index the stream was rewound to.
    at: usize,
    /// `Nak`s for the same index still expected from frames sent before the rewind.
    stale_left: usize,
}

#[derive(Clone, Copy, Debug)]
struct Ending {
    cmd: Control,
    id: u16,
    acked: bool,
}

/// Book-keeping of one streamed job: indices into the job's blocks.
struct JobState {
    base_seq: u16,
    /// Blocks accepted (cumulatively acknowledged).
    acked: usize,
    /// Next block to send.
    sent: usize,
    /// One past the highest block ever sent.
    high: usize,
    free: usize,
    /// `Control::EndJob` has been queued.
    end_sent: bool,
    /// Free bends (arcs the controller can take) after the last acknowledged block.
    free_bends: usize,
    /// `arcs_before[i]`: arcs among the blocks before `i`.
    arcs_before: Vec<usize>,
    buffered_ms: u32,
    window: usize,
    capacity: usize,
    guard: Option<Guard>,
    last_progress: Instant,
    done_before: u32,
    ending: Option<Ending>,
    planned_ms: Vec<f64>,
    stall: StallGuard,
}

impl JobState {
    fn new(base_seq: u16, capacity: u16, status: &Status) -> Self {
        Self {
            base_seq,
            acked: 0,
            sent: 0,
            high: 0,
            free: status.free_slots as usize,
            end_sent: false,
            free_bends: status.free_bends as usize,
            arcs_before: Vec::new(),
            buffered_ms: status.buffered_ms,
            window: (capacity as usize).max(MIN_WINDOW),
            capacity: (capacity as usize).max(MIN_WINDOW),
            guard: None,
            last_progress: Instant::now(),
            done_before: status.blocks_done,
            ending: None,
            planned_ms: Vec::new(),
            stall: StallGuard::default(),
        }
    }

    /// May block `i` be sent as far as bends go? Lines always; an arc while the arcs
    /// in flight before it leave the controller a free bend.
    fn bend_free_for(&self, i: usize) -> bool {
        match (self.arcs_before.get(i), self.arcs_before.get(i + 1)) {
            (Some(a), Some(b)) if b > a => {
                a - self.arcs_before.get(self.acked).copied().unwrap_or(0) < self.free_bends
            }
            _ => true,
        }
    }

    /// Estimated motion of the blocks in flight, ms.
    fn in_flight_ms(&self) -> f64 {
        match (
            self.planned_ms.get(self.sent),
            self.planned_ms.get(self.acked),
        ) {
            (Some(s), Some(a)) => s - a,
            _ => 0.0,
        }
    }

    fn seq_of(&self, index: usize) -> u16 {
        self.base_seq.wrapping_add(index as u16)
    }

    /// Index of the block with sequence number `seq`, if it is within what was sent
    /// (or one past it).
    fn index_at(&self, seq: u16) -> Option<usize> {
        let d = seq.wrapping_sub(self.seq_of(self.acked)) as i16 as i64;
        let i = self.acked as i64 + d;
        (i >= 0 && i as usize <= self.high).then_some(i as usize)
    }

    /// Number of blocks accepted if block `seq` is the last one accepted.
    fn index_after(&self, seq: u16) -> Option<usize> {
        let d = seq.wrapping_sub(self.seq_of(self.acked)) as i16 as i64;
        let n = self.acked as i64 + d + 1;
        (n >= 0 && n as usize <= self.high).then_some(n as usize)
    }

    fn advance(&mut self, acked: usize) {
        let k = acked - self.acked;
        self.acked = acked;
        self.sent = self.sent.max(acked);
        self.window = (self.window + k.min(4)).min(self.capacity);
        self.last_progress = Instant::now();
        if self.guard.is_some_and(|g| g.at < acked) {
            self.guard = None;
        }
    }

    fn rewind_to(&mut self, at: usize, stats: &mut ClientStats) {
        if at >= self.sent {
            return;
        }
        stats.rewinds += 1;
        self.sent = at;
        self.window = (self.window / 2).max(MIN_WINDOW);
    }
}

#[cfg(test)]
mod tests {
    #[cfg(unix)]
    #[test]
    fn a_port_reads_without_blocking_so_bytes_taken_by_another_reader_cannot_hang_the_client() {
        use std::io::Write;
        let (mut master, slave) = serialport::TTYPort::pair().unwrap();
        let path = serialport::SerialPort::name(&slave).unwrap();
        let mut port = super::PortTransport::open(&path).unwrap();
        // Another process opens the same port and takes what arrives.
        let mut thief = std::fs::File::open(&path).unwrap();
        master.write_all(b"x").unwrap();
        let mut one = [0u8; 1];
        std::io::Read::read(&mut thief, &mut one).unwrap();
        // The descriptor does not block: a read that finds nothing (as after a poll
        // that saw the stolen byte) returns at once instead of waiting forever.
        // SAFETY: fcntl on the transport's own, open descriptor.
        let flags = unsafe { libc::fcntl(port.fd, libc::F_GETFL) };
        assert_ne!(
            flags & libc::O_NONBLOCK,
            0,
            "a blocking read would wait forever"
        );
        // SAFETY: read into a live one-byte buffer from the same descriptor.
        let n = unsafe { libc::read(port.fd, one.as_mut_ptr().cast(), 1) };
        assert_eq!(n, -1);
        assert_eq!(
            std::io::Error::last_os_error().kind(),
            std::io::ErrorKind::WouldBlock
        );
        let start = std::time::Instant::now();
        let got = super::Transport::read_some(&mut port, &mut one, Duration::from_millis(50));
        assert_eq!(got.unwrap(), 0);
        assert!(start.elapsed() < Duration::from_secs(1));
    }

    use super::*;

    fn status() -> Status {
        Status {
            state: State::Idle,
            line: 0,
            blocks_done: 0,
            motion_ticks: 0,
            pose: [0; 6],
            joints: [0; pkmc::config::MAX_JOINTS],
            speed: 0,
            buffered_ms: 0,
            free_slots: 64,
            free_bends: 64,
            feed_override: 100,
            alarm: None,
            homed: false,
            orphan: false,
        }
    }

    fn block(motion: Motion, target: [i64; 6], feed_mm_s: i64) -> Block {
        Block {
            line: 1,
            motion,
            target,
            feed: feed_mm_s * 1_000_000,
            tolerance_nm: 0,
        }
    }

    #[test]
    fn motion_estimates_follow_feed_rapid_limits_arcs_and_dwells() {
        let vmax = [100_000_000; 6];
        let at = [0; 6];
        let mm = 1_000_000;
        let line = block(Motion::Linear, [30 * mm, 40 * mm, 0, 0, 0, 0], 10);
        assert!((estimate_ms(&at, &line, &vmax) - 5000.0).abs() < 1e-6);
        let rapid = block(Motion::Rapid, [50 * mm, 10 * mm, 0, 0, 0, 0], 0);
        assert!((estimate_ms(&at, &rapid, &vmax) - 500.0).abs() < 1e-6);
        // A half circle of radius 10 mm at 10 mm/s: 10π mm in π s.
        let half = block(
            Motion::Arc {
                center: [10 * mm, 0],
                plane: pkmc::protocol::Plane::Xy,
                clockwise: true,
                turns: 0,
            },
            [20 * mm, 0, 0, 0, 0, 0],
            10,
        );
        let ms = estimate_ms(&at, &half, &vmax);
        assert!((ms - std::f64::consts::PI * 1000.0).abs() < 1e-3, "{ms}");
        // The other way round with one extra turn: three half circles.
        let long = block(
            Motion::Arc {
                center: [10 * mm, 0],
                plane: pkmc::protocol::Plane::Xy,
                clockwise: false,
                turns: 1,
            },
            [20 * mm, 0, 0, 0, 0, 0],
            10,
        );
        let ms = estimate_ms(&at, &long, &vmax);
        assert!(
            (ms - 3.0 * std::f64::consts::PI * 1000.0).abs() < 1e-3,
            "{ms}"
        );
        assert_eq!(
            estimate_ms(&at, &block(Motion::Dwell(250), at, 0), &vmax),
            250.0
        );
    }

    #[test]
    fn sequence_numbers_map_to_block_indices_across_the_wrap() {
        let mut job = JobState::new(u16::MAX - 2, 64, &status());
        job.high = 8;
        job.advance(5);
        assert_eq!(job.seq_of(5), 2);
        assert_eq!(job.index_at(2), Some(5));
        assert_eq!(job.index_after(2), Some(6));
        assert_eq!(job.index_after(u16::MAX), Some(3));
        assert_eq!(job.index_at(9), None, "beyond what was sent");
    }

    #[test]
    fn a_rewind_halves_the_window_and_acknowledgements_grow_it_back() {
        let mut job = JobState::new(1, 64, &status());
        let mut stats = ClientStats::default();
        job.sent = 40;
        job.high = 40;
        job.rewind_to(10, &mut stats);
        assert_eq!((job.sent, job.window, stats.rewinds), (10, 32, 1));
        job.advance(2);
        assert_eq!(job.window, 34, "grown by the blocks acknowledged");
        job.advance(12);
        assert_eq!(job.window, 38, "by at most four per acknowledgement");
    }
}
