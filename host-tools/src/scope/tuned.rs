//! What `nc-send tune` (and the station's Tune) found ([`Tuned`]): the report, the
//! figures, the designed gains, the plot; and the gains written into the machine
//! file ([`write`]), as `--write` and the station's Write gains do.

use super::tune_write;
use crate::control::tune;
use crate::job::{exit, Failure};
use crate::scope::tune_plot::{self, BodeCurve, Curve};
use std::path::Path;

fn bad(message: impl Into<String>) -> Failure {
    Failure::new(exit::BAD_INPUT, message)
}

/// What a tune found: the report `nc-send tune` prints, the figures the station
/// shows, the gains and the line they would be written as, the plot's curves.
#[derive(Clone, Debug)]
pub struct Tuned {
    /// The joint's number from 0.
    pub joint: usize,
    /// Its name.
    pub name: String,
    /// "mm" or "°".
    pub unit: &'static str,
    /// The test signal's amplitude, encoder counts and mm (or degrees).
    pub amplitude: (u32, f64),
    /// The report, line by line (what `nc-send tune` prints).
    pub lines: Vec<String>,
    /// The identification's validation fit, percent.
    pub fit_percent: f64,
    /// The model's step against the measured one (`tune::step_error`'s ratio).
    pub step_error: f64,
    /// The present kp, ki, kd, kvff, kaff.
    pub present: [f64; 5],
    /// The designed ones.
    pub designed: [f64; 5],
    /// Margins of the present gains on the model.
    pub present_margins: tune::Margins,
    /// Margins of the designed gains on the model.
    pub designed_margins: tune::Margins,
    /// The crossover (rad/s) and phase margin (degrees) aimed at.
    pub aimed: (f64, f64),
    /// For a joint that runs LQG: the figures of its present and designed LQG loops on
    /// the model, and the designed weights.
    pub lqg: Option<String>,
    /// For a joint that runs LQG: its `lqg`, `lqg_gains` and `lqg_model` lines as
    /// they would be written (key, value).
    pub lqg_lines: Vec<(&'static str, String)>,
    /// The other joints that share its LQG design, which are written the same.
    pub alike: Vec<usize>,
    /// The joint's `servo = { … }` line as it would be written.
    pub line: String,
    pub(super) title: String,
    pub(super) steps: Vec<Curve>,
    pub(super) bode: Vec<BodeCurve>,
}

impl Tuned {
    /// The gains written into the machine file, by name.
    pub fn fields(&self) -> [(&'static str, f64); 5] {
        let d = self.designed;
        [
            ("kp", d[0]),
            ("ki", d[1]),
            ("kd", d[2]),
            ("kvff", d[3]),
            ("kaff", d[4]),
        ]
    }

    /// The predicted and measured steps and the Bode diagram (`--plot`) as SVG text.
    pub fn svg(&self) -> Result<String, String> {
        tune_plot::svg(&self.title, &self.steps, &self.bode)
    }

    /// The same drawn into `path` (.svg or .png).
    pub fn draw(&self, path: &Path) -> Result<(), Failure> {
        tune_plot::draw(path, &self.title, &self.steps, &self.bode).map_err(bad)
    }
}

/// Writes the designed gains of `tuned` into the joint's `servo` line of the machine
/// file at `path`, read again now (`--write`; the station's Write gains), and for a
/// joint that runs LQG its `lqg`, `lqg_gains` and `lqg_model` lines, into the joint
/// and every joint that shares its design: what was written, in a line.
pub fn write(path: &Path, tuned: &Tuned) -> Result<String, Failure> {
    let mut text = std::fs::read_to_string(path)
        .map_err(|e| bad(format!("{}: cannot read it: {e}", path.display())))?;
    let mut line = String::new();
    for &j in std::iter::once(&tuned.joint).chain(&tuned.alike) {
        let new = tune_write::rewrite(&text, j, &tuned.fields()).map_err(bad)?;
        text = new.text;
        if j == tuned.joint {
            line = new.line.trim().to_string();
        }
        for (key, value) in &tuned.lqg_lines {
            text = tune_write::set_line(&text, j, key, value).map_err(bad)?;
        }
    }
    std::fs::write(path, &text)
        .map_err(|e| bad(format!("{}: cannot write it: {e}", path.display())))?;
    Ok(written(tuned, &line))
}

/// What [`write`] writes, in a line: the `servo` line, the LQG lines' keys and the
/// joints that share them.
pub fn written(tuned: &Tuned, servo_line: &str) -> String {
    let mut s = servo_line.trim().to_string();
    if !tuned.lqg_lines.is_empty() {
        let keys: Vec<&str> = tuned.lqg_lines.iter().map(|(k, _)| *k).collect();
        s.push_str(&format!("; and {}", keys.join(", ")));
    }
    if !tuned.alike.is_empty() {
        let js: Vec<String> = tuned.alike.iter().map(|j| format!("joints[{j}]")).collect();
        s.push_str(&format!(
            "; the same for {}, which share its LQG design",
            js.join(", ")
        ));
    }
    s
}
