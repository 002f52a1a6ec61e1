//! G-code to blocks for a machine: compiling a program or an MDI line, refusing axes
//! the machine lacks, and the pre-flight findings in words.

use super::{exit, Failure};
use crate::gcode;
use pkmc::config::{MachineConfig, AXES};
use pkmc::protocol::Block;
use std::path::Path;

/// Reads and compiles a program for `machine`; checks every block end against the
/// machine's reach.
pub fn compile_program(
    path: &Path,
    machine: &MachineConfig,
    tools: &gcode::ToolTable,
) -> Result<Vec<Block>, Failure> {
    let text = crate::input::read_text(path, crate::input::MAX_PROGRAM_BYTES)
        .map_err(|m| Failure::new(exit::BAD_INPUT, m))?;
    let name = path.display().to_string();
    compile_text_with(&text, &name, machine, machine.home, tools)
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
    let options = gcode::Options {
        start,
        axes: machine_axes(machine),
        tools: tools.clone(),
        ..gcode::Options::default()
    };
    let canon = gcode::compile_canon(text, name, &options).map_err(|errs| {
        let lines: Vec<String> = errs.iter().map(|d| d.to_string()).collect();
        Failure::new(
            exit::BAD_INPUT,
            format!(
                "{}\n{} error(s); nothing was sent",
                lines.join("\n"),
                errs.len()
            ),
        )
    })?;
    let program = crate::gcode::blocks::from_canon(&canon, start);
    let report = crate::analysis::preflight::check(&program.blocks, machine, start);
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
    Ok(program.blocks)
}

/// The pre-flight findings as lines of text: a run of the same problem on consecutive
/// NC lines (a stretch of a program out of travel, thousands of lines of CAM output)
/// is one line naming its first and last line and how many, at its first pose.
fn findings_text(name: &str, findings: &[crate::analysis::preflight::Finding]) -> Vec<String> {
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

/// The axes `machine` has: those with limits in its `[axes]`. Any other axis has no
/// speed to move at, so a program naming one is refused before anything runs.
pub fn machine_axes(machine: &MachineConfig) -> [bool; AXES] {
    std::array::from_fn(|i| machine.axes[i].max_velocity > 0)
}
