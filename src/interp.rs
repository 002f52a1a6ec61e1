//! Fixed-period interpolator: turns a block into one pose per tick.
//!
//! Source: seeds-digest A, constant path speed with dS = V·T per period. A straight
//! move is planned when it is queued ([`Segment::plan`]) so its duration is known
//! exactly; each tick then evaluates the trapezoid of [`crate::profile`] in closed form
//! (never by accumulation, so there is no drift): pose = start + Δ·num(k)/den, rounded
//! to the nearest unit per axis. The last tick lands exactly on the block's target.
//!
//! Limits: the path speed V is the smallest of the feed and, for every moving axis and
//! joint i, v_max,i·S/|Δ_i| (likewise for acceleration), so no axis or joint exceeds
//! its own limit.

use crate::config::{MachineConfig, AXES};
use crate::kinematics::{Joints, MachineKinematics, Pose, Unreachable};
use crate::profile::Trapezoid;
use crate::protocol::{Block, Motion};
use crate::units::{div_round, TICK_HZ};

/// A planned block, ready to interpolate.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Segment {
    /// NC line.
    pub line: u32,
    /// Start pose.
    pub start: Pose,
    /// Target minus start, axis units.
    pub delta: [i64; AXES],
    /// Speed profile; `None` for a zero-length block.
    pub profile: Option<Trapezoid>,
    /// Set when the target cannot be reached: the block raises an alarm instead of
    /// moving.
    pub unreachable: Option<Unreachable>,
}

/// `a·b/c` for non-negative `a`, `b` and positive `c`, saturating.
fn mul_div(a: i64, b: i64, c: i64) -> u64 {
    (a as u128 * b as u128 / c.max(1) as u128).min(u64::MAX as u128) as u64
}

impl Segment {
    /// Plans `block` starting from `start` on `machine`.
    pub fn plan(
        block: &Block,
        start: &Pose,
        machine: &MachineConfig,
        kin: &MachineKinematics,
    ) -> Segment {
        let mut delta = [0i64; AXES];
        for (d, (t, s)) in delta.iter_mut().zip(block.target.iter().zip(start)) {
            *d = t - s;
        }
        let mut seg = Segment {
            line: block.line,
            start: *start,
            delta,
            profile: None,
            unreachable: None,
        };
        let mut q0: Joints = [0; crate::config::MAX_JOINTS];
        let mut q1 = q0;
        if let Err(e) = kin
            .inverse_checked(start, &machine.joints, &mut q0)
            .and_then(|_| kin.inverse_checked(&block.target, &machine.joints, &mut q1))
        {
            seg.unreachable = Some(e);
            return seg;
        }
        let sq = |r: core::ops::Range<usize>| -> u128 {
            delta[r]
                .iter()
                .map(|d| (*d as i128 * *d as i128) as u128)
                .sum()
        };
        let (linear, rotary) = (sq(0..3), sq(3..6));
        // Path length in nm over XYZ, or in n° when only rotary axes move.
        let (length, feed) = if linear > 0 {
            (linear.isqrt() as i64, block.feed)
        } else {
            (rotary.isqrt() as i64, block.feed.saturating_mul(1000))
        };
        if length == 0 {
            return seg;
        }
        let mut v = match block.motion {
            Motion::Rapid => u64::MAX,
            Motion::Linear => feed.max(1) as u64,
        };
        let mut a = u64::MAX;
        let mut limit = |d: i64, max_v: i64, max_a: i64| {
            if d != 0 {
                v = v.min(mul_div(max_v, length, d.abs()));
                a = a.min(mul_div(max_a, length, d.abs()));
            }
        };
        for (d, l) in delta.iter().zip(&machine.axes) {
            limit(*d, l.max_velocity, l.max_accel);
        }
        for (j, jc) in machine.joints.iter().enumerate() {
            limit(q1[j] - q0[j], jc.limits.max_velocity, jc.limits.max_accel);
        }
        seg.profile = Some(Trapezoid::plan(length as u64, v, a, TICK_HZ));
        seg
    }

    /// Ticks the segment lasts.
    pub fn ticks(&self) -> u32 {
        self.profile.map_or(0, |p| p.ticks())
    }

    /// Pose after `k` ticks.
    pub fn pose_at(&self, k: u32, pose: &mut Pose) {
        match self.profile {
            None => {
                for (p, (s, d)) in pose.iter_mut().zip(self.start.iter().zip(&self.delta)) {
                    *p = s + d;
                }
            }
            Some(prof) => {
                let (num, den) = (prof.progress(k) as i128, prof.den() as i128);
                for (p, (s, d)) in pose.iter_mut().zip(self.start.iter().zip(&self.delta)) {
                    *p = s + div_round(*d as i128 * num, den) as i64;
                }
            }
        }
    }

    /// End pose.
    pub fn end(&self) -> Pose {
        let mut p = [0; AXES];
        self.pose_at(u32::MAX, &mut p);
        p
    }
}

/// Executes one segment at a time, one tick per call.
#[derive(Clone, Debug, Default)]
pub struct Interpolator {
    active: Option<(Segment, u32)>,
}

impl Interpolator {
    /// An idle interpolator.
    pub const fn new() -> Self {
        Self { active: None }
    }

    /// Starts `seg` (replacing any active one).
    pub fn start(&mut self, seg: Segment) {
        self.active = Some((seg, 0));
    }

    /// Is a segment executing?
    pub fn busy(&self) -> bool {
        self.active.is_some()
    }

    /// Ticks left of the active segment.
    pub fn remaining_ticks(&self) -> u32 {
        self.active.map_or(0, |(s, k)| s.ticks().saturating_sub(k))
    }

    /// Advances one tick and writes the new pose; returns `true` when the segment has
    /// ended with this tick. Does nothing and returns `false` when idle.
    pub fn tick(&mut self, pose: &mut Pose) -> bool {
        let Some((seg, k)) = self.active.as_mut() else {
            return false;
        };
        *k += 1;
        seg.pose_at(*k, pose);
        if *k >= seg.ticks() {
            self.active = None;
            return true;
        }
        false
    }

    /// Drops the active segment.
    pub fn stop(&mut self) {
        self.active = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn block(target: [i64; AXES], feed: i64) -> Block {
        Block {
            line: 1,
            motion: Motion::Linear,
            target,
            feed,
        }
    }

    #[test]
    fn a_diagonal_move_ends_exactly_on_its_target() {
        let m = MachineConfig::cartesian_xyz();
        let k = MachineKinematics::new(&m);
        let seg = Segment::plan(
            &block([12_345_678, -3_333_333, 7, 0, 0, 0], 20_000_000),
            &[0; AXES],
            &m,
            &k,
        );
        let mut it = Interpolator::new();
        it.start(seg);
        let mut pose = [0; AXES];
        let mut n = 0;
        while !it.tick(&mut pose) {
            n += 1;
        }
        assert_eq!(n + 1, seg.ticks());
        assert_eq!(pose, [12_345_678, -3_333_333, 7, 0, 0, 0]);
    }

    #[test]
    fn the_slowest_axis_limit_caps_the_path_speed() {
        let mut m = MachineConfig::cartesian_xyz();
        m.axes[2].max_velocity = 10 * crate::units::NM_PER_MM; // Z: 10 mm/s
        let k = MachineKinematics::new(&m);
        // Pure Z move of 10 mm at F = 100 mm/s must take at least 1 s.
        let seg = Segment::plan(
            &block([0, 0, -10_000_000, 0, 0, 0], 100_000_000),
            &[0; 6],
            &m,
            &k,
        );
        assert!(seg.ticks() >= TICK_HZ, "{} ticks", seg.ticks());
    }

    #[test]
    fn an_unreachable_target_is_marked_not_moved() {
        let m = MachineConfig::cartesian_xyz();
        let k = MachineKinematics::new(&m);
        let seg = Segment::plan(
            &block([0, 0, 90_000_000, 0, 0, 0], 1_000_000),
            &[0; 6],
            &m,
            &k,
        );
        assert_eq!(seg.unreachable, Some(Unreachable::JointLimit { joint: 2 }));
    }
}
