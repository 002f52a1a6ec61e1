//! `nc-send tune`'s report lines and plot curves ([`super::tune`]'s results put into
//! words and drawings).

use super::{present, Joint, Measured, Outcome, H};
use crate::control::ident::{self, IdentOptions, Identified, Record};
use crate::control::lqg;
use crate::control::tune;
use crate::job::{exit, Failure};
use crate::scope::tune_plot::{BodeCurve, Curve};

fn numbers(v: &[f64]) -> String {
    let s: Vec<String> = v.iter().map(|x| format!("{x:e}")).collect();
    format!("[{}]", s.join(", "))
}

/// The report's lines: the model, the comparison with the measured step, the gains
/// and margins.
pub(super) fn report(
    j: &Joint,
    id: &Identified,
    o: &Outcome,
    m: &Measured,
    (amplitude, n): (u32, usize),
) -> Vec<String> {
    let mut out = Vec::new();
    let unit = if j.file.rotary { "°" } else { "mm" };
    out.push(format!(
        "joint {} ({}): test signal ±{} counts (±{} {unit}), {} samples",
        j.index,
        j.file.name,
        amplitude,
        amplitude as f64 / j.cpu,
        n
    ));
    out.push(format!(
        "model: num = {}, den = {} ({unit}/c.u.; na {} nb {} nk {})",
        numbers(&id.plant.num),
        numbers(&id.plant.den),
        id.arx.a.len() - 1,
        id.arx.b.len(),
        id.arx.nk
    ));
    out.push(format!("fit: {:.1} % (validation)", id.fit_percent));
    out.push(format!(
        "step: error {:.2} % of the measured step's rise (t90 {:.4} s), model against \
         measurement under the present gains",
        100.0 * m.error.ratio,
        m.error.rise_s
    ));
    let g = &j.gains;
    let t = &o.tuned;
    out.push(format!(
        "present: kp = {:.5e} ki = {:.5e} kd = {:.5e} kvff = {:.5e} kaff = {:.5e}",
        g.kp, g.ki, g.kd, g.kvff, g.kaff
    ));
    out.push(format!(
        "designed: kp = {:e} ki = {:e} kd = {:e} kvff = {:e} kaff = {:e}",
        t.kp, t.ki, t.kd, t.kvff, t.kaff
    ));
    let line = |what: &str, m: &tune::Margins| {
        format!(
            "{what}: crossover {:.1} rad/s ({:.2} Hz), PM {:.1}° at {:.1} rad/s, GM {:.1} dB, \
             stable {}",
            m.crossover_rad_s,
            m.crossover_rad_s / std::f64::consts::TAU,
            m.phase_margin_deg,
            m.phase_margin_at_rad_s,
            m.gain_margin_db(),
            m.stable
        )
    };
    out.push(line("present gains on the model", &o.present));
    out.push(line("designed gains on the model", &t.margins));
    out.push(format!(
        "aimed at: crossover {:.1} rad/s, PM {:.0}°",
        o.spec.crossover_rad_s, o.spec.phase_margin_deg
    ));
    if let Some(l) = &o.lqg {
        let r = &l.raised;
        out.push(format!(
            "LQG (law = \"lqg\"): the file's weights on the model: |S|max {:.2}, crossover \
             {:.1} rad/s",
            l.present.peak_sensitivity, l.present.crossover_rad_s
        ));
        out.push(format!(
            "LQG designed: position and integral weights ×{:.3} (the most that keeps the \
             crossover ≤ {:.1} rad/s and |S|max ≤ {:.2}, so PM ≥ 45.2° and GM ≥ 12.7 dB): \
             |S|max {:.2}, crossover {:.1} rad/s; lqg = {}",
            r.scale,
            l.cap,
            lqg::TUNED_MAX_SENSITIVITY,
            r.figures.peak_sensitivity,
            r.figures.crossover_rad_s,
            lqg::weights_toml(&r.weights)
        ));
    }
    out
}

/// The curves of the plot: the steps (measured, predicted, designed) and the Bode
/// diagram.
pub(super) fn curves(
    j: &Joint,
    rec: &Record,
    o: &IdentOptions,
    id: &Identified,
    out: &Outcome,
    m: &Measured,
) -> Result<(Vec<Curve>, Vec<BodeCurve>), Failure> {
    let every = |v: &[f64]| -> Vec<(f64, f64)> {
        let step = (v.len() / 500).max(1);
        v.iter()
            .enumerate()
            .step_by(step)
            .map(|(k, y)| (k as f64 * H, *y))
            .collect()
    };
    let designed = tune::closed_loop_step(&id.plant, j.cpu, H, out.tuned.pid(), m.measured.len());
    let curve = |label: &str, v: &[f64]| Curve {
        label: label.into(),
        points: every(v),
    };
    let steps = vec![
        curve("measured, present gains", &m.measured),
        curve("model, present gains", &m.predicted),
        curve("model, designed gains (no feed-forward)", &designed),
    ];
    let ws = tune::log_grid(1.0, 2000.0, 200);
    let fail = |e: String| Failure::new(exit::ALARM, e);
    let present =
        tune::bode(&id.plant, j.cpu, H, present(&j.gains), &ws).map_err(|e| fail(e.to_string()))?;
    let tuned =
        tune::bode(&id.plant, j.cpu, H, out.tuned.pid(), &ws).map_err(|e| fail(e.to_string()))?;
    let measured = ident::empirical_response(rec, o, &ws);
    let bode = vec![
        BodeCurve {
            label: "identified plant".into(),
            points: ws.iter().map(|&w| (w, id.plant.at(w))).collect(),
            marks: false,
        },
        BodeCurve {
            label: "measured plant".into(),
            points: ws
                .iter()
                .zip(measured)
                .filter_map(|(&w, v)| Some((w, v?)))
                .collect(),
            marks: true,
        },
        BodeCurve {
            label: "loop gain, present gains".into(),
            points: present.iter().map(|b| (b.w, b.loop_gain)).collect(),
            marks: false,
        },
        BodeCurve {
            label: "loop gain, designed gains".into(),
            points: tuned.iter().map(|b| (b.w, b.loop_gain)).collect(),
            marks: false,
        },
    ];
    Ok((steps, bode))
}
