//! Fixed-period interpolator: executes planned blocks one tick at a time.
//!
//! Source: seeds-digest A, constant path speed with dS = V·T per period T — here the
//! distance per tick comes from the block's [`Profile`] evaluated at the tick's time,
//! and the pose from the block's exact [`crate::motion::geometry::Path`]. Time carries across
//! blocks: when a block ends inside a tick, the rest of the tick is spent on the next
//! block, so a program of segments shorter than one tick's travel still runs at full
//! speed, and the block boundaries do not round to ticks.
//!
//! Jerk limitation (optional, per machine): the path distance s(t) of the profile is
//! passed through a moving average of w = 2ᵏ ticks before the pose is evaluated. The
//! geometry stays exact (only *where along the path* is smoothed, never the path), the
//! average of a motion within speed and acceleration limits stays within them, and the
//! acceleration now changes at most 2a/(w·T) per unit time — a jerk limit. This is the
//! FIR "bell-shaped acceleration" of commercial controllers, applied before
//! interpolation. A blended corner still turns within one tick; the planner keeps each
//! axis's speed change there within aᵢ·T/w (allowing for the smoothed speed exceeding
//! the profile's by up to a·w·T/2 around the corner), so the jerk stays within
//! 3aᵢ/(w·T) everywhere (the machine file picks w from the jerk limit on that basis).
//! Where a corner cannot be blended so, the profile stops there and the next block
//! waits until the smoothed motion has stopped too. The cost: every motion ends w·T/2 later on average, and dwells and
//! auxiliary functions wait for the smoothed motion to arrive.
//!
//! Invariants: the executing block was profiled from the speed the previous one left
//! at toward [`Planner::exit_target`] (the next block's planned entry, and a speed
//! from which the queued blocks can still stop); a hold or a feed-override change
//! re-profiles it from where it is, at the speed it has, so the stop happens on the
//! path and within v²/2a, continuing into the next blocks if need be (each is profiled
//! when it starts, from the speed the previous one left at). No pass over the queue.

use crate::config::AXES;
use crate::kinematics::Unreachable;
use crate::motion::block::Aux;
use crate::motion::geometry::{Bend, Form, Path};
use crate::motion::planner::{Kind, Planner};
use crate::motion::profile::{from_q32, Profile, HELD, TICK_Q32};

/// Profiles the executing block from `from` (nm Q16 into it) at speed `v0` (nm/tick)
/// into `out`, toward the exit speed `target`: up to its dip when `from` is before one
/// (passed at the dip's speed at most, and no faster than the rest of the block can
/// still slow down to `target` from, so that the stop within the buffer holds across
/// the dip: see [`crate::motion::planner`]), else to its end, capped at the dip's
/// `after` beyond a dip. Returns the speed the piece leaves at.
fn plan_piece(planner: &Planner, from: i64, v0: f32, target: f32, out: &mut Profile) -> f32 {
    let b = planner.executing().expect("a motion block is executing");
    let length = b.course.length << 16;
    // Only a curve has a dip (a line's start, the commonest, looks no further).
    let dip = if b.course.form == Form::Spline {
        match planner.bend() {
            Bend::Spline(_, dip) if dip.at > 0 => Some(dip),
            _ => None,
        }
    } else {
        None
    };
    let (end, cap, target) = match dip {
        Some(dip) => {
            let at = dip.at_q16(b.course.length);
            if from < at {
                let through = dip.through(b.course.length, b.accel, target);
                (at, planner.cap(b), through)
            } else {
                (length, planner.cap_after(b, dip), target)
            }
        }
        None => (length, planner.cap(b), target),
    };
    out.plan_into(end - from, v0, cap, target, b.accel).exit
}

/// Something the controller must act on, found while executing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Event {
    /// An auxiliary function was reached (motion before it is complete, at rest).
    Aux {
        /// NC line.
        line: u32,
        /// The function.
        aux: Aux,
    },
    /// A block that cannot be executed was reached (at rest).
    Unreachable {
        /// NC line.
        line: u32,
        /// Why.
        why: Unreachable,
    },
}

/// The executing block's state; the block itself stays in its queue slot
/// ([`Planner::executing`]).
#[derive(Clone, Copy, Debug)]
struct Active {
    profile: Option<Profile>,
    /// Time into the profile, ticks Q32.
    t: i64,
    /// Path distance where the profile starts, nm Q16.
    s_base: i64,
    /// Dwell ticks left.
    dwell_left: u32,
    /// The exit speed the profile was planned toward, nm/tick.
    target: f32,
}

/// Executes the planner's blocks.
#[derive(Clone, Debug)]
pub struct Executor {
    active: Option<Active>,
    /// Commanded pose, axis units.
    pub pose: [i64; AXES],
    /// Path speed, nm/tick Q32.
    pub speed: i64,
    /// NC line of the executing (or last) block.
    pub line: u32,
    /// Blocks completed.
    pub completed: u32,
    /// NC lines of the blocks started since the log was last taken (feature
    /// `line-log`; at most 64 per tick are kept, far more than a tick starts).
    #[cfg(feature = "line-log")]
    pub line_log: heapless::Vec<u32, 64>,
    /// Stop taking new blocks (a pause or tool change is waiting for resume).
    pub paused: bool,
    /// Speed at which the last profiled block leaves, nm/tick: the next block's entry.
    exit: f32,
    /// Jerk limitation (see the module doc); off (`log2` = 0) for plain trapezoids.
    /// Kept in place, on or off, so that nothing builds its history on the stack.
    smoothing: Smoothing,
    /// Path distance travelled since start-up by the unsmoothed profile, nm Q16
    /// (blocks laid end to end).
    s_raw: i64,
    /// Where the executing block starts on that scale.
    block_start: i64,
}

/// Most ticks of smoothing (the moving-average window); defined with the machine
/// configuration that it bounds (`motion.smoothing_ticks`).
pub use crate::config::{window_of, MAX_WINDOW};
/// Blocks remembered for the smoothed position to fall in.
pub const HISTORY: usize = 48;

#[derive(Clone, Debug)]
struct Past {
    start: i64,
    /// Where the path begins.
    from: [i64; AXES],
    path: Path,
    line: u32,
}

/// The last [`HISTORY`] blocks' paths, oldest first, written in place (a block's path
/// is copied once, into its slot).
#[derive(Clone, Debug)]
struct History {
    slots: [Past; HISTORY],
    /// Slot of the oldest.
    head: usize,
    len: usize,
}

impl History {
    fn clear(&mut self) {
        self.head = 0;
        self.len = 0;
    }
    fn get(&self, i: usize) -> &Past {
        &self.slots[(self.head + i) % HISTORY]
    }
    fn pop_front(&mut self) {
        if self.len > 0 {
            self.head = (self.head + 1) % HISTORY;
            self.len -= 1;
        }
    }
    /// A slot for the newest (the oldest is forgotten when full).
    fn push(&mut self) -> &mut Past {
        if self.len == HISTORY {
            self.pop_front();
        }
        let i = (self.head + self.len) % HISTORY;
        self.len += 1;
        &mut self.slots[i]
    }
}

/// Moving average of the path distance over a window of 2ᵏ ticks.
#[derive(Clone, Debug)]
struct Smoothing {
    log2: u32,
    ring: [i64; MAX_WINDOW],
    head: usize,
    sum: i128,
    s: i64,
    hist: History,
}

impl Executor {
    /// An idle executor at `pose` (on the host; the controller builds its own in place
    /// with [`Executor::init_at`]).
    pub fn new(pose: [i64; AXES]) -> Self {
        // SAFETY: `init_at` writes every field of the slot.
        unsafe { crate::place::built(|p| Self::init_at(p, pose)) }
    }

    /// Writes an idle executor at `pose`, without smoothing, into `p`, field by field
    /// (the smoothing history is 12 KB: no temporary of it on the stack).
    ///
    /// # Safety
    /// `p` must be valid for writes and aligned; whatever it held is overwritten
    /// without being dropped (nothing in an executor needs dropping).
    pub unsafe fn init_at(p: *mut Self, pose: [i64; AXES]) {
        use core::ptr::addr_of_mut as at;
        // SAFETY: the caller's promise; each write is to a field of `*p`.
        unsafe {
            at!((*p).active).write(None);
            at!((*p).pose).write(pose);
            at!((*p).speed).write(0);
            at!((*p).line).write(0);
            at!((*p).completed).write(0);
            #[cfg(feature = "line-log")]
            at!((*p).line_log).write(heapless::Vec::new());
            at!((*p).paused).write(false);
            at!((*p).exit).write(0.0);
            at!((*p).s_raw).write(0);
            at!((*p).block_start).write(0);
            let f = at!((*p).smoothing);
            at!((*f).log2).write(0);
            at!((*f).ring).write([0; MAX_WINDOW]);
            at!((*f).head).write(0);
            at!((*f).sum).write(0);
            at!((*f).s).write(0);
            let h = at!((*f).hist);
            at!((*h).head).write(0);
            at!((*h).len).write(0);
            let slots = at!((*h).slots) as *mut Past;
            for i in 0..HISTORY {
                let past = slots.add(i);
                at!((*past).start).write(0);
                at!((*past).from).write([0; AXES]);
                at!((*past).path).write(Path::default());
                at!((*past).line).write(0);
            }
        }
    }

    /// Back to idle at `pose`, keeping the smoothing window, in place.
    pub fn reset(&mut self, pose: [i64; AXES]) {
        let window = 1u32 << self.smoothing.log2;
        self.active = None;
        self.pose = pose;
        self.speed = 0;
        self.line = 0;
        self.completed = 0;
        self.paused = false;
        self.exit = 0.0;
        self.s_raw = 0;
        self.block_start = 0;
        self.set_smoothing(window);
    }

    /// Smooths the path distance with a moving average of `window` ticks (rounded up
    /// to a power of two, at most [`MAX_WINDOW`]); 1 turns smoothing off.
    pub fn set_smoothing(&mut self, window: u32) {
        let f = &mut self.smoothing;
        f.log2 = window_of(window).trailing_zeros();
        f.ring = [self.s_raw; MAX_WINDOW];
        f.head = 0;
        f.sum = (self.s_raw as i128) << f.log2;
        f.s = self.s_raw;
        f.hist.clear();
    }

    /// The smoothing, when on.
    fn smoothing(&self) -> Option<&Smoothing> {
        (self.smoothing.log2 > 0).then_some(&self.smoothing)
    }

    /// The smoothed motion has caught up with the profile (always, without smoothing).
    /// Not inlined: the tick asks only before a block that starts at rest, and inlined
    /// its 128-bit comparison was computed before every block.
    #[inline(never)]
    pub fn settled(&self) -> bool {
        self.smoothing()
            .is_none_or(|f| f.s == self.s_raw && f.sum == (self.s_raw as i128) << f.log2)
    }

    /// Is a block executing?
    pub fn busy(&self) -> bool {
        self.active.is_some()
    }

    /// At rest (nothing executing, or held still inside a block)?
    pub fn stopped(&self) -> bool {
        if !self.settled() {
            return false;
        }
        match &self.active {
            None => true,
            Some(a) => self.speed == 0 && a.profile.is_none_or(|p| p.t2 == HELD && a.t >= p.t1),
        }
    }

    /// Ticks left in the executing block (estimate for flow control).
    pub fn remaining_ticks(&self) -> f32 {
        match &self.active {
            None => 0.0,
            Some(a) => match a.profile {
                None => a.dwell_left as f32,
                Some(p) if p.t2 == HELD => 0.0,
                Some(p) => from_q32((p.duration() - a.t).max(0)),
            },
        }
    }

    /// Drops the executing block (alarm or abort); the pose stays where it is.
    pub fn stop(&mut self) {
        self.active = None;
        self.speed = 0;
        self.exit = 0.0;
        if let Some(f) = self.smoothing() {
            let window = 1 << f.log2;
            self.s_raw = 0;
            self.block_start = 0;
            self.set_smoothing(window);
        }
    }

    /// Starts the planner's next block ([`Planner::start`], in place); blocks that do
    /// not move are finished at once unless they wait (dwell).
    fn activate(&mut self, planner: &mut Planner) -> Option<Event> {
        if !planner.start() {
            return None;
        }
        let b = planner.executing().expect("started above");
        self.line = b.line;
        #[cfg(feature = "line-log")]
        let _ = self.line_log.push(b.line);
        match b.kind {
            Kind::Unreachable(why) => {
                let line = b.line;
                planner.finish();
                Some(Event::Unreachable { line, why })
            }
            Kind::Aux(aux) => {
                let line = b.line;
                planner.finish();
                self.exit = 0.0;
                self.completed += 1;
                Some(Event::Aux { line, aux })
            }
            Kind::Dwell(n) => {
                self.exit = 0.0;
                self.active = Some(Active {
                    profile: None,
                    t: 0,
                    s_base: 0,
                    dwell_left: n,
                    target: 0.0,
                });
                None
            }
            Kind::Rapid | Kind::Feed => {
                let target = planner.exit_target();
                self.block_start = self.s_raw;
                if self.smoothing.log2 > 0 {
                    let past = self.smoothing.hist.push();
                    past.start = self.s_raw;
                    past.from = *planner.front_start();
                    past.path.course = b.course;
                    if b.course.form.bends() {
                        past.path.bend = *planner.bend();
                    }
                    past.line = b.line;
                }
                // The profile is planned where it is kept (no copy of it).
                let exit = self.exit;
                let a = self.active.insert(Active {
                    profile: None,
                    t: 0,
                    s_base: 0,
                    dwell_left: 0,
                    target,
                });
                let p = a.profile.insert(Profile::IDLE);
                self.exit = plan_piece(planner, 0, exit, target, p);
                None
            }
        }
    }

    /// Re-profiles the executing block from where it is (after a hold, a resume or a
    /// feed-override change); later blocks are profiled when they start.
    pub fn replan(&mut self, planner: &mut Planner) {
        let Some(a) = self.active.as_mut() else {
            return;
        };
        let Some(p) = &a.profile else {
            return;
        };
        let Some(b) = planner.executing() else {
            return;
        };
        let (s, v) = p.at(a.t);
        a.s_base = (a.s_base + s).min(b.course.length << 16);
        let target = planner.exit_target();
        let p = a.profile.insert(Profile::IDLE);
        self.exit = plan_piece(planner, a.s_base, from_q32(v), target, p);
        a.t = 0;
        a.target = target;
    }

    /// Blocks that arrived after the executing block started may let it leave faster
    /// than it was planned to (it was profiled to stop where the queue ended):
    /// re-profiles it from where it is when the exit it may now aim for is higher. O(1).
    pub fn retarget(&mut self, planner: &mut Planner) {
        let Some(a) = self.active.as_ref() else {
            return;
        };
        let held = a.profile.is_none_or(|p| p.t2 == HELD);
        // A block that ends within this tick leaves as planned: the next one starts
        // from that speed, profiled toward the new target (one profile per tick
        // saved where blocks are shortest).
        let ending = a
            .profile
            .as_ref()
            .is_some_and(|p| p.duration() - a.t <= TICK_Q32);
        if !held && !ending && !planner.hold && planner.exit_target() > a.target * 1.001 + 0.01 {
            self.replan(planner);
        }
    }

    /// Advances one tick; returns an event when one stops execution at rest.
    pub fn tick(&mut self, planner: &mut Planner) -> Option<Event> {
        let mut budget = TICK_Q32;
        let mut event = None;
        loop {
            if self.active.is_none() {
                // A hold or pause takes no new block once at rest; a stop still under
                // way continues into the next blocks (profiled to stop).
                if self.paused || (planner.hold && self.exit <= 0.0) {
                    break;
                }
                // Dwells, auxiliary functions, faults and blocks entered from rest (a
                // stop at a corner) act at rest: let the smoothed motion arrive first.
                let at_rest_kind = planner.front().is_some_and(|b| {
                    !matches!(b.kind, Kind::Rapid | Kind::Feed) || b.corner == 0.0
                });
                if at_rest_kind && !self.settled() {
                    break;
                }
                if planner.front().is_none() {
                    break;
                }
                if let Some(e) = self.activate(planner) {
                    event = Some(e);
                    if matches!(e, Event::Unreachable { .. }) {
                        break;
                    }
                    if let Event::Aux {
                        aux: Aux::Pause(_) | Aux::ToolChange(_),
                        ..
                    } = e
                    {
                        self.paused = true;
                        break;
                    }
                    continue;
                }
            }
            let a = self.active.as_mut().expect("activated above");
            match &a.profile {
                None => {
                    if a.dwell_left > 0 && budget > 0 {
                        a.dwell_left -= 1;
                        budget = 0;
                    }
                    if a.dwell_left == 0 {
                        self.completed += 1;
                        if let Some(b) = planner.executing() {
                            self.pose = b.course.end;
                        }
                        planner.finish();
                        self.active = None;
                        continue;
                    }
                    break;
                }
                Some(p) => {
                    let b = planner.executing().expect("a motion block is executing");
                    a.t += budget;
                    if p.t2 == HELD {
                        a.t = a.t.min(p.t1.saturating_add(TICK_Q32));
                    }
                    let d = p.duration();
                    if p.t2 != HELD && a.t >= d {
                        let (v1, reached) = (p.v1, a.s_base + p.length);
                        budget = a.t - d;
                        if reached < b.course.length << 16 {
                            // At the dip: the rest of the block is profiled from it, from
                            // the speed the dip was passed at, toward the exit the queue
                            // allows now.
                            let target = planner.exit_target();
                            let p = a.profile.insert(Profile::IDLE);
                            self.exit = plan_piece(planner, reached, from_q32(v1), target, p);
                            (a.s_base, a.t, a.target) = (reached, 0, target);
                            continue;
                        }
                        self.s_raw = self.block_start + (b.course.length << 16);
                        if self.smoothing.log2 == 0 {
                            self.pose = b.course.end;
                        }
                        planner.finish();
                        self.completed += 1;
                        self.active = None;
                        if budget == 0 {
                            self.speed = v1;
                            break;
                        }
                        continue;
                    }
                    let (s, v) = p.at(a.t);
                    self.s_raw = self.block_start + a.s_base + s;
                    if self.smoothing.log2 == 0 {
                        b.course.pose_at(
                            planner.bend(),
                            planner.front_start(),
                            a.s_base + s,
                            &mut self.pose,
                        );
                        self.speed = v;
                    }
                    break;
                }
            }
        }
        if self.smoothing.log2 > 0 {
            self.smooth();
        } else if self.active.is_none() {
            self.speed = 0;
        }
        event
    }

    /// Moves the smoothed position one tick and evaluates the pose there.
    fn smooth(&mut self) {
        if self.smoothing.log2 == 0 {
            return;
        }
        let f = &mut self.smoothing;
        let window = 1usize << f.log2;
        f.sum += (self.s_raw - f.ring[f.head]) as i128;
        f.ring[f.head] = self.s_raw;
        f.head = (f.head + 1) & (window - 1);
        let s = (f.sum >> f.log2) as i64;
        self.speed = (s - f.s) << 16;
        f.s = s;
        // The oldest sample in the window bounds what can still be needed.
        let oldest = f.ring[f.head];
        while f.hist.len >= 2 && f.hist.get(1).start <= oldest {
            f.hist.pop_front();
        }
        if f.hist.len > 0 {
            let mut i = f.hist.len - 1;
            while i > 0 && f.hist.get(i).start > s {
                i -= 1;
            }
            let past = f.hist.get(i);
            past.path
                .pose_at(&past.from, s - past.start, &mut self.pose);
            self.line = past.line;
        }
    }
}
