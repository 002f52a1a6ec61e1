//! The machine-readable summary of a job (`--report json`) and its exit code.

use super::{exit, SimOutcome};
use crate::link::view::{AlarmView, StatusView};
use crate::link::{ClientStats, JobEnd};
use crate::sim::faults::FaultReport;
use pkmc::config::{MachineConfig, AXIS_NAMES};
use pkmc::units::TICK_NS;
use pkmc::wire::Status;
use serde::Serialize;
use std::io::Write;

/// The NC lines a simulated job executed.
#[derive(Clone, Debug, Serialize, PartialEq, Eq)]
pub struct LinesExecuted {
    /// Distinct lines in execution order (consecutive repeats merged).
    pub count: usize,
    /// FNV-1a digest of that sequence ([`crate::analysis::plot::lines_digest`]).
    pub digest: String,
}

/// The machine-readable summary of a job.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    /// Machine name.
    pub machine: String,
    /// Program file (or the MDI line).
    pub program: String,
    /// "done", "alarm", "aborted" or "stopped".
    pub result: String,
    /// Controller state at the end, by its stable name (`Idle`, `Alarm`).
    pub final_state: String,
    /// NC line of the last block executed, as the controller reports it (a block merged
    /// from several moves carries the line of its first).
    pub final_line: u32,
    /// Final commanded pose: X Y Z in mm, A B C in degrees.
    pub final_pose: std::collections::BTreeMap<String, f64>,
    /// Final commanded joints, mm or degrees.
    pub final_joints: Vec<f64>,
    /// Final drive positions (simulator only), steps or counts.
    pub final_joint_steps: Option<Vec<i64>>,
    /// Blocks sent.
    pub blocks_sent: usize,
    /// Blocks the controller executed.
    pub blocks_executed: u32,
    /// Motion time on the controller, s (for `--check`, the planned run time).
    pub run_time_s: f64,
    /// Alarms, in the core's words (`limit switch on joint 1 at line 1`).
    pub alarms: Vec<String>,
    /// NC line of the alarm, if any.
    pub alarm_line: Option<u32>,
    /// Cause of the alarm, if any (`EStop`, `LimitSwitch`, `DriveFault`, …).
    pub alarm_cause: Option<String>,
    /// Joint the alarm names, 1-based, if any.
    pub alarm_joint: Option<u8>,
    /// Simulated time the alarm was raised, s (simulator only).
    pub alarm_time_s: Option<f64>,
    /// Drive timing breaches (simulator only).
    pub drive_violations: Option<u64>,
    /// Link counters of the client.
    pub link: ClientStats,
    /// Frames the (simulated) controller found corrupt.
    pub controller_corrupt_frames: Option<u32>,
    /// Injected faults and what became of them (`--link-faults`).
    pub faults: Option<FaultReport>,
    /// NC lines executed (simulator only).
    pub lines_executed: Option<LinesExecuted>,
    /// Pre-flight (`--check`): poses sampled along the path and the smallest
    /// singularity margin met, with its NC line (see [`crate::analysis::preflight`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub preflight: Option<PreflightSummary>,
    /// The joint forces of the cutting load (`--wrench`, `--wrench-file`), when one
    /// was given.
    pub statics: Option<crate::analysis::statics::Statics>,
    /// What the chord compressor did, and how far the interpolated path strayed.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub compression: Option<CompressionSummary>,
    /// What each probing move found (G38, [`super::probing`]), in order.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub probes: Vec<super::probing::ProbeRecord>,
}

/// What the compressor made of a program (`--check`, `--sim`, runs on a board).
#[derive(Clone, Debug, Serialize)]
pub struct CompressionSummary {
    /// Blocks as programmed.
    pub blocks_programmed: usize,
    /// Blocks streamed.
    pub blocks_streamed: usize,
    /// Curves among them.
    pub curves: usize,
    /// The largest deviation of the interpolated path from the programmed chords,
    /// where curves stand for them (simulated runs only).
    pub deviation: Option<crate::analysis::deviation::Worst>,
}

impl CompressionSummary {
    /// The summary in words, when the compressor merged anything.
    pub fn text(&self) -> Option<String> {
        if self.curves == 0 {
            return None;
        }
        let dev = match &self.deviation {
            Some(d) if d.samples > 0 => format!(
                "; largest deviation of the interpolated path from the programmed moves \
                 {:.4} mm (line {}, {} poses measured)",
                d.deviation_mm, d.line, d.samples
            ),
            _ => String::new(),
        };
        Some(format!(
            "compression: {} blocks programmed, {} streamed ({} curves){dev}",
            self.blocks_programmed, self.blocks_streamed, self.curves
        ))
    }

    /// The summary of `compiled` after a run whose simulator side is `sim`.
    pub fn of(compiled: &super::Compiled, sim: Option<&super::SimOutcome>) -> Self {
        Self {
            blocks_programmed: compiled.programmed.len(),
            blocks_streamed: compiled.blocks.len(),
            curves: compiled.curves(),
            deviation: sim
                .and_then(|s| s.recorder.deviation.as_ref())
                .map(|m| m.worst.clone()),
        }
    }
}

/// What `--check` reports of the pre-flight.
#[derive(Clone, Debug, Serialize)]
pub struct PreflightSummary {
    /// Poses checked through the kinematics.
    pub samples: usize,
    /// Smallest singularity margin met (1 for a Cartesian machine, 0 at a singularity).
    pub min_singularity_margin: Option<f64>,
    /// NC line where it was met.
    pub min_margin_line: Option<u32>,
}

impl Report {
    /// Builds the report from the final status.
    pub fn new(
        machine: &MachineConfig,
        program: &str,
        blocks: usize,
        end: &JobEnd,
        status: &Status,
        sim: Option<&SimOutcome>,
        link: ClientStats,
    ) -> Self {
        let view = StatusView::with_joints(status, machine);
        let final_pose = (0..6)
            .map(|i| (AXIS_NAMES[i].to_ascii_lowercase().to_string(), view.pose[i]))
            .collect();
        let alarm = match end {
            JobEnd::Alarm(a) => Some(AlarmView::new(a)),
            _ => view.alarm.clone(),
        };
        Report {
            machine: machine.name.to_string(),
            program: program.to_string(),
            result: match end {
                JobEnd::Done => "done",
                JobEnd::Alarm(_) => "alarm",
                JobEnd::Aborted => "aborted",
                JobEnd::Stopped => "stopped",
                JobEnd::Paused(_) => "paused",
            }
            .into(),
            final_state: view.state,
            final_line: status.line,
            final_pose,
            final_joints: view.joints,
            final_joint_steps: sim.map(|s| s.joint_steps.clone()),
            blocks_sent: blocks,
            blocks_executed: status.blocks_done,
            run_time_s: status.motion_ticks as f64 * TICK_NS as f64 * 1e-9,
            alarms: alarm.iter().map(|a| a.words.clone()).collect(),
            alarm_line: alarm.as_ref().map(|a| a.line),
            alarm_joint: alarm.as_ref().and_then(|a| a.joint),
            alarm_cause: alarm.map(|a| a.cause),
            alarm_time_s: sim.and_then(|s| s.alarm_time_s),
            drive_violations: sim.map(|s| s.violation_count),
            link,
            controller_corrupt_frames: sim.map(|s| s.corrupt_frames),
            faults: sim.and_then(|s| s.faults),
            lines_executed: sim.map(|s| LinesExecuted {
                count: s.recorder.lines.len(),
                digest: s.recorder.lines.digest(),
            }),
            preflight: None,
            statics: None,
            compression: None,
            probes: Vec::new(),
        }
    }

    /// The exit code this outcome implies.
    pub fn exit_code(&self) -> i32 {
        match self.result.as_str() {
            "alarm" => exit::ALARM,
            "aborted" | "stopped" => exit::STOPPED,
            "paused" => exit::HELD,
            _ if self.drive_violations.unwrap_or(0) > 0 => exit::ALARM,
            _ if self.final_state != "Idle" => exit::ALARM,
            _ => exit::OK,
        }
    }
}

/// A pose in words: `X 1.0000 Y …` (mm, degrees).
pub fn pose_text(s: &Status) -> String {
    StatusView::new(s).pose_text()
}

/// A status as `nc-send status --report json` prints it.
pub fn status_json(s: &Status, machine: &MachineConfig, result: &str) -> serde_json::Value {
    let v = StatusView::with_joints(s, machine);
    let pose: serde_json::Map<String, serde_json::Value> = (0..6)
        .map(|i| {
            (
                AXIS_NAMES[i].to_ascii_lowercase().to_string(),
                v.pose[i].into(),
            )
        })
        .collect();
    serde_json::json!({
        "result": result,
        "state": v.state,
        "line": v.line,
        "pose": pose,
        "joints": v.joints,
        "measured": v.measured,
        "feed_mm_min": v.feed_mm_min,
        "feed_override": v.feed_override,
        "buffered_ms": s.buffered_ms,
        "free_slots": s.free_slots,
        "free_bends": s.free_bends,
        "alarm": v.alarm.map(|a| a.words),
        "homed": s.homed,
    })
}

/// Prints a run's summary on stdout: as JSON, or in words (`check`: a dry run).
pub fn print_report(report: &Report, json: bool, check: bool) {
    let mut out = std::io::stdout().lock();
    if json {
        let _ = writeln!(
            out,
            "{}",
            serde_json::to_string_pretty(report).unwrap_or_default()
        );
        return;
    }
    let p = &report.final_pose;
    let what = if check { "checked" } else { "ran" };
    let _ = writeln!(
        out,
        "{}: {} ({what}) on {} — {} of {} blocks in {:.3} s{}, state {}",
        report.program,
        report.result,
        report.machine,
        report.blocks_executed,
        report.blocks_sent,
        report.run_time_s,
        if check { " planned" } else { "" },
        report.final_state
    );
    let _ = writeln!(
        out,
        "final pose X {:.4} Y {:.4} Z {:.4} A {:.4} B {:.4} C {:.4}",
        p["x"], p["y"], p["z"], p["a"], p["b"], p["c"]
    );
    if let Some(pre) = &report.preflight {
        let margin = match (pre.min_singularity_margin, pre.min_margin_line) {
            (Some(m), Some(l)) => format!("smallest singularity margin {m:.4} (line {l})"),
            _ => "no singularity margin computed".into(),
        };
        let _ = writeln!(
            out,
            "pre-flight: {} poses checked through the kinematics, all reachable; {margin}",
            pre.samples
        );
    }
    if let Some(line) = report.compression.as_ref().and_then(|c| c.text()) {
        let _ = writeln!(out, "{line}");
    }
    if let Some(s) = &report.statics {
        let peaks: Vec<String> = s
            .peaks
            .iter()
            .map(|p| {
                let limit = p.limit.map_or(String::new(), |l| format!(" of {l:.0}"));
                format!(
                    "q{} {:+.0} N{limit} (line {})",
                    p.joint + 1,
                    p.force,
                    p.line
                )
            })
            .collect();
        let _ = writeln!(
            out,
            "statics: {} poses; largest joint forces (+ pushes): {}",
            s.samples,
            peaks.join(", ")
        );
        if let Some(l) = s.singular_at {
            let _ = writeln!(
                out,
                "statics: the joints cannot hold the load at a singular pose (line {l})"
            );
        }
    }
    if let Some(steps) = &report.final_joint_steps {
        let _ = writeln!(
            out,
            "drive positions (steps): {steps:?}; timing violations: {}",
            report.drive_violations.unwrap_or(0)
        );
    }
    if let Some(f) = &report.faults {
        let (a, b) = (&f.to_controller, &f.to_host);
        let _ = writeln!(
            out,
            "line faults at {}: corrupted {} dropped {} duplicated {} bytes; frames damaged {}, undetected {}; \
             {} Naks, {} blocks resent",
            f.rate,
            a.corrupted + b.corrupted,
            a.dropped + b.dropped,
            a.duplicated + b.duplicated,
            a.frames_damaged + b.frames_damaged,
            a.undetected + b.undetected,
            report.link.naks,
            report.link.resent
        );
    }
    for a in &report.alarms {
        let _ = writeln!(out, "ALARM: {a}");
    }
    if report.result == "paused" {
        let _ = writeln!(
            out,
            "PAUSED: a program pause or tool change, and no operator here to resume it (stdin \
             is not a terminal): the job stays held on the controller, which was sent \
             {} of the program's {} blocks and keeps the program's mark; `nc-send resume \
             {}` (the same file and options) resumes it and sends the rest to the end, \
             `nc-send abort` drops it",
            report.link.blocks_sent, report.blocks_sent, report.program
        );
    }
}
