//! The controller state machine: bytes in, bytes out, one interpolation tick at a time.
//!
//! [`Controller::receive`] takes bytes from the link, [`Controller::transmit`] hands
//! back bytes for it, and [`Controller::tick`] advances motion by one period T
//! ([`crate::units::TICK_NS`]) given the inputs read from the hardware, returning the
//! outputs to apply (step trains per stepper channel, commands per servo channel). The
//! firmware calls `tick` from its timer interrupt; the simulator calls it with
//! simulated time; both run exactly this code.
//!
//! States: `Idle` (queue empty, not moving) → `Running` (executing blocks) → `Idle`;
//! any fault → `Alarm`, in which nothing moves. Blocks are planned when they are
//! queued, so the buffered motion time is known exactly; each block starts and ends at
//! rest (look-ahead comes with the planner work).

use crate::config::{ConfigError, Drive, MachineConfig, MAX_JOINTS, MAX_SERVOS, MAX_STEPPERS};
use crate::interp::{Interpolator, Segment};
use crate::kinematics::{Joints, Kinematics, MachineKinematics, Pose, Unreachable};
use crate::protocol::{
    decode_frame, encode_frame, Alarm, CtrlMsg, FrameReader, HostMsg, NakReason, Pushed, State,
    Status, MAX_BODY, MAX_FRAME, PROTOCOL_VERSION,
};
use crate::servo::ServoLoop;
use crate::stepper::{StepScheduler, StepTrain};
use crate::units::TICK_HZ;

/// Blocks the controller buffers.
pub const QUEUE_CAPACITY: usize = 64;
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
    queue: heapless::Deque<Segment, QUEUE_CAPACITY>,
    queued_end: Pose,
    queued_ticks: u64,
    interp: Interpolator,
    pose: Pose,
    joints: Joints,
    steps: StepScheduler,
    servos: [ServoLoop; MAX_SERVOS],
    trains: [StepTrain; MAX_JOINTS],
    state: State,
    alarm: Option<Alarm>,
    line: u32,
    blocks_done: u32,
    motion_ticks: u64,
    since_status: u32,
    out: Outputs,
    stats: LinkStats,
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
        let mut servos = [ServoLoop::new(0); MAX_SERVOS];
        for (jc, q) in machine.joints.iter().zip(&joints) {
            if let Drive::Servo { channel, .. } = jc.drive {
                servos[channel as usize] = ServoLoop::new(jc.scale.steps_at(*q));
            }
        }
        Ok(Self {
            machine,
            kin,
            reader: FrameReader::new(),
            tx: heapless::Deque::new(),
            tx_seq: 0,
            session: false,
            expected_seq: 0,
            queue: heapless::Deque::new(),
            queued_end: pose,
            queued_ticks: 0,
            interp: Interpolator::new(),
            pose,
            joints,
            steps,
            servos,
            trains: [StepTrain::default(); MAX_JOINTS],
            state: State::Idle,
            alarm: None,
            line: 0,
            blocks_done: 0,
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
    pub fn pose(&self) -> &Pose {
        &self.pose
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
        self.line
    }
    /// Link counters.
    pub fn link_stats(&self) -> LinkStats {
        self.stats
    }
    /// Is motion executing or queued?
    pub fn has_work(&self) -> bool {
        self.interp.busy() || !self.queue.is_empty()
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
        let ticks = self.queued_ticks + self.interp.remaining_ticks() as u64;
        (ticks * 1000 / TICK_HZ as u64).min(u32::MAX as u64) as u32
    }

    fn free_slots(&self) -> u16 {
        (QUEUE_CAPACITY - self.queue.len()) as u16
    }

    fn ack(&mut self, seq: u16) {
        self.send(&CtrlMsg::Ack {
            seq,
            free_slots: self.free_slots(),
            buffered_ms: self.buffered_ms(),
        });
    }

    fn handle(&mut self, seq: u16, msg: HostMsg) {
        match msg {
            HostMsg::Hello { version } => {
                if version != PROTOCOL_VERSION {
                    self.nak(NakReason::Version);
                    return;
                }
                self.session = true;
                self.expected_seq = seq.wrapping_add(1);
                self.blocks_done = 0;
                self.motion_ticks = 0;
                self.send(&CtrlMsg::HelloAck {
                    version: PROTOCOL_VERSION,
                    queue_capacity: QUEUE_CAPACITY as u16,
                });
            }
            HostMsg::StatusRequest => {
                let s = self.status();
                self.send(&CtrlMsg::Status(s));
            }
            HostMsg::Abort => {
                self.interp.stop();
                self.queue.clear();
                self.queued_ticks = 0;
                self.queued_end = self.pose;
                self.state = State::Idle;
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
                if self.queue.is_full() {
                    self.nak(NakReason::QueueFull);
                    return;
                }
                let seg = Segment::plan(&block, &self.queued_end, &self.machine, &self.kin);
                if seg.unreachable.is_none() {
                    self.queued_end = block.target;
                }
                self.queued_ticks += seg.ticks() as u64;
                let _ = self.queue.push_back(seg);
                self.expected_seq = seq.wrapping_add(1);
                self.ack(seq);
            }
        }
    }

    /// A status snapshot.
    pub fn status(&self) -> Status {
        Status {
            state: self.state,
            line: self.line,
            blocks_done: self.blocks_done,
            motion_ticks: self.motion_ticks,
            pose: self.pose,
            joints: self.joints,
            buffered_ms: self.buffered_ms(),
            free_slots: self.free_slots(),
            alarm: self.alarm,
        }
    }

    fn raise(&mut self, alarm: Alarm) {
        self.alarm = Some(alarm);
        self.state = State::Alarm;
        self.interp.stop();
        self.queue.clear();
        self.queued_ticks = 0;
        self.queued_end = self.pose;
    }

    /// Starts the next queued segment, if any; completes zero-length ones at once.
    fn start_next(&mut self) {
        while !self.interp.busy() {
            let Some(seg) = self.queue.pop_front() else {
                return;
            };
            self.queued_ticks -= seg.ticks() as u64;
            self.line = seg.line;
            if let Some(why) = seg.unreachable {
                let joint = match why {
                    Unreachable::JointLimit { joint } => joint,
                    _ => u8::MAX,
                };
                self.raise(Alarm::Unreachable {
                    line: seg.line,
                    joint,
                });
                return;
            }
            if seg.ticks() == 0 {
                self.blocks_done += 1;
                continue;
            }
            self.interp.start(seg);
        }
    }

    /// Advances one interpolation period.
    pub fn tick(&mut self, inputs: &Inputs) -> &Outputs {
        if self.state != State::Alarm {
            self.start_next();
        }
        if self.interp.busy() {
            self.state = State::Running;
            self.motion_ticks += 1;
            if self.interp.tick(&mut self.pose) {
                self.blocks_done += 1;
            }
            let mut joints = self.joints;
            match self.kin.inverse(&self.pose, &mut joints) {
                Ok(()) => self.joints = joints,
                Err(_) => self.raise(Alarm::Unreachable {
                    line: self.line,
                    joint: u8::MAX,
                }),
            }
        }
        if self.state == State::Running && !self.has_work() {
            self.state = State::Idle;
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
        self.out.enable = self.state != State::Alarm;
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
    use crate::protocol::{Block, Motion};

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
        })
    }

    #[test]
    fn a_block_is_acknowledged_executed_and_ends_on_its_target() {
        let mut c = Controller::new(MachineConfig::cartesian_xyz()).unwrap();
        c.receive(&frame(
            0,
            &HostMsg::Hello {
                version: PROTOCOL_VERSION,
            },
        ));
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
        let inputs = Inputs::default();
        for _ in 0..10_000 {
            c.tick(&inputs);
        }
        assert_eq!(c.state(), State::Idle);
        assert_eq!(c.pose()[0], 10_000_000);
        assert_eq!(c.steps_emitted(0), 4000);
        assert_eq!(c.line(), 7);
    }

    #[test]
    fn a_duplicate_block_is_acknowledged_but_not_queued_twice() {
        let mut c = Controller::new(MachineConfig::cartesian_xyz()).unwrap();
        c.receive(&frame(
            0,
            &HostMsg::Hello {
                version: PROTOCOL_VERSION,
            },
        ));
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
        let mut c = Controller::new(MachineConfig::cartesian_xyz()).unwrap();
        c.receive(&frame(
            0,
            &HostMsg::Hello {
                version: PROTOCOL_VERSION,
            },
        ));
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
        let mut c = Controller::new(MachineConfig::cartesian_xyz()).unwrap();
        c.receive(&frame(
            0,
            &HostMsg::Hello {
                version: PROTOCOL_VERSION,
            },
        ));
        c.receive(&frame(1, &line_to(500, 42)));
        c.tick(&Inputs::default());
        assert_eq!(c.state(), State::Alarm);
        assert_eq!(
            c.status().alarm,
            Some(Alarm::Unreachable { line: 42, joint: 0 })
        );
        assert_eq!(c.pose()[0], 0);
    }
}
