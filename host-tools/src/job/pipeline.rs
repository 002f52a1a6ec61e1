//! The one way G-code becomes blocks a machine can run: the front end's canonical
//! commands made into protocol blocks ([`crate::gcode::blocks::from_canon`]), merged
//! into curves when asked, and checked by the pre-flight ([`checked`]). A whole
//! program comes to it from [`crate::gcode::compile_canon`] (runs, `--check`, the
//! station's program); a line at a time through [`LinePipeline`] (the station's MDI,
//! the Grbl bridge feeding a running job): the front end's modal state kept from line
//! to line, M2/M30 ending the program there, and a refused line leaving the
//! interpreter where the machine will be.

use super::compile::{for_machine, machine_axes, Compiled};
use crate::analysis::preflight::{self, Preflight};
use crate::gcode::interp::probe::{ProbeOutcome, Probing};
use crate::gcode::{self, canon::Canon, LineSession};
use pkmc::config::{MachineConfig, AXES};
use pkmc::motion::block::Block;
use std::collections::BTreeMap;

/// The front end's options for `machine`: its axes, the tool table `tools`, the
/// program starting at `start`.
pub fn front_end_options(
    machine: &MachineConfig,
    start: [i64; AXES],
    tools: &gcode::ToolTable,
) -> gcode::Options {
    gcode::Options {
        start,
        axes: machine_axes(machine),
        tools: tools.clone(),
        ..gcode::Options::default()
    }
}

/// Blocks made of canonical commands, and what was found in them.
pub struct Checked {
    /// The blocks: to stream, as programmed, and which stand for which.
    pub compiled: Compiled,
    /// The pre-flight of the blocks to stream.
    pub preflight: Preflight,
    /// `(MSG, …)` texts by NC line.
    pub messages: BTreeMap<u32, String>,
}

/// `canon` (starting at `start`) as blocks for `machine`, runs of short moves merged
/// into curves with `compress` (completed with the machine's figures; `None`: as
/// programmed), with the pre-flight of the blocks that will be streamed.
pub fn checked(
    canon: &[Canon],
    machine: &MachineConfig,
    start: [i64; AXES],
    compress: Option<&gcode::compress::Settings>,
) -> Checked {
    checked_with(canon, machine, start, compress, None)
}

/// [`checked`], with the statics of the blocks under `statics`' cutting load: each
/// block's path is derived once, here, and read by the pre-flight and the statics.
pub fn checked_with(
    canon: &[Canon],
    machine: &MachineConfig,
    start: [i64; AXES],
    compress: Option<&gcode::compress::Settings>,
    statics: Option<&super::StaticsSpec>,
) -> Checked {
    let program = gcode::blocks::from_canon(canon, start);
    let compiled = match compress {
        Some(settings) => {
            let settings = for_machine(settings, machine);
            let c = gcode::compress::compress(&program.blocks, start, &settings);
            Compiled {
                blocks: c.blocks,
                programmed: program.blocks,
                source: c.source,
                start,
                ..Compiled::default()
            }
        }
        None => Compiled {
            source: (0..program.blocks.len()).map(|i| i..i + 1).collect(),
            blocks: program.blocks.clone(),
            programmed: program.blocks,
            start,
            ..Compiled::default()
        },
    };
    let mut compiled = compiled;
    let paths = preflight::paths(&compiled.blocks, start);
    let chords = preflight::Chords {
        programmed: &compiled.programmed,
        first: 0,
        start,
        source: &compiled.source,
    };
    let preflight = preflight::check_paths(&compiled.blocks, &paths, machine, start, Some(&chords));
    compiled.statics = statics.map(|spec| {
        let b = &compiled.blocks;
        crate::analysis::statics::check_paths(b, &paths, machine, start, &spec.loads, &spec.limits)
    });
    compiled.preflight = Some(preflight.clone());
    compiled.paths = paths
        .into_iter()
        .collect::<Result<_, _>>()
        .unwrap_or_default();
    Checked {
        compiled,
        preflight,
        messages: program.messages,
    }
}

/// Why a line was refused. Nothing of it runs, and the interpreter stands where the
/// machine will be.
#[derive(Clone, Debug, PartialEq)]
pub enum LineFault {
    /// The front end refused it, at its line and column.
    FrontEnd(gcode::Diagnostic),
    /// The caller's own check of its commands refused it (the words say why).
    Vetted(String),
    /// The pre-flight refused its blocks: the first finding, as `name:line: what`.
    Preflight(String),
}

impl std::fmt::Display for LineFault {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            LineFault::FrontEnd(d) => write!(f, "{d}"),
            LineFault::Vetted(m) | LineFault::Preflight(m) => f.write_str(m),
        }
    }
}

impl From<LineFault> for super::Failure {
    fn from(fault: LineFault) -> Self {
        super::Failure::new(super::exit::BAD_INPUT, fault.to_string())
    }
}

/// What a line accepted makes.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LineBlocks {
    /// Its blocks, checked against the machine's reach.
    pub blocks: Vec<Block>,
    /// Its `(MSG, …)` texts by NC line.
    pub messages: BTreeMap<u32, String>,
    /// It ended the program (M2, M30): the next line starts afresh.
    pub ended: bool,
    /// It ends with a probing move (G38.2–G38.5, with [`gcode::Options::probing`]):
    /// its feed move, pre-flighted, from where `blocks` end, to run after them as
    /// [`crate::job::probing::probe`] runs one; the pipeline takes no line until
    /// [`LinePipeline::probed`] gives what it found.
    pub probe: Option<(Block, Probing)>,
}

/// G-code a line at a time for `machine`: the modal state kept between lines (G91,
/// G20, F, work offsets …), as an MDI or a sender streaming a program line by line
/// needs; each line's blocks checked as a program's are ([`checked`]).
pub struct LinePipeline<'o> {
    session: LineSession<'o>,
    machine: &'o MachineConfig,
    name: String,
}

impl<'o> LinePipeline<'o> {
    /// A pipeline at program start with `options` ([`front_end_options`]); errors
    /// and findings name `name` (`MDI`, `sender`).
    pub fn new(options: &'o gcode::Options, machine: &'o MachineConfig, name: &str) -> Self {
        Self {
            session: LineSession::new(options, name),
            machine,
            name: name.to_string(),
        }
    }

    /// The interpreter, for its state (where the machine will be, offsets, modes).
    pub fn interp(&self) -> &gcode::interp::Interp<'o> {
        self.session.interp()
    }

    /// The machine now stands at `pose` (machine frame): the next line starts there.
    pub fn set_position(&mut self, pose: [i64; AXES]) {
        self.session.set_position(pose);
    }

    /// Back to the state at program start at `pose`, keeping the parameters (a soft
    /// reset).
    pub fn restart(&mut self, pose: [i64; AXES]) {
        self.session.restart(pose);
    }

    /// One line, numbered `number`, from where the interpreter stands.
    pub fn line(&mut self, text: &str, number: u32) -> Result<LineBlocks, LineFault> {
        self.line_vetted(text, number, |_| Ok(()))
    }

    /// [`Self::line`], with `vet` asked about the line's commands before anything of
    /// them is kept (a command the caller cannot carry out).
    pub fn line_vetted(
        &mut self,
        text: &str,
        number: u32,
        vet: impl FnOnce(&[Canon]) -> Result<(), String>,
    ) -> Result<LineBlocks, LineFault> {
        let start = self.session.interp().pos;
        let mut canon = vec![Canon::PathMode {
            line: number,
            mode: self.session.interp().path,
        }];
        // The front end may have moved its position before it found the fault: back
        // to where the machine will be, as after any refused line.
        let refused = |this: &mut Self, fault| {
            this.session.set_position(start);
            Err(fault)
        };
        if let Err(d) = self.session.line(text, number, &mut canon) {
            return refused(self, LineFault::FrontEnd(d));
        }
        if let Err(why) = vet(&canon) {
            return refused(self, LineFault::Vetted(why));
        }
        let ended = self.session.ended();
        let probing = match canon.last() {
            _ if !self.session.waiting() => None,
            Some(Canon::Probe { probing, .. }) if !ended => Some(*probing),
            // A stop (M0, M1, M2, M30) on the probing move's line comes after it.
            _ => {
                let why = format!(
                    "{}:{number}: a probing move and a stop or program end (M0, M1, M2, \
                     M30) on one line: put the stop on a line of its own",
                    self.name
                );
                return refused(self, LineFault::Vetted(why));
            }
        };
        if ended {
            // M2/M30: what compensation holds ends here; the next line starts afresh.
            let _ = self.session.finish(number, &mut canon);
            let pos = self.session.interp().pos;
            self.session.restart(pos);
        }
        let c = checked(&canon, self.machine, start, None);
        if let Some(f) = c.preflight.findings.first() {
            let why = format!("{}:{}: {}", self.name, f.line, f.what);
            return refused(self, LineFault::Preflight(why));
        }
        let mut blocks = c.compiled.blocks;
        // The probing move is the last command, so its block is the last block.
        let probe = probing.and_then(|p| blocks.pop().map(|b| (b, p)));
        Ok(LineBlocks {
            blocks,
            messages: c.messages,
            ended,
            probe,
        })
    }

    /// Is a probing move waiting for its outcome ([`LineBlocks::probe`])?
    pub fn waiting(&self) -> bool {
        self.session.waiting()
    }

    /// What the probing move of line `number` found: the next line starts where the
    /// machine stopped, with #5061–#5070 set. A G38.2 or G38.4 that ended without the
    /// change is refused at its column (the position and parameters are set all the
    /// same).
    pub fn probed(&mut self, outcome: &ProbeOutcome, number: u32) -> Result<(), LineFault> {
        self.session
            .probed(outcome, number)
            .map_err(LineFault::FrontEnd)
    }
}
