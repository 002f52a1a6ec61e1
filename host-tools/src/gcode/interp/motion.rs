//! Moves: the end pose of a straight move from the axis and polar words, rapids, the
//! feed of a feed move, and G2/G3 arcs (centre or radius format, checked against
//! LinuxCNC's tolerances).
//!
//! Invariants: every pose computed here is within [`crate::gcode::MAX_AXIS_UNITS`] on
//! every axis (or the line fails at the word that would leave it); a move updates the
//! current pose only once its command is emitted, except a refused arc, which still
//! ends where it was programmed (one bad arc is one error, not a cascade).
//!
//! Source: LinuxCNC G-code reference (G0, G1, G2/G3, polar coordinates, G93/G94) and its
//! interpreter's `interp_convert.cc` (`convert_arc`, `convert_straight`).

use super::convert::Block;
use super::{
    bounded_round, check_range, fail, whole_in, FeedRate, Interp, LineError, Res, NM_PER_INCH,
};
use crate::gcode::arcs;
use crate::gcode::canon::{Canon, Feed, Plane};
use crate::gcode::lexer::{Word, Words};
use crate::gcode::ErrorKind;
use crate::gcode::MAX_AXIS_UNITS;
use pkmc::config::{AXES, AXIS_NAMES};
use pkmc::units::NM_PER_MM;

impl Interp<'_> {
    /// End pose of a straight move from the axis and polar words.
    pub(crate) fn target(&self, w: &Words, machine: bool) -> Res<[i64; AXES]> {
        let mut t = self.pos;
        self.target_into(w, machine, &mut t)?;
        Ok(t)
    }

    /// [`Self::target`] into `t`: the moves' hot path, whose pose returned inside a
    /// `Result` was copied with loads spanning the separate stores of its axes, which
    /// the processor does not forward (a stall per move).
    pub(crate) fn target_into(&self, w: &Words, machine: bool, t: &mut [i64; AXES]) -> Res<()> {
        if !machine && self.rotated() {
            *t = self.rotated_target(w)?;
            return Ok(());
        }
        *t = self.pos;
        for (i, slot) in t.iter_mut().enumerate() {
            let Some(word) = w.get(AXIS_NAMES[i] as u8) else {
                continue;
            };
            let v = self.axis_value(i, word)?;
            let p = if machine {
                v
            } else if self.absolute {
                v + self.off[i]
            } else {
                *slot + v
            };
            *slot = check_range(p, i, word.col)?;
        }
        if w.polar_radius.is_some() || w.polar_angle.is_some() {
            let (x, y) = self.polar(w, self.pos[0] - self.off[0], self.pos[1] - self.off[1])?;
            let col = w.polar_radius.or(w.polar_angle).map_or(1, |p| p.col);
            t[0] = check_range(x + self.off[0], 0, col)?;
            t[1] = check_range(y + self.off[1], 1, col)?;
        }
        Ok(())
    }

    /// [`Self::target`] in a rotated coordinate system: X and Y (and polar words) are
    /// read in the program frame and turned together; the other axes as usual; an
    /// axis the line does not name keeps its machine position exactly.
    fn rotated_target(&self, w: &Words) -> Res<[i64; AXES]> {
        let mut t = self.pos;
        let (mut x, mut y) = self.xy_to_program(self.pos[0], self.pos[1]);
        let mut xy_col = None;
        for (i, slot) in t.iter_mut().enumerate() {
            let Some(word) = w.get(AXIS_NAMES[i] as u8) else {
                continue;
            };
            let v = self.axis_value(i, word)?;
            match i {
                0 | 1 => {
                    let p = if i == 0 { &mut x } else { &mut y };
                    *p = if self.absolute { v } else { *p + v };
                    xy_col = Some(xy_col.map_or(word.col, |c: u32| c.min(word.col)));
                }
                _ => {
                    let p = if self.absolute {
                        v + self.off[i]
                    } else {
                        *slot + v
                    };
                    *slot = check_range(p, i, word.col)?;
                }
            }
        }
        if w.polar_radius.is_some() || w.polar_angle.is_some() {
            (x, y) = self.polar(w, x, y)?;
            xy_col = Some(w.polar_radius.or(w.polar_angle).map_or(1, |p| p.col));
        }
        if let Some(col) = xy_col {
            let (mx, my) = self.xy_to_machine(x, y, col)?;
            t[0] = check_range(mx, 0, col)?;
            t[1] = check_range(my, 1, col)?;
        }
        Ok(t)
    }

    /// Program X Y from the polar words `@` (radius) and `^` (angle, degrees) and the
    /// current program X Y, as LinuxCNC: absolute words measure from the origin; in G91
    /// `@` adds to the current distance from the origin and `^` to the current angle.
    pub(crate) fn polar(&self, w: &Words, x: i64, y: i64) -> Res<(i64, i64)> {
        let col = w.polar_radius.or(w.polar_angle).map_or(1, |p| p.col);
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
        let (xf, yf) = (x as f64, y as f64);
        let at_origin = x == 0 && y == 0;
        let radius = match w.polar_radius {
            Some(r) => Some((self.length(r)? as f64, r.col)),
            None => None,
        };
        let angle = w.polar_angle.map(|a| (a.num.to_f64().to_radians(), a.col));
        let (r, theta) = if self.absolute {
            let r = radius.map_or(xf.hypot(yf), |r| r.0);
            let theta = match angle {
                Some(a) => a.0,
                None if at_origin => {
                    return fail(
                        col,
                        ErrorKind::InvalidTarget,
                        "@ without ^ at the origin: the angle is undefined",
                    )
                }
                None => yf.atan2(xf),
            };
            (r, theta)
        } else {
            if at_origin {
                return fail(
                    col,
                    ErrorKind::InvalidTarget,
                    "incremental polar motion (G91 @ ^) is undefined at the origin",
                );
            }
            (
                xf.hypot(yf) + radius.map_or(0.0, |r| r.0),
                yf.atan2(xf) + angle.map_or(0.0, |a| a.0),
            )
        };
        let px = bounded_round(r * theta.cos(), col)?;
        let py = bounded_round(r * theta.sin(), col)?;
        Ok((px, py))
    }

    pub(crate) fn rapid(&mut self, line: u32, target: [i64; AXES], out: &mut Vec<Canon>) {
        out.push(Canon::Rapid { line, target });
        self.pos = target;
    }

    /// Feed of a feed move from the current pose to `end` (`arc`: along an arc).
    pub(crate) fn feed_for(
        &self,
        end: &[i64; AXES],
        arc: bool,
        line_inverse: Option<u64>,
        code: &str,
        col: u32,
    ) -> Res<Feed> {
        if self.inverse_time {
            return match line_inverse {
                Some(us) => Ok(Feed::InverseTime(us)),
                None => fail(
                    col,
                    ErrorKind::NoFeed,
                    format!("{code} in inverse-time mode (G93) needs F on its line"),
                ),
            };
        }
        let Some(f) = self.feed else {
            if self.feed_zero {
                return fail(
                    col,
                    ErrorKind::NoFeed,
                    format!("{code} at feed F0: a feed move needs F above zero"),
                );
            }
            return fail(col, ErrorKind::NoFeed, format!("{code} without a feed (F)"));
        };
        // An arc moves X Y Z even when it ends where it starts (a full circle).
        let linear = arc || (0..3).any(|i| end[i] != self.pos[i]);
        let rotary = (3..AXES).any(|i| end[i] != self.pos[i]);
        Ok(Feed::PerSecond(if rotary && !linear {
            f.rotary
        } else {
            f.linear
        }))
    }

    /// F in units per minute → nm/s and µ°/s.
    pub(super) fn feed_rate(&self, f: Word) -> Res<FeedRate> {
        if f.num.is_negative() || f.num.is_zero() {
            return fail(
                f.col,
                if f.num.is_negative() {
                    ErrorKind::Negative
                } else {
                    ErrorKind::NoFeed
                },
                format!("feed F{} must be above zero", f.num),
            );
        }
        let per = if self.inch { NM_PER_INCH } else { NM_PER_MM };
        let range = |v: Option<i64>| match v {
            Some(v) if (1..=MAX_AXIS_UNITS).contains(&v) => Ok(v),
            Some(v) if v < 1 => fail(
                f.col,
                ErrorKind::OutOfRange,
                format!("feed F{} too small", f.num),
            ),
            _ => fail(
                f.col,
                ErrorKind::OutOfRange,
                format!("feed F{} out of range", f.num),
            ),
        };
        Ok(FeedRate {
            linear: range(f.num.scaled(per, 60))?,
            rotary: range(f.num.scaled(1_000_000, 60))?,
        })
    }

    /// A G2/G3 move of line `b` (`col`: where an error about the whole arc is shown).
    pub(super) fn arc(
        &mut self,
        w: &Words,
        clockwise: bool,
        b: &Block,
        col: u32,
        out: &mut Vec<Canon>,
    ) -> Res<()> {
        self.comp_arc_allowed(col)?;
        let mut end = [0; AXES];
        self.target_into(w, false, &mut end)?;
        let done = self.arc_to(&end, w, clockwise, b, col, out);
        if done.is_err() {
            // A refused arc still ends where it was programmed to: later lines (their
            // G91 moves, their arc centres) start there, so one bad arc is one message,
            // not a cascade of knock-on errors.
            self.pos = end;
        }
        done
    }

    /// The arc of [`Self::arc`] to `end` (by reference: a copy of it right after
    /// `target_into` wrote it would wait for those stores).
    fn arc_to(
        &mut self,
        end: &[i64; AXES],
        w: &Words,
        clockwise: bool,
        block: &Block,
        col: u32,
        out: &mut Vec<Canon>,
    ) -> Res<()> {
        let (line, line_inverse) = (block.line, block.inverse);
        let name = if clockwise { "G2" } else { "G3" };
        let (a, b, h) = self.plane.axes();
        let offset_letter = |axis: usize| b"IJK"[axis];
        let plane_name = match self.plane {
            Plane::Xy => "XY plane (G17)",
            Plane::Zx => "XZ plane (G18)",
            Plane::Yz => "YZ plane (G19)",
        };
        if self.rotated() && self.plane != Plane::Xy {
            return fail(
                col,
                ErrorKind::Unsupported,
                crate::gcode::unsupported(&format!(
                    "arcs in the {plane_name} of a rotated coordinate system (G10 L2 R)"
                )),
            );
        }
        if let Some(k) = w.get(offset_letter(h)) {
            return fail(
                k.col,
                ErrorKind::UnusedWords,
                format!(
                    "{} word given for an arc in the {plane_name}",
                    offset_letter(h) as char
                ),
            );
        }
        let (wa, wb) = (w.get(offset_letter(a)), w.get(offset_letter(b)));
        let start = self.pos;
        let s = [start[a] as f64, start[b] as f64];
        let e = [end[a] as f64, end[b] as f64];
        let tol = self.opts.arc_tolerance_nm.max(0) as f64;
        let centre = match (w.get(b'R'), wa.is_some() || wb.is_some()) {
            (Some(r), true) => {
                return fail(
                    r.col,
                    ErrorKind::UnusedWords,
                    format!("{name} with both a radius (R) and a centre (I J K)"),
                )
            }
            (None, false) => {
                return fail(
                    col,
                    ErrorKind::ArcNoOffset,
                    format!("{name} without a centre (I J K) or a radius (R)"),
                )
            }
            (Some(r), false) => {
                let radius = self.length(r)?;
                if radius == 0 {
                    return fail(
                        r.col,
                        ErrorKind::ArcRadius,
                        format!("{name} with radius R0"),
                    );
                }
                // A `match`, not `map_err`: that is not inlined, and its result
                // went through memory.
                let c = match arcs::centre_from_radius(s, e, radius as f64, clockwise, tol) {
                    Ok(c) => c,
                    Err((kind, message)) => {
                        // Ending where it starts without an axis word in its plane:
                        // the line has no in-plane end point at all.
                        let in_plane = [a, b].iter().any(|&i| w.get(AXIS_NAMES[i] as u8).is_some());
                        let kind = match kind {
                            ErrorKind::InvalidTarget if !in_plane => ErrorKind::ArcNoPlaneAxis,
                            kind => kind,
                        };
                        return Err(LineError::boxed(col, kind, message));
                    }
                };
                [bounded_round(c[0], col)?, bounded_round(c[1], col)?]
            }
            (None, true) => self.centre_from_offsets([(a, wa), (b, wb)], s, e, col)?,
        };
        // Any radius: an arc the controller does not run exactly
        // (`pkmc::motion::geometry::Path::checked`) is sent as chords (`blocks::from_canon`).
        let turns = match w.get(b'P') {
            Some(p) => (whole_in(p, 1, i64::from(u32::MAX), "turns P")? - 1) as u32,
            None => 0,
        };
        let feed = self.feed_for(end, true, line_inverse, name, col)?;
        self.arc_move(line, *end, centre, clockwise, turns, feed, col, out)
    }

    /// The centre of a centre-format arc from `s` to `e` in the plane's axes `axes`
    /// (each with its I J K word, if given), checked against the arc's end.
    fn centre_from_offsets(
        &self,
        axes: [(usize, Option<Word>); 2],
        s: [f64; 2],
        e: [f64; 2],
        col: u32,
    ) -> Res<[i64; 2]> {
        let mut c = [0i64; 2];
        let mut offsets = [0i64; 2];
        for (k, (axis, word)) in axes.into_iter().enumerate() {
            let v = match word {
                Some(word) => self.length(word)?,
                None if self.arc_absolute => {
                    return fail(
                        col,
                        ErrorKind::MissingValue,
                        format!(
                            "{} word missing for an absolute centre (G90.1)",
                            b"IJK"[axis] as char
                        ),
                    )
                }
                None => 0,
            };
            let base = if self.arc_absolute {
                self.off[axis]
            } else {
                self.pos[axis]
            };
            c[k] = check_range(base + v, axis, word.map_or(col, |x| x.col))?;
            offsets[k] = v;
        }
        if self.rotated() {
            // I J are in the program frame (the plane is XY: see `arc_to`).
            c = if self.arc_absolute {
                let (x, y) = self.xy_to_machine(offsets[0], offsets[1], col)?;
                [check_range(x, 0, col)?, check_range(y, 1, col)?]
            } else {
                let (dx, dy) = self.turn_vector(offsets[0] as f64, offsets[1] as f64);
                [
                    check_range(bounded_round(s[0] + dx, col)?, 0, col)?,
                    check_range(bounded_round(s[1] + dy, col)?, 1, col)?,
                ]
            };
        }
        let abs = if self.inch {
            arcs::CENTRE_ARC_ABS_NM_INCH
        } else {
            arcs::CENTRE_ARC_ABS_NM_MM
        };
        arcs::check_end(s, e, [c[0] as f64, c[1] as f64], abs)
            .map_err(|(kind, message)| LineError::boxed(col, kind, message))?;
        Ok(c)
    }
}
