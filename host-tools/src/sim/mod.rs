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
//! ([`serve::serve`], `--sim`) paces it to the wall clock while the host
//! streams into a short queue, as a board's 1 kHz tick is (see `serve`'s module
//! documentation).
//!
//! The controller is paced exactly as on the board, by the same core code
//! ([`pkmc::controller::pacing`]): each tick starts with the servo interrupt's edge period
//! ([`ServoPacer`]: the previous tick's servo targets are loaded, the encoders and
//! trips are snapshotted), then the tick ([`TickPacer`]) applies the previous tick's
//! step trains, debounces the switches ([`pkmc::drive::debounce`]) and runs the controller,
//! then the tick's other nine servo periods run. So stepper and servo joints follow
//! the controller's commands one tick late, and an injected limit or home switch
//! reaches it after the board's three samples (the e-stop at once), as on the board.
//! The switches are sampled at the tick edge, where the joints stand before the tick's
//! trains start.

mod drives;
pub mod faults;
mod inject;
pub mod probe;
pub mod serve;
mod trace;

use drives::counts_of;
pub use drives::{
    drive_steps, SimServo, SimStepper, Violation, DEFAULT_PLANT_GAIN, DEFAULT_PLANT_TAU_S,
    INDEX_PITCH, LIMIT_BEYOND_TRAVEL, MAX_VIOLATIONS_KEPT, SWITCH_BEFORE_INDEX,
};
pub use inject::{FaultKind, Injection, LINK_CUT};
use trace::write_row;
pub use trace::TraceRow;

use crate::control::plant::{PlantError, PlantFile};
use pkmc::config::{Drive, MachineConfig, MAX_JOINTS, MAX_SERVOS, MAX_STEPPERS};
use pkmc::controller::pacing::{CommandSlot, RawInputs, ServoPacer, Snapshot, TickPacer};
use pkmc::controller::{Controller, Inputs};
use pkmc::drive::contour::{PeriodOutputs, ServoBank};
use pkmc::drive::debounce::Switches;
use pkmc::drive::servo::SERVO_PER_TICK;
use pkmc::kinematics::MachineKinematics;
use pkmc::units::{units_per_user, TICK_NS};
use pkmc::wire::State;
use std::io::Write;

/// Why the simulator cannot start or go on.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// The controller refused the machine.
    #[error("machine refused by the controller: {0}")]
    Refused(pkmc::config::ConfigError),
    /// A servo joint's plant model is malformed.
    #[error(transparent)]
    Plant(#[from] PlantError),
    /// An injection names a joint the machine does not have.
    #[error("--inject: joint {joint} does not exist ({machine} has {joints} joints, 0-based)")]
    NoSuchJoint {
        /// The joint named, 0-based.
        joint: usize,
        /// The machine's name.
        machine: String,
        /// How many joints it has.
        joints: usize,
    },
    /// A following error injected into a stepper joint, which has no encoder.
    #[error(
        "--inject following-error: joint {joint} of {machine} is a stepper: no encoder, \
         no following error (name a servo joint: following-error:J@SECONDS)"
    )]
    NotAServo {
        /// The joint named, 0-based.
        joint: usize,
        /// The machine's name.
        machine: String,
    },
    /// The machine adopted is too large for the flash page.
    #[error("machine configuration too large to store")]
    TooLarge,
    /// Writing the flash file or the trace failed.
    #[error(transparent)]
    Io(#[from] std::io::Error),
}

/// What the simulator's fallible calls return.
pub type Result<T, E = SimError> = std::result::Result<T, E>;

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
    /// The tick's command for the next tick edge (the firmware's mailbox).
    posted: CommandSlot,
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
    /// The channel map the last tick posted, if it completed one.
    last_map: Option<pkmc::kinematics::ContourMap>,
    /// The inputs the last tick passed to the controller.
    last_in: Inputs,
    /// The servo-period samples the last tick handed to the data recorder
    /// (`Controller::record_servo`), one entry per call: signals and rows.
    last_servo_record: Vec<ServoRecordCall>,
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
    /// The touch probe, if one is modelled ([`probe`]), with the kinematics that find
    /// the tool point.
    probe: Option<(probe::SimProbe, probe::Frame)>,
}

/// One `Controller::record_servo` call: the signals' servo-side ids and the packed
/// samples (one per servo period) handed over.
pub type ServoRecordCall = (
    [u8; pkmc::drive::recorder::MAX_SIGNALS],
    Vec<pkmc::drive::recorder::Row>,
);

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
        let ctrl = Controller::new(machine).map_err(SimError::Refused)?;
        let mut sim = Self {
            ctrl,
            steppers: Default::default(),
            violations_seen: [0; MAX_STEPPERS],
            tick_lines: heapless::Vec::new(),
            servos: Default::default(),
            servo: None,
            posted: CommandSlot::new(),
            bank_out: PeriodOutputs::default(),
            pacer: TickPacer::new(),
            plants,
            power_up_offset,
            injections: Vec::new(),
            forced: Inputs::default(),
            index: [None; MAX_SERVOS],
            last_out: pkmc::controller::Outputs::default(),
            last_map: None,
            last_in: Inputs::default(),
            last_servo_record: Vec::new(),
            alarm_tick: None,
            ticks: 0,
            idle_ticks: 0,
            trace: None,
            machine_id: 0,
            flash: None,
            probe: None,
        };
        sim.attach_drives()?;
        Ok(sim)
    }

    /// Models a touch probe touching `model`'s targets (none: its input stays clear),
    /// on the true machine `truth` (`None`: the machine file's geometry;
    /// [`probe::Frame`]); an error where the true machine cannot be built.
    pub fn set_probe(
        &mut self,
        model: Option<probe::ProbeModel>,
        truth: Option<&probe::Truth>,
    ) -> Result<(), String> {
        let frame = probe::Frame::new(self.ctrl.machine(), truth)?;
        self.probe = model.map(|m| (probe::SimProbe::new(m), frame));
        Ok(())
    }

    /// The tool point where the joints truly are, mm.
    fn tool_point(&mut self) -> Option<[f64; 3]> {
        let mut q = [0i64; MAX_JOINTS];
        for (j, slot) in q
            .iter_mut()
            .enumerate()
            .take(self.ctrl.machine().joints.len())
        {
            *slot = self.feedback(j);
        }
        let pose = *self.ctrl.pose();
        let machine = self.ctrl.machine();
        let (_, frame) = self.probe.as_mut()?;
        Some(frame.point(machine, &q, &pose))
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

    /// The channel map the last tick completed and posted to the servo loops, if any
    /// ([`pkmc::controller::Controller::contour_map`]).
    pub fn last_map(&self) -> Option<&pkmc::kinematics::ContourMap> {
        self.last_map.as_ref()
    }

    /// The servo-period samples the last [`Simulator::tick`] handed to the data
    /// recorder, one entry per `Controller::record_servo` call, in order (none when
    /// it records at the tick or not at all).
    pub fn last_servo_record(&self) -> &[ServoRecordCall] {
        &self.last_servo_record
    }

    /// Simulated time, s.
    pub fn time_s(&self) -> f64 {
        self.ticks as f64 * TICK_NS as f64 * 1e-9
    }

    /// A simulator whose controller boots from the machine stored in `flash` (as the
    /// firmware boots from its flash page), or from `fallback` when none is stored,
    /// its servo joints driving `plants` (the machine file's, as in
    /// [`Simulator::with_plants`]). Machines the host loads later are written back to
    /// `flash`.
    pub fn with_flash(
        flash: std::path::PathBuf,
        fallback: MachineConfig,
        plants: Vec<Option<PlantFile>>,
    ) -> Result<Self> {
        let stored = std::fs::read(&flash)
            .ok()
            .and_then(|b| pkmc::wire::store::read_record(&b).ok());
        let mut sim = Self::with_plants(stored.unwrap_or(fallback), plants, [0; MAX_JOINTS])?;
        sim.flash = Some(flash);
        Ok(sim)
    }

    /// Writes a machine the controller adopted to the flash file, as the firmware does.
    pub fn persist(&mut self) -> Result<()> {
        let (Some(path), Some(config)) = (self.flash.as_ref(), self.ctrl.take_store_request())
        else {
            return Ok(());
        };
        let mut rec = [0u8; pkmc::wire::store::HEADER_BYTES + pkmc::wire::store::MAX_CONFIG_BYTES];
        let n = pkmc::wire::store::record(config, &mut rec).ok_or(SimError::TooLarge)?;
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
        if let Some((_, frame)) = &mut self.probe {
            // The true machine of the new machine file (its own geometry if it has
            // no calibration model).
            let truth = frame.truth().cloned();
            *frame = probe::Frame::new(&machine, truth.as_ref())
                .unwrap_or_else(|_| probe::Frame::Nominal(MachineKinematics::new(&machine)));
        }
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
        self.posted = CommandSlot::new();
        self.bank_out = PeriodOutputs::default();
        // New drives, standing where the controller's joints are: no train of the old
        // ones is due on them.
        self.pacer = TickPacer::new();
        Ok(())
    }

    fn encoder_counts(&self) -> [i64; MAX_SERVOS] {
        counts_of(&self.servos)
    }

    /// Position of joint `j` as its drive reports it, axis units.
    pub fn feedback(&self, j: usize) -> i64 {
        self.feedback_steps(j)
            .map(|s| self.ctrl.machine().joints[j].scale.position_of(s))
            .unwrap_or(0)
    }

    /// True position of joint `j`, its units (nm or n°), as the plant has it: a servo
    /// joint's position not rounded to encoder counts (a stepper's is its steps).
    pub fn true_position(&self, j: usize) -> Option<f64> {
        let jc = self.ctrl.machine().joints.get(j)?;
        let steps = match jc.drive {
            pkmc::config::Drive::Servo { channel } => {
                self.servos[channel as usize].as_ref()?.exact_position()
            }
            _ => self.feedback_steps(j)? as f64,
        };
        Some(steps * jc.scale.per_units as f64 / jc.scale.steps as f64)
    }

    /// True position of joint `j` in drive steps or encoder counts (from the joint's
    /// zero).
    pub fn feedback_steps(&self, j: usize) -> Option<i64> {
        let jc = self.ctrl.machine().joints.get(j)?;
        drives::drive_steps(jc.drive, &self.steppers, &self.servos)
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
        if self.ctrl.has_work()
            || self.ctrl.state() == State::Running
            || self.steps_due()
            || self.ctrl.fresh()
            || self.ctrl.streams()
        {
            // (A controller that has not read its inputs since a machine was loaded
            // does so on its next tick, as a board's would within a period.)
            return true;
        }
        if self.idle_ticks >= SETTLE_TICKS {
            return false;
        }
        let Some(trips) = self.servo.as_ref().map(ServoPacer::trips) else {
            return false;
        };
        self.servos.iter().enumerate().any(|(c, s)| {
            s.as_ref().is_some_and(|s| {
                let target =
                    self.last_out.servo_target[c] >> pkmc::drive::servo::SETPOINT_FRAC_BITS;
                (s.counts() - target).abs() > 1
            }) && trips[c].is_none()
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
        let period = self.posted.period(pacer, &counts_of(&self.servos), fault);
        self.bank_out = *period.out;
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
        // The probe at this tick's start: before this tick's step trains run.
        let (probe, probe_edge_us) = match self.tool_point() {
            Some(p) => self
                .probe
                .as_mut()
                .map_or((false, None), |(sp, _)| sp.sample(p)),
            None => (false, None),
        };
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
            probe,
            probe_edge_us,
        };
        let command = self.pacer.tick(&mut self.ctrl, &raw, &snapshot);
        self.tick_lines = self.ctrl.take_line_log();
        self.last_in = *self.pacer.inputs();
        self.last_out = *self.pacer.due();
        self.last_map = command.map;
        if let Some(pacer) = self.servo.as_mut() {
            if command.reset {
                pacer.restart(ServoBank::new(self.ctrl.machine(), &snapshot.counts));
            }
            self.posted.post(command);
            self.last_servo_record.clear();
            if self.ctrl.records_servo() {
                // As the firmware: the last complete tick's servo-period samples,
                // taken in two halves, handed over in one call.
                let (ids, first) = pacer.staged(0);
                let (_, second) = pacer.staged(1);
                let rows = [first, second].concat();
                self.ctrl.record_servo(ids, &rows);
                self.last_servo_record.push((*ids, rows));
            }
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
            && self.ctrl.status().alarm.map(|a| a.cause) != Some(pkmc::wire::AlarmCause::Unhomed);
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
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_drive_whose_timing_is_breached_faults_and_the_controller_names_its_joint() {
        let mut sim = Simulator::new(MachineConfig::cartesian_xyz()).unwrap();
        sim.ctrl.unlock();
        sim.tick().unwrap();
        assert_eq!(sim.ctrl.state(), pkmc::wire::State::Idle);
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
        assert_eq!(alarm.cause, pkmc::wire::AlarmCause::DriveFault);
        assert_eq!(alarm.joint, 1);
        assert!(sim.violations().0 >= 1);
    }

    #[test]
    fn a_simulator_booting_from_its_flash_file_keeps_the_machine_files_plants() {
        use crate::contour_study::SEED_B;
        let file: crate::machine_file::MachineFile = toml::from_str(SEED_B).unwrap();
        let machine = file.to_config().unwrap();
        let plants: Vec<_> = file.joints.iter().map(|j| j.plant.clone()).collect();
        assert!(
            plants.iter().any(Option::is_some),
            "seed B has servo plants"
        );
        let flash = std::env::temp_dir().join(format!("pkmc-flash-{}.bin", std::process::id()));
        let _ = std::fs::remove_file(&flash);
        let booted = Simulator::with_flash(flash.clone(), machine.clone(), plants.clone()).unwrap();
        let direct = Simulator::with_plants(machine.clone(), plants, [0; MAX_JOINTS]).unwrap();
        let default = Simulator::new(machine).unwrap();
        let plant_of = |s: &Simulator| {
            s.servos
                .iter()
                .map(|d| d.as_ref().map(SimServo::plant).cloned())
                .collect::<Vec<_>>()
        };
        assert_eq!(plant_of(&booted), plant_of(&direct));
        assert_ne!(plant_of(&booted), plant_of(&default));
        let _ = std::fs::remove_file(&flash);
    }
}
