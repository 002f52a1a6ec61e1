//! Canned drilling cycles, expanded on the host into rapids, feeds and dwells: G73
//! (chip-breaking peck), G81 (drill), G82 (drill, dwell), G83 (peck), G85 (bore, feed
//! out), G89 (bore, dwell, feed out).
//!
//! In the plane in force (G17: holes at X Y, the cycle axis is Z; G18: Z X and Y; G19:
//! Y Z and X), as LinuxCNC:
//! - R (retract plane) and the cycle-axis word (hole bottom) are required on the first
//!   line of a cycle and remembered while the same cycle stays in force, as are P
//!   (dwell, seconds) and Q (peck, > 0). In G90 they are positions; in G91 R is measured
//!   from the cycle axis' level before the first cycle line and the bottom from R.
//! - Before the first hole, if the tool is below R it rises to R. Each of the L repeats
//!   (G91: the hole position advances by X Y, or by `@`/`^` in polar terms, each time)
//!   rapids to the hole at the current level, down to R, then drills; it retracts to R
//!   (G99) or to the level before the cycle (G98) when that is higher.
//! - G85 feeds out to R; G89 dwells and feeds out all the way to the retract level (R
//!   or, in G98, the level before the cycle), as LinuxCNC 2.9's `convert_cycle_g89`
//!   does, with no rapid after it.
//! - G73/G83 feed down by Q at a time; G83 rapids out to R between pecks and back down to
//!   0.254 mm (0.010 in) above the last depth, G73 only backs off by that much.
//! - The cycle runs in exact-stop mode: if blending is in force, a `PathMode` exact
//!   stop precedes the moves and the blending mode is restored after them.
//! - A B C may not move; inverse-time feed (G93) is refused; a feed (F) is required.
//!
//! Invariants: one line expands into at most [`MAX_CYCLE_REPEATS`] holes and at most
//! [`MAX_PECKS`] pecks in all; every position stays within [`super::MAX_AXIS_UNITS`].
//!
//! Source: LinuxCNC G-code reference (canned cycles) and its interpreter's
//! `interp_cycles.cc` (`convert_cycle_xy`, `CYCLE_MACRO`, `convert_cycle_g83`).

use super::interp::{check_range, dwell_ms, fail, whole_in, Cycle, Interp, Motion, Res};
use super::lexer::Words;
use super::{arcs, MAX_CYCLE_REPEATS, MAX_PECKS};
use crate::gcode::canon::{Canon, Feed, PathMode, Plane};
use crate::gcode::ErrorKind;
use pkmc::config::{AXES, AXIS_NAMES};

/// How far above the last depth G83 rapids back down, and G73 backs off, nm
/// (LinuxCNC's 0.010 in, also used in mm programs as 0.254 mm).
pub const PECK_CLEARANCE_NM: i64 = 254_000;

/// The words of one cycle line, with those not given taken from the cycle's memory.
struct CycleWords {
    /// Feed of the drilling moves.
    feed: Feed,
    /// R as given, axis units.
    r: i64,
    /// Cycle-axis word (hole bottom) as given, axis units.
    z: i64,
    /// L.
    repeats: i64,
    /// P, ms.
    p_ms: u32,
    /// Q, axis units.
    q: i64,
}

/// Where the holes of one line are: the hole axes' values before the first hole, and
/// what each repeat adds (G91: a step along the axes, or in polar terms).
struct Holes {
    a: i64,
    b: i64,
    step_a: i64,
    step_b: i64,
    /// G91 `@` and `^`: radius (axis units) and angle (radians) added per hole.
    polar_step: Option<(f64, f64)>,
}

/// One hole's drilling, between the approach to R and the retract.
struct Drill {
    kind: Cycle,
    line: u32,
    feed: Feed,
    /// Hole axes and cycle axis.
    axes: (usize, usize, usize),
    /// Retract plane, hole bottom and the level the hole is left at (R in G99), cycle-
    /// axis positions.
    r: i64,
    bottom: i64,
    clear: i64,
    p_ms: u32,
    q: i64,
}

impl Interp<'_> {
    /// Runs canned cycle `kind` for one line; `previous` is the motion mode before it.
    pub(crate) fn cycle(
        &mut self,
        w: &Words,
        kind: Cycle,
        previous: Motion,
        line: u32,
        col: u32,
        out: &mut Vec<Canon>,
    ) -> Res<()> {
        if self.rotated() {
            return fail(
                col,
                ErrorKind::Unsupported,
                crate::gcode::unsupported(
                    "canned cycles in a rotated coordinate system (G10 L2 R)",
                ),
            );
        }
        let words = self.cycle_words(w, kind, previous == Motion::Cycle(kind), col)?;
        let (ia, ib, ic) = self.plane.axes();
        let current = self.pos[ic];
        let initial = *self.cycle.initial_level.get_or_insert(current);
        let (r, bottom) = self.cycle_levels(kind, &words, initial, col)?;
        let mut holes = self.holes(w, col)?;

        let restore = self.path != PathMode::ExactStop;
        if restore {
            out.push(Canon::PathMode {
                line,
                mode: PathMode::ExactStop,
            });
        }
        let mut level = current;
        let mut old = initial;
        if old < r {
            let t = self.at(ia, ib, ic, self.pos[ia], self.pos[ib], r);
            self.rapid(line, t, out);
            old = r;
            level = r;
        }
        let clear = if self.retract_to_r { r } else { old };
        let drill = Drill {
            kind,
            line,
            feed: words.feed,
            axes: (ia, ib, ic),
            r,
            bottom,
            clear,
            p_ms: words.p_ms,
            q: words.q,
        };
        for rep in 0..words.repeats {
            let (aa, bb) = self.next_hole(&mut holes, (ia, ib), col)?;
            if rep == 0 && level > r {
                self.rapid(line, self.at(ia, ib, ic, aa, bb, level), out);
                self.rapid(line, self.at(ia, ib, ic, aa, bb, r), out);
            } else {
                self.rapid(line, self.at(ia, ib, ic, aa, bb, clear), out);
                if clear > r {
                    self.rapid(line, self.at(ia, ib, ic, aa, bb, r), out);
                }
            }
            self.drill(&drill, aa, bb, out);
            if kind != Cycle::G89 {
                // G89 fed out to the clear level already.
                self.rapid(line, self.at(ia, ib, ic, aa, bb, clear), out);
            }
        }
        if restore {
            out.push(Canon::PathMode {
                line,
                mode: self.path,
            });
        }
        self.cycle.r = words.r;
        self.cycle.z = words.z;
        self.cycle.p_ms = words.p_ms;
        self.cycle.q = words.q;
        Ok(())
    }

    /// Checks that cycle `kind` can run and reads its words (`same`: the same cycle
    /// was in force before the line, so missing words are remembered ones).
    fn cycle_words(&self, w: &Words, kind: Cycle, same: bool, col: u32) -> Res<CycleWords> {
        let name = kind.name();
        if self.inverse_time {
            return fail(
                col,
                ErrorKind::ModeConflict,
                format!("{name} cannot run in inverse-time feed mode (G93)"),
            );
        }
        let Some(rate) = self.feed else {
            return fail(col, ErrorKind::NoFeed, format!("{name} without a feed (F)"));
        };
        for l in [b'A', b'B', b'C'] {
            if let Some(x) = w.get(l) {
                return fail(
                    x.col,
                    ErrorKind::UnusedAxisWords,
                    format!("{} cannot move in a canned cycle", l as char),
                );
            }
        }
        let cc_letter = AXIS_NAMES[self.plane.axes().2];
        let r = match w.get(b'R') {
            Some(r) => self.length(r)?,
            None if same => self.cycle.r,
            None => {
                return fail(
                    col,
                    ErrorKind::MissingValue,
                    format!("{name} needs R (retract plane)"),
                )
            }
        };
        let z = match w.get(cc_letter as u8) {
            Some(z) => self.length(z)?,
            None if same => self.cycle.z,
            None => {
                return fail(
                    col,
                    ErrorKind::MissingValue,
                    format!("{name} needs {cc_letter} (hole bottom)"),
                )
            }
        };
        let repeats = match w.get(b'L') {
            Some(l) => whole_in(l, 1, MAX_CYCLE_REPEATS, "repeats L")?,
            None => 1,
        };
        let p_ms = match (kind, w.get(b'P')) {
            (Cycle::G82 | Cycle::G89, Some(p)) => dwell_ms(p)?,
            (Cycle::G82 | Cycle::G89, None) if !same => {
                return fail(
                    col,
                    ErrorKind::MissingValue,
                    format!("{name} needs P (dwell time, seconds)"),
                )
            }
            _ => self.cycle.p_ms,
        };
        let q = match (kind, w.get(b'Q')) {
            (Cycle::G73 | Cycle::G83, Some(q)) => {
                let v = self.length(q)?;
                if v <= 0 {
                    return fail(
                        q.col,
                        ErrorKind::Negative,
                        format!("peck depth Q{} must be above zero", q.num),
                    );
                }
                v
            }
            // A remembered Q only counts if one was ever given (a line that failed
            // may have left the cycle in force without one): a zero peck would never
            // reach the bottom.
            (Cycle::G73 | Cycle::G83, None) if !same || self.cycle.q <= 0 => {
                return fail(
                    col,
                    ErrorKind::MissingValue,
                    format!("{name} needs Q (peck depth)"),
                )
            }
            _ => self.cycle.q,
        };
        Ok(CycleWords {
            feed: Feed::PerSecond(rate.linear),
            r,
            z,
            repeats,
            p_ms,
            q,
        })
    }

    /// The retract plane and the hole bottom on the cycle axis (`initial`: its level
    /// before the run of cycle lines), checked against each other and the peck limit.
    fn cycle_levels(
        &self,
        kind: Cycle,
        words: &CycleWords,
        initial: i64,
        col: u32,
    ) -> Res<(i64, i64)> {
        let name = kind.name();
        let ic = self.plane.axes().2;
        let (r, bottom) = if self.absolute {
            (words.r + self.off[ic], words.z + self.off[ic])
        } else {
            (words.r + initial, words.r + initial + words.z)
        };
        let r = check_range(r, ic, col)?;
        let bottom = check_range(bottom, ic, col)?;
        if r < bottom {
            return fail(
                col,
                ErrorKind::InvalidTarget,
                format!(
                    "{name}: the retract plane R is below the hole bottom {} \
                     ({} mm under it)",
                    AXIS_NAMES[ic],
                    arcs::mm((bottom - r) as f64)
                ),
            );
        }
        if matches!(kind, Cycle::G73 | Cycle::G83)
            && ((r - bottom) / words.q.max(1)).saturating_mul(words.repeats) > MAX_PECKS
        {
            return fail(
                col,
                ErrorKind::OutOfRange,
                format!("{name} would peck more than {MAX_PECKS} times on one line"),
            );
        }
        Ok((r, bottom))
    }

    /// Hole positions: absolute once, or increments per repeat.
    fn holes(&self, w: &Words, col: u32) -> Res<Holes> {
        let (ia, ib, _) = self.plane.axes();
        let polar = w.polar_radius.is_some() || w.polar_angle.is_some();
        let mut h = Holes {
            a: self.pos[ia],
            b: self.pos[ib],
            step_a: 0,
            step_b: 0,
            polar_step: None,
        };
        if self.absolute {
            if polar {
                let (x, y) = self.polar(w, self.pos[0] - self.off[0], self.pos[1] - self.off[1])?;
                h.a = check_range(x + self.off[0], 0, col)?;
                h.b = check_range(y + self.off[1], 1, col)?;
            } else {
                if let Some(x) = w.get(AXIS_NAMES[ia] as u8) {
                    h.a = check_range(self.length(x)? + self.off[ia], ia, x.col)?;
                }
                if let Some(y) = w.get(AXIS_NAMES[ib] as u8) {
                    h.b = check_range(self.length(y)? + self.off[ib], ib, y.col)?;
                }
            }
        } else if polar {
            if self.plane != Plane::Xy {
                return fail(
                    col,
                    ErrorKind::ModeConflict,
                    "polar coordinates (@ ^) need the XY plane (G17)",
                );
            }
            if let Some(xy) = w.get(b'X').or(w.get(b'Y')) {
                return fail(
                    xy.col,
                    ErrorKind::ModeConflict,
                    "polar coordinates (@ ^) and X or Y on one line",
                );
            }
            let dr = match w.polar_radius {
                Some(r) => self.length(r)? as f64,
                None => 0.0,
            };
            let dt = w.polar_angle.map_or(0.0, |a| a.num.to_f64().to_radians());
            h.polar_step = Some((dr, dt));
        } else {
            if let Some(x) = w.get(AXIS_NAMES[ia] as u8) {
                h.step_a = self.length(x)?;
            }
            if let Some(y) = w.get(AXIS_NAMES[ib] as u8) {
                h.step_b = self.length(y)?;
            }
        }
        Ok(h)
    }

    /// Advances `h` to the next hole and returns its position on the hole axes.
    fn next_hole(&self, h: &mut Holes, (ia, ib): (usize, usize), col: u32) -> Res<(i64, i64)> {
        h.a = check_range(h.a + h.step_a, ia, col)?;
        h.b = check_range(h.b + h.step_b, ib, col)?;
        if let Some((dr, dt)) = h.polar_step {
            let (x, y) = ((h.a - self.off[0]) as f64, (h.b - self.off[1]) as f64);
            if x == 0.0 && y == 0.0 {
                return fail(
                    col,
                    ErrorKind::InvalidTarget,
                    "incremental polar motion (G91 @ ^) is undefined at the origin",
                );
            }
            let radius = x.hypot(y) + dr;
            let theta = y.atan2(x) + dt;
            h.a = self.round_at(radius * theta.cos(), 0, col)? + self.off[0];
            h.b = self.round_at(radius * theta.sin(), 1, col)? + self.off[1];
            h.a = check_range(h.a, 0, col)?;
            h.b = check_range(h.b, 1, col)?;
        }
        Ok((h.a, h.b))
    }

    /// Drills one hole from R: down to the bottom (in pecks for G73/G83), with the
    /// dwell of G82/G89 and the feed out of G85 (to R) and G89 (to the clear level).
    fn drill(&mut self, d: &Drill, aa: i64, bb: i64, out: &mut Vec<Canon>) {
        let (ia, ib, ic) = d.axes;
        let line = d.line;
        let feed_to = |s: &mut Self, depth: i64, out: &mut Vec<Canon>| {
            let target = s.at(ia, ib, ic, aa, bb, depth);
            out.push(Canon::Linear {
                line,
                target,
                feed: d.feed,
            });
            s.pos = target;
        };
        match d.kind {
            Cycle::G81 => feed_to(self, d.bottom, out),
            Cycle::G82 => {
                feed_to(self, d.bottom, out);
                out.push(Canon::Dwell { line, ms: d.p_ms });
            }
            Cycle::G85 => {
                feed_to(self, d.bottom, out);
                feed_to(self, d.r, out);
            }
            Cycle::G89 => {
                feed_to(self, d.bottom, out);
                out.push(Canon::Dwell { line, ms: d.p_ms });
                feed_to(self, d.clear, out);
            }
            Cycle::G73 | Cycle::G83 => {
                let mut depth = d.r - d.q;
                while depth > d.bottom {
                    feed_to(self, depth, out);
                    if d.kind == Cycle::G83 {
                        self.rapid(line, self.at(ia, ib, ic, aa, bb, d.r), out);
                    }
                    let back = (depth + PECK_CLEARANCE_NM).min(d.r);
                    self.rapid(line, self.at(ia, ib, ic, aa, bb, back), out);
                    // Q > 0 is checked when the words are read; max(1) keeps the loop
                    // finite whatever reaches here.
                    depth -= d.q.max(1);
                }
                feed_to(self, d.bottom, out);
            }
        }
    }

    /// The current pose with the hole axes at `aa`, `bb` and the cycle axis at `cc`.
    fn at(&self, ia: usize, ib: usize, ic: usize, aa: i64, bb: i64, cc: i64) -> [i64; AXES] {
        let mut t = self.pos;
        t[ia] = aa;
        t[ib] = bb;
        t[ic] = cc;
        t
    }

    fn round_at(&self, v: f64, i: usize, col: u32) -> Res<i64> {
        match super::lexer::f64_to_i64(v) {
            Some(u) => check_range(u, i, col),
            None => fail(
                col,
                ErrorKind::InvalidTarget,
                format!("{} position out of range", AXIS_NAMES[i]),
            ),
        }
    }
}
