//! A recorder table drawn as stacked traces against time (.svg or .png, by the
//! file's extension, or an SVG text for the station's scope panel): one panel per
//! signal, its column name as the title, and the trigger (time 0) marked on a
//! capture. The drawing also gives where it put things ([`Layout`]), so a page can
//! place cursors over it.

use super::{column, Table};
use crate::analysis::plot::{format_of, register_font, Format};
use plotters::coord::Shift;
use plotters::prelude::*;

/// Plot width, and height per signal, pixels.
const WIDTH: u32 = 1400;
const PANEL: u32 = 220;

/// Where a drawing put its traces, in the image's pixels: the time axis (common to
/// every panel) and each panel's value axis.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct Layout {
    /// The image's width.
    pub width: u32,
    /// The image's height.
    pub height: u32,
    /// The time at the plotting area's left end, s.
    pub t0: f64,
    /// The time at its right end, s.
    pub t1: f64,
    /// The plotting area's left end.
    pub x0: i32,
    /// Its right end.
    pub x1: i32,
    /// Each panel's plotting area, top and bottom, and the values there.
    pub panels: Vec<PanelLayout>,
}

/// One panel's value axis.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct PanelLayout {
    /// The plotting area's top.
    pub top: i32,
    /// Its bottom.
    pub bottom: i32,
    /// The value at the bottom.
    pub low: f64,
    /// The value at the top.
    pub high: f64,
}

/// Draws `table` into `path`.
pub fn draw(path: &std::path::Path, table: &Table) -> Result<(), String> {
    register_font();
    let name = path.display().to_string();
    let fail = |e: String| format!("{name}: cannot draw the plot: {e}");
    let size = (WIDTH, PANEL * table.signals.len().max(1) as u32 + 20);
    match format_of(path)? {
        Format::Svg => {
            let root = SVGBackend::new(path, size).into_drawing_area();
            render(&root, table, None, size).map_err(fail)?;
            root.present().map_err(|e| fail(e.to_string()))
        }
        Format::Png => {
            let root = BitMapBackend::new(path, size).into_drawing_area();
            render(&root, table, None, size).map_err(fail)?;
            root.present().map_err(|e| fail(e.to_string()))
        }
    }
}

/// Draws the samples of `table` between times `range` (s; `None`: all of them) as
/// SVG text `width` pixels wide and `panel` high per signal; returns it with where
/// the traces are.
pub fn svg(
    table: &Table,
    range: Option<(f64, f64)>,
    width: u32,
    panel: u32,
) -> Result<(String, Layout), String> {
    register_font();
    let size = (width, panel * table.signals.len().max(1) as u32 + 20);
    let mut text = String::new();
    let layout = {
        let root = SVGBackend::with_string(&mut text, size).into_drawing_area();
        let layout = render(&root, table, range, size)?;
        root.present().map_err(|e| e.to_string())?;
        layout
    };
    Ok((text, layout))
}

/// The time range drawn: `range` when given (widened to one sample period at least),
/// else the table's first to last sample.
fn time_range(t: &Table, range: Option<(f64, f64)>) -> (f64, f64) {
    let (a, b) = match (range, t.rows.first(), t.rows.last()) {
        (Some(r), _, _) => r,
        (None, Some(a), Some(b)) => (t.time(a.0), t.time(b.0)),
        _ => (0.0, 1.0),
    };
    (a, b.max(a + t.period_s.max(1e-6)))
}

fn render<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    t: &Table,
    range: Option<(f64, f64)>,
    size: (u32, u32),
) -> Result<Layout, String> {
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    root.fill(&WHITE).map_err(err)?;
    let panels = root.split_evenly((t.signals.len().max(1), 1));
    let (t0, t1) = time_range(t, range);
    // The samples drawn: those in the range (a trace is not drawn past its edges).
    let inside = |time: f64| time >= t0 - 1e-9 && time <= t1 + 1e-9;
    let mut layout = Layout {
        width: size.0,
        height: size.1,
        t0,
        t1,
        ..Layout::default()
    };
    for (k, (area, sig)) in panels.iter().zip(&t.signals).enumerate() {
        let values: Vec<(f64, f64)> = t
            .rows
            .iter()
            .map(|(n, v)| (t.time(*n), v[k] as f64))
            .filter(|p| inside(p.0))
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
        if t.zero != 0 && (t0..=t1).contains(&0.0) {
            chart
                .draw_series(LineSeries::new(
                    [(0.0, lo - pad), (0.0, hi + pad)],
                    RED.stroke_width(1),
                ))
                .map_err(err)?;
        }
        let (xs, ys) = chart.plotting_area().get_pixel_range();
        (layout.x0, layout.x1) = (xs.start, xs.end);
        layout.panels.push(PanelLayout {
            top: ys.start,
            bottom: ys.end,
            low: lo - pad,
            high: hi + pad,
        });
    }
    Ok(layout)
}
