//! Step scheduling: joint positions per tick become evenly timed step trains.
//!
//! Each tick, a stepper joint's target step count is the nearest whole step to its
//! commanded position ([`crate::config::Scale::steps_at`]); the difference from the
//! steps already emitted becomes one [`StepTrain`]: `count` rising edges evenly spaced
//! over the tick, the first at `first_edge_ns`, then every `interval_ns`, each held
//! high `pulse_ns`. When the direction changes, DIR switches at the start of the tick
//! and the train is confined to the part of the tick after the drive's DIR-setup time.
//!
//! Every train's first edge comes no later than one interval minus a pulse after the
//! tick starts (`first_edge_ns + pulse_ns <= interval_ns`), so timer hardware can
//! produce it by presetting its counter (`src/bin/firmware/steppers.rs`). A reversal
//! whose train could not keep that (many steps right after the DIR-setup time)
//! announces the direction instead: that tick carries a train of no steps with the new
//! DIR, and its steps move to the next tick, a full period after the DIR change.
//!
//! Invariants: the steps emitted always sum to what the positions demand. A train never
//! breaks the drive's timing ([`crate::config::StepTiming`]): if a tick would need more
//! steps than fit, the excess is carried to the next tick (never dropped) and counted
//! in [`StepScheduler::lagged_ticks`]. Edges of consecutive ticks are at least one
//! interval apart because each train leaves half an interval free at both ends.

use crate::config::{Drive, FastScale, JointConfig, Scale, StepTiming, MAX_JOINTS};
use crate::units::TICK_NS;

/// One tick's step train for one joint; times are from the start of the tick. With
/// `count` = 0 there are no steps and the times mean nothing (they are not cleared).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StepTrain {
    /// Steps to emit this tick.
    pub count: u32,
    /// Rising edge of the first step, ns after the tick starts.
    pub first_edge_ns: u32,
    /// Time between rising edges, ns.
    pub interval_ns: u32,
    /// STEP high time, ns.
    pub pulse_ns: u32,
    /// DIR level: `true` for positive motion (before any drive inversion). Last, so
    /// that clearing a train is four word stores and a byte.
    pub forward: bool,
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
    /// Each joint's scale with its reciprocal (no division per tick).
    fast: [FastScale; MAX_JOINTS],
}

impl StepScheduler {
    /// A scheduler whose joints stand at `joints` (axis units).
    pub fn new(config: &[JointConfig], joints: &[i64; MAX_JOINTS]) -> Self {
        let mut channels = [Channel {
            emitted: 0,
            forward: None,
        }; MAX_JOINTS];
        let mut fast = [Scale::new(1, 1).fast(); MAX_JOINTS];
        for ((c, f), (jc, q)) in channels
            .iter_mut()
            .zip(fast.iter_mut())
            .zip(config.iter().zip(joints))
        {
            c.emitted = jc.scale.steps_at(*q);
            *f = jc.scale.fast();
        }
        Self {
            channels,
            lagged_ticks: 0,
            offset: [0; MAX_JOINTS],
            fast,
        }
    }

    /// Joint `j`'s scale with its reciprocal: the controller's one copy, for its servo
    /// targets too.
    pub fn scale(&self, j: usize) -> &FastScale {
        &self.fast[j]
    }

    /// Steps emitted so far by joint `j` (its position in steps).
    pub fn steps(&self, j: usize) -> i64 {
        self.channels[j].emitted
    }

    /// Plans this tick's trains toward `joints`; non-stepper joints get empty trains.
    /// Returns the first joint whose steps did not all fit its drive's timing (the
    /// rest are carried to the next tick).
    pub fn tick(
        &mut self,
        config: &[JointConfig],
        joints: &[i64; MAX_JOINTS],
        out: &mut [StepTrain; MAX_JOINTS],
    ) -> Option<usize> {
        let mut lagged = None;
        for (j, jc) in config.iter().enumerate() {
            let Drive::Stepper { timing, .. } = jc.drive else {
                out[j].count = 0;
                continue;
            };
            let ch = &mut self.channels[j];
            let want = self.fast[j].steps_at(joints[j]) + self.offset[j] - ch.emitted;
            if want == 0 {
                out[j].count = 0;
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
            ch.forward = Some(forward);
            if train.first_edge_ns + train.pulse_ns > train.interval_ns {
                // Announce DIR now, step from the next tick (see the module docs).
                out[j] = StepTrain {
                    forward,
                    ..StepTrain::default()
                };
                continue;
            }
            if u64::from(count) < want.unsigned_abs() && lagged.is_none() {
                lagged = Some(j);
            }
            ch.emitted += if forward {
                count as i64
            } else {
                -(count as i64)
            };
            out[j] = StepTrain { forward, ..train };
        }
        if lagged.is_some() {
            self.lagged_ticks += 1;
        }
        lagged
    }
}

/// Spreads up to `want` steps evenly over the window `[start, TICK_NS)`; returns how
/// many fit and the train.
fn plan_train(want: u64, start_ns: u32, timing: &StepTiming) -> (u32, StepTrain) {
    let window = TICK_NS.saturating_sub(start_ns);
    let fits = timing.steps_in_tick_after(start_ns) as u64;
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
            let t = out[0];
            assert!(
                t.count == 0 || t.first_edge_ns + t.pulse_ns <= t.interval_ns,
                "{t:?}: the first edge must fit a counter preset"
            );
            total += if out[0].forward {
                out[0].count as i64
            } else {
                -(out[0].count as i64)
            };
            // Within one tick of carried steps (a reversal announced ahead).
            let lag = (total - m.joints[0].scale.steps_at(q[0])).abs();
            assert!(lag <= 400 * 2, "{lag} steps behind");
        }
        // Standing still, everything is emitted.
        for _ in 0..3 {
            s.tick(&m.joints, &q, &mut out);
            total += if out[0].forward {
                out[0].count as i64
            } else {
                -(out[0].count as i64)
            };
        }
        assert_eq!(total, m.joints[0].scale.steps_at(q[0]));
    }

    #[test]
    fn a_fast_reversal_announces_its_direction_a_tick_ahead() {
        let m = MachineConfig::cartesian_xyz();
        let mut s = StepScheduler::new(&m.joints, &[0; MAX_JOINTS]);
        let mut out = [StepTrain::default(); MAX_JOINTS];
        let mut q = [0i64; MAX_JOINTS];
        q[0] = 100_000; // 40 steps forward, the first train: DIR first
        s.tick(&m.joints, &q, &mut out);
        assert_eq!((out[0].count, out[0].forward), (0, true));
        s.tick(&m.joints, &q, &mut out);
        assert_eq!(out[0].count, 40);
        assert!(out[0].first_edge_ns + out[0].pulse_ns <= out[0].interval_ns);
        q[0] = 97_500; // a slow reversal (one step back): within the same tick
        s.tick(&m.joints, &q, &mut out);
        assert_eq!((out[0].count, out[0].forward), (1, false), "{:?}", out[0]);
        assert!(out[0].first_edge_ns >= StepTiming::PACSCI_6410.dir_setup_ns);
        q[0] = 200_000; // a fast one (41 steps forward): DIR now, steps next tick
        s.tick(&m.joints, &q, &mut out);
        assert_eq!((out[0].count, out[0].forward), (0, true));
        s.tick(&m.joints, &q, &mut out);
        assert_eq!(out[0].count, 41);
        assert_eq!(s.steps(0), 80);
    }

    #[test]
    fn every_step_after_a_dir_change_waits_for_the_dir_setup_time() {
        let m = MachineConfig::cartesian_xyz();
        let setup = StepTiming::PACSCI_6410.dir_setup_ns as u64;
        let mut s = StepScheduler::new(&m.joints, &[0; MAX_JOINTS]);
        let mut out = [StepTrain::default(); MAX_JOINTS];
        let mut q = [0i64; MAX_JOINTS];
        let mut dir: Option<(bool, u64)> = None; // level, time of the last change
        for k in 0..400u64 {
            // Back and forth at varying speeds: 1 to 60 steps per tick.
            let step = 2_500 * (1 + (k % 60) as i64);
            q[0] += if (k / 7) % 2 == 0 { step } else { -step };
            s.tick(&m.joints, &q, &mut out);
            let t0 = k * TICK_NS as u64;
            if dir.map(|d| d.0) != Some(out[0].forward) {
                dir = Some((out[0].forward, t0));
            }
            if out[0].count > 0 {
                let first = t0 + out[0].first_edge_ns as u64;
                assert!(first - dir.unwrap().1 >= setup, "tick {k}: {:?}", out[0]);
            }
        }
    }

    #[test]
    fn steps_that_do_not_fit_are_carried_not_dropped() {
        let m = MachineConfig::cartesian_xyz();
        let mut s = StepScheduler::new(&m.joints, &[0; MAX_JOINTS]);
        let mut out = [StepTrain::default(); MAX_JOINTS];
        let mut q = [0i64; MAX_JOINTS];
        q[1] = 10_000_000; // 4000 steps in one tick: more than 2 MHz allows
        s.tick(&m.joints, &q, &mut out);
        assert_eq!(out[1].count, 0, "the first train announces DIR");
        s.tick(&m.joints, &q, &mut out);
        assert!(out[1].count < 4000);
        assert_eq!(s.lagged_ticks, 1);
        let mut sum = out[1].count;
        for _ in 0..3 {
            s.tick(&m.joints, &q, &mut out);
            sum += out[1].count;
            if out[1].count > 0 {
                assert!(out[1].interval_ns >= StepTiming::PACSCI_6410.min_interval_ns());
            }
        }
        assert_eq!(sum, 4000);
    }
}
