//! The tool path of a simulated run, recorded tick by tick, and its plots.
//!
//! [`Recorder`] keeps one [`Sample`] per interpolation period (decimating by two
//! whenever [`MAX_SAMPLES`] is reached, so memory stays bounded however long the job)
//! plus the sequence of NC lines executed. [`draw`] renders top (XY), front (XZ) and
//! side (YZ) views of the tool path, path speed over time and joints over time, as SVG
//! or PNG (chosen by the file's extension).

use pkmc::config::MAX_JOINTS;

/// Samples kept before the recorder halves its rate.
pub const MAX_SAMPLES: usize = 100_000;

/// The state at the end of one interpolation period, user units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    /// Simulated time, s.
    pub t_s: f64,
    /// NC line executing.
    pub line: u32,
    /// Tool position X Y Z, mm.
    pub xyz: [f64; 3],
    /// Commanded joints, mm or degrees (the first `joints` entries).
    pub joints: [f64; MAX_JOINTS],
}

/// Records samples and executed lines from a simulator.
#[derive(Clone, Debug, Default)]
pub struct Recorder {
    /// Samples kept, in time order.
    pub samples: Vec<Sample>,
    /// Number of joints of the machine.
    pub joints: usize,
    /// NC lines in the order they started executing (consecutive repeats merged), as
    /// their count and digest.
    pub lines: LineLog,
    keep_path: bool,
    stride: u64,
    seen: u64,
    /// How far merged curves stray from their chords, when measured.
    pub deviation: Option<super::deviation::Meter>,
    /// When the controller had completed 1, 2, … blocks, simulated s (with the path).
    pub done_at: Vec<f64>,
}

impl Recorder {
    /// A recorder for a machine with `joints` joints; `keep_path` keeps samples (for
    /// plots), otherwise only the executed lines.
    pub fn new(joints: usize, keep_path: bool) -> Self {
        Self {
            joints,
            keep_path,
            stride: 1,
            ..Self::default()
        }
    }

    /// Records the simulator's state after a tick.
    pub fn record(&mut self, sim: &crate::sim::Simulator) {
        if let Some(m) = &mut self.deviation {
            m.record(sim.ctrl.status().blocks_done, sim.ctrl.pose());
        }
        // Every block started, from the controller's log (not the line at the end of
        // the tick, which misses blocks that start and end within one).
        for &line in sim.lines_started() {
            if line != 0 {
                self.lines.push(line);
            }
        }
        if !self.keep_path {
            return;
        }
        let done = sim.ctrl.status().blocks_done as usize;
        while self.done_at.len() < done {
            self.done_at
                .push(sim.ticks as f64 * pkmc::units::TICK_NS as f64 * 1e-9);
        }
        self.seen += 1;
        if self.seen < self.stride {
            return;
        }
        self.seen = 0;
        let row = sim.trace_row();
        let mut joints = [0.0; MAX_JOINTS];
        for (q, v) in joints.iter_mut().zip(&row.joints) {
            *q = *v;
        }
        self.samples.push(Sample {
            t_s: row.t_s,
            line: row.line,
            xyz: [row.pose[0], row.pose[1], row.pose[2]],
            joints,
        });
        if self.samples.len() >= MAX_SAMPLES {
            let mut i = 0;
            self.samples.retain(|_| {
                i += 1;
                i % 2 == 1
            });
            self.stride *= 2;
        }
    }
}

/// A 64-bit FNV-1a digest of a line sequence, in hex: equal sequences, equal digests.
pub fn lines_digest(lines: &[u32]) -> String {
    let mut log = LineLog::default();
    for &l in lines {
        log.add(l);
    }
    log.digest()
}

/// A sequence of NC lines kept as its length and running digest ([`lines_digest`]),
/// so that a program of any length costs the same memory; consecutive repeats are
/// merged by [`LineLog::push`].
#[derive(Clone, Debug)]
pub struct LineLog {
    count: usize,
    hash: u64,
    last: Option<u32>,
}

impl Default for LineLog {
    fn default() -> Self {
        Self {
            count: 0,
            hash: 0xcbf2_9ce4_8422_2325,
            last: None,
        }
    }
}

impl LineLog {
    /// `line` after the others, unless it repeats the last.
    pub fn push(&mut self, line: u32) {
        if self.last != Some(line) {
            self.add(line);
        }
    }

    fn add(&mut self, line: u32) {
        for b in line.to_le_bytes() {
            self.hash ^= b as u64;
            self.hash = self.hash.wrapping_mul(0x0100_0000_01b3);
        }
        self.count += 1;
        self.last = Some(line);
    }

    /// Lines in the sequence.
    pub fn len(&self) -> usize {
        self.count
    }

    /// Whether it is empty.
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// The sequence's digest, in hex.
    pub fn digest(&self) -> String {
        format!("{:016x}", self.hash)
    }
}

/// Image format of a plot, from the file's extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// Scalable vector graphics.
    Svg,
    /// Portable network graphics.
    Png,
}

/// The format `path` asks for, or why none.
pub fn format_of(path: &std::path::Path) -> Result<Format, String> {
    match path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .as_deref()
    {
        Some("svg") => Ok(Format::Svg),
        Some("png") => Ok(Format::Png),
        _ => Err(format!("{}: a plot is .svg or .png", path.display())),
    }
}

/// Plot size, pixels.
pub const SIZE: (u32, u32) = (1500, 1000);

/// Registers DejaVu Sans, embedded, as `sans-serif` (once): every plot of the crate
/// draws with it (the simulator's, the scope's and tuning's, calibration's), and no
/// system font is needed.
pub(crate) fn register_font() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // DejaVu Sans, embedded: no system fonts are needed.
        let _ = plotters::style::register_font(
            "sans-serif",
            plotters::style::FontStyle::Normal,
            dejavu::sans::regular(),
        );
    });
}

/// Draws `rec`'s tool path, speed and joints of `machine` into `path` (.svg or .png).
pub fn draw(
    path: &std::path::Path,
    rec: &Recorder,
    machine: &pkmc::config::MachineConfig,
) -> Result<(), String> {
    use plotters::prelude::*;
    register_font();
    let name = path.display().to_string();
    let fail = |e: String| format!("{name}: cannot draw the plot: {e}");
    match format_of(path)? {
        Format::Svg => {
            let root = SVGBackend::new(path, SIZE).into_drawing_area();
            render(&root, rec, machine).map_err(fail)?;
            root.present().map_err(|e| fail(e.to_string()))
        }
        Format::Png => {
            let root = BitMapBackend::new(path, SIZE).into_drawing_area();
            render(&root, rec, machine).map_err(fail)?;
            root.present().map_err(|e| fail(e.to_string()))
        }
    }
}

/// Smallest and largest of `values`, widened so that the range is never empty.
fn span(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    let pad = ((hi - lo) * 0.05).max(0.5);
    (lo - pad, hi + pad)
}

/// Path speed between consecutive samples, mm/min, at the later sample's time.
pub fn speeds(samples: &[Sample]) -> Vec<(f64, f64)> {
    samples
        .windows(2)
        .filter(|w| w[1].t_s > w[0].t_s)
        .map(|w| {
            let d: f64 = (0..3)
                .map(|i| (w[1].xyz[i] - w[0].xyz[i]).powi(2))
                .sum::<f64>()
                .sqrt();
            (w[1].t_s, d / (w[1].t_s - w[0].t_s) * 60.0)
        })
        .collect()
}

fn render<DB: plotters::prelude::DrawingBackend>(
    root: &plotters::prelude::DrawingArea<DB, plotters::coord::Shift>,
    rec: &Recorder,
    machine: &pkmc::config::MachineConfig,
) -> Result<(), String> {
    use plotters::prelude::*;
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    root.fill(&WHITE).map_err(err)?;
    let root = root
        .titled(
            &format!(
                "{}: tool path, {} samples over {:.3} s",
                machine.name,
                rec.samples.len(),
                rec.samples.last().map_or(0.0, |s| s.t_s)
            ),
            ("sans-serif", 22),
        )
        .map_err(err)?;
    let (top, bottom) = root.split_vertically(SIZE.1 as i32 / 2 - 20);
    let views = top.split_evenly((1, 3));
    let names = [
        ("top (XY)", 0, 1),
        ("front (XZ)", 0, 2),
        ("side (YZ)", 1, 2),
    ];
    let axis = ['X', 'Y', 'Z'];
    for (area, (title, a, b)) in views.iter().zip(names) {
        let xs = span(rec.samples.iter().map(|s| s.xyz[a]));
        let ys = span(rec.samples.iter().map(|s| s.xyz[b]));
        let mut chart = ChartBuilder::on(area)
            .caption(title, ("sans-serif", 18))
            .margin(10)
            .x_label_area_size(35)
            .y_label_area_size(50)
            .build_cartesian_2d(xs.0..xs.1, ys.0..ys.1)
            .map_err(err)?;
        chart
            .configure_mesh()
            .x_desc(format!("{} (mm)", axis[a]))
            .y_desc(format!("{} (mm)", axis[b]))
            .draw()
            .map_err(err)?;
        chart
            .draw_series(LineSeries::new(
                rec.samples.iter().map(|s| (s.xyz[a], s.xyz[b])),
                &BLUE,
            ))
            .map_err(err)?;
    }
    let (left, right) = bottom.split_horizontally(SIZE.0 as i32 / 2);
    let t_end = rec.samples.last().map_or(1.0, |s| s.t_s.max(1e-3));
    let v = speeds(&rec.samples);
    let vmax = v.iter().map(|p| p.1).fold(0.0f64, f64::max).max(1.0) * 1.05;
    let mut chart = ChartBuilder::on(&left)
        .caption("path speed", ("sans-serif", 18))
        .margin(10)
        .x_label_area_size(35)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..t_end, 0.0..vmax)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("time (s)")
        .y_desc("speed (mm/min)")
        .draw()
        .map_err(err)?;
    chart.draw_series(LineSeries::new(v, &RED)).map_err(err)?;
    let n = rec.joints.min(MAX_JOINTS);
    let qs = span(
        rec.samples
            .iter()
            .flat_map(|s| s.joints[..n].iter().copied()),
    );
    let mut chart = ChartBuilder::on(&right)
        .caption("joints", ("sans-serif", 18))
        .margin(10)
        .x_label_area_size(35)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..t_end, qs.0..qs.1)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("time (s)")
        .y_desc("joint (mm or deg)")
        .draw()
        .map_err(err)?;
    for j in 0..n {
        let color = Palette99::pick(j).to_rgba();
        chart
            .draw_series(LineSeries::new(
                rec.samples.iter().map(|s| (s.t_s, s.joints[j])),
                color,
            ))
            .map_err(err)?
            .label(format!("q{}", j + 1))
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color));
    }
    if n > 0 {
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(err)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_line_log_counts_and_digests_the_lines_with_repeats_merged() {
        let mut log = LineLog::default();
        for l in [3, 3, 4, 5, 5, 5, 4, 9] {
            log.push(l);
        }
        assert_eq!(log.len(), 5);
        assert_eq!(log.digest(), lines_digest(&[3, 4, 5, 4, 9]));
        assert_ne!(log.digest(), lines_digest(&[3, 4, 5, 9]));
        assert_eq!(LineLog::default().digest(), lines_digest(&[]));
    }
}
