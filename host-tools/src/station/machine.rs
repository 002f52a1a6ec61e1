//! The machine thread: the one owner of the link to the controller. Between jobs it
//! asks for the status 50 times a second and carries out the pages' commands; while
//! a job runs (a program, Run by Step, MDI, a jog, a joint move, the teach list) the
//! job's hooks take hold, resume, stop, override and the next step, publish every
//! status, and stop what a page started when that page's heartbeat is lost.

mod joint;
mod mdi;
mod scope;
mod staged;
mod tune;

use super::hub::{lock, Hub};
use super::{Cmd, Request};
use crate::job::{self, Failure};
use crate::link::view::{AlarmView, StatusView};
use crate::link::{Derived, JobEnd, JobHooks, Link, LinkView, Transport};
use pkmc::config::{MachineConfig, AXES};
use pkmc::motion::block::Block;
use pkmc::wire::{Control, Status};
use serde_json::{json, Value};
use std::collections::VecDeque;
use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::time::{Duration, Instant};

/// Between jobs, a status this often.
const IDLE_STATUS: Duration = Duration::from_millis(20);

/// A continuous jog goes this far (clipped to the joint travel) until released.
const JOG_FAR_MM: f64 = 10_000.0;

/// What runs, and for whom.
#[derive(Clone, Debug)]
pub(super) struct JobInfo {
    kind: &'static str,
    /// The page that started it.
    owner: u64,
    total: usize,
    executed: usize,
    /// Run by Step: the blocks, how many were fed, presses not yet served.
    steps: Option<(Vec<Block>, usize, usize)>,
    /// The owner's heartbeat was lost and the motion stopped for it.
    orphaned: bool,
    /// Controls to send, in order.
    controls: VecDeque<Control>,
    /// A run a stage at a time: the blocks executed before the stage that streams,
    /// and those sent so far ([`staged`]).
    base: usize,
    sent: usize,
    /// A capture read out while the job runs.
    scope: scope::Reading,
}

impl JobInfo {
    fn new(kind: &'static str, owner: u64, total: usize) -> Self {
        Self {
            kind,
            owner,
            total,
            executed: 0,
            steps: None,
            orphaned: false,
            controls: VecDeque::new(),
            base: 0,
            sent: 0,
            scope: Default::default(),
        }
    }
}

pub(super) struct Machine<'a> {
    pub(super) hub: &'a Hub,
    pub(super) machine: &'a MachineConfig,
    pub(super) rx: Receiver<Request>,
    /// MDI lines, read with their modal state kept from line to line (G91, G20, F,
    /// work offsets …), as a control's MDI does.
    pub(super) mdi: Mdi<'a>,
    /// The tool table (for the teach list's programs).
    pub(super) tools: crate::gcode::ToolTable,
    /// The kind of the last job run (for its end's message).
    pub(super) last_job: &'static str,
    /// The host timeout of a program's run (`None`: the short watch).
    pub(super) program_timeout: Option<Duration>,
    /// The machine file, for Tune and Write gains (`None`: a built-in machine).
    pub(super) machine_file: Option<std::path::PathBuf>,
}

/// The MDI's line-by-line front end.
pub(super) struct Mdi<'o> {
    pub(super) pipeline: job::LinePipeline<'o>,
    pub(super) lines: u32,
}

impl Mdi<'_> {
    /// One line from where the machine stands at `pose`: its blocks, checked against
    /// the machine's reach, and the probing move it ends in (G38.2–G38.5); an error
    /// names the MDI line and column and changes nothing.
    fn compile(&mut self, text: &str, pose: [i64; AXES]) -> Result<job::LineBlocks, Failure> {
        self.lines += 1;
        self.pipeline.set_position(pose);
        Ok(self.pipeline.line(text, self.lines)?)
    }
}

/// An alarm as the pages word it: its title (the core's wording of the cause; an
/// e-stop says e-stop) and what the operator does next.
fn alarm_words(a: &pkmc::wire::Alarm, view: &AlarmView, estop: bool) -> (String, &'static str) {
    use pkmc::wire::AlarmCause as C;
    if estop {
        let next = if a.cause == C::EStop {
            "Release the e-stop button, then Reset."
        } else {
            "Motion was cut at once. Reset clears the e-stop; then Home if the machine asks."
        };
        return ("E-STOP".into(), next);
    }
    let next = match a.cause {
        C::Unhomed => "Home the machine, or Reset to unlock it where it stands.",
        C::HomingFailed => "Check the home switches, then Home again (Reset unlocks).",
        C::LimitSwitch => "Reset, then jog off the switch.",
        C::DriveFault | C::FollowingError => "Check the drive and the load, then Reset.",
        C::LinkLoss | C::Watchdog => "Check the connection, then Reset.",
        C::Unreachable | C::JointLimit | C::Singularity | C::JointSpeed => {
            "Reset, then fix the program or the move (the line is shown)."
        }
        C::MachineMismatch => "The controller runs another machine: load this one.",
        _ => "Reset to clear the alarm.",
    };
    (format!("Alarm: {}", view.cause_words), next)
}

/// The status message: the controller's status in user units, the job, the lock and
/// the mechanism.
fn status_message(machine: &MachineConfig, hub: &Hub, s: &Status, job: Option<&JobInfo>) -> Value {
    let view = StatusView::with_joints(s, machine);
    let by_page = hub.estop_shown(s.alarm.is_some());
    let alarm = s.alarm.map(|a| {
        let joint = (a.joint != pkmc::wire::NO_JOINT).then(|| {
            hub.machine["joints"][a.joint as usize]["name"]
                .as_str()
                .unwrap_or("?")
                .to_string()
        });
        let estop = s.state == pkmc::wire::State::EStop
            || a.cause == pkmc::wire::AlarmCause::EStop
            || (a.cause == pkmc::wire::AlarmCause::Aborted && by_page);
        let v = AlarmView::new(&a);
        let (title, next) = alarm_words(&a, &v, estop);
        json!({"cause": v.cause, "cause_words": v.cause_words, "joint": joint,
               "line": v.line, "words": v.words, "estop": estop, "title": title,
               "next": next})
    });
    let job = job.map(|j| {
        let eta = match j.kind {
            "program" => lock(&hub.program).eta_s(j.executed, s.feed_override),
            _ => None,
        };
        let waiting = j
            .steps
            .as_ref()
            .is_some_and(|(_, fed, pending)| *pending == 0 && j.executed >= *fed);
        json!({
            "kind": j.kind, "executed": j.executed, "total": j.total,
            "percent": if j.total == 0 { 0.0 } else { 100.0 * j.executed as f64 / j.total as f64 },
            "eta_s": eta, "step": waiting,
        })
    });
    let holder = hub.holder();
    let r = super::program::round3;
    json!({
        "type": "status",
        "state": view.state,
        "state_words": view.state_words,
        "line": view.line,
        "homed": s.homed,
        "pose": view.pose.map(r),
        "joints": view.joints.iter().map(|&v| r(v)).collect::<Vec<_>>(),
        "measured": view.measured.iter().map(|&v| r(v)).collect::<Vec<_>>(),
        "feed": view.feed_mm_min.round(),
        "override": view.feed_override,
        "buffered_ms": s.buffered_ms,
        "alarm": alarm,
        "job": job,
        "lock": {"holder": holder.as_ref().map(|h| h.0), "name": holder.map(|h| h.1)},
        "scene": super::scene::scene(machine, &view.pose, &view.joints),
    })
}

impl Machine<'_> {
    fn publish(&self, s: &Status, job: Option<&JobInfo>) {
        let msg = status_message(self.machine, self.hub, s, job);
        self.hub.publish_status(s, msg);
    }

    /// Serves until `stop` says so.
    pub(super) fn serve<T: Transport>(
        &mut self,
        link: &mut Link<T>,
        stop: &dyn Fn() -> bool,
    ) -> Result<(), Failure> {
        let mut asked = Instant::now() - IDLE_STATUS;
        while !stop() {
            if asked.elapsed() >= IDLE_STATUS {
                let s = link.request_status()?;
                self.publish(&s, None);
                asked = Instant::now();
            }
            self.scope_poll(link)?;
            match self.rx.recv_timeout(Duration::from_millis(5)) {
                Ok(req) => {
                    let (page, id) = (req.page, req.id);
                    let r = self.command(link, req);
                    match r {
                        Ok(Some(text)) => self.hub.reply(page, id, Ok(text)),
                        Ok(None) => {}
                        Err(f) if f.code == crate::job::exit::LINK => return Err(f),
                        Err(f) => {
                            self.hub.reply(page, id, Err(f.message.clone()));
                            self.hub.log("error", &f.message);
                        }
                    }
                }
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => break,
            }
        }
        Ok(())
    }

    /// One command between jobs; `Ok(Some(text))` is the reply (a job replies when it
    /// starts and logs how it ended).
    fn command<T: Transport>(
        &mut self,
        link: &mut Link<T>,
        req: Request,
    ) -> Result<Option<String>, Failure> {
        let (page, id) = (req.page, req.id);
        let started = |what: &str| {
            self.hub.reply(page, id, Ok(format!("{what} started")));
        };
        let end = match req.cmd {
            Cmd::Run if lock(&self.hub.program).probing.is_some() => {
                let program = self.staged_program()?;
                started("program");
                self.run_staged(link, page, program)?
            }
            Cmd::Run => {
                let (compiled, lines) = self.program_to_run()?;
                started("program");
                let mut info = JobInfo::new("program", page, compiled.blocks.len());
                // The paths the compile derived, carried to the link's planner.
                let derived = compiled.derived();
                // With its mark: a job held when the station is gone is continued by
                // `nc-send resume PROGRAM` (the same file and options), and `resume`
                // without it says how much was never sent.
                let mark = job::program_mark(&compiled.blocks, lines);
                link.set_program(self.program_timeout, mark);
                let end = self.run_on(link, &compiled.blocks, derived, &mut info);
                link.set_program(None, pkmc::wire::JobMark::default());
                end?
            }
            Cmd::Step => {
                let blocks = self.programmed_blocks()?;
                if blocks.is_empty() {
                    return Ok(Some("nothing to run".into()));
                }
                started("run by step");
                let mut info = JobInfo::new("step", page, blocks.len());
                let first = vec![blocks[0]];
                info.steps = Some((blocks, 1, 0));
                self.run(link, &first, &mut info)?
            }
            Cmd::Hold => return self.control(link, Control::Hold),
            Cmd::Resume => return self.control(link, Control::Resume),
            Cmd::Stop => return self.control(link, Control::Abort),
            Cmd::Estop => {
                self.hub.request_estop();
                return self.control(link, Control::Stop);
            }
            Cmd::Reset => return self.control(link, Control::AlarmReset),
            Cmd::ScopeArm { .. } | Cmd::ScopeStop => return self.scope_command(link, req.cmd),
            Cmd::Tune { .. } | Cmd::TuneWrite => return self.tune_command(link, page, req.cmd),
            Cmd::Override { percent } => {
                return self.control(link, Control::FeedOverride(override_of(percent)?))
            }
            Cmd::JogStop => return Ok(Some("no jog runs".into())),
            Cmd::Jog {
                axis,
                distance,
                feed,
            } => {
                let cmd = jog(link, &axis, distance, feed)?;
                started("jog");
                let mut info = JobInfo::new("jog", page, 1);
                self.wait_move(link, cmd, &mut info)?
            }
            Cmd::JogStart { axis, dir, feed } => {
                let cmd = jog(link, &axis, dir.signum() * JOG_FAR_MM, feed)?;
                started("continuous jog");
                let mut info = JobInfo::new("jog_hold", page, 1);
                self.wait_move(link, cmd, &mut info)?
            }
            Cmd::Home => {
                let cmd = job::home_command(link)?;
                started("homing");
                let mut info = JobInfo::new("home", page, 1);
                self.wait_move(link, cmd, &mut info)?
            }
            Cmd::Mdi { text } => {
                let s = link.request_status()?;
                let line = self.mdi.compile(&text, s.pose)?;
                started("MDI");
                self.run_mdi(link, &line, page)?
            }
            Cmd::Joint {
                joint,
                distance,
                feed,
            } => {
                let s = link.request_status()?;
                let blocks = joint::joint_move(self.machine, &s, joint, distance, feed)?;
                started("joint move");
                let mut info = JobInfo::new("joint", page, blocks.len());
                self.run(link, &blocks, &mut info)?
            }
            Cmd::TeachRun | Cmd::TeachStep => {
                let step = matches!(req.cmd, Cmd::TeachStep);
                let s = link.request_status()?;
                let (text, total) = self.teach_program(step)?;
                let blocks =
                    job::compile_text_with(&text, "teach", self.machine, s.pose, &self.tools)?;
                started(if step { "teach step" } else { "teach run" });
                let mut info = JobInfo::new("teach", page, blocks.len().min(total));
                self.run(link, &blocks, &mut info)?
            }
            other => {
                return Err(Failure::new(
                    job::exit::BAD_INPUT,
                    format!("{} is not a machine command", other.name()),
                ))
            }
        };
        let s = link.request_status()?;
        self.publish(&s, None);
        self.report_end(&end);
        Ok(None)
    }

    /// The loaded program's blocks to stream, or as programmed (Run by Step); refused
    /// with the first error when it cannot run.
    /// The program as compiled (its blocks to stream, with their paths) and its
    /// text's lines.
    fn program_to_run(&self) -> Result<(job::Compiled, u32), Failure> {
        let p = lock(&self.hub.program);
        let lines = p.text.lines().count() as u32;
        match &p.compiled {
            Some(c) if p.runnable() => Ok((c.clone(), lines)),
            _ => Err(not_runnable(&p)),
        }
    }

    /// The program's blocks one by one, as programmed (Run by Step; not for a program
    /// that probes).
    fn programmed_blocks(&self) -> Result<Vec<Block>, Failure> {
        let p = lock(&self.hub.program);
        if !p.runnable() {
            return Err(not_runnable(&p));
        }
        if p.probing.is_some() {
            return Err(Failure::new(
                job::exit::BAD_INPUT,
                "Run by Step: not for a program that probes (G38); Run runs it a stage at \
                 a time",
            ));
        }
        Ok(p.programmed().to_vec())
    }

    fn control<T: Transport>(
        &mut self,
        link: &mut Link<T>,
        c: Control,
    ) -> Result<Option<String>, Failure> {
        link.control(c)?;
        if c == Control::Abort {
            link.release_held();
        }
        Ok(Some(format!("{c:?} sent")))
    }

    /// The teach list as a program: all of it, or the next position (Run by Step,
    /// which then moves on).
    fn teach_program(&self, step: bool) -> Result<(String, usize), Failure> {
        let axes: [bool; AXES] = job::machine_axes(self.machine);
        let mut t = lock(&self.hub.teach);
        if t.points.is_empty() {
            return Err(Failure::new(
                job::exit::BAD_INPUT,
                "the teach list is empty: Set Position first",
            ));
        }
        let text = if step {
            let i = t.next.unwrap_or(0).min(t.points.len() - 1);
            t.next = (i + 1 < t.points.len()).then_some(i + 1);
            super::program::teach_gcode(&t.points[i..=i], &axes, t.speed)
        } else {
            t.next = None;
            super::program::teach_gcode(&t.points, &axes, t.speed)
        };
        let n = if step { 1 } else { t.points.len() };
        drop(t);
        self.hub.publish_teach();
        Ok((text, n))
    }

    fn run<T: Transport>(
        &mut self,
        link: &mut Link<T>,
        blocks: &[Block],
        info: &mut JobInfo,
    ) -> Result<JobEnd, Failure> {
        self.run_on(link, blocks, None, info)
    }

    /// [`Self::run`] of blocks whose paths are `derived` already.
    fn run_on<T: Transport>(
        &mut self,
        link: &mut Link<T>,
        blocks: &[Block],
        derived: Option<Derived<'_>>,
        info: &mut JobInfo,
    ) -> Result<JobEnd, Failure> {
        self.last_job = info.kind;
        let mut hooks = Hooks { m: self, info };
        Ok(link.run_job_on(blocks, derived, &mut hooks)?)
    }

    fn wait_move<T: Transport>(
        &mut self,
        link: &mut Link<T>,
        cmd: Control,
        info: &mut JobInfo,
    ) -> Result<JobEnd, Failure> {
        self.last_job = info.kind;
        let mut hooks = Hooks { m: self, info };
        job::move_and_wait(link, cmd, &mut hooks)
    }

    /// What a job's end is worth saying: a program's end, an alarm, a stop. Jogs,
    /// MDI lines and joint moves that end as asked say nothing (a quiet log).
    fn report_end(&self, end: &JobEnd) {
        let kind = self.last_job;
        match end {
            JobEnd::Done if matches!(kind, "program" | "teach") => {
                self.hub.log("info", &format!("{kind} done"))
            }
            JobEnd::Done => {}
            JobEnd::Alarm(a) => self
                .hub
                .log("error", &format!("alarm: {}", AlarmView::new(a).words)),
            JobEnd::Aborted | JobEnd::Stopped => self.hub.log("warn", "stopped"),
            JobEnd::Paused(_) => self.hub.log("info", "paused: Resume continues"),
        }
    }
}

fn not_runnable(p: &super::program::Program) -> Failure {
    let why = match (p.compiled.is_some(), p.errors.first()) {
        (_, Some((l, c, m))) => format!("{}:{l}:{c}: {m}", p.name),
        (false, None) => "no program is loaded".to_string(),
        (true, None) => "the program cannot run".to_string(),
    };
    Failure::new(job::exit::BAD_INPUT, format!("not started: {why}"))
}

fn override_of(percent: f64) -> Result<u16, Failure> {
    if !(1.0..=200.0).contains(&percent) {
        return Err(Failure::new(
            job::exit::BAD_INPUT,
            format!("override {percent}: must be 1 to 200 percent"),
        ));
    }
    Ok(percent.round() as u16)
}

/// A jog of `distance` (mm or degrees) along `axis` at `feed` (mm/min or °/min),
/// checked as every jog is ([`job::jog_request`]).
fn jog<T: Transport>(
    link: &mut Link<T>,
    axis: &str,
    distance: f64,
    feed: f64,
) -> Result<Control, Failure> {
    let r = job::jog_request(axis, distance, feed, "feed")?;
    job::jog_command(link, r.axis, r.distance, r.feed)
}

/// The job's hooks: statuses published, the pages' commands while it runs.
struct Hooks<'m, 'a> {
    m: &'m mut Machine<'a>,
    info: &'m mut JobInfo,
}

impl Hooks<'_, '_> {
    /// A page's command while a job runs.
    fn during(&mut self, req: Request) {
        let reply = match req.cmd {
            Cmd::ScopeArm { .. } => return self.arm_during(req),
            Cmd::Hold => self.queue(Control::Hold),
            Cmd::Resume => self.queue(Control::Resume),
            Cmd::Stop => self.queue(Control::Abort),
            Cmd::Estop => {
                self.m.hub.request_estop();
                self.queue(Control::Stop)
            }
            Cmd::JogStop if self.info.kind == "jog_hold" => self.queue(Control::Abort),
            Cmd::JogStop => Ok("no continuous jog runs".into()),
            Cmd::ScopeStop => {
                lock(&self.m.hub.scope).disarm = true;
                self.m.scope_off();
                Ok("scope stopped (the recorder is disarmed when the job ends)".into())
            }
            Cmd::Override { percent } => override_of(percent)
                .map_err(|f| f.message)
                .and_then(|p| self.queue(Control::FeedOverride(p))),
            Cmd::Step => match self.info.steps.as_mut() {
                Some((_, _, pending)) => {
                    *pending += 1;
                    Ok("next block".into())
                }
                None => Err(format!(
                    "busy: a {} runs (Run by Step is not on)",
                    self.info.kind
                )),
            },
            other => Err(format!(
                "busy: a {} runs; {} waits until it ends (hold or stop it first)",
                self.info.kind,
                other.name()
            )),
        };
        self.m.hub.reply(req.page, req.id, reply);
    }

    fn queue(&mut self, c: Control) -> Result<String, String> {
        self.info.controls.push_back(c);
        Ok(format!("{c:?} sent"))
    }

    /// The page that started the job has gone: a jog (which needs its operator's
    /// hand on the button) stops once that page is silent for
    /// [`super::hub::HEARTBEAT_LOST`] or closed; anything else is held on its path when
    /// the page closes, for another page to resume or stop.
    fn watch_heartbeat(&mut self) {
        if self.info.orphaned {
            return;
        }
        let hub = self.m.hub;
        let jog = matches!(self.info.kind, "jog_hold" | "jog" | "joint");
        let lost = if jog {
            !hub.heard_within(self.info.owner, super::hub::HEARTBEAT_LOST)
        } else {
            !hub.connected(self.info.owner)
        };
        if !lost {
            return;
        }
        self.info.orphaned = true;
        let (c, what) = if jog {
            (Control::Abort, "stopped")
        } else {
            (Control::Hold, "held")
        };
        self.info.controls.push_back(c);
        hub.log(
            "warn",
            &format!(
                "the page that started the {} is gone: motion {what}",
                self.info.kind
            ),
        );
    }
}

impl JobHooks for Hooks<'_, '_> {
    fn status(&mut self, s: &Status) {
        self.m.publish(s, Some(self.info));
    }

    fn control(&mut self, view: &LinkView) -> Option<Control> {
        self.info.executed = (self.info.base + view.executed).min(self.info.total);
        self.watch_heartbeat();
        while let Ok(req) = self.m.rx.try_recv() {
            self.during(req);
        }
        self.info.controls.pop_front()
    }

    fn recorded(&mut self, pieces: &mut Vec<crate::link::Piece>) {
        if !pieces.is_empty() {
            self.m.scope_pieces(std::mem::take(pieces));
        }
    }

    fn record_ask(&mut self) -> Option<u32> {
        self.info.scope.ask(self.m.hub)
    }

    fn record_answer(&mut self, reply: &pkmc::drive::recorder::Reply, data: &[u8]) {
        self.info.scope.answer(self.m.hub, reply, data);
    }

    fn record_arm(&mut self) -> Option<pkmc::drive::recorder::Setup> {
        self.arm_now()
    }

    fn record_armed(&mut self, refused: Option<String>) {
        self.armed(refused);
    }

    fn feed(&mut self, view: &LinkView, out: &mut Vec<Block>) -> bool {
        let Some((blocks, fed, pending)) = self.info.steps.as_mut() else {
            return false;
        };
        if *pending > 0 && view.executed >= view.total && *fed < blocks.len() {
            out.push(blocks[*fed]);
            *fed += 1;
            *pending -= 1;
        }
        *fed < blocks.len()
    }
}
