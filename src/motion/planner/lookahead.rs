//! The host's look-ahead: each block's limits and corner ([`Lookahead`]), the reverse
//! and forward passes, and single planned moves (MDI, jogs).

use super::limits::{
    bend_jump_limit, corner_need, corner_share, limits_along, per_tick, Limits, Side,
    SPLINE_BEND_SHARE,
};
use super::splines::{refine_splines, restore, smoothed};
use crate::config::{MachineConfig, AXES, MAX_JOINTS};
use crate::kinematics::{MachineKinematics, Unreachable};
use crate::math::{fmax, fmin, i64_to_f32, sqrtf};
use crate::motion::block::{Aux, Block, Dip, Motion, Plan, PlannedBlock};
use crate::motion::geometry::{Course, Form, GeometryError, Path, Shape};
use crate::units::TICK_HZ;

/// What a queued block does.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// Motion at the machine's limits.
    Rapid,
    /// Motion at the programmed feed.
    Feed,
    /// Wait this many ticks at rest.
    Dwell(u32),
    /// Auxiliary function, executed at rest.
    Aux(Aux),
    /// The block cannot be executed (its target is out of reach); reaching it raises
    /// an alarm.
    Unreachable(Unreachable),
}

/// A block in the planner queue.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlanBlock {
    /// NC line.
    pub line: u32,
    /// Kind.
    pub kind: Kind,
    /// Geometry.
    pub path: Path,
    /// Requested feed, nm/tick (∞ for rapids).
    pub feed: f32,
    /// Hard speed limit, nm/tick.
    pub v_limit: f32,
    /// Acceleration used by the profile, nm/tick²: half of `accel_full` when a corner
    /// at either end is blended.
    pub accel: f32,
    /// Acceleration the limits allow along the block, nm/tick².
    pub accel_full: f32,
    /// Share of the acceleration reserved for the turn at the block's start.
    pub rho_in: f32,
    /// Hard limit on the entry speed from the corner with the previous block, nm/tick.
    pub corner: f32,
    /// Planned entry speed, nm/tick.
    pub entry: f32,
    /// The most the block may be left at, nm/tick: a spline's exit limit (its own
    /// speed limit assumes no faster exit, [`Limits::top`]), ∞ for other blocks.
    pub exit_most: f32,
    /// The most the block may be entered at for its own limits: a spline's first
    /// stretch's limit ([`super::limits::Limits::bend`]), ∞ for other blocks.
    pub entry_most: f32,
    /// A spline's dip ([`refine_splines`]): `v_limit` holds before it, and its own
    /// limits at it and beyond it. `None` as planned; the second look at the splines
    /// may give it one.
    pub dip: Option<Dip>,
    /// `corner`, `v_limit`, `accel_full` and `exit_most` as the block was planned,
    /// before the second look at the splines ([`refine_splines`]) set them for the
    /// speeds the passes found; each pass sequence starts again from them.
    pub first: [f32; 4],
}

impl PlanBlock {
    /// Length in nm as `f32`.
    pub fn length(&self) -> f32 {
        i64_to_f32(self.path.length)
    }

    /// What the host streams for this block.
    pub fn plan(&self) -> Plan {
        let mut shape = self.path.shape();
        if let Shape::Spline { dip, .. } = &mut shape {
            *dip = self.dip;
        }
        Plan {
            length: self.path.length,
            shape,
            v_limit: self.v_limit,
            accel: self.accel,
            entry: self.entry,
            stop: self.corner == 0.0,
        }
    }
}

impl Default for PlanBlock {
    /// An auxiliary no-op at the origin (a placeholder for buffers).
    fn default() -> Self {
        Self {
            line: 0,
            kind: Kind::Dwell(0),
            path: Path::default(),
            feed: 0.0,
            v_limit: 0.0,
            accel: 1.0,
            accel_full: 1.0,
            rho_in: 0.0,
            corner: 0.0,
            entry: 0.0,
            exit_most: f32::INFINITY,
            entry_most: f32::INFINITY,
            dip: None,
            first: [0.0, 0.0, 1.0, f32::INFINITY],
        }
    }
}

/// The planning state between blocks: where the last block ended and how, so that
/// the next one's corner can be planned ([`Lookahead::plan`]).
#[derive(Clone, Copy, Debug)]
pub struct Lookahead {
    /// End pose of the last block planned.
    pub end: [i64; AXES],
    end_tangent: [f32; AXES],
    /// d²P/ds² at the end of the last block (splines and arcs; 0 for lines).
    end_bend: [f32; AXES],
    end_stops: bool,
    /// Blending tolerance of the last block planned, nm.
    end_tolerance: u32,
    /// The speed the last block may be left at, nm/tick: a spline's exit limit
    /// ([`Limits::ends`]), ∞ after other blocks.
    end_limit: f32,
    /// Jerk-limitation window, ticks (1: none); see [`crate::motion::interp`].
    pub smoothing: u32,
}

/// Soft speed cap of a block (feed × override, 0 in a hold), nm/tick.
pub fn cap(b: &PlanBlock, feed_override: u16, hold: bool) -> f32 {
    cap_of(b.kind, b.feed, b.v_limit, feed_override, hold)
}

pub(super) fn cap_of(kind: Kind, feed: f32, v_limit: f32, feed_override: u16, hold: bool) -> f32 {
    if hold {
        return 0.0;
    }
    match kind {
        Kind::Rapid => v_limit,
        Kind::Feed => fmin(feed * feed_override as f32 / 100.0, v_limit),
        _ => 0.0,
    }
}

impl Lookahead {
    /// Planning from `pose`, at rest, with a jerk-limitation window of `smoothing`.
    pub fn new(pose: [i64; AXES], smoothing: u32) -> Self {
        Self {
            end: pose,
            end_tangent: [0.0; AXES],
            end_bend: [0.0; AXES],
            end_stops: true,
            end_tolerance: 0,
            end_limit: f32::INFINITY,
            smoothing,
        }
    }

    /// The corner speed (nm/tick) at which the tick that turns from the last block's
    /// end tangent to `start_tangent` cuts the corner by no more than the last block's
    /// path tolerance (∞ when it has none or there is no turn). Path tolerance (G64 P):
    /// between two tick samples the tool moves in a straight line, which cuts a corner
    /// taken at v (nm/tick) by v·|Δu|/4 at most (the corner half-way through a tick).
    #[inline(always)]
    fn tolerance_limit(&self, start_tangent: &[f32; AXES]) -> f32 {
        let du = sqrtf(
            (0..3)
                .map(|i| {
                    let d = start_tangent[i] - self.end_tangent[i];
                    d * d
                })
                .sum::<f32>(),
        );
        if self.end_tolerance == u32::MAX || du < 1e-9 {
            f32::INFINITY
        } else {
            4.0 * self.end_tolerance as f32 / du
        }
    }

    /// The corner speed (nm/tick) at which the jump of the acceleration from the last
    /// block's end bend to `path`'s start bend stays within jerk limitation's budget.
    #[inline(always)]
    fn bend_jump_limit(
        &self,
        path: &Path,
        machine: &MachineConfig,
        kin: &MachineKinematics,
    ) -> f32 {
        let start_bend = path.bend_at(0);
        let jump: [f32; AXES] = core::array::from_fn(|i| start_bend[i] - self.end_bend[i]);
        bend_jump_limit(&jump, &self.end, self.smoothing, machine, kin)
    }

    /// Plans `block` after `prev` (the block planned before it, whose acceleration a
    /// blended corner may reduce): geometry, limits along it, and its corner. Its
    /// `entry` is left at the corner limit, for the passes. An unreachable target is
    /// planned as such (it stops the machine there).
    pub fn plan(
        &mut self,
        block: &Block,
        prev: Option<&mut PlanBlock>,
        machine: &MachineConfig,
        kin: &MachineKinematics,
    ) -> Result<PlanBlock, GeometryError> {
        let path = Path::new(block, &self.end)?;
        Ok(self.plan_path(block, path, prev, machine, kin))
    }

    /// A spline's bend limits its speed most at one end or both: its entry and exit
    /// are limited there, and between them it may run faster
    /// ([`ends`](super::limits::Limits::ends), for its profile's acceleration `a`).
    /// Returns its corner (`corner` within the last block's exit limit and its own
    /// entry limit), its speed limit, its exit limit (which goes into the next
    /// block's corner) and its first stretch's limit; for other blocks, `corner`
    /// within the last block's exit limit and `v_limit`.
    fn spline_ends(
        &mut self,
        limits: Option<Limits>,
        path: &Path,
        corner: f32,
        v_limit: f32,
        feed: f32,
        a: f32,
    ) -> (f32, f32, f32, f32) {
        let corner = fmin(corner, self.end_limit);
        let (corner, v_limit, end_limit, first) = match limits {
            Some(l) if path.form == Form::Spline => {
                let (entry, exit, top) = l.ends(corner, a, path.length as f32, fmin(feed, l.v));
                (fmin(corner, entry), top, exit, fmin(l.bend[0], l.v))
            }
            _ => (corner, v_limit, f32::INFINITY, f32::INFINITY),
        };
        self.end_limit = end_limit;
        (corner, v_limit, end_limit, first)
    }

    /// The speed and the share ρ of the acceleration of a blended corner whose turn
    /// needs `n` of the acceleration per unit of speed, after `prev`, into `path`
    /// (asked for at `feed`, whose first stretch allows `v_start`, at acceleration
    /// `accel`), within the path tolerance's `by_tolerance`.
    fn turn(
        &self,
        n: f32,
        prev: Option<&PlanBlock>,
        path: &Path,
        (feed, v_start, accel): (f32, f32, f32),
        by_tolerance: f32,
    ) -> (f32, f32) {
        // With jerk limitation over w ticks the smoothed motion passes the
        // corner up to a·w·T/2 faster than the profile does, and its one-tick
        // turn must stay within aᵢ·T/w per axis (a third of the jerk budget, see
        // [`crate::motion::interp`]); a corner that cannot is a stop, which the executor
        // lets the smoothing settle into before turning.
        let w = self.smoothing.max(1) as f32;
        let a_near = prev.map_or(0.0, |p| p.accel_full).max(accel);
        let by_jerk = (1.0 / (w * n) - a_near * w / 2.0).max(0.0);
        let limit = by_tolerance.min(if self.smoothing > 1 {
            by_jerk
        } else {
            f32::INFINITY
        });
        let prev_v = prev
            .as_ref()
            .map_or(0.0, |p| p.feed.min(p.v_limit).min(p.exit_most));
        let want = prev_v.min(feed.min(v_start)).min(limit);
        // Blocks shorter than a tick's travel put several corners into one
        // tick, whose turns add up: at v over blocks of length L, v/L of them,
        // so the share a corner needs is v·n·max(1, v/L), and v ≤ √(ρ·L/n)
        // as well as ρ/n.
        let short = prev
            .as_ref()
            .map_or(path.length, |p| p.path.length.min(path.length))
            .max(1) as f32;
        let per_tick = fmax(1.0, want / short);
        // max/min rather than clamp: clamp's panic message formats floats, which
        // costs the firmware kilobytes of formatting code.
        #[allow(clippy::manual_clamp)]
        let most = (want * n * per_tick * 1.0001).max(0.0).min(0.5);
        let speed = |rho: f32| fmin(fmin(rho / n, sqrtf(rho * short / n)), limit);
        let before = prev.map(|p| Side {
            far: fmin(p.corner, prev_v),
            top: prev_v,
            a: p.accel_full,
            taken: p.rho_in,
            length: p.length(),
        });
        let this = Side {
            far: f32::NAN,
            top: fmin(feed, v_start),
            a: accel,
            taken: 0.0,
            length: path.length as f32,
        };
        // A stop waits for the smoothed motion to arrive (about w ticks).
        let settle = if self.smoothing > 1 { w } else { 0.0 };
        // The share at which the turn allows a speed c.
        let share = |c: f32| fmax(c * n, c * c * n / short);
        let rho = corner_share(most, (speed, share), [before, Some(this)], settle);
        (speed(rho), rho)
    }

    /// [`Lookahead::plan`] of `block` whose path from [`Lookahead::end`] is derived
    /// already (`Path::new(block, &self.end)`: a host that derived it for its
    /// pre-flight carries it here rather than deriving it again).
    pub fn plan_path(
        &mut self,
        block: &Block,
        path: Path,
        prev: Option<&mut PlanBlock>,
        machine: &MachineConfig,
        kin: &MachineKinematics,
    ) -> PlanBlock {
        let mut kind = kind_of(block, &path);
        let feed = feed_of(block, &path, kind);
        // The fastest this block may be asked to go (feed override up to 200 %).
        let requested = feed * 2.0;
        let limits = match kind {
            Kind::Rapid | Kind::Feed => {
                match limits_along(
                    &self.end,
                    &path,
                    requested,
                    None,
                    SPLINE_BEND_SHARE,
                    machine,
                    kin,
                ) {
                    Ok(l) => Some(smoothed(l, &path, self.smoothing)),
                    Err(e) => {
                        kind = Kind::Unreachable(e);
                        None
                    }
                }
            }
            _ => None,
        };
        let (v_limit, accel) = limits.map_or((0.0, 1.0), |l| (l.lowest(), l.a));
        // The speed the block may start at: on a spline, its first stretch's.
        let v_start = limits.map_or(v_limit, |l| fmin(l.v, l.bend[0]));
        // Corners compare dP/ds (a spline's tangent is |dP/du|/length ≤ 1 long): where
        // two splines meet with one direction but different |dP/ds| the tool's speed
        // jumps by the difference, which the corner limits as it limits a turn.
        let start_tangent = path.tangent_at(0);
        let moving = matches!(kind, Kind::Rapid | Kind::Feed);
        let accel = accel.max(1e-9);
        let need = if self.end_stops || !moving {
            None
        } else {
            corner_need(&self.end_tangent, &start_tangent, &self.end, machine, kin)
        };
        // Split each axis's acceleration at a blended corner: a share ρ for the turn,
        // the rest for the two blocks' profiles (see the module doc): at most what the
        // turn needs at the speed both blocks ask for, and one half; less where that
        // is faster ([`corner_share`]).
        let by_tolerance = self.tolerance_limit(&start_tangent);
        let (corner, rho) = match need {
            None => (0.0, 0.0),
            Some(n) if n <= 0.0 => (by_tolerance, 0.0),
            Some(n) => self.turn(
                n,
                prev.as_deref(),
                &path,
                (feed, v_start, accel),
                by_tolerance,
            ),
        };
        if rho > 0.0 {
            if let Some(prev) = prev {
                prev.accel = prev.accel_full * (1.0 - rho.max(prev.rho_in));
            }
        }
        // Where a spline or an arc meets its neighbour its bend jumps: each axis's and joint's
        // acceleration changes by v²·Δx″ in one tick, which jerk limitation over w
        // ticks allows a third of its budget for (aᵢ/w per tick, as a corner's turn).
        let corner = if self.smoothing > 1 && moving && corner > 0.0 {
            fmin(corner, self.bend_jump_limit(&path, machine, kin))
        } else {
            corner
        };
        let (corner, v_limit, end_limit, entry_most) =
            self.spline_ends(limits, &path, corner, v_limit, feed, accel * (1.0 - rho));
        self.end_bend = path.bend_at(path.length << 16);
        self.end = path.end;
        self.end_tangent = path.tangent_at(path.length << 16);
        self.end_stops = !moving || block.tolerance_nm == 0;
        self.end_tolerance = block.tolerance_nm;
        PlanBlock {
            line: block.line,
            kind,
            path,
            feed,
            v_limit,
            accel: accel * (1.0 - rho),
            accel_full: accel,
            rho_in: rho,
            corner,
            entry: corner,
            exit_most: end_limit,
            entry_most,
            dip: None,
            first: [corner, v_limit, accel, end_limit],
        }
    }
}

/// What a block does, given its geometry (a move of length 0 is a dwell of 0 ticks).
pub(super) fn kind_of(block: &Block, path: &Course) -> Kind {
    let kind = match block.motion {
        Motion::Rapid => Kind::Rapid,
        Motion::Linear | Motion::Arc { .. } | Motion::Cubic { .. } | Motion::Quadratic { .. } => {
            Kind::Feed
        }
        Motion::Dwell(ms) => Kind::Dwell(((ms as u64 * TICK_HZ as u64).div_ceil(1000)) as u32),
        Motion::Aux(a) => Kind::Aux(a),
    };
    if path.length == 0 && matches!(kind, Kind::Rapid | Kind::Feed) {
        return Kind::Dwell(0);
    }
    kind
}

/// Requested feed of a block, nm/tick (∞ for rapids and blocks that do not move).
pub(super) fn feed_of(block: &Block, path: &Course, kind: Kind) -> f32 {
    match kind {
        Kind::Feed if path.rotary_only => per_tick(block.feed.saturating_mul(1000)),
        Kind::Feed => per_tick(block.feed),
        _ => f32::INFINITY,
    }
}

/// Largest entry speed allowed for block `i` (corner, its cap, the previous cap).
pub(super) fn entry_limit(blocks: &[PlanBlock], i: usize, feed_override: u16, hold: bool) -> f32 {
    let b = &blocks[i];
    let prev_cap = if i == 0 {
        f32::INFINITY
    } else {
        cap(&blocks[i - 1], feed_override, hold)
    };
    fmin(fmin(b.corner, cap(b, feed_override, hold)), prev_cap)
}

/// The reverse pass over `blocks` (see the module doc): the last one ends at rest.
pub fn reverse_pass(blocks: &mut [PlanBlock], feed_override: u16, hold: bool) {
    let mut next_entry = 0.0f32;
    for i in (0..blocks.len()).rev() {
        let limit = entry_limit(blocks, i, feed_override, hold);
        let b = &mut blocks[i];
        let reach = sqrtf(next_entry * next_entry + 2.0 * b.accel * b.length());
        b.entry = fmin(limit, reach);
        next_entry = b.entry;
    }
}

/// The forward pass over `blocks` from `first_entry` (see the module doc).
pub fn forward_pass(blocks: &mut [PlanBlock], first_entry: f32) {
    let Some(first) = blocks.first_mut() else {
        return;
    };
    first.entry = first_entry;
    for i in 0..blocks.len() - 1 {
        let (e, a, len) = (blocks[i].entry, blocks[i].accel, blocks[i].length());
        let hi = sqrtf(e * e + 2.0 * a * len);
        let lo = sqrtf(fmax(e * e - 2.0 * a * len, 0.0));
        let nb = &mut blocks[i + 1];
        nb.entry = fmax(fmin(nb.entry, hi), lo);
    }
}

/// Plans a whole program from `start` at rest, with unlimited look-ahead (the host's
/// job): `out[i]` receives block `i`'s plan ([`PlanBlock::plan`] is what is streamed).
/// `smoothing` is the controller's jerk-limitation window in ticks
/// ([`crate::config::window_of`] of the machine's). Fails with the index of a block
/// whose geometry is malformed.
pub fn plan_into(
    blocks: &[Block],
    start: [i64; AXES],
    machine: &MachineConfig,
    kin: &MachineKinematics,
    smoothing: u32,
    out: &mut [PlanBlock],
) -> Result<(), (usize, GeometryError)> {
    let mut la = Lookahead::new(start, smoothing);
    for (i, b) in blocks.iter().enumerate() {
        let (done, rest) = out.split_at_mut(i);
        rest[0] = la
            .plan(b, done.last_mut(), machine, kin)
            .map_err(|e| (i, e))?;
    }
    replan_from(
        &mut out[..blocks.len()],
        0,
        start,
        smoothing,
        machine,
        kin,
        &mut || {},
    );
    Ok(())
}

/// The look-ahead's pass sequence, the one both [`plan_into`] and the host's link run:
/// the passes, the second look at the splines, the passes again, over `blocks[from..]`
/// (`start`: where `blocks[0]` starts). The blocks before `from` are final (sent):
/// the first replanned block is entered no faster than the last final one reaches over
/// its length from its own planned entry, and at rest when `from` is 0. `between` is
/// called between the steps and before each spline's second look (the host keeps its
/// link alive, and the Grbl bridge answers its sender, while a program is planned).
pub fn replan_from(
    blocks: &mut [PlanBlock],
    from: usize,
    start: [i64; AXES],
    smoothing: u32,
    machine: &MachineConfig,
    kin: &MachineKinematics,
    between: &mut dyn FnMut(),
) {
    let from = from.min(blocks.len());
    restore(blocks, from);
    let reach = from.checked_sub(1).map(|last| {
        let sent = &blocks[last];
        sqrtf(sent.entry * sent.entry + 2.0 * sent.accel * sent.length())
    });
    let passes = |tail: &mut [PlanBlock]| {
        reverse_pass(tail, 100, false);
        let first_entry = match (reach, tail.first()) {
            (Some(r), Some(first)) => first.entry.min(r),
            _ => 0.0,
        };
        forward_pass(tail, first_entry);
    };
    between();
    passes(&mut blocks[from..]);
    between();
    if refine_splines(blocks, from, start, smoothing, machine, kin, between) {
        between();
        passes(&mut blocks[from..]);
    }
    between();
}

/// Motion time of planned blocks (as [`plan_into`] leaves them) at 100 % feed, ticks:
/// each block profiled from its entry to the next one's (0 before a block that does
/// not move, and at the end), dwells counted.
pub fn planned_ticks(blocks: &[PlanBlock]) -> f64 {
    let mut ticks = 0.0;
    for (i, b) in blocks.iter().enumerate() {
        match b.kind {
            Kind::Dwell(n) => ticks += n as f64,
            Kind::Rapid | Kind::Feed => {
                let exit = blocks
                    .get(i + 1)
                    .filter(|n| matches!(n.kind, Kind::Rapid | Kind::Feed))
                    .map_or(0.0, |n| n.entry);
                use crate::motion::profile::Profile;
                let length = b.path.length << 16;
                let p = match &b.dip {
                    // Profiled in two pieces, as the controller does (`interp`).
                    Some(d) => {
                        let at = d.at_q16(b.path.length);
                        let through = d.through(b.path.length, b.accel, exit);
                        let (p1, got) =
                            Profile::plan(at, b.entry, cap(b, 100, false), through, b.accel);
                        let after = cap_of(b.kind, b.feed, d.after(), 100, false);
                        let (p2, _) = Profile::plan(length - at, got.exit, after, exit, b.accel);
                        p1.duration() + p2.duration()
                    }
                    None => {
                        let cap = cap(b, 100, false);
                        Profile::plan(length, b.entry, cap, exit, b.accel)
                            .0
                            .duration()
                    }
                };
                ticks += p as f64 / 4_294_967_296.0;
            }
            _ => {}
        }
    }
    ticks
}

/// Plans one move from `start`, from rest to rest, as the host streams it (a jog, the
/// move home): what [`crate::wire::Control::Jog`] carries.
pub fn plan_move(
    block: &Block,
    start: [i64; AXES],
    machine: &MachineConfig,
    kin: &MachineKinematics,
) -> Result<PlannedBlock, GeometryError> {
    let mut out = [PlanBlock::default()];
    let window = crate::config::window_of(machine.motion.smoothing_ticks as u32);
    plan_into(
        core::slice::from_ref(block),
        start,
        machine,
        kin,
        window,
        &mut out,
    )
    .map_err(|(_, e)| e)?;
    Ok(PlannedBlock {
        block: *block,
        plan: out[0].plan(),
    })
}

/// A jog as the host sends it: `distance` (axis units) along pose axis `axis` from
/// `from` at `feed` (units/s), clipped to the joint travel ([`jog_target`]) and planned
/// from rest to rest ([`plan_move`]).
pub fn plan_jog(
    machine: &MachineConfig,
    kin: &MachineKinematics,
    from: &[i64; AXES],
    axis: usize,
    distance: i64,
    feed: i64,
) -> Result<PlannedBlock, GeometryError> {
    let block = Block {
        line: 0,
        motion: Motion::Linear,
        target: jog_target(machine, kin, from, axis.min(AXES - 1), distance),
        feed: feed.max(1),
        tolerance_nm: 0,
    };
    plan_move(&block, *from, machine, kin)
}

/// The pose a jog of `distance` (axis units) along pose axis `axis` reaches from
/// `from`, shortened so that every joint stays inside its travel (the soft limits):
/// the largest reachable distance, by bisection through the inverse kinematics.
pub fn jog_target(
    machine: &MachineConfig,
    kin: &MachineKinematics,
    from: &[i64; AXES],
    axis: usize,
    distance: i64,
) -> [i64; AXES] {
    let at = |d: i64| {
        let mut t = *from;
        t[axis] = t[axis].saturating_add(d);
        t
    };
    let ok = |d: i64| {
        let mut q = [0; MAX_JOINTS];
        kin.inverse_checked(&at(d), &machine.joints, &mut q).is_ok()
    };
    if ok(distance) {
        return at(distance);
    }
    let (mut lo, mut hi) = (0i64, distance);
    while (hi - lo).abs() > 1 {
        let mid = lo + (hi - lo) / 2;
        if ok(mid) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    at(lo)
}
