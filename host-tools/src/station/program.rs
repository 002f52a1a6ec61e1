//! The loaded program: compiled as the page sends it, every front-end error at its
//! line and column, and the pre-flight dry run (the controller core in this process,
//! as `nc-send --check`) that gives the tool path, the run time, the smallest
//! singularity margin and the times the blocks end (the ETA while it runs).

use crate::gcode;
use crate::job::{self, Compiled, RunOptions};
use pkmc::config::MachineConfig;
use pkmc::motion::block::{Block, Motion};
use serde_json::{json, Value};

/// Points of the tool path sent to the page, at most.
const PATH_POINTS: usize = 20_000;

/// A program as loaded and checked.
#[derive(Clone, Debug, Default)]
pub struct Program {
    pub name: String,
    pub text: String,
    /// The blocks to stream (merged into curves where `G64 P` allows).
    pub compiled: Option<Compiled>,
    /// Errors of the front end and pre-flight findings: line, column, message.
    pub errors: Vec<(usize, usize, String)>,
    /// The dry run, once made.
    pub check: Option<CheckResult>,
    /// A program that probes (G38): its probing moves' lines and codes, as far as the
    /// preview went (the blocks above take each to its programmed end; the run finds
    /// the real outcomes a stage at a time, `job::probing`).
    pub probing: Option<Vec<(u32, &'static str)>>,
    /// The merging it was compiled with (a run that probes compiles it again).
    pub compress: Option<gcode::compress::Settings>,
}

/// What the dry run found.
#[derive(Clone, Debug, Default)]
pub struct CheckResult {
    pub ok: bool,
    pub run_time_s: f64,
    pub min_margin: Option<(f64, u32)>,
    /// Problems with their NC lines (an alarm of the dry run).
    pub findings: Vec<(u32, String)>,
    /// Tool path: x y z (workpiece mm), NC line, rapid.
    pub path: Vec<[f64; 5]>,
    /// Simulated time at which block k + 1 had completed.
    pub done_at: Vec<f64>,
}

impl Program {
    /// Compiles `text` for `machine`: the front end's errors, or the blocks and their
    /// pre-flight findings (each at its line, column 1).
    pub fn load(name: &str, text: &str, machine: &MachineConfig, opts: &RunOptions<'_>) -> Self {
        let mut p = Program {
            name: name.to_string(),
            text: text.to_string(),
            compress: opts.compress,
            ..Program::default()
        };
        if job::probing::names_g38(text) {
            let pp = job::probing::ProbingProgram {
                text,
                name,
                machine,
                start: machine.home,
                tools: &opts.tools,
                compress: opts.compress.as_ref(),
            };
            match job::probing::preview(&pp) {
                Err(diags) => p.errors = located(diags),
                Ok((c, pre, moves)) => {
                    p.errors = findings(&pre);
                    p.compiled = Some(c);
                    p.probing = (!moves.is_empty()).then_some(moves);
                }
            }
            return p;
        }
        let compiled = job::compile_located(
            text,
            name,
            machine,
            machine.home,
            &opts.tools,
            opts.compress.as_ref(),
        );
        match compiled {
            Err(diags) => p.errors = located(diags),
            Ok((c, pre)) => {
                p.errors = findings(&pre);
                p.compiled = Some(c);
            }
        }
        p
    }

    /// Can it run? Compiled without an error.
    pub fn runnable(&self) -> bool {
        self.compiled.is_some() && self.errors.is_empty()
    }

    /// The blocks to stream.
    pub fn blocks(&self) -> &[Block] {
        self.compiled.as_ref().map_or(&[], |c| &c.blocks)
    }

    /// The blocks one by one, as programmed (Run by Step).
    pub fn programmed(&self) -> &[Block] {
        self.compiled.as_ref().map_or(&[], |c| &c.programmed)
    }

    /// The dry run: the controller core in this process on the simulated clock.
    pub fn dry_run(&mut self, machine: &MachineConfig, opts: &RunOptions<'_>) {
        let Some(compiled) = self.compiled.as_ref() else {
            return;
        };
        let mut o = opts.clone();
        o.target = job::Target::Sim;
        o.sim.trace = None;
        o.sim.record_path = true;
        o.sim.inject = Vec::new();
        o.sim.faults = None;
        let r = job::check_compiled(machine, &self.name, compiled, &o, &mut DryRun::default());
        let rapid_lines: std::collections::HashSet<u32> = compiled
            .blocks
            .iter()
            .filter(|b| matches!(b.motion, Motion::Rapid))
            .map(|b| b.line)
            .collect();
        let mut c = CheckResult::default();
        match r {
            Err(f) => {
                c.findings.push((first_line(&f.message), f.message));
            }
            Ok(r) => {
                let rep = &r.report;
                c.ok = rep.result == "done";
                c.run_time_s = rep.run_time_s;
                if let Some(p) = &rep.preflight {
                    c.min_margin = p.min_singularity_margin.zip(p.min_margin_line);
                }
                if !c.ok {
                    let why = rep
                        .alarm_cause
                        .clone()
                        .unwrap_or_else(|| rep.result.clone());
                    c.findings.push((rep.alarm_line.unwrap_or(0), why));
                }
                if let Some(sim) = r.sim {
                    let samples = &sim.recorder.samples;
                    let stride = samples.len().div_ceil(PATH_POINTS).max(1);
                    let mut last_line = u32::MAX;
                    for (i, s) in samples.iter().enumerate() {
                        if i % stride == 0 || s.line != last_line || i + 1 == samples.len() {
                            let rapid = rapid_lines.contains(&s.line) as u8 as f64;
                            c.path
                                .push([s.xyz[0], s.xyz[1], s.xyz[2], s.line as f64, rapid]);
                        }
                        last_line = s.line;
                    }
                    c.done_at = sim.recorder.done_at;
                }
            }
        }
        self.check = Some(c);
    }

    /// Seconds left, with `executed` blocks of the job done, at `override_pct`.
    pub fn eta_s(&self, executed: usize, override_pct: u16) -> Option<f64> {
        let c = self.check.as_ref()?;
        let total = c.done_at.last().copied()?;
        let at = match executed {
            0 => 0.0,
            n => c.done_at.get(n - 1).copied()?,
        };
        Some((total - at).max(0.0) * 100.0 / override_pct.max(1) as f64)
    }

    /// The path through the blocks' end points (arcs as chords), from home:
    /// x y z (workpiece mm), NC line, rapid.
    fn block_path(&self) -> Vec<[f64; 5]> {
        let mut out = Vec::new();
        let mut step = 1;
        let blocks = self.blocks();
        if blocks.len() > PATH_POINTS {
            step = blocks.len().div_ceil(PATH_POINTS);
        }
        for (i, b) in blocks.iter().enumerate() {
            if matches!(b.motion, Motion::Dwell(_) | Motion::Aux(_)) {
                continue;
            }
            if i % step != 0 && i + 1 != blocks.len() {
                continue;
            }
            let mm = |k: usize| round3(b.target[k] as f64 / 1e6);
            let rapid = matches!(b.motion, Motion::Rapid) as u8 as f64;
            out.push([mm(0), mm(1), mm(2), b.line as f64, rapid]);
        }
        out
    }

    /// The `program` message.
    pub fn message(&self) -> Value {
        let errors: Vec<Value> = self
            .errors
            .iter()
            .map(|(l, c, m)| json!({"line": l, "col": c, "message": m}))
            .collect();
        let check = self.check.as_ref().map(|c| {
            json!({
                "ok": c.ok,
                "run_time_s": c.run_time_s,
                "min_margin": c.min_margin.map(|m| m.0),
                "margin_line": c.min_margin.map(|m| m.1),
                "findings": c.findings.iter()
                    .map(|(l, m)| json!({"line": l, "message": m}))
                    .collect::<Vec<_>>(),
            })
        });
        let mut path: Vec<[f64; 5]> = self
            .check
            .as_ref()
            .map(|c| c.path.iter().map(|p| p.map(round3)).collect())
            .unwrap_or_default();
        if path.is_empty() {
            // No dry run (a pre-flight error stops it): the blocks' end points, so that
            // the program is still drawn, its errors marked on it by the page.
            path = self.block_path();
        }
        json!({
            "type": "program",
            "name": self.name,
            "text": self.text,
            "lines": self.text.lines().count(),
            "blocks": self.blocks().len(),
            "errors": errors,
            "path": path,
            "check": check,
            "probing": self.probing.as_ref().map(|m| json!({
                "moves": m.iter().map(|(line, code)| json!({"line": line, "code": code}))
                    .collect::<Vec<_>>(),
                "capped": m.len() >= job::probing::PREVIEW_PROBES,
            })),
        })
    }
}

/// The front end's errors: line, column, message.
fn located(diags: Vec<gcode::Diagnostic>) -> Vec<(usize, usize, String)> {
    diags
        .into_iter()
        .map(|d| (d.line, d.col, d.message))
        .collect()
}

/// The pre-flight's findings, each at its line, column 1.
fn findings(pre: &crate::analysis::preflight::Preflight) -> Vec<(usize, usize, String)> {
    pre.findings
        .iter()
        .map(|f| (f.line as usize, 1, f.what.clone()))
        .collect()
}

/// The dry run's operator: program pauses (M0, M1, M6) are resumed at once, as
/// `nc-send --check` does; nobody else holds a dry run.
#[derive(Default)]
struct DryRun {
    /// The line of the pause last resumed, while statuses still show it.
    resumed: Option<u32>,
}

impl crate::link::JobHooks for DryRun {
    fn control(&mut self, view: &crate::link::LinkView) -> Option<pkmc::wire::Control> {
        let s = view.status.as_ref()?;
        if s.state != pkmc::wire::State::Hold {
            self.resumed = None;
            return None;
        }
        if view.control_pending || s.speed != 0 || self.resumed == Some(s.line) {
            return None;
        }
        self.resumed = Some(s.line);
        Some(pkmc::wire::Control::Resume)
    }
}

/// A value to 3 decimals (µm), for the page.
pub fn round3(v: f64) -> f64 {
    (v * 1000.0).round() / 1000.0
}

/// The NC line of a message `name:LINE: …`, or 0.
fn first_line(msg: &str) -> u32 {
    msg.split(':')
        .nth(1)
        .and_then(|l| l.trim().parse().ok())
        .unwrap_or(0)
}

/// The teach list's positions as G-code: absolute moves at `speed` mm/min.
pub fn teach_gcode(points: &[[f64; 6]], axes: &[bool; 6], speed: f64) -> String {
    let mut out = String::from("(pkmc teach list)\nG21 G90 G64\n");
    for (i, p) in points.iter().enumerate() {
        let words: Vec<String> = (0..6)
            .filter(|&k| axes[k])
            // Every digit the machine has: 1 nm (6 decimals of mm), 1 n° (9 of a degree).
            .map(|k| {
                let digits = if k >= 3 { 9 } else { 6 };
                format!("{}{:.*}", pkmc::config::AXIS_NAMES[k], digits, p[k])
            })
            .collect();
        out += &format!("G1 {} F{speed:.1} (P{})\n", words.join(" "), i + 1);
    }
    out += "M2\n";
    out
}

/// Positions read back from a teach file: the pose after each line that moves (any
/// program our front end reads; errors at their line and column).
pub fn teach_points(
    name: &str,
    text: &str,
    machine: &MachineConfig,
) -> Result<(Vec<[f64; 6]>, Option<f64>), String> {
    let canon = gcode::compile_canon(
        text,
        name,
        &job::front_end_options(machine, machine.home, &gcode::ToolTable::default()),
    )
    .map_err(|errs| {
        errs.iter()
            .map(|d| d.to_string())
            .collect::<Vec<_>>()
            .join("\n")
    })?;
    let program = gcode::blocks::from_canon(&canon, machine.home);
    let mut points = Vec::new();
    let mut speed = None;
    for b in &program.blocks {
        if matches!(b.motion, Motion::Dwell(_) | Motion::Aux(_)) {
            continue;
        }
        if b.feed > 0 {
            // The feed is kept in nm/s: 2000 mm/min is 33 333 333 nm/s, which reads
            // back as 1999.99998. To 0.001 mm/min, an F of up to three decimals
            // comes back exactly (one nm/s is 0.00006 mm/min).
            speed = Some(round3(crate::link::view::feed_mm_min(b.feed)));
        }
        points.push(std::array::from_fn(|k| {
            b.target[k] as f64 / pkmc::units::units_per_user(k >= 3) as f64
        }));
    }
    Ok((points, speed))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn opts() -> RunOptions<'static> {
        RunOptions {
            target: job::Target::Sim,
            sim: Default::default(),
            link: Default::default(),
            home: false,
            tools: Default::default(),
            statics: None,
            compress: None,
        }
    }

    #[test]
    fn a_program_with_pauses_is_dry_run_to_its_end_with_the_times_its_blocks_end() {
        let machine = MachineConfig::h4_table();
        let text = "G21 G90\nG1 X10 F1200\nM0\nG1 Y10\nM1\nG1 X0 Y0\nM2\n";
        let mut p = Program::load("paused.ngc", text, &machine, &opts());
        assert!(p.runnable(), "{:?}", p.errors);
        p.dry_run(&machine, &opts());
        let c = p.check.clone().unwrap();
        assert!(c.ok, "{:?}", c.findings);
        assert_eq!(c.done_at.len(), p.blocks().len());
        assert!(c.run_time_s > 1.0, "{}", c.run_time_s);
        let total = p.eta_s(0, 100).unwrap();
        assert!((total - c.done_at.last().unwrap()).abs() < 1e-9);
        assert_eq!(p.eta_s(p.blocks().len(), 100), Some(0.0));
        // At 200 % the time left halves.
        let half = p.eta_s(1, 200).unwrap();
        assert!((half * 2.0 - p.eta_s(1, 100).unwrap()).abs() < 1e-9);
        assert!(!c.path.is_empty());
    }

    #[test]
    fn errors_carry_line_and_column_and_nothing_runs() {
        let machine = MachineConfig::h4_table();
        let p = Program::load("bad.ngc", "G21\nG1 X1 F100\nG1 X2 Q3\n", &machine, &opts());
        assert!(!p.runnable());
        assert_eq!(
            p.errors.iter().map(|e| (e.0, e.1)).collect::<Vec<_>>(),
            vec![(3, 7)]
        );
    }

    #[test]
    fn a_program_that_probes_is_previewed_with_each_probing_move_to_its_end() {
        let machine = MachineConfig::cartesian_xyz();
        // The second probing move depends on the first's outcome (#5063), and a
        // branch on #5070 takes the touch the preview assumes.
        let text = "G21 G90\nG0 Z5\nG38.2 Z-10 F300\nO1 if [#5070 EQ 1]\n\
                    G0 Z[#5063 + 2]\nO1 endif\nG38.3 X10 F300\nG0 X0\nM2\n";
        let mut p = Program::load("probe.ngc", text, &machine, &opts());
        assert!(p.runnable(), "{:?}", p.errors);
        assert_eq!(p.probing, Some(vec![(3, "G38.2"), (7, "G38.3")]));
        let ends: Vec<[i64; 3]> = p
            .blocks()
            .iter()
            .map(|b| [b.target[0], b.target[1], b.target[2]])
            .collect();
        // To Z5, down to the probing move's end, 2 mm above it, along X to the
        // second's end, back.
        let mm = 1_000_000;
        assert_eq!(
            ends,
            vec![
                [0, 0, 5 * mm],
                [0, 0, -10 * mm],
                [0, 0, -8 * mm],
                [10 * mm, 0, -8 * mm],
                [0, 0, -8 * mm]
            ]
        );
        let msg = p.message();
        assert_eq!(msg["probing"]["moves"][1]["code"], "G38.3");
        assert_eq!(msg["probing"]["capped"], false);
        p.dry_run(&machine, &opts());
        assert!(p.check.as_ref().unwrap().ok);
        // Without G38 a program says nothing of probing.
        let plain = Program::load("plain.ngc", "G0 X1\nM2\n", &machine, &opts());
        assert_eq!(plain.probing, None);
        assert!(plain.message()["probing"].is_null());
    }

    #[test]
    fn the_teach_list_goes_to_g_code_and_back() {
        let machine = MachineConfig::h4_table();
        let axes = job::machine_axes(&machine);
        let points = vec![
            [1.0, 2.0, -70.0, 5.0, 0.0, 0.0],
            [3.5, -2.25, -75.0, 0.0, 0.0, 10.0],
        ];
        let text = teach_gcode(&points, &axes, 1500.0);
        let (back, speed) = teach_points("teach.ngc", &text, &machine).unwrap();
        assert_eq!(back, points, "{text}");
        assert_eq!(speed, Some(1500.0));
    }
}
