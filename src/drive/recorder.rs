//! The data recorder (issue 35, first part): up to [`MAX_SIGNALS`] signals from a
//! fixed list ([`Signal`]), sampled every servo period or every tick with a chosen
//! decimation, kept in a RAM ring, captured around a trigger ([`Trigger`]) with a
//! chosen number of pre-trigger samples, and read out afterwards in order
//! ([`Recorder::read`]).
//!
//! **Memory.** The ring is [`RING_BYTES`] bytes, taken from the controller's look-ahead
//! queue: [`RING_SLOTS`] of its line-sized slots of 160 bytes on the MCU
//! (`motion::planner::QUEUE_CAPACITY` is that much shorter; `docs/recorder.md`). A
//! sample is the signals' values side by side, little-endian, each 2 or 4 bytes
//! ([`Signal::width`]): the following error, the DAC code or step rate and the state
//! fit 16 bits (saturated), positions, speed, contour error and line take 32. So the
//! ring holds `RING_BYTES / sample width` samples: 90 of eight 16-bit signals
//! (9 ms at 10 kHz, 90 ms at 1 kHz), 45 of eight 32-bit ones.
//!
//! **Sampling.** The caller forms the values of the configured signals and hands them
//! to [`Recorder::sample`] once per servo period or tick (as [`Setup::servo`] says);
//! every `decimate`th call stores one sample. The fast path is a counter, a
//! comparison and the stores of the sample's bytes. Events (a job started, an NC
//! line began, an alarm was raised) are read from what [`Recorder::observe`] is told
//! every tick; they latch, so decimation cannot miss them.
//!
//! **Capture.** Armed, the recorder stores samples continuously in the ring. At the
//! trigger (its sample is the first of the trigger condition) it keeps up to `pre`
//! samples before it, the trigger's sample and as many after as fill the ring, and
//! stops ([`Phase::Done`]). A trigger before `pre` samples were stored keeps those
//! there are ([`Capture::pre`]).
//!
//! Invariants: no allocation, no time source; the ring is never read while the
//! recorder writes it (readout is of a finished capture).

use crate::config::MAX_JOINTS;

/// Signals a capture can hold.
pub const MAX_SIGNALS: usize = 8;
/// Queue slots of 160 bytes (on the MCU) given to the ring.
pub const RING_SLOTS: usize = 9;
/// The ring's size, bytes.
pub const RING_BYTES: usize = RING_SLOTS * 160;
/// Bytes a sample can take at most (eight 32-bit signals).
pub const ROW_BYTES: usize = MAX_SIGNALS * 4;

/// A sample as the ring keeps it: its signals' values side by side, little-endian,
/// each 2 or 4 bytes ([`Signal::width`]); the bytes past its width are unused.
pub type Row = [u8; ROW_BYTES];

/// A signal the recorder can sample. Its wire id is `kind << 4 | joint`
/// ([`Signal::id`], [`Signal::from_id`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Signal {
    /// Joint's commanded position, actuator counts or steps (kind 0).
    Commanded(u8),
    /// Joint's measured position, actuator counts or steps (kind 1).
    Measured(u8),
    /// Joint's following error, commanded − measured, counts; 16 bits (kind 2).
    FollowingError(u8),
    /// Joint's DAC code (servo: the period's, or at the tick the mean of its periods)
    /// or step rate, steps per tick (stepper); 16 bits (kind 3).
    Output(u8),
    /// The path speed, µm/s (kind 8).
    PathSpeed,
    /// The contour error of the path, the size of its X Y Z part, nm (kind 9).
    ContourError,
    /// The contour error of the tool's direction, the size of its A B part, µ° (kind
    /// 10; zero on machines that do not tilt the tool).
    DirectionError,
    /// The NC line being executed (kind 11).
    Line,
    /// The controller's state, as `wire::State`'s index; 16 bits (kind 12).
    State,
}

/// A recorder request the recorder refuses, naming what is wrong and where.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RecorderError {
    /// Signal number `index` of the request has an id that names no signal.
    BadSignal {
        /// Its place in the request's list.
        index: u8,
        /// The id.
        id: u8,
    },
    /// No signals, or more than [`MAX_SIGNALS`].
    SignalCount {
        /// Signals asked for.
        count: u8,
    },
    /// A decimation of 0.
    Decimation,
    /// The request holds a bad value at byte `at` ([`Setup::unpack`]), or (`at`
    /// 255) asks for nothing the recorder does.
    Malformed {
        /// The byte's place.
        at: u8,
    },
    /// The level trigger names signal number `index`, beyond the request's signals.
    TriggerSignal {
        /// The signal number it names.
        index: u8,
    },
    /// A test signal (`drive::excite`) while the machine is not homed and standing
    /// idle with nothing queued.
    ExciteBusy,
    /// A test signal on joint `joint`, which is not driven by a servo channel.
    ExciteJoint {
        /// The joint.
        joint: u8,
    },
    /// A test signal's amplitude not below joint `joint`'s standstill
    /// following-error limit of `limit` counts.
    ExciteAmplitude {
        /// The joint.
        joint: u8,
        /// The limit, counts.
        limit: u16,
    },
    /// A test signal that would take joint `joint` outside its travel.
    ExciteTravel {
        /// The joint.
        joint: u8,
    },
    /// `pre` pre-trigger samples asked; the ring holds `capacity` of these signals.
    PreTrigger {
        /// Pre-trigger samples asked for.
        pre: u16,
        /// Samples the ring holds.
        capacity: u16,
    },
}

impl Signal {
    /// The signal of wire id `id`, or `None`.
    pub fn from_id(id: u8) -> Option<Self> {
        let joint = id & 0x0f;
        let per_joint = (joint as usize) < MAX_JOINTS;
        Some(match id >> 4 {
            0 if per_joint => Self::Commanded(joint),
            1 if per_joint => Self::Measured(joint),
            2 if per_joint => Self::FollowingError(joint),
            3 if per_joint => Self::Output(joint),
            8 if joint == 0 => Self::PathSpeed,
            9 if joint == 0 => Self::ContourError,
            10 if joint == 0 => Self::DirectionError,
            11 if joint == 0 => Self::Line,
            12 if joint == 0 => Self::State,
            _ => return None,
        })
    }

    /// The signal's wire id.
    pub fn id(self) -> u8 {
        match self {
            Self::Commanded(j) => j,
            Self::Measured(j) => 0x10 | j,
            Self::FollowingError(j) => 0x20 | j,
            Self::Output(j) => 0x30 | j,
            Self::PathSpeed => 0x80,
            Self::ContourError => 0x90,
            Self::DirectionError => 0xa0,
            Self::Line => 0xb0,
            Self::State => 0xc0,
        }
    }

    /// Bytes a sample of this signal takes in the ring.
    pub fn width(self) -> u8 {
        match self {
            Self::FollowingError(_) | Self::Output(_) | Self::State => 2,
            _ => 4,
        }
    }
}

/// What starts a capture.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Trigger {
    /// The first sample after arming.
    Now,
    /// A job starts (its first block is queued), or a move sent alone (MDI, a jog)
    /// starts running.
    JobStart,
    /// NC line `n` begins executing.
    Line(u32),
    /// Any alarm is raised.
    Alarm,
    /// No capture: continuous mode. The ring is a queue of the samples not yet sent,
    /// which the controller streams as they come ([`Recorder::unsent`],
    /// [`Recorder::sent`]); when the link falls behind, the oldest are overwritten
    /// and their loss shows as a gap in the samples' numbers.
    Stream,
    /// The request's signal number `signal` crosses `level`: upward when `rising`
    /// (from below it to at or above it), else downward.
    Level {
        /// The signal's number in the request.
        signal: u8,
        /// The level.
        level: i32,
        /// Upward crossing; else downward.
        rising: bool,
    },
}

/// A capture's request.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Setup {
    /// The signals' wire ids; `count` of them are used.
    pub signals: [u8; MAX_SIGNALS],
    /// Signals used.
    pub count: u8,
    /// Sample in every servo period (10 kHz) rather than every tick (1 kHz).
    pub servo: bool,
    /// Store every `decimate`th period or tick (at least 1).
    pub decimate: u16,
    /// What starts the capture.
    pub trigger: Trigger,
    /// Samples to keep before the trigger's.
    pub pre: u16,
}

/// Where a capture is.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Phase {
    /// Nothing armed.
    #[default]
    Off,
    /// Recording, waiting for the trigger.
    Armed,
    /// Triggered, filling the samples after it.
    Triggered,
    /// The capture is complete: read it out.
    Done,
    /// Streaming continuously ([`Trigger::Stream`]).
    Streaming,
}

/// What a capture holds, for its readout.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Capture {
    /// Where it is.
    pub phase: Phase,
    /// Samples in the capture (when done), or stored so far.
    pub samples: u16,
    /// Samples before the trigger's.
    pub pre: u16,
    /// Bytes a sample takes.
    pub width: u16,
}

/// The recorder's book-keeping (all but the ring).
#[derive(Clone, Copy, Debug)]
struct Book {
    setup: Setup,
    width: u16,
    /// Bit i: signal i is stored in 16 bits.
    narrow: u8,
    /// Samples the ring holds at this width.
    capacity: u16,
    phase: Phase,
    /// Calls until the next stored sample.
    countdown: u16,
    /// The next sample's index in the ring.
    head: u16,
    /// Samples stored since arming (saturating at `capacity`); streaming, those not
    /// sent yet.
    stored: u16,
    /// Samples still to store after the trigger.
    remaining: u16,
    pre_kept: u16,
    /// An awaited event happened since the last stored sample.
    pending: bool,
    /// The level signal's last stored value.
    last_level: Option<i32>,
    /// The level signal's first byte in a sample.
    level_at: u8,
    /// Streaming: samples stored since arming (the next one's number), wrapping.
    taken: u32,
}

const OFF: Book = Book {
    setup: Setup {
        signals: [0; MAX_SIGNALS],
        count: 0,
        servo: false,
        decimate: 1,
        trigger: Trigger::Now,
        pre: 0,
    },
    width: 0,
    narrow: 0,
    capacity: 0,
    phase: Phase::Off,
    countdown: 0,
    head: 0,
    stored: 0,
    remaining: 0,
    pre_kept: 0,
    pending: false,
    last_level: None,
    level_at: 0,
    taken: 0,
};

/// The recorder. See the module documentation.
#[derive(Clone, Debug)]
pub struct Recorder {
    s: Book,
    /// What [`Recorder::observe`] was told last: job open, line, alarm.
    seen: (bool, u32, bool),
    /// The samples, each the little-endian bytes of its signals' values side by side.
    ring: [u8; RING_BYTES],
}

impl Default for Recorder {
    fn default() -> Self {
        Self::new()
    }
}

impl Recorder {
    /// A recorder with nothing armed.
    pub const fn new() -> Self {
        Self {
            s: OFF,
            seen: (false, 0, false),
            ring: [0; RING_BYTES],
        }
    }

    /// Writes a recorder with nothing armed into `p`, field by field (the MCU's stack
    /// need not hold the ring).
    ///
    /// # Safety
    /// `p` valid for writes and aligned.
    pub unsafe fn init_at(p: *mut Self) {
        use core::ptr::addr_of_mut as at;
        // SAFETY: the caller's promise; both fields are written, the ring as zeros.
        unsafe {
            at!((*p).ring).write_bytes(0, 1);
            at!((*p).s).write(OFF);
            at!((*p).seen).write((false, 0, false));
        }
    }

    /// Checks `setup` and arms it, dropping any capture held.
    #[inline(never)]
    pub fn arm(&mut self, setup: &Setup) -> Result<(), RecorderError> {
        let count = setup.count;
        if count == 0 || count as usize > MAX_SIGNALS {
            return Err(RecorderError::SignalCount { count });
        }
        if setup.decimate == 0 {
            return Err(RecorderError::Decimation);
        }
        let mut width = 0u16;
        let mut narrow = 0u8;
        for (i, &id) in setup.signals[..count as usize].iter().enumerate() {
            let s = Signal::from_id(id).ok_or(RecorderError::BadSignal { index: i as u8, id })?;
            width += s.width() as u16;
            if s.width() == 2 {
                narrow |= 1 << i;
            }
        }
        let mut level_at = 0;
        if let Trigger::Level { signal, .. } = setup.trigger {
            if signal >= count {
                return Err(RecorderError::TriggerSignal { index: signal });
            }
            for &id in &setup.signals[..signal as usize] {
                level_at += Signal::from_id(id).map_or(0, Signal::width);
            }
        }
        let capacity = (RING_BYTES / width as usize) as u16;
        let stream = setup.trigger == Trigger::Stream;
        if setup.pre >= capacity || (stream && setup.pre != 0) {
            return Err(RecorderError::PreTrigger {
                pre: setup.pre,
                capacity,
            });
        }
        // The ring stays where it is (no copy of it on the stack).
        self.s = Book {
            setup: *setup,
            width,
            narrow,
            capacity,
            level_at,
            phase: if stream {
                Phase::Streaming
            } else {
                Phase::Armed
            },
            ..OFF
        };
        Ok(())
    }

    /// Stops recording and drops the capture.
    pub fn disarm(&mut self) {
        self.s.phase = Phase::Off;
    }

    /// The request armed last.
    pub fn setup(&self) -> &Setup {
        &self.s.setup
    }

    /// The configured signals' wire ids (the first [`Setup::count`]).
    pub fn signals(&self) -> &[u8] {
        &self.s.setup.signals[..self.s.setup.count as usize]
    }

    /// Recording: samples are wanted, every servo period when `servo`, else every tick.
    pub fn wants(&self, servo: bool) -> bool {
        matches!(
            self.s.phase,
            Phase::Armed | Phase::Triggered | Phase::Streaming
        ) && self.s.setup.servo == servo
    }

    /// Tells the recorder, every tick, of the events it may wait for: a job is open
    /// (`job`; its start is the tick it opens), the NC line executing (`line`; a line
    /// begins the tick it changes to), an alarm is raised (`alarm`; its raising is the
    /// tick it appears). An awaited event is latched for the next stored sample.
    pub fn observe(&mut self, job: bool, line: u32, alarm: bool) {
        let (was_job, was_line, was_alarm) = self.seen;
        if self.s.phase == Phase::Armed {
            self.s.pending |= match self.s.setup.trigger {
                Trigger::JobStart => job && !was_job,
                Trigger::Line(n) => line == n && line != was_line,
                Trigger::Alarm => alarm && !was_alarm,
                _ => false,
            };
        }
        self.seen = (job, line, alarm);
    }

    /// One period's or tick's values of the configured signals (in their order; the
    /// values beyond [`Setup::count`] are ignored). Stores every `decimate`th.
    pub fn sample(&mut self, values: &[i32; MAX_SIGNALS]) {
        let mut row = [0; ROW_BYTES];
        pack(values, self.s.narrow, &mut row);
        self.sample_packed(&row);
    }

    /// [`Recorder::sample`] of a sample already packed ([`Row`]; the servo side's
    /// samples are staged so, `pacing::ServoPacer::staged`).
    pub fn sample_packed(&mut self, row: &Row) {
        if !matches!(
            self.s.phase,
            Phase::Armed | Phase::Triggered | Phase::Streaming
        ) {
            return;
        }
        if self.s.countdown > 0 {
            self.s.countdown -= 1;
            return;
        }
        self.s.countdown = self.s.setup.decimate - 1;
        self.store(row);
        if self.s.phase == Phase::Streaming {
            self.s.taken = self.s.taken.wrapping_add(1);
        } else if self.s.phase == Phase::Armed {
            if self.triggered(row) {
                self.s.pre_kept = self.s.setup.pre.min(self.s.stored - 1);
                self.s.remaining = self.s.capacity - 1 - self.s.pre_kept;
                self.s.phase = Phase::Triggered;
                if self.s.remaining == 0 {
                    self.s.phase = Phase::Done;
                }
            }
        } else {
            self.s.remaining -= 1;
            if self.s.remaining == 0 {
                self.s.phase = Phase::Done;
            }
        }
    }

    fn store(&mut self, row: &Row) {
        let width = self.s.width as usize;
        let at = self.s.head as usize * width;
        if let (Some(out), Some(bytes)) = (self.ring.get_mut(at..at + width), row.get(..width)) {
            // Four bytes at a time (one load and one store each on the M4, which
            // allows them unaligned), then the 16-bit rest: a call to a byte-wise
            // `memcpy` cost twice as much.
            let mut words = out.chunks_exact_mut(4);
            let mut from = bytes.chunks_exact(4);
            for (o, b) in (&mut words).zip(&mut from) {
                o.copy_from_slice(b);
            }
            // Widths are even: the rest is no byte or two.
            let rest = words.into_remainder();
            if let (Some(o), Some(b)) =
                (rest.first_chunk_mut::<2>(), from.remainder().first_chunk())
            {
                *o = *b;
            }
        }
        self.s.head += 1;
        if self.s.head == self.s.capacity {
            self.s.head = 0;
        }
        if self.s.stored < self.s.capacity {
            self.s.stored += 1;
        }
    }

    fn triggered(&mut self, row: &Row) -> bool {
        match self.s.setup.trigger {
            Trigger::Now => true,
            Trigger::Level {
                signal,
                level,
                rising,
            } => {
                let at = self.s.level_at as usize;
                let v = if self.s.narrow & (1 << signal) != 0 {
                    row.get(at..at + 2)
                        .map_or(0, |b| i16::from_le_bytes([b[0], b[1]]) as i32)
                } else {
                    row.get(at..at + 4)
                        .map_or(0, |b| i32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                };
                let crossed = self.s.last_level.is_some_and(|last| {
                    if rising {
                        last < level && v >= level
                    } else {
                        last > level && v <= level
                    }
                });
                self.s.last_level = Some(v);
                crossed
            }
            _ => core::mem::take(&mut self.s.pending),
        }
    }

    /// Streaming: the number of the oldest sample not sent yet, and how many of the
    /// samples waiting fit in `room` bytes (whole samples; `(n, 0)` when nothing waits
    /// or the recorder is not streaming).
    pub fn unsent(&self, room: usize) -> (u32, u16) {
        if self.s.phase != Phase::Streaming || self.s.width == 0 {
            return (self.s.taken, 0);
        }
        let n = self.s.stored.min((room / self.s.width as usize) as u16);
        (self.s.taken.wrapping_sub(self.s.stored as u32), n)
    }

    /// Streaming: the oldest `out.len() / width` unsent samples (at most those
    /// [`Recorder::unsent`] counted) copied into `out`, oldest first.
    pub fn copy_unsent(&self, out: &mut [u8]) {
        let width = self.s.width as usize;
        let total = self.s.capacity as usize * width;
        let first = (self.s.head + self.s.capacity - self.s.stored) % self.s.capacity.max(1);
        let n = out.len().min(self.s.stored as usize * width);
        self.copy_wrapped(first as usize * width, total, &mut out[..n]);
    }

    /// Copies `out.len()` bytes of the ring's first `total`, from byte `from`, wrapping
    /// at `total`: at most two copies.
    fn copy_wrapped(&self, from: usize, total: usize, out: &mut [u8]) {
        let (Some(ring), true) = (self.ring.get(..total), from <= total) else {
            return;
        };
        let (wrapped, from_on) = ring.split_at(from);
        let k = out.len().min(from_on.len());
        let (a, b) = out.split_at_mut(k);
        a.copy_from_slice(&from_on[..k]);
        let m = b.len().min(wrapped.len());
        b[..m].copy_from_slice(&wrapped[..m]);
    }

    /// Streaming: the oldest `n` unsent samples went out.
    pub fn sent(&mut self, n: u16) {
        self.s.stored -= n.min(self.s.stored);
    }

    /// Where the capture is.
    pub fn capture(&self) -> Capture {
        Capture {
            phase: self.s.phase,
            samples: if self.s.phase == Phase::Done {
                self.s.capacity
            } else {
                self.s.stored
            },
            pre: self.s.pre_kept,
            width: self.s.width,
        }
    }

    /// How many of the finished capture's bytes there are from byte `offset` (0 past
    /// the end, or when no capture is finished): what [`Recorder::read`] copies into a
    /// buffer that long.
    pub fn readable(&self, offset: usize) -> usize {
        if self.s.phase != Phase::Done {
            return 0;
        }
        (self.s.capacity as usize * self.s.width as usize).saturating_sub(offset)
    }

    /// Copies the finished capture's bytes from byte `offset` (samples in time order,
    /// oldest first) into `out`; returns the bytes copied (0 past the end, or when no
    /// capture is finished).
    pub fn read(&self, offset: usize, out: &mut [u8]) -> usize {
        if self.s.phase != Phase::Done {
            return 0;
        }
        let total = self.s.capacity as usize * self.s.width as usize;
        if offset >= total {
            return 0;
        }
        // Done means the ring is full: the oldest sample is the one `head` overwrites
        // next.
        let start = self.s.head as usize * self.s.width as usize;
        let n = out.len().min(total - offset);
        self.copy_wrapped((start + offset) % total, total, &mut out[..n]);
        n
    }
}

/// Writes `values` side by side into `out` until it is full ([`put`]): two bytes
/// where bit i of `narrow` is set, else four.
#[inline(always)]
fn pack(values: &[i32; MAX_SIGNALS], narrow: u8, out: &mut [u8]) {
    let mut rest = out;
    let mut narrow = narrow;
    for &v in values {
        let Some(r) = put(rest, v, narrow & 1 == 0) else {
            break;
        };
        rest = r;
        narrow >>= 1;
    }
}

/// Writes `v` at the front of `out` as a sample holds it: its four little-endian
/// bytes when `wide`, else two (saturated to 16 bits). Returns the rest of `out`, or
/// `None` (nothing written) when `out` has no room.
#[inline(always)]
pub fn put(out: &mut [u8], v: i32, wide: bool) -> Option<&mut [u8]> {
    if wide {
        let (o, rest) = out.split_first_chunk_mut::<4>()?;
        *o = v.to_le_bytes();
        Some(rest)
    } else {
        let (o, rest) = out.split_first_chunk_mut::<2>()?;
        *o = (v.clamp(i16::MIN as i32, i16::MAX as i32) as i16).to_le_bytes();
        Some(rest)
    }
}

mod pack;
pub use pack::{Reply, REPLY_HEADER, SETUP_BYTES};

#[cfg(test)]
#[path = "recorder_tests.rs"]
mod tests;
