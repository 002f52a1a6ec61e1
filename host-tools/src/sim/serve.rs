//! The simulator's board loop: [`serve`] runs a [`Simulator`] behind a serial port (a
//! pseudo-terminal), optionally through a [`FaultyLine`]; [`InProcess`] is the same
//! simulator as a [`Transport`] in this process (`nc-send --check`). Either way the
//! client reaches the controller only through its bytes, as it reaches a board.
//!
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

use crate::link::{is_timeout, Transport};
use crate::sim::faults::FaultyLine;
use crate::sim::Simulator;
use pkmc::wire::State;
use serialport::SerialPort;
use std::io;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

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
fn settle(sim: &mut Simulator) -> crate::sim::Result<bool> {
    if sim.ctrl.state() == State::Hold && !sim.ctrl.has_work() {
        sim.tick()?;
        return Ok(true);
    }
    Ok(false)
}

/// Why the simulator's board loop stopped: reading or writing its port, the
/// simulation itself, or the trace failed.
#[derive(Debug, thiserror::Error)]
#[error("{port}: {op} failed: {source}")]
pub struct ServeError {
    /// Port.
    pub port: String,
    /// What failed ("read", "write", "simulate", ...).
    pub op: &'static str,
    /// Why.
    #[source]
    pub source: io::Error,
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
    /// Always one tick per millisecond of wall time, as a board: for senders that
    /// watch the machine move (`nc-send grbl`).
    RealTime,
}

/// The board loop's memory between turns.
struct Board<'a> {
    port: &'a mut dyn SerialPort,
    faults: Option<&'a mut FaultyLine>,
    name: String,
    stats: ServeStats,
    buf: Vec<u8>,
    out: Vec<u8>,
    line_out: Vec<u8>,
    pending: Vec<u8>,
    /// Wall time of the last bytes delivered to the controller.
    delivered: Instant,
    /// Wall time at which the host last queued a block, or the controller's queue was
    /// last seen full: the host is streaming.
    fed: Instant,
    /// The end of an injected link cut.
    cut_until: Option<Instant>,
    /// Wall time at which the next paced tick is due; `None` while running free.
    next_tick: Option<Instant>,
}

impl Board<'_> {
    fn error(&self, op: &'static str, source: io::Error) -> ServeError {
        ServeError {
            port: self.name.clone(),
            op,
            source,
        }
    }

    /// Takes what the port has (waiting up to `wait`) to the controller, through the
    /// faulty line when there is one; a cut line delivers nothing.
    fn receive(
        &mut self,
        sim: &mut Simulator,
        wait: Duration,
        cut: bool,
        free_before: u16,
        on_tick: &mut dyn FnMut(&Simulator),
    ) -> Result<(), ServeError> {
        self.port
            .set_timeout(wait)
            .map_err(|e| self.error("read", e.into()))?;
        match self.port.read(&mut self.buf) {
            Ok(_) if cut => {}
            Ok(n) => {
                self.stats.bytes_in += n as u64;
                if n > 0 {
                    self.delivered = Instant::now();
                }
                match self.faults.as_deref_mut() {
                    Some(line) => {
                        self.line_out.clear();
                        line.towards_controller(&self.buf[..n], &mut self.line_out);
                        sim.ctrl.receive(&self.line_out);
                    }
                    None => sim.ctrl.receive(&self.buf[..n]),
                }
                if sim.ctrl.status().free_slots < free_before {
                    // Blocks queued (the queue only fills on receipt).
                    self.fed = Instant::now();
                }
                sim.persist()
                    .map_err(|e| self.error("store the machine", io::Error::other(e)))?;
                if settle(sim).map_err(|e| self.error("simulate", io::Error::other(e)))? {
                    on_tick(sim);
                }
            }
            Err(e) if is_timeout(&e) => {}
            Err(e) => return Err(self.error("read", e)),
        }
        Ok(())
    }

    /// Takes what the controller has to say and writes what the port accepts now; a
    /// cut line loses it.
    fn transmit(&mut self, sim: &mut Simulator, cut: bool) -> Result<(), ServeError> {
        loop {
            let n = sim.ctrl.transmit(&mut self.out);
            if n == 0 {
                break;
            }
            if cut {
                continue;
            }
            match self.faults.as_deref_mut() {
                Some(line) => line.towards_host(&self.out[..n], &mut self.pending),
                None => self.pending.extend_from_slice(&self.out[..n]),
            }
        }
        if self.pending.is_empty() {
            return Ok(());
        }
        // No wait: a host that does not read (stopped, or gone) must not slow the
        // board's clock down; what the port does not take now waits in `pending`.
        self.port
            .set_timeout(Duration::ZERO)
            .map_err(|e| self.error("write", e.into()))?;
        match self.port.write(&self.pending) {
            Ok(n) => {
                self.stats.bytes_out += n as u64;
                self.pending.drain(..n);
            }
            Err(e) if is_timeout(&e) => {}
            Err(e) => return Err(self.error("write", e)),
        }
        Ok(())
    }

    /// The next paced deadline, one tick on; a server that fell further behind than
    /// it may catch up lets simulated time lag instead.
    fn next_deadline(&mut self) {
        if let Some(t) = self.next_tick.as_mut() {
            *t += Duration::from_nanos(pkmc::units::TICK_NS as u64);
            let late = Instant::now().saturating_duration_since(*t);
            if late > PACE_CATCH_UP {
                *t += late - PACE_CATCH_UP;
            }
        }
    }
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
    faults: Option<&mut FaultyLine>,
    clock: ServeClock,
    on_tick: &mut dyn FnMut(&Simulator),
) -> Result<ServeStats, ServeError> {
    let now = Instant::now();
    let mut board = Board {
        name: port.name().unwrap_or_else(|| "pseudo-terminal".into()),
        port,
        faults,
        stats: ServeStats::default(),
        buf: vec![0u8; 65536],
        out: vec![0u8; pkmc::controller::TX_CAPACITY],
        line_out: Vec::with_capacity(65536),
        pending: Vec::with_capacity(65536),
        delivered: now,
        fed: now,
        cut_until: None,
        next_tick: None,
    };
    while !stop.load(Ordering::Relaxed) {
        let now = Instant::now();
        if sim.take_link_cut() {
            board.cut_until = Some(now + crate::sim::LINK_CUT);
        }
        let cut = board.cut_until.is_some_and(|t| now < t);
        // Simulated time may run ahead of the host's wall clock; it may pass the
        // controller's link-loss limit only when the host has really been silent
        // that long (or the line is cut).
        let limit = sim.ctrl.silence_limit();
        let limit_wall = Duration::from_nanos(limit as u64 * pkmc::units::TICK_NS as u64);
        let starved =
            sim.ctrl.link_silence_ticks() + 1 >= limit && board.delivered.elapsed() < limit_wall;
        let busy = sim.busy() && !starved;
        let status = sim.ctrl.status();
        if status.free_slots == 0 || status.free_bends == 0 {
            // A full queue (or ring of arcs): a streaming host waits only for the next
            // free slot.
            board.fed = now;
        }
        let paced = busy
            && (clock == ServeClock::RealTime
                || sim.ctrl.recording()
                || clock == ServeClock::Paced
                    && status.buffered_ms < PACE_BELOW_MS
                    && now.duration_since(board.fed) < PACE_AFTER_BLOCKS);
        // Paced, the tick is due at its deadline (at once when pacing starts); free,
        // at once.
        let due = if paced {
            *board.next_tick.get_or_insert(now)
        } else {
            board.next_tick = None;
            now
        };
        let tick_now = busy && now >= due;
        let ready = if tick_now {
            board.port.bytes_to_read().unwrap_or(0) as usize
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
            board.receive(sim, wait, cut, status.free_slots, on_tick)?;
        }
        if tick_now {
            sim.tick()
                .map_err(|e| board.error("simulate", io::Error::other(e)))?;
            on_tick(sim);
            board.next_deadline();
        }
        board.transmit(sim, cut)?;
    }
    // The host is done: servo joints still settling on their last targets finish
    // doing so (the controller itself has nothing left to do).
    while !sim.ctrl.has_work() && sim.busy() {
        sim.tick()
            .map_err(|e| board.error("simulate", io::Error::other(e)))?;
        on_tick(sim);
    }
    sim.finish_trace()
        .map_err(|e| board.error("write the trace", io::Error::other(e)))?;
    Ok(board.stats)
}
