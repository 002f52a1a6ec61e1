//! The scope panel's state, shared in the hub: what the recorder was asked for (a
//! live stream or a triggered capture), the samples it gave, and the messages for
//! the pages. The traces are drawn here with `plotters` (the scope room's
//! [`crate::scope::plot::svg`], the drawing `nc-send record --plot` makes) for the
//! time range a page asks; the CSV is [`Table::csv`], as `nc-send record` writes it.
//! The machine thread fills it ([`super::machine`]); the web side draws from it.

use crate::link::Piece;
use crate::scope::{column, plot, Table};
use pkmc::drive::recorder::{Setup, Trigger};
use serde_json::{json, Value};
use std::time::{Duration, Instant};

/// A live stream keeps this many samples at most (the oldest go first): a minute at
/// the tick rate.
pub const LIVE_SAMPLES: usize = 60_000;

/// Live samples reach the pages at most this often (each message is small; a page
/// asks for a drawing when it is ready for one).
const LIVE_PUBLISH: Duration = Duration::from_millis(100);

/// A drawing's height per signal, and its width's bounds, pixels.
const PANEL_PX: u32 = 120;
const WIDTH_PX: (f64, f64) = (320.0, 2400.0);

/// A drawing's samples for the page's cursors: at most this many (more are thinned).
const CURSOR_SAMPLES: usize = 6000;

/// What the recorder does for the panel.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Mode {
    /// Nothing armed (the last samples stay to be viewed and exported).
    Off,
    /// Streaming continuously.
    Live,
    /// A capture waits for its trigger or fills.
    Armed,
    /// A capture was read out.
    Done,
}

/// The panel's state.
#[derive(Clone, Debug)]
pub struct Scope {
    pub mode: Mode,
    /// The request as the page wrote it.
    pub signals: String,
    pub trigger: String,
    pub pre: u16,
    pub decimate: u16,
    /// A live stream's pieces (at most [`LIVE_SAMPLES`] samples).
    pieces: Vec<Piece>,
    samples: usize,
    /// A finished capture's table.
    capture: Option<Table>,
    /// Counts every change of the samples (a page redraws when it moves).
    pub version: u64,
    /// Why the last request failed, naming the field.
    pub error: Option<String>,
    /// The recorder is to be stopped once the machine thread is free (asked while a
    /// job ran).
    pub disarm: bool,
    /// When the capture's phase was last asked, and the live samples last published.
    pub asked: Option<Instant>,
    published: Option<Instant>,
    /// Arm or Live pressed while a job runs: sent beside the job, answered once the
    /// controller acknowledges it ([`super::machine`]).
    pub pending: Option<PendingArm>,
}

/// An arm request from a page while a job runs, on its way to the controller.
#[derive(Clone, Debug)]
pub struct PendingArm {
    /// The page and its command's id, answered once it is armed.
    pub page: u64,
    pub id: u64,
    /// The fields as the page wrote them, and the request.
    pub signals: String,
    pub trigger: String,
    pub setup: Setup,
    /// Handed to the link already.
    pub sent: bool,
}

impl Default for Scope {
    fn default() -> Self {
        Self {
            mode: Mode::Off,
            signals: "ferr:0,cmd:0,meas:0".into(),
            trigger: "stream".into(),
            pre: 0,
            decimate: 1,
            pieces: Vec::new(),
            samples: 0,
            capture: None,
            version: 0,
            error: None,
            disarm: false,
            asked: None,
            published: None,
            pending: None,
        }
    }
}

/// The recorder's request from the panel's fields, or an error that names the field
/// at fault (Signals, Trigger, Pre-trigger, Decimate).
pub fn check(signals: &str, trigger: &str, pre: f64, decimate: f64) -> Result<Setup, String> {
    let whole = |v: f64, what: &str, low: f64| {
        if v.fract() == 0.0 && (low..=u16::MAX as f64).contains(&v) {
            Ok(v as u16)
        } else {
            Err(format!(
                "{what}: {v} is not a whole number from {low} to {}",
                u16::MAX
            ))
        }
    };
    let pre = whole(pre, "Pre-trigger", 0.0)?;
    let decimate = whole(decimate, "Decimate", 1.0)?;
    let words = |e: String| e.replace("--signals", "the signals");
    crate::scope::setup(signals, "now", 0, 1, false)
        .map_err(|e| format!("Signals: {}", words(e)))?;
    crate::scope::setup(signals, trigger, pre, decimate, false)
        .map_err(|e| format!("Trigger: {}", words(e)))
}

impl Scope {
    /// A new request armed: the old samples go.
    pub fn armed(&mut self, signals: &str, trigger: &str, setup: &Setup) {
        self.mode = if setup.trigger == Trigger::Stream {
            Mode::Live
        } else {
            Mode::Armed
        };
        (self.signals, self.trigger) = (signals.trim().into(), trigger.trim().into());
        (self.pre, self.decimate) = (setup.pre, setup.decimate);
        self.pieces.clear();
        self.samples = 0;
        self.capture = None;
        self.error = None;
        self.disarm = false;
        self.asked = None;
        self.version += 1;
    }

    /// Streamed pieces, kept while live (dropped otherwise); whether the pages should
    /// hear of them now.
    pub fn add(&mut self, pieces: Vec<Piece>) -> bool {
        if self.mode != Mode::Live || pieces.is_empty() {
            return false;
        }
        self.samples += pieces.iter().map(|p| p.samples.len()).sum::<usize>();
        self.pieces.extend(pieces);
        let mut old = 0;
        while self.samples > LIVE_SAMPLES && old + 1 < self.pieces.len() {
            self.samples -= self.pieces[old].samples.len();
            old += 1;
        }
        self.pieces.drain(..old);
        self.version += 1;
        let due = self.published.is_none_or(|t| t.elapsed() >= LIVE_PUBLISH);
        if due {
            self.published = Some(Instant::now());
        }
        due
    }

    /// A finished capture read out.
    pub fn captured(&mut self, rec: &crate::link::Recording) {
        self.capture = Some(Table::of_capture(rec));
        self.mode = Mode::Done;
        self.version += 1;
    }

    /// The samples to view and export: the capture, or the live stream's.
    pub fn table(&self) -> Option<Table> {
        match &self.capture {
            Some(t) => Some(t.clone()),
            None => Table::of_stream(&self.pieces),
        }
    }

    /// The `scope` message: the request, where the recorder is, how many samples.
    pub fn message(&self) -> Value {
        let table = self.table();
        let span = table.as_ref().and_then(|t| {
            let (a, b) = (t.rows.first()?, t.rows.last()?);
            Some([t.time(a.0), t.time(b.0)])
        });
        let columns: Vec<String> = table
            .as_ref()
            .map(|t| t.signals.iter().map(|s| column(*s)).collect())
            .unwrap_or_default();
        json!({
            "type": "scope",
            "mode": self.mode,
            "signals": self.signals,
            "trigger": self.trigger,
            "pre": self.pre,
            "decimate": self.decimate,
            "columns": columns,
            "samples": table.as_ref().map_or(0, |t| t.rows.len()),
            "missing": table.as_ref().map_or(0, |t| t.missing()),
            "span": span,
            "period_s": table.as_ref().map(|t| t.period_s),
            "version": self.version,
            "error": self.error,
        })
    }
}

/// The time range a page asks to see: `from`..`to` (s) when both are given, else the
/// last `window` seconds, else everything.
fn range_of(
    t: &Table,
    from: Option<f64>,
    to: Option<f64>,
    window: Option<f64>,
) -> Option<(f64, f64)> {
    let ok = |v: f64| v.is_finite();
    match (from, to, window) {
        (Some(a), Some(b), _) if ok(a) && ok(b) && b > a => Some((a, b)),
        (_, _, Some(w)) if ok(w) && w > 0.0 => {
            let last = t.time(t.rows.last()?.0);
            let first = t.time(t.rows.first()?.0);
            Some(((last - w).max(first), last.max(first + t.period_s)))
        }
        _ => None,
    }
}

/// The `scope_plot` message for one page: the traces between the times asked drawn
/// `width` pixels wide (SVG), where they lie in it, and the samples drawn (times and
/// each signal's values, thinned past [`CURSOR_SAMPLES`]) for the page's cursors.
pub fn plot_message(
    scope: &Scope,
    from: Option<f64>,
    to: Option<f64>,
    window: Option<f64>,
    width: f64,
) -> Result<Value, String> {
    let table = scope
        .table()
        .ok_or("scope: nothing recorded yet (Live or Arm first)")?;
    let width = if width.is_finite() {
        width.clamp(WIDTH_PX.0, WIDTH_PX.1)
    } else {
        WIDTH_PX.0
    };
    let range = range_of(&table, from, to, window);
    let (svg, layout) = plot::svg(&table, range, width as u32, PANEL_PX)?;
    let rows: Vec<&(i64, Vec<i32>)> = table
        .rows
        .iter()
        .filter(|(n, _)| {
            let t = table.time(*n);
            t >= layout.t0 - 1e-9 && t <= layout.t1 + 1e-9
        })
        .collect();
    let stride = rows.len().div_ceil(CURSOR_SAMPLES).max(1);
    let kept: Vec<&&(i64, Vec<i32>)> = rows.iter().step_by(stride).collect();
    let times: Vec<f64> = kept.iter().map(|(n, _)| table.time(*n)).collect();
    let values: Vec<Vec<i32>> = (0..table.signals.len())
        .map(|k| kept.iter().map(|(_, v)| v[k]).collect())
        .collect();
    Ok(json!({
        "type": "scope_plot",
        "version": scope.version,
        "svg": svg,
        "layout": layout,
        "columns": table.signals.iter().map(|s| column(*s)).collect::<Vec<_>>(),
        "times": times,
        "values": values,
        "thinned": stride > 1,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bad_field_is_named() {
        assert!(check("ferr:0", "job", 10.0, 1.0).is_ok());
        let e = check("torque", "job", 0.0, 1.0).unwrap_err();
        assert!(e.starts_with("Signals: signal `torque`"), "{e}");
        let e = check("", "job", 0.0, 1.0).unwrap_err();
        assert!(e.starts_with("Signals: the signals"), "{e}");
        let e = check("ferr:0", "soon", 0.0, 1.0).unwrap_err();
        assert!(e.starts_with("Trigger: trigger `soon`"), "{e}");
        assert!(check("ferr:0", "job", -1.0, 1.0)
            .unwrap_err()
            .starts_with("Pre-trigger"));
        assert!(check("ferr:0", "job", 0.0, 0.0)
            .unwrap_err()
            .starts_with("Decimate"));
    }
}
