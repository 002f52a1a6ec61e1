//! The controller state machine: bytes in, bytes out, one interpolation tick at a time.
//!
//! [`Controller::receive`] takes bytes from the link, [`Controller::transmit`] hands
//! back bytes for it, and [`Controller::tick`] advances motion by one period T
//! ([`crate::units::TICK_NS`]) given the inputs read from the hardware, returning the
//! outputs to apply (step trains per stepper channel, targets per servo channel for
//! the 10 kHz loops of [`crate::contour::ServoBank`]). The firmware calls `tick` from
//! its timer interrupt; the simulator calls it with simulated time; both run exactly
//! this code.
//!
//! States: after a reset (or a new machine) the controller is locked in `Alarm`
//! (cause `Unhomed`): it moves once homed (`Home`, state `Homing`, [`crate::homing`])
//! or unlocked (`AlarmReset`). `Idle` (nothing to do) ⇄ `Running` (executing) ⇄ `Hold`
//! (feed hold, pause or tool change: decelerating on the path or stopped on it,
//! resumed by `Resume`). Faults:
//!
//! | fault | raised when | alarm names |
//! |---|---|---|
//! | e-stop input | active (level) | state `EStop`, cause `EStop` |
//! | limit switch | a joint's switch becomes active (not while that joint homes) | `LimitSwitch`, joint |
//! | drive fault | a stepper drive's fault input, or a servo amplifier's, while the drives are powered | `DriveFault`, joint |
//! | following error | a servo loop trips ([`crate::servo`]) | `FollowingError`, joint |
//! | link loss | no valid frame for [`LINK_LOSS_TICKS`] while moving | `LinkLoss` |
//! | joint travel | a block would take a joint outside its travel | `JointLimit`, joint |
//!
//! Every alarm carries the NC line executing. On a fault the motion stops on the path
//! at the planned deceleration (as a feed hold does, so the stop distance is at most
//! v²/2a plus one period and the position is kept: no step is lost, the pose is where
//! the drives are), then the queue is dropped; nothing moves until `AlarmReset`, which
//! is refused while an e-stop or a drive fault is still active. The drives stay
//! enabled in `Alarm` (holding position) and are disabled in `EStop` once stopped; a
//! tripped servo loop disables its own amplifier. Blocks are planned as they are
//! queued ([`crate::planner`]); control commands bypass the queue.

mod actuators;
mod safety;

use crate::config::{ConfigError, Drive, FastScale, MachineConfig, MAX_JOINTS, MAX_SERVOS};
use crate::homing::Homer;
use crate::interp::{Event, Executor};
use crate::kinematics::{Joints, MachineKinematics, Unreachable};
use crate::planner::{Planner, PushError};
use crate::protocol::{
    decode_block, encode_ack, encode_frame_with, encode_status, Alarm, AlarmCause, Aux, Control,
    CtrlMsg, FrameDecoder, HostMsgOf, NakReason, NotBlock, PlannedBlock, State, Status, MAX_BODY,
    MAX_FRAME, NO_JOINT, PROTOCOL_VERSION,
};
use crate::stepper::{StepScheduler, StepTrain};
use crate::units::TICK_HZ;
pub use actuators::{Inputs, Outputs};
use safety::{alarm_of, UNHOMED};

pub use crate::planner::QUEUE_CAPACITY;
/// Bytes of outgoing frames buffered between two `transmit` calls.
pub const TX_CAPACITY: usize = 2048;
/// Ticks between two unsolicited status messages (50 ms at 1 kHz). Freed queue slots
/// are reported at once, by an `Ack` of the last block accepted, from the tick that
/// frees them.
pub const STATUS_EVERY_TICKS: u32 = 50;
/// Ticks without a valid frame from the host, while moving, after which the link is
/// lost (1 s at 1 kHz; the host asks for a status at least every 100 ms).
pub const LINK_LOSS_TICKS: u32 = 1000;

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
    kin: MachineKinematics,
    reader: FrameDecoder,
    tx: crate::ring::ByteRing<TX_CAPACITY>,
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
    assembler: crate::store::Assembler,
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
    /// Each joint's scale, with its reciprocal (no division per tick).
    fast: [FastScale; MAX_JOINTS],
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
    since_status: u32,
    /// An `Ack` of the last block accepted is owed (acks are cumulative: one covers
    /// every block accepted and every slot freed since the last); encoded by
    /// `transmit`, not in the `receive` or `tick` that made it due.
    ack_due: bool,
    /// A status is owed (requested, or periodic); encoded by `transmit`.
    status_due: bool,
    silent_ticks: u32,
    link_watch: bool,
    last: Inputs,
    out: Outputs,
    stats: LinkStats,
}

/// What a controller for a machine needs besides the machine, computed and checked
/// before anything is written (small: no queue).
struct Prepared {
    kin: MachineKinematics,
    joints: Joints,
    steps: StepScheduler,
    servo_joint: [u8; MAX_SERVOS],
    fast: [FastScale; MAX_JOINTS],
    machine_id: u32,
}

impl Prepared {
    fn of(machine: &MachineConfig) -> Result<Self, ConfigError> {
        machine.validate()?;
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
        let mut fast = [crate::config::Scale::new(1, 1).fast(); MAX_JOINTS];
        for (f, jc) in fast.iter_mut().zip(&machine.joints) {
            *f = jc.scale.fast();
        }
        Ok(Self {
            kin,
            steps: StepScheduler::new(&machine.joints, &joints),
            joints,
            servo_joint,
            fast,
            machine_id: crate::store::identity(machine),
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
    /// machine is invalid.
    pub fn init(
        slot: &mut core::mem::MaybeUninit<Self>,
        machine: MachineConfig,
    ) -> Result<&mut Self, ConfigError> {
        let prepared = Prepared::of(&machine)?;
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
        let window = crate::interp::window_of(machine.motion.smoothing_ticks as u32);
        // SAFETY: the caller's promise; each write is to a field of `*p`.
        unsafe {
            at!((*p).machine).write(machine);
            at!((*p).kin).write(prep.kin);
            at!((*p).reader).write(FrameDecoder::new());
            at!((*p).tx).write(crate::ring::ByteRing::default());
            at!((*p).tx_body).write([0; MAX_BODY]);
            at!((*p).tx_frame).write([0; MAX_FRAME]);
            at!((*p).tx_seq).write(0);
            at!((*p).session).write(false);
            at!((*p).expected_seq).write(0);
            at!((*p).last_control).write(None);
            at!((*p).machine_id).write(prep.machine_id);
            at!((*p).mismatch).write(false);
            at!((*p).assembler).write(crate::store::Assembler::new());
            at!((*p).store_pending).write(false);
            Planner::init_at(at!((*p).planner), pose);
            (*p).planner.smoothing = window;
            Executor::init_at(at!((*p).exec), pose);
            (*p).exec.set_smoothing(window);
            at!((*p).joints).write(prep.joints);
            at!((*p).home_joints).write(prep.joints);
            at!((*p).offset).write([0; MAX_JOINTS]);
            at!((*p).steps).write(prep.steps.clone());
            at!((*p).trains).write([StepTrain::default(); MAX_JOINTS]);
            at!((*p).homer).write(Homer::default());
            at!((*p).servo_joint).write(prep.servo_joint);
            at!((*p).fast).write(prep.fast);
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
            at!((*p).silent_ticks).write(0);
            at!((*p).link_watch).write(true);
            at!((*p).last).write(Inputs::default());
            at!((*p).out).write(Outputs::default());
            at!((*p).stats).write(LinkStats::default());
            (*p).update_servo_targets();
        }
    }

    /// Ticks since the last valid frame from the host.
    pub fn link_silence_ticks(&self) -> u32 {
        self.silent_ticks
    }

    /// Turns the link-loss watch off (or on): only for a controller fed in the same
    /// process as its host, where there is no link to lose (`nc-send --check`).
    pub fn set_link_watch(&mut self, on: bool) {
        self.link_watch = on;
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
    /// Spindle state last commanded.
    pub fn spindle(&self) -> Aux {
        self.spindle
    }
    /// Link counters.
    pub fn link_stats(&self) -> LinkStats {
        self.stats
    }
    /// Is motion executing or queued (time must advance for it)?
    pub fn has_work(&self) -> bool {
        if self.resync {
            return true;
        }
        match self.state {
            State::Alarm | State::EStop => self.stopping || self.resync,
            State::Homing => true,
            // An abort completes on the next tick once stopped: that tick is work.
            State::Hold => !self.exec.stopped() || self.abort_pending,
            _ => self.path_moving(),
        }
    }

    /// A block executing or queued, or smoothing still catching up.
    fn path_moving(&self) -> bool {
        self.exec.busy() || !self.planner.is_empty() || !self.exec.settled()
    }

    /// Jerk limitation: smooths the path motion over `window` ticks (1 = off); see
    /// [`crate::interp`].
    pub fn set_smoothing(&mut self, window: u32) {
        self.exec.set_smoothing(window);
        self.planner.smoothing = crate::interp::window_of(window);
    }

    /// Feeds bytes received from the link.
    pub fn receive(&mut self, bytes: &[u8]) {
        let mut rest = bytes;
        while !rest.is_empty() {
            let (taken, frame) = self.reader.feed(rest);
            rest = &rest[taken..];
            let Some(frame) = frame else {
                continue;
            };
            let Ok((seq, message)) = frame else {
                self.corrupt();
                continue;
            };
            // Messages are handled by reference: a block is some 250 bytes, not to be
            // moved around; blocks, the bulk of the traffic, are decoded by hand.
            match &decode_block(message) {
                Some(Ok(planned)) => {
                    self.silent_ticks = 0;
                    self.block(seq, planned);
                }
                Some(Err(_)) => self.corrupt(),
                None => match &postcard::from_bytes::<HostMsgOf<NotBlock>>(message) {
                    Ok(msg) => {
                        self.silent_ticks = 0;
                        self.handle(seq, msg);
                    }
                    Err(_) => self.corrupt(),
                },
            }
        }
    }

    #[cold]
    fn corrupt(&mut self) {
        self.stats.corrupt += 1;
        self.nak(NakReason::Corrupt);
    }

    /// Moves pending outgoing bytes into `out`; returns how many. The `Ack` and the
    /// status owed are encoded first (one of each, however many blocks were accepted,
    /// slots freed or statuses asked for since the last call).
    pub fn transmit(&mut self, out: &mut [u8]) -> usize {
        self.send_due();
        self.tx.pop_into(out)
    }

    /// Adds a frame to the transmit buffer, made by `encode` from the next sequence
    /// number (into the buffer itself when the largest frame fits there in one piece,
    /// else into scratch, then copied); false when it does not fit (nothing added).
    fn push_frame(
        &mut self,
        encode: impl FnOnce(u16, &mut [u8; MAX_BODY], &mut [u8; MAX_FRAME]) -> Option<usize>,
    ) -> bool {
        let seq = self.tx_seq;
        let added = match self.tx.tail_mut::<MAX_FRAME>() {
            Some(room) => encode(seq, &mut self.tx_body, room).map(|n| self.tx.commit(n)),
            None => encode(seq, &mut self.tx_body, &mut self.tx_frame)
                .filter(|&n| self.tx.push_slice(&self.tx_frame[..n]))
                .map(drop),
        };
        if added.is_some() {
            self.tx_seq = seq.wrapping_add(1);
        }
        added.is_some()
    }

    fn send(&mut self, msg: &CtrlMsg) {
        if !self.push_frame(|seq, body, out| encode_frame_with(seq, msg, body, out).ok()) {
            self.stats.tx_dropped += 1;
        }
    }

    /// Encodes the `Ack` and the status owed; what does not fit stays owed.
    fn send_due(&mut self) {
        if self.ack_due {
            let acked = self.expected_seq.wrapping_sub(1);
            let (free, ms) = (self.planner.free() as u16, self.buffered_ms());
            self.ack_due = !self
                .push_frame(|seq, body, out| Some(encode_ack(seq, acked, free, ms, body, out)));
        }
        if self.status_due {
            let s = self.status();
            self.status_due =
                !self.push_frame(|seq, body, out| Some(encode_status(seq, &s, body, out)));
        }
    }

    fn nak(&mut self, reason: NakReason) {
        self.send(&CtrlMsg::Nak {
            expected: self.expected_seq,
            reason,
        });
    }

    fn buffered_ms(&self) -> u32 {
        let ticks = self.planner.buffered_ticks() + self.exec.remaining_ticks();
        (ticks * 1000.0 / TICK_HZ as f32).min(u32::MAX as f32) as u32
    }

    /// A message other than a block (rare: not inlined into `receive`, whose block
    /// path it would slow down).
    #[inline(never)]
    fn handle(&mut self, seq: u16, msg: &HostMsgOf<NotBlock>) {
        match *msg {
            HostMsgOf::Hello { version, machine } => {
                // What the old session is owed goes first, as it was owed.
                self.send_due();
                if version != PROTOCOL_VERSION {
                    self.nak(NakReason::Version);
                    return;
                }
                self.session = true;
                self.expected_seq = seq.wrapping_add(1);
                self.last_control = None;
                self.exec.completed = 0;
                self.motion_ticks = 0;
                self.mismatch = machine != self.machine_id;
                if self.mismatch {
                    self.raise(Alarm {
                        cause: AlarmCause::MachineMismatch,
                        joint: NO_JOINT,
                        line: 0,
                    });
                }
                self.send(&CtrlMsg::HelloAck {
                    version: PROTOCOL_VERSION,
                    queue_capacity: QUEUE_CAPACITY as u16,
                    machine: self.machine_id,
                });
            }
            HostMsgOf::Machine {
                id,
                offset,
                total,
                crc,
                ref data,
            } => {
                let fresh = self.last_control != Some(id);
                self.last_control = Some(id);
                self.send(&CtrlMsg::ControlAck { id });
                if !fresh {
                    return;
                }
                if self.has_work() {
                    self.send(&CtrlMsg::MachineRefused {
                        error: crate::store::StoreError::Busy,
                    });
                    return;
                }
                match self
                    .assembler
                    .add(offset as usize, total as usize, crc, data)
                {
                    Ok(None) => {}
                    Ok(Some(config)) => {
                        // What is owed goes out before the controller restarts.
                        self.send_due();
                        self.load_machine(config)
                    }
                    Err(error) => self.send(&CtrlMsg::MachineRefused { error }),
                }
            }
            HostMsgOf::StatusRequest => self.status_due = true,
            HostMsgOf::Control { id, cmd } => {
                if self.last_control != Some(id) {
                    self.last_control = Some(id);
                    self.control(cmd);
                }
                self.send(&CtrlMsg::ControlAck { id });
            }
            HostMsgOf::Block(never) => match never {},
        }
    }

    /// A block message (sequenced).
    fn block(&mut self, seq: u16, planned: &PlannedBlock) {
        if !self.session {
            self.nak(NakReason::NoSession);
            return;
        }
        let ahead = seq.wrapping_sub(self.expected_seq) as i16;
        if ahead < 0 {
            // A duplicate of an accepted frame: acknowledge, do not execute.
            self.ack_due = true;
            return;
        }
        if ahead > 0 {
            self.nak(NakReason::Gap);
            return;
        }
        if self.mismatch {
            self.nak(NakReason::MachineMismatch);
            return;
        }
        if matches!(self.state, State::Alarm | State::EStop) {
            // Accepted and dropped: the job is over until the alarm is reset.
            self.expected_seq = seq.wrapping_add(1);
            self.ack_due = true;
            return;
        }
        match self.planner.push_planned(planned, &self.machine, &self.kin) {
            Ok(()) => {
                self.expected_seq = seq.wrapping_add(1);
                self.ack_due = true;
            }
            Err(PushError::Full) => self.nak(NakReason::QueueFull),
            Err(PushError::Geometry(_)) => self.nak(NakReason::BadBlock),
        }
    }

    /// Adopts `config`: the controller restarts at its home pose, keeping the session.
    /// Rebuilt in place (no second controller on the stack).
    fn load_machine(&mut self, config: MachineConfig) {
        let prepared = match Prepared::of(&config) {
            Ok(p) => p,
            Err(e) => {
                self.send(&CtrlMsg::MachineRefused {
                    error: crate::store::StoreError::Invalid(e),
                });
                return;
            }
        };
        let (tx_seq, expected_seq, last_control, stats) = (
            self.tx_seq,
            self.expected_seq,
            self.last_control,
            self.stats,
        );
        let mut tx = crate::ring::ByteRing::default();
        core::mem::swap(&mut tx, &mut self.tx);
        // SAFETY: `self` is a valid, aligned controller; `write` overwrites every field
        // and nothing in it needs dropping.
        unsafe { Self::write(self, config, &prepared) };
        core::mem::swap(&mut tx, &mut self.tx);
        (
            self.tx_seq,
            self.expected_seq,
            self.last_control,
            self.stats,
        ) = (tx_seq, expected_seq, last_control, stats);
        self.session = true;
        self.store_pending = true;
        self.send(&CtrlMsg::MachineLoaded {
            machine: self.machine_id,
        });
    }

    /// Identity of the machine configuration in force.
    pub fn machine_id(&self) -> u32 {
        self.machine_id
    }

    /// A configuration adopted from the host that the firmware should now write to
    /// flash; returned once.
    pub fn take_store_request(&mut self) -> Option<&MachineConfig> {
        if core::mem::replace(&mut self.store_pending, false) {
            Some(&self.machine)
        } else {
            None
        }
    }

    fn control(&mut self, cmd: Control) {
        if self.mismatch && !matches!(cmd, Control::Stop | Control::Abort) {
            return;
        }
        match cmd {
            Control::Hold => {
                if matches!(self.state, State::Running | State::Idle) {
                    self.planner.hold = true;
                    self.exec.replan(&mut self.planner);
                    self.state = State::Hold;
                }
            }
            Control::Resume => {
                if self.state == State::Hold && !self.abort_pending {
                    self.planner.hold = false;
                    self.exec.paused = false;
                    self.exec.replan(&mut self.planner);
                    // A pause or hold with nothing after it (M0 then M2): idle at once.
                    // Running with nothing to run would wait for a tick to turn idle,
                    // and a tick comes only while there is work (`has_work`).
                    self.state = if self.path_moving() {
                        State::Running
                    } else {
                        State::Idle
                    };
                }
            }
            Control::Abort => {
                if matches!(self.state, State::Running | State::Hold | State::Idle) {
                    self.planner.hold = true;
                    self.abort_pending = true;
                    self.exec.replan(&mut self.planner);
                    self.state = State::Hold;
                } else if self.state == State::Homing {
                    self.homer.cancel();
                    self.locked = true;
                    self.state = State::Alarm;
                    self.alarm = Some(UNHOMED);
                }
            }
            Control::AlarmReset => self.reset_alarm(),
            Control::FeedOverride(p) => {
                self.planner.feed_override = p.clamp(1, 200);
                self.exec.replan(&mut self.planner);
            }
            Control::Jog(planned) => {
                if self.state == State::Idle && !self.has_work() {
                    // Refused (it does not start here, or is malformed): nothing moves,
                    // and the host, which waits for the target, says so.
                    let _ = self
                        .planner
                        .push_planned(&planned, &self.machine, &self.kin);
                }
            }
            Control::Stop => {
                if self.state == State::Homing {
                    self.homer.cancel();
                    self.locked = true;
                }
                self.raise(Alarm {
                    cause: AlarmCause::Aborted,
                    joint: NO_JOINT,
                    line: self.exec.line,
                })
            }
            Control::Home => self.home(),
        }
    }

    /// A status snapshot.
    pub fn status(&self) -> Status {
        Status {
            state: self.state,
            line: self.exec.line,
            blocks_done: self.exec.completed,
            motion_ticks: self.motion_ticks,
            pose: self.exec.pose,
            joints: self.joints,
            speed: ((self.exec.speed as i128 * TICK_HZ as i128) >> 32) as i64,
            buffered_ms: self.buffered_ms(),
            free_slots: self.planner.free() as u16,
            feed_override: self.planner.feed_override,
            alarm: self.alarm,
            homed: self.homed,
        }
    }

    /// One tick of path motion (also the stop after a fault).
    fn motion_tick(&mut self) {
        if self.path_moving() {
            self.motion_ticks += 1;
            if self.state == State::Idle {
                self.state = State::Running;
            }
        }
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
        let mut joints = self.joints;
        match self
            .kin
            .inverse_checked(&self.exec.pose, &self.machine.joints, &mut joints)
        {
            Ok(()) => self.joints = joints,
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
            self.state = State::Idle;
        }
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
                        - self.fast[j].steps_at(self.joints[j]);
                }
            }
            self.out.servo_reset = true;
        }
        self.check_inputs(inputs);
        if self.resync {
            self.resync_servos(inputs);
        }
        let queued = self.planner.len();
        match self.state {
            State::Homing => self.home_tick(inputs),
            State::Alarm | State::EStop if !self.stopping => {}
            _ => self.motion_tick(),
        }
        if self.session && self.planner.len() < queued && self.state != State::Alarm {
            // Credits as slots free: the host refills within a tick or two instead of
            // waiting for the next status.
            self.ack_due = true;
        }
        self.update_outputs();
        self.since_status += 1;
        if self.session && self.since_status >= STATUS_EVERY_TICKS {
            self.since_status = 0;
            self.status_due = true;
        }
        &self.out
    }
}

#[cfg(test)]
mod tests;
