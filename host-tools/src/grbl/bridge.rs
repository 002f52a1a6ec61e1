//! The bridge's state: the sender's bytes and lines, the line-by-line front end, the
//! controls to send, and what is said back. [`Bridge`] is the job's hooks while a job
//! streams (lines keep arriving and are fed into the running job), and is driven by
//! [`super::serve`]'s loop between jobs.

use super::input::{Input, Item, RealTime};
use super::ports::{write_all_patiently, End, Event, Ports};
use super::words::{self, Mode, BLOCK_BUFFER, RX_BUFFER};
use crate::gcode::canon::Canon;
use crate::gcode::{Diagnostic, LineSession};
use crate::link::{JobHooks, LinkView};
use pkmc::config::MachineConfig;
use pkmc::protocol::{Block, Control, State, Status};
use std::collections::{HashMap, VecDeque};
use std::net::TcpStream;
use std::time::{Duration, Instant};

/// A job's feed is closed after this long with nothing to feed and the controller
/// idle with every block executed.
const CLOSE_AFTER: Duration = Duration::from_millis(60);

/// What a queued line is, for deciding where it may run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Needs {
    /// G-code or a `$` command answered from the bridge's own state.
    Nothing,
    /// A `$` command that acts on the controller (`$H`, `$X`, `$J=`, `$C`): only
    /// between jobs.
    Link,
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
    pub(super) session: LineSession<'o>,
    /// Lines read since the start (the NC line numbers of the blocks).
    pub(super) line_no: u32,
    pub(super) status: Option<Status>,
    pub(super) controls: VecDeque<Control>,
    feed_override: u16,
    rapid_spindle: (u8, u8),
    pub(super) mode: Mode,
    /// A soft reset is to be carried out once the motion has stopped.
    pub(super) reset: bool,
    /// Blocks of the job running, and executed of them (from the job's view).
    job: Option<(usize, usize)>,
    last_busy: Instant,
    pub(super) startup: [String; 2],
    busy_told: Option<Instant>,
    /// Counters for the summary at exit.
    pub(super) counts: Counts,
}

/// What the bridge did, printed when it stops.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub(super) struct Counts {
    /// Lines answered `ok`.
    pub(super) ok: u64,
    /// Lines answered `error:N`.
    pub(super) errors: u64,
    /// Blocks fed to the controller.
    pub(super) blocks: u64,
    /// Blocks the controller reported executed.
    pub(super) executed: u64,
}

impl<'o> Bridge<'o> {
    pub(super) fn new(machine: &'o MachineConfig, ports: Ports, session: LineSession<'o>) -> Self {
        Self {
            machine,
            ports,
            tcp: HashMap::new(),
            active: End::Pty,
            input: Input::default(),
            lines: VecDeque::new(),
            session,
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
            busy_told: None,
            counts: Counts::default(),
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
                    if self.active == End::Pty {
                        self.active = End::Tcp(id);
                        self.input.clear();
                        self.lines.clear();
                        self.say(&words::banner());
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
                Event::Bytes(end, bytes) if end == self.active => self.bytes(&bytes),
                Event::Bytes(end, _) => self.tell_busy(end),
            }
        }
    }

    fn tell_busy(&mut self, end: End) {
        if self
            .busy_told
            .is_some_and(|t| t.elapsed() < Duration::from_secs(1))
        {
            return;
        }
        self.busy_told = Some(Instant::now());
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
                self.controls.push_back(Control::FeedOverride(v));
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
        let mode = Mode {
            pending: ahead > 0,
            ..self.mode
        };
        let report = words::Report {
            machine: self.machine,
            mode,
            free: (
                BLOCK_BUFFER.saturating_sub(ahead),
                RX_BUFFER.saturating_sub(queued_bytes),
            ),
            wco: self.session.interp().work_offset(),
            rapid_spindle: self.rapid_spindle,
        };
        words::status_report(s, &report)
    }

    /// A refused line: `[MSG:where: why]` then `error:N`.
    pub(super) fn refuse(&mut self, code: u8, why: &str) {
        self.counts.errors += 1;
        self.say(&format!("[MSG:{why}]"));
        self.say(&format!("error:{code}"));
    }

    fn refuse_diagnostic(&mut self, d: &Diagnostic) {
        let code = words::error_code(&d.message);
        self.refuse(code, &d.to_string());
    }

    /// Compiles one G-code line into blocks (none in check mode); an error is
    /// answered here and gives `None`.
    pub(super) fn compile(&mut self, text: &str) -> Option<Vec<Block>> {
        self.line_no += 1;
        let n = self.line_no;
        let start = self.session.interp().pos;
        let mut canon = vec![Canon::PathMode {
            line: n,
            mode: self.session.interp().path,
        }];
        if let Err(d) = self.session.line(text, n, &mut canon) {
            self.refuse_diagnostic(&d);
            return None;
        }
        if self.session.ended() {
            // M2/M30: what compensation holds ends here; the next line starts afresh.
            let _ = self.session.finish(n, &mut canon);
            let pos = self.session.interp().pos;
            self.session.restart(pos);
        }
        let program = crate::gcode::blocks::from_canon(&canon, start);
        let report = crate::analysis::preflight::check(&program.blocks, self.machine, start);
        if let Some(f) = report.findings.first() {
            let why = format!("{}:{}: {}", "sender", f.line, f.what);
            self.refuse(33, &why);
            // The interpreter already moved to the refused target: back to where the
            // machine will be.
            self.session.set_position(start);
            return None;
        }
        for text in program.messages.values() {
            self.say(&format!("[MSG:{text}]"));
        }
        self.ok();
        if self.mode.check {
            return Some(Vec::new());
        }
        self.counts.blocks += program.blocks.len() as u64;
        Some(program.blocks)
    }

    /// `ok`.
    pub(super) fn ok(&mut self) {
        self.counts.ok += 1;
        self.say("ok");
    }

    /// Is the controller locked (alarm, e-stop)? Then G-code is refused (error:9).
    pub(super) fn locked(&self) -> bool {
        self.status
            .as_ref()
            .is_some_and(|s| matches!(s.state, State::Alarm | State::EStop))
    }

    /// Takes queued lines while a job runs: G-code lines are compiled and their blocks
    /// appended to `out`; lines for the bridge alone are answered; a line that needs
    /// the controller between jobs waits (and the job's feed closes).
    fn take_lines(&mut self, view: &LinkView, out: &mut Vec<Block>) -> bool {
        while let Some((item, _)) = self.lines.front() {
            let ahead = view.total + out.len() - view.executed.min(view.total);
            if ahead >= BLOCK_BUFFER {
                return true;
            }
            if let Item::Line(text) = item {
                if super::commands::needs(text) == Needs::Link {
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
                Item::Line(text) if text.trim_start().starts_with('$') => {
                    self.line_no += 1;
                    super::commands::answer_local(self, &text);
                }
                Item::Line(_) if self.locked() => {
                    self.line_no += 1;
                    self.refuse(
                        9,
                        "G-code is locked out during an alarm: $X unlocks, $H homes",
                    );
                }
                Item::RealTime(_) => {}
                Item::Line(text) => match self.compile(&text) {
                    Some(blocks) => out.extend(blocks),
                    None => {
                        if view.total > view.executed {
                            // An error holds the stream: the machine stops on the path
                            // until the operator resumes (~) or resets.
                            self.controls.push_back(Control::Hold);
                        }
                    }
                },
            }
        }
        true
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
        self.job = job;
    }
}

impl JobHooks for Bridge<'_> {
    fn status(&mut self, status: &Status) {
        self.status = Some(status.clone());
    }

    fn control(&mut self, _link: &LinkView) -> Option<Control> {
        self.controls.pop_front()
    }

    fn feed(&mut self, view: &LinkView, out: &mut Vec<Block>) -> bool {
        self.poll(Duration::ZERO);
        self.job = Some((view.total, view.executed));
        if self.reset {
            return false;
        }
        if !self.take_lines(view, out) {
            return false;
        }
        if !out.is_empty() || !self.lines.is_empty() {
            self.last_busy = Instant::now();
            return true;
        }
        // Closed once everything has executed, the controller is at rest and no line
        // has come for a while.
        let at_rest = self
            .status
            .as_ref()
            .is_some_and(|s| s.state == State::Idle && s.speed == 0)
            && view.acked == view.total
            && view.executed >= view.total;
        !(at_rest && self.last_busy.elapsed() > CLOSE_AFTER)
    }
}
