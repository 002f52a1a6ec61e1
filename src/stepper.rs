//! Step scheduling: joint positions per tick become evenly timed step trains.
//!
//! Each tick, a stepper joint's target step count is the nearest whole step to its
//! commanded position ([`crate::config::Scale::steps_at`]); the difference from the
//! steps already emitted becomes one [`StepTrain`]: `count` rising edges evenly spaced
//! over the tick, the first at `first_edge_ns`, then every `interval_ns`, each held
//! high `pulse_ns`. When the direction changes, DIR switches at the start of the tick
//! and the train is confined to the part of the tick after the drive's DIR-setup time.
//!
//! Invariants: the steps emitted always sum to what the positions demand. A train never
//! breaks the drive's timing ([`crate::config::StepTiming`]): if a tick would need more
//! steps than fit, the excess is carried to the next tick (never dropped) and counted
//! in [`StepScheduler::lagged_ticks`]. Edges of consecutive ticks are at least one
//! interval apart because each train leaves half an interval free at both ends.

use crate::config::{Drive, JointConfig, StepTiming, MAX_JOINTS};
use crate::units::TICK_NS;

/// One tick's step train for one joint; times are from the start of the tick.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StepTrain {
    /// Steps to emit this tick.
    pub count: u32,
    /// DIR level: `true` for positive motion (before any drive inversion).
    pub forward: bool,
    /// Rising edge of the first step, ns after the tick starts.
    pub first_edge_ns: u32,
    /// Time between rising edges, ns.
    pub interval_ns: u32,
    /// STEP high time, ns.
    pub pulse_ns: u32,
}

/// Longest STEP pulse we emit, ns: long enough for opto-coupled inputs.
pub const MAX_PULSE_NS: u32 = 2_000;

#[derive(Clone, Copy, Debug, Default)]
struct Channel {
    emitted: i64,
    /// DIR level last set; `None` until the first train, whose DIR is always treated
    /// as a change (the drive's DIR line may be at either level after power-up).
    forward: Option<bool>,
}

/// Step-train planner for every stepper joint of a machine.
#[derive(Clone, Debug)]
pub struct StepScheduler {
    channels: [Channel; MAX_JOINTS],
    /// Ticks in which some joint could not emit all the steps it needed.
    pub lagged_ticks: u32,
    /// Steps added to each joint's position in steps (set by homing: the drive's step
    /// count where the joint position is zero).
    pub offset: [i64; MAX_JOINTS],
}

impl StepScheduler {
    /// A scheduler whose joints stand at `joints` (axis units).
    pub fn new(config: &[JointConfig], joints: &[i64; MAX_JOINTS]) -> Self {
        let mut channels = [Channel {
            emitted: 0,
            forward: None,
        }; MAX_JOINTS];
        for (c, (jc, q)) in channels.iter_mut().zip(config.iter().zip(joints)) {
            c.emitted = jc.scale.steps_at(*q);
        }
        Self {
            channels,
            lagged_ticks: 0,
            offset: [0; MAX_JOINTS],
        }
    }

    /// Steps emitted so far by joint `j` (its position in steps).
    pub fn steps(&self, j: usize) -> i64 {
        self.channels[j].emitted
    }

    /// Plans this tick's trains toward `joints`; non-stepper joints get empty trains.
    pub fn tick(
        &mut self,
        config: &[JointConfig],
        joints: &[i64; MAX_JOINTS],
        out: &mut [StepTrain; MAX_JOINTS],
    ) {
        let mut lagged = false;
        for (j, jc) in config.iter().enumerate() {
            out[j] = StepTrain::default();
            let Drive::Stepper { timing, .. } = jc.drive else {
                continue;
            };
            let ch = &mut self.channels[j];
            let want = jc.scale.steps_at(joints[j]) + self.offset[j] - ch.emitted;
            if want == 0 {
                out[j].forward = ch.forward.unwrap_or(true);
                continue;
            }
            let forward = want > 0;
            let start = if Some(forward) != ch.forward {
                timing.dir_setup_ns
            } else {
                0
            };
            let (count, train) = plan_train(want.unsigned_abs(), start, &timing);
            lagged |= u64::from(count) < want.unsigned_abs();
            ch.forward = Some(forward);
            ch.emitted += if forward {
                count as i64
            } else {
                -(count as i64)
            };
            out[j] = StepTrain { forward, ..train };
        }
        if lagged {
            self.lagged_ticks += 1;
        }
    }
}

/// Spreads up to `want` steps evenly over the window `[start, TICK_NS)`; returns how
/// many fit and the train.
fn plan_train(want: u64, start_ns: u32, timing: &StepTiming) -> (u32, StepTrain) {
    let window = TICK_NS.saturating_sub(start_ns);
    let min_interval = timing.min_interval_ns().max(2 * timing.min_pulse_ns).max(1);
    let fits = (window / min_interval) as u64;
    let count = want.min(fits) as u32;
    if count == 0 {
        return (0, StepTrain::default());
    }
    let interval = window / count;
    let pulse = (interval / 2).clamp(timing.min_pulse_ns, MAX_PULSE_NS.max(timing.min_pulse_ns));
    let train = StepTrain {
        count,
        forward: true,
        first_edge_ns: start_ns + interval / 2,
        interval_ns: interval,
        pulse_ns: pulse,
    };
    (count, train)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::MachineConfig;

    #[test]
    fn steps_emitted_always_equal_the_position_demanded() {
        let m = MachineConfig::cartesian_xyz();
        let mut s = StepScheduler::new(&m.joints, &[0; MAX_JOINTS]);
        let mut out = [StepTrain::default(); MAX_JOINTS];
        let mut q = [0i64; MAX_JOINTS];
        let mut total = 0i64;
        for k in 0..500i64 {
            q[0] = (k * 37_123) % 900_000 - 450_000; // jumps both ways
            s.tick(&m.joints, &q, &mut out);
            total += if out[0].forward {
                out[0].count as i64
            } else {
                -(out[0].count as i64)
            };
            assert_eq!(total, m.joints[0].scale.steps_at(q[0]));
        }
    }

    #[test]
    fn a_reversal_waits_for_the_dir_setup_time() {
        let m = MachineConfig::cartesian_xyz();
        let mut s = StepScheduler::new(&m.joints, &[0; MAX_JOINTS]);
        let mut out = [StepTrain::default(); MAX_JOINTS];
        let mut q = [0i64; MAX_JOINTS];
        q[0] = 10_000; // the first train: DIR is set, then the setup time passes
        s.tick(&m.joints, &q, &mut out);
        assert!(out[0].forward);
        assert!(out[0].first_edge_ns >= StepTiming::PACSCI_6410.dir_setup_ns);
        q[0] = 1_010_000; // 400 steps the same way: no wait
        s.tick(&m.joints, &q, &mut out);
        assert!(out[0].first_edge_ns < StepTiming::PACSCI_6410.dir_setup_ns);
        q[0] = 0; // reversal
        s.tick(&m.joints, &q, &mut out);
        assert!(!out[0].forward);
        assert!(out[0].first_edge_ns >= StepTiming::PACSCI_6410.dir_setup_ns);
    }

    #[test]
    fn steps_that_do_not_fit_are_carried_not_dropped() {
        let m = MachineConfig::cartesian_xyz();
        let mut s = StepScheduler::new(&m.joints, &[0; MAX_JOINTS]);
        let mut out = [StepTrain::default(); MAX_JOINTS];
        let mut q = [0i64; MAX_JOINTS];
        q[1] = 10_000_000; // 4000 steps in one tick: more than 2 MHz allows
        s.tick(&m.joints, &q, &mut out);
        assert!(out[1].count < 4000);
        assert_eq!(s.lagged_ticks, 1);
        let mut sum = out[1].count;
        for _ in 0..2 {
            s.tick(&m.joints, &q, &mut out);
            sum += out[1].count;
        }
        assert_eq!(sum, 4000);
        assert!(out[1].interval_ns >= StepTiming::PACSCI_6410.min_interval_ns());
    }
}
