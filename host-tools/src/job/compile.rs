//! G-code to blocks for a machine: compiling a program or an MDI line, refusing axes
//! the machine lacks, and the pre-flight findings in words.

use super::{exit, Failure};
use crate::gcode;
use pkmc::config::{MachineConfig, AXES};
use pkmc::motion::block::Block;
use std::path::Path;

/// Reads and compiles a program for `machine`; checks every block end against the
/// machine's reach.
pub fn compile_program(
    path: &Path,
    machine: &MachineConfig,
    tools: &gcode::ToolTable,
) -> Result<Vec<Block>, Failure> {
    compile_job(path, machine, tools, None).map(|c| c.blocks)
}

/// A program compiled for streaming: its blocks, and what they stand for when the
/// compressor merged chords into curves.
#[derive(Clone, Debug, Default)]
pub struct Compiled {
    /// The blocks to stream.
    pub blocks: Vec<Block>,
    /// The blocks as programmed (before compression).
    pub programmed: Vec<Block>,
    /// For each streamed block, the programmed blocks it stands for.
    pub source: Vec<std::ops::Range<usize>>,
    /// Where the program starts.
    pub start: [i64; AXES],
    /// The pre-flight of `blocks` from `start`, as the compile ran it (`None`: not run,
    /// as for a restart's blocks).
    pub preflight: Option<crate::analysis::preflight::Preflight>,
    /// The statics of `blocks` from `start` under the cutting load the compile was
    /// given (`None`: none given), on the paths the pre-flight read.
    pub statics: Option<Result<crate::analysis::statics::Statics, String>>,
    /// Each block's path from `start` on, as the pre-flight derived them (empty: not
    /// derived, or a block is malformed): the link plans on them
    /// ([`Compiled::derived`]).
    pub paths: Vec<pkmc::motion::geometry::Path>,
}

impl Compiled {
    /// The programmed moves its blocks stand for, for the pre-flight to name a
    /// finding on a merged curve at its programmed move.
    pub fn chords(&self) -> crate::analysis::preflight::Chords<'_> {
        crate::analysis::preflight::Chords {
            programmed: &self.programmed,
            first: 0,
            start: self.start,
            source: &self.source,
        }
    }

    /// A meter of how far the merged curves stray from their chords.
    pub fn deviation_meter(&self) -> crate::analysis::deviation::Meter {
        crate::analysis::deviation::Meter::new(
            &self.programmed,
            &self.blocks,
            &self.source,
            self.start,
        )
    }

    /// The paths of `blocks` as the compile derived them, for the link
    /// ([`crate::link::Link::run_job_on`]); `None` when they were not derived.
    pub fn derived(&self) -> Option<crate::link::Derived<'_>> {
        (!self.paths.is_empty() && self.paths.len() == self.blocks.len()).then_some(
            crate::link::Derived {
                start: self.start,
                paths: &self.paths,
            },
        )
    }

    /// Curves among the streamed blocks.
    pub fn curves(&self) -> usize {
        self.blocks
            .iter()
            .filter(|b| matches!(b.motion, pkmc::motion::block::Motion::Cubic { .. }))
            .count()
    }
}

/// Reads and compiles a program for `machine`, merging runs of short moves into curves
/// with `compress` ([`gcode::compress`]; `None`: as programmed); the pre-flight checks
/// the blocks that will be streamed.
pub fn compile_job(
    path: &Path,
    machine: &MachineConfig,
    tools: &gcode::ToolTable,
    compress: Option<&gcode::compress::Settings>,
) -> Result<Compiled, Failure> {
    let text = crate::input::read_text(path, crate::input::MAX_PROGRAM_BYTES)
        .map_err(|m| Failure::new(exit::BAD_INPUT, m))?;
    let name = path.display().to_string();
    compile_compressed(&text, &name, machine, machine.home, tools, compress)
}

/// [`compile_job`] with `opts`' tool table, compression and cutting load: the statics
/// is computed in the compile, on the paths the pre-flight derived
/// ([`Compiled::statics`]).
pub fn compile_for(
    path: &Path,
    machine: &MachineConfig,
    opts: &super::RunOptions<'_>,
) -> Result<Compiled, Failure> {
    let text = crate::input::read_text(path, crate::input::MAX_PROGRAM_BYTES)
        .map_err(|m| Failure::new(exit::BAD_INPUT, m))?;
    let name = path.display().to_string();
    let options = super::pipeline::front_end_options(machine, machine.home, &opts.tools);
    let canon = gcode::compile_canon(&text, &name, &options).map_err(|errs| refused(&errs))?;
    let compress = opts.compress.as_ref();
    let statics = opts.statics.as_ref();
    let c = super::pipeline::checked_with(&canon, machine, machine.home, compress, statics);
    refuse_findings(&name, c.preflight)?;
    Ok(c.compiled)
}

/// Compiles program text named `name` for `machine`, starting from pose `start`;
/// refuses axis words for axes the machine lacks ([`machine_axes`]) and checks every
/// block end against the machine's reach. The one place where G-code becomes blocks
/// (files through [`compile_program`], MDI lines directly).
pub fn compile_text(
    text: &str,
    name: &str,
    machine: &MachineConfig,
    start: [i64; AXES],
) -> Result<Vec<Block>, Failure> {
    compile_text_with(text, name, machine, start, &gcode::ToolTable::new())
}

/// [`compile_text`] with the tool table `tools`.
pub fn compile_text_with(
    text: &str,
    name: &str,
    machine: &MachineConfig,
    start: [i64; AXES],
    tools: &gcode::ToolTable,
) -> Result<Vec<Block>, Failure> {
    compile_compressed(text, name, machine, start, tools, None).map(|c| c.blocks)
}

/// [`compile_text_with`], merging chords into curves with `compress` (the settings
/// are completed with `machine`'s figures, as for a program file).
pub fn compile_compressed(
    text: &str,
    name: &str,
    machine: &MachineConfig,
    start: [i64; AXES],
    tools: &gcode::ToolTable,
    compress: Option<&gcode::compress::Settings>,
) -> Result<Compiled, Failure> {
    let (compiled, report) = compile_located(text, name, machine, start, tools, compress)
        .map_err(|errs| refused(&errs))?;
    refuse_findings(name, report)?;
    Ok(compiled)
}

/// A pre-flight with findings as the failure nc-send reports (nothing was sent).
pub(super) fn refuse_findings(
    name: &str,
    report: crate::analysis::preflight::Preflight,
) -> Result<(), Failure> {
    if !report.findings.is_empty() {
        let lines = findings_text(name, &report.findings);
        return Err(Failure::new(
            exit::PREFLIGHT,
            format!(
                "{}\n{} pre-flight problem(s); nothing was sent",
                lines.join("\n"),
                report.findings.len()
            ),
        ));
    }
    Ok(())
}

/// [`compile_compressed`] with its results as they are: the front end's errors, each
/// at its line and column, or the blocks with the pre-flight of the blocks to stream
/// (for a page that marks them in its editor).
pub fn compile_located(
    text: &str,
    name: &str,
    machine: &MachineConfig,
    start: [i64; AXES],
    tools: &gcode::ToolTable,
    compress: Option<&gcode::compress::Settings>,
) -> Result<(Compiled, crate::analysis::preflight::Preflight), Vec<gcode::Diagnostic>> {
    let options = super::pipeline::front_end_options(machine, start, tools);
    let canon = gcode::compile_canon(text, name, &options)?;
    let c = super::pipeline::checked(&canon, machine, start, compress);
    Ok((c.compiled, c.preflight))
}

/// The front end's errors as the failure nc-send reports: each at its place, and how
/// many; nothing was sent.
pub(super) fn refused(errs: &[gcode::Diagnostic]) -> Failure {
    let lines: Vec<String> = errs.iter().map(|d| d.to_string()).collect();
    Failure::new(
        exit::BAD_INPUT,
        format!(
            "{}\n{} error(s); nothing was sent",
            lines.join("\n"),
            errs.len()
        ),
    )
}

/// The pre-flight findings as lines of text: a run of the same problem on consecutive
/// NC lines (a stretch of a program out of travel, thousands of lines of CAM output)
/// is one line naming its first and last line and how many, at its first pose.
pub(super) fn findings_text(
    name: &str,
    findings: &[crate::analysis::preflight::Finding],
) -> Vec<String> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < findings.len() {
        let f = &findings[i];
        let mut j = i + 1;
        while j < findings.len()
            && findings[j].what == f.what
            && findings[j].line <= findings[j - 1].line + 1
        {
            j += 1;
        }
        let at = format!(
            "X{} Y{} Z{} A{} B{} C{}",
            f.at[0], f.at[1], f.at[2], f.at[3], f.at[4], f.at[5]
        );
        let last = &findings[j - 1];
        out.push(if j - i == 1 {
            format!("{name}:{}: {} (at {at})", f.line, f.what)
        } else {
            format!(
                "{name}:{}: {} (at {at}), and on every line to {name}:{} ({} lines)",
                f.line,
                f.what,
                last.line,
                j - i
            )
        });
        i = j;
    }
    out
}

/// The compressor's settings with `machine`'s smallest X Y Z acceleration and speed
/// (what a curve's time is weighed with), and the most its bends can take.
pub fn for_machine(
    settings: &gcode::compress::Settings,
    machine: &MachineConfig,
) -> gcode::compress::Settings {
    let xyz = || machine.axes[..3].iter().filter(|a| a.max_accel > 0);
    gcode::compress::Settings {
        accel: xyz()
            .map(|a| a.max_accel as f64)
            .fold(f64::INFINITY, f64::min),
        max_speed: xyz()
            .map(|a| a.max_velocity as f64)
            .fold(f64::INFINITY, f64::min),
        bend_accel: xyz()
            .map(|a| (a.max_accel as f64).powi(2))
            .sum::<f64>()
            .sqrt()
            * pkmc::motion::planner::SPLINE_BEND_SHARE as f64,
        ..*settings
    }
    .finite()
}

/// The axes `machine` has: those with limits in its `[axes]`. Any other axis has no
/// speed to move at, so a program naming one is refused before anything runs.
pub fn machine_axes(machine: &MachineConfig) -> [bool; AXES] {
    std::array::from_fn(|i| machine.axes[i].max_velocity > 0)
}

/// The tool table: from `tools` (a tool file) if given, else from the machine file's
/// `[[tools]]`, else empty.
pub fn load_tools(
    tools: Option<&Path>,
    machine: Option<&Path>,
) -> Result<gcode::ToolTable, Failure> {
    let bad = |m: String| Failure::new(exit::BAD_INPUT, m);
    if let Some(p) = tools {
        let text = crate::input::read_text(p, crate::input::MAX_MACHINE_FILE_BYTES).map_err(bad)?;
        return gcode::ToolTable::parse(&text, &p.display().to_string())
            .map_err(|d| bad(d.to_string()));
    }
    match machine {
        Some(p) => crate::machine_file::load_tools(p).map_err(|e| bad(e.to_string())),
        None => Ok(gcode::ToolTable::new()),
    }
}
