//! Whole programs recorded on the host, call by call, for the emulator to replay
//! (`python3 .ci/m4count.py`, the whole-call section of `docs/performance.md`).
//!
//! Each program ([`crate::programs`]: generated G-code and report B's example helices)
//! is compiled by the host's G-code front end as `nc-send` compiles a file
//! ([`pkmc_host::job::compile_text`]: parser, canonical commands, blocks, pre-flight
//! against the machine's reach), and streamed by `nc-send`'s own link client as
//! `nc-send --check` streams it:
//! [`Link::connect`], [`pkmc_host::job::prepare`] (which unlocks the controller),
//! [`Link::run_job`] and a last status request, with the default [`LinkOptions`]. The
//! client talks to a [`Simulator`] in this process through [`Recorder`], a transport
//! that stands for the board's USB link and logs every call into the controller, in
//! order, with its arguments and results:
//!
//! * `receive(bytes)`: the host's writes cut into USB full-speed bulk packets of at
//!   most [`USB_PACKET`] bytes, one call per packet, as the firmware's link task calls
//!   it (`src/bin/firmware/main.rs`: one `receive` per `read_packet`);
//! * `tick(&inputs)`: the inputs exactly as [`Simulator::tick`] passed them (read back
//!   through [`Simulator::last_inputs`]) and the controller's outputs;
//! * `transmit(buf)`: the controller's transmit buffer drained into buffers of
//!   [`USB_PACKET`] bytes until a call returns 0, after every packet received and
//!   after every tick, as the firmware's `drain` does; the bytes each call returned.
//!
//! Link timing. Like `nc-send --check` ([`pkmc_host::link::InProcess`]), simulated
//! time advances only while the controller has work (or when the link holds bytes back,
//! below), and a read runs ticks until the controller has something to say. Unlike it,
//! a write is not handed to the controller at once: between two ticks the link carries
//! at most [`USB_PACKETS_PER_TICK`] packets and [`FRAMES_PER_TICK`] frames; the
//! rest waits for the next tick (the write returns short, and the client writes the rest
//! later, as with a real port). The frame limit is the streaming rate (10 000
//! blocks/s); without it the client's first write (the queue's 64 free slots at once)
//! would put all of them into one period, which no link can do in 1 ms (USB full speed
//! carries about 30 block frames of 36–46 bytes per millisecond).
//!
//! Data recorder. A program may arm the recorder before its job (`Program::record`,
//! [`Link::record_arm`]); in continuous mode the controller streams pieces of samples
//! beside the job, which the client keeps ([`Link::record_take`]: the recording checks
//! that they came). Sampling every servo period, the simulator hands each tick's
//! servo-period samples to the controller after the tick in two calls, as the firmware
//! does under the same lock ([`Simulator::last_servo_record`]); they are logged too.
//!
//! Log (little-endian), one file per program: the magic `PKMC-M4-CALLS-3` (2: the
//! tick's outputs carry the contour map; 3: the tick's inputs carry the recorder's DAC
//! means and contour error, its outputs the servo-side signals, and `S` records), then
//! records until the end of the file:
//!
//! * `R` `len: u16` `bytes[len]`: `receive(bytes)`;
//! * `T` `inputs: [i64; INPUT_WORDS]` `outputs: [i64; OUTPUT_WORDS]`: `tick`, its
//!   inputs and outputs flattened by [`crate::wire`];
//! * `S` `ids: [u8; MAX_SIGNALS]` `n: u8` `rows: [Row; n]` (packed samples, 32 bytes each):
//!   `record_servo(ids, rows)` after the tick before it;
//! * `X` `n: u16` `bytes[n]`: `transmit` into a [`USB_PACKET`]-byte buffer returned `n`.

use crate::programs::{programs, Program};
use crate::wire;
use pkmc::config::MachineConfig;
use pkmc::controller::Controller;
use pkmc::wire::Control;
use pkmc::wire::State;
use pkmc_host::job::{compile_compressed, prepare};
use pkmc_host::link::{JobEnd, JobHooks, Link, LinkOptions, LinkView, NoHooks, Transport};
use pkmc_host::sim::Simulator;
use pkmc_host::sim::{FaultKind, Injection};
use std::io;
use std::path::Path;
use std::time::Duration;

/// Bytes of a USB full-speed bulk packet: the most one `receive` or `transmit` call
/// of the firmware handles.
pub const USB_PACKET: usize = 64;
/// Packets USB full speed carries at most in one 1 ms frame (19 bulk packets of 64
/// bytes).
pub const USB_PACKETS_PER_TICK: usize = 19;
/// Frames the link delivers at most between two ticks: the streaming rate of 10 000
/// blocks/s that the period budget assumes (issue 9).
pub const FRAMES_PER_TICK: usize = 10;
/// Magic at the start of a log.
pub const MAGIC: &[u8] = b"PKMC-M4-CALLS-3";
/// Most ticks one read runs before returning empty-handed (as `InProcess`).
const TICKS_PER_READ: u32 = 10_000;

/// Calls of one recording.
#[derive(Clone, Copy, Debug, Default)]
pub struct Counts {
    /// `tick` calls.
    pub ticks: u64,
    /// `receive` calls (packets).
    pub packets: u64,
    /// Frames delivered (frame delimiters received).
    pub frames: u64,
    /// `transmit` calls.
    pub transmits: u64,
    /// `record_servo` calls.
    pub record_servo: u64,
}

/// The recording transport: the link to a simulated controller, logging every call
/// into it. See the module documentation.
pub struct Recorder {
    /// The simulated controller.
    pub sim: Simulator,
    /// The log so far.
    pub log: Vec<u8>,
    /// Calls made.
    pub counts: Counts,
    /// Bytes the controller transmitted that the client has not read yet.
    rx: Vec<u8>,
    /// Packets and frames the link may still carry before the next tick.
    packets_left: usize,
    frames_left: usize,
    /// The last write was cut short by the link's rate: the next read runs a tick.
    held_back: bool,
}

impl Recorder {
    /// Wraps `sim`, with the controller's link-loss watch off, as `InProcess` does
    /// (simulated time runs far ahead of the client's wall-clock heartbeat).
    pub fn new(mut sim: Simulator) -> Self {
        sim.ctrl.set_link_watch(false);
        Self {
            sim,
            log: MAGIC.to_vec(),
            counts: Counts::default(),
            rx: Vec::new(),
            packets_left: USB_PACKETS_PER_TICK,
            frames_left: FRAMES_PER_TICK,
            held_back: false,
        }
    }

    /// One `receive` call with one packet.
    fn receive(&mut self, packet: &[u8]) {
        self.log.push(b'R');
        self.log
            .extend_from_slice(&(packet.len() as u16).to_le_bytes());
        self.log.extend_from_slice(packet);
        self.sim.ctrl.receive(packet);
        self.counts.packets += 1;
    }

    /// Drains the controller's transmit buffer in packets, as the firmware does.
    fn drain(&mut self) {
        loop {
            let mut buf = [0u8; USB_PACKET];
            let n = self.sim.ctrl.transmit(&mut buf);
            self.log.push(b'X');
            self.log.extend_from_slice(&(n as u16).to_le_bytes());
            self.log.extend_from_slice(&buf[..n]);
            self.counts.transmits += 1;
            self.rx.extend_from_slice(&buf[..n]);
            if n == 0 {
                break;
            }
        }
    }

    /// One simulator tick (one `tick` call), then a drain; the link's budget renews.
    fn tick(&mut self) -> io::Result<()> {
        self.sim.tick().map_err(io::Error::other)?;
        let inputs = *self.sim.last_inputs();
        let words = wire::inputs_words(&inputs);
        if wire::inputs_from(&words) != inputs {
            return Err(io::Error::other(format!(
                "the tick inputs do not survive the log's words: {inputs:?}"
            )));
        }
        self.log.push(b'T');
        for w in words.iter().chain(&wire::outputs_words(
            self.sim.last_outputs(),
            self.sim.last_map(),
        )) {
            self.log.extend_from_slice(&w.to_le_bytes());
        }
        self.counts.ticks += 1;
        for (ids, rows) in self.sim.last_servo_record() {
            self.log.push(b'S');
            self.log.extend_from_slice(ids);
            self.log.push(rows.len() as u8);
            for row in rows {
                self.log.extend_from_slice(row);
            }
            self.counts.record_servo += 1;
        }
        self.packets_left = USB_PACKETS_PER_TICK;
        self.frames_left = FRAMES_PER_TICK;
        self.drain();
        Ok(())
    }

    /// Hands over what the controller transmitted, as far as `buf` takes it.
    fn hand_over(&mut self, buf: &mut [u8]) -> usize {
        let n = self.rx.len().min(buf.len());
        buf[..n].copy_from_slice(&self.rx[..n]);
        self.rx.drain(..n);
        n
    }
}

impl Transport for Recorder {
    fn name(&self) -> &str {
        "recorded in-process simulator"
    }

    /// The simulated clock, as `InProcess` gives it: a client waiting for the machine
    /// (a probing move, [`pkmc_host::link::Link::wait_idle`]) reads to let it run.
    fn sim_ticks(&self) -> Option<u64> {
        Some(self.sim.ticks)
    }

    fn write_some(&mut self, bytes: &[u8], _wait: Duration) -> io::Result<usize> {
        let mut taken = 0;
        while taken < bytes.len() && self.packets_left > 0 && self.frames_left > 0 {
            let mut end = (taken + USB_PACKET).min(bytes.len());
            // A packet ends early after the last frame the link may still carry.
            let mut frames = 0;
            for (i, &b) in bytes[taken..end].iter().enumerate() {
                if b == 0 {
                    frames += 1;
                    if frames == self.frames_left {
                        end = taken + i + 1;
                        break;
                    }
                }
            }
            let packet = &bytes[taken..end];
            self.receive(packet);
            self.counts.frames += frames as u64;
            self.frames_left -= frames;
            self.packets_left -= 1;
            taken = end;
            self.drain();
        }
        self.held_back = taken < bytes.len();
        // As `InProcess`: a held controller with a command taking effect on the next
        // tick (an abort finishing a hold) gets that tick.
        if self.sim.ctrl.state() == State::Hold && !self.sim.ctrl.has_work() {
            self.tick()?;
        }
        Ok(taken)
    }

    fn read_some(&mut self, buf: &mut [u8], _wait: Duration) -> io::Result<usize> {
        if !self.rx.is_empty() {
            return Ok(self.hand_over(buf));
        }
        if self.held_back {
            // The client is waiting for the link: a period passes.
            self.held_back = false;
            self.tick()?;
            return Ok(self.hand_over(buf));
        }
        for _ in 0..TICKS_PER_READ {
            if !self.sim.busy() {
                return Ok(0);
            }
            self.tick()?;
            if !self.rx.is_empty() {
                return Ok(self.hand_over(buf));
            }
        }
        Ok(0)
    }
}

/// The operator of the `events` programs: at these motion times (ticks, as the
/// controller's status reports them) a hold, a resume once the hold has stopped the
/// machine (`None`: when the status shows it held at rest), feed overrides of 50 %,
/// 150 % and 100 %; then the e-stop at [`EVENTS_ESTOP_S`] of simulated time.
const OPERATOR_EVENTS: [(Option<u64>, Control); 5] = [
    (Some(300), Control::Hold),
    (None, Control::Resume),
    (Some(600), Control::FeedOverride(50)),
    (Some(800), Control::FeedOverride(150)),
    (Some(1000), Control::FeedOverride(100)),
];

/// When the `events` programs' e-stop trips, s of simulated time (plus the program's
/// lead, [`Program::lead_ticks`]).
const EVENTS_ESTOP_S: f64 = 1.4;

/// Sends [`OPERATOR_EVENTS`] as their times come, `lead` ticks later (nothing when
/// `on` is false).
struct Operator {
    on: bool,
    lead: u64,
    next: usize,
}

impl Operator {
    fn new(on: bool, lead: u64) -> Self {
        Self { on, lead, next: 0 }
    }
}

impl JobHooks for Operator {
    fn control(&mut self, link: &LinkView) -> Option<Control> {
        let (at, cmd) = *OPERATOR_EVENTS.get(self.next).filter(|_| self.on)?;
        let status = link.status.as_ref()?;
        let due = match at {
            Some(t) => status.motion_ticks >= t + self.lead,
            None => status.state == State::Hold && status.speed == 0,
        };
        if link.control_pending || !due {
            return None;
        }
        self.next += 1;
        Some(cmd)
    }
}

/// The machine files `nc-send` would be given for machine `m`.
fn machine_file(m: u32) -> std::path::PathBuf {
    let name = match m {
        0 => "h4-table",
        1 => "hexapod",
        _ => "hexapod-xy",
    };
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../examples/machines")
        .join(format!("{name}.toml"))
}

/// Records `p` as `nc-send --check` would run it; returns the log and the calls made.
pub fn record(p: &Program) -> Result<(Vec<u8>, Counts, usize), String> {
    let machine: MachineConfig = crate::machine(p.machine);
    // The emulated controller is built from the built-in configuration; it must be
    // the machine file's.
    let file = machine_file(p.machine);
    let loaded = pkmc_host::machine_file::load(&file).map_err(|e| format!("{e:#}"))?;
    if loaded != machine {
        return Err(format!(
            "{} differs from the built-in machine",
            file.display()
        ));
    }
    // As `nc-send --g64-tolerance 0` compiles a file: runs of short moves in G64 P
    // merged into curves, and those in G64 without P streamed as programmed (merged
    // within 1 µm by default, the dense G64 sines would be curves; they stand for the
    // dense blocks a sender can still stream, the P0.01 sines for curves).
    let settings = pkmc_host::gcode::compress::Settings {
        g64_tolerance_nm: 0.0,
        ..Default::default()
    };
    let blocks = if p.probe.is_some() {
        Vec::new()
    } else {
        compile_compressed(
            &p.text,
            &p.name,
            &machine,
            machine.home,
            &Default::default(),
            Some(&settings),
        )
        .map_err(|e| e.message)?
        .blocks
    };
    // As `nc-send --machine FILE` simulates it: the servo joints' plants are the file's
    // (the hexapod-xy's: the report's identified plants; the H-4 and the hexapod give
    // none, the simulator's default).
    let plants = pkmc_host::machine_file::load_plants(&file).map_err(|e| format!("{e:#}"))?;
    let mut sim = Simulator::with_plants(machine.clone(), plants, [0; pkmc::config::MAX_JOINTS])
        .map_err(|e| format!("{e:#}"))?;
    if p.events {
        sim.inject(&[Injection {
            kind: FaultKind::EStop,
            joint: None,
            at_s: EVENTS_ESTOP_S + p.lead_ticks as f64 / 1000.0,
        }])
        .map_err(|e| format!("{e:#}"))?;
    }
    if let Some((centre, radius)) = p.probe {
        use pkmc_host::sim::probe::{ProbeModel, Target};
        sim.set_probe(
            Some(ProbeModel {
                targets: vec![Target::Sphere { centre, radius }],
                noise_mm: 0.0005,
                delay_us: 20.0,
                seed: 1,
            }),
            None,
        )?;
    }
    let io = Recorder::new(sim);
    let mut link =
        Link::connect(io, &machine, LinkOptions::default()).map_err(|e| e.to_string())?;
    if let Some(setup) = &p.record {
        link.record_arm(setup).map_err(|e| e.to_string())?;
    }
    let mut hooks = Operator::new(p.events, p.lead_ticks);
    let mut sent = blocks.len();
    let end = match prepare(&mut link, false, true, &mut NoHooks).map_err(|e| e.message)? {
        Some(end) => end,
        // A program that probes: a stage at a time, as `nc-send` runs it.
        None if p.probe.is_some() => {
            let program = pkmc_host::job::probing::ProbingProgram {
                text: &p.text,
                name: &p.name,
                machine: &machine,
                start: machine.home,
                tools: &Default::default(),
                compress: Some(&settings),
            };
            let (end, found, n) = pkmc_host::job::probing::run_on(
                &mut link,
                &program,
                &mut pkmc_host::job::probing::Plain(&mut hooks),
            )
            .map_err(|e| e.message)?;
            if found.len() != 5 || found.iter().any(|r| !r.contact) {
                return Err(format!(
                    "{}: the probe did not touch 5 times: {found:?}",
                    p.name
                ));
            }
            sent = n;
            end
        }
        None => link
            .run_job(&blocks, &mut hooks)
            .map_err(|e| e.to_string())?,
    };
    let status = link.request_status().map_err(|e| e.to_string())?;
    let expected = if p.events {
        matches!(end, JobEnd::Alarm(a) if a.cause == pkmc::wire::AlarmCause::EStop)
            && status.state == State::EStop
            && hooks.next == OPERATOR_EVENTS.len()
    } else {
        end == JobEnd::Done && status.state == State::Idle
    };
    if !expected {
        return Err(format!(
            "{}: the job ended {end:?} in state {:?}",
            p.name, status.state
        ));
    }
    match &p.record {
        Some(setup) if setup.trigger == pkmc::drive::recorder::Trigger::Stream => {
            streamed_enough(p, setup, &mut link)?
        }
        Some(_) => {
            // A capture waiting for its trigger: still armed, its ring written.
            let (reply, _) = link.record_query(0).map_err(|e| e.to_string())?;
            let armed = reply.capture.phase == pkmc::drive::recorder::Phase::Armed;
            if !armed || reply.capture.samples == 0 {
                return Err(format!("{}: the recorder is {:?}", p.name, reply.capture));
            }
        }
        None => {}
    }
    let io = link.into_transport();
    Ok((io.log, io.counts, sent))
}

/// Checks that a recording program's stream came: pieces of its signals, at its
/// rate, holding most of the samples of the job's ticks (the link may lose some).
fn streamed_enough(
    p: &Program,
    setup: &pkmc::drive::recorder::Setup,
    link: &mut Link<Recorder>,
) -> Result<(), String> {
    let pieces = link.record_take();
    let samples: usize = pieces.iter().map(|piece| piece.samples.len()).sum();
    let ticks = link.transport().counts.ticks as usize;
    let per_tick = if setup.servo { 10 } else { 1 };
    let ok = pieces
        .iter()
        .all(|piece| piece.servo == setup.servo && piece.signals.len() == setup.count as usize);
    eprintln!(
        "pkmc-m4count: {}: {} streamed pieces, {samples} samples over {ticks} ticks",
        p.name,
        pieces.len()
    );
    if !ok || samples < ticks * per_tick / 2 {
        return Err(format!(
            "{}: the recorder streamed {samples} samples in {} pieces over {ticks} ticks",
            p.name,
            pieces.len()
        ));
    }
    Ok(())
}

/// Records every program into `dir` (one `NAME.calls` file each) and prints one line
/// per program: `program NAME MACHINE FILE BLOCKS TICKS PACKETS FRAMES TRANSMITS
/// SERVO REC`, SERVO the servo bench whose tick stands for the program's servo periods
/// in its 1 ms figure (`-`: the machine's bank, as `.ci/m4count.py` chooses it), REC
/// `armed` when the program arms the data recorder (else `-`).
pub fn record_all(dir: &Path) -> Result<(), String> {
    std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    for p in programs() {
        let (log, c, blocks) = record(&p)?;
        let path = dir.join(format!("{}.calls", p.name));
        std::fs::write(&path, &log).map_err(|e| format!("{}: {e}", path.display()))?;
        std::fs::write(dir.join(format!("{}.ngc", p.name)), &p.text)
            .map_err(|e| format!("{}: {e}", path.display()))?;
        println!(
            "program {} {} {} {blocks} {} {} {} {} {} {}",
            p.name,
            p.machine,
            path.display(),
            c.ticks,
            c.packets,
            c.frames,
            c.transmits,
            p.servo_bench.unwrap_or("-"),
            if p.record.is_some() { "armed" } else { "-" }
        );
    }
    // The controller's size on the host, for comparison with the target's.
    eprintln!(
        "pkmc-m4count: Controller is {} bytes on the host",
        core::mem::size_of::<Controller>()
    );
    Ok(())
}
