//! Corner blends within `G64 P`: where two feed moves (lines or merged curves) meet
//! at an angle, the end of the first and the start of the second are trimmed by a
//! length d and a cubic blend ([`Motion::Cubic`]) joins them, leaving along the first's
//! tangent and arriving along the second's, so the path is tangent-continuous there.
//!
//! **Why.** The controller passes a corner within one tick, so its speed there is
//! limited by the acceleration that turns the velocity in one tick (about a·T/|Δu|:
//! under 1 mm/s at 90° on a machine of 1000 mm/s²): every corner is nearly a stop. A
//! blend of smallest radius r is passed at about √(a·r).
//!
//! **Which corners.** Both blocks are `G1` lines or cubics merged within a tolerance
//! ([`super::merge_tolerance`]: `G64 P`, or in `G64` without P
//! [`Settings::g64_tolerance_nm`], 1 µm by default; never `G61`), neither moves A B C
//! (the blend is X Y Z only), and the path turns there by more than
//! [`Settings::blend_min_deg`], or, turning less, the tool's velocity over the path
//! speed (dP/ds) jumps there by more than the feed allows (a curve ending at another
//! |dP/ds| than the next starts, or a turn of a fraction of a degree at speed,
//! [`jumps`]: the planner would take more than [`Settings::jump_share`] of the
//! acceleration from both blocks to pass the junction at the feed). The tolerance is
//! the smaller of the two, and the
//! blend's samples, with the cut of the ticks' chords of it at its tightest bend on
//! top (`fit::tick_sag`), must lie within it. A dwell, an auxiliary function or any
//! other block between them leaves the corner as it is.
//!
//! **How far.** d is at most [`Settings::blend_share`] of either block's length (so the
//! trims at both ends of a block never meet); it starts at the length where a
//! symmetric blend of straight legs turning by θ strays d·sin θ/4 from them (for
//! turns of a few degrees too: a 4.5° corner in `G64` without P takes 48 µm a side), and
//! shrinks until every sample of the blend (rounded to whole units, as it is sent)
//! lies within [`Settings::fit_share`] of the smaller `P` of the two blocks from the
//! *programmed* polyline (the chords the two blocks stand for), less
//! [`ROUNDING_NM`].
//!
//! **Shape.** The inner control points lie along the tangents, at distances in the
//! ratio of the trimmed blocks' |dP/ds| where they meet the blend, scaled so that the
//! blend's |dP/ds| at its ends (its |dP/du| over the largest, as the controller runs
//! it) is theirs: the speed does not jump at the joins. The second block's |dP/ds| is
//! that of its part as streamed, whose end the next corner may trim as well (taking
//! its fastest point, and so raising its |dP/ds| at the start): a blend is shaped
//! again for it and handed out with the block, once that block's end is known.
//!
//! **After the trim.** That end trim can also open a jump where there was none: at a
//! junction that barely turns and was not blended, a block whose fastest point was at
//! its end starts at a higher |dP/ds| once its end is trimmed. So the block before
//! such a junction waits ([`Blender`]'s `waiting`) until the next corner is known, and
//! the junction is looked at again with the block's part as streamed
//! ([`after_trim`]); a blend found then is handed out between them, and the next
//! corner's blend is shaped again for where it now leaves the block.
//!
//! **Blocks.** The blend carries the NC line of the programmed move that ends at the
//! corner, the smaller feed of the two and the first's tolerance; it stands for the
//! programmed chords it spans ([`Compressed::source`]). A trimmed curve is the
//! original one cut by de Casteljau at the parameters of the trims; a trimmed line
//! gets a new end. A corner's blend depends only on the two blocks as the run
//! compressor made them, so a program blended a piece at a time ([`Blender`] keeps
//! the last block of a piece until the next comes) is the program blended at once.

use super::space::{on_segment, to_fit};
use super::{dot, norm, sub, unit, Compressed, Settings, V};
use pkmc::config::AXES;
use pkmc::motion::block::{Block, Motion};
use std::ops::Range;
use std::sync::Arc;

#[path = "blend_geo.rs"]
mod geo;
#[cfg(test)]
#[path = "blend_tests.rs"]
mod tests;

use geo::{block_of, round, Geo, STEPS};

/// Margin for the rounding of the blend's points to whole units, nm.
pub const ROUNDING_NM: f64 = 3.0;
/// Samples of a blend checked against the polyline. The polyline of a program written
/// with few decimals zigzags by its rounding, and a sample may pass between two of its
/// peaks: with 48, a blend over the three-decimal spiral of
/// `compression::a_three_decimal_polyline_in_g64_without_p_runs_at_the_feed` passed
/// between them and ran more than that test's 1 µm from the chords.
const SAMPLES: usize = 400;
/// Each try shrinks d by this.
const SHRINK: f64 = 0.85;
/// Tries before a corner stays a corner.
const TRIES: usize = 40;

/// A block that may take part in a blend, held until the next comes.
#[derive(Clone, Debug)]
struct Held {
    block: Block,
    geo: Geo,
    table: Vec<f64>,
    /// Where the block starts as streamed (after the trim of a blend before it), and
    /// its parameter there.
    start: [i64; AXES],
    u0: f64,
    /// The programmed blocks it stands for, and the programmed polyline (the start,
    /// then each one's end), in fit space.
    source: Range<usize>,
    points: Vec<V>,
    /// NC line of the last programmed move (the one ending at the block's end).
    last_line: u32,
    /// The blend of the corner before it, handed out with it: its speed at the join
    /// depends on where the block's own end is trimmed.
    before: Option<Corner>,
}

impl Held {
    fn length(&self) -> f64 {
        self.table[STEPS]
    }
}

/// Blends corners of a stream of compressed blocks, holding each blendable block
/// until the next comes (module doc).
#[derive(Clone, Debug)]
pub struct Blender {
    s: Settings,
    held: Option<Held>,
    /// The block before `held` when their corner is not blended: it waits until
    /// `held`'s end is known (module doc, "After the trim").
    waiting: Option<Held>,
    /// The end of the last block pushed (as the run compressor made it).
    pose: [i64; AXES],
    /// The end of the last block handed out.
    emitted: [i64; AXES],
}

/// Can `b`, from `from`, take part in a blend?
fn blendable(b: &Block, from: &[i64; AXES], s: &Settings) -> bool {
    let rotary_still = match b.motion {
        Motion::Linear => true,
        Motion::Cubic { c1, c2 } => c1[3..].iter().chain(&c2[3..]).all(|&x| x == 0),
        _ => return false,
    };
    super::merge_tolerance(b, s).is_some()
        && rotary_still
        && b.target[3..] == from[3..]
        && b.target[..3] != from[..3]
}

impl Blender {
    /// A blender with settings `s` whose first block starts at `start`.
    pub fn new(s: &Settings, start: [i64; AXES]) -> Self {
        Self {
            s: *s,
            held: None,
            waiting: None,
            pose: start,
            emitted: start,
        }
    }

    /// Where the next block handed out starts.
    pub fn emitted(&self) -> [i64; AXES] {
        self.emitted
    }

    /// Is a block held for the corner after it?
    pub fn holds(&self) -> bool {
        self.held.is_some() || self.waiting.is_some()
    }

    /// Takes the blocks of `c`, compressed from `programmed` (whose first block is
    /// programmed block `first` of the whole program), and hands out what is done.
    pub fn push(
        &mut self,
        programmed: &[Block],
        c: &Compressed,
        first: usize,
        out: &mut Compressed,
    ) {
        for (b, r) in c.blocks.iter().zip(&c.source) {
            let source = r.start + first..r.end + first;
            self.push_one(b, source, &programmed[r.clone()], out);
        }
    }

    /// Hands out the block held (at the end of the program).
    pub fn finish(&mut self, out: &mut Compressed) {
        if let Some(w) = self.waiting.take() {
            self.emit(&w, 1.0, out);
        }
        if let Some(h) = self.held.take() {
            self.emit(&h, 1.0, out);
        }
    }

    fn push_one(
        &mut self,
        b: &Block,
        source: Range<usize>,
        programmed: &[Block],
        out: &mut Compressed,
    ) {
        if matches!(b.motion, Motion::Dwell(_) | Motion::Aux(_)) {
            self.finish(out);
            self.put(*b, source, out);
            return;
        }
        let from = self.pose;
        self.pose = b.target;
        if !self.s.blend || !blendable(b, &from, &self.s) {
            self.finish(out);
            self.put(*b, source, out);
            return;
        }
        let geo = Geo::of(b, &from).expect("a line or a cubic");
        let mut points = vec![to_fit(&from)];
        points.extend(programmed.iter().map(|p| to_fit(&p.target)));
        let mut next = Held {
            block: *b,
            table: geo.table(),
            geo,
            start: from,
            u0: 0.0,
            source,
            points,
            last_line: programmed.last().map_or(b.line, |p| p.line),
            before: None,
        };
        if let Some(mut h) = self.held.take() {
            let mut j = corner(&h, &next, &self.s);
            if let Some(w) = self.waiting.take() {
                let w1 = j
                    .as_mut()
                    .map_or(1.0, |j| look_again(&w, &mut h, j, &self.s));
                self.emit(&w, w1, out);
            }
            match j {
                Some(j) => {
                    self.emit(&h, j.ua, out);
                    next.u0 = j.ub;
                    next.start = j.block.target;
                    next.before = Some(j);
                }
                None => self.waiting = Some(h),
            }
        }
        self.held = Some(next);
    }

    fn put(&mut self, b: Block, source: Range<usize>, out: &mut Compressed) {
        if !matches!(b.motion, Motion::Dwell(_) | Motion::Aux(_)) {
            self.emitted = b.target;
        }
        out.blocks.push(b);
        out.source.push(source);
    }

    /// Hands out `h` up to parameter `u1`, after the blend before it.
    fn emit(&mut self, h: &Held, u1: f64, out: &mut Compressed) {
        if let Some(j) = &h.before {
            // The blend arrives at the block's |dP/ds| as the controller runs the
            // block's part from u0 to u1: its end trim may have taken the block's
            // fastest point, which the blend was first shaped against.
            let rb = speed_ratio(&h.geo, h.u0, u1, h.u0);
            let block = j
                .with_ratios(j.shape.ra, rb, &self.s)
                .map_or(j.block, |(_, block)| block);
            self.put(block, j.source.clone(), out);
        }
        if h.u0 == 0.0 && u1 == 1.0 {
            return self.put(h.block, h.source.clone(), out);
        }
        let mut g = h.geo.part(h.u0, u1);
        // The ends as streamed: the start where the blend before ended, the end the
        // block's own unless a blend follows.
        if u1 == 1.0 {
            match &mut g {
                Geo::Line(p) => p[1] = to_fit(&h.block.target),
                Geo::Cubic(p) => p[3] = to_fit(&h.block.target),
            }
        }
        if let Geo::Cubic(p) = &mut g {
            p[0] = to_fit(&h.start);
        }
        let b = block_of(&g, &h.block, &h.start);
        self.put(b, h.source.clone(), out);
    }
}

/// The blend of the corner between `w` and `h` once `h`'s end is trimmed at `u1`, where
/// the corner barely turns and was not blended (module doc, "After the trim"): `ub` in
/// `h`'s own parameter.
fn after_trim(w: &Held, h: &Held, u1: f64, s: &Settings) -> Option<Corner> {
    if u1 >= 1.0 || turn(&w.geo, &h.geo) >= s.blend_min_deg.to_radians() {
        return None;
    }
    let geo = h.geo.part(0.0, u1);
    let part = Held {
        table: geo.table(),
        geo,
        ..h.clone()
    };
    let mut j = corner(w, &part, s)?;
    j.ub *= u1;
    Some(j)
}

/// The junction between `w` and `h` (left unblended) looked at again now that the
/// corner after `h` is `j` ([`after_trim`]): a blend found is handed out with `h`, and
/// `j` leaves `h`'s part as now streamed. Returns where `w` ends.
fn look_again(w: &Held, h: &mut Held, j: &mut Corner, s: &Settings) -> f64 {
    let Some(wj) = after_trim(w, h, j.ua, s) else {
        return 1.0;
    };
    let w1 = wj.ua;
    h.u0 = wj.ub;
    h.start = wj.block.target;
    h.before = Some(wj);
    j.reshape_start(h, s);
    w1
}

/// The angle between the direction `a` ends along and the one `b` starts along.
fn turn(a: &Geo, b: &Geo) -> f64 {
    dot(&unit(&a.deriv(1.0)), &unit(&b.deriv(0.0)))
        .clamp(-1.0, 1.0)
        .acos()
}

/// A corner's blend.
#[derive(Clone, Debug)]
struct Corner {
    ua: f64,
    ub: f64,
    block: Block,
    source: Range<usize>,
    /// What shaped it.
    shape: Shape,
}

/// A blend's shape: from `pa` leaving along `da` at |dP/ds| `ra`, to `pb` arriving
/// along `db` at `rb`, checked within `tol` against the chords of the programmed
/// polyline that may come that near it (`near`, [`near_chords`]).
#[derive(Clone, Debug)]
struct Shape {
    pa: V,
    pb: V,
    da: V,
    db: V,
    ra: f64,
    rb: f64,
    near: Arc<[[V; 2]]>,
    tol: f64,
    /// The block it is sent as (its line, feed and tolerance) and the A B C it keeps.
    line: Block,
    keep: [i64; AXES],
}

impl Corner {
    /// Shapes the blend again for the |dP/ds| where it leaves `h` (its start trimmed
    /// since), if that changed and the new shape fits.
    fn reshape_start(&mut self, h: &Held, s: &Settings) {
        let ra = speed_ratio(&h.geo, h.u0, self.ua, self.ua);
        if let Some((shape, block)) = self.with_ratios(ra, self.shape.rb, s) {
            self.shape = shape;
            self.block = block;
        }
    }

    /// The blend shaped again for |dP/ds| `ra` and `rb` at its ends, where either
    /// changed and the new shape fits.
    fn with_ratios(&self, ra: f64, rb: f64, s: &Settings) -> Option<(Shape, Block)> {
        if (ra - self.shape.ra).abs() <= 1e-6 && (rb - self.shape.rb).abs() <= 1e-6 {
            return None;
        }
        let shape = Shape {
            ra,
            rb,
            ..self.shape.clone()
        };
        let block = shape.block(s)?;
        Some((shape, block))
    }
}

impl Shape {
    /// The blend as it is sent, if every sample of it, with the cut of the ticks'
    /// chords at its tightest bend (`fit::tick_sag`) on top of the farthest, lies
    /// within the tolerance.
    fn block(&self, s: &Settings) -> Option<Block> {
        let chord = norm(&sub(&self.pb, &self.pa));
        let g = blend_curve(
            &self.pa, &self.pb, &self.da, &self.db, self.ra, self.rb, chord,
        );
        let block = block_of(&g, &self.line, &self.keep);
        let sent = Geo::of(&block, &round(&self.pa, &self.keep)).expect("a cubic");
        let (mut farthest, mut kappa) = (0.0f64, 0.0f64);
        for k in 0..=SAMPLES {
            let u = k as f64 / SAMPLES as f64;
            let q = sent.at(u);
            let d = self
                .near
                .iter()
                .map(|[a, b]| on_segment(&q, a, b).1)
                .fold(f64::INFINITY, f64::min);
            farthest = farthest.max(d);
            kappa = kappa.max(sent.bend(u));
        }
        let fits = farthest + super::fit::tick_sag(self.line.feed as f64, kappa, s) <= self.tol;
        (fits && chord >= 1.0).then_some(block)
    }
}

/// Distance from `q` to the polyline `pts`, and the index of its nearest chord's end.
fn to_polyline(q: &V, pts: &[V]) -> (f64, usize) {
    let mut best = (f64::INFINITY, 1);
    for e in 1..pts.len() {
        let d = on_segment(q, &pts[e - 1], &pts[e]).1;
        if d < best.0 {
            best = (d, e);
        }
    }
    best
}

/// The chords of `pts` within `reach` of the corner `c`. A blend whose points all lie
/// within `reach` − `tol` of `c` is within `tol` of the polyline exactly where it is
/// within `tol` of these: a chord farther from `c` is farther than `tol` from every
/// point of the blend. (The check of a blend then costs its samples times a few
/// chords, instead of times every chord the two blocks stand for.)
fn near_chords(pts: &[V], c: &V, reach: f64) -> Arc<[[V; 2]]> {
    pts.windows(2)
        .filter(|w| on_segment(c, &w[0], &w[1]).1 <= reach)
        .map(|w| [w[0], w[1]])
        .collect()
}

/// |dP/du| of `g` at `at` over its largest between `lo` and `hi`: its |dP/ds| there
/// as the controller runs the part between them.
fn speed_ratio(g: &Geo, lo: f64, hi: f64, at: f64) -> f64 {
    let here = norm(&g.deriv(at));
    let most = (0..=32)
        .map(|k| norm(&g.deriv(lo + (hi - lo) * k as f64 / 32.0)))
        .fold(here, f64::max);
    if most > 0.0 {
        here / most
    } else {
        1.0
    }
}

/// The blend from `pa` (leaving along `da`) to `pb` (arriving along `db`) whose
/// |dP/ds| at its ends is `ra` and `rb` (those of the blocks it joins, so the speed
/// does not jump there): inner control points at `ra`·k and `rb`·k along the
/// tangents, with the least k such that the largest |dP/du| is 3k. For two lines (`ra` = `rb` =
/// 1) the ends and the middle are equally fast.
fn blend_curve(pa: &V, pb: &V, da: &V, db: &V, ra: f64, rb: f64, chord: f64) -> Geo {
    let curve = |k: f64| {
        Geo::Cubic([
            *pa,
            core::array::from_fn(|i| pa[i] + ra * k * da[i]),
            core::array::from_fn(|i| pb[i] - rb * k * db[i]),
            *pb,
        ])
    };
    let excess = |k: f64| {
        let g = curve(k);
        (0..=32)
            .map(|j| norm(&g.deriv(j as f64 / 32.0)))
            .fold(0.0, f64::max)
            - 3.0 * k
    };
    // The least such k (for two lines every k past it keeps the ends fastest).
    let (mut lo, mut hi) = (0.0, chord);
    for _ in 0..40 {
        let mid = (lo + hi) / 2.0;
        if excess(mid) > 1e-9 * chord {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    curve(hi)
}

/// Does the tool's velocity over the path speed (dP/ds, as streamed from `a`'s start
/// trim) jump where `a` ends and `b` starts, in direction or size, by more than the
/// feed allows? The planner passes a junction whose jump is n on an axis at
/// v = ρ·a·T/n with ρ of the acceleration taken from the blocks on both sides (their
/// profiles keep 1 − ρ, see the planner's module doc): at the feed F, ρ = n·F/(a·T).
/// A junction is blended where that is over [`Settings::jump_share`]. Without the
/// machine's figures, a jump of 1 %.
fn jumps(a: &Held, b: &Held, s: &Settings) -> bool {
    let ra = speed_ratio(&a.geo, a.u0, 1.0, 1.0);
    let rb = speed_ratio(&b.geo, 0.0, 1.0, 0.0);
    let (ta, tb) = (unit(&a.geo.deriv(1.0)), unit(&b.geo.deriv(0.0)));
    let jump = (0..3)
        .map(|i| (ra * ta[i] - rb * tb[i]).abs())
        .fold(0.0, f64::max);
    let mut feed = a.block.feed.min(b.block.feed) as f64;
    if s.max_speed > 0.0 {
        feed = feed.min(s.max_speed);
    }
    let least = if s.accel > 0.0 && feed > 0.0 {
        s.jump_share * s.accel / pkmc::units::TICK_HZ as f64 / feed
    } else {
        0.01
    };
    jump > least
}

/// The blend of the corner between `a` and `b`, if one fits (module doc).
fn corner(a: &Held, b: &Held, s: &Settings) -> Option<Corner> {
    let (Some(ta), Some(tb)) = (
        super::merge_tolerance(&a.block, s),
        super::merge_tolerance(&b.block, s),
    ) else {
        return None;
    };
    let tol = ta.min(tb) * s.fit_share - ROUNDING_NM;
    let (ea, eb) = (a.geo.deriv(1.0), b.geo.deriv(0.0));
    if norm(&ea) < 1.0 || norm(&eb) < 1.0 {
        return None;
    }
    let turn = turn(&a.geo, &b.geo);
    // A junction that barely turns is blended too where the tool's speed over the path
    // speed jumps there enough to hold the junction below the feed.
    let small = turn < s.blend_min_deg.to_radians() && !jumps(a, b, s);
    if tol <= 0.0 || small || turn > 179f64.to_radians() {
        return None;
    }
    let most = s.blend_share * a.length().min(b.length());
    let mut d = most.min(4.0 * tol / turn.sin().max(1e-3));
    // The programmed polyline around the corner: the first's chords, then the
    // second's (whose start is the first's last point).
    let mut pts = a.points.clone();
    pts.extend_from_slice(&b.points[1..]);
    // Every point of a blend lies within 3d of the corner (plus the rounding of its
    // control points): its ends are within d along the blocks, its inner control
    // points within ra·k ≤ |pb − pa| ≤ 2d of them, and a cubic stays within its
    // control points' hull. d only shrinks from here.
    let c = to_fit(&a.block.target);
    let near = near_chords(&pts, &c, 3.0 * d + 4.0 + tol + 1.0);
    let keep = a.block.target;
    for _ in 0..TRIES {
        if d < 1.0 {
            return None;
        }
        let ua = a.geo.u_at(&a.table, a.length() - d);
        let ub = b.geo.u_at(&b.table, d);
        let pa = to_fit(&round(&a.geo.at(ua), &keep));
        let pb = to_fit(&round(&b.geo.at(ub), &keep));
        // |dP/ds| of the trimmed blocks where they meet the blend (the second's up to
        // its end: its own end trim is not known yet, see `Blender::emit`).
        let shape = Shape {
            pa,
            pb,
            da: unit(&a.geo.deriv(ua)),
            db: unit(&b.geo.deriv(ub)),
            ra: speed_ratio(&a.geo, a.u0, ua, ua),
            rb: speed_ratio(&b.geo, ub, 1.0, ub),
            near: near.clone(),
            tol,
            line: Block {
                line: a.last_line,
                feed: a.block.feed.min(b.block.feed),
                ..a.block
            },
            keep,
        };
        if let Some(block) = shape.block(s) {
            let first = to_polyline(&pa, &pts).1 - 1;
            let last = to_polyline(&pb, &pts).1 - 1;
            let n = a.points.len() - 1;
            let at = |k: usize| {
                if k < n {
                    a.source.start + k
                } else {
                    b.source.start + (k - n)
                }
            };
            return Some(Corner {
                ua,
                ub,
                block,
                source: at(first)..at(last.max(first)) + 1,
                shape,
            });
        }
        d *= SHRINK;
    }
    None
}
