//! G5 cubic splines and G5.1 quadratic B-splines, as LinuxCNC defines them: Bézier
//! curves in the XY plane that move X and Y only.
//!
//! `G5 X Y I J P Q`: from the current point through the control points start + (I, J)
//! and end + (P, Q) to the end X Y. P and Q are required; I and J both, or neither
//! when the move right before was a G5: the first control point then mirrors that G5's
//! second one about their common point (I J = −P −Q of the previous G5), so the two
//! curves meet with one tangent. `G5.1 X Y I J`: from the current point through the
//! control point start + (I, J) to the end. X Y are read as for G1 (G90/G91, polar
//! words, an omitted one keeps its value); I J P Q are always offsets in the program's
//! length units, turned with the coordinate system (G10 L2 R). The feed is a G1's.
//!
//! Errors (LinuxCNC's, in its order, at the line's G5/G5.1 word or at the word at
//! fault): cutter radius compensation on; no feed (G94) or no F on the line (G93); a
//! plane other than XY (G17); a Z A B C word; no end point (X, Y or polar words); only
//! one of I J; I J omitted on the first G5 of a series, or on a G5.1; G5.1 with I and J
//! both zero; only one of P Q, or neither; and, beyond LinuxCNC, a curve larger than
//! the controller interpolates ([`pkmc::motion::geometry::MAX_SPLINE_SPAN`]).
//!
//! Invariants: the emitted offsets are zero but along X and Y; the target's other axes
//! are the current pose's; a refused spline still ends where it was programmed (as a
//! refused arc: one bad line is one message), and a G5 whose P and Q were read still
//! sets the tangent the next G5 continues. The end is computed first (after the check
//! for cutter compensation), so an error in X Y (out of range, a polar word with X)
//! comes before the others.
//!
//! Source: LinuxCNC G-code reference (G5, G5.1) and its interpreter's
//! `interp_convert.cc` (`convert_spline`, 2.9: "Must specify both I and J, or
//! neither", "Must specify both P and Q with G5", "Must specify both I and J with
//! G5.1", "Splines must be in the XY plane", "Splines may not have motion in Z, A, B, or
//! C", "Cannot convert spline with cutter radius compensation").

use super::convert::Block;
use super::{bounded_round, fail, Interp, Res};
use crate::gcode::canon::{Canon, Feed, Plane};
use crate::gcode::lexer::{Word, Words};
use crate::gcode::ErrorKind;
use pkmc::config::AXES;
use pkmc::motion::block::Motion;
use pkmc::motion::geometry::{Path, MAX_SPLINE_SPAN};

impl Interp<'_> {
    /// A G5 (`quadratic` false) or G5.1 move of line `b`; `tangent`: the first control
    /// point offset a G5 without I J takes (`None` unless the previous move was a G5);
    /// `col`: where an error about the whole move is shown.
    pub(super) fn spline(
        &mut self,
        w: &Words,
        quadratic: bool,
        tangent: Option<[i64; 2]>,
        b: &Block,
        col: u32,
        out: &mut Vec<Canon>,
    ) -> Res<()> {
        let name = if quadratic { "G5.1" } else { "G5" };
        let second = if quadratic {
            None
        } else {
            Some(self.spline_pq(w, col))
        };
        if let Some(Ok([p, q])) = second {
            self.g5_tangent = Some([-p, -q]);
        }
        self.comp_spline_allowed(name, col)?;
        let end = self.target(w, false)?;
        let done = self.spline_checked(w, quadratic, tangent, second, b, end, col, out);
        if done.is_err() {
            // As a refused arc: later lines start where this one was programmed to end.
            self.pos = end;
        }
        done
    }

    /// [`Self::spline`] once its end is known; `second`: G5's P Q as read.
    #[allow(clippy::too_many_arguments)]
    fn spline_checked(
        &mut self,
        w: &Words,
        quadratic: bool,
        tangent: Option<[i64; 2]>,
        second: Option<Res<[i64; 2]>>,
        b: &Block,
        end: [i64; AXES],
        col: u32,
        out: &mut Vec<Canon>,
    ) -> Res<()> {
        let name = if quadratic { "G5.1" } else { "G5" };
        let feed = self.feed_for(&end, true, b.inverse, name, col)?;
        if self.plane != Plane::Xy {
            return fail(
                col,
                ErrorKind::ModeConflict,
                format!("{name}: splines must be in the XY plane (G17)"),
            );
        }
        let other = [b'Z', b'A', b'B', b'C']
            .into_iter()
            .filter_map(|l| w.get(l).map(|word| (l, word)))
            .min_by_key(|(_, word)| word.col);
        if let Some((letter, word)) = other {
            return fail(
                word.col,
                ErrorKind::UnusedAxisWords,
                format!(
                    "{}{} with {name}: splines may not move Z, A, B or C (X and Y only)",
                    letter as char, word.num
                ),
            );
        }
        let polar = w.polar_radius.is_some() || w.polar_angle.is_some();
        if w.get(b'X').is_none() && w.get(b'Y').is_none() && !polar {
            return fail(
                col,
                ErrorKind::NoAxisWords,
                format!("{name} needs X or Y (its end point)"),
            );
        }
        let first = self.spline_ij(w, quadratic, tangent, col)?;
        let second = second.transpose()?;
        self.spline_to(b.line, end, first, second, feed, name, col, out)
    }

    /// G5's P and Q (both required), nm.
    fn spline_pq(&self, w: &Words, col: u32) -> Res<[i64; 2]> {
        match (w.get(b'P'), w.get(b'Q')) {
            (Some(p), Some(q)) => Ok([self.length(p)?, self.length(q)?]),
            (Some(x), None) | (None, Some(x)) => fail(
                x.col,
                ErrorKind::MissingValue,
                "G5 needs both P and Q (the offset from its end to its second control point)",
            ),
            (None, None) => fail(
                col,
                ErrorKind::MissingValue,
                "G5 needs P and Q (the offset from its end to its second control point)",
            ),
        }
    }

    /// The first control point's offset from the start: I J, or a G5's `tangent`.
    fn spline_ij(
        &self,
        w: &Words,
        quadratic: bool,
        tangent: Option<[i64; 2]>,
        col: u32,
    ) -> Res<[i64; 2]> {
        let both = |one: Word| {
            let what = if quadratic {
                "G5.1 needs both I and J (the offset from its start to its control point)"
            } else {
                "G5 needs both I and J, or neither (after another G5)"
            };
            fail(one.col, ErrorKind::MissingValue, what)
        };
        let offset = match (w.get(b'I'), w.get(b'J')) {
            (Some(i), Some(j)) => [self.length(i)?, self.length(j)?],
            (Some(x), None) | (None, Some(x)) => return both(x),
            (None, None) if quadratic => {
                return fail(
                    col,
                    ErrorKind::MissingValue,
                    "G5.1 needs I and J (the offset from its start to its control point)",
                )
            }
            (None, None) => match tangent {
                Some(t) => t,
                None => {
                    return fail(
                        col,
                        ErrorKind::MissingValue,
                        "G5 without I and J: only a G5 right after another G5 may omit them \
                         (the first of a series needs its first control point)",
                    )
                }
            },
        };
        if quadratic && offset == [0, 0] {
            let at = w.get(b'I').map_or(col, |i| i.col);
            return fail(
                at,
                ErrorKind::InvalidTarget,
                "G5.1 with I and J both zero: its control point must differ from its start",
            );
        }
        Ok(offset)
    }

    /// Emits the spline from the current pose to `end` with the program-frame offsets
    /// `first` (from the start) and, for G5, `second` (from the end).
    #[allow(clippy::too_many_arguments)]
    fn spline_to(
        &mut self,
        line: u32,
        end: [i64; AXES],
        first: [i64; 2],
        second: Option<[i64; 2]>,
        feed: Feed,
        name: &str,
        col: u32,
        out: &mut Vec<Canon>,
    ) -> Res<()> {
        let c1 = self.spline_offset(first, col)?;
        let motion = match second {
            Some(s) => Motion::Cubic {
                c1,
                c2: self.spline_offset(s, col)?,
            },
            None => Motion::Quadratic { c: c1 },
        };
        let block = pkmc::motion::block::Block {
            line,
            motion,
            target: end,
            feed: 1,
            tolerance_nm: 0,
        };
        // The controller's range; a G5 that does not move at all (its control points
        // and end at its start) is no curve, and is streamed as a line of length zero.
        let still = end == self.pos
            && matches!(motion, Motion::Cubic { c1, c2 } if c1 == [0; AXES] && c2 == [0; AXES]);
        if !still && Path::new(&block, &self.pos).is_err() {
            return fail(
                col,
                ErrorKind::InvalidTarget,
                format!(
                    "{name}: the curve is too large for the controller (its Bézier \
                     coefficients along an axis may add up to at most {} m)",
                    MAX_SPLINE_SPAN / 1_000_000_000
                ),
            );
        }
        out.push(match motion {
            Motion::Cubic { c1, c2 } => Canon::Cubic {
                line,
                target: end,
                c1,
                c2,
                feed,
            },
            _ => Canon::Quadratic {
                line,
                target: end,
                c: c1,
                feed,
            },
        });
        self.pos = end;
        Ok(())
    }

    /// A program-frame XY offset as an offset pose, turned with the coordinate system.
    fn spline_offset(&self, v: [i64; 2], col: u32) -> Res<[i64; AXES]> {
        let mut o = [0i64; AXES];
        if self.rotated() {
            let (x, y) = self.turn_vector(v[0] as f64, v[1] as f64);
            o[0] = bounded_round(x, col)?;
            o[1] = bounded_round(y, col)?;
        } else {
            o[0] = v[0];
            o[1] = v[1];
        }
        Ok(o)
    }
}

#[cfg(test)]
mod tests {
    use crate::gcode::blocks::{from_canon, BLEND_ANY};
    use crate::gcode::{compile, Options};
    use pkmc::config::AXES;
    use pkmc::motion::block::{Block, Motion};
    use pkmc::motion::geometry::{coefficients, Path};

    /// The blocks the controller receives for `program`, and the pose each starts at.
    fn blocks(program: &str) -> Vec<(Block, [i64; AXES])> {
        let canon = compile(program, "t.ngc", &Options::default()).expect("compiles");
        let mut from = [0i64; AXES];
        from_canon(&canon, from)
            .blocks
            .into_iter()
            .map(|b| {
                let start = from;
                from = b.target;
                (b, start)
            })
            .collect()
    }

    /// dP/du at u of a spline block from `start`, X Y (exact integers).
    fn tangent(b: &Block, start: &[i64; AXES], u: i64) -> [i64; 2] {
        let a = coefficients(&b.motion, start, &b.target).expect("a spline in range");
        [0, 1].map(|i| a[0][i] + 2 * a[1][i] * u + 3 * a[2][i] * u * u)
    }

    #[test]
    fn a_g5_without_i_j_leaves_along_the_tangent_the_previous_g5_arrived_on() {
        for program in [
            "G0 X0 Y0\nG5 X10 Y5 I3 J4 P-2 Q3 F600\nG5 X20 Y0 P1 Q1\nX25 Y-5 P0 Q2",
            // Turned frames and inches turn and scale both curves alike.
            "G20 G10 L2 P1 X1 Y2 R30\nG0 X0 Y0\nG5 X1 Y0.5 I0.3 J0.4 P-0.2 Q0.3 F10\nG5 X2 Y0 P0.1 Q0.1",
        ] {
            let b = blocks(program);
            let curves: Vec<_> = b
                .iter()
                .filter(|(b, _)| matches!(b.motion, Motion::Cubic { .. }))
                .collect();
            assert!(curves.len() >= 2, "{program}");
            for pair in curves.windows(2) {
                let (first, s0) = pair[0];
                let (next, s1) = pair[1];
                assert_eq!(first.target, *s1, "the curves meet");
                let arrive = tangent(first, s0, 1);
                let leave = tangent(next, s1, 0);
                let cross = arrive[0] as i128 * leave[1] as i128 - arrive[1] as i128 * leave[0] as i128;
                let dot = arrive[0] as i128 * leave[0] as i128 + arrive[1] as i128 * leave[1] as i128;
                // Parallel and the same way (LinuxCNC mirrors the control point: the
                // tangents are equal, within the turned frame's rounding).
                let scale = (arrive[0] as f64).hypot(arrive[1] as f64);
                assert!(
                    (cross as f64).abs() <= 4.0 * scale,
                    "{program}: {arrive:?} then {leave:?}"
                );
                assert!(dot > 0, "{program}: {arrive:?} then {leave:?}");
                for i in 0..2 {
                    assert!((arrive[i] - leave[i]).abs() <= 6, "{arrive:?} {leave:?}");
                }
            }
        }
    }

    /// The pose of `b` (from `start`) at the fraction `num/den` of its parameter, via
    /// the controller's own evaluation.
    fn pose_at(b: &Block, start: &[i64; AXES], num: i64, den: i64) -> [i64; AXES] {
        let path = Path::new(b, start).expect("a valid spline");
        let mut pose = [0; AXES];
        path.pose_at(start, (path.length << 16) / den * num, &mut pose);
        pose
    }

    #[test]
    fn a_g5_block_is_the_bezier_through_its_programmed_control_points() {
        // P0 = (1, 2), C1 = P0 + (1, 0) = (2, 2), C2 = P3 + (0, −2) = (4, 4), P3 = (4, 6).
        let b = blocks("G0 X1 Y2\nG5 X4 Y6 I1 J0 P0 Q-2 F600");
        let (g5, start) = &b[1];
        let mm = 1_000_000;
        assert_eq!(
            *g5,
            Block {
                line: 2,
                motion: Motion::Cubic {
                    c1: [mm, 0, 0, 0, 0, 0],
                    c2: [0, -2 * mm, 0, 0, 0, 0],
                },
                target: [4 * mm, 6 * mm, 0, 0, 0, 0],
                feed: 10_000_000,
                tolerance_nm: BLEND_ANY,
            }
        );
        assert_eq!(*start, [mm, 2 * mm, 0, 0, 0, 0]);
        // B(u) = (1−u)³P0 + 3u(1−u)²C1 + 3u²(1−u)C2 + u³P3, by hand:
        // B(¼) = (27·P0 + 27·C1 + 9·C2 + P3)/64 = (1.890625, 2.34375) mm,
        // B(½) = (P0 + 3·C1 + 3·C2 + P3)/8 = (2.875, 3.25) mm.
        for (num, want) in [(1, [1_890_625, 2_343_750]), (2, [2_875_000, 3_250_000])] {
            let got = pose_at(g5, start, num, 4);
            for i in 0..2 {
                assert!((got[i] - want[i]).abs() <= 2, "u = {num}/4: {got:?}");
            }
            assert_eq!(got[2..], [0; 4]);
        }
    }

    #[test]
    fn a_g5_1_block_is_the_parabola_through_its_control_point() {
        // LinuxCNC's example: from (−2, 4) through the control point (0, −4) to (2, 4):
        // B(u) = (1−u)²P0 + 2u(1−u)C + u²P2, B(½) = the origin, B(¼) = (−1, 1).
        let b = blocks("G0 X-2 Y4\nG5.1 X2 I2 J-8 F600");
        let (g51, start) = &b[1];
        let mm = 1_000_000;
        assert_eq!(
            g51.motion,
            Motion::Quadratic {
                c: [2 * mm, -8 * mm, 0, 0, 0, 0]
            }
        );
        for (num, want) in [(1, [-mm, mm]), (2, [0, 0]), (3, [mm, mm])] {
            let got = pose_at(g51, start, num, 4);
            for i in 0..2 {
                assert!((got[i] - want[i]).abs() <= 2, "u = {num}/4: {got:?}");
            }
        }
    }

    #[test]
    fn a_sender_sees_g5_and_g5_1_in_force_and_a_jog_ends_a_series() {
        let opts = Options::default();
        let mut s = crate::gcode::LineSession::new(&opts, "sender");
        let mut out = Vec::new();
        s.line("G5 X1 Y1 I0 J1 P0 Q-1 F600", 1, &mut out).unwrap();
        assert!(s.interp().modal_words().starts_with("G5 G54 "));
        s.line("X2 Y2 P0 Q-1", 2, &mut out).unwrap();
        s.set_position([3_000_000, 0, 0, 0, 0, 0]);
        let e = s.line("X4 Y1 P0 Q-1", 3, &mut out).unwrap_err();
        assert!(
            e.message.contains("only a G5 right after another G5"),
            "{e}"
        );
        s.line("G5.1 X5 Y1 I1 J1", 4, &mut out).unwrap();
        assert!(s.interp().modal_words().starts_with("G5.1 G54 "));
    }

    #[test]
    fn a_g5_that_does_not_move_is_streamed_as_a_line_and_the_pose_follows_splines() {
        let b = blocks("G0 X1 Y1\nG5 X1 Y1 I0 J0 P0 Q0 F600\nG5.1 X3 Y1 I1 J1\nM3 S100");
        assert_eq!(b[1].0.motion, Motion::Linear);
        assert_eq!(b[1].0.target, b[0].0.target);
        assert!(matches!(b[2].0.motion, Motion::Quadratic { .. }));
        assert_eq!(
            b[3].0.target, b[2].0.target,
            "aux blocks stay at the curve's end"
        );
    }
}
