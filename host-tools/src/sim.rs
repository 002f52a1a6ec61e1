//! The simulated controller: the core [`Controller`] driven with simulated time against
//! simulated drives.
//!
//! * Stepper drives receive every STEP and DIR edge the step trains describe and check
//!   each against the drive's timing rules ([`StepTiming`]: minimum pulse, maximum
//!   rate, DIR setup and hold); any breach is recorded as a [`Violation`] and fails the
//!   run. They count steps, which is the position a real drive would have moved to.
//! * Servo plants are a second-order model, velocity lagging the command with time
//!   constant τ and position integrating velocity: G(s) = K / (s·(τ·s + 1)), in
//!   encoder counts, integrated with ten sub-steps per tick.
//!
//! Time advances only through [`Simulator::tick`], one interpolation period at a time,
//! so runs are deterministic however fast the host computer is.

use anyhow::Result;
use pkmc::config::{Drive, MachineConfig, StepTiming, MAX_JOINTS, MAX_SERVOS, MAX_STEPPERS};
use pkmc::controller::{Controller, Inputs};
use pkmc::stepper::StepTrain;
use pkmc::units::{to_user, TICK_NS};
use serde::Serialize;
use std::io::Write;

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

/// Second-order servo plant, in encoder counts: G(s) = K / (s·(τ·s + 1)).
#[derive(Clone, Debug)]
pub struct ServoPlant {
    /// Steady-state speed per unit command, counts/s per DAC count.
    pub gain: f64,
    /// Velocity time constant, s.
    pub tau_s: f64,
    velocity: f64,
    /// Position, counts.
    pub position: f64,
}

impl ServoPlant {
    /// A plant at rest at `position` counts.
    pub fn new(gain: f64, tau_s: f64, position: f64) -> Self {
        Self {
            gain,
            tau_s,
            velocity: 0.0,
            position,
        }
    }

    /// Integrates one tick under `command`.
    pub fn step(&mut self, command: i32, dt_s: f64) {
        const SUB: u32 = 10;
        let h = dt_s / SUB as f64;
        for _ in 0..SUB {
            let accel = (self.gain * command as f64 - self.velocity) / self.tau_s;
            self.velocity += accel * h;
            self.position += self.velocity * h;
        }
    }

    /// Encoder reading, whole counts.
    pub fn counts(&self) -> i64 {
        self.position.round() as i64
    }
}

/// Simulated servo plant used for every servo joint: 100 counts/s per DAC count (so
/// ±2047 counts is ±204 700 counts/s), velocity time constant τ = 20 ms.
pub const SERVO_GAIN: f64 = 100.0;
/// See [`SERVO_GAIN`].
pub const SERVO_TAU_S: f64 = 0.02;

/// One trace row, in user units.
#[derive(Clone, Debug, PartialEq)]
pub struct TraceRow {
    /// Time at the end of the tick, s.
    pub t_s: f64,
    /// NC line executing.
    pub line: u32,
    /// Commanded pose, mm and degrees.
    pub pose: [f64; 6],
    /// Commanded joints, mm or degrees.
    pub joints: Vec<f64>,
    /// Joint positions the drives report (steps or encoder counts scaled back).
    pub feedback: Vec<f64>,
}

/// The controller with its simulated hardware.
pub struct Simulator {
    /// The controller under simulation.
    pub ctrl: Controller,
    steppers: [Option<SimStepper>; MAX_STEPPERS],
    servos: [Option<ServoPlant>; MAX_SERVOS],
    /// Ticks simulated.
    pub ticks: u64,
    trace: Option<Box<dyn Write + Send>>,
    /// Identity of the machine the drives were built for.
    machine_id: u32,
    /// File standing in for the controller's flash page, if any.
    pub flash: Option<std::path::PathBuf>,
}

impl Simulator {
    /// A simulator for `machine`, at its home pose.
    pub fn new(machine: MachineConfig) -> Result<Self> {
        let ctrl = Controller::new(machine)
            .map_err(|e| anyhow::anyhow!("machine refused by the controller: {e:?}"))?;
        let mut sim = Self {
            ctrl,
            steppers: Default::default(),
            servos: Default::default(),
            ticks: 0,
            trace: None,
            machine_id: 0,
            flash: None,
        };
        sim.attach_drives();
        Ok(sim)
    }

    /// A simulator whose controller boots from the machine stored in `flash` (as the
    /// firmware boots from its flash page), or from `fallback` when none is stored.
    /// Machines the host loads later are written back to `flash`.
    pub fn with_flash(flash: std::path::PathBuf, fallback: MachineConfig) -> Result<Self> {
        let stored = std::fs::read(&flash)
            .ok()
            .and_then(|b| pkmc::store::read_record(&b).ok());
        let mut sim = Self::new(stored.unwrap_or(fallback))?;
        sim.flash = Some(flash);
        Ok(sim)
    }

    /// Writes a machine the controller adopted to the flash file, as the firmware does.
    pub fn persist(&mut self) -> Result<()> {
        let (Some(path), Some(config)) = (self.flash.as_ref(), self.ctrl.take_store_request())
        else {
            return Ok(());
        };
        let mut rec = [0u8; pkmc::store::HEADER_BYTES + pkmc::store::MAX_CONFIG_BYTES];
        let n = pkmc::store::record(config, &mut rec)
            .ok_or_else(|| anyhow::anyhow!("machine configuration too large to store"))?;
        std::fs::write(path, &rec[..n])?;
        Ok(())
    }

    /// Builds the simulated drives for the controller's machine, standing where the
    /// controller believes its joints are (as after power-up).
    fn attach_drives(&mut self) {
        let machine = self.ctrl.machine().clone();
        self.machine_id = self.ctrl.machine_id();
        self.steppers = Default::default();
        self.servos = Default::default();
        for (j, jc) in machine.joints.iter().enumerate() {
            match jc.drive {
                Drive::Stepper {
                    channel,
                    timing,
                    invert_dir,
                } => {
                    let mut d = SimStepper::new(channel as usize, timing, !invert_dir);
                    d.position = self.ctrl.steps_emitted(j) * if invert_dir { -1 } else { 1 };
                    self.steppers[channel as usize] = Some(d);
                }
                Drive::Servo { channel, .. } => {
                    let at = jc.scale.steps_at(self.ctrl.joints()[j]) as f64;
                    self.servos[channel as usize] =
                        Some(ServoPlant::new(SERVO_GAIN, SERVO_TAU_S, at));
                }
            }
        }
    }

    /// Writes a CSV trace row per tick to `out` from now on (header first).
    pub fn trace_to(&mut self, mut out: Box<dyn Write + Send>) -> Result<()> {
        let n = self.ctrl.machine().joints.len();
        let mut header = String::from("t_s,line,x,y,z,a,b,c");
        for j in 1..=n {
            header += &format!(",q{j}");
        }
        for j in 1..=n {
            header += &format!(",fb{j}");
        }
        writeln!(out, "{header}")?;
        self.trace = Some(out);
        Ok(())
    }

    /// Flushes the trace, if any.
    pub fn finish_trace(&mut self) -> Result<()> {
        if let Some(t) = self.trace.as_mut() {
            t.flush()?;
        }
        Ok(())
    }

    /// Position of joint `j` as its drive reports it, axis units.
    pub fn feedback(&self, j: usize) -> i64 {
        self.feedback_steps(j)
            .map(|s| self.ctrl.machine().joints[j].scale.position_of(s))
            .unwrap_or(0)
    }

    /// Position of joint `j` in drive steps or encoder counts.
    pub fn feedback_steps(&self, j: usize) -> Option<i64> {
        let jc = self.ctrl.machine().joints.get(j)?;
        match jc.drive {
            Drive::Stepper {
                channel,
                invert_dir,
                ..
            } => self.steppers[channel as usize].as_ref().map(|d| {
                if invert_dir {
                    -d.position
                } else {
                    d.position
                }
            }),
            Drive::Servo { channel, .. } => {
                self.servos[channel as usize].as_ref().map(|p| p.counts())
            }
        }
    }

    /// Drive timing breaches of every stepper channel.
    pub fn violations(&self) -> (u64, Vec<Violation>) {
        let mut all = Vec::new();
        let mut count = 0;
        for d in self.steppers.iter().flatten() {
            count += d.violation_count;
            all.extend(d.violations.iter().cloned());
        }
        (count, all)
    }

    /// Simulates one interpolation period.
    pub fn tick(&mut self) -> Result<()> {
        if self.ctrl.machine_id() != self.machine_id {
            // The host loaded another machine: the controller restarted at its home.
            self.attach_drives();
        }
        let mut inputs = Inputs::default();
        for (c, p) in self.servos.iter().enumerate() {
            if let Some(p) = p {
                inputs.encoder_counts[c] = p.counts();
            }
        }
        let out = *self.ctrl.tick(&inputs);
        let t0 = self.ticks * TICK_NS as u64;
        for (d, train) in self.steppers.iter_mut().zip(&out.steps) {
            if let Some(d) = d {
                d.apply(t0, train);
            }
        }
        let dt = TICK_NS as f64 * 1e-9;
        for (p, cmd) in self.servos.iter_mut().zip(&out.servo_command) {
            if let Some(p) = p {
                p.step(*cmd, dt);
            }
        }
        self.ticks += 1;
        if let Some(mut out) = self.trace.take() {
            let row = self.trace_row();
            let written = write_row(out.as_mut(), &row);
            self.trace = Some(out);
            written?;
        }
        Ok(())
    }

    /// The trace row of the current state.
    pub fn trace_row(&self) -> TraceRow {
        let m = self.ctrl.machine();
        let mut pose = [0.0; 6];
        for (i, p) in pose.iter_mut().enumerate() {
            *p = to_user(self.ctrl.pose()[i], pkmc::config::axis_is_rotary(i));
        }
        let n = m.joints.len().min(MAX_JOINTS);
        TraceRow {
            t_s: self.ticks as f64 * TICK_NS as f64 * 1e-9,
            line: self.ctrl.line(),
            pose,
            joints: (0..n)
                .map(|j| to_user(self.ctrl.joints()[j], m.joints[j].rotary))
                .collect(),
            feedback: (0..n)
                .map(|j| to_user(self.feedback(j), m.joints[j].rotary))
                .collect(),
        }
    }
}

fn write_row(out: &mut dyn Write, r: &TraceRow) -> std::io::Result<()> {
    write!(out, "{:.6},{}", r.t_s, r.line)?;
    for v in r.pose.iter().chain(&r.joints).chain(&r.feedback) {
        write!(out, ",{v:.9}")?;
    }
    writeln!(out)
}

#[cfg(test)]
mod tests {
    use super::*;

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

    #[test]
    fn the_servo_plant_settles_at_the_commanded_speed() {
        let mut p = ServoPlant::new(100.0, 0.01, 0.0);
        for _ in 0..1000 {
            p.step(10, 0.001);
        }
        // After 1 s at 1000 counts/s with a 10 ms lag: about 990 counts.
        assert!((p.position - 990.0).abs() < 2.0, "{}", p.position);
    }
}
