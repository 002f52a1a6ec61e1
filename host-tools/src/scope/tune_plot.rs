//! Plots of a tuning: step responses (predicted against measured or true) on the
//! left, the Bode diagram (magnitude in dB, phase in degrees, unwrapped, against
//! log ω) on the right; SVG or PNG by the file's extension, in the house style of
//! the simulator's plots (white ground, DejaVu Sans, 1500 × 1000 pixels).

use crate::control::plant::Complex;

/// A curve of a step-response panel.
#[derive(Clone, Debug, PartialEq)]
pub struct Curve {
    /// Legend.
    pub label: String,
    /// (time s, position mm or degrees).
    pub points: Vec<(f64, f64)>,
}

/// A curve of the Bode diagram.
#[derive(Clone, Debug, PartialEq)]
pub struct BodeCurve {
    /// Legend.
    pub label: String,
    /// (ω rad/s, response).
    pub points: Vec<(f64, Complex)>,
    /// Draw as separate marks (measured data) rather than a line.
    pub marks: bool,
}

/// Plot size, pixels.
pub const SIZE: (u32, u32) = (1500, 1000);

/// Draws `steps` and `bode` under `title` into `path` (.svg or .png).
pub fn draw(
    path: &std::path::Path,
    title: &str,
    steps: &[Curve],
    bode: &[BodeCurve],
) -> Result<(), String> {
    use plotters::prelude::*;
    crate::analysis::plot::register_font();
    let name = path.display().to_string();
    let fail = |e: String| format!("{name}: cannot draw the plot: {e}");
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase());
    match ext.as_deref() {
        Some("svg") => {
            let root = SVGBackend::new(path, SIZE).into_drawing_area();
            render(&root, title, steps, bode).map_err(fail)?;
            root.present().map_err(|e| fail(e.to_string()))
        }
        Some("png") => {
            let root = BitMapBackend::new(path, SIZE).into_drawing_area();
            render(&root, title, steps, bode).map_err(fail)?;
            root.present().map_err(|e| fail(e.to_string()))
        }
        _ => Err(format!("{name}: a plot is .svg or .png")),
    }
}

/// Draws `steps` and `bode` under `title` as SVG text (what [`draw`] writes to an
/// `.svg` file).
pub fn svg(title: &str, steps: &[Curve], bode: &[BodeCurve]) -> Result<String, String> {
    use plotters::prelude::*;
    crate::analysis::plot::register_font();
    let mut out = String::new();
    {
        let root = SVGBackend::with_string(&mut out, SIZE).into_drawing_area();
        render(&root, title, steps, bode)?;
        root.present().map_err(|e| e.to_string())?;
    }
    Ok(out)
}

/// Smallest and largest of `values`, padded by 5 % (never an empty range).
fn span(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    let pad = ((hi - lo) * 0.05).max(1e-9);
    (lo - pad, hi + pad)
}

/// Phase in degrees, unwrapped along the curve.
fn unwrapped(points: &[(f64, Complex)]) -> Vec<(f64, f64)> {
    let mut out: Vec<(f64, f64)> = Vec::with_capacity(points.len());
    for &(w, c) in points {
        let mut p = c.arg().to_degrees();
        if let Some(&(_, last)) = out.last() {
            p += 360.0 * ((last - p) / 360.0).round();
        }
        out.push((w, p));
    }
    out
}

fn render<DB: plotters::prelude::DrawingBackend>(
    root: &plotters::prelude::DrawingArea<DB, plotters::coord::Shift>,
    title: &str,
    steps: &[Curve],
    bode: &[BodeCurve],
) -> Result<(), String> {
    use plotters::prelude::*;
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    root.fill(&WHITE).map_err(err)?;
    let root = root.titled(title, ("sans-serif", 22)).map_err(err)?;
    let (left, right) = root.split_horizontally(SIZE.0 as i32 / 2);
    let ts = span(steps.iter().flat_map(|c| c.points.iter().map(|p| p.0)));
    let ys = span(steps.iter().flat_map(|c| c.points.iter().map(|p| p.1)));
    let mut chart = ChartBuilder::on(&left)
        .caption("step response", ("sans-serif", 18))
        .margin(10)
        .x_label_area_size(35)
        .y_label_area_size(60)
        .build_cartesian_2d(ts.0..ts.1, ys.0..ys.1)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("time (s)")
        .y_desc("position (mm or deg)")
        .draw()
        .map_err(err)?;
    for (i, c) in steps.iter().enumerate() {
        let color = Palette99::pick(i).to_rgba();
        chart
            .draw_series(LineSeries::new(c.points.iter().copied(), color))
            .map_err(err)?
            .label(c.label.clone())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color));
    }
    if !steps.is_empty() {
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(err)?;
    }
    let (top, bottom) = right.split_vertically((SIZE.1 as i32 - 40) / 2);
    let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
    for &(w, _) in bode.iter().flat_map(|c| &c.points) {
        if w > 0.0 && w.is_finite() {
            lo = lo.min(w);
            hi = hi.max(w);
        }
    }
    let ws = if lo < hi { (lo, hi) } else { (1.0, 1000.0) };
    let db = |c: Complex| 20.0 * c.abs().log10();
    let mags: Vec<Vec<(f64, f64)>> = bode
        .iter()
        .map(|c| c.points.iter().map(|&(w, v)| (w, db(v))).collect())
        .collect();
    let phases: Vec<Vec<(f64, f64)>> = bode.iter().map(|c| unwrapped(&c.points)).collect();
    for (area, data, what) in [
        (&top, &mags, "magnitude (dB)"),
        (&bottom, &phases, "phase (deg)"),
    ] {
        let vs = span(data.iter().flatten().map(|p| p.1));
        let mut chart = ChartBuilder::on(area)
            .caption(what, ("sans-serif", 18))
            .margin(10)
            .x_label_area_size(35)
            .y_label_area_size(60)
            .build_cartesian_2d((ws.0..ws.1).log_scale(), vs.0..vs.1)
            .map_err(err)?;
        chart
            .configure_mesh()
            .x_desc("ω (rad/s)")
            .y_desc(what)
            .draw()
            .map_err(err)?;
        for (i, (c, pts)) in bode.iter().zip(data).enumerate() {
            let color = Palette99::pick(i + steps.len()).to_rgba();
            let pts = pts.iter().copied().filter(|p| p.1.is_finite());
            let series = if c.marks {
                chart.draw_series(pts.map(|p| Circle::new(p, 3, color.filled())))
            } else {
                chart.draw_series(LineSeries::new(pts, color))
            };
            series
                .map_err(err)?
                .label(c.label.clone())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color));
        }
        if !bode.is_empty() {
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .draw()
                .map_err(err)?;
        }
    }
    Ok(())
}
