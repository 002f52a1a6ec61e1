//! Programs that probe (G38.2–G38.5): run a stage at a time.
//!
//! What follows a probing move may depend on what it found, so the front end stops at
//! the first probing move whose outcome it does not have
//! ([`crate::gcode::interp::probe`]). A run here goes in stages:
//!
//! 1. compile the program with the outcomes so far ([`stage`]); its blocks after the
//!    last probing move with a known outcome, up to the next probing move, are a
//!    stage, compiled and pre-flighted as any program is, from where the machine
//!    stopped;
//! 2. stream the stage as a job and wait for it to end;
//! 3. send the probing move as `Control::Probe` (planned from the controller's pose,
//!    as a jog), wait until the machine stands still, and read the result: the joints
//!    latched at the probe's change, through the machine's forward kinematics, give
//!    the probed pose, and the status gives where the machine stopped;
//! 4. compile again with that outcome, and go on from 1 until a stage ends the
//!    program.
//!
//! A G38.2 or G38.4 that ends without the change stops the run at the next compile,
//! which refuses it at its line. A probe already in the state a move seeks raises the
//! controller's alarm `ProbeAtStart`: the run ends in alarm. Each stage is a job of
//! its own: a replug or `resume` takes up a stage, not the whole program.

use super::compile::{refuse_findings, refused};
use super::{exit, pipeline, Failure};
use crate::gcode::{self, canon::Canon, interp::probe::ProbeOutcome, interp::probe::Probing};
use crate::link::{JobEnd, JobHooks, Link, Transport};
use pkmc::config::{MachineConfig, AXES, MAX_JOINTS};
use pkmc::drive::probe::{ProbeMode, LATCH_FRAC_BITS};
use pkmc::kinematics::{Kinematics, MachineKinematics};
use pkmc::motion::block::Block;
use pkmc::wire::Control;
use serde::Serialize;

/// Axis units per mm (linear) and per degree (rotary).
const UNIT: [f64; 2] = [1e6, 1e9];

/// Does the program text name G38 anywhere (spaces and case aside)? Only such a
/// program is compiled a stage at a time.
pub fn names_g38(text: &str) -> bool {
    let mut last = [0u8; 3];
    text.bytes().filter(|b| !b.is_ascii_whitespace()).any(|b| {
        last = [last[1], last[2], b.to_ascii_uppercase()];
        &last == b"G38"
    })
}

/// [`names_g38`] of the program file at `path` (false when it cannot be read: the
/// compile that follows says why).
pub fn file_names_g38(path: &std::path::Path) -> bool {
    crate::input::read_text(path, crate::input::MAX_PROGRAM_BYTES).is_ok_and(|t| names_g38(&t))
}

/// A program that probes, and how to compile it.
pub struct ProbingProgram<'a> {
    /// Its text.
    pub text: &'a str,
    /// Its name in messages.
    pub name: &'a str,
    /// The machine.
    pub machine: &'a MachineConfig,
    /// Where it starts.
    pub start: [i64; AXES],
    /// The tool table.
    pub tools: &'a gcode::ToolTable,
    /// Merging of short moves (`None`: as programmed).
    pub compress: Option<&'a gcode::compress::Settings>,
}

/// One stage: the blocks up to the next probing move, and that move.
pub struct Stage {
    /// The blocks to stream first.
    pub compiled: super::Compiled,
    /// The probing move after them (`None`: the stage ends the program).
    pub probe: Option<(Block, Probing)>,
}

/// What a probing move found, for the report.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct ProbeRecord {
    /// NC line of the G38.
    pub line: u32,
    /// Which one (`G38.2` …).
    pub code: &'static str,
    /// The probe changed as sought.
    pub contact: bool,
    /// The probed pose, machine frame: X Y Z mm, A B C degrees.
    pub position: [f64; AXES],
    /// The joints latched, mm or degrees.
    pub joints: Vec<f64>,
    /// Where the machine stopped, machine frame: X Y Z mm, A B C degrees.
    pub stopped: [f64; AXES],
}

/// Does `canon` (a compile with probing allowed) stop at a probing move?
pub fn stops_at_probe(canon: &[Canon]) -> bool {
    matches!(canon.last(), Some(Canon::Probe { outcome: None, .. }))
}

/// Compiles `p` with `outcomes` and returns the stage after them.
pub fn stage(p: &ProbingProgram<'_>, outcomes: &[ProbeOutcome]) -> Result<Stage, Failure> {
    stage_located(p, outcomes).map_err(|r| r.failure)
}

/// Why a stage cannot run: the failure as nc-send reports it, and where in the program
/// (the first error's line, column and message) when it is the program's fault.
pub struct StageRefused {
    /// The whole failure.
    pub failure: Failure,
    /// Line, column and what is wrong there.
    pub at: Option<(usize, usize, String)>,
}

/// [`stage`], its refusal located.
fn stage_located(p: &ProbingProgram<'_>, outcomes: &[ProbeOutcome]) -> Result<Stage, StageRefused> {
    let mut options = pipeline::front_end_options(p.machine, p.start, p.tools);
    options.probing = true;
    options.probes = outcomes.to_vec();
    let canon = gcode::compile_canon(p.text, p.name, &options).map_err(|e| StageRefused {
        at: e.first().map(|d| (d.line, d.col, d.message.clone())),
        failure: match outcomes {
            [] => refused(&e),
            // Past a probing move (a G38.2 or G38.4 that found nothing, or what
            // follows): the program stops there, with what ran so far.
            _ => Failure::new(
                exit::ALARM,
                format!(
                    "{}\nthe program stopped there, after {} probing move(s)",
                    e.iter()
                        .map(|d| d.to_string())
                        .collect::<Vec<_>>()
                        .join("\n"),
                    outcomes.len()
                ),
            ),
        },
    })?;
    let from = canon
        .iter()
        .rposition(|c| {
            matches!(
                c,
                Canon::Probe {
                    outcome: Some(_),
                    ..
                }
            )
        })
        .map_or(0, |i| i + 1);
    let pending = stops_at_probe(&canon);
    let end = canon.len() - pending as usize;
    // The path mode in force where the stage starts.
    let mode = canon[..from].iter().rev().find_map(|c| match c {
        Canon::PathMode { mode, .. } => Some(*mode),
        _ => None,
    });
    let mut part: Vec<Canon> = mode
        .map(|mode| Canon::PathMode { line: 0, mode })
        .into_iter()
        .collect();
    part.extend_from_slice(&canon[from..end]);
    let start = outcomes.last().map_or(p.start, |o| o.stopped);
    let checked = pipeline::checked(&part, p.machine, start, p.compress);
    let at = checked
        .preflight
        .findings
        .first()
        .map(|f| (f.line as usize, 1, f.what.clone()));
    refuse_findings(p.name, checked.preflight).map_err(|failure| StageRefused { failure, at })?;
    let probe = match canon.last() {
        Some(c @ Canon::Probe { probing, .. }) if pending => {
            let at = super::pose_after(&checked.compiled.blocks, start);
            let blocks = gcode::blocks::from_canon(std::slice::from_ref(c), at).blocks;
            blocks.first().map(|b| (*b, *probing))
        }
        _ => None,
    };
    Ok(Stage {
        compiled: checked.compiled,
        probe,
    })
}

/// Most probing moves a preview takes to their programmed ends ([`preview`]); past
/// them it stops at the next one.
pub const PREVIEW_PROBES: usize = 500;

/// A program that probes, as far as it can be known before it runs: compiled with each
/// probing move taken to its programmed end and touching there (its outcome a
/// change, found and stopped at the move's end), up to [`PREVIEW_PROBES`] of them.
/// What follows a probing move follows from that assumed outcome; the run finds the
/// real ones. Returns the blocks (each probing move a straight feed move to its end)
/// with their pre-flight, and each probing move's line and code; or the front end's
/// errors, each at its place.
#[allow(clippy::type_complexity)]
pub fn preview(
    p: &ProbingProgram<'_>,
) -> Result<
    (
        super::Compiled,
        crate::analysis::preflight::Preflight,
        Vec<(u32, &'static str)>,
    ),
    Vec<gcode::Diagnostic>,
> {
    let mut options = pipeline::front_end_options(p.machine, p.start, p.tools);
    options.probing = true;
    let mut moves = Vec::new();
    loop {
        let canon = gcode::compile_canon(p.text, p.name, &options)?;
        let pending = match canon.last() {
            Some(Canon::Probe {
                line,
                target,
                probing,
                outcome: None,
                ..
            }) => Some((*line, *target, probing.name())),
            _ => None,
        };
        match pending {
            Some((line, target, code)) if moves.len() < PREVIEW_PROBES => {
                moves.push((line, code));
                options.probes.push(ProbeOutcome {
                    changed: true,
                    probed: target,
                    stopped: target,
                });
            }
            _ => {
                let checked = pipeline::checked(&canon, p.machine, p.start, p.compress);
                return Ok((checked.compiled, checked.preflight, moves));
            }
        }
    }
}

/// What a run a stage at a time ([`run_on`]) tells its caller besides the jobs' hooks.
pub trait ProbingHooks: JobHooks {
    /// A stage of `blocks` blocks is about to stream.
    fn stage(&mut self, _blocks: usize) {}
    /// Do these hooks want each probed position in the program's frame too (one more
    /// run of the front end per probing move)?
    fn wants_program_frame(&self) -> bool {
        false
    }
    /// A probing move's result, as soon as it is known; with the probed X Y Z in the
    /// program's frame (mm: the work offset, G92 and the tool offset taken off; `None`
    /// when not asked for, or in a rotated coordinate system).
    fn probed(&mut self, _record: &ProbeRecord, _program: Option<[f64; 3]>) {}
    /// The program cannot go on: the error at `line`, `col` (the run then ends with
    /// the failure that says so).
    fn refused(&mut self, _line: usize, _col: usize, _message: &str) {}
}

/// A job's hooks, and nothing more, for a run a stage at a time (nc-send's).
pub struct Plain<'h>(pub &'h mut dyn JobHooks);

impl JobHooks for Plain<'_> {
    fn status(&mut self, s: &pkmc::wire::Status) {
        self.0.status(s)
    }
    fn control(&mut self, view: &crate::link::LinkView) -> Option<Control> {
        self.0.control(view)
    }
    fn ends_at_pause(&self) -> bool {
        self.0.ends_at_pause()
    }
    fn feed(&mut self, view: &crate::link::LinkView, out: &mut Vec<Block>) -> bool {
        self.0.feed(view, out)
    }
    fn rewind(&mut self, to: usize) -> Option<crate::link::Rewound> {
        self.0.rewind(to)
    }
    fn note(&mut self, text: &str) {
        self.0.note(text)
    }
    fn warn(&mut self, text: &str) {
        self.0.warn(text)
    }
}

impl ProbingHooks for Plain<'_> {}

/// The work offset in force at the probing move after `outcomes` (machine units: the
/// machine position minus it is the program's), from one more run of the front end,
/// which waits there; `None` in a rotated coordinate system (G10 L2 R), where the
/// program's frame is more than an offset.
fn work_offset(p: &ProbingProgram<'_>, outcomes: &[ProbeOutcome]) -> Option<[i64; AXES]> {
    let mut options = pipeline::front_end_options(p.machine, p.start, p.tools);
    options.probing = true;
    options.probes = outcomes.to_vec();
    let mut interp = gcode::interp::Interp::new(&options);
    let program = gcode::flow::Program::index(p.text, options.block_delete, &interp.params);
    let (mut out, mut errors) = (Vec::new(), Vec::new());
    if !program.broken {
        gcode::flow::run(&program, p.text, p.name, &mut interp, &mut out, &mut errors);
    }
    (interp.waiting() && errors.is_empty() && !interp.rotated()).then(|| interp.work_offset())
}

/// The pose of the joints `at` (actuator units × 2^[`LATCH_FRAC_BITS`], as latched)
/// through `machine`'s forward kinematics from `guess`, and the joints (axis units).
pub fn latched_pose(
    machine: &MachineConfig,
    at: &[i64; MAX_JOINTS],
    guess: &[i64; AXES],
) -> Result<([i64; AXES], [i64; MAX_JOINTS]), Failure> {
    let mut q = [0i64; MAX_JOINTS];
    for (j, jc) in machine.joints.iter().enumerate() {
        let den = (jc.scale.steps as i128) << LATCH_FRAC_BITS;
        q[j] = pkmc::units::div_round(at[j] as i128 * jc.scale.per_units as i128, den) as i64;
    }
    let kin = MachineKinematics::new(machine);
    let mut pose = *guess;
    kin.forward(&q, guess, &mut pose).map_err(|e| {
        Failure::new(
            exit::ALARM,
            format!("the probed joints have no pose (forward kinematics: {e:?})"),
        )
    })?;
    Ok((pose, q))
}

/// Runs `p` on `link` a stage at a time (module documentation): how the run ended,
/// what each probing move found, and how many blocks and moves were sent.
pub fn run_on<T: Transport>(
    link: &mut Link<T>,
    p: &ProbingProgram<'_>,
    hooks: &mut dyn ProbingHooks,
) -> Result<(JobEnd, Vec<ProbeRecord>, usize), Failure> {
    let mut outcomes = Vec::new();
    let mut records = Vec::new();
    let mut sent = 0;
    loop {
        let st = match stage_located(p, &outcomes) {
            Ok(st) => st,
            Err(r) => {
                if let Some((line, col, message)) = &r.at {
                    hooks.refused(*line, *col, message);
                }
                return Err(r.failure);
            }
        };
        hooks.stage(st.compiled.blocks.len());
        sent += st.compiled.blocks.len();
        if !st.compiled.blocks.is_empty() {
            let end = link.run_job_on(&st.compiled.blocks, st.compiled.derived(), hooks)?;
            if end != JobEnd::Done {
                return Ok((end, records, sent));
            }
        }
        let Some((block, probing)) = st.probe else {
            return Ok((JobEnd::Done, records, sent));
        };
        let offset = match hooks.wants_program_frame() {
            true => work_offset(p, &outcomes),
            false => None,
        };
        let (found, end) = probe(link, p.machine, &block, probing, hooks)?;
        sent += 1;
        let Some((outcome, record)) = found else {
            return Ok((end, records, sent));
        };
        let program = offset
            .map(|off| std::array::from_fn(|i| (outcome.probed[i] - off[i]) as f64 / UNIT[0]));
        hooks.probed(&record, program);
        outcomes.push(outcome);
        records.push(record);
    }
}

/// One probing move from where the controller stands: its outcome and record, or
/// (`None`) how the move ended when it did not end at rest (an alarm). `block` is the
/// G38 line's feed move (its start is where the machine stands). The staged program
/// runs its moves with it, and so do the Grbl bridge and the station's MDI line by line.
#[allow(clippy::type_complexity)]
pub(crate) fn probe<T: Transport>(
    link: &mut Link<T>,
    machine: &MachineConfig,
    block: &Block,
    probing: Probing,
    hooks: &mut dyn JobHooks,
) -> Result<(Option<(ProbeOutcome, ProbeRecord)>, JobEnd), Failure> {
    let before = link.request_status()?;
    let kin = MachineKinematics::new(machine);
    let mut block = *block;
    // The feed move of the G38 line, from where the machine stands (the stage ended
    // there: the same pose but for the rounding of a stop).
    block.tolerance_nm = 0;
    let planned =
        pkmc::motion::planner::plan_move(&block, before.pose, machine, &kin).map_err(|e| {
            Failure::new(
                exit::BAD_INPUT,
                format!(
                    "line {}: {} cannot be planned: {e:?}",
                    block.line,
                    probing.name()
                ),
            )
        })?;
    let mode = match probing.toward {
        true => ProbeMode::Touch,
        false => ProbeMode::Release,
    };
    link.control(Control::Probe { planned, mode })?;
    let end = link.wait_idle(hooks)?;
    if end != JobEnd::Done {
        return Ok((None, end));
    }
    let (status, result) = link.request_probe()?;
    let r = result.filter(|r| r.count != before.probes).ok_or_else(|| {
        Failure::new(
            exit::ALARM,
            format!(
                "line {}: the controller did not make the {} move (it refuses one that does \
                 not start where it stands)",
                block.line,
                probing.name()
            ),
        )
    })?;
    let (probed, q) = latched_pose(machine, &r.at, &status.pose)?;
    let outcome = ProbeOutcome {
        changed: r.contact,
        probed,
        stopped: status.pose,
    };
    let user = |p: &[i64; AXES]| std::array::from_fn(|i| p[i] as f64 / UNIT[(i >= 3) as usize]);
    let record = ProbeRecord {
        line: block.line,
        code: probing.name(),
        contact: r.contact,
        position: user(&probed),
        joints: machine
            .joints
            .iter()
            .enumerate()
            .map(|(j, jc)| q[j] as f64 / UNIT[jc.rotary as usize])
            .collect(),
        stopped: user(&status.pose),
    };
    Ok((Some((outcome, record)), JobEnd::Done))
}
