//! Look-ahead planning: the speeds at which each block is entered, and the queue of
//! blocks the controller executes.
//!
//! **Where the planning runs.** The whole program is known on the host, so the host
//! plans it ([`plan_into`]) with unlimited look-ahead, using this module's code with
//! the same kinematics: each block's limits (from every pose axis and every joint,
//! sampled along the block through the kinematics, and from curvature on arcs), its
//! corner with the previous block, then a reverse and a forward pass over the whole
//! program. Each block is streamed with that plan ([`crate::motion::block::Plan`]). The
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
//! corner: at most the share the turn needs at the programmed speed (so a gentle
//! polyline keeps almost all of its acceleration), capped at ½, and of that share, its
//! halves and 0, the one under which the two blocks take least time as trapezoids
//! through the corner's speed (a sharp turn between long blocks is worth less than half
//! of their acceleration, and stops). G61 (tolerance 0) stops exactly at the corner.
//!
//! Speeds are in nm/tick (`f32`), accelerations in nm/tick².

mod limits;
mod lookahead;
mod queue;
mod splines;
#[cfg(test)]
mod tests;

pub use limits::{LIMIT_MARGIN, LIMIT_SAMPLES, SPLINE_BEND_SHARE, SPLINE_SAMPLES};
pub use lookahead::{
    cap, forward_pass, jog_target, plan_into, plan_jog, plan_move, planned_ticks, replan_from,
    reverse_pass, Kind, Lookahead, PlanBlock,
};
pub use queue::{Planner, PushError, Queued, BEND_CAPACITY, QUEUE_CAPACITY};
pub use splines::refine_splines;
