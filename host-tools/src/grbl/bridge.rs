//! The bridge's state: the sender's bytes and lines, the line-by-line front end, the
//! controls to send, and what is said back. [`Bridge`] is the job's hooks while a job
//! streams (lines keep arriving and are fed into the running job), and is driven by
//! [`super::serve`]'s loop between jobs.

use super::input::{Input, Item, RealTime};
use super::ports::{write_all_patiently, End, Event, Ports};
use super::words::{self, Mode, BLOCK_BUFFER, RX_BUFFER};
use super::Counts;
use crate::gcode::canon::Canon;
use crate::job::{LineFault, LinePipeline};
use crate::link::{JobHooks, LinkView};
use pkmc::config::{MachineConfig, AXES};
use pkmc::motion::block::Block;
use pkmc::wire::{Control, State, Status};
use std::collections::{HashMap, VecDeque};
use std::net::TcpStream;
use std::time::{Duration, Instant};

/// A job's feed is closed after this long with nothing to feed and the controller
/// idle with every block executed.
const CLOSE_AFTER: Duration = Duration::from_millis(60);
/// The longest a turn of a job's loop waits for the sender's next lines.
const SENDER_TURN: Duration = Duration::from_millis(3);

/// What a queued line is, for deciding where it may run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Needs {
    /// G-code or a `$` command answered from the bridge's own state.
    Nothing,
    /// A `$` command that acts on the controller (`$H`, `$X`, `$J=`, `$C`): only
    /// between jobs.
    Link,
}

/// Grbl 1.1's state as its `$` commands see it (`sys.state` in Grbl's
/// `system_execute_line`): what a `?` would report at that moment.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Phase {
    Idle,
    Alarm,
    Check,
    Jog,
    /// `Run`, `Hold`, `Home`: a cycle under way or held.
    Cycle,
}

pub(super) struct Bridge<'o> {
    pub(super) machine: &'o MachineConfig,
    pub(super) ports: Ports,
    tcp: HashMap<u32, TcpStream>,
    /// The sender that holds the bridge: the pseudo-terminal unless a TCP sender is
    /// connected.
    active: End,
    input: Input,
    /// Lines received and not yet answered, with their byte counts.
    pub(super) lines: VecDeque<(Item, usize)>,
    /// The sender's lines through the front end, their modal state kept.
    pub(super) pipeline: LinePipeline<'o>,
    /// Lines read since the start (the NC line numbers of the blocks).
    pub(super) line_no: u32,
    pub(super) status: Option<Status>,
    pub(super) controls: VecDeque<Control>,
    /// The feed override the sender set, %. The controller has it except during a
    /// jog, which runs at 100 % (see [`Bridge::real_time`]).
    pub(super) feed_override: u16,
    rapid_spindle: (u8, u8),
    pub(super) mode: Mode,
    /// A soft reset is to be carried out once the motion has stopped.
    pub(super) reset: bool,
    /// Blocks of the job running, and executed of them (from the job's view).
    job: Option<(usize, usize)>,
    last_busy: Instant,
    pub(super) startup: [String; 2],
    /// When each sender that does not hold the bridge was last told Busy.
    busy_told: HashMap<End, Instant>,
    /// Counters for the summary at exit.
    pub(super) counts: Counts,
    /// When the pseudo-terminal last sent a byte.
    pty_heard: Option<Instant>,
    /// Which sender started the job that is open.
    job_owner: Option<End>,
    /// Where the jogs accepted so far end (the next queued jog starts there).
    pub(super) jog_end: [i64; AXES],
    /// A homing cycle is under way (a reset then is Grbl's ALARM:6).
    pub(super) homing: bool,
    /// M6 holds for a manual tool change instead of Grbl 1.1's `error:20`.
    pub(super) tool_change: bool,
    /// `$130`–`$132`: the travel of X, Y and Z through the start pose, mm.
    pub(super) travel: [f64; 3],
    /// Ctrl-C: asked when the bridge should stop.
    stop: &'o dyn Fn() -> bool,
    /// Ctrl-C was seen: no more lines are taken.
    pub(super) stopping: bool,
    /// The held job was abandoned for Ctrl-C.
    stop_aborted: bool,
    /// The alarm last reported (`ALARM:N`), so that it is said once.
    pub(super) alarm_told: Option<pkmc::wire::Alarm>,
    /// Short moves held back for merging.
    pub(super) merge: super::merge::Merger,
    /// A probing move accepted, to run once the motion before it has ended
    /// ([`super::probe`]): the job's feed closes at it.
    pub(super) probe: Option<super::probe::Pending>,
    /// The last probe's result (`[PRB:…]`, `$#`).
    pub(super) last_probe: super::probe::Last,
}

/// A pseudo-terminal sender counts as present this long after its last byte (a
/// pseudo-terminal does not tell when its other end closes).
const PTY_PRESENT: Duration = Duration::from_secs(5);

/// Why G-code is refused during a jog (Grbl's `error:9`).
const JOG_LOCK: &str =
    "G-code is locked out while jogging: wait for the jog to end or cancel it (0x85)";

impl<'o> Bridge<'o> {
    pub(super) fn new(
        machine: &'o MachineConfig,
        ports: Ports,
        pipeline: LinePipeline<'o>,
        stop: &'o dyn Fn() -> bool,
    ) -> Self {
        let start = pipeline.interp().pos;
        Self {
            machine,
            ports,
            tcp: HashMap::new(),
            active: End::Pty,
            input: Input::default(),
            lines: VecDeque::new(),
            pipeline,
            line_no: 0,
            status: None,
            controls: VecDeque::new(),
            feed_override: 100,
            rapid_spindle: (100, 100),
            mode: Mode::default(),
            reset: false,
            job: None,
            last_busy: Instant::now(),
            startup: [String::new(), String::new()],
            busy_told: HashMap::new(),
            counts: Counts::default(),
            pty_heard: None,
            job_owner: None,
            jog_end: start,
            homing: false,
            tool_change: false,
            travel: words::max_travel(machine, &start),
            stop,
            stopping: false,
            stop_aborted: false,
            alarm_told: None,
            merge: super::merge::Merger::new(None, start),
            probe: None,
            last_probe: super::probe::Last::default(),
        }
    }

    /// Says `text` and a line break to the sender holding the bridge.
    pub(super) fn say(&mut self, text: &str) {
        let bytes = format!("{text}\r\n");
        match self.active {
            End::Pty => self.ports.write_pty(bytes.as_bytes()),
            End::Tcp(id) => {
                if let Some(s) = self.tcp.get_mut(&id) {
                    if !write_all_patiently(s, bytes.as_bytes()) {
                        self.tcp.remove(&id);
                        self.active = End::Pty;
                    }
                }
            }
        }
    }

    /// Reads what the senders sent, waiting up to `wait` for the first event;
    /// real-time commands act at once, lines are queued.
    pub(super) fn poll(&mut self, wait: Duration) {
        let mut first = true;
        loop {
            let ev = if first && !wait.is_zero() {
                self.ports.events.recv_timeout(wait).ok()
            } else {
                self.ports.events.try_recv().ok()
            };
            first = false;
            let Some(ev) = ev else {
                return;
            };
            match ev {
                Event::Connected(id, stream) => {
                    self.tcp.insert(id, stream);
                    if self.active == End::Pty && !self.pty_holds() {
                        self.take_over(End::Tcp(id));
                    } else if let Some(s) = self.tcp.get_mut(&id) {
                        let msg = "[MSG:Busy: another sender holds this bridge]\r\n";
                        write_all_patiently(s, msg.as_bytes());
                    }
                }
                Event::Closed(id) => {
                    self.tcp.remove(&id);
                    if self.active == End::Tcp(id) {
                        self.active = End::Pty;
                        self.input.clear();
                    }
                }
                Event::Bytes(end, bytes) if end == self.active => {
                    if end == End::Pty {
                        self.pty_heard = Some(Instant::now());
                    }
                    self.bytes(&bytes)
                }
                Event::Bytes(End::Tcp(id), bytes)
                    if self.active == End::Pty && !self.pty_holds() =>
                {
                    // A TCP sender told Busy before, now that the pseudo-terminal's
                    // sender has gone quiet: it takes the bridge.
                    self.take_over(End::Tcp(id));
                    self.bytes(&bytes);
                }
                Event::Bytes(end, _) => self.tell_busy(end),
            }
        }
    }

    /// Does the pseudo-terminal's sender hold the bridge? While it has been heard
    /// lately, or while a job it started is moving.
    fn pty_holds(&self) -> bool {
        let moving = self.job_owner == Some(End::Pty)
            && self
                .status
                .as_ref()
                .is_some_and(|s| s.state != State::Hold || s.speed != 0);
        self.pty_heard.is_some_and(|t| t.elapsed() < PTY_PRESENT) || moving
    }

    /// `end` becomes the sender holding the bridge: the banner, and a word about a
    /// job the previous sender left.
    fn take_over(&mut self, end: End) {
        self.active = end;
        self.input.clear();
        self.lines.clear();
        self.say(&words::banner());
        if let Some((total, done)) = self.job {
            let line = self.status.as_ref().map_or(0, |s| s.line);
            let state = match self.status.as_ref() {
                Some(s) if s.state == State::Hold => "is held",
                _ => "is running",
            };
            let ahead = total.saturating_sub(done);
            self.say(&format!(
                "[MSG:A job of the previous sender {state} at line {line} with {ahead} blocks ahead: '~' resumes it, Ctrl-X clears it]"
            ));
        }
    }

    fn tell_busy(&mut self, end: End) {
        // At most once a second to each sender.
        if self
            .busy_told
            .get(&end)
            .is_some_and(|t| t.elapsed() < Duration::from_secs(1))
        {
            return;
        }
        self.busy_told.insert(end, Instant::now());
        let msg = b"[MSG:Busy: another sender holds this bridge; nothing was read]\r\n";
        match end {
            End::Pty => self.ports.write_pty(msg),
            End::Tcp(id) => {
                if let Some(s) = self.tcp.get_mut(&id) {
                    write_all_patiently(s, msg);
                }
            }
        }
    }

    fn bytes(&mut self, bytes: &[u8]) {
        let mut items = Vec::new();
        self.input.push(bytes, &mut items);
        for item in items {
            match item {
                Item::RealTime(rt) => self.real_time(rt),
                other => {
                    let n = match &other {
                        Item::Line(l) => l.len() + 1,
                        _ => 1,
                    };
                    self.lines.push_back((other, n));
                }
            }
        }
    }

    fn real_time(&mut self, rt: RealTime) {
        match rt {
            RealTime::Status => {
                let text = self.status_report();
                self.say(&text);
            }
            // A feed hold during a jog cancels it (Grbl's jogging interface), and
            // leaves no hold behind.
            RealTime::Hold | RealTime::Door if self.mode.jogging => {
                self.controls.push_back(Control::Abort)
            }
            RealTime::Hold | RealTime::Door => self.controls.push_back(Control::Hold),
            RealTime::Resume => self.controls.push_back(Control::Resume),
            RealTime::Reset => {
                self.reset = true;
                self.input.clear();
                self.lines.clear();
                if self.busy() {
                    self.controls.push_back(Control::Abort);
                }
            }
            RealTime::JogCancel => {
                if self.mode.jogging {
                    self.controls.push_back(Control::Abort);
                }
            }
            RealTime::Feed(d) => {
                let v = match d {
                    0 => 100,
                    d => (self.feed_override as i32 + d as i32).clamp(10, 200) as u16,
                };
                self.feed_override = v;
                // Grbl's jogs ignore the feed override (its jog motions are planned
                // with PL_COND_FLAG_NO_FEED_OVERRIDE): during a jog the controller
                // stays at 100 % and gets the new value when the jog ends.
                if !self.mode.jogging {
                    self.controls.push_back(Control::FeedOverride(v));
                }
            }
            RealTime::Rapid(v) => {
                self.rapid_spindle.0 = v;
                self.say(
                    "[MSG:Rapid override is not supported: rapids run at the machine's limits]",
                );
            }
            RealTime::Spindle(d) => {
                let v = match d {
                    0 => 100,
                    d => (self.rapid_spindle.1 as i32 + d as i32).clamp(10, 200) as u8,
                };
                self.rapid_spindle.1 = v;
                self.say("[MSG:Spindle override is not supported by this controller]");
            }
            RealTime::Toggle(_) => {
                self.say("[MSG:Spindle stop and coolant toggles are not supported]")
            }
        }
    }

    /// Is the controller moving or holding motion?
    pub(super) fn busy(&self) -> bool {
        self.job.is_some()
            || self.mode.jogging
            || self
                .status
                .as_ref()
                .is_some_and(|s| !matches!(s.state, State::Idle | State::Alarm | State::EStop))
    }

    pub(super) fn status_report(&self) -> String {
        let Some(s) = self.status.as_ref() else {
            return "<Idle|MPos:0.000,0.000,0.000|FS:0,0>".into();
        };
        let queued_bytes: usize =
            self.lines.iter().map(|(_, n)| n).sum::<usize>() + self.input.held();
        let ahead = self
            .job
            .map_or(0, |(total, done)| total.saturating_sub(done));
        // Moves held for merging are in Grbl's planner buffer too: a sender that has
        // had every line answered sees `Run` until they have run.
        let mode = Mode {
            pending: ahead > 0 || !self.merge.is_empty(),
            ..self.mode
        };
        let report = words::Report {
            machine: self.machine,
            mode,
            free: (
                BLOCK_BUFFER.saturating_sub(ahead),
                RX_BUFFER.saturating_sub(queued_bytes),
            ),
            wco: self.pipeline.interp().work_offset(),
            feed_override: self.feed_override,
            rapid_spindle: self.rapid_spindle,
        };
        words::status_report(s, &report)
    }

    /// The state Grbl would be in for a `$` line read now; `accepted`: blocks of
    /// lines answered in this turn that the job has not taken yet (a `?` would
    /// already say `Run` or `Jog`).
    pub(super) fn phase(&self, accepted: bool) -> Phase {
        let Some(s) = self.status.as_ref() else {
            return Phase::Idle;
        };
        let ahead = self
            .job
            .map_or(0, |(total, done)| total.saturating_sub(done));
        let mode = Mode {
            pending: ahead > 0 || accepted || !self.merge.is_empty(),
            ..self.mode
        };
        match words::state_word(s, mode) {
            "Idle" => Phase::Idle,
            "Alarm" => Phase::Alarm,
            "Check" => Phase::Check,
            "Jog" => Phase::Jog,
            _ => Phase::Cycle,
        }
    }

    /// A refused line: `[MSG:where: why]` then `error:N`.
    pub(super) fn refuse(&mut self, code: u8, why: &str) {
        self.counts.errors += 1;
        self.say(&format!("[MSG:{why}]"));
        self.say(&format!("error:{code}"));
    }

    /// Compiles one G-code line into blocks (none in check mode); an error is
    /// answered here and gives `None`. A line that ends in a probing move is answered
    /// once the move has run ([`Self::probe`]).
    pub(super) fn compile(&mut self, text: &str) -> Option<Vec<Block>> {
        match self.compile_line(text) {
            Ok(blocks) => {
                if self.probe.is_none() {
                    self.ok();
                }
                Some(blocks)
            }
            Err((code, why)) => {
                self.refuse(code, &why);
                None
            }
        }
    }

    /// Compiles one G-code line: its blocks (none in check mode), its messages said,
    /// its probing move kept in [`Self::probe`]; or Grbl's error number and why, the
    /// interpreter left where the machine will be.
    pub(super) fn compile_line(&mut self, text: &str) -> Result<Vec<Block>, (u8, String)> {
        self.line_no += 1;
        let n = self.line_no;
        let tool_change = self.tool_change;
        let vet = |canon: &[Canon]| {
            if tool_change || !canon.iter().any(|c| matches!(c, Canon::ToolChange { .. })) {
                return Ok(());
            }
            // Grbl 1.1 has no M6 (error:20); a sender that wants the hold asks for it.
            Err(format!(
                "sender:{n}: M6 (tool change) is not supported, as on Grbl 1.1; \
                 start the bridge with --tool-change pause to hold for one"
            ))
        };
        let line = self.pipeline.line_vetted(text, n, vet).map_err(|f| {
            let code = match &f {
                LineFault::FrontEnd(d) => words::error_code(d.kind),
                LineFault::Vetted(_) => 20,
                LineFault::Preflight(_) => 33,
            };
            (code, f.to_string())
        })?;
        for text in line.messages.values() {
            self.say(&format!("[MSG:{text}]"));
        }
        if line.ended {
            self.say("[MSG:Pgm End]");
        }
        if self.mode.check {
            if let Some((block, _)) = line.probe {
                super::probe::checked(self, &block, n);
            }
            return Ok(Vec::new());
        }
        self.probe = line.probe.map(|(block, probing)| super::probe::Pending {
            block,
            probing,
            line: n,
        });
        self.counts.blocks += line.blocks.len() as u64;
        Ok(line.blocks)
    }

    /// `ok`.
    pub(super) fn ok(&mut self) {
        self.counts.ok += 1;
        self.say("ok");
    }

    /// Is the controller locked (alarm, e-stop), or the bridge in a probe's alarm?
    /// Then G-code is refused (error:9).
    pub(super) fn locked(&self) -> bool {
        self.mode.alarm
            || self
                .status
                .as_ref()
                .is_some_and(|s| matches!(s.state, State::Alarm | State::EStop))
    }

    /// Takes queued lines while a job runs: G-code lines are compiled and their blocks
    /// appended to `out` (during a jog, `$J=` lines are queued jogs and G-code is
    /// refused); `$` lines are answered as Grbl answers them in this state. Only once
    /// the job is at rest does a line that needs the controller between jobs close
    /// the job's feed (returns `false`) to run after it.
    fn take_lines(&mut self, view: &LinkView, out: &mut Vec<Block>) -> bool {
        while let Some((item, _)) = self.lines.front() {
            let ahead = view.total + out.len() - view.executed.min(view.total);
            if ahead >= BLOCK_BUFFER || self.merge.full() {
                return true;
            }
            if let Item::Line(text) = item {
                let jog =
                    self.mode.jogging && text.trim_start().to_ascii_uppercase().starts_with("$J=");
                if super::commands::needs(text) == Needs::Link
                    && !jog
                    && self.at_rest(view)
                    && out.is_empty()
                {
                    return false;
                }
            }
            let Some((item, _)) = self.lines.pop_front() else {
                break;
            };
            match item {
                Item::Refused { code, why } => {
                    self.line_no += 1;
                    let n = self.line_no;
                    self.refuse(code, &format!("sender:{n}: {why}"));
                }
                Item::Line(text) if self.mode.jogging => self.line_in_jog(&text, out),
                Item::Line(text) if text.trim_start().starts_with('$') => {
                    self.line_no += 1;
                    let phase = self.phase(!out.is_empty());
                    super::commands::answer_local(self, &text, phase);
                }
                Item::Line(_) if self.locked() => {
                    self.line_no += 1;
                    self.refuse(
                        9,
                        "G-code is locked out during an alarm: $X unlocks, $H homes",
                    );
                }
                Item::RealTime(_) => {}
                // An error does not hold the stream (Grbl streams on after one).
                Item::Line(text) => {
                    let blocks = self.compile(&text).unwrap_or_default();
                    self.merge.take(blocks, out);
                    if self.probe.is_some() {
                        // A probing move: the job runs out before it (Grbl synchronises).
                        self.merge.flush(out);
                        return false;
                    }
                }
            }
        }
        true
    }

    /// A line during a jog: `$J=` queues a jog after those accepted; other `$` lines
    /// are answered; G-code is refused (`error:9`).
    fn line_in_jog(&mut self, text: &str, out: &mut Vec<Block>) {
        self.line_no += 1;
        let t = text.trim();
        if t.to_ascii_uppercase().starts_with("$J=") {
            let from = self.jog_end;
            match super::commands::jog_block(self, &t[3..], &from) {
                Ok(block) => {
                    self.jog_end = block.target;
                    self.ok();
                    out.push(block);
                }
                Err((code, why)) => self.refuse(code, &format!("{t}: {why}")),
            }
        } else if t.starts_with('$') {
            let phase = self.phase(!out.is_empty());
            super::commands::answer_local(self, t, phase);
        } else if t.is_empty() {
            self.ok();
        } else {
            self.refuse(9, JOG_LOCK);
        }
    }

    /// Has every block of the job executed, with the controller idle and still?
    fn at_rest(&self, view: &LinkView) -> bool {
        self.status
            .as_ref()
            .is_some_and(|s| s.state == State::Idle && s.speed == 0)
            && view.acked == view.total
            && view.executed >= view.total
            && self.merge.is_empty()
    }

    /// The job ended with every block executed.
    pub(super) fn job_done(&mut self) {
        self.job = self.job.map(|(total, _)| (total, total));
    }

    /// A job starts (`Some`) or has ended (`None`: its executed blocks are counted).
    pub(super) fn set_job(&mut self, job: Option<(usize, usize)>) {
        if job.is_none() {
            self.counts.executed += self.job.map_or(0, |(_, done)| done as u64);
        }
        self.job_owner = job.map(|_| self.active);
        self.job = job;
    }

    /// Ctrl-C: no more lines are taken; a job under way runs to its end, and a job
    /// held at rest (which would never end) is abandoned, stopped where it stands.
    fn check_stop(&mut self) {
        if !self.stopping {
            if !(self.stop)() {
                return;
            }
            self.stopping = true;
        }
        let held = self
            .status
            .as_ref()
            .is_some_and(|s| s.state == State::Hold && s.speed == 0);
        if held && !self.stop_aborted {
            self.stop_aborted = true;
            self.controls.push_back(Control::Abort);
        }
    }
}

impl JobHooks for Bridge<'_> {
    fn status(&mut self, status: &Status) {
        self.status = Some(status.clone());
    }

    /// Asked on every turn of a job's loop, and while homing or waiting: the ports
    /// are read here, so real-time bytes act in every state.
    fn control(&mut self, _link: &LinkView) -> Option<Control> {
        self.meanwhile();
        self.controls.pop_front()
    }

    /// While the link plans the lines fed: `?` is answered, and real-time commands
    /// are queued, as in every other state.
    fn meanwhile(&mut self) {
        self.poll(Duration::ZERO);
        self.check_stop();
    }

    fn feed(&mut self, view: &LinkView, out: &mut Vec<Block>) -> bool {
        self.poll(Duration::ZERO);
        self.job = Some((view.total, view.executed));
        if self.reset || self.stopping || self.probe.is_some() {
            return false;
        }
        // A sender streams as fast as the answers come (character counting keeps its
        // few lines in Grbl's 128-byte buffer): its next lines are awaited here for a
        // moment, rather than a turn of the job's loop later.
        let until = Instant::now() + SENDER_TURN;
        loop {
            if !self.take_lines(view, out) {
                return false;
            }
            if Instant::now() >= until || self.reset || self.stopping || self.probe.is_some() {
                break;
            }
            self.poll(Duration::from_micros(300));
            if self.lines.is_empty() {
                break;
            }
        }
        let queued = view.total.saturating_sub(view.executed) + out.len();
        let (at_rest, buffered_ms) = self
            .status
            .as_ref()
            .map_or((true, 0), |s| (s.speed == 0, s.buffered_ms));
        self.merge
            .send_due((queued, at_rest, buffered_ms), !self.lines.is_empty(), out);
        // The blocks handed out are the job's from now (a status asked before the next
        // turn counts them).
        self.job = Some((view.total + out.len(), view.executed));
        if !out.is_empty() || !self.lines.is_empty() {
            self.last_busy = Instant::now();
            return true;
        }
        // Closed once everything has executed, the controller is at rest and no line
        // has come for a while.
        !(self.at_rest(view) && self.last_busy.elapsed() > CLOSE_AFTER)
    }
}
