//! Look-ahead planning: the speeds at which each block is entered, and the queue of
//! blocks the controller executes.
//!
//! **Where the planning runs.** The whole program is known on the host, so the host
//! plans it ([`plan_into`]) with unlimited look-ahead, using this module's code with
//! the same kinematics: each block's limits (from every pose axis and every joint,
//! sampled along the block through the kinematics, and from curvature on arcs), its
//! corner with the previous block, then a reverse and a forward pass over the whole
//! program. Each block is streamed with that plan ([`crate::protocol::Plan`]). The
//! controller ([`Planner`]) does no pass over its queue: pushing a block is O(1)
//! (check the geometry, check the target against the joint travel, add the block to two
//! running sums), and so is choosing the speed at which the executing block may leave:
//! the smaller of the next block's planned entry and the speed from which the machine
//! can still stop within what is buffered ([`Planner::exit_target`]). A feed hold, a
//! feed-override change or a fault re-profiles only the executing block; each later
//! block is profiled when it starts, from the speed the previous one left at, so a stop
//! continues block by block at the planned deceleration.
//!
//! **Stopping within the buffer** (invariant, O(1) per tick): let W be Σ 2·aᵢ·Sᵢ over
//! the queued blocks (the speed² that decelerating at each block's acceleration sheds
//! over them; an exact integer sum). A block is entered at speed v with v² ≤ its own
//! 2·a·S plus the W behind it, and leaves at x with x² ≤ W behind it: so whatever
//! arrives later, or if nothing does, the machine can stop at the end of the buffer.
//! Blocks only add to W. Speeds never exceed the host's plan, whose hard limits
//! (corners, joints) therefore hold.
//!
//! **The host's passes** (grbl's scheme, with its invariants stated):
//! * Reverse pass, last block to first. Invariant after it: every block can
//!   decelerate from its entry speed to the next block's entry speed within its length
//!   (entryᵢ² ≤ entryᵢ₊₁² + 2·aᵢ·Sᵢ), the block after the last is entered at 0 — so
//!   the path always ends in a complete stop — and no entry exceeds its corner limit or
//!   the speed caps of the blocks on either side.
//! * Forward pass, first block to last, from rest. Invariant after it: every block can
//!   also reach its successor's entry by accelerating (entryᵢ₊₁² ≤ entryᵢ² + 2·aᵢ·Sᵢ).
//!
//! Corner limit (the discrete-time rule, stricter than grbl's junction deviation): the
//! path passes through the programmed corner, so the velocity turns from u₁ to u₂ within
//! one tick, and the tick that turns may also carry the blocks' own acceleration. The
//! acceleration budget of each axis and joint is therefore split at a blended corner:
//! a share ρ ≤ ½ goes to the turn, which may change each axis's or joint's speed by at
//! most ρ·aᵢ·T (v ≤ ρ·minᵢ aᵢ·T/|Δuᵢ|), and the two blocks meeting there are profiled
//! with (1 − ρ) of their acceleration. Together never more than aᵢ. ρ is chosen per
//! corner as the share the turn needs at the programmed speed (so a gentle polyline
//! keeps almost all of its acceleration), capped at ½. G61 (tolerance 0) stops exactly
//! at the corner.
//!
//! Speeds are in nm/tick (`f32`), accelerations in nm/tick².

use crate::config::{MachineConfig, AXES, MAX_JOINTS};
use crate::geometry::{Bend, Course, Form, GeometryError, Path, Shape};
use crate::kinematics::{Jacobian, Kinematics, MachineKinematics, Unreachable};
use crate::math::{f32_to_i64, fmax, fmin, i64_to_f32, sqrtf, u64_to_f32};
use crate::protocol::{Aux, Block, Motion, Plan, PlannedBlock};
use crate::units::TICK_HZ;

/// Blocks the controller buffers: enough that the H-4's stopping distance at its top
/// speed, along its XYZ diagonal at 346 mm/s (17.3 mm at 3464 mm/s²), fits in 0.05 mm
/// segments (346 of them) with 22 to spare for the link's latency; with the bends,
/// about all the RAM allows (94.2 of the 96 KiB static budget, see
/// `docs/performance.md`). Programs of dense chords in `G64 P` are streamed as curves,
/// which need far fewer.
pub const QUEUE_CAPACITY: usize = 368;

/// Arcs and curves the controller buffers (their curved parts, [`Bend`]s of 112 bytes
/// on the MCU, are kept apart from the queue's slots, which are line-sized). 48 curves
/// of a merged 0.05 mm program hold seconds of motion (56 until the eight servo
/// channels and their LQG designs needed the RAM).
pub const BEND_CAPACITY: usize = 48;

/// Factor applied to every planned limit so that single-precision rounding cannot
/// take a joint past its own limit.
pub const LIMIT_MARGIN: f32 = 1.0 - 4e-6;

/// Points sampled along a block for its speed limits.
pub const LIMIT_SAMPLES: usize = 5;

/// Most of an axis's or joint's acceleration a spline's bend may take (a half on
/// lines and arcs, see [`split`]): a curve that stands for a run of short moves is
/// taken at a near-constant speed, so its profile needs the smaller share; the
/// chords it stands for, with a corner every few hundred micrometres, would turn
/// with about as much.
pub const SPLINE_BEND_SHARE: f32 = 2.0 / 3.0;

/// Points sampled along a spline (whose bend varies along it: the joints' rates
/// between samples are bounded by their change, which closer samples keep tight).
pub const SPLINE_SAMPLES: usize = 17;

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
}

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

impl PlanBlock {
    /// Length in nm as `f32`.
    pub fn length(&self) -> f32 {
        i64_to_f32(self.path.length)
    }

    /// What the host streams for this block.
    pub fn plan(&self) -> Plan {
        Plan {
            length: self.path.length,
            shape: self.path.shape(),
            v_limit: self.v_limit,
            accel: self.accel,
            entry: self.entry,
            stop: self.corner == 0.0,
        }
    }
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
    /// Jerk-limitation window, ticks (1: none); see [`crate::interp`].
    pub smoothing: u32,
}

fn per_tick(v: i64) -> f32 {
    v as f32 / TICK_HZ as f32
}

fn per_tick2(a: i64) -> f32 {
    a as f32 / (TICK_HZ as f32 * TICK_HZ as f32)
}

/// Soft speed cap of a block (feed × override, 0 in a hold), nm/tick.
pub fn cap(b: &PlanBlock, feed_override: u16, hold: bool) -> f32 {
    cap_of(b.kind, b.feed, b.v_limit, feed_override, hold)
}

fn cap_of(kind: Kind, feed: f32, v_limit: f32, feed_override: u16, hold: bool) -> f32 {
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
            smoothing,
        }
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
        let mut kind = kind_of(block, &path);
        let feed = feed_of(block, &path, kind);
        // The fastest this block may be asked to go (feed override up to 200 %).
        let requested = feed * 2.0;
        let (v_limit, accel) = match kind {
            Kind::Rapid | Kind::Feed => {
                match limits_along(&self.end, &path, requested, None, machine, kin) {
                    Ok(l) => l,
                    Err(e) => {
                        kind = Kind::Unreachable(e);
                        (0.0, 1.0)
                    }
                }
            }
            _ => (0.0, 1.0),
        };
        // With jerk limitation over w ticks the smoothed speed may exceed the
        // profile's by a·w·T/2 (see below): a curve's or an arc's bend, sized for its
        // speed limit, would then take more than its share; its limit is lowered by
        // that.
        let v_limit = if path.form.bends() && self.smoothing > 1 {
            fmax(
                v_limit - accel * self.smoothing as f32 / 2.0,
                0.25 * v_limit,
            )
        } else {
            v_limit
        };
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
        // the rest for the two blocks' profiles (see the module doc). ρ is what the
        // turn needs at the speed both blocks ask for, at most one half.
        // Path tolerance (G64 P): between two tick samples the tool moves in a
        // straight line, which cuts a corner taken at v (nm/tick) by v·|Δu|/4 at most
        // (the corner half-way through a tick); keep that within the tolerance.
        let du = sqrtf(
            (0..3)
                .map(|i| {
                    let d = start_tangent[i] - self.end_tangent[i];
                    d * d
                })
                .sum::<f32>(),
        );
        let by_tolerance = if self.end_tolerance == u32::MAX || du < 1e-9 {
            f32::INFINITY
        } else {
            4.0 * self.end_tolerance as f32 / du
        };
        let (corner, rho) = match need {
            None => (0.0, 0.0),
            Some(n) if n <= 0.0 => (by_tolerance, 0.0),
            Some(n) => {
                // With jerk limitation over w ticks the smoothed motion passes the
                // corner up to a·w·T/2 faster than the profile does, and its one-tick
                // turn must stay within aᵢ·T/w per axis (a third of the jerk budget, see
                // [`crate::interp`]); a corner that cannot is a stop, which the executor
                // lets the smoothing settle into before turning.
                let w = self.smoothing.max(1) as f32;
                let a_near = prev.as_ref().map_or(0.0, |p| p.accel_full).max(accel);
                let by_jerk = (1.0 / (w * n) - a_near * w / 2.0).max(0.0);
                let limit = by_tolerance.min(if self.smoothing > 1 {
                    by_jerk
                } else {
                    f32::INFINITY
                });
                let prev_v = prev.as_ref().map_or(0.0, |p| p.feed.min(p.v_limit));
                let want = prev_v.min(feed.min(v_limit)).min(limit);
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
                let rho = (want * n * per_tick * 1.0001).max(0.0).min(0.5);
                let v = fmin(rho / n, sqrtf(rho * short / n));
                (v.min(limit), rho)
            }
        };
        if rho > 0.0 {
            if let Some(prev) = prev {
                prev.accel = prev.accel_full * (1.0 - rho.max(prev.rho_in));
            }
        }
        // Where a spline or an arc meets its neighbour its bend jumps: each axis's and joint's
        // acceleration changes by v²·Δx″ in one tick, which jerk limitation over w
        // ticks allows a third of its budget for (aᵢ/w per tick, as a corner's turn).
        let start_bend = path.bend_at(0);
        let corner = if self.smoothing > 1 && moving && corner > 0.0 {
            let jump: [f32; AXES] = core::array::from_fn(|i| start_bend[i] - self.end_bend[i]);
            fmin(
                corner,
                bend_jump_limit(&jump, &self.end, self.smoothing, machine, kin),
            )
        } else {
            corner
        };
        self.end_bend = path.bend_at(path.length << 16);
        self.end = path.end;
        self.end_tangent = path.tangent_at(path.length << 16);
        self.end_stops = !moving || block.tolerance_nm == 0;
        self.end_tolerance = block.tolerance_nm;
        Ok(PlanBlock {
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
        })
    }
}

/// What a block does, given its geometry (a move of length 0 is a dwell of 0 ticks).
fn kind_of(block: &Block, path: &Course) -> Kind {
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
fn feed_of(block: &Block, path: &Course, kind: Kind) -> f32 {
    match kind {
        Kind::Feed if path.rotary_only => per_tick(block.feed.saturating_mul(1000)),
        Kind::Feed => per_tick(block.feed),
        _ => f32::INFINITY,
    }
}

/// Largest entry speed allowed for block `i` (corner, its cap, the previous cap).
fn entry_limit(blocks: &[PlanBlock], i: usize, feed_override: u16, hold: bool) -> f32 {
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
    let out = &mut out[..blocks.len()];
    reverse_pass(out, 100, false);
    forward_pass(out, 0.0);
    if refine_splines(out, 0, start, machine, kin) {
        reverse_pass(out, 100, false);
        forward_pass(out, 0.0);
    }
    Ok(())
}

/// A second look at the splines once the passes know how fast each one runs
/// (`blocks[from..]`; `start`: where `blocks[0]` starts): a spline's bend was given
/// the acceleration share it needs at its feed ([`split`]), but one that runs slower
/// (a neighbour's corner, a bend further on, the stop at the end) needs less of it;
/// its limits are found again for the speed it reaches, which gives its profile the
/// rest, and its hard speed limit becomes that speed. Nothing else changes; true when
/// any spline changed (the passes are then run again).
pub fn refine_splines(
    blocks: &mut [PlanBlock],
    from: usize,
    start: [i64; AXES],
    machine: &MachineConfig,
    kin: &MachineKinematics,
) -> bool {
    let mut changed = false;
    for i in from..blocks.len() {
        let b = &blocks[i];
        if b.path.form != Form::Spline || b.kind != Kind::Feed {
            continue;
        }
        let next = blocks.get(i + 1);
        let exit = next
            .filter(|n| matches!(n.kind, Kind::Rapid | Kind::Feed))
            .map_or(0.0, |n| n.entry);
        let top = fmin(cap(b, 100, false), b.v_limit);
        let peak = fmin(
            sqrtf((b.entry * b.entry + exit * exit) / 2.0 + b.accel * b.length()),
            top,
        );
        if peak >= 0.98 * top || peak <= 0.0 {
            continue;
        }
        let from_pose = if i == 0 {
            start
        } else {
            blocks[i - 1].path.end
        };
        let Ok((v, a)) = limits_along(
            &from_pose,
            &b.path,
            b.feed * 2.0,
            Some(peak * 1.01),
            machine,
            kin,
        ) else {
            continue;
        };
        let rho_out = next.map_or(0.0, |n| n.rho_in);
        let b = &mut blocks[i];
        if a > b.accel_full {
            b.v_limit = fmin(b.v_limit, v);
            b.accel_full = a;
            b.accel = a * (1.0 - fmax(b.rho_in, rho_out));
            changed = true;
        }
    }
    changed
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
                let (p, _) = crate::profile::Profile::plan(
                    b.path.length << 16,
                    b.entry,
                    cap(b, 100, false),
                    exit,
                    b.accel,
                );
                ticks += p.duration() as f64 / 4_294_967_296.0;
            }
            _ => {}
        }
    }
    ticks
}

/// Plans one move from `start`, from rest to rest, as the host streams it (a jog, the
/// move home): what [`crate::protocol::Control::Jog`] carries.
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

/// Joint rates per unit of path along `tangent` at `pose`: q′ = J·t, with the
/// kinematics' analytic Jacobian J = ∂q/∂p.
fn joint_rates(
    pose: &[i64; AXES],
    tangent: &[f32; AXES],
    kin: &MachineKinematics,
    n: usize,
) -> Result<[f32; MAX_JOINTS], Unreachable> {
    let mut jac: Jacobian = [[0.0; AXES]; MAX_JOINTS];
    kin.jacobian(pose, &mut jac)?;
    let mut r = [0f32; MAX_JOINTS];
    for (r, row) in r.iter_mut().zip(&jac).take(n) {
        *r = row.iter().zip(tangent).map(|(j, t)| j * t).sum();
    }
    Ok(r)
}

/// Speed (nm/tick) and acceleration (nm/tick²) limits of a path for a requested speed
/// `feed` (nm/tick), from every axis and joint at [`LIMIT_SAMPLES`] points, and from
/// curvature.
///
/// A joint moves at q′·v and accelerates at q′·a + q″·v² (q′, q″ its first and second
/// derivatives along the path: q′ = J·t from the kinematics' analytic Jacobian, q″ a
/// central difference of q′, free of the joints' nm rounding that a second difference
/// of the inverse would divide by h²). Where the q″·v² term matters at the requested
/// speed, each joint's acceleration budget is split: half for q′·a, half for q″·v²
/// (v ≤ √(aⱼ/(2|q″|))). On arcs the pose axes get the same split against the
/// centripetal v²/r. Fails when a sampled pose is out of reach or outside a joint's
/// travel.
fn limits_along(
    start: &[i64; AXES],
    path: &Path,
    feed: f32,
    bend_speed: Option<f32>,
    machine: &MachineConfig,
    kin: &MachineKinematics,
) -> Result<(f32, f32), Unreachable> {
    let (mut v, mut a) = (f32::INFINITY, f32::INFINITY);
    let n = machine.joints.len();
    let len = path.length << 16;
    // The speed a bend's share of the acceleration is sized for: the requested one,
    // but on a spline the programmed feed (as at a blended corner, whose limit is
    // sized for the programmed speed: a curve that stands for chords keeps their
    // acceleration, and the override cannot take it faster than its bend allows);
    // and on a spline the bend may take up to [`SPLINE_BEND_SHARE`].
    let bend_feed = match bend_speed {
        Some(v) => v,
        None if path.form == Form::Spline => feed / 2.0,
        None => feed,
    };
    let bend_most = if path.form == Form::Spline {
        SPLINE_BEND_SHARE
    } else {
        0.5
    };
    // Difference step: 0.25 mm, or a quarter of a short block (nm Q16).
    let h = (len / 4).clamp(1 << 16, 250_000 << 16);
    let samples = if path.form == Form::Spline {
        SPLINE_SAMPLES
    } else {
        LIMIT_SAMPLES
    };
    let spacing = path.length as f32 / (samples - 1) as f32;
    let mut q = [0i64; MAX_JOINTS];
    let mut pose = [0i64; AXES];
    for k in 0..samples {
        let s = (len as i128 * k as i128 / (samples as i128 - 1)) as i64;
        path.pose_at(start, s, &mut pose);
        kin.inverse_checked(&pose, &machine.joints, &mut q)?;
        let t = path.tangent_at(s);
        for (rate, l) in t.iter().zip(&machine.axes) {
            let r = rate.abs();
            if r > 1e-12 {
                v = v.min(per_tick(l.max_velocity) / r);
                a = a.min(per_tick2(l.max_accel) / r);
            }
        }
        let rate = joint_rates(&pose, &t, kin, n)?;
        // q″: central difference of the rates inside the block.
        let mid = s.clamp(h.min(len / 2), (len - h).max(len / 2));
        let (s0, s2) = (mid - h.min(mid), mid + h);
        path.pose_at(start, s0, &mut pose);
        let r0 = joint_rates(&pose, &path.tangent_at(s0), kin, n)?;
        path.pose_at(start, s2, &mut pose);
        let r2 = joint_rates(&pose, &path.tangent_at(s2), kin, n)?;
        let span = (s2 - s0) as f32 / 65_536.0;
        for j in 0..n {
            let jc = &machine.joints[j];
            let d2 = ((r2[j] - r0[j]) / span).abs();
            // The rate may grow between samples by up to |q″| × half the spacing.
            let d1 = rate[j].abs() + d2 * spacing / 2.0;
            let (vmax, amax) = (
                per_tick(jc.limits.max_velocity),
                per_tick2(jc.limits.max_accel),
            );
            if d1 > 1e-12 {
                v = v.min(vmax / d1);
            }
            split(&mut v, &mut a, bend_feed, d1, d2, amax, bend_most);
        }
    }
    if let Some(r) = path.radius() {
        // Half the acceleration for the tangential profile, half for the centripetal
        // v²/r: an axis then never sees more than a.
        a /= 2.0;
        v = v.min(crate::math::sqrtf(a * r as f32));
    }
    if let crate::geometry::Bend::Spline(c) = &path.bend {
        // An axis moves at x′·v and accelerates at x′·a + x″·v², with x′ and x″ its
        // exact largest first and second derivatives along the curve: half of its
        // acceleration for each term, as for joints.
        let (d1, d2) = path.course.spline_bounds(c);
        for i in 0..AXES {
            let l = &machine.axes[i];
            if d1[i] > 1e-12 && l.max_velocity > 0 {
                v = v.min(per_tick(l.max_velocity) / d1[i]);
            }
            if l.max_accel > 0 {
                split(
                    &mut v,
                    &mut a,
                    bend_feed,
                    d1[i],
                    d2[i],
                    per_tick2(l.max_accel),
                    bend_most,
                );
            }
        }
    }
    // Single-precision planning rounds to about 10⁻⁷: stay that far inside.
    Ok((v * LIMIT_MARGIN, a * LIMIT_MARGIN))
}

/// The speed (nm/tick) at which a jump `jump` of d²P/ds² (per nm²) at `pose` changes
/// no axis's or joint's acceleration by more than aᵢ/w in one tick (∞ when nothing
/// jumps; 0 where the kinematics cannot be evaluated).
fn bend_jump_limit(
    jump: &[f32; AXES],
    pose: &[i64; AXES],
    smoothing: u32,
    machine: &MachineConfig,
    kin: &MachineKinematics,
) -> f32 {
    if jump.iter().all(|j| j.abs() < 1e-20) {
        return f32::INFINITY;
    }
    let w = smoothing.max(1) as f32;
    let mut v2 = f32::INFINITY;
    for (j, l) in jump.iter().zip(&machine.axes) {
        if j.abs() > 1e-20 && l.max_accel > 0 {
            v2 = v2.min(per_tick2(l.max_accel) / (w * j.abs()));
        }
    }
    // The joints' jump: J·Δx″ (the rest of q″, from the Jacobian's change along the
    // tangent, is the same on both sides of a tangent-continuous join).
    let n = machine.joints.len();
    let Ok(dq) = joint_rates(pose, jump, kin, n) else {
        return 0.0;
    };
    for (d, jc) in dq.iter().zip(&machine.joints) {
        if d.abs() > 1e-20 {
            v2 = v2.min(per_tick2(jc.limits.max_accel) / (w * d.abs()));
        }
    }
    sqrtf(v2)
}

/// Splits an axis's or joint's acceleration budget `amax` between the two terms of
/// its acceleration along a path, x′·a + x″·v² (x′, x″ its largest first and second
/// derivatives along the path): the share ρ the bend needs at the speed asked for
/// (`feed`, or the limit `v` found so far when lower), at most `most`, goes to
/// x″·v² — which caps `v` there — and the rest to the profile's x′·a. A straight
/// path keeps its whole budget; together never more than `amax`.
fn split(v: &mut f32, a: &mut f32, feed: f32, d1: f32, d2: f32, amax: f32, most: f32) {
    let speed = feed.min(*v);
    let rho = if d2 > 0.0 {
        (d2 * speed * speed / amax).min(most)
    } else {
        0.0
    };
    if d1 > 1e-12 {
        *a = a.min((1.0 - rho) * amax / d1);
    }
    if d2 > 0.0 && rho > 0.0 {
        *v = v.min(crate::math::sqrtf(rho * amax / d2));
    }
}

/// What turning from `u1` to `u2` at `pose` costs: the largest |Δuᵢ| / aᵢ over every
/// axis and joint (ticks per nm/tick), so that a corner taken at speed v uses the
/// share v·need of the tightest acceleration budget in one tick. `None` when the
/// kinematics cannot be evaluated there (the corner is then a stop).
fn corner_need(
    u1: &[f32; AXES],
    u2: &[f32; AXES],
    pose: &[i64; AXES],
    machine: &MachineConfig,
    kin: &MachineKinematics,
) -> Option<f32> {
    let mut need = 0.0f32;
    for i in 0..AXES {
        let d = (u2[i] - u1[i]).abs();
        if d > 1e-9 && machine.axes[i].max_accel > 0 {
            need = need.max(d / per_tick2(machine.axes[i].max_accel));
        }
    }
    let n = machine.joints.len();
    let r1 = joint_rates(pose, u1, kin, n).ok()?;
    let r2 = joint_rates(pose, u2, kin, n).ok()?;
    for (j, jc) in machine.joints.iter().enumerate() {
        let d = (r2[j] - r1[j]).abs();
        if d > 1e-9 {
            need = need.max(d / per_tick2(jc.limits.max_accel));
        }
    }
    Some(need)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(x: i64, y: i64, feed_mm_s: i64, tol: u32) -> Block {
        Block {
            line: 1,
            motion: Motion::Linear,
            target: [x, y, 0, 0, 0, 0],
            feed: feed_mm_s * 1_000_000,
            tolerance_nm: tol,
        }
    }

    fn planner_with(blocks: &[Block]) -> Vec<PlanBlock> {
        let m = MachineConfig::cartesian_xyz();
        let k = MachineKinematics::new(&m);
        let mut out = vec![PlanBlock::default(); blocks.len()];
        plan_into(blocks, [0; AXES], &m, &k, 1, &mut out).unwrap();
        out
    }

    fn planned(blocks: &[Block]) -> Vec<PlannedBlock> {
        blocks
            .iter()
            .zip(planner_with(blocks))
            .map(|(b, p)| PlannedBlock {
                block: *b,
                plan: p.plan(),
            })
            .collect()
    }

    #[test]
    fn the_last_block_always_plans_to_stop() {
        let p = planner_with(&[
            line(50_000_000, 0, 50, u32::MAX),
            line(100_000_000, 0, 50, u32::MAX),
        ]);
        let last = p.iter().last().unwrap();
        // It can stop within its own length from its entry speed.
        assert!(last.entry * last.entry <= 2.0 * last.accel * last.length() * 1.0001);
        // Collinear blocks are joined at full speed (50 mm/s = 50 000 nm/tick).
        assert!((last.entry - 50_000.0).abs() < 1.0, "{}", last.entry);
    }

    #[test]
    fn exact_stop_mode_stops_at_every_corner() {
        let p = planner_with(&[line(50_000_000, 0, 50, 0), line(100_000_000, 0, 50, 0)]);
        assert_eq!(p.iter().last().unwrap().entry, 0.0);
    }

    #[test]
    fn a_right_angle_corner_is_taken_at_half_a_times_t() {
        let p = planner_with(&[
            line(50_000_000, 0, 50, u32::MAX),
            line(50_000_000, 50_000_000, 50, u32::MAX),
        ]);
        let e = p.iter().last().unwrap().entry;
        assert!((e - 500.0).abs() < 1.0, "{e}");
    }

    #[test]
    fn a_ten_degree_corner_is_taken_at_the_axis_acceleration_budget() {
        let (c, s) = (10f64.to_radians().cos(), 10f64.to_radians().sin());
        let p = planner_with(&[
            line(50_000_000, 0, 50, u32::MAX),
            line(
                50_000_000 + (50e6 * c) as i64,
                (50e6 * s) as i64,
                50,
                u32::MAX,
            ),
        ]);
        // a = 1000 nm/tick² per axis; |Δu_y| = sin 10°: v = 1000 / (2 sin 10°).
        let want = 1000.0 / (2.0 * s);
        let e = p.iter().last().unwrap().entry as f64;
        assert!((e - want).abs() < want * 0.01, "{e} vs {want}");
    }

    #[test]
    fn a_path_tolerance_bounds_the_corner_speed() {
        // G64 P0.001 at a right angle allows 4 · 1000 nm / √2 per tick, more than the
        // acceleration budget (500 nm/tick): the budget decides.
        let p = planner_with(&[
            line(50_000_000, 0, 50, 1_000),
            line(50_000_000, 50_000_000, 50, 1_000),
        ]);
        let e = p.iter().last().unwrap().entry;
        assert!((e - 500.0).abs() < 1.0, "{e}");
        // G64 P0.0001: 400 nm / √2 per tick.
        let p = planner_with(&[
            line(50_000_000, 0, 50, 100),
            line(50_000_000, 50_000_000, 50, 100),
        ]);
        let e = p.iter().last().unwrap().entry;
        assert!((e - 400.0 / 2f32.sqrt()).abs() < 0.5, "{e}");
    }

    #[test]
    fn a_hold_caps_every_block_at_zero() {
        let mut p = planner_with(&[
            line(50_000_000, 0, 50, u32::MAX),
            line(100_000_000, 0, 50, u32::MAX),
        ]);
        reverse_pass(&mut p, 100, true);
        forward_pass(&mut p, 30_000.0);
        let e = p.iter().last().unwrap().entry;
        // Entered at 30 000 nm/tick, the first block (50 mm) can only slow to
        // sqrt(30000² − 2·1000·5e7) < 0 → 0.
        assert_eq!(e, 0.0);
    }

    #[test]
    fn the_controller_never_leaves_faster_than_it_can_stop_within_its_queue() {
        let m = MachineConfig::cartesian_xyz();
        let k = MachineKinematics::new(&m);
        // 600 collinear 0.05 mm segments at 100 mm/s: the host plans the middle ones
        // at full speed (its look-ahead sees the whole 30 mm), but a queue holding only
        // 0.5 mm of them can stop from √(2·a·0.5 mm) only.
        let blocks: Vec<Block> = (1..=600)
            .map(|i| line(i * 50_000, 0, 100, u32::MAX))
            .collect();
        let plan = planned(&blocks);
        assert!(plan[200].plan.entry > 99_000.0, "{}", plan[200].plan.entry);
        let mut p = Planner::new(plan[199].block.target);
        for b in &plan[200..211] {
            p.push_planned(b, &m, &k).unwrap();
        }
        p.pop();
        // Ten segments behind: 2 · 1000 nm/tick² · 0.5 mm.
        let want = (2.0f32 * 1000.0 * LIMIT_MARGIN * 500_000.0).sqrt();
        let got = p.exit_target();
        assert!((got - want).abs() < want * 1e-4, "{got} vs {want}");
        assert!(got <= plan[201].plan.entry);
        // A full queue lets the planned speed through.
        let mut p = Planner::new(plan[199].block.target);
        for b in &plan[200..200 + QUEUE_CAPACITY] {
            p.push_planned(b, &m, &k).unwrap();
        }
        p.pop();
        assert_eq!(p.exit_target(), plan[201].plan.entry);
        // Draining the queue brings the budget back to exactly zero.
        let mut p = Planner::new([0; AXES]);
        for b in &plan[..11] {
            p.push_planned(b, &m, &k).unwrap();
        }
        while p.pop().is_some() {}
        assert_eq!(p.exit_target(), 0.0);
        assert_eq!(p.buffered_ticks(), 0.0);
    }

    /// A full circle about `center` from and back to the current point.
    fn circle(x: i64, center: [i64; 2]) -> Block {
        Block {
            line: 2,
            motion: Motion::Arc {
                center,
                plane: crate::protocol::Plane::Xy,
                clockwise: true,
                turns: 0,
            },
            target: [x, 0, 0, 0, 0, 0],
            feed: 50_000_000,
            tolerance_nm: u32::MAX,
        }
    }

    #[test]
    fn arcs_wait_for_a_free_bend_lines_do_not_and_each_arc_runs_on_its_own_bend() {
        let m = MachineConfig::cartesian_xyz();
        let k = MachineKinematics::new(&m);
        // A line to X10, then circles through X10 about X5 and X0 in turn (radii 5 and
        // 10 mm), more than the ring of bends holds, then a line.
        let mut blocks = vec![line(10_000_000, 0, 50, u32::MAX)];
        for i in 0..=BEND_CAPACITY {
            blocks.push(circle(10_000_000, [5_000_000 * (i as i64 % 2), 0]));
        }
        blocks.push(line(20_000_000, 0, 50, u32::MAX));
        let plan = planned(&blocks);
        let mut p = Planner::new([0; AXES]);
        for b in &plan[..=BEND_CAPACITY] {
            assert_eq!(p.push_planned(b, &m, &k), Ok(()));
        }
        assert_eq!(p.free_bends(), 0);
        assert_eq!(p.free(), QUEUE_CAPACITY - BEND_CAPACITY - 1);
        // One more arc does not fit; a line does (tried here out of turn, from where the
        // last arc ends, as it would be sent if it came next).
        let extra = &plan[BEND_CAPACITY + 1];
        assert_eq!(p.push_planned(extra, &m, &k), Err(PushError::Full));
        let mut q = p.clone();
        assert_eq!(q.push_planned(&plan[BEND_CAPACITY + 2], &m, &k), Ok(()));
        // The line leaves: still no bend. The first arc leaves: one.
        assert_eq!(p.pop().map(|b| b.course.form), Some(Form::Line));
        assert_eq!(p.free_bends(), 0);
        assert!(p.start());
        assert_eq!(p.bend().circle().r0, 10_000_000);
        p.finish();
        assert_eq!(p.free_bends(), 1);
        assert_eq!(p.push_planned(extra, &m, &k), Ok(()));
        // Every arc executes on its own bend, in order.
        for i in 1..=BEND_CAPACITY {
            assert!(p.start());
            let want = if i % 2 == 0 { 10_000_000 } else { 5_000_000 };
            assert_eq!(p.bend().circle().r0, want, "arc {i}");
            let mut pose = [0; AXES];
            let b = *p.executing().unwrap();
            b.course
                .pose_at(p.bend(), p.front_start(), b.course.length << 15, &mut pose);
            let c = 5_000_000 * (i as i64 % 2);
            assert!((pose[0] - (c - want)).abs() <= 2, "arc {i}: {pose:?}");
            p.finish();
        }
        assert!(p.is_empty());
        assert_eq!(p.free_bends(), BEND_CAPACITY);
    }

    #[test]
    fn a_plan_that_does_not_match_its_block_is_refused() {
        let m = MachineConfig::cartesian_xyz();
        let k = MachineKinematics::new(&m);
        let plan = planned(&[line(10_000_000, 0, 50, u32::MAX)]);
        let mut p = Planner::new([0; AXES]);
        let mut short = plan[0];
        short.plan.length /= 2;
        assert_eq!(
            p.push_planned(&short, &m, &k),
            Err(PushError::Geometry(GeometryError::PlanMismatch))
        );
        let mut elsewhere = plan[0];
        elsewhere.block.target[1] = 3_000_000;
        elsewhere.block.target[0] = 9_539_392;
        assert_eq!(
            p.push_planned(&elsewhere, &m, &k),
            Err(PushError::Geometry(GeometryError::PlanMismatch))
        );
        let mut nan = plan[0];
        nan.plan.v_limit = f32::NAN;
        assert!(p.push_planned(&nan, &m, &k).is_err());
        assert_eq!(p.push_planned(&plan[0], &m, &k), Ok(()));
    }
}
