//! The Tune panel's state, shared in the hub: the tune running (its joint), the last
//! result (`nc-send tune`'s, [`crate::scope::tune::Tuned`]) with its plot drawn as
//! SVG (the drawing `nc-send tune --plot` makes), the line Write gains wrote, and
//! why the last request was refused. The machine thread runs the tune
//! ([`super::machine`]); every page hears the `tune` message.

use crate::scope::tune::{TuneArgs, Tuned};
use serde_json::{json, Value};

/// The panel's state.
#[derive(Clone, Debug, Default)]
pub struct Tune {
    /// The joint being tuned now.
    pub running: Option<String>,
    /// The last tune's result and its plot (SVG).
    pub result: Option<(Tuned, String)>,
    /// The line Write gains wrote, and where.
    pub written: Option<String>,
    /// Why the last request was refused, in the tuner's or the controller's words.
    pub error: Option<String>,
}

/// `nc-send tune`'s arguments from the panel's fields: the joint, and the amplitude,
/// bandwidth and phase margin where given (else `nc-send tune`'s defaults).
pub fn args(
    joint: &str,
    amplitude: Option<f64>,
    bandwidth: Option<f64>,
    phase_margin: Option<f64>,
) -> TuneArgs {
    let mut a = TuneArgs::new(joint);
    a.amplitude = amplitude;
    a.bandwidth = bandwidth;
    if let Some(pm) = phase_margin {
        a.phase_margin = pm;
    }
    a
}

fn gains(v: &[f64; 5]) -> Value {
    json!({"kp": v[0], "ki": v[1], "kd": v[2], "kvff": v[3], "kaff": v[4]})
}

fn margins(m: &crate::scope::tune::Margins) -> Value {
    let gm = m.gain_margin_db();
    json!({
        "crossover_rad_s": m.crossover_rad_s,
        "phase_margin_deg": m.phase_margin_deg,
        "gain_margin_db": gm.is_finite().then_some(gm),
        "stable": m.stable,
    })
}

impl Tune {
    /// The `tune` message.
    pub fn message(&self) -> Value {
        let result = self.result.as_ref().map(|(t, svg)| {
            json!({
                "joint": t.joint,
                "name": t.name,
                "unit": t.unit,
                "amplitude": t.amplitude.1,
                "amplitude_counts": t.amplitude.0,
                "fit_percent": t.fit_percent,
                "step_error": t.step_error,
                "present": gains(&t.present),
                "designed": gains(&t.designed),
                "margins": {"present": margins(&t.present_margins),
                            "designed": margins(&t.designed_margins)},
                "aimed": {"crossover_rad_s": t.aimed.0, "phase_margin_deg": t.aimed.1},
                "lqg": t.lqg,
                "line": crate::scope::tuned::written(t, &t.line),
                "report": t.lines,
                "svg": svg,
            })
        });
        json!({
            "type": "tune",
            "running": self.running,
            "result": result,
            "written": self.written,
            "error": self.error,
        })
    }
}
