//! The controller state machine: bytes in, bytes out, one interpolation tick at a time.
//!
//! [`Controller::receive`] takes bytes from the link, [`Controller::transmit`] hands
//! back bytes for it, and [`Controller::tick`] advances motion by one period T
//! ([`crate::units::TICK_NS`]) given the inputs read from the hardware, returning the
//! outputs to apply (step trains per stepper channel, targets per servo channel for
//! the 10 kHz loops of [`crate::drive::contour::ServoBank`]). The firmware calls `tick` from
//! its timer interrupt; the simulator calls it with simulated time; both run exactly
//! this code.
//!
//! States: after a reset (or a new machine) the controller is locked in `Alarm`
//! (cause `Unhomed`): it moves once homed (`Home`, state `Homing`, [`crate::drive::homing`])
//! or unlocked (`AlarmReset`). `Idle` (nothing to do) ⇄ `Running` (executing) ⇄ `Hold`
//! (feed hold, pause or tool change: decelerating on the path or stopped on it,
//! resumed by `Resume`). Faults:
//!
//! | fault | raised when | alarm names |
//! |---|---|---|
//! | e-stop input | active (level) | state `EStop`, cause `EStop` |
//! | limit switch | a joint's switch becomes active (not while that joint homes) | `LimitSwitch`, joint |
//! | drive fault | a stepper drive's fault input, or a servo amplifier's, while the drives are powered | `DriveFault`, joint |
//! | following error | a servo loop trips ([`crate::drive::servo`]) | `FollowingError`, joint |
//! | link loss | no valid frame for [`LINK_LOSS_TICKS`] while moving (a jog, MDI, homing) | `LinkLoss` |
//! | host timeout | a streamed job's host silent for its host timeout (`Control::BeginJob`; before that its queue runs out and the state is `Starved`) | `HostTimeout`; the job is held, not dropped |
//! | joint travel | a block would take a joint outside its travel | `JointLimit`, joint |
//! | per-period guard | a joint setpoint would move more in one period than its maximum velocity × T (+ [`GUARD_MARGIN_PERCENT`] + [`GUARD_SLACK_UNITS`]), or a stepper's steps would not fit its drive's timing | `JointSpeed`, joint; the setpoint is not applied, the machine stops at once |
//!
//! Every alarm carries the NC line executing. On a fault the motion stops on the path
//! at the planned deceleration (as a feed hold does, so the stop distance is at most
//! v²/2a plus one period and the position is kept: no step is lost, the pose is where
//! the drives are), then the queue is dropped; nothing moves until `AlarmReset`, which
//! is refused while an e-stop or a drive fault is still active. The drives stay
//! enabled in `Alarm` (holding position) and are disabled in `EStop` once stopped; a
//! tripped servo loop disables its own amplifier. Blocks are planned as they are
//! queued ([`crate::motion::planner`]); control commands bypass the queue.

mod actuators;
pub mod pacing;
mod probing;
mod recording;
mod safety;
mod session;

use crate::config::{BoardChannels, ConfigError, Drive, MachineConfig, MAX_JOINTS, MAX_SERVOS};
use crate::drive::homing::Homer;
use crate::drive::probe::ProbeLatch;
use crate::drive::stepper::{StepScheduler, StepTrain};
use crate::kinematics::hexapod_xy_map::MapBuilder;
use crate::kinematics::ContourMap;
use crate::kinematics::{Joints, MachineKinematics, Unreachable};
use crate::motion::block::Aux;
use crate::motion::interp::{Event, Executor};
use crate::motion::planner::Planner;
use crate::wire::{Alarm, FrameDecoder, HeldJob, JobMark, State, MAX_BODY, MAX_FRAME, NO_JOINT};
pub use actuators::{Inputs, Outputs};
use safety::{alarm_of, UNHOMED};

pub use crate::motion::planner::QUEUE_CAPACITY;
/// Bytes of outgoing frames buffered between two `transmit` calls.
pub const TX_CAPACITY: usize = 2048;
/// Ticks between two unsolicited status messages while moving (50 ms at 1 kHz; at
/// rest, one only if the state changed since the last status). Freed queue slots
/// are reported at once, by an `Ack` of the last block accepted, from the tick that
/// frees them.
pub const STATUS_EVERY_TICKS: u32 = 50;
/// Ticks without a valid frame from the host, while moving, after which the link is
/// lost (1 s at 1 kHz; the host asks for a status at least every 100 ms).
pub const LINK_LOSS_TICKS: u32 = 1000;
/// The host timeout of a streamed job by default (`Control::BeginJob`), ms: the
/// machine file's `host_timeout_s`.
pub const DEFAULT_HOST_TIMEOUT_MS: u32 = 30_000;
/// Shortest host timeout a streamed job may ask for, ms: more than the link-loss
/// watch, so that the short watch is never the longer one.
pub const MIN_HOST_TIMEOUT_MS: u32 = 2_000;
/// Longest host timeout a streamed job may ask for, ms (one hour).
pub const MAX_HOST_TIMEOUT_MS: u32 = 3_600_000;
/// The controller keeps a host timeout in units of this many ticks (100 ms).
pub const PATIENCE_UNIT_TICKS: u32 = 100;

/// The per-period guard's margin: a joint setpoint may move in one period at most its
/// maximum velocity × T plus this share of it, plus [`GUARD_SLACK_UNITS`].
pub const GUARD_MARGIN_PERCENT: u64 = 5;
/// The guard's allowance for rounding, axis units (nm or n°).
pub const GUARD_SLACK_UNITS: u64 = 2;

/// Link counters, for diagnostics.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LinkStats {
    /// Frames that failed COBS, CRC or message decoding, or were overlong.
    pub corrupt: u32,
    /// Outgoing frames dropped because the transmit buffer was full.
    pub tx_dropped: u32,
}

/// The controller. See the module documentation.
pub struct Controller {
    machine: MachineConfig,
    /// The channels of the board it runs on: every machine it adopts is checked
    /// against them.
    board: BoardChannels,
    kin: MachineKinematics,
    reader: FrameDecoder,
    tx: crate::wire::ring::ByteRing<TX_CAPACITY>,
    /// Scratch for outgoing frames: a body and its encoding (fields, so that no call
    /// clears them).
    tx_body: [u8; MAX_BODY],
    tx_frame: [u8; MAX_FRAME],
    tx_seq: u16,
    session: bool,
    expected_seq: u16,
    last_control: Option<u16>,
    machine_id: u32,
    mismatch: bool,
    /// The session's host (`Hello::host`).
    host: u32,
    /// An earlier session's job, queued or held, not yet resumed or aborted by this
    /// one.
    orphan: Option<HeldJob>,
    /// Blocks were accepted and the host has not said the job is complete
    /// (`Control::EndJob`).
    job_open: bool,
    /// The running job is a streamed program (`Control::BeginJob`): host silence
    /// starves it and, after this many [`PATIENCE_UNIT_TICKS`], holds it; 0: the
    /// short link-loss watch. (16 bits: it fits the controller's padding, and the
    /// firmware's static RAM has no room for more.)
    patience: u16,
    /// The streamed program's identity and how far it was received
    /// (`Control::BeginJob`), kept with its job for a new host (`HelloAck::mark`).
    mark: JobMark,
    assembler: crate::wire::store::Assembler,
    store_pending: bool,
    planner: Planner,
    exec: Executor,
    joints: Joints,
    /// Joint positions of the home pose (where homing ends).
    home_joints: Joints,
    /// Steps or counts of each joint's actuator at joint position zero (homing).
    offset: [i64; MAX_JOINTS],
    steps: StepScheduler,
    trains: [StepTrain; MAX_JOINTS],
    homer: Homer,
    /// Joint of each servo channel.
    servo_joint: [u8; MAX_SERVOS],
    /// Largest setpoint change per period allowed by the guard, per joint, axis units.
    max_step: [u64; MAX_JOINTS],
    state: State,
    alarm: Option<Alarm>,
    /// Locked after a reset: neither homed nor unlocked.
    locked: bool,
    homed: bool,
    /// In `Alarm`/`EStop`, still decelerating on the path.
    stopping: bool,
    /// Servo joints must be resynchronised to their feedback on the next tick.
    resync: bool,
    /// No tick yet: the servo encoders' readings are adopted as the joints' positions.
    fresh: bool,
    abort_pending: bool,
    spindle: Aux,
    motion_ticks: u64,
    /// Ticks since the last periodic status (16 bits: with `patience`, the controller
    /// stays within the firmware's static RAM; it saturates without a session).
    since_status: u16,
    /// An `Ack` of the last block accepted is owed (acks are cumulative: one covers
    /// every block accepted and every slot freed since the last); encoded by
    /// `transmit`, not in the `receive` or `tick` that made it due.
    ack_due: bool,
    /// A status is owed (requested, or periodic); encoded by `transmit`.
    status_due: bool,
    /// The state of the last status encoded: at rest, a periodic status goes out only
    /// when the state is another.
    reported: State,
    silent_ticks: u32,
    link_watch: bool,
    last: Inputs,
    out: Outputs,
    /// The hexapod-xy's contour map, built a phase a tick (`update_contour_map`).
    map: MapBuilder,
    /// This tick completed a map.
    map_fresh: bool,
    stats: LinkStats,
    /// The probing move's latch and result ([`crate::drive::probe`]).
    probe: ProbeLatch,
    /// The steppers' steps at the next tick's start, while a probing move runs
    /// (`probing`).
    probe_ref: [i64; MAX_JOINTS],
    /// A probing move touched: it is stopping on the path, then its rest is dropped.
    probe_stop: bool,
    /// The probe's result is owed to the host ([`crate::wire::CtrlMsg::Probe`]).
    probe_due: bool,
    /// A `ControlAck` owed for a control carrying a planned move (encoded by
    /// `transmit`).
    control_ack_due: Option<u16>,
    /// The data recorder, its ring taken from the queue (`drive::recorder`).
    recorder: crate::drive::recorder::Recorder,
    /// Why the last arm request was refused.
    record_refused: Option<crate::drive::recorder::RecorderError>,
    /// Ticks since the recorder's last streamed piece.
    stream_wait: u8,
    /// A streamed piece is due: encoded by the next `transmit`.
    stream_due: bool,
    /// A test signal running on a servo joint (`drive::excite`).
    excite: Option<crate::drive::excite::Signal>,
}

/// What a controller for a machine needs besides the machine, computed and checked
/// before anything is written (small: no queue).
struct Prepared {
    board: BoardChannels,
    kin: MachineKinematics,
    joints: Joints,
    steps: StepScheduler,
    servo_joint: [u8; MAX_SERVOS],
    machine_id: u32,
    max_step: [u64; MAX_JOINTS],
}

impl Prepared {
    fn of(machine: &MachineConfig, board: BoardChannels) -> Result<Self, ConfigError> {
        machine.validate_on(board)?;
        let kin = MachineKinematics::new(machine);
        let mut joints = [0; MAX_JOINTS];
        kin.inverse_checked(&machine.home, &machine.joints, &mut joints)
            .map_err(|e| match e {
                Unreachable::JointLimit { joint } => ConfigError::HomeOutsideTravel { joint },
                _ => ConfigError::HomeOutsideTravel { joint: 0 },
            })?;
        let mut servo_joint = [NO_JOINT; MAX_SERVOS];
        for (j, jc) in machine.joints.iter().enumerate() {
            if let Drive::Servo { channel } = jc.drive {
                servo_joint[channel as usize] = j as u8;
            }
        }
        let mut max_step = [0; MAX_JOINTS];
        for (m, jc) in max_step.iter_mut().zip(&machine.joints) {
            let v = jc.limits.max_velocity.max(0) as u64;
            *m = (v * (100 + GUARD_MARGIN_PERCENT)).div_ceil(100 * crate::units::TICK_HZ as u64)
                + GUARD_SLACK_UNITS;
        }
        Ok(Self {
            board,
            kin,
            max_step,
            steps: StepScheduler::new(&machine.joints, &joints),
            joints,
            servo_joint,
            machine_id: crate::wire::store::identity(machine),
        })
    }
}

impl Controller {
    /// A controller for `machine`, standing at its home pose (on the host: the value is
    /// tens of kilobytes; the firmware builds it in place with [`Controller::init`]).
    pub fn new(machine: MachineConfig) -> Result<Self, ConfigError> {
        let mut slot = core::mem::MaybeUninit::<Self>::uninit();
        Self::init(&mut slot, machine)?;
        // SAFETY: `init` succeeded, so it wrote every field.
        Ok(unsafe { slot.assume_init() })
    }

    /// Builds a controller for `machine` in `slot`, field by field, so that no
    /// temporary of the whole controller (or of its queue) is made on the stack: the
    /// MCU's stack could not hold one. Fails, leaving `slot` untouched, when the
    /// machine is invalid. The board is [`BoardChannels::ALL`].
    pub fn init(
        slot: &mut core::mem::MaybeUninit<Self>,
        machine: MachineConfig,
    ) -> Result<&mut Self, ConfigError> {
        Self::init_on(slot, machine, BoardChannels::ALL)
    }

    /// [`init`](Self::init) for a board that wires only `board`'s channels: this
    /// machine, and every machine loaded later, must use no other
    /// ([`MachineConfig::validate_on`]).
    pub fn init_on(
        slot: &mut core::mem::MaybeUninit<Self>,
        machine: MachineConfig,
        board: BoardChannels,
    ) -> Result<&mut Self, ConfigError> {
        let prepared = Prepared::of(&machine, board)?;
        // SAFETY: `write` writes every field; the slot is valid and aligned.
        unsafe {
            Self::write(slot.as_mut_ptr(), machine, &prepared);
            Ok(slot.assume_init_mut())
        }
    }

    /// Writes every field of a fresh controller into `p`.
    ///
    /// # Safety
    /// `p` valid for writes and aligned; its old contents are not dropped (nothing in
    /// a controller needs dropping).
    unsafe fn write(p: *mut Self, machine: MachineConfig, prep: &Prepared) {
        use core::ptr::addr_of_mut as at;
        let pose = machine.home;
        let window = crate::motion::interp::window_of(machine.motion.smoothing_ticks as u32);
        // SAFETY: the caller's promise; each write is to a field of `*p`.
        unsafe {
            at!((*p).map).write(MapBuilder::new(&machine));
            at!((*p).map_fresh).write(false);
            at!((*p).machine).write(machine);
            at!((*p).board).write(prep.board);
            at!((*p).kin).write(prep.kin);
            at!((*p).reader).write(FrameDecoder::new());
            at!((*p).tx).write(crate::wire::ring::ByteRing::default());
            at!((*p).tx_body).write([0; MAX_BODY]);
            at!((*p).tx_frame).write([0; MAX_FRAME]);
            at!((*p).tx_seq).write(0);
            at!((*p).session).write(false);
            at!((*p).expected_seq).write(0);
            at!((*p).last_control).write(None);
            at!((*p).machine_id).write(prep.machine_id);
            at!((*p).mismatch).write(false);
            at!((*p).host).write(0);
            at!((*p).orphan).write(None);
            at!((*p).job_open).write(false);
            at!((*p).patience).write(0);
            at!((*p).mark).write(JobMark::default());
            at!((*p).assembler).write(crate::wire::store::Assembler::new());
            at!((*p).store_pending).write(false);
            Planner::init_at(at!((*p).planner), pose);
            Executor::init_at(at!((*p).exec), pose);
            (*p).exec.set_smoothing(window);
            at!((*p).joints).write(prep.joints);
            at!((*p).home_joints).write(prep.joints);
            at!((*p).offset).write([0; MAX_JOINTS]);
            at!((*p).steps).write(prep.steps.clone());
            at!((*p).trains).write([StepTrain::default(); MAX_JOINTS]);
            at!((*p).homer).write(Homer::default());
            at!((*p).servo_joint).write(prep.servo_joint);
            at!((*p).max_step).write(prep.max_step);
            at!((*p).state).write(State::Alarm);
            at!((*p).alarm).write(Some(UNHOMED));
            at!((*p).locked).write(true);
            at!((*p).homed).write(false);
            at!((*p).stopping).write(false);
            at!((*p).resync).write(false);
            at!((*p).fresh).write(true);
            at!((*p).abort_pending).write(false);
            at!((*p).spindle).write(Aux::SpindleOff);
            at!((*p).motion_ticks).write(0);
            at!((*p).since_status).write(0);
            at!((*p).ack_due).write(false);
            at!((*p).status_due).write(false);
            at!((*p).reported).write(State::Alarm);
            at!((*p).silent_ticks).write(0);
            at!((*p).link_watch).write(true);
            at!((*p).last).write(Inputs::default());
            at!((*p).out).write(Outputs::default());
            at!((*p).stats).write(LinkStats::default());
            at!((*p).probe).write(ProbeLatch::new());
            at!((*p).probe_ref).write([0; MAX_JOINTS]);
            at!((*p).probe_stop).write(false);
            at!((*p).probe_due).write(false);
            at!((*p).control_ack_due).write(None);
            crate::drive::recorder::Recorder::init_at(at!((*p).recorder));
            at!((*p).record_refused).write(None);
            at!((*p).stream_wait).write(0);
            at!((*p).stream_due).write(false);
            at!((*p).excite).write(None);
            (*p).update_servo_targets();
        }
    }

    /// Has the controller not yet ticked (read its inputs) since it started or since a
    /// machine was loaded?
    pub fn fresh(&self) -> bool {
        self.fresh
    }

    /// Has every joint with a home switch been homed since the reset?
    pub fn homed(&self) -> bool {
        self.homed
    }

    /// Actuator position (steps or counts) at joint position zero, per joint.
    pub fn joint_offsets(&self) -> &[i64; MAX_JOINTS] {
        &self.offset
    }

    /// The machine configuration in force.
    pub fn machine(&self) -> &MachineConfig {
        &self.machine
    }
    /// Current state.
    pub fn state(&self) -> State {
        self.state
    }
    /// Commanded pose, axis units.
    pub fn pose(&self) -> &[i64; crate::config::AXES] {
        &self.exec.pose
    }
    /// Commanded joint positions, axis units.
    pub fn joints(&self) -> &Joints {
        &self.joints
    }
    /// Steps emitted so far by stepper joint `j`.
    pub fn steps_emitted(&self, j: usize) -> i64 {
        self.steps.steps(j)
    }
    /// NC line of the executing or last executed block.
    pub fn line(&self) -> u32 {
        self.exec.line
    }
    /// The NC lines of the blocks started since the last call, in order (feature
    /// `line-log`, host builds: the simulator's exact record of executed lines).
    #[cfg(feature = "line-log")]
    pub fn take_line_log(&mut self) -> heapless::Vec<u32, 64> {
        core::mem::take(&mut self.exec.line_log)
    }
    /// The last probing move's result ([`crate::drive::probe`]).
    pub fn probe_result(&self) -> Option<crate::drive::probe::ProbeResult> {
        self.probe.result()
    }

    /// Spindle state last commanded.
    pub fn spindle(&self) -> Aux {
        self.spindle
    }
    /// Is motion executing or queued (time must advance for it)?
    pub fn has_work(&self) -> bool {
        if self.resync {
            return true;
        }
        match self.state {
            State::Alarm | State::EStop => self.stopping || self.resync,
            State::Homing => true,
            // An abort completes on the next tick once stopped: that tick is work; so
            // is the link-loss watch over a held job.
            State::Hold => !self.exec.stopped() || self.abort_pending || self.watching_hold(),
            State::Idle => self.path_moving() || self.watching_hold(),
            // The host-timeout watch of a starved job (or blocks just queued).
            State::Starved => self.path_moving() || self.watching_starved(),
            _ => self.path_moving(),
        }
    }

    /// A job is queued, executing or held (a pause or hold at rest counts).
    pub(super) fn job_held(&self) -> bool {
        !self.planner.is_empty()
            || self.exec.busy()
            || matches!(self.state, State::Hold | State::Starved)
    }

    /// The host-timeout watch of a starved job is running.
    fn watching_starved(&self) -> bool {
        self.session && self.link_watch && self.silent_ticks < self.patience_ticks()
    }

    /// The host timeout of the streamed job, ticks (0: none).
    pub(super) fn patience_ticks(&self) -> u32 {
        self.patience as u32 * PATIENCE_UNIT_TICKS
    }

    /// Where a job with nothing left to execute rests: `Starved` while its host may
    /// still send blocks of a streamed program, else `Idle`.
    pub(super) fn rest_state(&self) -> State {
        if self.job_open && self.patience > 0 {
            State::Starved
        } else {
            State::Idle
        }
    }

    /// The link-loss watch of a held or unfinished job is running (time must advance
    /// for it).
    fn watching_hold(&self) -> bool {
        self.session
            && self.link_watch
            && self.alarm.is_none()
            && self.silent_ticks < LINK_LOSS_TICKS
            && (self.job_held() || self.job_open)
    }

    /// Is anything moving, or about to (running, homing, decelerating)? Periodic
    /// statuses are sent only then: at rest (idle, starved, held, an alarm) the next
    /// periodic one only if the state is not the one last reported, and any on
    /// request, so that a controller whose clock runs ahead of its host (the
    /// simulator) does not flood the link with identical statuses.
    fn moving(&self) -> bool {
        matches!(self.state, State::Running | State::Homing) || !self.exec.stopped()
    }

    /// A block executing or queued, or smoothing still catching up.
    pub(super) fn path_moving(&self) -> bool {
        self.exec.busy() || !self.planner.is_empty() || !self.exec.settled()
    }

    /// Jerk limitation: smooths the path motion over `window` ticks (1 = off); see
    /// [`crate::motion::interp`].
    pub fn set_smoothing(&mut self, window: u32) {
        self.exec.set_smoothing(window);
    }

    /// One tick of path motion (also the stop after a fault).
    fn motion_tick(&mut self) {
        if self.path_moving() {
            self.motion_ticks += 1;
            if matches!(self.state, State::Idle | State::Starved) {
                self.state = State::Running;
            }
        }
        let was_stopped = self.exec.stopped();
        self.exec.retarget(&mut self.planner);
        match self.exec.tick(&mut self.planner) {
            Some(Event::Unreachable { line, why }) => self.raise(alarm_of(why, line)),
            Some(Event::Aux { aux, .. }) => match aux {
                Aux::Pause(_) | Aux::ToolChange(_) if !self.stopping => self.state = State::Hold,
                Aux::SpindleOff | Aux::SpindleCw(_) | Aux::SpindleCcw(_) => self.spindle = aux,
                _ => {}
            },
            None => {}
        }
        if was_stopped && !self.exec.stopped() {
            // Motion starts: the contour map's phases start with it, so that its maps
            // are taken at the same poses whatever the ticks before (a job's first
            // block comes when the link brings it).
            self.map.restart();
        }
        let mut joints = self.joints;
        match self
            .kin
            .inverse_checked(&self.exec.pose, &self.machine.joints, &mut joints)
        {
            Ok(()) => match self.overspeed(&joints) {
                None => self.joints = joints,
                Some(j) => self.guard_trip(j),
            },
            Err(why) => self.raise(alarm_of(why, self.exec.line)),
        }
        if self.stopping && self.exec.stopped() {
            self.exec.stop();
            self.planner.clear(self.exec.pose);
            self.planner.hold = false;
            self.exec.paused = false;
            self.stopping = false;
        }
        if self.state == State::Hold && self.abort_pending && self.exec.stopped() {
            self.exec.stop();
            self.planner.clear(self.exec.pose);
            self.planner.hold = false;
            self.abort_pending = false;
            self.exec.paused = false;
            self.state = State::Idle;
        }
        if self.state == State::Running && !self.path_moving() {
            self.state = self.rest_state();
            if self.state == State::Idle {
                // The streamed job is over: the next one says again what it is.
                self.patience = 0;
            }
        }
    }

    /// The channels' map to the pose that this tick completed (the hexapod-xy with
    /// contour control, every [`crate::kinematics::hexapod_xy_map::MAP_PHASES`]
    /// ticks): for [`crate::drive::contour::ServoBank::load_map`], with this tick's outputs.
    /// Valid until the next tick.
    pub fn contour_map(&self) -> Option<&ContourMap> {
        self.map_fresh.then(|| self.map.map())
    }

    /// Advances one interpolation period.
    pub fn tick(&mut self, inputs: &Inputs) -> &Outputs {
        self.out.servo_reset = false;
        if self.fresh {
            // Power-up: an encoder counter reads whatever it reads; the joint is where
            // the controller believes (home pose) until homed.
            self.fresh = false;
            for (j, jc) in self.machine.joints.iter().enumerate() {
                if let Drive::Servo { channel } = jc.drive {
                    self.offset[j] = inputs.encoder_counts[channel as usize]
                        - self.steps.scale(j).steps_at(self.joints[j]);
                }
            }
            self.out.servo_reset = true;
        }
        self.check_inputs(inputs);
        if self.resync {
            self.resync_servos(inputs);
        }
        if self.probe.armed() {
            self.probe_tick();
        }
        let queued = self.planner.len();
        match self.state {
            State::Homing => self.home_tick(inputs),
            State::Alarm | State::EStop if !self.stopping => {}
            _ => self.motion_tick(),
        }
        if self.probe.armed() || self.probe_stop {
            self.probe_after();
        }
        if self.session && self.planner.len() < queued && self.state != State::Alarm {
            // Credits as slots free: the host refills within a tick or two instead of
            // waiting for the next status.
            self.ack_due = true;
        }
        self.update_outputs();
        self.excite_tick();
        self.record_tick();
        self.since_status = self.since_status.saturating_add(1);
        if self.session && self.since_status as u32 >= STATUS_EVERY_TICKS {
            self.since_status = 0;
            if self.moving() || self.state != self.reported {
                self.status_due = true;
            }
        }
        &self.out
    }
}

#[cfg(test)]
mod drive_tests;
#[cfg(test)]
mod probe_tests;
#[cfg(test)]
mod starve_tests;
#[cfg(test)]
mod tests;
