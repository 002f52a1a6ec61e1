//! Pacing of the servo loops and the interpolation tick: what the 10 kHz servo
//! interrupt and the 1 kHz tick hand each other, and when. The firmware's interrupt
//! handlers are thin adapters around these two state machines (they read the
//! hardware, call them, and write what they return); the simulator drives the very
//! same code with simulated time, so it reproduces the board's latencies.
//!
//! **Servo side** ([`ServoPacer`], one call per servo period). Every
//! [`SERVO_PER_TICK`]th period is a tick edge. There the pacer first takes the
//! [`Command`] the previous tick posted (read in place from the caller's slot,
//! [`CommandSlot`] or the firmware's mailbox): the tick's targets
//! ([`ServoBank::load_tick`]), the channel map if it changes along the path, and the
//! enable; then it runs the period; then it leaves
//! a [`Snapshot`] of that period (encoder counts, trips, whether each channel's fault
//! input was active in any period since the last edge) and reports the edge
//! ([`ServoPeriod::tick`]): the tick runs next, on that snapshot. A tick that has not
//! posted by the next edge (only if it ran longer than a tick) is counted in
//! [`ServoStats::late_ticks`]; the loops then hold their last target for that tick.
//!
//! **Tick side** ([`TickPacer`], one call per tick). At the start of tick N the caller
//! applies [`TickPacer::due`], the outputs tick N − 1 computed (step trains, DIR and
//! ENABLE); then [`TickPacer::tick`] debounces the raw switch samples
//! ([`crate::drive::debounce`]), builds the controller's [`Inputs`] from them and from edge
//! N's snapshot, advances the controller, keeps its outputs as the next due ones and
//! returns the command to post for edge N + 1.
//!
//! So the targets computed by tick N are loaded at edge N + 1, the same edge at which
//! tick N + 1 starts tick N's step trains: servo and stepper joints follow the path
//! with the same one-tick delay, and the loops always ramp over exactly
//! [`SERVO_PER_TICK`] periods. A limit or home switch reaches the controller two ticks
//! after the tick that first read it (three equal samples), the e-stop in the tick
//! that reads it.
//!
//! Invariants: no time source, no hardware: a call is a period or a tick. The servo
//! side's state is touched only by the servo interrupt, except
//! [`ServoPacer::snapshot`] and [`ServoPacer::stats`], which the tick calls (the
//! firmware under a short critical section: copies only), and the command slot, which
//! the tick writes while the servo side does not read it.

use crate::config::{Drive, MachineConfig, MAX_SERVOS};
use crate::controller::{Controller, Inputs, Outputs};
use crate::drive::contour::{PeriodOutputs, ServoBank};
use crate::drive::debounce::{Debouncer, SwitchFilter, Switches, SWITCH};
use crate::drive::recorder::{self, Row, MAX_SIGNALS, ROW_BYTES};
use crate::drive::servo::{Trip, SERVO_PER_TICK, SETPOINT_FRAC_BITS};
use crate::kinematics::{ContourMap, POSE_AXES};

/// In [`Command::record`]: no signal (past the capture's signals, or none armed).
pub const NOT_SERVO: u8 = 0xff;
/// In [`Command::record`]: a 32-bit signal the tick samples itself, its value in
/// [`Command::record_add`], held over the tick's periods.
pub const HELD: u8 = 0xfe;
/// [`HELD`], a 16-bit signal.
pub const HELD_NARROW: u8 = 0xfd;

/// One tick's servo-period samples for the data recorder: each period's sample of
/// the signals asked for, packed as the recorder's ring holds it, periods in time
/// order.
pub type ServoSamples = [Row; SERVO_PER_TICK];

/// The length of a contour error (mm or degrees) in nm or µ°, rounded.
#[inline(always)]
fn norm_f32(sq: f32) -> i32 {
    (crate::math::sqrtf(sq) * 1.0e6 + 0.5) as i32
}

/// A contour error in the loops' units (mm, degrees) as whole nm and µ° (both a
/// millionth), into `out`.
fn contour_units(e: &[f32; POSE_AXES], out: &mut [i32; POSE_AXES]) {
    for (o, &x) in out.iter_mut().zip(e) {
        *o = (x * 1.0e6) as i32;
    }
}

/// What the servo side saw at the last tick edge, for the tick.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Snapshot {
    /// Encoder positions read in the edge period, counts.
    pub counts: [i64; MAX_SERVOS],
    /// Trip latched by each channel's loop, as of the edge period.
    pub trips: [Option<Trip>; MAX_SERVOS],
    /// Each channel's amplifier fault input was active in at least one period since
    /// the previous edge (edge included).
    pub fault: [bool; MAX_SERVOS],
    /// Servo periods run since start-up (wrapping).
    pub periods: u32,
    /// Each channel's DAC code averaged over the [`SERVO_PER_TICK`] periods up to the
    /// edge (edge included), rounded (for the data recorder).
    pub dac: [u16; MAX_SERVOS],
    /// The contour error estimated in the edge period: X Y Z in nm, the tool
    /// direction's A B in µ° (for the data recorder; zero when uncoupled).
    pub contour: [i32; POSE_AXES],
}

/// What a tick hands to the servo loops, taken at the next tick edge.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Command {
    /// The controller asked for a servo reset: the caller has installed a bank rebuilt
    /// at the snapshot's counts ([`ServoPacer::restart`]) before posting this.
    pub reset: bool,
    /// Each channel's target at the end of the next tick, counts × 2^16.
    pub targets: [i64; MAX_SERVOS],
    /// The controller wants the amplifiers enabled.
    pub enable: bool,
    /// The channels' map to the pose for the next tick, when it changes along the path.
    pub map: Option<ContourMap>,
    /// The data recorder's signals to sample every servo period of the next tick
    /// (`Outputs::servo_record`).
    pub record: [u8; MAX_SIGNALS],
    /// Added to each of them (`Outputs::servo_record_add`).
    pub record_add: [i32; MAX_SIGNALS],
}

impl Command {
    /// The loops standing at `counts` (their own positions), disabled.
    pub fn standing(counts: &[i64; MAX_SERVOS]) -> Self {
        Self {
            reset: false,
            targets: counts.map(|c| c << SETPOINT_FRAC_BITS),
            enable: false,
            map: None,
            record: [NOT_SERVO; MAX_SIGNALS],
            record_add: [0; MAX_SIGNALS],
        }
    }

    /// What the controller's outputs `out` ask of the loops, with the channel map
    /// `map` if the tick completed one ([`Controller::contour_map`]).
    pub fn of(out: &Outputs, map: Option<&ContourMap>) -> Self {
        Self {
            reset: out.servo_reset,
            targets: out.servo_target,
            enable: out.servo_enable,
            map: map.copied(),
            record: out.servo_record,
            record_add: out.servo_record_add,
        }
    }
}

/// Diagnostics of the servo side (wrapping counters).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ServoStats {
    /// Servo periods run.
    pub periods: u32,
    /// Tick edges at which the previous tick had not posted its command yet.
    pub late_ticks: u32,
    /// Some channel's fault input at the last edge (see [`Snapshot::fault`]).
    pub fault: bool,
}

/// What one servo period drives.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ServoPeriod<'a> {
    /// The loops' outputs: DAC codes, amplifier enables, trips (the pacer's own, kept
    /// from one period to the next: nothing is copied).
    pub out: &'a PeriodOutputs,
    /// This period was a tick edge: its snapshot is ready and the tick runs now.
    pub tick: bool,
}

/// The servo loops and their side of the exchange with the tick. See the module
/// documentation. The command a tick posts waits in the caller's slot until the next
/// edge, which reads it in place ([`ServoPacer::period`]): the firmware's mailbox, or
/// a [`CommandSlot`].
#[derive(Clone, Debug, PartialEq)]
pub struct ServoPacer {
    bank: ServoBank,
    /// The bank's outputs, kept from one period to the next
    /// ([`ServoBank::period_into`]).
    out: PeriodOutputs,
    /// `PeriodInputs::enable` in force (from the last command taken).
    enable: bool,
    /// Periods since the last tick edge: 0 at an edge.
    phase: usize,
    /// The next edge's targets are loaded already (the loops' standing ones, at
    /// start-up): an edge without a command is then not a late tick.
    preloaded: bool,
    /// Fault input of each channel seen active since the last edge.
    fault_seen: [bool; MAX_SERVOS],
    stats: ServoStats,
    /// Each channel's DAC codes summed since the last edge.
    dac_sum: [u32; MAX_SERVOS],
    /// The recorder's signals sampled this tick ([`Command::record`]) and what is
    /// added to each.
    record: [u8; MAX_SIGNALS],
    record_add: [i32; MAX_SIGNALS],
    /// `record` names a signal.
    staging: bool,
    /// The recorder's samples of two ticks, by [`ServoPacer::staged`]'s bank: this
    /// tick's being written, the last one's for the tick to read; and their signals.
    staged: [ServoSamples; 2],
    staged_ids: [[u8; MAX_SIGNALS]; 2],
    /// The bank written this tick.
    bank_w: usize,
    snapshot: Snapshot,
}

impl ServoPacer {
    /// The loops of `bank`, whose encoders read `counts`: the next period is a tick
    /// edge, at which the loops hold their own standing targets, disabled, unless a
    /// command comes.
    pub fn new(mut bank: ServoBank, counts: &[i64; MAX_SERVOS]) -> Self {
        // What taking `Command::standing(counts)` does, built in place (the firmware
        // builds the pacer on its stack).
        bank.load_tick(&counts.map(|c| c << SETPOINT_FRAC_BITS));
        Self {
            bank,
            out: PeriodOutputs::IDLE,
            enable: false,
            phase: 0,
            preloaded: true,
            fault_seen: [false; MAX_SERVOS],
            stats: ServoStats::default(),
            dac_sum: [0; MAX_SERVOS],
            record: [NOT_SERVO; MAX_SIGNALS],
            record_add: [0; MAX_SIGNALS],
            staging: false,
            staged: [[[0; ROW_BYTES]; SERVO_PER_TICK]; 2],
            staged_ids: [[NOT_SERVO; MAX_SIGNALS]; 2],
            bank_w: 0,
            snapshot: Snapshot {
                counts: *counts,
                ..Snapshot::default()
            },
        }
    }

    /// The next period is a tick edge: the one that takes a posted command.
    pub fn at_edge(&self) -> bool {
        self.phase == 0
    }

    /// A tick's command, taken at an edge.
    fn take(&mut self, command: &Command) {
        self.bank.load_tick(&command.targets);
        if let Some(map) = &command.map {
            self.bank.load_map(map);
        }
        self.enable = command.enable;
        self.record = command.record;
        self.record_add = command.record_add;
        self.staging = self.record[0] != NOT_SERVO;
    }

    /// One servo period, on the encoder positions `feedback` (counts) and each
    /// channel's amplifier fault input `fault`, both read at the start of the period.
    /// At a tick edge ([`ServoPacer::at_edge`]) `posted` is the command the last tick
    /// posted, if it did (read in place, not kept); elsewhere it is not read.
    pub fn period(
        &mut self,
        feedback: &[i64; MAX_SERVOS],
        fault: &[bool; MAX_SERVOS],
        posted: Option<&Command>,
    ) -> ServoPeriod<'_> {
        for (seen, &f) in self.fault_seen.iter_mut().zip(fault) {
            *seen |= f;
        }
        let edge = self.phase == 0;
        if edge {
            // The last tick's samples are complete: the tick reads them from now on.
            self.bank_w ^= 1;
            match posted {
                Some(command) => self.take(command),
                None if self.preloaded => {}
                None => self.stats.late_ticks = self.stats.late_ticks.wrapping_add(1),
            }
            self.preloaded = false;
        }
        self.bank
            .period_into(feedback, fault, self.enable, &mut self.out);
        self.stats.periods = self.stats.periods.wrapping_add(1);
        if edge {
            self.staged_ids[self.bank_w] = self.record;
        }
        if self.staging {
            if let Some(row) = self.staged[self.bank_w & 1].get_mut(self.phase) {
                stage(
                    row,
                    &self.record,
                    &self.record_add,
                    &self.bank,
                    feedback,
                    &self.out,
                );
            }
        }
        for (sum, &code) in self.dac_sum.iter_mut().zip(&self.out.dac) {
            *sum += code as u32;
        }
        self.phase += 1;
        if self.phase == SERVO_PER_TICK {
            self.phase = 0;
        }
        if edge {
            // The snapshot written in place, field by field (no copy of a whole one).
            self.stats.fault = self.fault_seen.iter().any(|&f| f);
            let snap = &mut self.snapshot;
            snap.counts = *feedback;
            self.bank.trips_into(&mut snap.trips);
            snap.fault = self.fault_seen;
            snap.periods = self.stats.periods;
            for (dac, sum) in snap.dac.iter_mut().zip(&mut self.dac_sum) {
                *dac = ((*sum + SERVO_PER_TICK as u32 / 2) / SERVO_PER_TICK as u32) as u16;
                *sum = 0;
            }
            contour_units(&self.out.contour_error, &mut snap.contour);
            self.fault_seen = [false; MAX_SERVOS];
        }
        ServoPeriod {
            out: &self.out,
            tick: edge,
        }
    }

    /// The recorder's samples of the last complete tick, `SERVO_PER_TICK / 2`
    /// periods from period `half · SERVO_PER_TICK / 2` (the firmware copies them in
    /// two short critical sections), and the signals they are of. Valid until the
    /// next tick edge.
    pub fn staged(&self, half: usize) -> (&[u8; MAX_SIGNALS], &[Row]) {
        let r = self.bank_w ^ 1;
        let n = SERVO_PER_TICK / 2;
        let from = (half % 2) * n;
        (&self.staged_ids[r], &self.staged[r][from..from + n])
    }

    /// Replaces the bank at once (the controller asked for a servo reset: a bank of
    /// its machine standing at the snapshot's counts, built by the tick side). A reset
    /// takes effect before the next edge, up to one tick early: the loops then hold
    /// the snapshot's position, which is what the reset asks; the bank is not carried
    /// in the [`Command`], which keeps the servo side's state to one bank.
    pub fn restart(&mut self, bank: ServoBank) {
        self.bank = bank;
        self.out = PeriodOutputs::IDLE;
    }

    /// The trip latched by each channel's loop, now.
    pub fn trips(&self) -> [Option<Trip>; MAX_SERVOS] {
        self.bank.trips()
    }

    /// The snapshot of the last tick edge.
    pub fn snapshot(&self) -> Snapshot {
        self.snapshot
    }

    /// Diagnostics since start-up.
    pub fn stats(&self) -> ServoStats {
        self.stats
    }
}

/// This period's sample of the recorder's signals `record` into `row`, packed
/// (`drive::recorder::Row`): each servo-side signal's value (wire ids with the channel
/// in place of the joint) plus its `record_add` (a position's joint zero taken off), a
/// [`HELD`] one's `record_add` itself.
fn stage(
    row: &mut Row,
    record: &[u8; MAX_SIGNALS],
    record_add: &[i32; MAX_SIGNALS],
    bank: &ServoBank,
    feedback: &[i64; MAX_SERVOS],
    out: &PeriodOutputs,
) {
    let mut rest = &mut row[..];
    let e = &out.contour_error;
    for (&id, &add) in record.iter().zip(record_add) {
        let c = (id & 0x0f) as usize % MAX_SERVOS;
        let (v, wide) = match id >> 4 {
            0 => (bank.setpoint_counts(c), true),
            1 => (feedback[c] as i32, true),
            // The setpoint's whole counts less the encoder (`following_error`'s whole
            // part, in 32 bits; 16 of it kept, saturated).
            2 => {
                let cmd = bank.setpoint_counts(c);
                (cmd.wrapping_sub(feedback[c] as i32), false)
            }
            3 => (out.dac[c] as i32, false),
            9 => (norm_f32(e[0] * e[0] + e[1] * e[1] + e[2] * e[2]), true),
            10 => (norm_f32(e[3] * e[3] + e[4] * e[4]), true),
            _ if id == NOT_SERVO => break,
            _ => (0, id == HELD),
        };
        let Some(r) = recorder::put(rest, v.wrapping_add(add), wide) else {
            break;
        };
        rest = r;
    }
}

/// A tick's command waiting in memory for the next edge, for the simulator and the
/// tests: what the firmware's mailbox does (`servo_period.rs`). The edge reads it in
/// place.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CommandSlot {
    command: Command,
    posted: bool,
}

impl Default for CommandSlot {
    fn default() -> Self {
        Self {
            command: Command::standing(&[0; MAX_SERVOS]),
            posted: false,
        }
    }
}

impl CommandSlot {
    /// Empty.
    pub fn new() -> Self {
        Self::default()
    }

    /// Posts a tick's command, to be taken at the next tick edge (replacing one not
    /// yet taken).
    pub fn post(&mut self, command: Command) {
        self.command = command;
        self.posted = true;
    }

    /// One period of `pacer` ([`ServoPacer::period`]), taking the posted command at
    /// an edge.
    pub fn period<'a>(
        &mut self,
        pacer: &'a mut ServoPacer,
        feedback: &[i64; MAX_SERVOS],
        fault: &[bool; MAX_SERVOS],
    ) -> ServoPeriod<'a> {
        let posted = pacer.at_edge() && core::mem::take(&mut self.posted);
        pacer.period(feedback, fault, posted.then_some(&self.command))
    }
}

/// What the tick reads itself, raw, besides the servo side's [`Snapshot`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RawInputs {
    /// The e-stop and the limit and home switches, as sampled (debounced by the
    /// [`TickPacer`]).
    pub switches: Switches,
    /// Drive fault lines the tick reads directly (bit j), taken as they are: stepper
    /// drives' lines (none on the reference board). The servo amplifiers' fault
    /// inputs come through the snapshot.
    pub drive_fault: u16,
    /// Encoder count latched by the hardware at an index pulse since the last tick,
    /// per servo channel (none on the reference board).
    pub index: [Option<i64>; MAX_SERVOS],
    /// The touch probe's input as sampled, active when touching (debounced by the
    /// [`TickPacer`] like a switch).
    pub probe: bool,
    /// When the probe's input last changed since the last tick, µs after that tick's
    /// start: a timer's input capture (`None`: no capture).
    pub probe_edge_us: Option<u16>,
}

/// The tick's side of the pacing: the switch filters and the outputs due at the start
/// of the next tick. See the module documentation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TickPacer {
    switches: SwitchFilter,
    probe: Debouncer,
    /// Outputs of the last tick, applied at the start of the next.
    due: Outputs,
    /// What the last tick handed to the controller.
    inputs: Inputs,
}

impl Default for TickPacer {
    fn default() -> Self {
        Self {
            switches: SwitchFilter::new(),
            probe: SWITCH,
            due: Outputs::default(),
            inputs: Inputs::default(),
        }
    }
}

impl TickPacer {
    /// Every switch inactive, nothing due.
    pub fn new() -> Self {
        Self::default()
    }

    /// The outputs the previous tick computed: apply them at the very start of this
    /// tick, before [`TickPacer::tick`].
    pub fn due(&self) -> &Outputs {
        &self.due
    }

    /// The inputs the last tick handed to the controller.
    pub fn inputs(&self) -> &Inputs {
        &self.inputs
    }

    /// The debounced switch states the last tick handed to the controller.
    pub fn switches(&self) -> Switches {
        self.switches.state()
    }

    /// One tick of `ctrl` on the raw inputs `raw` and the snapshot of this tick's
    /// edge; its outputs become [`TickPacer::due`], and the returned command is to be
    /// posted to the servo side for the next edge (after [`ServoPacer::restart`] with
    /// `ServoBank::new(ctrl.machine(), &snapshot.counts)` when it asks for a reset).
    pub fn tick(&mut self, ctrl: &mut Controller, raw: &RawInputs, snapshot: &Snapshot) -> Command {
        let switches = self.switches.sample(&raw.switches);
        let amplifier_fault = if snapshot.fault.iter().any(|&f| f) {
            servo_joints_faulted(ctrl.machine(), &snapshot.fault)
        } else {
            0
        };
        // The update keeps this building when the core adds an input.
        #[allow(clippy::needless_update)]
        let inputs = Inputs {
            encoder_counts: snapshot.counts,
            index: raw.index,
            estop: switches.estop,
            limit: switches.limit,
            home: switches.home,
            drive_fault: raw.drive_fault | amplifier_fault,
            servo_trip: snapshot.trips,
            probe: self.probe.sample(raw.probe),
            probe_raw: raw.probe,
            probe_edge_us: raw.probe_edge_us,
            servo_dac: snapshot.dac,
            contour: snapshot.contour,
            ..Inputs::default()
        };
        self.inputs = inputs;
        self.due = *ctrl.tick(&inputs);
        Command::of(&self.due, ctrl.contour_map())
    }
}

/// Bit j set for every joint of `machine` driven by a servo channel whose fault input
/// is active in `fault`.
fn servo_joints_faulted(machine: &MachineConfig, fault: &[bool; MAX_SERVOS]) -> u16 {
    let mut bits = 0;
    for (j, joint) in machine.joints.iter().enumerate() {
        if let Drive::Servo { channel } = joint.drive {
            if fault.get(channel as usize).copied().unwrap_or(false) {
                bits |= 1 << j;
            }
        }
    }
    bits
}

#[cfg(test)]
#[path = "pacing_tests.rs"]
mod tests;
