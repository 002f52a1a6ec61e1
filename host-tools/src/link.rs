//! Both ends of the serial link on the host: [`serve`] runs a [`Simulator`] behind a
//! serial port (a pseudo-terminal), and [`Link`] is `nc-send`'s client, used unchanged
//! for a board and for the simulator.
//!
//! Client protocol (see `pkmc::protocol`): handshake with `Hello`, then stream blocks
//! with consecutive sequence numbers while the blocks in flight (sent, not yet
//! acknowledged) are fewer than the free queue slots last reported. A `Nak` rewinds
//! the stream to the sequence number the controller expects (go-back-N); silence for
//! [`RESEND_AFTER`] with blocks in flight does the same. When every block is
//! acknowledged, the client polls status until the controller has executed them all
//! and is idle, or reports an alarm.

use crate::sim::Simulator;
use anyhow::{anyhow, bail, Result};
use pkmc::config::MachineConfig;
use pkmc::protocol::{
    decode_frame, encode_frame, Block, CtrlMsg, FrameReader, HostMsg, NakReason, Pushed, State,
    Status, MAX_BODY, MAX_FRAME, PROTOCOL_VERSION,
};
use serialport::SerialPort;
use std::io::{ErrorKind, Read, Write};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// Silence after which unacknowledged blocks are sent again.
pub const RESEND_AFTER: Duration = Duration::from_millis(500);
/// Silence after which the link is declared dead.
pub const LINK_TIMEOUT: Duration = Duration::from_secs(5);
/// Status polling period while waiting for the end of the job.
pub const POLL_EVERY: Duration = Duration::from_millis(20);

fn is_timeout(e: &std::io::Error) -> bool {
    matches!(
        e.kind(),
        ErrorKind::TimedOut | ErrorKind::WouldBlock | ErrorKind::Interrupted
    )
}

/// Serves `sim` on `port` until `stop` is set. Simulated time advances while the
/// controller has motion to execute; when idle, the loop waits for bytes.
pub fn serve(sim: &mut Simulator, port: &mut dyn SerialPort, stop: &AtomicBool) -> Result<()> {
    let mut buf = [0u8; 4096];
    let mut out = [0u8; pkmc::controller::TX_CAPACITY];
    while !stop.load(Ordering::Relaxed) {
        let busy = sim.ctrl.has_work();
        let ready = port.bytes_to_read().unwrap_or(0) as usize;
        if ready > 0 || !busy {
            port.set_timeout(Duration::from_millis(if busy { 0 } else { 5 }))?;
            let want = ready.clamp(1, buf.len());
            match port.read(&mut buf[..want]) {
                Ok(n) => {
                    sim.ctrl.receive(&buf[..n]);
                    sim.persist()?;
                }
                Err(e) if is_timeout(&e) => {}
                Err(e) => return Err(e.into()),
            }
        }
        if sim.ctrl.has_work() {
            sim.tick()?;
        }
        let n = sim.ctrl.transmit(&mut out);
        if n > 0 {
            port.write_all(&out[..n])?;
        }
    }
    sim.finish_trace()
}

/// How a job ended.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum JobEnd {
    /// Every block executed; the controller is idle.
    Done,
    /// The controller raised an alarm.
    Alarm,
}

/// Link statistics seen by the client.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct ClientStats {
    /// Frames sent (including resends).
    pub frames_sent: u64,
    /// Blocks sent again after a Nak or a timeout.
    pub resent: u64,
    /// Naks received.
    pub naks: u64,
    /// Received frames that failed to decode.
    pub corrupt_received: u64,
}

/// `nc-send`'s end of the link.
pub struct Link {
    port: Box<dyn SerialPort>,
    reader: FrameReader,
    next_seq: u16,
    capacity: u16,
    /// Last status received.
    pub status: Option<Status>,
    /// Counters.
    pub stats: ClientStats,
    next_control: u16,
}

impl Link {
    /// Opens a session on `port` for `machine`: sends `Hello` and waits for
    /// `HelloAck`; when the controller has another machine, sends it ours and waits
    /// until it is loaded (the controller refuses to move until then).
    pub fn connect(mut port: Box<dyn SerialPort>, machine: &MachineConfig) -> Result<Self> {
        port.set_timeout(Duration::from_millis(10))?;
        let mut link = Link {
            port,
            reader: FrameReader::new(),
            next_seq: 0,
            capacity: 0,
            status: None,
            stats: ClientStats::default(),
            next_control: 1,
        };
        let ours = pkmc::store::identity(machine);
        for _attempt in 0..5 {
            link.send(
                0,
                &HostMsg::Hello {
                    version: PROTOCOL_VERSION,
                    machine: ours,
                },
            )?;
            let until = Instant::now() + Duration::from_millis(500);
            while Instant::now() < until {
                for msg in link.pump()? {
                    match msg {
                        CtrlMsg::HelloAck {
                            version,
                            queue_capacity,
                            machine: theirs,
                        } if version == PROTOCOL_VERSION => {
                            link.capacity = queue_capacity;
                            link.next_seq = 1;
                            if theirs != ours {
                                link.send_machine(machine)?;
                            }
                            return Ok(link);
                        }
                        CtrlMsg::Nak {
                            reason: NakReason::Version,
                            ..
                        } => bail!("the controller speaks another protocol version (ours is {PROTOCOL_VERSION})"),
                        _ => {}
                    }
                }
            }
        }
        bail!("no answer to the handshake: is a pkmc controller on this port?")
    }

    /// Sends `machine` in chunks, each resent until acknowledged, and waits for the
    /// controller to load it.
    fn send_machine(&mut self, machine: &MachineConfig) -> Result<()> {
        let mut payload = [0u8; pkmc::store::MAX_CONFIG_BYTES];
        let n = pkmc::store::encode(machine, &mut payload)
            .ok_or_else(|| anyhow!("the machine configuration is too large to send"))?;
        let crc = pkmc::crc::crc32(&payload[..n]);
        let mut early = Vec::new();
        for off in (0..n).step_by(pkmc::store::CHUNK_BYTES) {
            let end = (off + pkmc::store::CHUNK_BYTES).min(n);
            let id = self.next_control;
            self.next_control = self.next_control.wrapping_add(1);
            let msg = HostMsg::Machine {
                id,
                offset: off as u16,
                total: n as u16,
                crc,
                data: heapless::Vec::from_slice(&payload[off..end])
                    .map_err(|_| anyhow!("chunk too large"))?,
            };
            early.extend(self.until_acked(id, &msg)?);
        }
        let start = Instant::now();
        while start.elapsed() < LINK_TIMEOUT {
            let msgs = std::mem::take(&mut early).into_iter().chain(self.pump()?);
            for m in msgs.collect::<Vec<_>>() {
                match m {
                    CtrlMsg::MachineLoaded { machine } if machine == crc => return Ok(()),
                    CtrlMsg::MachineRefused { error } => {
                        bail!("the controller refused the machine configuration: {error:?}")
                    }
                    _ => {}
                }
            }
        }
        bail!("link lost: the controller did not confirm the machine configuration")
    }

    /// Sends `msg` (a control or machine chunk with `id`) until `ControlAck { id }`;
    /// returns the other messages received meanwhile.
    fn until_acked(&mut self, id: u16, msg: &HostMsg) -> Result<Vec<CtrlMsg>> {
        let start = Instant::now();
        let mut others = Vec::new();
        while start.elapsed() < LINK_TIMEOUT {
            self.send(0, msg)?;
            let until = Instant::now() + Duration::from_millis(100);
            while Instant::now() < until {
                let mut acked = false;
                for m in self.pump()? {
                    if m == (CtrlMsg::ControlAck { id }) {
                        acked = true;
                    } else {
                        others.push(m);
                    }
                }
                if acked {
                    return Ok(others);
                }
            }
        }
        bail!("link lost: no acknowledgement of {msg:?}")
    }

    fn send(&mut self, seq: u16, msg: &HostMsg) -> Result<()> {
        let mut frame = [0u8; MAX_FRAME];
        let n = encode_frame(seq, msg, &mut frame)
            .map_err(|e| anyhow!("cannot frame {msg:?}: {e:?}"))?;
        self.port.write_all(&frame[..n])?;
        self.stats.frames_sent += 1;
        Ok(())
    }

    /// Reads what has arrived (waiting up to the port timeout) and decodes it.
    fn pump(&mut self) -> Result<Vec<CtrlMsg>> {
        let mut buf = [0u8; 4096];
        let n = match self.port.read(&mut buf) {
            Ok(n) => n,
            Err(e) if is_timeout(&e) => 0,
            Err(e) => return Err(anyhow!("link read failed: {e}")),
        };
        let mut msgs = Vec::new();
        for &b in &buf[..n] {
            match self.reader.push(b) {
                Pushed::Pending => {}
                Pushed::Overlong => self.stats.corrupt_received += 1,
                Pushed::Frame(f) => {
                    let mut body = [0u8; MAX_BODY];
                    match decode_frame::<CtrlMsg>(f, &mut body) {
                        Ok((_, m)) => msgs.push(m),
                        Err(_) => self.stats.corrupt_received += 1,
                    }
                }
            }
        }
        for m in &msgs {
            if let CtrlMsg::Status(s) = m {
                self.status = Some(s.clone());
            }
        }
        Ok(msgs)
    }

    /// Asks for and waits for a fresh status.
    pub fn request_status(&mut self) -> Result<Status> {
        let start = Instant::now();
        loop {
            self.send(0, &HostMsg::StatusRequest)?;
            let until = Instant::now() + Duration::from_millis(200);
            while Instant::now() < until {
                for m in self.pump()? {
                    if let CtrlMsg::Status(s) = m {
                        return Ok(s);
                    }
                }
            }
            if start.elapsed() > LINK_TIMEOUT {
                bail!("link lost: no status from the controller for {LINK_TIMEOUT:?}");
            }
        }
    }

    /// Streams `blocks` and waits until they have all executed. `progress` is called
    /// with every status received.
    pub fn run_job(
        &mut self,
        blocks: &[Block],
        mut progress: impl FnMut(&Status),
    ) -> Result<JobEnd> {
        let base = self.next_seq;
        let total = blocks.len();
        let (mut sent, mut acked) = (0usize, 0usize);
        let mut free = self.capacity as usize;
        let mut last_heard = Instant::now();
        let index_of = |seq: u16| seq.wrapping_sub(base) as usize;
        while acked < total {
            while sent < total && sent - acked < free {
                let seq = base.wrapping_add(sent as u16);
                self.send(seq, &HostMsg::Block(blocks[sent]))?;
                sent += 1;
            }
            let msgs = self.pump()?;
            if !msgs.is_empty() {
                last_heard = Instant::now();
            }
            for m in msgs {
                match m {
                    CtrlMsg::Ack {
                        seq, free_slots, ..
                    } => {
                        let done = index_of(seq).wrapping_add(1);
                        if done <= total && done >= acked {
                            acked = done;
                            free = free_slots as usize;
                            sent = sent.max(acked);
                        }
                    }
                    CtrlMsg::Nak { expected, reason } => {
                        self.stats.naks += 1;
                        match reason {
                            NakReason::Version | NakReason::NoSession => {
                                bail!("the controller refused the session ({reason:?})")
                            }
                            NakReason::QueueFull => free = 0,
                            NakReason::Corrupt | NakReason::Gap => {}
                            _ => {}
                        }
                        let back = index_of(expected);
                        if back <= total && back >= acked && back < sent {
                            self.stats.resent += (sent - back) as u64;
                            sent = back;
                        }
                    }
                    CtrlMsg::Status(s) => {
                        free = s.free_slots as usize;
                        progress(&s);
                        if s.state == State::Alarm {
                            return Ok(JobEnd::Alarm);
                        }
                    }
                    CtrlMsg::HelloAck { .. }
                    | CtrlMsg::ControlAck { .. }
                    | CtrlMsg::MachineLoaded { .. }
                    | CtrlMsg::MachineRefused { .. } => {}
                }
            }
            let silent = last_heard.elapsed();
            if silent > LINK_TIMEOUT {
                bail!("link lost: no answer from the controller for {LINK_TIMEOUT:?}");
            }
            if silent > RESEND_AFTER && sent > acked {
                self.stats.resent += (sent - acked) as u64;
                sent = acked;
                last_heard = Instant::now() - RESEND_AFTER / 2;
            }
        }
        self.next_seq = base.wrapping_add(total as u16);
        loop {
            let s = self.request_status()?;
            progress(&s);
            if s.state == State::Alarm {
                return Ok(JobEnd::Alarm);
            }
            if s.state == State::Idle && s.blocks_done as usize >= total {
                return Ok(JobEnd::Done);
            }
            std::thread::sleep(POLL_EVERY);
        }
    }
}
