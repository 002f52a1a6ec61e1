//! How far the interpolated path strays from the programmed polyline where the
//! compressor ([`crate::gcode::compress`]) merged chords into curves: measured on the
//! controller's own commanded pose, every tick of a simulated run (`--check`,
//! `--sim`), and half-way between ticks (the drives move straight from one tick's
//! pose to the next).
//!
//! The executing block is known from the controller's count of completed blocks, so
//! each pose is compared with the chords of exactly the curve it lies on (and the
//! chord either side of it, where a corner is blended): a program that passes the same
//! place twice is not measured against the wrong pass. Distances are in the
//! compressor's space ([`crate::gcode::compress::space`]): nm over X Y Z, 1° counted
//! as 1 mm.

use crate::gcode::compress::space::{on_segment, to_fit, Point as V};
use pkmc::config::AXES;
use pkmc::motion::block::{Block, Motion};
use serde::Serialize;
use std::ops::Range;

/// The largest deviation found, for the report.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct Worst {
    /// Largest distance from the programmed polyline, mm (1° as 1 mm).
    pub deviation_mm: f64,
    /// NC line of the programmed chord nearest to where it was met.
    pub line: u32,
    /// Poses measured.
    pub samples: u64,
}

/// The meter: the programmed points and, per streamed block, the chords it stands for.
#[derive(Clone, Debug, Default)]
pub struct Meter {
    /// Programmed points: the start, then each motion block's end.
    points: Vec<V>,
    /// NC line of the chord ending at each point.
    lines: Vec<u32>,
    /// Per streamed block: the chords (indices of their end points) it stands for;
    /// empty for blocks that are not merged curves.
    spans: Vec<Range<usize>>,
    prev: Option<(V, usize)>,
    cursor: Option<usize>,
    /// What was found so far.
    pub worst: Worst,
}

impl Meter {
    /// A meter for `streamed` blocks standing for `programmed` ones (`source[i]`: the
    /// programmed blocks of streamed block `i`), both from `start`.
    pub fn new(
        programmed: &[Block],
        streamed: &[Block],
        source: &[Range<usize>],
        start: [i64; AXES],
    ) -> Self {
        let mut points = vec![to_fit(&start)];
        let mut lines = vec![0];
        // Programmed block k ends at point index[k].
        let mut index = Vec::with_capacity(programmed.len());
        for b in programmed {
            if !matches!(b.motion, Motion::Dwell(_) | Motion::Aux(_)) {
                points.push(to_fit(&b.target));
                lines.push(b.line);
            }
            index.push(points.len() - 1);
        }
        let spans = streamed
            .iter()
            .zip(source)
            .map(|(b, r)| match b.motion {
                Motion::Cubic { .. } if !r.is_empty() => index[r.start]..index[r.end - 1] + 1,
                _ => 0..0,
            })
            .collect();
        Self {
            points,
            lines,
            spans,
            ..Self::default()
        }
    }

    /// Measures the pose of a tick: `done` blocks of the job completed so far (the
    /// controller's count, from 0 when the host connected), `pose` commanded (axis
    /// units).
    pub fn record(&mut self, done: u32, pose: &[i64; AXES]) {
        let k = done as usize;
        let q = to_fit(pose);
        if let Some((p, prev_k)) = self.prev {
            if prev_k == k {
                let mid: V = core::array::from_fn(|i| (p[i] + q[i]) / 2.0);
                self.measure(k, &mid);
            }
        }
        self.measure(k, &q);
        self.prev = Some((q, k));
    }

    fn measure(&mut self, k: usize, q: &V) {
        // With jerk limitation the commanded pose trails the block count by up to
        // half a smoothing window: the curve executing and the two before it, one
        // chord more either side for blended joins, near where the last pose was.
        let spans =
            &self.spans[k.saturating_sub(2).min(self.spans.len())..(k + 1).min(self.spans.len())];
        let Some(now) = self.spans.get(k).filter(|r| !r.is_empty()) else {
            return;
        };
        let first = spans
            .iter()
            .find(|r| !r.is_empty())
            .map_or(now.start, |r| r.start);
        let mut lo = first.saturating_sub(1).max(1);
        let mut hi = (now.end + 1).min(self.points.len());
        if let Some(c) = self.cursor {
            lo = lo.max(c.saturating_sub(WINDOW));
            hi = hi.min(c + WINDOW).max(lo);
        }
        let mut best = (f64::INFINITY, 0);
        for e in lo..hi {
            let d = on_segment(q, &self.points[e - 1], &self.points[e]).1;
            if d < best.0 {
                best = (d, e);
            }
        }
        if best.1 == 0 {
            return;
        }
        self.cursor = Some(best.1);
        self.worst.samples += 1;
        let mm = best.0 / 1e6;
        if mm > self.worst.deviation_mm {
            self.worst.deviation_mm = mm;
            self.worst.line = self.lines[best.1];
        }
    }
}

/// Chords searched either side of the last nearest one.
const WINDOW: usize = 64;
