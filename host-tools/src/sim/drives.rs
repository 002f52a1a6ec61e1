//! Simulated drives: stepper drives that count every step and check each edge
//! against the drive's timing rules, and servo joints (a plant under the DAC's held
//! output, an incremental encoder with index marks).

use super::Result;
use crate::control::plant::{DiscretePlant, PlantFile, TransferFunction};
use pkmc::config::{StepTiming, MAX_SERVOS};
use pkmc::drive::servo::{DAC_MID, SERVO_HZ};
use pkmc::drive::stepper::StepTrain;
use pkmc::units::units_per_user;
use serde::Serialize;

/// A breach of a drive's timing rules.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct Violation {
    /// Stepper channel.
    pub channel: usize,
    /// Simulated time of the offending edge, ns.
    pub t_ns: u64,
    /// What was broken.
    pub rule: &'static str,
    /// Measured value against the rule, ns.
    pub measured_ns: u64,
}

/// Violations kept in full; further ones are only counted.
pub const MAX_VIOLATIONS_KEPT: usize = 100;

/// A step/direction drive that checks every edge.
#[derive(Clone, Debug)]
pub struct SimStepper {
    channel: usize,
    timing: StepTiming,
    /// Position in steps (positive when DIR is high).
    pub position: i64,
    dir_high: bool,
    last_dir_change: Option<u64>,
    last_rise: Option<u64>,
    /// Timing breaches seen (first [`MAX_VIOLATIONS_KEPT`]).
    pub violations: Vec<Violation>,
    /// Timing breaches seen in all.
    pub violation_count: u64,
}

impl SimStepper {
    /// A drive on `channel` with DIR initially at `dir_high`.
    pub fn new(channel: usize, timing: StepTiming, dir_high: bool) -> Self {
        Self {
            channel,
            timing,
            position: 0,
            dir_high,
            last_dir_change: None,
            last_rise: None,
            violations: Vec::new(),
            violation_count: 0,
        }
    }

    fn breach(&mut self, t_ns: u64, rule: &'static str, measured_ns: u64) {
        self.violation_count += 1;
        if self.violations.len() < MAX_VIOLATIONS_KEPT {
            self.violations.push(Violation {
                channel: self.channel,
                t_ns,
                rule,
                measured_ns,
            });
        }
    }

    /// DIR set to `high` at `t_ns`.
    pub fn dir(&mut self, t_ns: u64, high: bool) {
        if high == self.dir_high {
            return;
        }
        if let Some(r) = self.last_rise {
            if t_ns - r < self.timing.dir_hold_ns as u64 {
                self.breach(t_ns, "DIR hold after STEP", t_ns - r);
            }
        }
        self.dir_high = high;
        self.last_dir_change = Some(t_ns);
    }

    /// A STEP pulse rising at `rise_ns`, high for `high_ns`.
    pub fn pulse(&mut self, rise_ns: u64, high_ns: u64) {
        if let Some(d) = self.last_dir_change {
            if rise_ns - d < self.timing.dir_setup_ns as u64 {
                self.breach(rise_ns, "DIR setup before STEP", rise_ns - d);
            }
        }
        if let Some(r) = self.last_rise {
            if rise_ns - r < self.timing.min_interval_ns() as u64 {
                self.breach(rise_ns, "STEP rate", rise_ns - r);
            }
        }
        if high_ns < self.timing.min_pulse_ns as u64 {
            self.breach(rise_ns, "STEP pulse width", high_ns);
        }
        self.last_rise = Some(rise_ns);
        self.position += if self.dir_high { 1 } else { -1 };
    }

    /// Applies one tick's train starting at `t0_ns`.
    pub fn apply(&mut self, t0_ns: u64, train: &StepTrain) {
        if train.count == 0 {
            return;
        }
        self.dir(t0_ns, train.forward);
        for i in 0..train.count as u64 {
            let rise = t0_ns + train.first_edge_ns as u64 + i * train.interval_ns as u64;
            self.pulse(rise, train.pulse_ns as u64);
        }
    }
}

/// A simulated servo joint: amplifier and mechanics as a transfer function from the
/// amplifier's command to the joint's displacement ([`crate::control::plant`]), stepped at the
/// servo rate, read back through a quadrature encoder (whole counts, 16-bit hardware
/// counter extended as the firmware does) with index marks.
#[derive(Clone, Debug)]
pub struct SimServo {
    plant: DiscretePlant,
    /// Command units per DAC count above mid-scale.
    input_per_count: f64,
    /// Encoder counts per user unit (mm or degree).
    counts_per_user: f64,
    /// Counts the encoder reads at true joint position zero.
    zero: i64,
    /// True position at power-up, counts from `zero`.
    start: f64,
    /// Frozen (a jammed axis) at this many counts from `zero`.
    jammed: Option<f64>,
    /// Encoder reading now, counts.
    counts: i64,
    /// Index marks at these counts (from `zero`) plus multiples of `index_pitch`.
    index_at: Option<(i64, i64)>,
    /// Encoder noise, σ in counts ([`PlantFile::encoder_noise`]), and its generator.
    noise: f64,
    rng: u64,
    /// The noiseless reading's counts from `zero` (index marks are read from it).
    clean: i64,
}

/// Default plant of a servo joint whose machine file gives none: the amplifier and
/// motor as G(s) = K / (s·(τs + 1)), K = 300 encoder counts/s per DAC count, τ = 20 ms
/// (the model [`pkmc::config::ServoGains::DEFAULT_PLANT`] is tuned for).
pub const DEFAULT_PLANT_GAIN: f64 = 300.0;
/// See [`DEFAULT_PLANT_GAIN`].
pub const DEFAULT_PLANT_TAU_S: f64 = 0.02;
/// Spacing of a simulated encoder's index marks, user units (mm or degrees); one mark
/// sits exactly at the joint's `homing.switch_at`.
pub const INDEX_PITCH: f64 = 5.0;
/// How far beyond the index mark (towards the switch) a simulated home switch of a
/// joint homing on its index releases, user units.
pub const SWITCH_BEFORE_INDEX: f64 = 0.3;
/// How far beyond a joint's travel its simulated limit switches trip, user units.
pub const LIMIT_BEYOND_TRAVEL: f64 = 3.0;

impl SimServo {
    /// The plant of joint `jc` from `file` (or the default), at rest at true
    /// position `at` (axis units), its encoder reading `reading` there.
    pub fn new(
        jc: &pkmc::config::JointConfig,
        file: Option<&PlantFile>,
        at: i64,
        reading: i64,
    ) -> Result<Self> {
        let counts_per_user =
            jc.scale.steps as f64 / jc.scale.per_units as f64 * units_per_user(jc.rotary) as f64;
        let noise = file.map_or(0.0, |f| f.encoder_noise);
        if !(noise.is_finite() && noise >= 0.0) {
            return Err(crate::control::plant::PlantError::NotFinite.into());
        }
        let (tf, input_per_count) = match file {
            Some(f) => (TransferFunction::new(&f.num, &f.den)?, f.input_per_count),
            None => (
                TransferFunction::new(
                    &[DEFAULT_PLANT_GAIN / counts_per_user],
                    &[DEFAULT_PLANT_TAU_S, 1.0, 0.0],
                )?,
                1.0,
            ),
        };
        let start = jc.scale.steps_at(at);
        let zero = reading - start;
        let index_at = (jc.homing.use_index).then(|| {
            (
                jc.scale.steps_at(jc.homing.switch_at),
                (INDEX_PITCH * counts_per_user).round() as i64,
            )
        });
        Ok(Self {
            plant: tf.discretize(1.0 / SERVO_HZ as f64),
            input_per_count,
            counts_per_user,
            zero,
            start: start as f64,
            jammed: None,
            counts: reading,
            index_at,
            noise,
            rng: 0x5EED_0000
                + match jc.drive {
                    pkmc::config::Drive::Servo { channel } => channel as u64,
                    _ => 0,
                },
            clean: reading - zero,
        })
    }

    /// True position, counts from the joint's zero (fractional).
    fn true_counts(&self, u: f64) -> f64 {
        match self.jammed {
            Some(at) => at,
            None => self.start + self.plant.output(u) * self.counts_per_user,
        }
    }

    /// One servo period under DAC code `dac` (amplifier enabled or not); returns the
    /// count of an index mark crossed, if any.
    pub fn period(&mut self, dac: u16, enabled: bool) -> Option<i64> {
        let u = if enabled {
            (dac as i32 - DAC_MID) as f64 * self.input_per_count
        } else {
            0.0
        };
        let before = self.clean;
        if self.jammed.is_none() {
            self.plant.step(u);
        }
        let exact = self.true_counts(0.0);
        let now = exact.round() as i64;
        self.clean = now;
        let noisy = if self.noise > 0.0 {
            (exact + self.noise * self.normal()).round() as i64
        } else {
            now
        };
        self.counts = noisy + self.zero;
        let (first, pitch) = self.index_at?;
        if pitch <= 0 || now == before {
            return None;
        }
        let (lo, hi) = (before.min(now), before.max(now));
        // The mark k with first + k·pitch in (lo, hi] (or [lo, hi) moving down).
        let k = (hi - first).div_euclid(pitch);
        let mark = first + k * pitch;
        let crossed = if now > before {
            mark > lo && mark <= hi
        } else {
            mark >= lo && mark < hi
        };
        crossed.then_some(mark + self.zero)
    }

    /// A standard normal deviate (SplitMix64, Box–Muller).
    fn normal(&mut self) -> f64 {
        let mut uniform = || {
            self.rng = self.rng.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = self.rng;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
        };
        let u1 = uniform().max(1e-300);
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * uniform()).cos()
    }

    /// The plant model, with its state.
    pub fn plant(&self) -> &DiscretePlant {
        &self.plant
    }

    /// Encoder reading, counts.
    pub fn counts(&self) -> i64 {
        self.counts
    }

    /// True position, counts from the joint's zero (without the encoder's noise).
    pub fn position(&self) -> i64 {
        self.clean
    }

    /// True position, counts from the joint's zero, as the plant has it: not rounded to
    /// whole counts (a strictly proper plant's output does not depend on the input).
    pub fn exact_position(&self) -> f64 {
        self.true_counts(0.0)
    }

    /// Jams the axis where it is (an injected following error).
    pub fn jam(&mut self) {
        self.jammed = Some(self.clean as f64);
    }
}

/// Where the drive of a joint driven by `drive` is, from the joint's zero: a
/// stepper's steps (its DIR sense undone) or a servo's encoder counts; `None` if no
/// drive is on that channel. Shared by the simulator and the virtual board.
pub fn drive_steps(
    drive: pkmc::config::Drive,
    steppers: &[Option<SimStepper>],
    servos: &[Option<SimServo>],
) -> Option<i64> {
    match drive {
        pkmc::config::Drive::Stepper {
            channel,
            invert_dir,
            ..
        } => steppers[channel as usize].as_ref().map(|d| {
            if invert_dir {
                -d.position
            } else {
                d.position
            }
        }),
        pkmc::config::Drive::Servo { channel } => {
            servos[channel as usize].as_ref().map(SimServo::position)
        }
    }
}

/// Encoder reading of each servo channel (zero where none).
pub(super) fn counts_of(servos: &[Option<SimServo>; MAX_SERVOS]) -> [i64; MAX_SERVOS] {
    servos
        .each_ref()
        .map(|s| s.as_ref().map_or(0, SimServo::counts))
}

#[cfg(test)]
mod tests {
    use super::*;
    use pkmc::config::StepTiming;

    #[test]
    fn a_step_too_soon_after_a_dir_change_is_a_violation() {
        let mut d = SimStepper::new(0, StepTiming::PACSCI_6410, true);
        d.dir(1_000, false);
        d.pulse(20_000, 500);
        assert_eq!(d.violation_count, 1);
        assert_eq!(d.violations[0].rule, "DIR setup before STEP");
        d.pulse(20_100, 100);
        assert_eq!(d.violation_count, 4); // setup still short, rate, pulse width
        assert_eq!(d.position, -2);
    }
}
