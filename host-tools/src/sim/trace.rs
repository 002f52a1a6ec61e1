//! The trace of a simulated run (`--trace FILE.csv`): one row per interpolation
//! period, commanded pose and joints, the drives' feedback and where the joints truly
//! are, in user units.

use super::Result;
use super::Simulator;
use pkmc::config::MAX_JOINTS;
use pkmc::units::{to_user, TICK_NS};
use std::io::Write;

/// One trace row, in user units.
#[derive(Clone, Debug, PartialEq)]
pub struct TraceRow {
    /// Time at the end of the tick, s.
    pub t_s: f64,
    /// NC line executing.
    pub line: u32,
    /// Commanded pose, mm and degrees.
    pub pose: [f64; 6],
    /// Commanded joints, mm or degrees.
    pub joints: Vec<f64>,
    /// Joint positions the drives report (steps or encoder counts scaled back).
    pub feedback: Vec<f64>,
    /// Where the joints truly are: a servo plant's position not rounded to encoder
    /// counts (a stepper's steps, as `feedback`).
    pub truth: Vec<f64>,
}

impl Simulator {
    /// Writes a CSV trace row per tick to `out` from now on (header first).
    pub fn trace_to(&mut self, mut out: Box<dyn Write + Send>) -> Result<()> {
        let n = self.ctrl.machine().joints.len();
        let mut header = String::from("t_s,line,x,y,z,a,b,c");
        for j in 1..=n {
            header += &format!(",q{j}");
        }
        for j in 1..=n {
            header += &format!(",fb{j}");
        }
        for j in 1..=n {
            header += &format!(",tq{j}");
        }
        writeln!(out, "{header}")?;
        self.trace = Some(out);
        Ok(())
    }

    /// Flushes the trace, if any.
    pub fn finish_trace(&mut self) -> Result<()> {
        if let Some(t) = self.trace.as_mut() {
            t.flush()?;
        }
        Ok(())
    }

    /// The trace row of the current state.
    pub fn trace_row(&self) -> TraceRow {
        let m = self.ctrl.machine();
        let mut pose = [0.0; 6];
        for (i, p) in pose.iter_mut().enumerate() {
            *p = to_user(self.ctrl.pose()[i], pkmc::config::axis_is_rotary(i));
        }
        let n = m.joints.len().min(MAX_JOINTS);
        TraceRow {
            t_s: self.ticks as f64 * TICK_NS as f64 * 1e-9,
            line: self.ctrl.line(),
            pose,
            joints: (0..n)
                .map(|j| to_user(self.ctrl.joints()[j], m.joints[j].rotary))
                .collect(),
            feedback: (0..n)
                .map(|j| to_user(self.feedback(j), m.joints[j].rotary))
                .collect(),
            truth: (0..n)
                .map(|j| {
                    let per_user = pkmc::units::units_per_user(m.joints[j].rotary) as f64;
                    self.true_position(j).unwrap_or(0.0) / per_user
                })
                .collect(),
        }
    }
}

pub(super) fn write_row(out: &mut dyn Write, r: &TraceRow) -> std::io::Result<()> {
    write!(out, "{:.6},{}", r.t_s, r.line)?;
    for v in r
        .pose
        .iter()
        .chain(&r.joints)
        .chain(&r.feedback)
        .chain(&r.truth)
    {
        write!(out, ",{v:.9}")?;
    }
    writeln!(out)
}
