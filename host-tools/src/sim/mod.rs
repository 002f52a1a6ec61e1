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
//! so runs are deterministic however fast the host computer is. Who calls it decides
//! how simulated time relates to the wall clock: the in-process `--check` ticks when
//! the client reads, until the controller has something to say; the server on a pseudo-terminal
//! ([`crate::link::serve`], `--sim`) paces it to the wall clock while the host
//! streams into a short queue, as a board's 1 kHz tick is (see `link`'s module
//! documentation).
//!
//! The controller is paced exactly as on the board, by the same core code
//! ([`pkmc::pacing`]): each tick starts with the servo interrupt's edge period
//! ([`ServoPacer`]: the previous tick's servo targets are loaded, the encoders and
//! trips are snapshotted), then the tick ([`TickPacer`]) applies the previous tick's
//! step trains, debounces the switches ([`pkmc::debounce`]) and runs the controller,
//! then the tick's other nine servo periods run. So stepper and servo joints follow
//! the controller's commands one tick late, and an injected limit or home switch
//! reaches it after the board's three samples (the e-stop at once), as on the board.
//! The switches are sampled at the tick edge, where the joints stand before the tick's
//! trains start.

pub mod faults;
pub mod plant;
pub mod serve;

use crate::sim::plant::{DiscretePlant, PlantFile, TransferFunction};
use anyhow::{bail, Result};
use pkmc::config::{Drive, MachineConfig, StepTiming, MAX_JOINTS, MAX_SERVOS, MAX_STEPPERS};
use pkmc::contour::{PeriodOutputs, ServoBank};
use pkmc::controller::{Controller, Inputs};
use pkmc::debounce::Switches;
use pkmc::pacing::{RawInputs, ServoPacer, Snapshot, TickPacer};
use pkmc::protocol::State;
use pkmc::servo::{DAC_MID, SERVO_HZ, SERVO_PER_TICK};
use pkmc::stepper::StepTrain;
use pkmc::units::{to_user, units_per_user, TICK_NS};
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

/// A simulated servo joint: amplifier and mechanics as a transfer function from the
/// amplifier's command to the joint's displacement ([`crate::sim::plant`]), stepped at the
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
        let before = self.counts - self.zero;
        if self.jammed.is_none() {
            self.plant.step(u);
        }
        let now = self.true_counts(0.0).round() as i64;
        self.counts = now + self.zero;
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

    /// Encoder reading, counts.
    pub fn counts(&self) -> i64 {
        self.counts
    }

    /// True position, counts from the joint's zero.
    pub fn position(&self) -> i64 {
        self.counts - self.zero
    }

    /// Jams the axis where it is (an injected following error).
    pub fn jam(&mut self) {
        self.jammed = Some((self.counts - self.zero) as f64);
    }
}

/// A fault injected into the simulator (`nc-send --inject KIND[:JOINT]@SECONDS`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Injection {
    /// What.
    pub kind: FaultKind,
    /// Joint concerned (limit switch, drive fault, following error), 0-based.
    pub joint: Option<usize>,
    /// Simulated time, s.
    pub at_s: f64,
}

/// Kinds of injectable faults.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FaultKind {
    /// The e-stop input becomes active and stays so.
    EStop,
    /// A joint's limit switch trips and stays tripped.
    Limit,
    /// A joint's drive (or servo amplifier) reports a fault and goes on reporting it.
    DriveFault,
    /// A servo joint jams: it stops moving, so its following error grows.
    FollowingError,
    /// The line goes dead both ways for [`LINK_CUT`] (wall time).
    LinkLoss,
}

/// How long an injected link loss lasts: longer than the controller's limit
/// ([`pkmc::controller::LINK_LOSS_TICKS`], 1 s), shorter than the time after which
/// nc-send gives the link up (3 s), so the host hears the alarm afterwards.
pub const LINK_CUT: std::time::Duration = std::time::Duration::from_millis(1500);

impl std::str::FromStr for Injection {
    type Err = String;
    fn from_str(text: &str) -> Result<Self, String> {
        let bad = |why: &str| {
            format!("--inject {text:?}: {why} (KIND[:JOINT]@SECONDS, KIND one of estop, limit, drive-fault, following-error, link-loss)")
        };
        let (what, at) = text.split_once('@').ok_or_else(|| bad("no @SECONDS"))?;
        let at_s: f64 = at
            .parse()
            .ok()
            .filter(|t: &f64| t.is_finite() && *t >= 0.0)
            .ok_or_else(|| bad("SECONDS must be a non-negative number"))?;
        let (kind, joint) = match what.split_once(':') {
            Some((k, j)) => (
                k,
                Some(
                    j.parse::<usize>()
                        .map_err(|_| bad("JOINT must be a joint index (0-based)"))?,
                ),
            ),
            None => (what, None),
        };
        let kind = match kind {
            "estop" | "e-stop" => FaultKind::EStop,
            "limit" => FaultKind::Limit,
            "drive-fault" => FaultKind::DriveFault,
            "following-error" => FaultKind::FollowingError,
            "link-loss" => FaultKind::LinkLoss,
            other => return Err(bad(&format!("unknown fault {other:?}"))),
        };
        if joint.is_some() && matches!(kind, FaultKind::EStop | FaultKind::LinkLoss) {
            return Err(bad("this fault names no joint"));
        }
        Ok(Injection { kind, joint, at_s })
    }
}

/// Encoder reading of each servo channel (zero where none).
fn counts_of(servos: &[Option<SimServo>; MAX_SERVOS]) -> [i64; MAX_SERVOS] {
    servos
        .each_ref()
        .map(|s| s.as_ref().map_or(0, SimServo::counts))
}

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
    /// NC lines of the blocks the last tick started.
    tick_lines: heapless::Vec<u32, 64>,
    /// Each drive's timing breaches already reported by its fault line.
    violations_seen: [u64; MAX_STEPPERS],
    servos: [Option<SimServo>; MAX_SERVOS],
    /// The servo interrupt's loops and pacing; `None` for a machine without servo
    /// joints (the loops would have nothing to drive).
    servo: Option<ServoPacer>,
    /// Outputs of the last servo period.
    bank_out: PeriodOutputs,
    /// The tick's side of the pacing: switch filters, the step trains due next.
    pacer: TickPacer,
    /// Plant of each joint, from the machine file ([`DEFAULT_PLANT_GAIN`] when absent).
    plants: Vec<Option<PlantFile>>,
    /// True position minus believed position of each joint at power-up, axis units.
    power_up_offset: [i64; MAX_JOINTS],
    injections: Vec<Injection>,
    /// Inputs forced by the injections so far.
    forced: Inputs,
    /// Index marks crossed since the last tick, per servo channel.
    index: [Option<i64>; MAX_SERVOS],
    /// The controller's last outputs.
    last_out: pkmc::controller::Outputs,
    /// The inputs the last tick passed to the controller.
    last_in: Inputs,
    /// First tick at which the controller was in `Alarm` or `EStop` (not the lock
    /// after reset).
    pub alarm_tick: Option<u64>,
    /// Ticks simulated.
    pub ticks: u64,
    /// Ticks since the controller last had work (servo settling runs on).
    idle_ticks: u64,
    trace: Option<Box<dyn Write + Send>>,
    /// Identity of the machine the drives were built for.
    machine_id: u32,
    /// File standing in for the controller's flash page, if any.
    pub flash: Option<std::path::PathBuf>,
}

/// Ticks the simulator goes on running after the controller's work is done, while a
/// servo joint is still settling (more than one count from its target).
pub const SETTLE_TICKS: u64 = 2000;

impl Simulator {
    /// A simulator for `machine`, its joints standing where the controller believes
    /// (its home pose), servo joints with the default plant.
    pub fn new(machine: MachineConfig) -> Result<Self> {
        Self::with_plants(machine, Vec::new(), [0; MAX_JOINTS])
    }

    /// A simulator for `machine` with the plants of its servo joints (indexed by joint;
    /// missing entries take the default) and the joints' true positions at power-up
    /// differing from the believed ones by `power_up_offset` (axis units).
    pub fn with_plants(
        machine: MachineConfig,
        plants: Vec<Option<PlantFile>>,
        power_up_offset: [i64; MAX_JOINTS],
    ) -> Result<Self> {
        let ctrl = Controller::new(machine)
            .map_err(|e| anyhow::anyhow!("machine refused by the controller: {e:?}"))?;
        let mut sim = Self {
            ctrl,
            steppers: Default::default(),
            violations_seen: [0; MAX_STEPPERS],
            tick_lines: heapless::Vec::new(),
            servos: Default::default(),
            servo: None,
            bank_out: PeriodOutputs::default(),
            pacer: TickPacer::new(),
            plants,
            power_up_offset,
            injections: Vec::new(),
            forced: Inputs::default(),
            index: [None; MAX_SERVOS],
            last_out: pkmc::controller::Outputs::default(),
            last_in: Inputs::default(),
            alarm_tick: None,
            ticks: 0,
            idle_ticks: 0,
            trace: None,
            machine_id: 0,
            flash: None,
        };
        sim.attach_drives()?;
        Ok(sim)
    }

    /// Injects faults at their times; refuses one that cannot happen on this machine.
    pub fn inject(&mut self, injections: &[Injection]) -> Result<()> {
        let m = self.ctrl.machine();
        for i in injections {
            let joint = i.joint.unwrap_or_else(|| match i.kind {
                FaultKind::FollowingError => m
                    .joints
                    .iter()
                    .position(|j| matches!(j.drive, Drive::Servo { .. }))
                    .unwrap_or(0),
                _ => 0,
            });
            let Some(jc) = m.joints.get(joint) else {
                bail!(
                    "--inject: joint {joint} does not exist ({} has {} joints, 0-based)",
                    m.name,
                    m.joints.len()
                );
            };
            if i.kind == FaultKind::FollowingError && !matches!(jc.drive, Drive::Servo { .. }) {
                bail!(
                    "--inject following-error: joint {joint} of {} is a stepper: no encoder, \
                     no following error (name a servo joint: following-error:J@SECONDS)",
                    m.name
                );
            }
            self.injections.push(Injection {
                joint: Some(joint),
                ..*i
            });
        }
        Ok(())
    }

    /// The inputs the last [`Simulator::tick`] passed to the controller (for harnesses
    /// that replay a run call by call: `perf/m4count`).
    pub fn last_inputs(&self) -> &Inputs {
        &self.last_in
    }

    /// The outputs the controller returned on the last [`Simulator::tick`].
    pub fn last_outputs(&self) -> &pkmc::controller::Outputs {
        &self.last_out
    }

    /// Simulated time, s.
    pub fn time_s(&self) -> f64 {
        self.ticks as f64 * TICK_NS as f64 * 1e-9
    }

    /// Is an injected link cut due (its start time reached)? True once per injection:
    /// the server then cuts the line for [`LINK_CUT`].
    pub fn take_link_cut(&mut self) -> bool {
        let now = self.time_s();
        if let Some(k) = self
            .injections
            .iter()
            .position(|i| i.kind == FaultKind::LinkLoss && i.at_s <= now)
        {
            self.injections.remove(k);
            return true;
        }
        false
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
    /// controller believes its joints are plus the power-up offsets (as after
    /// power-up: encoder counters read zero, step counts are positions), with the
    /// servo and tick pacing of a board just started.
    fn attach_drives(&mut self) -> Result<()> {
        let machine = self.ctrl.machine().clone();
        self.machine_id = self.ctrl.machine_id();
        self.steppers = Default::default();
        self.violations_seen = [0; MAX_STEPPERS];
        self.servos = Default::default();
        for (j, jc) in machine.joints.iter().enumerate() {
            let truth = self.ctrl.joints()[j] + self.power_up_offset[j];
            match jc.drive {
                Drive::Stepper {
                    channel,
                    timing,
                    invert_dir,
                } => {
                    let mut d = SimStepper::new(channel as usize, timing, !invert_dir);
                    d.position = jc.scale.steps_at(truth) * if invert_dir { -1 } else { 1 };
                    self.steppers[channel as usize] = Some(d);
                }
                Drive::Servo { channel } => {
                    let plant = self.plants.get(j).and_then(Option::as_ref);
                    self.servos[channel as usize] = Some(SimServo::new(jc, plant, truth, 0)?);
                }
            }
        }
        let counts = self.encoder_counts();
        self.servo = self
            .servos
            .iter()
            .any(Option::is_some)
            .then(|| ServoPacer::new(ServoBank::new(&machine, &counts), &counts));
        self.bank_out = PeriodOutputs::default();
        // New drives, standing where the controller's joints are: no train of the old
        // ones is due on them.
        self.pacer = TickPacer::new();
        Ok(())
    }

    fn encoder_counts(&self) -> [i64; MAX_SERVOS] {
        counts_of(&self.servos)
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

    /// True position of joint `j` in drive steps or encoder counts (from the joint's
    /// zero).
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
            Drive::Servo { channel } => self.servos[channel as usize]
                .as_ref()
                .map(SimServo::position),
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

    /// NC lines of the blocks the last tick started, in order.
    pub fn lines_started(&self) -> &[u32] {
        &self.tick_lines
    }

    /// Has the controller computed steps that the drives have not taken yet (the last
    /// tick's trains, which start at the next tick edge, as on the board)?
    pub fn steps_due(&self) -> bool {
        self.pacer.due().steps.iter().any(|t| t.count > 0)
    }

    /// Does simulated time need to advance: the controller has work, or says it is
    /// running (a board's clock never stops: a controller left running with nothing
    /// to do gets the tick that makes it idle, and one stuck running is seen by the
    /// stall guard, which measures simulated time), the last tick's step trains are
    /// still to run, or a servo joint is still settling on its target (for at most
    /// [`SETTLE_TICKS`] after the work)?
    pub fn busy(&self) -> bool {
        if self.ctrl.has_work() || self.ctrl.state() == State::Running || self.steps_due() {
            return true;
        }
        if self.idle_ticks >= SETTLE_TICKS {
            return false;
        }
        self.servos.iter().enumerate().any(|(c, s)| {
            s.as_ref().is_some_and(|s| {
                let target = self.last_out.servo_target[c] >> pkmc::servo::SETPOINT_FRAC_BITS;
                (s.counts() - target).abs() > 1
            }) && self.bank_out.trip[c].is_none()
                && self.last_out.servo_enable
        })
    }

    /// The switches as the joints' true positions set them: home switches (bits),
    /// limit switches (bits).
    fn switches(&self) -> (u16, u16) {
        let m = self.ctrl.machine();
        let (mut home, mut limit) = (0u16, 0u16);
        for (j, jc) in m.joints.iter().enumerate() {
            let Some(steps) = self.feedback_steps(j) else {
                continue;
            };
            let user = units_per_user(jc.rotary) as f64;
            let h = jc.homing;
            if h.enabled() {
                let dir = h.search_velocity.signum();
                let edge = if h.use_index {
                    h.switch_at + dir * (SWITCH_BEFORE_INDEX * user).round() as i64
                } else {
                    h.switch_at
                };
                let e = jc.scale.steps_at(edge);
                if (dir > 0 && steps > e) || (dir < 0 && steps < e) {
                    home |= 1 << j;
                }
            }
            let p = jc.scale.position_of(steps);
            let beyond = (LIMIT_BEYOND_TRAVEL * user).round() as i64;
            if p > jc.max + beyond || p < jc.min - beyond {
                limit |= 1 << j;
            }
        }
        (home, limit)
    }

    fn apply_injections(&mut self) {
        let now = self.time_s();
        let mut k = 0;
        while k < self.injections.len() {
            let i = self.injections[k];
            if i.kind == FaultKind::LinkLoss || i.at_s > now {
                k += 1;
                continue;
            }
            self.injections.remove(k);
            let j = i.joint.unwrap_or(0);
            match i.kind {
                FaultKind::EStop => self.forced.estop = true,
                FaultKind::Limit => self.forced.limit |= 1 << j,
                FaultKind::DriveFault => self.forced.drive_fault |= 1 << j,
                FaultKind::FollowingError => {
                    if let Drive::Servo { channel } = self.ctrl.machine().joints[j].drive {
                        if let Some(s) = self.servos[channel as usize].as_mut() {
                            s.jam();
                        }
                    }
                }
                FaultKind::LinkLoss => {}
            }
        }
    }

    /// Each servo channel's amplifier fault input, from the injected drive faults of
    /// the servo joints.
    fn amplifier_faults(&self) -> [bool; MAX_SERVOS] {
        let mut fault = [false; MAX_SERVOS];
        for (j, jc) in self.ctrl.machine().joints.iter().enumerate() {
            if let Drive::Servo { channel } = jc.drive {
                fault[channel as usize] |= self.forced.drive_fault & (1 << j) != 0;
            }
        }
        fault
    }

    /// One servo period of the servo interrupt, the simulated plants following its
    /// outputs; returns whether it was a tick edge.
    fn servo_period(&mut self, fault: &[bool; MAX_SERVOS]) -> bool {
        let Some(pacer) = self.servo.as_mut() else {
            return false;
        };
        let period = pacer.period(&counts_of(&self.servos), fault);
        self.bank_out = period.out;
        for (c, s) in self.servos.iter_mut().enumerate() {
            if let Some(s) = s {
                let mark = s.period(period.out.dac[c], period.out.enable[c]);
                if self.index[c].is_none() {
                    self.index[c] = mark;
                }
            }
        }
        period.tick
    }

    /// Simulates one interpolation period, in the board's order: the switches as they
    /// stand at the tick edge, the edge's servo period, the previous tick's step
    /// trains, the controller's tick, the remaining servo periods.
    pub fn tick(&mut self) -> Result<()> {
        if self.ctrl.machine_id() != self.machine_id {
            // The host loaded another machine: the controller restarted at its home.
            self.attach_drives()?;
        }
        self.apply_injections();
        let (home, limit) = self.switches();
        let fault = self.amplifier_faults();
        let edge = self.servo_period(&fault);
        let snapshot = match &self.servo {
            Some(pacer) => {
                debug_assert!(edge, "every tick starts at a tick edge");
                pacer.snapshot()
            }
            None => Snapshot::default(),
        };
        let t0 = self.ticks * TICK_NS as u64;
        // A drive that sees its timing breached faults (its fault line is high for
        // this tick): the controller stops and names the joint, instead of believing
        // steps the drive may not have made.
        let mut breached = [false; MAX_STEPPERS];
        for (((d, train), b), seen) in self
            .steppers
            .iter_mut()
            .zip(&self.pacer.due().steps)
            .zip(&mut breached)
            .zip(&mut self.violations_seen)
        {
            if let Some(d) = d {
                d.apply(t0, train);
                *b = d.violation_count > *seen;
                *seen = d.violation_count;
            }
        }
        let mut servo_joints = 0u16;
        let mut timing_fault = 0u16;
        for (j, jc) in self.ctrl.machine().joints.iter().enumerate() {
            match jc.drive {
                Drive::Servo { .. } => servo_joints |= 1 << j,
                Drive::Stepper { channel, .. } if breached[channel as usize] => {
                    timing_fault |= 1 << j
                }
                Drive::Stepper { .. } => {}
            }
        }
        let raw = RawInputs {
            switches: Switches {
                estop: self.forced.estop,
                limit: limit | self.forced.limit,
                home,
            },
            // Stepper drives' fault lines, read by the tick; the servo joints' come
            // through the amplifier fault inputs and the snapshot.
            drive_fault: (self.forced.drive_fault | timing_fault) & !servo_joints,
            index: std::mem::take(&mut self.index),
        };
        let command = self.pacer.tick(&mut self.ctrl, &raw, &snapshot);
        self.tick_lines = self.ctrl.take_line_log();
        self.last_in = *self.pacer.inputs();
        self.last_out = *self.pacer.due();
        if let Some(pacer) = self.servo.as_mut() {
            pacer.post(command);
        }
        for _ in 1..SERVO_PER_TICK {
            self.servo_period(&fault);
        }
        self.ticks += 1;
        self.idle_ticks = if self.ctrl.has_work() {
            0
        } else {
            self.idle_ticks + 1
        };
        let alarmed = matches!(self.ctrl.state(), State::Alarm | State::EStop)
            && self.ctrl.status().alarm.map(|a| a.cause)
                != Some(pkmc::protocol::AlarmCause::Unhomed);
        if alarmed && self.alarm_tick.is_none() {
            self.alarm_tick = Some(self.ticks);
        }
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
    fn a_drive_whose_timing_is_breached_faults_and_the_controller_names_its_joint() {
        let mut sim = Simulator::new(MachineConfig::cartesian_xyz()).unwrap();
        sim.ctrl.unlock();
        sim.tick().unwrap();
        assert_eq!(sim.ctrl.state(), pkmc::protocol::State::Idle);
        // Two 10 ns STEP pulses on Y's drive 100 ns apart: shorter and faster than it
        // allows.
        let y = sim.steppers[1].as_mut().unwrap();
        y.pulse(10_000, 10);
        y.pulse(10_100, 10);
        // The tick reads the drives' fault lines as they stood at its edge (one tick
        // of latency, as on the board).
        sim.tick().unwrap();
        sim.tick().unwrap();
        let alarm = sim.ctrl.status().alarm.expect("an alarm");
        assert_eq!(alarm.cause, pkmc::protocol::AlarmCause::DriveFault);
        assert_eq!(alarm.joint, 1);
        assert!(sim.violations().0 >= 1);
    }

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
    fn injections_parse_and_bad_ones_say_why() {
        let i: Injection = "limit:2@1.5".parse().unwrap();
        assert_eq!(
            i,
            Injection {
                kind: FaultKind::Limit,
                joint: Some(2),
                at_s: 1.5
            }
        );
        assert_eq!(
            "estop@0".parse::<Injection>().unwrap().kind,
            FaultKind::EStop
        );
        let e = "smoke@1".parse::<Injection>().unwrap_err();
        assert!(e.contains("unknown fault \"smoke\""), "{e}");
        assert!("estop:1@1".parse::<Injection>().is_err());
        assert!("limit@-1".parse::<Injection>().is_err());
        assert!("limit"
            .parse::<Injection>()
            .unwrap_err()
            .contains("no @SECONDS"));
    }

    #[test]
    fn a_following_error_cannot_be_injected_into_a_stepper() {
        let mut sim = Simulator::new(MachineConfig::cartesian_xyz()).unwrap();
        let e = sim
            .inject(&["following-error:1@1".parse().unwrap()])
            .unwrap_err();
        assert!(
            format!("{e}").contains("joint 1 of cartesian-xyz is a stepper"),
            "{e}"
        );
    }
}
