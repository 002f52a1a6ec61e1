//! The controller's queue ([`Planner`]): blocks pushed with their host plan, the
//! ring of bends, and the speed a block may leave at so that the machine can stop
//! within what is buffered.

use super::lookahead::{cap_of, feed_of, kind_of};
use super::*;
use crate::config::{MachineConfig, AXES, MAX_JOINTS};
use crate::kinematics::MachineKinematics;
use crate::math::{f32_to_i64, fmax, fmin, i64_to_f32, sqrtf, u64_to_f32};
use crate::motion::block::{Dip, PlannedBlock};
use crate::motion::geometry::{Bend, Course, Form, GeometryError, Shape};

/// Blocks the controller buffers: enough that the H-4's stopping distance at its top
/// speed, along its XYZ diagonal at 346 mm/s (17.3 mm at 3464 mm/s²), fits in 0.05 mm
/// segments (346 of them) with 3 to spare for the link's latency; with the bends,
/// about all the RAM allows (see `docs/performance.md`; three slots went to the touch
/// probe's latch, sixteen to the data recorder: its ring, its state and the servo
/// side's samples, `docs/recorder.md`). Programs of dense chords in `G64 P` are
/// streamed as curves, which need far fewer.
pub const QUEUE_CAPACITY: usize = 349;

/// Arcs and curves the controller buffers (their curved parts, [`Bend`]s of 112 bytes
/// on the MCU, are kept apart from the queue's slots, which are line-sized). 48 curves
/// of a merged 0.05 mm program hold seconds of motion (56 until the eight servo
/// channels and their LQG designs needed the RAM).
pub const BEND_CAPACITY: usize = 48;

/// A block in the controller's queue: what the controller uses of a [`PlanBlock`],
/// with the path's [`Course`] (an arc's [`Bend`] is in the queue's ring of bends).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Queued {
    /// NC line.
    pub line: u32,
    /// Kind.
    pub kind: Kind,
    /// End, length and direction.
    pub course: Course,
    /// Requested feed, nm/tick (∞ for rapids).
    pub feed: f32,
    /// Hard speed limit, nm/tick.
    pub v_limit: f32,
    /// Acceleration of the profile, nm/tick².
    pub accel: f32,
    /// Hard limit on the entry speed, nm/tick (0: entered from rest).
    pub corner: f32,
    /// Planned entry speed, nm/tick.
    pub entry: f32,
    /// Its share of the controller's stop budget and of the buffered-time estimate
    /// ([`Queued::budget`], [`Queued::estimate`]), formed once when queued.
    shares: (u64, u64),
}

impl Queued {
    /// A no-op at the origin (a placeholder for the queue's free slots).
    const EMPTY: Self = Self {
        line: 0,
        kind: Kind::Dwell(0),
        course: Course {
            end: [0; AXES],
            length: 0,
            rotary_only: false,
            form: Form::Point,
            unit: [0; AXES],
        },
        feed: 0.0,
        v_limit: 0.0,
        accel: 1.0,
        corner: 0.0,
        entry: 0.0,
        shares: (0, 0),
    };

    /// Length in nm as `f32`.
    fn length(&self) -> f32 {
        i64_to_f32(self.course.length)
    }

    /// Its share of the stop budget: 2·a·S, (nm/tick)² (0 for blocks that do not
    /// move, or cannot be executed).
    fn budget(&self) -> u64 {
        match self.kind {
            Kind::Rapid | Kind::Feed => f32_to_i64(2.0 * self.accel * self.length()).max(0) as u64,
            _ => 0,
        }
    }

    /// Estimated duration, ticks × 16 (for flow control): at the planned entry and
    /// its cap, whichever is faster.
    fn estimate(&self) -> u64 {
        match self.kind {
            Kind::Dwell(n) => n as u64 * 16,
            Kind::Rapid | Kind::Feed => {
                let v = fmax(fmin(self.feed, self.v_limit), self.entry);
                if v > 0.0 {
                    f32_to_i64(self.length() * 16.0 / v).max(0) as u64
                } else {
                    0
                }
            }
            _ => 0,
        }
    }
}

/// A ring of [`QUEUE_CAPACITY`] blocks whose slots are written in place, and beside
/// it a ring of [`BEND_CAPACITY`] bends, one per queued arc in the same order: a block
/// is built in the next free slot (and bend, [`Ring::spare`]) and becomes queued only
/// when complete ([`Ring::commit`]); nothing is copied on the way in or out. The front
/// bend is the first queued arc's.
#[derive(Clone, Debug)]
struct Ring {
    slots: [Queued; QUEUE_CAPACITY],
    /// Slot of the oldest.
    head: usize,
    len: usize,
    bends: [Bend; BEND_CAPACITY],
    /// Bend of the oldest arc.
    bend_head: usize,
    bend_len: usize,
}

impl Ring {
    fn get(&self, i: usize) -> Option<&Queued> {
        (i < self.len).then(|| &self.slots[(self.head + i) % QUEUE_CAPACITY])
    }
    fn front(&self) -> Option<&Queued> {
        self.get(0)
    }
    fn pop_front(&mut self) {
        if self.len > 0 {
            if self.slots[self.head].course.form.bends() {
                self.bend_head = (self.bend_head + 1) % BEND_CAPACITY;
                self.bend_len -= 1;
            }
            self.head = (self.head + 1) % QUEUE_CAPACITY;
            self.len -= 1;
        }
    }

    /// The slot and the bend after the last (not queued; the queue must not be full).
    fn spare(&mut self) -> (&mut Queued, &mut Bend) {
        (
            &mut self.slots[(self.head + self.len) % QUEUE_CAPACITY],
            &mut self.bends[(self.bend_head + self.bend_len) % BEND_CAPACITY],
        )
    }
    /// Queues the spare slot (and its bend, for an arc).
    fn commit(&mut self) {
        if self.slots[(self.head + self.len) % QUEUE_CAPACITY]
            .course
            .form
            .bends()
        {
            self.bend_len += 1;
        }
        self.len += 1;
    }
    fn clear(&mut self) {
        self.head = 0;
        self.len = 0;
        self.bend_head = 0;
        self.bend_len = 0;
    }
}

/// The controller's queue of planned blocks.
#[derive(Clone, Debug)]
pub struct Planner {
    queue: Ring,
    /// End pose of the last block pushed (where the next one starts).
    pub end: [i64; AXES],
    /// Feed override, percent.
    pub feed_override: u16,
    /// Feed hold: every soft cap is 0.
    pub hold: bool,
    /// Σ 2·a·S of the queued blocks, (nm/tick)² (see the module doc).
    budget: u64,
    /// Σ estimated duration of the queued blocks, ticks × 16.
    estimate: u64,
    /// Where the front block starts (the end of the block before it).
    head_start: [i64; AXES],
    /// Joints of the last target checked against the travel (scratch).
    scratch: [i64; MAX_JOINTS],
    /// The front block is executing ([`Planner::start`]): it stays in its slot (no
    /// copy of it is made) until [`Planner::finish`], but is no longer in the stop
    /// budget or the estimate, and [`Planner::front`] is the block after it.
    running: bool,
}

impl Planner {
    /// An empty planner at `pose` (on the host; the controller builds its own in place
    /// with [`Planner::init_at`]).
    pub fn new(pose: [i64; AXES]) -> Self {
        // SAFETY: `init_at` writes every field of the slot.
        unsafe { crate::place::built(|p| Self::init_at(p, pose)) }
    }

    /// Writes an empty planner at `pose` into `p`, field by field (the queue is tens of
    /// kilobytes: no temporary of it on the stack).
    ///
    /// # Safety
    /// `p` must be valid for writes and aligned; whatever it held is overwritten
    /// without being dropped (queued blocks need no dropping).
    pub unsafe fn init_at(p: *mut Self, pose: [i64; AXES]) {
        use core::ptr::addr_of_mut as at;
        // SAFETY: the caller's promise; each write is to a field of `*p`.
        unsafe {
            let q = at!((*p).queue);
            at!((*q).head).write(0);
            at!((*q).len).write(0);
            at!((*q).bend_head).write(0);
            at!((*q).bend_len).write(0);
            let slots = at!((*q).slots) as *mut Queued;
            for i in 0..QUEUE_CAPACITY {
                slots.add(i).write(Queued::EMPTY);
            }
            let bends = at!((*q).bends) as *mut Bend;
            for i in 0..BEND_CAPACITY {
                bends.add(i).write(Bend::default());
            }
            at!((*p).end).write(pose);
            at!((*p).feed_override).write(100);
            at!((*p).hold).write(false);
            at!((*p).budget).write(0);
            at!((*p).estimate).write(0);
            at!((*p).running).write(false);
            at!((*p).scratch).write([0; MAX_JOINTS]);
            at!((*p).head_start).write(pose);
        }
    }

    /// Occupied slots (the executing block included).
    pub fn len(&self) -> usize {
        self.queue.len
    }
    /// No block queued or executing?
    pub fn is_empty(&self) -> bool {
        self.queue.len == 0
    }
    /// Free slots (a line needs one; an arc one and a bend).
    pub fn free(&self) -> usize {
        QUEUE_CAPACITY - self.queue.len
    }
    /// Free bends: how many arcs can be queued now (at most [`Planner::free`]).
    pub fn free_bends(&self) -> usize {
        (BEND_CAPACITY - self.queue.bend_len).min(self.free())
    }
    /// The next block to start, if any.
    pub fn front(&self) -> Option<&Queued> {
        self.queue.get(self.running as usize)
    }
    /// The bend of the first queued arc: the executing block's when it is an arc
    /// (meaningless otherwise).
    pub fn bend(&self) -> &Bend {
        &self.queue.bends[self.queue.bend_head]
    }
    /// The soft speed cap beyond the executing block's dip (as [`Planner::cap`]).
    pub fn cap_after(&self, b: &Queued, dip: &Dip) -> f32 {
        cap_of(b.kind, b.feed, dip.after(), self.feed_override, self.hold)
    }

    /// The executing block, if one was started and not finished.
    pub fn executing(&self) -> Option<&Queued> {
        if self.running {
            self.queue.front()
        } else {
            None
        }
    }
    /// Starts the next block in place: it leaves the stop budget and the estimate and
    /// becomes [`Planner::executing`]. False when nothing is queued (or one is still
    /// executing).
    pub fn start(&mut self) -> bool {
        if self.running {
            return false;
        }
        let Some(b) = self.queue.front() else {
            return false;
        };
        self.budget -= b.shares.0;
        self.estimate -= b.shares.1;
        self.running = true;
        true
    }
    /// Where the executing block (or, none executing, the next) starts.
    pub fn front_start(&self) -> &[i64; AXES] {
        &self.head_start
    }
    /// Frees the executing block's slot.
    pub fn finish(&mut self) {
        if self.running {
            self.running = false;
            if let Some(b) = self.queue.front() {
                self.head_start = b.course.end;
            }
            self.queue.pop_front();
        }
    }
    /// Takes the next block whole (tests).
    #[cfg(test)]
    pub fn pop(&mut self) -> Option<Queued> {
        self.finish();
        if !self.start() {
            return None;
        }
        let b = *self.queue.front()?;
        self.finish();
        Some(b)
    }

    /// Drops every queued block; the next block starts at `pose`, at rest.
    pub fn clear(&mut self, pose: [i64; AXES]) {
        self.queue.clear();
        self.head_start = pose;
        self.end = pose;
        self.budget = 0;
        self.estimate = 0;
        self.running = false;
    }

    /// Soft speed cap of a block now (feed × override, 0 in a hold), nm/tick.
    pub fn cap(&self, b: &Queued) -> f32 {
        cap_of(b.kind, b.feed, b.v_limit, self.feed_override, self.hold)
    }

    /// The speed at which the executing block may leave (it has been taken off the
    /// queue): the next block's planned entry and cap, and no faster than the machine
    /// can stop from within the queued blocks. 0 when nothing is queued. O(1).
    pub fn exit_target(&self) -> f32 {
        let Some(next) = self.front() else {
            return 0.0;
        };
        let stop = sqrtf(u64_to_f32(self.budget));
        fmin(fmin(next.entry, self.cap(next)), stop)
    }

    /// Total time of the queued motion, ticks (an estimate for flow control). O(1).
    pub fn buffered_ticks(&self) -> f32 {
        u64_to_f32(self.estimate) / 16.0
    }

    /// Queues a block the host planned, in O(1): checks its geometry against the block
    /// ([`Path::from_plan`]), its speeds (finite, not negative) and its target against
    /// the joint travel (an unreachable target is queued as such: the machine stops
    /// before it and raises an alarm there).
    pub fn push_planned(
        &mut self,
        pb: &PlannedBlock,
        machine: &MachineConfig,
        kin: &MachineKinematics,
    ) -> Result<(), PushError> {
        let arc = matches!(pb.plan.shape, Shape::Arc { .. } | Shape::Spline { .. });
        if self.free() == 0 || (arc && self.free_bends() == 0) {
            return Err(PushError::Full);
        }
        let (block, plan) = (&pb.block, &pb.plan);
        let speeds_ok = [plan.v_limit, plan.accel, plan.entry]
            .iter()
            .all(|v| v.is_finite() && *v >= 0.0)
            && plan.accel > 0.0;
        if !speeds_ok {
            return Err(PushError::Geometry(GeometryError::PlanMismatch));
        }
        // Built in place, in the queue's spare slot: the path is checked where it is
        // written, and the block is queued (committed) only when whole.
        let start = self.end;
        let (b, bend) = self.queue.spare();
        b.course
            .set_from_plan(bend, block, &start, plan.length, &plan.shape)
            .map_err(PushError::Geometry)?;
        let path = &b.course;
        let mut kind = kind_of(block, path);
        if matches!(kind, Kind::Rapid | Kind::Feed) {
            // The joints are not kept (only whether they are within travel): a scratch
            // array that is not cleared per block.
            if let Err(e) = kin.inverse_checked(&path.end, &machine.joints, &mut self.scratch) {
                kind = Kind::Unreachable(e);
            }
        }
        let moving = matches!(kind, Kind::Rapid | Kind::Feed);
        let corner = if plan.stop || !moving {
            0.0
        } else {
            f32::INFINITY
        };
        b.feed = feed_of(block, path, kind);
        b.line = block.line;
        b.kind = kind;
        b.v_limit = if moving { plan.v_limit } else { 0.0 };
        b.accel = plan.accel;
        b.corner = corner;
        b.entry = if moving {
            fmin(plan.entry, corner)
        } else {
            0.0
        };
        b.shares = (b.budget(), b.estimate());
        let shares = b.shares;
        self.end = b.course.end;
        self.budget += shares.0;
        self.estimate += shares.1;
        if self.queue.len == 0 {
            self.head_start = start;
        }
        self.queue.commit();
        Ok(())
    }
}

/// Why a block was not queued.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PushError {
    /// No free slot.
    Full,
    /// Malformed geometry.
    Geometry(GeometryError),
}
