//! The tool position error over the workspace before and after calibration: two maps
//! over X and Y at the home pose's Z and angles, each cell the error of the nominal
//! (left) and of the calibrated (right) parameters against the true machine.

use super::forward::predict;
use super::model::Model;
use super::plan::{workspace, Usable};
use pkmc::config::MachineConfig;
use plotters::coord::Shift;
use plotters::prelude::*;

/// Cells per side.
const CELLS: usize = 48;

/// Position errors (µm) on the grid, `None` where the pose is not usable; and the
/// grid's X and Y ranges.
type Grid = (Vec<Vec<Option<[f64; 2]>>>, [f64; 2], [f64; 2]);

fn grid(config: &MachineConfig, model: &Model, truth: &[f64], fitted: &[f64]) -> Grid {
    let usable = Usable::new(config);
    let ws = workspace(model);
    let th = model.nominal();
    let at = |r: [f64; 2], k: usize| r[0] + (r[1] - r[0]) * (k as f64 + 0.5) / CELLS as f64;
    let cells = (0..CELLS)
        .map(|iy| {
            (0..CELLS)
                .map(|ix| {
                    let mut pose = model.home;
                    pose[0] = at(ws[0], ix);
                    pose[1] = at(ws[1], iy);
                    if !usable.check(&pose) {
                        return None;
                    }
                    let (q, x) = model.inverse(&th, &pose)?;
                    let t = predict(model, truth, &q, &x)?.0;
                    let err =
                        |p: &[f64]| (0..3).map(|k| (p[k] - t[k]).powi(2)).sum::<f64>().sqrt() * 1e3;
                    let n = predict(model, &th, &q, &x)?.0;
                    let c = predict(model, fitted, &q, &x)?.0;
                    Some([err(&n), err(&c)])
                })
                .collect()
        })
        .collect();
    (cells, ws[0], ws[1])
}

/// Dark blue through green to yellow for 0..1.
fn colour(v: f64) -> RGBColor {
    let stops = [
        (68.0, 1.0, 84.0),
        (59.0, 82.0, 139.0),
        (33.0, 145.0, 140.0),
        (94.0, 201.0, 98.0),
        (253.0, 231.0, 37.0),
    ];
    let x = v.clamp(0.0, 1.0) * (stops.len() - 1) as f64;
    let (i, f) = (
        (x as usize).min(stops.len() - 2),
        x - (x as usize).min(stops.len() - 2) as f64,
    );
    let mix = |a: f64, b: f64| (a + (b - a) * f) as u8;
    let (a, b) = (stops[i], stops[i + 1]);
    RGBColor(mix(a.0, b.0), mix(a.1, b.1), mix(a.2, b.2))
}

fn panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    g: &Grid,
    which: usize,
    title: &str,
) -> Result<(), String> {
    let e = |x: DrawingAreaErrorKind<DB::ErrorType>| x.to_string();
    let max =
        g.0.iter()
            .flatten()
            .flatten()
            .map(|v| v[which])
            .fold(0.0, f64::max);
    let mut chart = ChartBuilder::on(area)
        .caption(
            format!("{title}: 0 (dark) to {max:.1} µm (yellow)"),
            ("sans-serif", 24),
        )
        .margin(15)
        .x_label_area_size(40)
        .y_label_area_size(50)
        .build_cartesian_2d(g.1[0]..g.1[1], g.2[0]..g.2[1])
        .map_err(e)?;
    chart
        .configure_mesh()
        .x_desc("X, mm")
        .y_desc("Y, mm")
        .disable_mesh()
        .draw()
        .map_err(e)?;
    let (dx, dy) = (
        (g.1[1] - g.1[0]) / CELLS as f64,
        (g.2[1] - g.2[0]) / CELLS as f64,
    );
    let cells = g.0.iter().enumerate().flat_map(|(iy, row)| {
        row.iter().enumerate().map(move |(ix, c)| {
            let (x0, y0) = (g.1[0] + dx * ix as f64, g.2[0] + dy * iy as f64);
            let fill = c.map_or(RGBColor(200, 200, 200), |v| {
                colour(v[which] / max.max(1e-9))
            });
            Rectangle::new([(x0, y0), (x0 + dx, y0 + dy)], fill.filled())
        })
    });
    chart.draw_series(cells).map_err(e)?;
    Ok(())
}

/// Draws the two maps into `path` (.svg or .png); returns the largest error before
/// and after, µm.
pub fn draw(
    path: &std::path::Path,
    config: &MachineConfig,
    model: &Model,
    truth: &[f64],
    fitted: &[f64],
) -> Result<[f64; 2], String> {
    crate::analysis::plot::register_font();
    let g = grid(config, model, truth, fitted);
    let name = path.display().to_string();
    let size = (1600, 760);
    let fail = |e: String| format!("{name}: cannot draw the plot: {e}");
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("");
    macro_rules! both {
        ($root:expr) => {{
            let root = $root.into_drawing_area();
            root.fill(&WHITE).map_err(|e| fail(e.to_string()))?;
            let (l, r) = root.split_horizontally(size.0 / 2);
            panel(&l, &g, 0, "nominal machine file").map_err(fail)?;
            panel(&r, &g, 1, "calibrated").map_err(fail)?;
            root.present().map_err(|e| fail(e.to_string()))?;
        }};
    }
    match ext {
        "svg" => both!(SVGBackend::new(path, size)),
        "png" => both!(BitMapBackend::new(path, size)),
        _ => return Err(format!("{name}: a plot is .svg or .png")),
    }
    let max = |w: usize| {
        g.0.iter()
            .flatten()
            .flatten()
            .map(|v| v[w])
            .fold(0.0, f64::max)
    };
    Ok([max(0), max(1)])
}
