//! The controller state machine: bytes in, bytes out, one interpolation tick at a time.
//!
//! [`Controller::receive`] takes bytes from the link, [`Controller::transmit`] hands
//! back bytes for it, and [`Controller::tick`] advances motion by one period T
//! ([`crate::units::TICK_NS`]) given the inputs read from the hardware, returning the
//! outputs to apply (step trains per stepper channel, commands per servo channel). The
//! firmware calls `tick` from its timer interrupt; the simulator calls it with
//! simulated time; both run exactly this code.
//!
//! States: `Idle` (nothing to do) ⇄ `Running` (executing) ⇄ `Hold` (feed hold, pause or
//! tool change: decelerating on the path or stopped on it, resumed by `Resume`); any
//! fault → `Alarm`, in which nothing moves until `AlarmReset`. Blocks are planned as
//! they are queued ([`crate::planner`]); control commands bypass the queue.

use crate::config::{ConfigError, Drive, MachineConfig, MAX_JOINTS, MAX_SERVOS, MAX_STEPPERS};
use crate::interp::{Event, Executor};
use crate::kinematics::{Joints, MachineKinematics, Unreachable};
use crate::planner::{Planner, PushError};
use crate::protocol::{
    decode_frame, encode_frame, Alarm, AlarmCause, Aux, Block, Control, CtrlMsg, FrameReader,
    HostMsg, Motion, NakReason, Pushed, State, Status, MAX_BODY, MAX_FRAME, NO_JOINT,
    PROTOCOL_VERSION,
};
use crate::servo::ServoLoop;
use crate::stepper::{StepScheduler, StepTrain};
use crate::units::TICK_HZ;

pub use crate::planner::QUEUE_CAPACITY;
/// Bytes of outgoing frames buffered between two `transmit` calls.
pub const TX_CAPACITY: usize = 2048;
/// Ticks between two unsolicited status messages (50 ms at 1 kHz).
pub const STATUS_EVERY_TICKS: u32 = 50;

/// What the hardware reports each tick.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Inputs {
    /// Encoder position of each servo channel, counts.
    pub encoder_counts: [i64; MAX_SERVOS],
}

/// What the hardware must do this tick.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Outputs {
    /// Step train of each stepper channel; `forward` already includes DIR inversion.
    pub steps: [StepTrain; MAX_STEPPERS],
    /// Command of each servo channel, signed DAC counts around mid-scale.
    pub servo_command: [i32; MAX_SERVOS],
    /// Drives enabled.
    pub enable: bool,
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
    reader: FrameReader,
    tx: heapless::Deque<u8, TX_CAPACITY>,
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
    steps: StepScheduler,
    servos: [ServoLoop; MAX_SERVOS],
    trains: [StepTrain; MAX_JOINTS],
    state: State,
    alarm: Option<Alarm>,
    abort_pending: bool,
    spindle: Aux,
    motion_ticks: u64,
    since_status: u32,
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
        planner.smoothing = machine.motion.smoothing_ticks as u32;
        let mut servos = [ServoLoop::new(0); MAX_SERVOS];
        for (jc, q) in machine.joints.iter().zip(&joints) {
            if let Drive::Servo { channel, .. } = jc.drive {
                servos[channel as usize] = ServoLoop::new(jc.scale.steps_at(*q));
            }
        }
        let machine_for_id = machine.clone();
        Ok(Self {
            machine,
            kin,
            reader: FrameReader::new(),
            tx: heapless::Deque::new(),
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
            steps,
            servos,
            trains: [StepTrain::default(); MAX_JOINTS],
            state: State::Idle,
            alarm: None,
            abort_pending: false,
            spindle: Aux::SpindleOff,
            motion_ticks: 0,
            since_status: 0,
            out: Outputs::default(),
            stats: LinkStats::default(),
        })
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
        match self.state {
            State::Alarm | State::EStop => false,
            // An abort completes on the next tick once stopped: that tick is work.
            State::Hold => !self.exec.stopped() || self.abort_pending,
            _ => self.exec.busy() || !self.planner.is_empty() || !self.exec.settled(),
        }
    }

    /// Jerk limitation: smooths the path motion over `window` ticks (1 = off); see
    /// [`crate::interp`].
    pub fn set_smoothing(&mut self, window: u32) {
        self.exec.set_smoothing(window);
        self.planner.smoothing = window.max(1).next_power_of_two();
    }

    /// Feeds bytes received from the link.
    pub fn receive(&mut self, bytes: &[u8]) {
        for &b in bytes {
            let mut body = [0u8; MAX_BODY];
            let decoded = match self.reader.push(b) {
                Pushed::Pending => continue,
                Pushed::Overlong => None,
                Pushed::Frame(f) => decode_frame::<HostMsg>(f, &mut body).ok(),
            };
            match decoded {
                Some((seq, msg)) => self.handle(seq, msg),
                None => {
                    self.stats.corrupt += 1;
                    self.nak(NakReason::Corrupt);
                }
            }
        }
    }

    /// Moves pending outgoing bytes into `out`; returns how many.
    pub fn transmit(&mut self, out: &mut [u8]) -> usize {
        let mut n = 0;
        while n < out.len() {
            match self.tx.pop_front() {
                Some(b) => {
                    out[n] = b;
                    n += 1;
                }
                None => break,
            }
        }
        n
    }

    fn send(&mut self, msg: &CtrlMsg) {
        let mut frame = [0u8; MAX_FRAME];
        let Ok(n) = encode_frame(self.tx_seq, msg, &mut frame) else {
            self.stats.tx_dropped += 1;
            return;
        };
        if self.tx.capacity() - self.tx.len() < n {
            self.stats.tx_dropped += 1;
            return;
        }
        self.tx_seq = self.tx_seq.wrapping_add(1);
        for &b in &frame[..n] {
            let _ = self.tx.push_back(b);
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

    fn ack(&mut self, seq: u16) {
        self.send(&CtrlMsg::Ack {
            seq,
            free_slots: self.planner.free() as u16,
            buffered_ms: self.buffered_ms(),
        });
    }

    fn handle(&mut self, seq: u16, msg: HostMsg) {
        match msg {
            HostMsg::Hello { version, machine } => {
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
            HostMsg::Machine {
                id,
                offset,
                total,
                crc,
                data,
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
                    .add(offset as usize, total as usize, crc, &data)
                {
                    Ok(None) => {}
                    Ok(Some(config)) => self.load_machine(config),
                    Err(error) => self.send(&CtrlMsg::MachineRefused { error }),
                }
            }
            HostMsg::StatusRequest => {
                let s = self.status();
                self.send(&CtrlMsg::Status(s));
            }
            HostMsg::Control { id, cmd } => {
                if self.last_control != Some(id) {
                    self.last_control = Some(id);
                    self.control(cmd);
                }
                self.send(&CtrlMsg::ControlAck { id });
            }
            HostMsg::Block(block) => {
                if !self.session {
                    self.nak(NakReason::NoSession);
                    return;
                }
                let ahead = seq.wrapping_sub(self.expected_seq) as i16;
                if ahead < 0 {
                    // A duplicate of an accepted frame: acknowledge, do not execute.
                    self.ack(self.expected_seq.wrapping_sub(1));
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
                    self.ack(seq);
                    return;
                }
                match self.planner.push(&block, &self.machine, &self.kin) {
                    Ok(()) => {
                        self.expected_seq = seq.wrapping_add(1);
                        self.ack(seq);
                    }
                    Err(PushError::Full) => self.nak(NakReason::QueueFull),
                    Err(PushError::Geometry(_)) => self.nak(NakReason::BadBlock),
                }
            }
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
                    self.state = State::Running;
                }
            }
            Control::Abort => {
                if matches!(self.state, State::Running | State::Hold | State::Idle) {
                    self.planner.hold = true;
                    self.abort_pending = true;
                    self.exec.replan(&mut self.planner);
                    self.state = State::Hold;
                }
            }
            Control::AlarmReset => {
                if self.state == State::Alarm && !self.mismatch {
                    self.alarm = None;
                    self.state = State::Idle;
                }
            }
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
                    let mut target = self.exec.pose;
                    target[axis as usize] = target[axis as usize].saturating_add(distance);
                    self.push_motion(Motion::Linear, target, feed.max(1));
                }
            }
            Control::Stop => self.raise(Alarm {
                cause: AlarmCause::Aborted,
                joint: NO_JOINT,
                line: self.exec.line,
            }),
            Control::Home => {
                if self.state == State::Idle && !self.has_work() {
                    self.push_motion(Motion::Rapid, self.machine.home, 0);
                }
            }
        }
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
        }
    }

    fn raise(&mut self, alarm: Alarm) {
        self.alarm = Some(alarm);
        self.state = State::Alarm;
        self.exec.stop();
        self.planner.hold = false;
        self.abort_pending = false;
        self.planner.clear(self.exec.pose);
    }

    /// Advances one interpolation period.
    pub fn tick(&mut self, inputs: &Inputs) -> &Outputs {
        if !matches!(self.state, State::Alarm | State::EStop) {
            let moving = self.exec.busy() || !self.planner.is_empty() || !self.exec.settled();
            if moving {
                self.motion_ticks += 1;
                if self.state == State::Idle {
                    self.state = State::Running;
                }
            }
            match self.exec.tick(&mut self.planner) {
                Some(Event::Unreachable { line, why }) => self.raise(alarm_of(why, line)),
                Some(Event::Aux { aux, .. }) => match aux {
                    Aux::Pause(_) | Aux::ToolChange(_) => self.state = State::Hold,
                    Aux::SpindleOff | Aux::SpindleCw(_) | Aux::SpindleCcw(_) => self.spindle = aux,
                    _ => {}
                },
                None => {}
            }
            if self.state != State::Alarm {
                let mut joints = self.joints;
                match self
                    .kin
                    .inverse_checked(&self.exec.pose, &self.machine.joints, &mut joints)
                {
                    Ok(()) => self.joints = joints,
                    Err(why) => self.raise(alarm_of(why, self.exec.line)),
                }
            }
            if self.state == State::Hold && self.abort_pending && self.exec.stopped() {
                self.exec.stop();
                self.planner.clear(self.exec.pose);
                self.planner.hold = false;
                self.abort_pending = false;
                self.exec.paused = false;
                self.state = State::Idle;
            }
            if self.state == State::Running
                && !self.exec.busy()
                && self.planner.is_empty()
                && self.exec.settled()
            {
                self.state = State::Idle;
            }
        }
        self.steps
            .tick(&self.machine.joints, &self.joints, &mut self.trains);
        self.out.steps = [StepTrain::default(); MAX_STEPPERS];
        for (j, jc) in self.machine.joints.iter().enumerate() {
            match jc.drive {
                Drive::Stepper {
                    channel,
                    invert_dir,
                    ..
                } => {
                    let mut t = self.trains[j];
                    t.forward ^= invert_dir;
                    self.out.steps[channel as usize] = t;
                }
                Drive::Servo {
                    channel,
                    kp_q16,
                    kvff_q16,
                    out_limit,
                } => {
                    let c = channel as usize;
                    let target = jc.scale.steps_at(self.joints[j]);
                    self.out.servo_command[c] = self.servos[c].update(
                        target,
                        inputs.encoder_counts[c],
                        kp_q16,
                        kvff_q16,
                        out_limit,
                    );
                }
            }
        }
        self.out.enable = !matches!(self.state, State::Alarm | State::EStop);
        self.since_status += 1;
        if self.session && self.since_status >= STATUS_EVERY_TICKS {
            self.since_status = 0;
            let s = self.status();
            self.send(&CtrlMsg::Status(s));
        }
        &self.out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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

    fn line_to(x_mm: i64, line: u32) -> HostMsg {
        HostMsg::Block(Block {
            line,
            motion: Motion::Linear,
            target: [x_mm * 1_000_000, 0, 0, 0, 0, 0],
            feed: 50_000_000,
            tolerance_nm: u32::MAX,
        })
    }

    fn hello(c: &Controller) -> HostMsg {
        HostMsg::Hello {
            version: PROTOCOL_VERSION,
            machine: c.machine_id(),
        }
    }

    fn session() -> Controller {
        let mut c = Controller::new(MachineConfig::cartesian_xyz()).unwrap();
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
        assert_eq!(c.state(), State::Idle);
        c.receive(&frame(1, &line_to(10, 1)));
        run(&mut c, 10_000);
        assert_eq!(c.pose()[0], 10_000_000);
    }

    fn run(c: &mut Controller, ticks: usize) {
        for _ in 0..ticks {
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
                free_slots: 63,
                ..
            }
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
        c.receive(&frame(1, &line_to(10, 1)));
        let r = replies(&mut c);
        assert!(matches!(
            r[2],
            CtrlMsg::Ack {
                seq: 1,
                free_slots: 63,
                ..
            }
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
        c.receive(&frame(2, &line_to(500, 42)));
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
}
