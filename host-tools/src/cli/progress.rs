//! The operator's side of a running job: progress on stderr, Ctrl-C, and single keys.
//!
//! * [`Progress`] shows the current NC line, the percentage of blocks executed, the
//!   feed (mm/min, from `Status.speed`) and an estimated time to go: as a bar redrawn
//!   in place when stderr is a terminal, as a plain line every
//!   [`PLAIN_EVERY`] otherwise, and not at all when quiet (`--report json`).
//! * [`Operator`] turns Ctrl-C and keys into control commands ([`JobHooks`]): the first
//!   Ctrl-C (or `q`) is a controlled stop — feed hold, then `Abort` once the machine
//!   stands still; a second one is an immediate `Stop`. Keys, read in raw mode when
//!   stdin is a terminal ([`RawKeys`]): `h` or space hold, `r` resume, `q` controlled
//!   stop, `+`/`-` feed override ±10 %.
//!
//! Invariant: the terminal's mode is restored when [`RawKeys`] is dropped, and Ctrl-C
//! still raises SIGINT in raw mode (ISIG stays on).

use crate::link::view::StatusView;
use crate::link::{JobHooks, LinkView};
use pkmc::wire::{Control, State, Status};
use std::io::{IsTerminal, Write};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc::Receiver;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Period of the plain progress lines when stderr is not a terminal.
pub const PLAIN_EVERY: Duration = Duration::from_secs(2);
/// Redraw period of the progress bar.
pub const BAR_EVERY: Duration = Duration::from_millis(100);
/// Width of the bar, characters.
const BAR_WIDTH: usize = 24;

/// How progress is shown.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Style {
    /// A bar redrawn in place (stderr is a terminal).
    Bar,
    /// A line now and then (stderr is a file or a pipe).
    Plain,
    /// Nothing (machine-readable output was asked for).
    Quiet,
}

impl Style {
    /// The style for stderr as it is, unless `quiet`.
    pub fn for_stderr(quiet: bool) -> Self {
        if quiet {
            Style::Quiet
        } else if std::io::stderr().is_terminal() {
            Style::Bar
        } else {
            Style::Plain
        }
    }
}

/// Progress of one job.
pub struct Progress {
    style: Style,
    total: usize,
    baseline: Option<u32>,
    started: Instant,
    last_draw: Option<Instant>,
    drawn: bool,
    last: Option<Status>,
}

/// Formats seconds as `m:ss` or `h:mm:ss`.
pub fn clock(secs: f64) -> String {
    let s = secs.max(0.0).round() as u64;
    if s >= 3600 {
        format!("{}:{:02}:{:02}", s / 3600, s / 60 % 60, s % 60)
    } else {
        format!("{}:{:02}", s / 60, s % 60)
    }
}

impl Progress {
    /// Progress of a job of `total` blocks shown in `style`; with `total` 0 (a single
    /// command) only messages are shown.
    pub fn new(style: Style, total: usize) -> Self {
        Self {
            style,
            total,
            baseline: None,
            started: Instant::now(),
            last_draw: None,
            drawn: false,
            last: None,
        }
    }

    /// Blocks executed in this job so far, per `s`.
    fn done(&self, s: &Status) -> usize {
        s.blocks_done.wrapping_sub(self.baseline.unwrap_or(0)) as usize
    }

    /// The progress line for status `s` after `elapsed`.
    pub fn line(&self, s: &Status, elapsed: Duration) -> String {
        let done = self.done(s).min(self.total);
        let frac = if self.total == 0 {
            1.0
        } else {
            done as f64 / self.total as f64
        };
        let view = StatusView::new(s);
        let eta = if frac > 0.01 && frac < 1.0 {
            clock(elapsed.as_secs_f64() * (1.0 - frac) / frac)
        } else if frac >= 1.0 {
            clock(0.0)
        } else {
            "--:--".into()
        };
        let mut text = format!(
            "{:5.1}%  line {:>6}  {:>7.0} mm/min  ETA {eta}  {}",
            frac * 100.0,
            view.line,
            view.feed_mm_min,
            view.state_words
        );
        if view.feed_override != 100 {
            text += &format!("  override {}%", view.feed_override);
        }
        if self.style == Style::Bar {
            let filled = ((frac * BAR_WIDTH as f64) as usize).min(BAR_WIDTH);
            text = format!(
                "[{}{}] {text}",
                "#".repeat(filled),
                "-".repeat(BAR_WIDTH - filled)
            );
        }
        text
    }

    /// Takes a status; redraws when due.
    pub fn update(&mut self, s: &Status) {
        if self.baseline.is_none() {
            self.baseline = Some(s.blocks_done);
        }
        self.last = Some(s.clone());
        if self.total == 0 {
            return;
        }
        let every = match self.style {
            Style::Quiet => return,
            Style::Bar => BAR_EVERY,
            Style::Plain => PLAIN_EVERY,
        };
        if self.last_draw.is_some_and(|t| t.elapsed() < every) {
            return;
        }
        self.draw();
    }

    fn draw(&mut self) {
        let Some(s) = self.last.as_ref() else {
            return;
        };
        let text = self.line(s, self.started.elapsed());
        let mut err = std::io::stderr().lock();
        let _ = match self.style {
            Style::Bar => write!(err, "\r\x1b[K{text}"),
            Style::Plain => writeln!(err, "progress: {text}"),
            Style::Quiet => Ok(()),
        };
        let _ = err.flush();
        self.last_draw = Some(Instant::now());
        self.drawn = true;
    }

    /// Prints a message without tearing the bar.
    pub fn say(&mut self, message: &str) {
        if self.style == Style::Quiet {
            return;
        }
        let mut err = std::io::stderr().lock();
        if self.style == Style::Bar && self.drawn {
            let _ = write!(err, "\r\x1b[K");
        }
        let _ = writeln!(err, "{message}");
        drop(err);
        if self.style == Style::Bar && self.total > 0 {
            self.draw();
        }
    }

    /// Writes a warning, as [`Progress::say`] does, but also when quiet (the report on
    /// stdout is for programs; stderr is still the operator's).
    pub fn warn(&mut self, message: &str) {
        let message = format!("warning: {message}");
        if self.style == Style::Quiet {
            eprintln!("{message}");
        } else {
            self.say(&message);
        }
    }

    /// Draws the final state and ends the bar's line.
    pub fn finish(&mut self) {
        if self.style == Style::Quiet || self.last.is_none() || self.total == 0 {
            return;
        }
        self.draw();
        if self.style == Style::Bar {
            eprintln!();
        }
    }
}

/// Counts Ctrl-C presses (SIGINT) from the moment it is installed.
#[derive(Clone, Debug, Default)]
pub struct Interrupts(Arc<AtomicUsize>);

/// The terminal settings before [`RawKeys`] changed them, restored on a forced exit.
static SAVED_TERMINAL: std::sync::OnceLock<libc::termios> = std::sync::OnceLock::new();

/// The Ctrl-C press that exits at once, whatever `nc-send` is waiting for.
pub const EXIT_PRESS: usize = 3;

impl Interrupts {
    /// Installs the SIGINT handler (once per process). The first press asks for a
    /// controlled stop, the second for an immediate one (see [`Operator`]); the third
    /// exits at once (exit code 6), whatever `nc-send` is waiting for: no wait
    /// outlives the operator's patience (the controller stops on its own once the link
    /// has been silent for a second).
    pub fn install() -> Result<Self, String> {
        let count = Arc::new(AtomicUsize::new(0));
        let c = count.clone();
        ctrlc::set_handler(move || {
            if c.fetch_add(1, Ordering::SeqCst) + 1 >= EXIT_PRESS {
                if let Some(t) = SAVED_TERMINAL.get() {
                    // SAFETY: restores fd 0's settings from a valid termios.
                    unsafe { libc::tcsetattr(0, libc::TCSANOW, t) };
                }
                eprintln!("\nnc-send: Ctrl-C three times: exiting now");
                std::process::exit(6);
            }
        })
        .map_err(|e| format!("cannot install the Ctrl-C handler: {e}"))?;
        Ok(Self(count))
    }

    /// Presses so far.
    pub fn count(&self) -> usize {
        self.0.load(Ordering::SeqCst)
    }

    /// Counts one more press (as the `q` key does).
    pub fn press(&self) {
        self.0.fetch_add(1, Ordering::SeqCst);
    }
}

/// Stdin in raw mode, read a key at a time by a thread.
pub struct RawKeys {
    saved: libc::termios,
    keys: Receiver<u8>,
}

impl RawKeys {
    /// Switches stdin to raw mode when it is a terminal; `None` otherwise.
    pub fn start() -> Option<Self> {
        if !std::io::stdin().is_terminal() {
            return None;
        }
        // SAFETY: tcgetattr/tcsetattr on fd 0 with a properly sized termios buffer.
        let saved = unsafe {
            let mut t: libc::termios = std::mem::zeroed();
            if libc::tcgetattr(0, &mut t) != 0 {
                return None;
            }
            t
        };
        let _ = SAVED_TERMINAL.set(saved);
        let mut raw = saved;
        raw.c_lflag &= !(libc::ICANON | libc::ECHO);
        raw.c_cc[libc::VMIN] = 1;
        raw.c_cc[libc::VTIME] = 0;
        // SAFETY: as above.
        if unsafe { libc::tcsetattr(0, libc::TCSANOW, &raw) } != 0 {
            return None;
        }
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let mut b = [0u8; 1];
            loop {
                // SAFETY: reading one byte from fd 0 into a one-byte buffer.
                let n = unsafe { libc::read(0, b.as_mut_ptr().cast(), 1) };
                if n != 1 || tx.send(b[0]).is_err() {
                    break;
                }
            }
        });
        Some(Self { saved, keys: rx })
    }

    /// The next key pressed, if any.
    pub fn key(&self) -> Option<u8> {
        self.keys.try_recv().ok()
    }
}

impl Drop for RawKeys {
    fn drop(&mut self) {
        // SAFETY: restores the attributes saved by `start`.
        unsafe {
            libc::tcsetattr(0, libc::TCSANOW, &self.saved);
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Stage {
    Running,
    /// Controlled stop: hold sent, waiting for the machine to stand still.
    Holding,
    /// Controlled stop: abort sent.
    Aborting,
    /// Immediate stop sent.
    Stopping,
}

/// Progress plus the operator's commands: the [`JobHooks`] of `nc-send`.
pub struct Operator {
    /// Progress display.
    pub progress: Progress,
    interrupts: Interrupts,
    keys: Option<RawKeys>,
    stage: Stage,
    handled: usize,
    announced_pause: bool,
    /// Resume program pauses (M0, M1, M6) by itself: no operator to press resume
    /// (simulation and dry runs).
    pub auto_resume: bool,
    user_hold: bool,
    resume_due: bool,
    /// The line of the pause last resumed, until a status shows the controller out of
    /// it: statuses still showing that pause (in flight when the resume was sent) are
    /// not a new pause; a hold at another line is.
    resumed_line: Option<u32>,
    /// The line of the pause last announced.
    paused_line: u32,
}

impl Operator {
    /// An operator watching `interrupts` and, if given, `keys`.
    pub fn new(progress: Progress, interrupts: Interrupts, keys: Option<RawKeys>) -> Self {
        Self {
            progress,
            interrupts,
            keys,
            stage: Stage::Running,
            handled: 0,
            announced_pause: false,
            auto_resume: false,
            user_hold: false,
            resume_due: false,
            resumed_line: None,
            paused_line: 0,
        }
    }

    /// Did the operator ask for a stop?
    pub fn stopped(&self) -> bool {
        self.stage != Stage::Running
    }

    fn key_command(&mut self, key: u8, status: Option<&Status>) -> Option<Control> {
        let over = status.map_or(100, |s| s.feed_override);
        match key {
            b'h' | b'H' | b' ' => {
                self.progress.say("hold (r resumes)");
                self.user_hold = true;
                Some(Control::Hold)
            }
            b'r' | b'R' => {
                self.progress.say("resume");
                self.announced_pause = false;
                self.user_hold = false;
                Some(Control::Resume)
            }
            b'q' | b'Q' => {
                self.interrupts.press();
                None
            }
            b'+' | b'=' => Some(Control::FeedOverride((over + 10).min(200))),
            b'-' | b'_' => Some(Control::FeedOverride(over.saturating_sub(10).max(10))),
            _ => None,
        }
    }
}

impl JobHooks for Operator {
    fn status(&mut self, s: &Status) {
        self.progress.update(s);
        if s.state != State::Hold || s.speed != 0 || self.resumed_line != Some(s.line) {
            self.resumed_line = None;
        }
        // (A hold for this host's own silence is the link's to resume: `note`.)
        let host_timeout = s
            .alarm
            .is_some_and(|a| a.cause == pkmc::wire::AlarmCause::HostTimeout);
        if s.state == State::Hold
            && !host_timeout
            && self.resumed_line.is_none()
            && s.speed == 0
            && self.stage == Stage::Running
            && !self.announced_pause
        {
            self.announced_pause = true;
            self.paused_line = s.line;
            if self.auto_resume && !self.user_hold {
                self.resume_due = true;
                self.progress.say(&format!(
                    "program pause or tool change at line {}: resumed automatically (no operator in a simulation)",
                    s.line
                ));
            } else if self.keys.is_some() {
                self.progress
                    .say("held (pause, tool change or hold): press r to resume");
            } else {
                self.progress.say("held (pause, tool change or hold)");
            }
        }
    }

    fn note(&mut self, text: &str) {
        self.progress.say(text);
    }

    fn warn(&mut self, text: &str) {
        self.progress.warn(text);
    }

    fn ends_at_pause(&self) -> bool {
        !self.auto_resume && self.keys.is_none() && !self.user_hold && self.stage == Stage::Running
    }

    fn control(&mut self, view: &LinkView) -> Option<Control> {
        let presses = self.interrupts.count();
        if presses > self.handled {
            self.handled = presses;
            if presses >= 2 && self.stage != Stage::Stopping {
                self.stage = Stage::Stopping;
                self.progress.say("immediate stop");
                return Some(Control::Stop);
            }
            if self.stage == Stage::Running {
                self.stage = Stage::Holding;
                self.progress
                    .say("stopping: feed hold, then abort (Ctrl-C again stops at once)");
                return Some(Control::Hold);
            }
        }
        if self.stage == Stage::Holding && !view.control_pending {
            if let Some(s) = &view.status {
                if matches!(s.state, State::Hold | State::Idle) && s.speed == 0 {
                    self.stage = Stage::Aborting;
                    return Some(Control::Abort);
                }
            }
        }
        if self.resume_due && self.stage == Stage::Running && !view.control_pending {
            self.resume_due = false;
            self.announced_pause = false;
            self.resumed_line = Some(self.paused_line);
            return Some(Control::Resume);
        }
        if self.stage == Stage::Running && !view.control_pending {
            if let Some(k) = self.keys.as_ref().and_then(|k| k.key()) {
                return self.key_command(k, view.status.as_ref());
            }
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn status(done: u32, line: u32, speed_mm_s: i64) -> Status {
        Status {
            state: State::Running,
            line,
            blocks_done: done,
            motion_ticks: 0,
            pose: [0; 6],
            joints: [0; pkmc::config::MAX_JOINTS],
            measured: [0; pkmc::config::MAX_JOINTS],
            speed: speed_mm_s * 1_000_000,
            buffered_ms: 0,
            free_slots: 0,
            free_bends: 0,
            feed_override: 100,
            alarm: None,
            homed: false,
            orphan: false,
            probe_input: false,
            probes: 0,
        }
    }

    #[test]
    fn the_bar_shows_percent_line_feed_and_eta() {
        let mut p = Progress::new(Style::Bar, 200);
        p.baseline = Some(10);
        let text = p.line(&status(60, 42, 20), Duration::from_secs(30));
        assert!(
            text.starts_with("[######------------------]  25.0%"),
            "{text}"
        );
        assert!(text.contains("line     42"), "{text}");
        assert!(text.contains("1200 mm/min"), "{text}");
        assert!(text.contains("ETA 1:30"), "{text}");
    }

    #[test]
    fn clock_formats_minutes_and_hours() {
        assert_eq!(clock(59.6), "1:00");
        assert_eq!(clock(3725.0), "1:02:05");
    }

    #[test]
    fn ctrl_c_holds_then_aborts_and_a_second_one_stops_at_once() {
        let interrupts = Interrupts::default();
        let mut op = Operator::new(Progress::new(Style::Quiet, 10), interrupts.clone(), None);
        let mut view = LinkView {
            status: Some(status(0, 1, 20)),
            ..LinkView::default()
        };
        assert_eq!(op.control(&view), None);
        interrupts.press();
        assert_eq!(op.control(&view), Some(Control::Hold));
        assert_eq!(op.control(&view), None, "still moving");
        let mut held = status(0, 1, 0);
        held.state = State::Hold;
        view.status = Some(held);
        assert_eq!(op.control(&view), Some(Control::Abort));
        interrupts.press();
        assert_eq!(op.control(&view), Some(Control::Stop));
    }
}
