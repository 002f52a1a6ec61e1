//! The protocol client: handshake, machine transfer, frames in and out, control
//! commands, status requests, and waiting for the controller to come to rest.

use super::hooks::{JobEnd, JobHooks, LinkView};
use super::stall::StallGuard;
use super::{
    Link, LinkError, LinkOptions, Transport, CONTROL_RESEND_AFTER, HELLO_RESEND_AFTER, READ_WAIT,
    REASK_AFTER_DAMAGE, STALL_TICKS,
};
use pkmc::config::MachineConfig;
use pkmc::wire::{
    decode_frame, encode_frame, Control, CtrlMsg, FrameReader, HostMsg, NakReason, Pushed, State,
    Status, MAX_BODY, MAX_FRAME, PROTOCOL_VERSION,
};
use std::collections::VecDeque;
use std::time::{Duration, Instant};

#[derive(Clone, Copy, Debug)]
pub(super) struct PendingControl {
    pub(super) id: u16,
    pub(super) cmd: Control,
    pub(super) sent_at: Option<Instant>,
}

impl<T: Transport> Link<T> {
    /// The machine this link runs.
    pub fn machine(&self) -> &MachineConfig {
        &self.machine
    }

    /// Opens a session on `io` for `machine`: sends `Hello` until `HelloAck` arrives;
    /// when the controller has another machine, sends it ours and waits until it is
    /// loaded (the controller refuses to move until then).
    pub fn connect(io: T, machine: &MachineConfig, opts: LinkOptions) -> Result<Self, LinkError> {
        let mut link = Self::handshake(io, machine, opts)?;
        if link.their_machine != pkmc::wire::store::identity(machine) {
            link.send_machine(machine)?;
        }
        Ok(link)
    }

    pub(super) fn handshake(
        io: T,
        machine: &MachineConfig,
        opts: LinkOptions,
    ) -> Result<Self, LinkError> {
        let ours = pkmc::wire::store::identity(machine);
        let now = Instant::now();
        let mut link = Link {
            io,
            opts,
            reader: FrameReader::new(),
            rx: vec![0; 65536],
            tx: Vec::with_capacity(65536),
            next_seq: 1,
            capacity: 0,
            last_heard: now,
            last_bytes: now,
            last_pump: now,
            last_gap_end: now,
            last_request: now,
            next_control_id: 1,
            controls: VecDeque::new(),
            control: None,
            acked_control: None,
            machine_answer: None,
            probe_result: None,
            streamed: Vec::new(),
            arming: None,
            stashed: Vec::new(),
            status: None,
            stats: super::ClientStats::default(),
            their_machine: 0,
            held: None,
            held_mark: None,
            axis_vmax: core::array::from_fn(|i| machine.axes[i].max_velocity),
            machine: machine.clone(),
        };
        let start = Instant::now();
        while !link.given_up(start) {
            link.queue(
                0,
                &HostMsg::Hello {
                    version: PROTOCOL_VERSION,
                    machine: ours,
                    host: std::process::id(),
                },
            )?;
            link.flush()?;
            let until = Instant::now() + HELLO_RESEND_AFTER;
            while Instant::now() < until {
                for msg in link.pump(READ_WAIT)? {
                    match msg {
                        CtrlMsg::HelloAck {
                            version,
                            queue_capacity,
                            held,
                            mark,
                            machine,
                        } => {
                            link.held = held;
                            link.held_mark = mark;
                            if version != PROTOCOL_VERSION {
                                return Err(LinkError::Version {
                                    port: link.io.name().into(),
                                    theirs: Some(version),
                                });
                            }
                            link.capacity = queue_capacity;
                            link.their_machine = machine;
                            return Ok(link);
                        }
                        CtrlMsg::Nak {
                            reason: NakReason::Version,
                            ..
                        } => {
                            return Err(LinkError::Version {
                                port: link.io.name().into(),
                                theirs: None,
                            })
                        }
                        _ => {}
                    }
                }
            }
        }
        Err(LinkError::NoAnswer {
            port: link.io.name().into(),
            waited: start.elapsed(),
        })
    }

    /// The transport (e.g. to read the in-process simulator after a check).
    pub fn transport(&self) -> &T {
        &self.io
    }

    /// The transport, to act on (a simulator's clock: its ticks at rest).
    pub fn transport_mut(&mut self) -> &mut T {
        &mut self.io
    }

    /// Gives the transport back.
    pub fn into_transport(self) -> T {
        self.io
    }

    /// The unfinished job of an earlier host that the controller held when this link
    /// opened, if any (see `nc-send resume` and `abort`).
    pub fn held(&self) -> Option<pkmc::wire::HeldJob> {
        self.held
    }

    /// An error naming the held job, if one is held: a new job or move is refused
    /// rather than queued behind it.
    pub fn refuse_if_held(&self) -> Result<(), LinkError> {
        match self.held {
            Some(job) => Err(LinkError::JobHeld {
                port: self.port(),
                job,
            }),
            None => Ok(()),
        }
    }

    /// The held job's program and how far the controller received it, if it was
    /// streamed with a mark (`Control::BeginJob`).
    pub fn held_mark(&self) -> Option<pkmc::wire::JobMark> {
        self.held.and(self.held_mark)
    }

    /// What the next jobs' `Control::BeginJob` says: the host timeout (`None`: no
    /// `BeginJob`, the short link watch of MDI and jogs) and the program's mark.
    pub fn set_program(&mut self, host_timeout: Option<Duration>, mark: pkmc::wire::JobMark) {
        self.opts.host_timeout = host_timeout;
        self.opts.mark = mark;
    }

    /// Marks the held job as dealt with (resumed or aborted by this host).
    pub fn release_held(&mut self) {
        self.held = None;
        self.held_mark = None;
    }

    /// Block-queue capacity the controller announced.
    pub fn capacity(&self) -> u16 {
        self.capacity
    }

    pub(super) fn port(&self) -> String {
        self.io.name().to_string()
    }

    /// Appends a frame to the transmit buffer.
    pub(super) fn queue(&mut self, seq: u16, msg: &HostMsg) -> Result<(), LinkError> {
        let mut frame = [0u8; MAX_FRAME];
        let n = encode_frame(seq, msg, &mut frame).map_err(|e| LinkError::Frame {
            port: self.port(),
            what: format!("{msg:?} ({e:?})"),
        })?;
        self.tx.extend_from_slice(&frame[..n]);
        self.stats.frames_sent += 1;
        self.stats.bytes_sent += n as u64;
        Ok(())
    }

    /// Writes what the port takes now, without blocking for long.
    pub(super) fn flush_some(&mut self) -> Result<(), LinkError> {
        if self.tx.is_empty() {
            return Ok(());
        }
        let n = self
            .io
            .write_some(&self.tx, Duration::from_millis(1))
            .map_err(|source| LinkError::Io {
                port: self.port(),
                op: "write",
                source,
            })?;
        self.tx.drain(..n);
        Ok(())
    }

    /// Writes the whole transmit buffer (reading meanwhile, so neither side stalls).
    pub(super) fn flush(&mut self) -> Result<(), LinkError> {
        let start = Instant::now();
        while !self.tx.is_empty() {
            self.flush_some()?;
            if !self.tx.is_empty() {
                // A gap of our own: the port had no chance to take the bytes.
                if self.since(start).elapsed() > self.opts.link_timeout {
                    return Err(LinkError::Lost {
                        port: self.port(),
                        silent: start.elapsed(),
                        waited: start.elapsed(),
                        during: "writing",
                    });
                }
                let msgs = self.pump(Duration::ZERO)?;
                self.absorb(&msgs);
            }
        }
        Ok(())
    }

    /// Control acknowledgements and machine answers from messages read outside a job
    /// loop.
    pub(super) fn absorb(&mut self, msgs: &[CtrlMsg]) {
        for m in msgs {
            match m {
                CtrlMsg::ControlAck { id } => self.acked_control = Some(*id),
                CtrlMsg::MachineLoaded { .. } | CtrlMsg::MachineRefused { .. } => {
                    self.machine_answer = Some(m.clone())
                }
                CtrlMsg::Probe(r) => self.probe_result = Some(*r),
                CtrlMsg::Record(bytes) => self.keep_streamed(bytes),
                _ => {}
            }
        }
    }

    /// Sends `machine` in chunks, each resent until acknowledged, and waits for the
    /// controller to load it.
    pub(super) fn send_machine(&mut self, machine: &MachineConfig) -> Result<(), LinkError> {
        let mut payload = [0u8; pkmc::wire::store::MAX_CONFIG_BYTES];
        let n =
            pkmc::wire::store::encode(machine, &mut payload).ok_or_else(|| LinkError::Frame {
                port: self.port(),
                what: "the machine configuration (too large)".into(),
            })?;
        let crc = pkmc::wire::crc::crc32(&payload[..n]);
        self.machine_answer = None;
        for off in (0..n).step_by(pkmc::wire::store::CHUNK_BYTES) {
            let end = (off + pkmc::wire::store::CHUNK_BYTES).min(n);
            let id = self.fresh_control_id();
            let data =
                heapless::Vec::from_slice(&payload[off..end]).map_err(|_| LinkError::Frame {
                    port: self.port(),
                    what: "a machine chunk".into(),
                })?;
            let msg = HostMsg::Machine {
                id,
                offset: off as u16,
                total: n as u16,
                crc,
                data,
            };
            self.until_acked(id, &msg, "sending the machine configuration")?;
        }
        let start = Instant::now();
        loop {
            match self.machine_answer.take() {
                Some(CtrlMsg::MachineLoaded { machine }) if machine == crc => {
                    self.their_machine = machine;
                    return Ok(());
                }
                Some(CtrlMsg::MachineRefused { error }) => {
                    return Err(LinkError::MachineRefused {
                        port: self.port(),
                        error: error.to_string(),
                    })
                }
                _ => {}
            }
            if self.since(start).elapsed() > self.opts.link_timeout {
                return Err(self.lost("waiting for the controller to load the machine", start));
            }
            let msgs = self.pump(READ_WAIT)?;
            self.absorb(&msgs);
        }
    }

    /// Sends `msg` (a control command or machine chunk carrying `id`) until
    /// `ControlAck { id }` arrives.
    pub(super) fn until_acked(
        &mut self,
        id: u16,
        msg: &HostMsg,
        during: &'static str,
    ) -> Result<(), LinkError> {
        let start = Instant::now();
        let mut first = true;
        loop {
            self.queue(0, msg)?;
            if !std::mem::take(&mut first) {
                self.stats.controls_resent += 1;
            }
            self.flush()?;
            let until = Instant::now() + CONTROL_RESEND_AFTER;
            while Instant::now() < until {
                let msgs = self.pump(READ_WAIT)?;
                self.absorb(&msgs);
                if self.acked_control == Some(id) {
                    return Ok(());
                }
            }
            if self.given_up(start) {
                return Err(self.lost(during, start));
            }
        }
    }

    /// Reads what has arrived (waiting up to `wait` for it) and decodes it. After a
    /// gap of the client's own ([`super::OWN_GAP`]) the silence timers start again and
    /// a status is asked for at once: the controller is probed again before any
    /// silence counts against it.
    pub(super) fn pump(&mut self, wait: Duration) -> Result<Vec<CtrlMsg>, LinkError> {
        // Stopped between two reads, or inside the read (a read never takes much
        // longer than its wait).
        self.own_gap(self.last_pump.elapsed())?;
        let read_at = Instant::now();
        let n = self
            .io
            .read_some(&mut self.rx, wait)
            .map_err(|source| LinkError::Io {
                port: self.io.name().to_string(),
                op: "read",
                source,
            })?;
        let mut msgs = Vec::new();
        for &b in &self.rx[..n] {
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
        self.own_gap(read_at.elapsed().saturating_sub(wait))?;
        self.last_pump = Instant::now();
        if n > 0 {
            self.last_bytes = Instant::now();
        }
        if !msgs.is_empty() {
            self.last_heard = Instant::now();
            self.stats.frames_received += msgs.len() as u64;
        }
        for m in &msgs {
            if let CtrlMsg::Status(s) = m {
                self.status = Some(s.clone());
            }
        }
        Ok(msgs)
    }

    pub(super) fn lost(&self, during: &'static str, since: Instant) -> LinkError {
        LinkError::Lost {
            port: self.port(),
            silent: self.last_heard.elapsed(),
            waited: since.elapsed(),
            during,
        }
    }

    /// Has a request made at `start` waited long enough? After the link timeout when
    /// nothing has arrived for that long; while bytes keep arriving (a live controller
    /// on a damaged line: the answer may get through), up to ten times it.
    pub(super) fn given_up(&self, start: Instant) -> bool {
        let t = self.opts.link_timeout;
        let waited = self.since(start).elapsed();
        waited > t && (self.last_bytes.elapsed() > t || waited > t * 10)
    }

    /// When a wait that began at `start` began, as far as the controller can be
    /// blamed: not before the end of the client's last gap of its own
    /// ([`super::OWN_GAP`]).
    pub(super) fn since(&self, start: Instant) -> Instant {
        start.max(self.last_gap_end)
    }

    /// Asks for and waits for a fresh status. The request is repeated every
    /// keepalive; sooner (but not within [`REASK_AFTER_DAMAGE`]) once a damaged frame
    /// has arrived since it was sent, since that frame may have been its answer: on a
    /// noisy line a long status frame often arrives damaged, and waiting out the
    /// keepalive after each made a finished job's last status take seconds.
    pub fn request_status(&mut self) -> Result<Status, LinkError> {
        let start = Instant::now();
        loop {
            self.queue(0, &HostMsg::StatusRequest)?;
            self.stats.status_requests += 1;
            self.flush()?;
            let asked = Instant::now();
            let damaged_before = self.stats.corrupt_received;
            let until = asked + self.opts.keepalive.max(Duration::from_millis(50));
            while Instant::now() < until {
                let msgs = self.pump(READ_WAIT)?;
                self.absorb(&msgs);
                for m in msgs {
                    if let CtrlMsg::Status(s) = m {
                        return Ok(s);
                    }
                }
                if self.stats.corrupt_received > damaged_before
                    && asked.elapsed() >= REASK_AFTER_DAMAGE
                {
                    break;
                }
            }
            if self.given_up(start) {
                return Err(self.lost("waiting for a status", start));
            }
        }
    }

    /// A fresh status, and the last probing move's result (`None` before any): the
    /// controller sends the result after the status that answers a request; asked
    /// again until the result the status counts has come.
    pub fn request_probe(
        &mut self,
    ) -> Result<(Status, Option<pkmc::drive::probe::ProbeResult>), LinkError> {
        let start = Instant::now();
        loop {
            let s = self.request_status()?;
            if s.probes == 0 {
                return Ok((s, None));
            }
            let until = Instant::now() + Duration::from_millis(200);
            loop {
                if let Some(r) = self.probe_result.filter(|r| r.count == s.probes) {
                    return Ok((s, Some(r)));
                }
                if Instant::now() >= until {
                    break;
                }
                let msgs = self.pump(READ_WAIT)?;
                self.absorb(&msgs);
            }
            if self.given_up(start) {
                return Err(self.lost("waiting for a probe result", start));
            }
        }
    }

    /// Sends one control command and waits for its acknowledgement.
    pub fn control(&mut self, cmd: Control) -> Result<(), LinkError> {
        let id = self.fresh_control_id();
        self.stats.controls += 1;
        self.until_acked(
            id,
            &HostMsg::Control { id, cmd },
            "waiting for a control acknowledgement",
        )
    }

    pub(super) fn fresh_control_id(&mut self) -> u16 {
        let id = self.next_control_id;
        self.next_control_id = self.next_control_id.wrapping_add(1).max(1);
        id
    }

    /// The stall guard on status `s` (simulators only): an error once the controller
    /// has been moving without progress for [`STALL_TICKS`] plus `allowance` ticks.
    pub(super) fn check_stall(
        &self,
        guard: &mut StallGuard,
        s: &Status,
        allowance: u64,
    ) -> Result<(), LinkError> {
        let Some(now) = self.io.sim_ticks() else {
            return Ok(());
        };
        let still = guard.observe(s, now);
        if still <= STALL_TICKS + allowance {
            return Ok(());
        }
        Err(LinkError::Stalled {
            port: self.port(),
            line: s.line,
            state: s.state,
            still: Duration::from_nanos(still * pkmc::units::TICK_NS as u64),
        })
    }

    /// Waits until the controller is at rest: idle with an empty queue (`Done`), or in
    /// alarm. `hooks` sees every status.
    /// The operator's controls from `hooks` are sent on the way; after an `Abort` the
    /// end is `Aborted`, after a `Stop` it is `Stopped`. On a simulator, a controller
    /// moving without progress is an error ([`LinkError::Stalled`]).
    pub fn wait_idle(&mut self, hooks: &mut dyn JobHooks) -> Result<JobEnd, LinkError> {
        self.wait_until_idle(hooks, false)
    }

    /// Waits for a job resumed with `Resume` (no host streams it): until it ends, as
    /// [`Link::wait_idle`], or until it stops at rest in a later pause
    /// ([`JobEnd::Paused`]) instead of waiting for an operator this host does not have.
    pub fn wait_resumed(&mut self, hooks: &mut dyn JobHooks) -> Result<JobEnd, LinkError> {
        self.wait_until_idle(hooks, true)
    }

    pub(super) fn wait_until_idle(
        &mut self,
        hooks: &mut dyn JobHooks,
        end_at_pause: bool,
    ) -> Result<JobEnd, LinkError> {
        let mut ended_by = None;
        let mut guard = StallGuard::default();
        loop {
            let s = self.request_status()?;
            hooks.status(&s);
            hooks.recorded(&mut self.streamed);
            self.check_stall(&mut guard, &s, 0)?;
            let view = LinkView {
                status: Some(s.clone()),
                ..LinkView::default()
            };
            if let Some(cmd) = hooks.control(&view) {
                self.control(cmd)?;
                if matches!(cmd, Control::Abort | Control::Stop) {
                    ended_by = Some(cmd);
                }
                continue;
            }
            if let Some(setup) = hooks.record_arm() {
                self.streamed.clear();
                match self.record_arm(&setup) {
                    Ok(()) => hooks.record_armed(None),
                    Err(LinkError::Recorder { error, .. }) => {
                        hooks.record_armed(Some(error.to_string()))
                    }
                    Err(e) => return Err(e),
                }
            }
            if matches!(s.state, State::Alarm | State::EStop) && s.speed == 0 {
                if ended_by == Some(Control::Stop) {
                    return Ok(JobEnd::Stopped);
                }
                if let Some(a) = s.alarm {
                    return Ok(JobEnd::Alarm(a));
                }
            }
            if end_at_pause && ended_by.is_none() && s.state == State::Hold && s.speed == 0 {
                return Ok(JobEnd::Paused(s.line));
            }
            if s.state == State::Idle
                && s.speed == 0
                && s.free_slots == self.capacity
                && s.buffered_ms == 0
            {
                return Ok(match ended_by {
                    Some(_) => JobEnd::Aborted,
                    None => JobEnd::Done,
                });
            }
            if self.io.sim_ticks().is_some() {
                // A simulated clock advances only while it is read: let it run to its
                // next status (an in-process controller answers a status request at
                // once, without ticking, so asking again would never move it).
                self.pump(Duration::from_millis(10))?;
            } else {
                std::thread::sleep(Duration::from_millis(10));
            }
        }
    }
}
