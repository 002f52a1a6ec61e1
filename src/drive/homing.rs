//! Homing: finding where the joints are after a reset.
//!
//! Every joint with a home switch ([`Homing::enabled`]) runs the same cycle at once, in
//! joint space (the kinematics are not used: until homed, the pose is not known):
//!
//! 1. **Search**: accelerate at the joint's `max_accel` to `search_velocity` (its sign
//!    is the direction) until the home switch is active, then stop. A joint already on
//!    its switch skips the search.
//! 2. **Latch**: move back at `latch_velocity` until the switch releases. Without
//!    `use_index`, that instant defines the position `switch_at` (to within the
//!    motion of one period at the latch speed: keep it below one step or count per
//!    period for an exact result).
//! 3. **Index** (servo joints with `use_index`): keep going at the latch speed until
//!    the encoder's index pulse; the count latched by the encoder hardware at the
//!    pulse defines `switch_at`, independent of the switch's repeatability.
//! 4. Once every joint has latched: **return** each joint in joint space to the joint
//!    position of the machine's home pose, where the pose is then known exactly.
//!
//! The controller ([`crate::controller`]) owns the joints' positions; [`Homer::tick`]
//! moves them and tells it when a joint has latched, so it can re-base the joint
//! (the actuator's steps or counts stay continuous, the joint position jumps to what
//! the switch says). A search or index hunt that runs further than the joint's whole
//! travel fails the cycle.

use crate::config::{Homing, JointConfig, MAX_JOINTS, MAX_SERVOS};
use crate::math::isqrt_floor;
use crate::units::TICK_HZ;

/// Where one joint is in the cycle.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Phase {
    /// No home switch: waits for the return.
    #[default]
    Waiting,
    /// Moving towards the switch.
    Search,
    /// On the switch: stopping before backing off.
    StopOnSwitch,
    /// Backing off at the latch speed until the switch releases.
    Latch,
    /// Still at the latch speed, waiting for the index pulse.
    Index,
    /// Latched: stopping.
    Latched,
    /// Going to the home pose's joint position.
    Return,
    /// At the home pose's joint position.
    Done,
}

/// What the homing cycle needs from the hardware each tick.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct HomeInputs {
    /// Home switch of each joint (bit j), active.
    pub home: u16,
    /// Encoder count latched at an index pulse during the last tick, per servo channel.
    pub index: [Option<i64>; MAX_SERVOS],
}

/// What happened this tick.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HomeEvent {
    /// Joint `joint` latched: its position is now `switch_at`; with `index`, at the
    /// given encoder count rather than at the joint's present position.
    Latched {
        /// Joint index.
        joint: usize,
        /// Encoder count at the index pulse, if the joint latched on one.
        index: Option<i64>,
    },
    /// Joint `joint` found no switch (or no index) within its travel.
    Failed {
        /// Joint index.
        joint: usize,
    },
    /// Every joint stands at the home pose's joint position.
    Finished,
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Axis {
    phase: Phase,
    /// Speed, axis units/s.
    v: i64,
    /// Remainder of `v / TICK_HZ` carried between ticks.
    carry: i64,
    /// Distance run in the present phase, axis units.
    run: u64,
}

/// The homing cycle of every joint. See the module documentation.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Homer {
    axes: [Axis; MAX_JOINTS],
    active: bool,
}

impl Homer {
    /// Is a cycle running?
    pub fn active(&self) -> bool {
        self.active
    }

    /// Phase of joint `j`.
    pub fn phase(&self, j: usize) -> Phase {
        self.axes[j].phase
    }

    /// Starts a cycle for `joints`.
    pub fn start(&mut self, joints: &[JointConfig]) {
        self.axes = [Axis::default(); MAX_JOINTS];
        for (a, jc) in self.axes.iter_mut().zip(joints) {
            a.phase = if jc.homing.enabled() {
                Phase::Search
            } else {
                Phase::Waiting
            };
        }
        self.active = true;
    }

    /// Abandons the cycle (the joints keep their positions; the speeds are dropped:
    /// only for an alarm, which stops everything at once).
    pub fn cancel(&mut self) {
        self.active = false;
    }

    /// Advances one tick: moves `q` (joint positions, axis units), reports the first
    /// event. `targets` are the home pose's joint positions.
    pub fn tick(
        &mut self,
        joints: &[JointConfig],
        targets: &[i64; MAX_JOINTS],
        inputs: &HomeInputs,
        q: &mut [i64; MAX_JOINTS],
    ) -> Option<HomeEvent> {
        if !self.active {
            return None;
        }
        let mut event = None;
        let all_latched = self.axes[..joints.len()].iter().all(|a| {
            matches!(a.phase, Phase::Waiting | Phase::Return | Phase::Done)
                || (a.phase == Phase::Latched && a.v == 0)
        });
        for (j, jc) in joints.iter().enumerate() {
            let h: Homing = jc.homing;
            let a = &mut self.axes[j];
            let on_switch = inputs.home & (1 << j) != 0;
            let travel = (jc.max - jc.min).unsigned_abs();
            let dir = h.search_velocity.signum();
            if all_latched && matches!(a.phase, Phase::Waiting | Phase::Latched) {
                a.phase = Phase::Return;
                a.run = 0;
            }
            // The phase's target speed.
            let want = match a.phase {
                Phase::Search if on_switch => {
                    a.phase = Phase::StopOnSwitch;
                    0
                }
                Phase::Search => h.search_velocity,
                Phase::StopOnSwitch if a.v == 0 => {
                    a.phase = Phase::Latch;
                    a.run = 0;
                    -dir * h.latch_velocity
                }
                Phase::Latch if !on_switch => {
                    if h.use_index {
                        a.phase = Phase::Index;
                        a.run = 0;
                        -dir * h.latch_velocity
                    } else {
                        a.phase = Phase::Latched;
                        event.get_or_insert(HomeEvent::Latched {
                            joint: j,
                            index: None,
                        });
                        0
                    }
                }
                Phase::Latch => -dir * h.latch_velocity,
                Phase::Index => {
                    let c = match jc.drive {
                        crate::config::Drive::Servo { channel } => channel as usize,
                        _ => 0,
                    };
                    match inputs.index.get(c).copied().flatten() {
                        Some(count) => {
                            a.phase = Phase::Latched;
                            event.get_or_insert(HomeEvent::Latched {
                                joint: j,
                                index: Some(count),
                            });
                            0
                        }
                        None => -dir * h.latch_velocity,
                    }
                }
                Phase::Return => return_speed(jc, targets[j] - q[j]),
                _ => 0,
            };
            // Ramp the speed towards `want` at the joint's acceleration.
            let dv = (jc.limits.max_accel / TICK_HZ as i64).max(1);
            a.v = if want > a.v {
                (a.v + dv).min(want)
            } else {
                (a.v - dv).max(want)
            };
            let total = a.v + a.carry;
            let step = total / TICK_HZ as i64;
            a.carry = total % TICK_HZ as i64;
            if a.phase == Phase::Return {
                let d = targets[j] - q[j];
                // There, or this period's step reaches it (or it is one unit off at rest).
                if d == 0
                    || (d > 0 && step >= d)
                    || (d < 0 && step <= d)
                    || (a.v == 0 && d.abs() <= 1)
                {
                    q[j] = targets[j];
                    a.v = 0;
                    a.carry = 0;
                    a.phase = Phase::Done;
                    continue;
                }
            }
            q[j] += step;
            a.run += step.unsigned_abs();
            let limit = match a.phase {
                Phase::Search | Phase::StopOnSwitch => travel + travel / 10,
                Phase::Latch | Phase::Index => travel / 10,
                _ => u64::MAX,
            };
            if a.run > limit {
                self.active = false;
                return Some(HomeEvent::Failed { joint: j });
            }
        }
        if self.axes[..joints.len()]
            .iter()
            .all(|a| a.phase == Phase::Done)
        {
            self.active = false;
            return Some(HomeEvent::Finished);
        }
        event
    }
}

/// The speed at which a joint `d` units from its home target returns there: the
/// search or latch speed (a tenth of its top speed without homing), braking so as to
/// stop on the target.
#[inline(always)]
fn return_speed(jc: &JointConfig, d: i64) -> i64 {
    let h = jc.homing;
    let vmax = if h.enabled() {
        h.search_velocity.abs().max(h.latch_velocity)
    } else {
        (jc.limits.max_velocity / 10).max(1)
    };
    let brake = isqrt_floor(2 * jc.limits.max_accel as u128 * d.unsigned_abs() as u128)
        .min(i64::MAX as u128) as i64;
    d.signum() * vmax.min(brake)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::MachineConfig;

    /// Home switches: active beyond `switch_at` in the search direction, where the
    /// joints really are (`q + offset`).
    fn switches(m: &MachineConfig, q: &[i64; MAX_JOINTS], offset: &[i64; MAX_JOINTS]) -> u16 {
        let mut bits = 0;
        for (j, jc) in m.joints.iter().enumerate() {
            let h = jc.homing;
            let p = q[j] + offset[j];
            let on = if h.search_velocity > 0 {
                p > h.switch_at
            } else {
                p < h.switch_at
            };
            if h.enabled() && on {
                bits |= 1 << j;
            }
        }
        bits
    }

    #[test]
    fn a_cycle_finds_every_switch_and_returns_home() {
        let m = MachineConfig::cartesian_xyz();
        let n = m.joints.len();
        let mut q = [0i64; MAX_JOINTS];
        let targets = [0i64; MAX_JOINTS];
        // The joints really stand 3.3 mm further than believed.
        let mut offset = [3_300_000i64; MAX_JOINTS];
        let mut h = Homer::default();
        h.start(&m.joints);
        let mut latched = 0;
        let mut finished = false;
        for _ in 0..100_000 {
            let inputs = HomeInputs {
                home: switches(&m, &q, &offset),
                index: [None; MAX_SERVOS],
            };
            match h.tick(&m.joints, &targets, &inputs, &mut q) {
                Some(HomeEvent::Latched { joint, index: None }) => {
                    // Re-base as the controller does: the joint is at `switch_at`.
                    let truth = q[joint] + offset[joint];
                    let at = m.joints[joint].homing.switch_at;
                    // Within one period at the latch speed (1 mm/s: 1 µm).
                    assert!((truth - at).abs() <= 1_000, "{joint}: {truth} vs {at}");
                    q[joint] = at;
                    offset[joint] = truth - at;
                    latched += 1;
                }
                Some(HomeEvent::Finished) => {
                    finished = true;
                    break;
                }
                Some(e) => panic!("{e:?}"),
                None => {}
            }
        }
        assert!(finished && !h.active());
        assert_eq!(latched, n);
        assert_eq!(q, targets);
        assert!(
            offset.iter().take(n).all(|o| o.abs() <= 1_000),
            "{offset:?}"
        );
    }

    #[test]
    fn a_missing_switch_fails_the_cycle_naming_the_joint() {
        let mut m = MachineConfig::cartesian_xyz();
        m.joints[0].homing = Homing::NONE;
        m.joints[2].homing = Homing::NONE;
        let mut q = [0i64; MAX_JOINTS];
        let mut h = Homer::default();
        h.start(&m.joints);
        let inputs = HomeInputs {
            home: 0, // Y's switch never closes
            index: [None; MAX_SERVOS],
        };
        let mut failed = None;
        for _ in 0..1_000_000 {
            if let Some(HomeEvent::Failed { joint }) =
                h.tick(&m.joints, &[0; MAX_JOINTS], &inputs, &mut q)
            {
                failed = Some(joint);
                break;
            }
        }
        assert_eq!(failed, Some(1));
        // It ran no further than its travel and a tenth.
        assert!(q[1] <= 330_000_000 + 20_000_000, "{}", q[1]);
    }
}
