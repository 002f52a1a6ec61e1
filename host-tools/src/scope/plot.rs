//! A recorder table drawn as stacked traces against time (.svg or .png, by the
//! file's extension): one panel per signal, its column name as the title, and the
//! trigger (time 0) marked on a capture.

use super::{column, Table};
use crate::analysis::plot::{format_of, register_font, Format};
use plotters::coord::Shift;
use plotters::prelude::*;

/// Plot width, and height per signal, pixels.
const WIDTH: u32 = 1400;
const PANEL: u32 = 220;

/// Draws `table` into `path`.
pub fn draw(path: &std::path::Path, table: &Table) -> Result<(), String> {
    register_font();
    let name = path.display().to_string();
    let fail = |e: String| format!("{name}: cannot draw the plot: {e}");
    let size = (WIDTH, PANEL * table.signals.len().max(1) as u32 + 20);
    match format_of(path)? {
        Format::Svg => {
            let root = SVGBackend::new(path, size).into_drawing_area();
            render(&root, table).map_err(fail)?;
            root.present().map_err(|e| fail(e.to_string()))
        }
        Format::Png => {
            let root = BitMapBackend::new(path, size).into_drawing_area();
            render(&root, table).map_err(fail)?;
            root.present().map_err(|e| fail(e.to_string()))
        }
    }
}

fn render<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, t: &Table) -> Result<(), String> {
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    root.fill(&WHITE).map_err(err)?;
    let panels = root.split_evenly((t.signals.len().max(1), 1));
    let (t0, t1) = match (t.rows.first(), t.rows.last()) {
        (Some(a), Some(b)) => (t.time(a.0), t.time(b.0).max(t.time(a.0) + t.period_s)),
        _ => (0.0, 1.0),
    };
    for (k, (area, sig)) in panels.iter().zip(&t.signals).enumerate() {
        let values: Vec<(f64, f64)> = t
            .rows
            .iter()
            .map(|(n, v)| (t.time(*n), v[k] as f64))
            .collect();
        let (mut lo, mut hi) = values
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                (lo.min(p.1), hi.max(p.1))
            });
        if !lo.is_finite() {
            (lo, hi) = (0.0, 1.0);
        }
        let pad = ((hi - lo) * 0.08).max(0.5);
        let mut chart = ChartBuilder::on(area)
            .caption(column(*sig), ("sans-serif", 16))
            .margin(6)
            .x_label_area_size(28)
            .y_label_area_size(80)
            .build_cartesian_2d(t0..t1, (lo - pad)..(hi + pad))
            .map_err(err)?;
        chart
            .configure_mesh()
            .x_desc("s")
            .light_line_style(WHITE.mix(0.0))
            .draw()
            .map_err(err)?;
        chart
            .draw_series(LineSeries::new(values, BLUE.stroke_width(1)))
            .map_err(err)?;
        if t.zero != 0 {
            chart
                .draw_series(LineSeries::new(
                    [(0.0, lo - pad), (0.0, hi + pad)],
                    RED.stroke_width(1),
                ))
                .map_err(err)?;
        }
    }
    Ok(())
}
