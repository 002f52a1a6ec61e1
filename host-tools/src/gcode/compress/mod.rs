//! The chord compressor: runs of short `G1` moves (CAM output for surfaces: thousands
//! of chords of a fraction of a millimetre) become cubic spline blocks
//! ([`Motion::Cubic`]) that stay within the program's `G64 P` tolerance of the
//! programmed polyline; its real corners are rounded within the tolerance too.
//!
//! **Which moves.** Consecutive feed moves (`G1`) with the same feed and the same
//! blending tolerance that move X Y Z form a run: in `G64 P` within P, in `G64`
//! without P within [`Settings::g64_tolerance_nm`] (`nc-send
//! --g64-tolerance`; 1 µm by default: `G64` alone asks for the best speed and bounds no
//! deviation, as in LinuxCNC, and 1 µm keeps every programmed point within a count of
//! the scales; 0 merges nothing there), never in `G61`. A run ends where the path
//! turns by more than [`Settings::corner_deg`] between two moves — a real corner stays
//! a corner: a curve ends exactly on it and the planner blends or stops there as it
//! does for lines — and at anything else (a rapid, an arc, an auxiliary function, a
//! feed change).
//!
//! **Pieces.** A run is cut into curves from its start: each curve reaches as far
//! along the run as one cubic can follow within the tolerance ([`fit`]), found by
//! doubling, then bisection. Consecutive curves share their tangent at the point
//! where they meet (the second leaves along the first's end direction), so the tool
//! path is tangent-continuous along the run. Where no curve of two chords or more can
//! leave along that direction, one may leave along its own, turning at that point by
//! no more than the program's own corner there (the planner blends it as it blends
//! chords); where none can, the chord stays a line.
//!
//! **Time.** The controller plans one speed limit per block, from its tightest bend, and
//! runs a curve's parameter at a uniform rate (so the tool is slower where |dP/du| is
//! below its largest). A curve that turns more than [`Settings::max_turn_deg`] is kept
//! only if its estimated time at that limit is no longer than its chords' own
//! (the chords' time is estimated as the planner takes them: each vertex at the speed
//! its turn allows in one tick and its bend allows, from the machine's smallest X Y Z
//! acceleration, [`Settings::accel`]): dense chords of a gentle curve, which already
//! run fast, are merged into curves of a few degrees each; coarse chords, which stop
//! at every vertex, into long ones. Of the fits within the tolerance that reach as far,
//! the one kept runs most evenly, and starts at the speed the curve before it ends at
//! and ends at its own largest |dP/du|: where two curves meet along one direction,
//! the tool's speed jumps by the difference of their ends' shares of the path speed,
//! which the planner limits as it limits a turn.
//!
//! **Corners.** Once the runs are curves, each corner between two feed moves (lines or
//! curves) within `G64 P` that move X Y Z only is rounded by a cubic blend, tangent
//! to both, within `P` of the programmed polyline ([`blend`]; [`compress_runs`] is the
//! compressor without it).
//!
//! Rotary axes take part in the fit with 1° counted as 1 mm ([`space`]; a curve then
//! keeps them within the tolerance as well). The fit tolerance is
//! [`Settings::fit_share`] of `P`.

pub mod blend;
mod fit;
mod meet;
mod reach;
pub mod space;
#[cfg(test)]
mod tests;

use fit::Goal;
use meet::Held;
use pkmc::config::AXES;
use pkmc::motion::block::{Block, Motion};
use space::{from_fit, to_fit};
use std::ops::Range;

pub use fit::to_polyline;

/// What the compressor may do.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Settings {
    /// A turn sharper than this between two moves is a corner, degrees.
    pub corner_deg: f64,
    /// Smallest share of the speed asked for that the junction where a curve starts
    /// may allow (the jump of the tool's speed over the path speed from the block
    /// before, `fit::junction_share`); a curve that starts slower or faster is not
    /// taken.
    pub min_junction_share: f64,
    /// A curve whose start does not match the block before it is taken only where the
    /// one that does merges less than this share of its moves.
    pub matched_reach: f64,
    /// Longer moves are never merged, nm.
    pub max_chord_nm: f64,
    /// Share of the `G64 P` tolerance a curve may use (the rest is margin for the
    /// rounding of control points to whole units).
    pub fit_share: f64,
    /// Most moves in one curve.
    pub max_chords: usize,
    /// Smallest ratio of the slowest to the fastest |dP/du| along a curve.
    pub min_speed_ratio: f64,
    /// A curve of this many moves or more is cut shorter where one of at least a quarter
    /// as many (half of this number is always enough) runs more evenly than
    /// [`Settings::even_ratio`] (its slowest |dP/du| over its largest) and its own does
    /// not.
    pub even_from_moves: usize,
    /// The evenness asked of a long curve ([`Settings::even_from_moves`]).
    pub even_ratio: f64,
    /// A curve of four moves or more whose uneven pace ([`Settings::even_ratio`]) would
    /// lose this much time at the speed asked for or more (its polyline's length over
    /// the speed, times 1/pace − 1), s, is cut shorter as a long one is.
    pub even_cost_s: f64,

    /// A curve turning more than this, degrees, is weighed for time (module doc).
    pub max_turn_deg: f64,
    /// Tangents at the moves' ends are taken from points at least this many fit
    /// tolerances away (the rounding of short moves would turn them otherwise).
    pub tangent_reach: f64,
    /// Reweighted least-squares rounds of a fit with a free end tangent.
    pub reweights: usize,
    /// A fit with a free end tangent is preferred when it reaches this many times as
    /// far as one along the data's tangent.
    pub free_gain: f64,
    /// The machine's smallest X Y Z acceleration, nm/s² (0: unknown: curves are not
    /// weighed for time).
    pub accel: f64,
    /// The machine's smallest X Y Z speed, nm/s (0: unknown).
    pub max_speed: f64,
    /// The most acceleration a curve's bend can take at the tool, nm/s²: the planner's
    /// share of the X Y Z accelerations (0: unknown; the tolerance then makes no
    /// allowance for the ticks' chords, `fit::tick_sag`).
    pub bend_accel: f64,
    /// Corners between feed moves within `G64 P` are rounded by blends ([`blend`]).
    pub blend: bool,
    /// Turns of less than this, degrees, are not blended.
    pub blend_min_deg: f64,
    /// A blend trims at most this share of either block's length.
    pub blend_share: f64,
    /// A junction that turns less than [`Self::blend_min_deg`] is blended where the
    /// planner would give it more than this share of the acceleration at the feed
    /// ([`blend`]'s "Which corners").
    pub jump_share: f64,
    /// Where two curves of a run meet, the tangent there is turned towards the data's
    /// in this many steps at most, the data's first ([`meet`]; 0: never).
    pub turn_steps: u32,
    /// The tolerance runs are merged and corners blended within in `G64` without P,
    /// nm (the default 1 µm; 0: neither). The station's run by step runs the program
    /// as written, so a blend (a block of its own) never stops it.
    pub g64_tolerance_nm: f64,
}

impl Default for Settings {
    fn default() -> Self {
        Self {
            corner_deg: 30.0,
            min_junction_share: 0.5,
            matched_reach: 0.65,
            max_chord_nm: 100_000_000.0,
            fit_share: 0.95,
            max_chords: 400,
            min_speed_ratio: 0.5,
            even_from_moves: 40,
            even_ratio: 0.99,
            even_cost_s: 0.1,
            max_turn_deg: 8.0,
            tangent_reach: 3.0,
            reweights: 4,
            free_gain: 1.2,
            accel: 0.0,
            max_speed: 0.0,
            bend_accel: 0.0,
            blend: true,
            blend_min_deg: 0.5,
            blend_share: 0.45,
            jump_share: 0.05,
            turn_steps: 8,
            g64_tolerance_nm: 1000.0,
        }
    }
}

impl Settings {
    /// The defaults with the command line's choices: `--corner-deg`, blends (not
    /// `--no-blend`) and `--g64-tolerance` (mm); a value out of range is refused by the
    /// option's name.
    pub fn of_options(corner_deg: f64, blend: bool, g64_tolerance_mm: f64) -> Result<Self, String> {
        if !(corner_deg > 0.0 && corner_deg < 180.0) {
            return Err(format!(
                "--corner-deg {corner_deg}: give an angle between 0 and 180 degrees"
            ));
        }
        if !(0.0..=1.0).contains(&g64_tolerance_mm) {
            return Err(format!(
                "--g64-tolerance {g64_tolerance_mm}: give 0 to 1 mm"
            ));
        }
        Ok(Self {
            corner_deg,
            blend,
            g64_tolerance_nm: (g64_tolerance_mm * 1e6).round(),
            ..Self::default()
        })
    }

    /// Unknown (infinite) machine figures as 0.
    pub fn finite(self) -> Self {
        let f = |x: f64| if x.is_finite() { x } else { 0.0 };
        Self {
            accel: f(self.accel),
            max_speed: f(self.max_speed),
            bend_accel: f(self.bend_accel),
            ..self
        }
    }
}

/// A compressed program.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Compressed {
    /// The blocks to stream.
    pub blocks: Vec<Block>,
    /// For each block, the input blocks it stands for.
    pub source: Vec<Range<usize>>,
}

/// A point in fit space ([`space`]).
type V = space::Point;

fn sub(a: &V, b: &V) -> V {
    core::array::from_fn(|i| a[i] - b[i])
}

fn dot(a: &V, b: &V) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

fn norm(a: &V) -> f64 {
    dot(a, a).sqrt()
}

fn unit(a: &V) -> V {
    let n = norm(a);
    if n > 0.0 {
        a.map(|x| x / n)
    } else {
        *a
    }
}

/// May `b`, starting at `from`, be part of a run?
/// The tolerance a run of blocks like `b` is merged within, nm: its `G64 P`, or in
/// `G64` without P [`Settings::g64_tolerance_nm`]; `None` where none is merged (`G61`,
/// or `G64` with a zero `g64_tolerance_nm`).
pub fn merge_tolerance(b: &Block, s: &Settings) -> Option<f64> {
    match b.tolerance_nm {
        0 => None,
        u32::MAX => (s.g64_tolerance_nm > 0.0).then_some(s.g64_tolerance_nm),
        t => Some(t as f64),
    }
}

fn mergeable(b: &Block, from: &[i64; AXES], s: &Settings) -> bool {
    if b.motion != Motion::Linear || merge_tolerance(b, s).is_none() {
        return false;
    }
    let d = sub(&to_fit(&b.target), &to_fit(from));
    let xyz = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    xyz >= 1.0 && norm(&d) <= s.max_chord_nm
}

/// Compresses `blocks` (starting at `start`) with settings `s`, corners blended
/// ([`blend`]).
pub fn compress(blocks: &[Block], start: [i64; AXES], s: &Settings) -> Compressed {
    let runs = compress_runs(blocks, start, s);
    if !s.blend {
        return runs;
    }
    let mut out = Compressed::default();
    let mut b = blend::Blender::new(s, start);
    b.push(blocks, &runs, 0, &mut out);
    b.finish(&mut out);
    out
}

/// Compresses `blocks` (starting at `start`) with settings `s`: runs into curves,
/// corners not blended.
pub fn compress_runs(blocks: &[Block], start: [i64; AXES], s: &Settings) -> Compressed {
    compress_runs_after(blocks, start, s, Resume::default()).0
}

/// Where a merged piece of a polyline left off, for the next piece (the Grbl bridge
/// merges a sender's moves piece by piece): the direction and the ratio of the tool's
/// speed to the path speed its last block ends with, and its last chord's direction.
#[derive(Clone, Copy, Debug)]
pub struct Lead {
    dir: V,
    ratio: f64,
    chord: V,
    /// Where the last block is a curve whose end the next curve turned ([`meet`]): the
    /// direction and ratio it had been found to end with, which the next curve is
    /// looked for from.
    found: Option<(V, f64)>,
}

impl Lead {
    fn plain(dir: V, ratio: f64, chord: V) -> Self {
        Lead {
            dir,
            ratio,
            chord,
            found: None,
        }
    }
}

/// How a piece of a sender's moves goes on from the pieces merged before it (the Grbl
/// bridge, [`compress_runs_after`]).
#[derive(Clone, Copy, Debug, Default)]
pub struct Resume {
    /// The piece's first `done` blocks were merged before: they are there for the
    /// points a run's tangents look back on, and the merge goes on after them.
    pub done: usize,
    /// How the last block merged before ended (`None`: it was no curve).
    pub lead: Option<Lead>,
    /// More moves may follow the piece: a run that reaches its end is merged only as
    /// far as its curves cannot depend on what follows.
    pub open: bool,
}

/// [`compress_runs`] of `blocks[resume.done..]`, which go on from the piece that
/// `resume.lead` ended: a run that starts there and turns by less than a corner leaves
/// along the lead at its speed ratio, so that the pieces meet as one merge's curves do.
///
/// With `resume.open`, a run that reaches the last block is merged up to the first
/// curve whose fit could depend on moves not yet given: one whose reach of
/// [`Settings::max_chords`] moves, or the tangents at their ends (`tangents`, which
/// look [`Settings::tangent_reach`] tolerances ahead), run past the last block. Each
/// curve before it is the one the whole program gives, since a curve's fit depends only
/// on its start, its lead and those points.
///
/// Returns the blocks made, where they leave off (when the last is a run's) and the
/// number of `blocks` merged (`blocks.len()` unless an open run stopped early).
pub fn compress_runs_after(
    blocks: &[Block],
    start: [i64; AXES],
    s: &Settings,
    resume: Resume,
) -> (Compressed, Option<Lead>, usize) {
    let done = resume.done.min(blocks.len());
    let mut out = Compressed::default();
    let mut pose = start;
    let mut i = 0;
    let mut last = None;
    while i < blocks.len() {
        let b = &blocks[i];
        last = None;
        let Some((j, pts)) = run_from(blocks, i, &pose, s) else {
            if i >= done {
                out.blocks.push(*b);
                out.source.push(i..i + 1);
            }
            if !matches!(b.motion, Motion::Dwell(_) | Motion::Aux(_)) {
                pose = b.target;
            }
            i += 1;
            continue;
        };
        if j <= done {
            // A run merged before, which ended there.
            pose = blocks[j - 1].target;
            i = j;
            continue;
        }
        let begin = done.saturating_sub(i);
        let speed = if s.max_speed > 0.0 {
            (b.feed as f64).min(s.max_speed)
        } else {
            b.feed as f64
        };
        let goal = Goal {
            tol: merge_tolerance(b, s).unwrap_or(0.0) * s.fit_share,
            speed,
            lead_ratio: 1.0,
            edge: None,
        };
        // A run merged in part before goes on as its last curve ended; one that starts
        // where the last piece ended does where the polyline turns no corner.
        let carried = if begin > 0 {
            resume.lead
        } else if i == 0 && done == 0 {
            resume.lead.filter(|l| {
                let first_chord = unit(&sub(&pts[1], &pts[0]));
                dot(&l.chord, &first_chord) >= s.corner_deg.to_radians().cos()
            })
        } else {
            None
        };
        let open = resume.open && j == blocks.len();
        let (lead, stopped) = fit_run(
            &blocks[i..j],
            i,
            &pts,
            &goal,
            s,
            &mut out,
            (carried, begin, open),
        );
        last = lead;
        if let Some(a) = stopped {
            return (out, last, i + a);
        }
        pose = blocks[j - 1].target;
        i = j;
    }
    (out, last, blocks.len())
}

/// The first of `blocks` to keep as context for merging on after `blocks[..upto]`
/// ([`Resume::done`]): enough of the points before the last one merged that every
/// tangent after it looks back as it would in the whole run (the kept blocks start at
/// a point at least twice the tangents' reach from it; at 0 when none is).
pub fn context_from(blocks: &[Block], upto: usize, s: &Settings) -> usize {
    let Some(last) = upto.checked_sub(1).map(|k| &blocks[k]) else {
        return 0;
    };
    let reach = 2.0 * merge_tolerance(last, s).unwrap_or(0.0) * s.fit_share * s.tangent_reach;
    let end = to_fit(&last.target);
    (1..upto)
        .rev()
        .find(|&k| norm(&sub(&to_fit(&blocks[k - 1].target), &end)) >= reach)
        .unwrap_or(0)
}

/// The run of mergeable blocks starting at `blocks[i]` (from `pose`): its end `j`
/// and its points (the start, then each block's end), or `None` when `blocks[i]`
/// is not mergeable (it stands alone). Whether a block joins the run depends only on
/// it and the two points before it, so a run found in a prefix of the blocks is the
/// run of the whole unless it reaches the prefix's end.
fn run_from(
    blocks: &[Block],
    i: usize,
    pose: &[i64; AXES],
    s: &Settings,
) -> Option<(usize, Vec<V>)> {
    let b = &blocks[i];
    if !mergeable(b, pose, s) {
        return None;
    }
    let cos_corner = s.corner_deg.to_radians().cos();
    // The run: blocks i..j, points pts[0] (the start) ..= pts[j − i].
    let mut pts = vec![to_fit(pose), to_fit(&b.target)];
    let mut j = i + 1;
    while j < blocks.len() {
        let n = &blocks[j];
        let last = &blocks[j - 1];
        if n.feed != b.feed || n.tolerance_nm != b.tolerance_nm || !mergeable(n, &last.target, s) {
            break;
        }
        let k = pts.len();
        let d0 = unit(&sub(&pts[k - 1], &pts[k - 2]));
        let d1 = unit(&sub(&to_fit(&n.target), &pts[k - 1]));
        if dot(&d0, &d1) < cos_corner {
            break;
        }
        pts.push(to_fit(&n.target));
        j += 1;
    }
    Some((j, pts))
}

/// Where the last run of `blocks` (from `start`) starts, and the pose there: what
/// [`compress`] makes of the blocks before it is what it makes of them in any longer
/// program that begins with `blocks` (a program compressed a piece at a time carries
/// the last run over to the next piece).
pub fn last_run_start(blocks: &[Block], start: [i64; AXES], s: &Settings) -> (usize, [i64; AXES]) {
    let (mut pose, mut i) = (start, 0);
    let mut last = (0, start);
    while i < blocks.len() {
        last = (i, pose);
        let b = &blocks[i];
        match run_from(blocks, i, &pose, s) {
            Some((j, _)) => {
                pose = blocks[j - 1].target;
                i = j;
            }
            None => {
                if !matches!(b.motion, Motion::Dwell(_) | Motion::Aux(_)) {
                    pose = b.target;
                }
                i += 1;
            }
        }
    }
    last
}

/// Unit tangents at the points of a run: from the nearest points at least `reach`
/// away on either side (so that the rounding of short chords does not turn them),
/// weighted for unequal distances (the tangent of the parabola through the three
/// points); one-sided at the run's ends.
fn tangents(pts: &[V], reach: f64) -> Vec<V> {
    let m = pts.len() - 1;
    let away = |k: usize, step: isize| -> usize {
        let mut j = k as isize;
        loop {
            let n = j + step;
            if n < 0 || n > m as isize {
                return j as usize;
            }
            j = n;
            if norm(&sub(&pts[j as usize], &pts[k])) >= reach {
                return j as usize;
            }
        }
    };
    (0..=m)
        .map(|k| {
            let (i, j) = (away(k, -1), away(k, 1));
            if i == k {
                return unit(&sub(&pts[j], &pts[k]));
            }
            if j == k {
                return unit(&sub(&pts[k], &pts[i]));
            }
            let (a, b) = (sub(&pts[k], &pts[i]), sub(&pts[j], &pts[k]));
            let (la, lb) = (norm(&a).max(1e-9), norm(&b).max(1e-9));
            unit(&core::array::from_fn(|x| a[x] * lb / la + b[x] * la / lb))
        })
        .collect()
}

/// Fits the run `run` (input blocks from index `first`, points `pts`) piece by piece
/// (see the module doc), its first block leaving as `carried` ends; returns how its
/// last block ends, and where it stopped when `open` and the curves from there could
/// still change with the moves to come.
fn fit_run(
    run: &[Block],
    first: usize,
    pts: &[V],
    g: &Goal,
    s: &Settings,
    out: &mut Compressed,
    (carried, begin, open): (Option<Lead>, usize, bool),
) -> (Option<Lead>, Option<usize>) {
    let m = pts.len() - 1;
    let reach_ahead = g.tol * s.tangent_reach;
    let t = tangents(pts, reach_ahead);
    // Open: the first point whose tangent would look past the last point; a fit that
    // tries to reach it (or past it) is not final.
    let unsure = core::cell::Cell::new(false);
    let edge = open.then(|| {
        let k = (0..=m)
            .find(|&k| {
                !pts[k + 1..]
                    .iter()
                    .any(|p| norm(&sub(p, &pts[k])) >= reach_ahead)
            })
            .unwrap_or(m);
        (k, &unsure)
    });
    // Each curve is looked for leaving along the block before it as that was found
    // (before the two had their junction turned, [`meet`]), at its end's lead ratio.
    let (mut lead, lead_ratio) = carried.map_or((None, 1.0), |l| {
        let (dir, ratio) = l.found.unwrap_or((l.dir, l.ratio));
        (Some(dir), ratio)
    });
    let g = &mut Goal {
        edge,
        lead_ratio,
        ..*g
    };
    let mut held: Option<Held> = None;
    let mut a = begin;
    while a < m {
        // The chord into point a, for the turn the program makes there.
        let into = if a > 0 {
            Some(unit(&sub(&pts[a], &pts[a - 1])))
        } else {
            carried.map(|l| l.chord)
        };
        let found = reach::next_curve(pts, &t, a, (lead, into), g, s);
        if unsure.get() {
            // The fit from here could change with the moves to come, and with it the
            // end of the curve before.
            if let Some(h) = held {
                return (h.before, Some(h.a));
            }
            let ended = match into {
                Some(chord) if a > begin => lead.map(|dir| Lead::plain(dir, g.lead_ratio, chord)),
                _ => carried,
            };
            return (ended, Some(a));
        }
        let Some((b, c1, c2)) = found else {
            if let Some(h) = held.take() {
                hand_out(run, first, pts, &h, out);
            }
            out.blocks.push(run[a]);
            out.source.push(first + a..first + a + 1);
            lead = Some(unit(&sub(&pts[a + 1], &pts[a])));
            g.lead_ratio = 1.0;
            a += 1;
            continue;
        };
        let mut next = Held::found(pts, (a, b), (c1, c2), g.lead_ratio);
        next.before = match held.take() {
            Some(mut h) => {
                let turned = meet::turn(pts, &t[a], (&mut h, &mut next), g, s)
                    .then(|| (lead.unwrap_or(h.end), g.lead_ratio));
                hand_out(run, first, pts, &h, out);
                into.map(|chord| Lead {
                    found: turned,
                    ..Lead::plain(h.end, fit::end_ratio(&h.c), chord)
                })
            }
            None if a == begin => {
                // Going on from a curve handed out before, as it ended.
                if let Some(l) = carried.filter(|l| l.found.is_some()) {
                    next.refit(pts, (l.dir, l.ratio), g, s);
                }
                carried
            }
            None => into.and_then(|chord| lead.map(|dir| Lead::plain(dir, g.lead_ratio, chord))),
        };
        lead = Some(next.end);
        g.lead_ratio = fit::end_ratio(&next.c);
        held = Some(next);
        a = b;
    }
    if let Some(h) = held.take() {
        hand_out(run, first, pts, &h, out);
    }
    let ended = lead.map(|dir| Lead::plain(dir, g.lead_ratio, unit(&sub(&pts[m], &pts[m - 1]))));
    (ended, None)
}

/// Hands out the curve `h` of the run `run` (input blocks from index `first`, points
/// `pts`) as a block.
fn hand_out(run: &[Block], first: usize, pts: &[V], h: &Held, out: &mut Compressed) {
    let end = &run[h.b - 1];
    let start = &pts[h.a];
    let target = to_fit(&end.target);
    let (c1, c2) = (h.c[1], h.c[2]);
    out.blocks.push(Block {
        line: run[h.a].line,
        motion: Motion::Cubic {
            c1: core::array::from_fn(|i| from_fit(i, c1[i] - start[i])),
            c2: core::array::from_fn(|i| from_fit(i, c2[i] - target[i])),
        },
        ..*end
    });
    out.source.push(first + h.a..first + h.b);
}
