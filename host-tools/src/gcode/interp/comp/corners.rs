//! The geometry of compensated moves: entry moves, and the joins between consecutive
//! moves (convex: a corner arc about the programmed corner; concave: the held move cut
//! back to where the offset paths meet; tangent: nothing).
//!
//! Angles are in radians, positions in nm (output frame, XY). `SMALL` decides what is
//! a corner, as LinuxCNC's `TOLERANCE_CONCAVE_CORNER` does: joins turning by less are
//! tangent.

use super::queue::{Held, Shape};
use super::{ArcMove, Side, Straight};
use crate::gcode::arcs;
use crate::gcode::canon::{Canon, Feed};
use crate::gcode::interp::{fail, Interp, Res};
use crate::gcode::ErrorKind;
use pkmc::config::AXES;
use std::f64::consts::{FRAC_PI_2, PI, TAU};

/// Turn below which a join is tangent, radians (LinuxCNC's 0.05).
const SMALL: f64 = 0.05;

/// Unit vector at angle `a`.
fn unit(a: f64) -> [f64; 2] {
    [a.cos(), a.sin()]
}

/// `p + k·u`.
fn along(p: [f64; 2], k: f64, u: [f64; 2]) -> [f64; 2] {
    [p[0] + k * u[0], p[1] + k * u[1]]
}

/// Direction from `from` to `to`.
fn angle(from: [f64; 2], to: [f64; 2]) -> f64 {
    (to[1] - from[1]).atan2(to[0] - from[0])
}

fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

fn xy(p: &[i64; AXES]) -> [f64; 2] {
    [p[0] as f64, p[1] as f64]
}

/// Is the tool inside an arc turning `turn` (counter-clockwise when positive)?
fn inside(side: Side, turn: i64) -> bool {
    (side == Side::Left && turn > 0) || (side == Side::Right && turn < 0)
}

fn mm(nm: f64) -> String {
    arcs::mm(nm)
}

/// Signed angle an arc about `centre` turning `turn` sweeps from `start` to `end`
/// (LinuxCNC's `find_turn`): counter-clockwise positive, with |turn| − 1 extra turns.
pub(super) fn swept(start: [f64; 2], centre: [f64; 2], turn: i64, end: [f64; 2]) -> f64 {
    if turn == 0 {
        return 0.0;
    }
    let mut a = angle(centre, start);
    let mut b = angle(centre, end);
    if turn > 0 {
        if b <= a {
            b += TAU;
        }
        b - a + (turn - 1) as f64 * TAU
    } else {
        if a <= b {
            a += TAU;
        }
        b - a + (turn + 1) as f64 * TAU
    }
}

/// The gouge error of a concave corner no join can reach.
fn gouge<T>(col: u32, what: &str) -> Res<T> {
    fail(
        col,
        ErrorKind::InvalidTarget,
        format!(
            "cutter compensation: {what} makes a concave corner the tool cannot reach \
             without gouging the part"
        ),
    )
}

impl Interp<'_> {
    fn comp_side(&self) -> Side {
        self.comp.side.unwrap_or(Side::Left)
    }

    /// The pose of a corner arc before a move to `target`: X Y are replaced; Z stays
    /// (the move makes the Z motion), A B C move on the corner (LinuxCNC's split).
    fn corner_pose(&self, target: &[i64; AXES]) -> [i64; AXES] {
        let mut pose = *target;
        pose[2] = self.pos[2];
        pose
    }

    /// The entry move (first straight move after G41/G42): from the uncompensated
    /// position to the point one radius beside the programmed end.
    pub(super) fn straight_entry(
        &mut self,
        line: u32,
        kind: Straight,
        target: [i64; AXES],
        col: u32,
    ) -> Res<()> {
        let r = self.comp.radius;
        let (c, p) = (xy(&self.pos), xy(&target));
        let length = dist(c, p);
        if length <= r {
            return fail(
                col,
                ErrorKind::InvalidTarget,
                format!(
                    "the cutter compensation entry move ({} mm in XY) must be longer than \
                     the tool radius ({} mm)",
                    mm(length),
                    mm(r)
                ),
            );
        }
        let normal = match self.comp_side() {
            Side::Left => FRAC_PI_2,
            Side::Right => -FRAC_PI_2,
        };
        let n = unit(angle(c, p) + normal);
        let end = along(p, r, n);
        self.comp.queue.set_start(c);
        self.comp.queue.push(Held {
            line,
            shape: Shape::Straight { kind, dir: n },
            end,
            pose: target,
        });
        self.comp.first = false;
        self.comp.current = end;
        Ok(())
    }

    /// A straight move after the entry: joined to the held move, then held.
    pub(super) fn straight_next(
        &mut self,
        line: u32,
        kind: Straight,
        target: [i64; AXES],
        col: u32,
        out: &mut Vec<Canon>,
    ) -> Res<()> {
        let (side, r) = (self.comp_side(), self.comp.radius);
        let (c, op, p) = (self.comp.current, xy(&self.pos), xy(&target));
        if p == op {
            // No XY motion (a Z move, say): it stays where the tool is, and its end
            // moves with the held moves'.
            self.comp.queue.push(Held {
                line,
                shape: Shape::Straight {
                    kind,
                    dir: [0.0; 2],
                },
                end: c,
                pose: target,
            });
            return Ok(());
        }
        let mut theta = angle(op, c);
        let mut alpha = angle(op, p);
        let (beta, gamma) = match side {
            Side::Left => {
                if theta < alpha {
                    theta += TAU;
                }
                (theta - alpha - FRAC_PI_2, FRAC_PI_2)
            }
            Side::Right => {
                if alpha < theta {
                    alpha += TAU;
                }
                (alpha - theta - FRAC_PI_2, -FRAC_PI_2)
            }
        };
        let n = unit(alpha + gamma);
        let end = along(p, r, n);
        let held_arc_turn = match self.comp.queue.first_move().map(|m| m.shape) {
            Some(Shape::Arc { turn, .. }) => Some(turn),
            _ => None,
        };
        // Leaving an arc the tool is outside of straight back along it (the top of an
        // "h"): the tool keeps to the outside, as LinuxCNC does.
        let over_the_top =
            beta > PI - SMALL && held_arc_turn.is_some_and(|t| t != 0 && !inside(side, t));
        let concave = !(-SMALL..=PI + SMALL).contains(&beta) || over_the_top;
        let mut joined = Ok(());
        if concave {
            joined = self
                .concave_before_line(beta, theta + gamma, p, col)
                .and_then(|at| self.comp.end_held_at(at, out, col));
        } else if beta > SMALL {
            // Convex: the held move ends where it is; the tool rolls about the corner.
            self.comp.end_held_at(c, out, col)?;
            let shape = match kind {
                Straight::Feed(feed) => corner_arc(side, op, feed),
                // No rapid arc exists: a rapid to the start of the offset line.
                Straight::Rapid => Shape::Straight {
                    kind,
                    dir: [0.0; 2],
                },
            };
            let corner = Held {
                line,
                shape,
                end: along(op, r, n),
                pose: self.corner_pose(&target),
            };
            self.start_after(Some(corner), c, out, col)?;
        } else {
            self.start_after(None, c, out, col)?;
        }
        let next = Held {
            line,
            shape: Shape::Straight {
                kind,
                dir: [p[0] - op[0], p[1] - op[1]],
            },
            end,
            pose: target,
        };
        self.hold_next(joined, next)
    }

    /// After a convex join, `corner` (the move about the programmed corner) goes out
    /// with everything held, and the next move starts at its end; after a tangent one
    /// (`None`), what is held goes out and the next move starts at `c`.
    fn start_after(
        &mut self,
        corner: Option<Held>,
        c: [f64; 2],
        out: &mut Vec<Canon>,
        col: u32,
    ) -> Res<()> {
        let start = match corner {
            Some(m) => {
                let end = m.end;
                self.comp.queue.push(m);
                end
            }
            None => c,
        };
        self.comp.release(out, col)?;
        self.comp.queue.set_start(start);
        Ok(())
    }

    /// Holds `next` after its join (`joined`); a failed join forgets what it held, so
    /// the moves after it join `next`'s offset end (one mistake, one message).
    fn hold_next(&mut self, joined: Res<()>, next: Held) -> Res<()> {
        if joined.is_err() {
            self.comp.queue.discard();
        }
        self.comp.current = next.end;
        self.comp.queue.push(next);
        joined
    }

    /// Where the held move ends in a concave corner before a straight move to `p`
    /// (`beta`: the turn, `back`: the direction back along the held offset line).
    fn concave_before_line(&self, beta: f64, back: f64, p: [f64; 2], col: u32) -> Res<[f64; 2]> {
        let (side, r) = (self.comp_side(), self.comp.radius);
        let (c, op) = (self.comp.current, xy(&self.pos));
        let Some(held) = self.comp.queue.first_move().copied() else {
            return fail(
                col,
                ErrorKind::InvalidTarget,
                "cutter compensation: a concave corner right after a stop (M0/M1) cannot \
                 be compensated, since the move before the stop has ended",
            );
        };
        let Shape::Arc {
            centre: pc, turn, ..
        } = held.shape
        else {
            // Line to line: cut the held line back to where the offset lines cross.
            let half = (beta + PI) / 2.0;
            if half == 0.0 {
                return fail(
                    col,
                    ErrorKind::InvalidTarget,
                    "cutter compensation: a zero-degree inside corner cannot be compensated",
                );
            }
            return Ok(along(c, r / half.tan(), unit(back)));
        };
        // Arc to line: where the held (offset) arc meets the new offset line.
        let oldrad = dist(pc, held.end);
        let base = angle(op, p);
        let theta = if turn > 0 {
            base + FRAC_PI_2
        } else {
            base - FRAC_PI_2
        };
        let phi = angle(op, pc);
        let tool_inside = inside(side, turn);
        let programmed = if tool_inside { oldrad + r } else { oldrad - r };
        let d = programmed * (theta - phi).cos();
        let l = if tool_inside { d - r } else { d + r } / oldrad;
        if !(-1.0..=1.0).contains(&l) {
            return gouge(
                col,
                "leaving the arc of the line before on this straight move",
            );
        }
        let turn_back = if (turn > 0) == tool_inside {
            -l.acos()
        } else {
            l.acos()
        };
        Ok(along(pc, oldrad, unit(turn_back + theta + PI)))
    }

    /// The entry arc (first arc after G41/G42): from the uncompensated position to the
    /// point one radius beside the programmed end, on a circle about a new centre.
    pub(super) fn arc_entry(&mut self, line: u32, arc: ArcMove, col: u32) -> Res<()> {
        let (side, r) = (self.comp_side(), self.comp.radius);
        let (c, e) = (xy(&self.pos), xy(&arc.end));
        let length = dist(c, e);
        if length <= r {
            return fail(
                col,
                ErrorKind::InvalidTarget,
                format!(
                    "the cutter compensation entry arc must end farther than the tool radius \
                     ({} mm) from where it starts ({} mm)",
                    mm(r),
                    mm(length)
                ),
            );
        }
        let tool_inside = inside(side, arc.turn);
        let radius = dist(arc.centre, c);
        if tool_inside && radius <= r {
            return self.too_small(radius, col);
        }
        let gamma = if tool_inside {
            angle(e, arc.centre)
        } else {
            angle(arc.centre, e)
        };
        let end = along(e, r, unit(gamma));
        // The new centre: on the line from the new end towards the programmed centre,
        // equally far from the start and the new end.
        let half_chord = dist(c, end) / 2.0;
        let towards = angle(end, arc.centre);
        let apex = (angle(end, c) - towards).cos();
        if apex.abs() < 1e-6 {
            return self.too_small(radius, col);
        }
        let centre = along(end, half_chord / apex, unit(towards));
        let slack = if self.inch {
            arcs::CENTRE_ARC_ABS_NM_INCH
        } else {
            arcs::CENTRE_ARC_ABS_NM_MM
        };
        if (dist(centre, end) - dist(centre, c)).abs() > slack {
            return fail(
                col,
                ErrorKind::InvalidTarget,
                "cutter compensation: no entry arc fits this move (its start and end are not \
                 equally far from any centre on the programmed one's side)",
            );
        }
        self.comp.queue.push(Held {
            line,
            shape: Shape::Arc {
                centre,
                turn: arc.turn,
                swept: swept(c, centre, arc.turn, end),
                feed: arc.feed,
            },
            end,
            pose: arc.end,
        });
        self.comp.first = false;
        self.comp.current = end;
        Ok(())
    }

    fn too_small<T>(&self, radius: f64, col: u32) -> Res<T> {
        fail(
            col,
            ErrorKind::InvalidTarget,
            format!(
                "cutter compensation: the tool radius ({} mm) is not smaller than the radius \
                 of the arc it must stay inside ({} mm)",
                mm(self.comp.radius),
                mm(radius)
            ),
        )
    }

    /// An arc after the entry: joined to the held move, then held.
    pub(super) fn arc_next(
        &mut self,
        line: u32,
        arc: ArcMove,
        col: u32,
        out: &mut Vec<Canon>,
    ) -> Res<()> {
        let (side, r) = (self.comp_side(), self.comp.radius);
        let (c, op, e) = (self.comp.current, xy(&self.pos), xy(&arc.end));
        let radius = dist(arc.centre, e);
        let theta = angle(op, c)
            + match side {
                Side::Left => -FRAC_PI_2,
                Side::Right => FRAC_PI_2,
            };
        let mut delta = angle(op, arc.centre);
        let alpha = if arc.turn > 0 {
            delta - FRAC_PI_2
        } else {
            delta + FRAC_PI_2
        };
        let mut beta = match side {
            Side::Left => theta - alpha,
            Side::Right => alpha - theta,
        };
        if beta > 1.5 * PI {
            beta -= TAU;
        } else if beta < -FRAC_PI_2 {
            beta += TAU;
        }
        let tool_inside = inside(side, arc.turn);
        let mut joined = if tool_inside && radius <= r {
            self.too_small(radius, col)
        } else {
            Ok(())
        };
        let gamma = if tool_inside {
            angle(e, arc.centre)
        } else {
            delta += PI;
            angle(arc.centre, e)
        };
        let end = along(e, r, unit(gamma));
        let concave =
            !(-SMALL..=PI + SMALL).contains(&beta) || ((beta - PI).abs() < SMALL && !tool_inside);
        if joined.is_err() {
        } else if concave {
            joined = self
                .concave_before_arc(&arc, beta, theta, col)
                .and_then(|at| self.comp.end_held_at(at, out, col));
        } else if beta > SMALL {
            // Convex: a corner arc about the programmed corner first.
            self.comp.release(out, col)?;
            let corner = Held {
                line,
                shape: corner_arc(side, op, arc.feed),
                end: along(op, r, unit(delta)),
                pose: self.corner_pose(&arc.end),
            };
            self.start_after(Some(corner), c, out, col)?;
        } else {
            self.start_after(None, c, out, col)?;
        }
        let next = Held {
            line,
            shape: Shape::Arc {
                centre: arc.centre,
                turn: arc.turn,
                swept: swept(op, arc.centre, arc.turn, e),
                feed: arc.feed,
            },
            end,
            pose: arc.end,
        };
        self.hold_next(joined, next)
    }

    /// Where the held move ends in a concave corner before `arc` (`theta`: the
    /// direction from the programmed corner to the tool, turned back a quarter).
    fn concave_before_arc(&self, arc: &ArcMove, beta: f64, theta: f64, col: u32) -> Res<[f64; 2]> {
        let (side, r) = (self.comp_side(), self.comp.radius);
        let radius = dist(arc.centre, xy(&arc.end));
        let tool_inside = inside(side, arc.turn);
        let Some(held) = self.comp.queue.first_move().copied() else {
            return fail(
                col,
                ErrorKind::InvalidTarget,
                "cutter compensation: a concave corner right after a stop (M0/M1) cannot \
                 be compensated, since the move before the stop has ended",
            );
        };
        let Shape::Arc {
            centre: pc,
            turn: prev_turn,
            ..
        } = held.shape
        else {
            // Line to arc: where the held offset line meets the new offset circle.
            let across = radius * (beta - FRAC_PI_2).sin();
            let (reach, l) = if tool_inside {
                (radius - r, (across + r) / (radius - r))
            } else {
                (radius + r, (across - r) / (radius + r))
            };
            if !(-1.0..=1.0).contains(&l) {
                return gouge(col, "this arc, after the straight move before it,");
            }
            let a = match (tool_inside, arc.turn > 0) {
                (true, true) => theta + l.asin(),
                (true, false) => theta - l.asin(),
                (false, true) => theta + PI - l.asin(),
                (false, false) => theta + PI + l.asin(),
            };
            return Ok(along(arc.centre, reach, unit(a)));
        };
        // Arc to arc: where the two offset circles cross.
        let oldrad = dist(pc, held.end);
        let newrad = if tool_inside { radius - r } else { radius + r };
        let between = dist(pc, arc.centre);
        if oldrad == 0.0 || between == 0.0 {
            return fail(
                col,
                ErrorKind::InvalidTarget,
                "cutter compensation: two arcs with the same centre meet in a concave corner",
            );
        }
        let a = (oldrad * oldrad + between * between - newrad * newrad) / (2.0 * oldrad * between);
        if !(-1.0..=1.0).contains(&a) {
            return gouge(col, "this arc, after the arc before it,");
        }
        let pullback = a.acos();
        let towards = angle(pc, arc.centre);
        let dir = if inside(side, prev_turn) == (arc.turn > 0) {
            towards + pullback
        } else {
            towards - pullback
        };
        Ok(along(pc, oldrad, unit(dir)))
    }
}

/// The corner arc about the programmed corner `op` that keeps a tool on `side`
/// rolling round a convex corner (its sweep is set when it is released).
fn corner_arc(side: Side, op: [f64; 2], feed: Feed) -> Shape {
    Shape::Arc {
        centre: op,
        turn: if side == Side::Left { -1 } else { 1 },
        swept: 0.0,
        feed,
    }
}
