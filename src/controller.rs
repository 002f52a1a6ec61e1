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

use crate::config::{
    ConfigError, Drive, FastScale, MachineConfig, MAX_JOINTS, MAX_SERVOS, MAX_STEPPERS,
};
use crate::homing::{HomeEvent, HomeInputs, Homer};
use crate::interp::{Event, Executor};
use crate::kinematics::{Joints, Kinematics, MachineKinematics, Unreachable};
use crate::planner::{Planner, PushError};
use crate::protocol::{
    decode_block, encode_ack, encode_frame_with, encode_status, Alarm, AlarmCause, Aux, Block,
    Control, CtrlMsg, FrameDecoder, HostMsgOf, Motion, NakReason, NotBlock, PlannedBlock, State,
    Status, MAX_BODY, MAX_FRAME, NO_JOINT, PROTOCOL_VERSION,
};
use crate::servo::{Trip, SETPOINT_FRAC_BITS};
use crate::stepper::{StepScheduler, StepTrain};
use crate::units::TICK_HZ;

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

/// What the hardware reports each tick.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Inputs {
    /// Encoder position of each servo channel, counts (extended beyond 16 bits).
    pub encoder_counts: [i64; MAX_SERVOS],
    /// Encoder count latched by the hardware at an index pulse since the last tick.
    pub index: [Option<i64>; MAX_SERVOS],
    /// Emergency stop input active.
    pub estop: bool,
    /// Limit switch of each joint (bit j), active when tripped.
    pub limit: u16,
    /// Home switch of each joint (bit j), active.
    pub home: u16,
    /// Fault input of each joint's drive (bit j), active: stepper drives and servo
    /// amplifiers alike (the servo loops also see their amplifier's line).
    pub drive_fault: u16,
    /// Trip latched by each servo channel's loop ([`crate::contour::ServoBank`]).
    pub servo_trip: [Option<Trip>; MAX_SERVOS],
}

/// What the hardware must do this tick.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Outputs {
    /// Step train of each stepper channel; `forward` already includes DIR inversion.
    pub steps: [StepTrain; MAX_STEPPERS],
    /// Target of each servo channel at the end of this tick, counts × 2^16: load into
    /// [`crate::contour::ServoBank::load_tick`].
    pub servo_target: [i64; MAX_SERVOS],
    /// Stepper drives enabled.
    pub enable: bool,
    /// Servo amplifiers enabled (the loops' `enable`).
    pub servo_enable: bool,
    /// The servo loops must restart, clearing their trips, standing at their present
    /// feedback (which `servo_target` now equals): rebuild the bank from it.
    pub servo_reset: bool,
}

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

fn alarm_of(why: Unreachable, line: u32) -> Alarm {
    let (cause, joint) = match why {
        Unreachable::JointLimit { joint } => (AlarmCause::JointLimit, joint),
        Unreachable::Singular => (AlarmCause::Singularity, NO_JOINT),
        _ => (AlarmCause::Unreachable, NO_JOINT),
    };
    Alarm { cause, joint, line }
}

/// The lock after a reset: no joint, no NC line.
const UNHOMED: Alarm = Alarm {
    cause: AlarmCause::Unhomed,
    joint: NO_JOINT,
    line: 0,
};

/// Lowest set bit of `bits` among the first `n`.
fn first_bit(bits: u16, n: usize) -> Option<usize> {
    (0..n).find(|j| bits & (1 << j) != 0)
}

impl Controller {
    /// A controller for `machine`, standing at its home pose.
    pub fn new(machine: MachineConfig) -> Result<Self, ConfigError> {
        machine.validate()?;
        let kin = MachineKinematics::new(&machine);
        let pose = machine.home;
        let mut joints = [0; MAX_JOINTS];
        kin.inverse_checked(&pose, &machine.joints, &mut joints)
            .map_err(|e| match e {
                Unreachable::JointLimit { joint } => ConfigError::HomeOutsideTravel { joint },
                _ => ConfigError::HomeOutsideTravel { joint: 0 },
            })?;
        let steps = StepScheduler::new(&machine.joints, &joints);
        let mut exec = Executor::new(pose);
        exec.set_smoothing(machine.motion.smoothing_ticks as u32);
        let mut planner = Planner::new(pose);
        planner.smoothing = crate::interp::window_of(machine.motion.smoothing_ticks as u32);
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
        let machine_for_id = machine.clone();
        let mut c = Self {
            machine,
            kin,
            reader: FrameDecoder::new(),
            tx: crate::ring::ByteRing::default(),
            tx_body: [0; MAX_BODY],
            tx_frame: [0; MAX_FRAME],
            tx_seq: 0,
            session: false,
            expected_seq: 0,
            last_control: None,
            machine_id: crate::store::identity(&machine_for_id),
            mismatch: false,
            assembler: crate::store::Assembler::new(),
            store_pending: false,
            planner,
            exec,
            joints,
            home_joints: joints,
            offset: [0; MAX_JOINTS],
            steps,
            trains: [StepTrain::default(); MAX_JOINTS],
            homer: Homer::default(),
            servo_joint,
            fast,
            state: State::Alarm,
            alarm: Some(UNHOMED),
            locked: true,
            homed: false,
            stopping: false,
            resync: false,
            fresh: true,
            abort_pending: false,
            spindle: Aux::SpindleOff,
            motion_ticks: 0,
            since_status: 0,
            ack_due: false,
            status_due: false,
            silent_ticks: 0,
            link_watch: true,
            last: Inputs::default(),
            out: Outputs::default(),
            stats: LinkStats::default(),
        };
        c.update_servo_targets();
        Ok(c)
    }

    /// Unlocks a controller locked after a reset, at the position it believes it is at
    /// (what `AlarmReset` does to the `Unhomed` alarm).
    pub fn unlock(&mut self) {
        if self.alarm.map(|a| a.cause) == Some(AlarmCause::Unhomed) {
            self.locked = false;
            self.alarm = None;
            self.state = State::Idle;
        }
    }

    /// Raises an alarm found at start-up (the firmware: a watchdog reset); the
    /// controller stays locked.
    pub fn raise_at_start(&mut self, cause: AlarmCause) {
        self.alarm = Some(Alarm {
            cause,
            joint: NO_JOINT,
            line: 0,
        });
        self.state = State::Alarm;
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
    fn load_machine(&mut self, config: MachineConfig) {
        match Controller::new(config) {
            Err(e) => self.send(&CtrlMsg::MachineRefused {
                error: crate::store::StoreError::Invalid(e),
            }),
            Ok(fresh) => {
                let link = (
                    core::mem::take(&mut self.tx),
                    self.tx_seq,
                    self.expected_seq,
                    self.last_control,
                    self.stats,
                );
                *self = fresh;
                (
                    self.tx,
                    self.tx_seq,
                    self.expected_seq,
                    self.last_control,
                    self.stats,
                ) = link;
                self.session = true;
                self.store_pending = true;
                self.send(&CtrlMsg::MachineLoaded {
                    machine: self.machine_id,
                });
            }
        }
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
            Control::Jog {
                axis,
                distance,
                feed,
            } => {
                if self.state == State::Idle && !self.has_work() && (axis as usize) < 6 {
                    let target = self.jog_target(axis as usize, distance);
                    if target != self.exec.pose {
                        self.push_motion(Motion::Linear, target, feed.max(1));
                    }
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

    /// `AlarmReset`: refused while the cause is still there (e-stop or a drive fault
    /// active) or the motion is still stopping.
    fn reset_alarm(&mut self) {
        if !matches!(self.state, State::Alarm | State::EStop) || self.mismatch || self.stopping {
            return;
        }
        let n = self.machine.joints.len();
        if self.last.estop || first_bit(self.last.drive_fault, n).is_some() {
            return;
        }
        let servo_tripped = self.last.servo_trip.iter().any(Option::is_some);
        let cause = self.alarm.map(|a| a.cause);
        if cause == Some(AlarmCause::Unhomed) {
            self.unlock();
            return;
        }
        if servo_tripped || cause == Some(AlarmCause::FollowingError) {
            // The loops restart where the joints are: resynchronise on the next tick.
            self.resync = true;
        }
        if self.locked {
            self.alarm = Some(UNHOMED);
            self.state = State::Alarm;
        } else {
            self.alarm = None;
            self.state = State::Idle;
        }
    }

    /// `Home`: the homing cycle on a machine with home switches, else a rapid move to
    /// the home pose (only when unlocked).
    fn home(&mut self) {
        let switches = self.machine.joints.iter().any(|j| j.homing.enabled());
        let locked = self.alarm.map(|a| a.cause) == Some(AlarmCause::Unhomed);
        if switches && (locked || (self.state == State::Idle && !self.has_work())) {
            self.alarm = None;
            self.state = State::Homing;
            self.homed = false;
            self.homer.start(&self.machine.joints);
        } else if !switches && self.state == State::Idle && !self.has_work() {
            self.push_motion(Motion::Rapid, self.machine.home, 0);
        }
    }

    /// The pose a jog of `distance` along `axis` reaches, shortened so that every
    /// joint stays inside its travel (the soft limits).
    fn jog_target(&self, axis: usize, distance: i64) -> [i64; crate::config::AXES] {
        let from = self.exec.pose;
        let at = |d: i64| {
            let mut t = from;
            t[axis] = t[axis].saturating_add(d);
            t
        };
        let ok = |d: i64| {
            let mut q = [0; MAX_JOINTS];
            self.kin
                .inverse_checked(&at(d), &self.machine.joints, &mut q)
                .is_ok()
        };
        if ok(distance) {
            return at(distance);
        }
        // Largest reachable distance by bisection (to the unit).
        let (mut lo, mut hi) = (0i64, distance);
        while (hi - lo).abs() > 1 {
            let mid = lo + (hi - lo) / 2;
            if ok(mid) {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        at(lo)
    }

    fn push_motion(&mut self, motion: Motion, target: [i64; 6], feed: i64) {
        let b = Block {
            line: 0,
            motion,
            target,
            feed,
            tolerance_nm: 0,
        };
        let _ = self.planner.push(&b, &self.machine, &self.kin);
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

    /// An alarm that ends motion at once (the motion has already stopped, or must).
    fn raise(&mut self, alarm: Alarm) {
        self.alarm = Some(alarm);
        self.state = State::Alarm;
        self.exec.stop();
        self.planner.hold = false;
        self.abort_pending = false;
        self.stopping = false;
        self.planner.clear(self.exec.pose);
    }

    /// A fault: the first alarm is kept (an e-stop replaces any other), motion stops
    /// on the path at the planned deceleration, homing stops at once.
    fn fault(&mut self, alarm: Alarm, estop: bool) {
        match self.state {
            State::EStop => return,
            State::Alarm if !estop => return,
            _ => {}
        }
        let homing = self.state == State::Homing;
        self.state = if estop { State::EStop } else { State::Alarm };
        if self.alarm.is_none() || estop {
            self.alarm = Some(alarm);
        }
        self.abort_pending = false;
        if homing {
            self.homer.cancel();
            self.locked = true;
            self.homed = false;
            return;
        }
        if self.stopping {
            return;
        }
        if self.exec.stopped() {
            self.exec.stop();
            self.planner.hold = false;
            self.planner.clear(self.exec.pose);
        } else {
            self.planner.hold = true;
            self.exec.replan(&mut self.planner);
            self.stopping = true;
        }
    }

    /// Reads the safety inputs and raises what they say.
    fn check_inputs(&mut self, inputs: &Inputs) {
        let n = self.machine.joints.len();
        let line = self.exec.line;
        let at = |cause, joint: Option<usize>| Alarm {
            cause,
            joint: joint.map_or(NO_JOINT, |j| j as u8),
            line,
        };
        if inputs.estop {
            self.fault(at(AlarmCause::EStop, None), true);
        }
        // Many drives report a fault while disabled: a fault line counts only while the
        // drives are powered (after an e-stop they are not, and the reset must pass).
        let powered = self.out.enable || self.out.servo_enable;
        let drive_fault = if powered { inputs.drive_fault } else { 0 };
        if let Some(j) = first_bit(drive_fault, n) {
            self.fault(at(AlarmCause::DriveFault, Some(j)), false);
        }
        // A reset restarts the loops this tick: their trips until then are the ones
        // just cleared.
        let trips = if self.resync {
            [None; MAX_SERVOS]
        } else {
            inputs.servo_trip
        };
        for (c, trip) in trips.iter().enumerate() {
            let joint = self.servo_joint[c] as usize;
            match trip {
                Some(Trip::AmplifierFault) => {
                    self.fault(at(AlarmCause::DriveFault, Some(joint)), false)
                }
                Some(_) => self.fault(at(AlarmCause::FollowingError, Some(joint)), false),
                None => {}
            }
        }
        let mut rising = inputs.limit & !self.last.limit;
        if self.state == State::Homing {
            // Shared home/limit switches: a homing joint's limit is its home switch.
            for (j, jc) in self.machine.joints.iter().enumerate() {
                if jc.homing.enabled() {
                    rising &= !(1 << j);
                }
            }
        }
        if let Some(j) = first_bit(rising, n) {
            self.fault(at(AlarmCause::LimitSwitch, Some(j)), false);
        }
        if self.session {
            self.silent_ticks = self.silent_ticks.saturating_add(1);
        }
        let moving = match self.state {
            State::Running | State::Homing => true,
            State::Hold => !self.exec.stopped(),
            _ => false,
        };
        if self.link_watch && moving && self.silent_ticks >= LINK_LOSS_TICKS {
            self.fault(at(AlarmCause::LinkLoss, None), false);
        }
        self.last = Inputs {
            drive_fault,
            ..*inputs
        };
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

    /// Actuator reference of joint `j` (steps or encoder counts) for the position
    /// `q`, counts × 2^16.
    fn actuator_q16(&self, j: usize, q: i64) -> i64 {
        self.fast[j].steps_at_frac(q, SETPOINT_FRAC_BITS) + (self.offset[j] << SETPOINT_FRAC_BITS)
    }

    /// Re-bases joint `j`: the actuator reading `reference` (steps or counts) is the
    /// joint position `at`. The actuator's command stays where it is; the joint's
    /// believed position moves.
    fn rebase(&mut self, j: usize, reference: i64, at: i64, moved: i64) {
        let scale = self.machine.joints[j].scale;
        let before = self.joints[j] - moved;
        let command = scale.steps_at(before) + self.offset[j];
        self.offset[j] = reference - scale.steps_at(at);
        self.steps.offset[j] = self.offset[j];
        self.joints[j] = scale.position_of(command - self.offset[j]) + moved;
    }

    fn home_tick(&mut self, inputs: &Inputs) {
        self.motion_ticks += 1;
        let before = self.joints;
        let hin = HomeInputs {
            home: inputs.home,
            index: inputs.index,
        };
        let event = self.homer.tick(
            &self.machine.joints,
            &self.home_joints,
            &hin,
            &mut self.joints,
        );
        match event {
            Some(HomeEvent::Latched { joint, index }) => {
                let jc = self.machine.joints[joint];
                let reference = match (jc.drive, index) {
                    (_, Some(count)) => count,
                    (Drive::Servo { channel }, None) => inputs.encoder_counts[channel as usize],
                    (Drive::Stepper { .. }, None) => self.steps.steps(joint),
                };
                let moved = self.joints[joint] - before[joint];
                self.rebase(joint, reference, jc.homing.switch_at, moved);
            }
            Some(HomeEvent::Failed { joint }) => {
                self.locked = true;
                self.raise(Alarm {
                    cause: AlarmCause::HomingFailed,
                    joint: joint as u8,
                    line: 0,
                });
            }
            Some(HomeEvent::Finished) => {
                let completed = self.exec.completed;
                let window = self.machine.motion.smoothing_ticks as u32;
                self.exec = Executor::new(self.machine.home);
                self.exec.set_smoothing(window);
                self.exec.completed = completed;
                self.planner.clear(self.machine.home);
                self.homed = true;
                self.locked = false;
                self.state = State::Idle;
            }
            None => {}
        }
    }

    /// After a servo trip is reset: the servo joints take their feedback as their
    /// position and the pose follows by the forward kinematics.
    fn resync_servos(&mut self, inputs: &Inputs) {
        self.resync = false;
        let mut joints = self.joints;
        for (j, jc) in self.machine.joints.iter().enumerate() {
            if let Drive::Servo { channel } = jc.drive {
                joints[j] = jc
                    .scale
                    .position_of(inputs.encoder_counts[channel as usize] - self.offset[j]);
            }
        }
        let mut pose = self.exec.pose;
        match self.kin.forward(&joints, &self.exec.pose, &mut pose) {
            Ok(()) => {
                self.joints = joints;
                let completed = self.exec.completed;
                let line = self.exec.line;
                self.exec = Executor::new(pose);
                self.exec
                    .set_smoothing(self.machine.motion.smoothing_ticks as u32);
                self.exec.completed = completed;
                self.exec.line = line;
                self.planner.clear(pose);
                self.out.servo_reset = true;
            }
            Err(_) => {
                self.joints = joints;
                self.locked = true;
                self.homed = false;
                self.out.servo_reset = true;
                self.raise(UNHOMED);
            }
        }
    }

    fn update_servo_targets(&mut self) {
        for (j, jc) in self.machine.joints.iter().enumerate() {
            if let Drive::Servo { channel } = jc.drive {
                self.out.servo_target[channel as usize] = self.actuator_q16(j, self.joints[j]);
            }
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
        self.steps
            .tick(&self.machine.joints, &self.joints, &mut self.trains);
        self.out.steps = [StepTrain::default(); MAX_STEPPERS];
        for (j, jc) in self.machine.joints.iter().enumerate() {
            if let Drive::Stepper {
                channel,
                invert_dir,
                ..
            } = jc.drive
            {
                let mut t = self.trains[j];
                t.forward ^= invert_dir;
                self.out.steps[channel as usize] = t;
            }
        }
        self.update_servo_targets();
        let powered = self.state != State::EStop || self.stopping;
        self.out.enable = powered;
        self.out.servo_enable = powered;
        self.since_status += 1;
        if self.session && self.since_status >= STATUS_EVERY_TICKS {
            self.since_status = 0;
            self.status_due = true;
        }
        &self.out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::{decode_frame, encode_frame, FrameReader, HostMsg, Pushed};

    fn frame(seq: u16, msg: &HostMsg) -> Vec<u8> {
        let mut f = [0u8; MAX_FRAME];
        let n = encode_frame(seq, msg, &mut f).unwrap();
        f[..n].to_vec()
    }

    fn replies(c: &mut Controller) -> Vec<CtrlMsg> {
        let mut buf = [0u8; TX_CAPACITY];
        let n = c.transmit(&mut buf);
        let mut reader = FrameReader::new();
        let mut out = Vec::new();
        for &b in &buf[..n] {
            if let Pushed::Frame(f) = reader.push(b) {
                let mut body = [0u8; MAX_BODY];
                out.push(decode_frame::<CtrlMsg>(f, &mut body).unwrap().1);
            }
        }
        out
    }

    /// The host's plan of `blocks` from `start` on `m` (unlimited look-ahead).
    fn planned(m: &MachineConfig, start: [i64; 6], blocks: &[Block]) -> Vec<HostMsg> {
        let kin = MachineKinematics::new(m);
        let mut out = vec![crate::planner::PlanBlock::default(); blocks.len()];
        crate::planner::plan_into(blocks, start, m, &kin, 1, &mut out).unwrap();
        blocks
            .iter()
            .zip(&out)
            .map(|(b, p)| {
                HostMsg::Block(crate::protocol::PlannedBlock {
                    block: *b,
                    plan: p.plan(),
                })
            })
            .collect()
    }

    /// A line along X from X = 0 on the Cartesian machine, planned by the host.
    fn line_to(x_mm: i64, line: u32) -> HostMsg {
        line_from(0, x_mm, line)
    }

    fn line_from(from_mm: i64, x_mm: i64, line: u32) -> HostMsg {
        let b = Block {
            line,
            motion: Motion::Linear,
            target: [x_mm * 1_000_000, 0, 0, 0, 0, 0],
            feed: 50_000_000,
            tolerance_nm: u32::MAX,
        };
        let start = [from_mm * 1_000_000, 0, 0, 0, 0, 0];
        planned(&MachineConfig::cartesian_xyz(), start, &[b]).remove(0)
    }

    fn hello(c: &Controller) -> HostMsg {
        HostMsg::Hello {
            version: PROTOCOL_VERSION,
            machine: c.machine_id(),
        }
    }

    fn session() -> Controller {
        let mut c = Controller::new(MachineConfig::cartesian_xyz()).unwrap();
        c.unlock();
        c.receive(&frame(0, &hello(&c)));
        c
    }

    #[test]
    fn a_controller_that_disagrees_about_the_machine_refuses_to_move_until_sent_it() {
        let mut other = MachineConfig::cartesian_xyz();
        other.joints[0].limits.max_velocity /= 2;
        other.axes[0].max_velocity /= 2;
        let mut c = Controller::new(MachineConfig::cartesian_xyz()).unwrap();
        let id = crate::store::identity(&other);
        c.receive(&frame(
            0,
            &HostMsg::Hello {
                version: PROTOCOL_VERSION,
                machine: id,
            },
        ));
        c.receive(&frame(1, &line_to(10, 1)));
        let r = replies(&mut c);
        assert!(matches!(r[0], CtrlMsg::HelloAck { machine, .. } if machine != id));
        assert_eq!(
            r[1],
            CtrlMsg::Nak {
                expected: 1,
                reason: NakReason::MachineMismatch
            }
        );
        assert_eq!(
            c.status().alarm.map(|a| a.cause),
            Some(AlarmCause::MachineMismatch)
        );
        // Send the machine in chunks, each twice (a resend), the first once more.
        let mut payload = [0u8; crate::store::MAX_CONFIG_BYTES];
        let n = crate::store::encode(&other, &mut payload).unwrap();
        let offsets = (0..n).step_by(crate::store::CHUNK_BYTES).chain([0]);
        for (chunk_id, off) in (100..).zip(offsets) {
            let end = (off + crate::store::CHUNK_BYTES).min(n);
            let msg = HostMsg::Machine {
                id: chunk_id,
                offset: off as u16,
                total: n as u16,
                crc: id,
                data: heapless::Vec::from_slice(&payload[off..end]).unwrap(),
            };
            c.receive(&frame(0, &msg));
            c.receive(&frame(0, &msg));
        }
        assert!(replies(&mut c).contains(&CtrlMsg::MachineLoaded { machine: id }));
        assert_eq!(c.machine(), &other);
        assert_eq!(c.take_store_request(), Some(&other));
        assert_eq!(c.take_store_request(), None);
        // A new machine: locked until homed or unlocked.
        assert_eq!(c.status().alarm.map(|a| a.cause), Some(AlarmCause::Unhomed));
        c.unlock();
        assert_eq!(c.state(), State::Idle);
        c.receive(&frame(1, &line_to(10, 1)));
        run(&mut c, 10_000);
        assert_eq!(c.pose()[0], 10_000_000);
    }

    /// Runs `ticks` periods, the host asking for a status every 100 ms as nc-send does.
    fn run(c: &mut Controller, ticks: usize) {
        for t in 0..ticks {
            if t % 100 == 0 {
                c.receive(&frame(0, &HostMsg::StatusRequest));
            }
            c.tick(&Inputs::default());
        }
    }

    #[test]
    fn a_block_is_acknowledged_executed_and_ends_on_its_target() {
        let mut c = session();
        c.receive(&frame(1, &line_to(10, 7)));
        let r = replies(&mut c);
        assert!(matches!(r[0], CtrlMsg::HelloAck { .. }));
        assert!(matches!(
            r[1],
            CtrlMsg::Ack {
                seq: 1,
                free_slots,
                ..
            } if free_slots as usize == QUEUE_CAPACITY - 1
        ));
        run(&mut c, 10_000);
        assert_eq!(c.state(), State::Idle);
        assert_eq!(c.pose()[0], 10_000_000);
        assert_eq!(c.steps_emitted(0), 4000);
        assert_eq!(c.line(), 7);
    }

    #[test]
    fn a_duplicate_block_is_acknowledged_but_not_queued_twice() {
        let mut c = session();
        c.receive(&frame(1, &line_to(10, 1)));
        let _ = replies(&mut c);
        c.receive(&frame(1, &line_to(10, 1)));
        // Acks are owed until `transmit`: the duplicate is acknowledged on its own.
        let r = replies(&mut c);
        assert!(matches!(
            r[..],
            [CtrlMsg::Ack {
                seq: 1,
                free_slots,
                ..
            }] if free_slots as usize == QUEUE_CAPACITY - 1
        ));
        // Received together, the block and its duplicate draw one cumulative ack.
        let mut c = session();
        let _ = replies(&mut c);
        c.receive(&frame(1, &line_to(10, 1)));
        c.receive(&frame(1, &line_to(10, 1)));
        let r = replies(&mut c);
        assert!(matches!(
            r[..],
            [CtrlMsg::Ack {
                seq: 1,
                free_slots,
                ..
            }] if free_slots as usize == QUEUE_CAPACITY - 1
        ));
    }

    #[test]
    fn a_gap_and_a_corrupt_frame_are_refused_with_the_expected_sequence() {
        let mut c = session();
        c.receive(&frame(5, &line_to(10, 1)));
        let mut bad = frame(1, &line_to(10, 1));
        bad[3] ^= 0x10;
        c.receive(&bad);
        let r = replies(&mut c);
        assert_eq!(
            r[1],
            CtrlMsg::Nak {
                expected: 1,
                reason: NakReason::Gap
            }
        );
        assert_eq!(
            r[2],
            CtrlMsg::Nak {
                expected: 1,
                reason: NakReason::Corrupt
            }
        );
        assert_eq!(c.link_stats().corrupt, 1);
    }

    #[test]
    fn an_unreachable_block_raises_an_alarm_naming_line_and_joint() {
        let mut c = session();
        c.receive(&frame(1, &line_to(50, 41)));
        c.receive(&frame(2, &line_from(50, 500, 42)));
        run(&mut c, 5000);
        assert_eq!(c.state(), State::Alarm);
        assert_eq!(
            c.status().alarm,
            Some(Alarm {
                cause: AlarmCause::JointLimit,
                joint: 0,
                line: 42
            })
        );
        // It stopped at rest at the end of the reachable block.
        assert_eq!(c.pose()[0], 50_000_000);
    }

    #[test]
    fn a_feed_hold_stops_on_the_path_within_the_braking_distance_and_resumes() {
        let mut c = session();
        c.receive(&frame(1, &line_to(80, 1)));
        run(&mut c, 1000); // at 50 mm/s by now
        let v = c.status().speed as f64 / 1e6; // mm/s
        let at = c.pose()[0];
        c.receive(&frame(
            0,
            &HostMsg::Control {
                id: 1,
                cmd: Control::Hold,
            },
        ));
        run(&mut c, 500);
        assert_eq!(c.state(), State::Hold);
        assert_eq!(c.status().speed, 0);
        let stop = (c.pose()[0] - at) as f64 / 1e6;
        let limit = v * v / (2.0 * 1000.0) + v * 1e-3;
        assert!(
            stop <= limit + 1e-6,
            "stopped after {stop} mm, limit {limit}"
        );
        assert_eq!(c.pose()[1], 0, "on the path");
        let held = *c.pose();
        run(&mut c, 500);
        assert_eq!(c.pose(), &held, "a hold keeps its position");
        c.receive(&frame(
            0,
            &HostMsg::Control {
                id: 2,
                cmd: Control::Resume,
            },
        ));
        run(&mut c, 5000);
        assert_eq!(c.state(), State::Idle);
        assert_eq!(c.pose()[0], 80_000_000);
    }

    #[test]
    fn a_resume_after_a_pause_that_ends_the_queue_is_idle_at_once() {
        let mut c = session();
        c.receive(&frame(1, &line_to(1, 1)));
        let pause = Block {
            line: 2,
            motion: Motion::Aux(Aux::Pause(true)),
            target: [1_000_000, 0, 0, 0, 0, 0],
            feed: 0,
            tolerance_nm: 0,
        };
        let at = [1_000_000, 0, 0, 0, 0, 0];
        let pause = planned(&MachineConfig::cartesian_xyz(), at, &[pause]).remove(0);
        c.receive(&frame(2, &pause));
        run(&mut c, 2000);
        assert_eq!(c.state(), State::Hold, "M1 pauses");
        assert!(!c.has_work());
        c.receive(&frame(
            0,
            &HostMsg::Control {
                id: 1,
                cmd: Control::Resume,
            },
        ));
        assert_eq!(
            c.state(),
            State::Idle,
            "nothing left to run: no tick needed"
        );
        assert_eq!(c.status().blocks_done, 2);
    }

    #[test]
    fn a_repeated_control_id_is_acknowledged_but_acted_on_once() {
        let mut c = session();
        c.receive(&frame(
            0,
            &HostMsg::Control {
                id: 9,
                cmd: Control::FeedOverride(50),
            },
        ));
        c.receive(&frame(
            0,
            &HostMsg::Control {
                id: 9,
                cmd: Control::FeedOverride(150),
            },
        ));
        assert_eq!(c.status().feed_override, 50);
        let acks = replies(&mut c)
            .iter()
            .filter(|m| matches!(m, CtrlMsg::ControlAck { id: 9 }))
            .count();
        assert_eq!(acks, 2);
    }

    fn run_with(c: &mut Controller, ticks: usize, inputs: &Inputs) {
        for t in 0..ticks {
            if t % 100 == 0 {
                c.receive(&frame(0, &HostMsg::StatusRequest));
            }
            c.tick(inputs);
        }
    }

    fn control(c: &mut Controller, id: u16, cmd: Control) {
        c.receive(&frame(0, &HostMsg::Control { id, cmd }));
    }

    #[test]
    fn after_reset_nothing_moves_until_unlocked() {
        let mut c = Controller::new(MachineConfig::cartesian_xyz()).unwrap();
        c.receive(&frame(0, &hello(&c)));
        assert_eq!(c.state(), State::Alarm);
        assert_eq!(c.status().alarm.map(|a| a.cause), Some(AlarmCause::Unhomed));
        c.receive(&frame(1, &line_to(10, 1)));
        control(
            &mut c,
            1,
            Control::Jog {
                axis: 0,
                distance: 1_000_000,
                feed: 10_000_000,
            },
        );
        run(&mut c, 2000);
        assert_eq!(
            c.pose()[0],
            0,
            "locked: neither the block nor the jog moved"
        );
        control(&mut c, 2, Control::AlarmReset);
        assert_eq!(c.state(), State::Idle);
        assert!(!c.homed(), "unlocked, not homed");
    }

    #[test]
    fn an_estop_stops_on_the_path_disables_the_drives_and_holds_until_released() {
        let mut c = session();
        c.receive(&frame(1, &line_to(80, 3)));
        run(&mut c, 1000);
        let v = c.status().speed as f64 / 1e6;
        let at = c.pose()[0];
        let pressed = Inputs {
            estop: true,
            ..Inputs::default()
        };
        run_with(&mut c, 500, &pressed);
        assert_eq!(c.state(), State::EStop);
        assert_eq!(
            c.status().alarm,
            Some(Alarm {
                cause: AlarmCause::EStop,
                joint: NO_JOINT,
                line: 3
            })
        );
        let stop = (c.pose()[0] - at) as f64 / 1e6;
        assert!(stop <= v * v / 2000.0 + v * 1e-3 + 1e-6, "{stop} mm");
        assert!(!c.tick(&pressed).enable, "drives off once stopped");
        let held = *c.pose();
        // Reset is refused while the e-stop is pressed; once released it is accepted
        // and the controller stays where it stopped.
        control(&mut c, 1, Control::AlarmReset);
        assert_eq!(c.state(), State::EStop);
        run(&mut c, 10);
        control(&mut c, 2, Control::AlarmReset);
        assert_eq!(c.state(), State::Idle);
        run(&mut c, 100);
        assert_eq!(c.pose(), &held);
        assert_eq!(
            c.steps_emitted(0),
            c.machine().joints[0].scale.steps_at(held[0])
        );
    }

    #[test]
    fn a_limit_switch_alarms_on_its_edge_naming_the_joint() {
        let mut c = session();
        c.receive(&frame(1, &line_to(80, 9)));
        run(&mut c, 300);
        let tripped = Inputs {
            limit: 0b100,
            ..Inputs::default()
        };
        run_with(&mut c, 500, &tripped);
        assert_eq!(
            c.status().alarm,
            Some(Alarm {
                cause: AlarmCause::LimitSwitch,
                joint: 2,
                line: 9
            })
        );
        // Reset is allowed with the switch still active (to move off it) and the
        // still-active switch does not alarm again.
        control(&mut c, 1, Control::AlarmReset);
        run_with(&mut c, 10, &tripped);
        assert_eq!(c.state(), State::Idle);
    }

    #[test]
    fn jogs_stop_at_the_soft_limits() {
        let mut c = session();
        control(
            &mut c,
            1,
            Control::Jog {
                axis: 0,
                distance: 500_000_000,
                feed: 100_000_000,
            },
        );
        run(&mut c, 10_000);
        assert_eq!(c.state(), State::Idle);
        assert_eq!(c.pose()[0], c.machine().joints[0].max);
    }

    #[test]
    fn silence_from_the_host_while_moving_stops_the_machine_on_the_path() {
        let mut c = session();
        c.receive(&frame(1, &line_to(80, 4)));
        for _ in 0..LINK_LOSS_TICKS - 1 {
            c.tick(&Inputs::default());
        }
        assert_eq!(c.state(), State::Running);
        c.tick(&Inputs::default());
        assert_eq!(
            c.status().alarm,
            Some(Alarm {
                cause: AlarmCause::LinkLoss,
                joint: NO_JOINT,
                line: 4
            })
        );
        assert!(c.has_work(), "still stopping on the path");
        for _ in 0..1000 {
            c.tick(&Inputs::default());
        }
        assert!(!c.has_work());
        assert_eq!(c.status().speed, 0);
    }

    #[test]
    fn a_servo_trip_names_the_joint_of_its_channel() {
        let mut c = Controller::new(MachineConfig::h4_table()).unwrap();
        c.unlock();
        c.receive(&frame(0, &hello(&c)));
        let trip = Inputs {
            servo_trip: [
                None,
                None,
                Some(Trip::FollowingError {
                    error: 5000,
                    limit: 2000,
                }),
                None,
            ],
            ..Inputs::default()
        };
        c.tick(&trip);
        assert_eq!(
            c.status().alarm.map(|a| (a.cause, a.joint)),
            Some((AlarmCause::FollowingError, 2))
        );
        // After the reset the loops restart from their feedback; the trip the bank
        // still reports in that tick is the one cleared.
        control(&mut c, 1, Control::AlarmReset);
        assert!(c.tick(&trip).servo_reset);
        assert_eq!(c.state(), State::Idle);
        assert!(c.status().alarm.is_none());
    }

    /// A gantry with a second Y motor and rotary A B C: seven stepper joints, one on
    /// every board channel (channel 6 is HRTIM1's).
    fn seven_steppers() -> MachineConfig {
        let mut m = MachineConfig::cartesian_xyz();
        let deg = crate::units::NDEG_PER_DEG;
        let rotary = crate::config::Limits {
            max_velocity: 90 * deg,
            max_accel: 900 * deg,
        };
        for (c, axis) in [(3u8, 3u8), (4, 4), (5, 5), (6, 1)] {
            let mut j = m.joints[1];
            if let Drive::Stepper { channel, .. } = &mut j.drive {
                *channel = c;
            }
            if axis >= 3 {
                j.rotary = true;
                j.scale = crate::config::Scale::new(50, deg as u64);
                j.min = -180 * deg;
                j.max = 180 * deg;
                j.limits = rotary;
                j.homing = crate::config::Homing::NONE;
                m.axes[axis as usize] = rotary;
            }
            let _ = m.joints.push(j);
            if let crate::config::KinematicsConfig::Cartesian { axis_of_joint } = &mut m.kinematics
            {
                axis_of_joint[m.joints.len() - 1] = axis;
            }
        }
        m
    }

    #[test]
    fn seven_stepper_joints_end_on_exact_steps() {
        let m = seven_steppers();
        assert_eq!(m.validate(), Ok(()));
        let mut c = Controller::new(m.clone()).unwrap();
        c.unlock();
        c.receive(&frame(0, &hello(&c)));
        let deg = crate::units::NDEG_PER_DEG;
        let target = [
            10_000_000,
            20_000_000,
            -5_000_000,
            30 * deg,
            -45 * deg,
            90 * deg,
        ];
        let b = Block {
            line: 1,
            motion: Motion::Linear,
            target,
            feed: 20_000_000,
            tolerance_nm: 0,
        };
        c.receive(&frame(1, &planned(&m, *c.pose(), &[b])[0]));
        let mut emitted = [0i64; MAX_STEPPERS];
        for t in 0..20_000 {
            if t % 100 == 0 {
                c.receive(&frame(0, &HostMsg::StatusRequest));
            }
            let out = *c.tick(&Inputs::default());
            for (e, train) in emitted.iter_mut().zip(&out.steps) {
                *e += if train.forward {
                    train.count as i64
                } else {
                    -(train.count as i64)
                };
            }
            if c.state() == State::Idle && !c.has_work() {
                break;
            }
        }
        assert_eq!(c.pose(), &target);
        // Channel 6 (the second Y motor) emitted exactly what Y did.
        let want = [4000, 8000, -2000, 1500, -2250, 4500, 8000];
        assert_eq!(emitted, want);
    }

    #[test]
    fn a_drive_fault_while_the_drives_are_off_does_not_block_the_reset() {
        let mut c = session();
        let pressed = Inputs {
            estop: true,
            drive_fault: 0b1, // this drive reports a fault whenever it is disabled
            ..Inputs::default()
        };
        run_with(&mut c, 10, &pressed);
        assert_eq!(c.state(), State::EStop);
        let released = Inputs {
            drive_fault: 0b1,
            ..Inputs::default()
        };
        run_with(&mut c, 10, &released);
        control(&mut c, 1, Control::AlarmReset);
        assert_eq!(c.state(), State::Idle, "the fault line of a disabled drive");
        // Powered again, the fault is real.
        run_with(&mut c, 2, &released);
        assert_eq!(
            c.status().alarm.map(|a| (a.cause, a.joint)),
            Some((AlarmCause::DriveFault, 0))
        );
    }
}
