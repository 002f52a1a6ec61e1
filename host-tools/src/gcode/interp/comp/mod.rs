//! Cutter radius compensation: G41 / G42 (tool radius from the tool table), G41.1 /
//! G42.1 (diameter on the line) and G40, in the XY plane, as LinuxCNC does it.
//!
//! The programmed path is the part's outline; the tool centre runs one tool radius to
//! its left (G41) or right (G42). Where two programmed moves meet, the compensated
//! moves meet too: around an outside (convex) corner the tool rolls on an arc about
//! the programmed corner; into an inside (concave) corner the move before is cut back
//! to where the two offset paths cross. That needs the next move before the previous
//! one can be emitted, so compensated moves are held in a short queue ([`Queue`]) and
//! everything the program emits meanwhile (spindle, coolant, dwell, messages) waits
//! behind them in order. The first move after G41/G42 is the entry: it goes from the
//! uncompensated position to the offset end of its programmed move. After G40 the
//! last held move ends at its offset point, and the next move (which must be
//! straight) leaves from there to its programmed end.
//!
//! Frame: everything is computed in the output frame (after work offsets, G92 and a
//! G10 L2 R rotation): offsets are translations and the rotation is proper, so an
//! offset to the left of a path stays to its left, at the same distance. While
//! compensation is on the interpreter's `pos` is the *programmed* point (so that
//! incremental moves, arc centres and omitted axis words refer to the outline, as in
//! LinuxCNC); the tool centre is [`Comp::current`].
//!
//! Invariants: `side` is `None` or the radius is at least zero; when `first` is false
//! `current` is the tool centre; the queue holds no command unless it starts with a
//! move; `mark` is where this line's not-yet-held output starts in `out`.
//!
//! Source: LinuxCNC's G41/G42 reference, and its interpreter's `convert_straight_comp1`
//! / `_comp2`, `convert_arc_comp1` / `_comp2`, `convert_cutter_compensation_*`
//! (`interp_convert.cc`) and the queue (`interp_queue.cc`), whose geometry and error
//! cases are followed here so that programs behave as they do there.

mod corners;
mod queue;

use super::convert::Block;
use super::modal::{code_name, Group};
use super::{fail, whole_in, Interp, Res};
use crate::gcode::canon::{Canon, Feed, Plane};
use crate::gcode::lexer::{bit, Words};
use crate::gcode::unsupported;
use crate::gcode::ErrorKind;
use pkmc::config::AXES;
pub(crate) use queue::Queue;

/// Which side of the programmed path the tool runs on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Side {
    /// G41: left of the path, looking along the motion.
    Left,
    /// G42: right.
    Right,
}

/// Straight move kinds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Straight {
    /// G0.
    Rapid,
    /// G1, with its feed.
    Feed(Feed),
}

/// An arc as programmed (before compensation), output frame, XY plane.
#[derive(Clone, Copy, Debug)]
pub(crate) struct ArcMove {
    /// Programmed end pose.
    pub end: [i64; AXES],
    /// Centre, nm.
    pub centre: [f64; 2],
    /// Signed turns: +n counter-clockwise (G3 with P n), −n clockwise.
    pub turn: i64,
    /// Feed.
    pub feed: Feed,
}

/// Compensation state of a run.
#[derive(Debug)]
pub(crate) struct Comp {
    /// Side in force (`None`: G40).
    side: Option<Side>,
    /// Tool radius in force, nm (not negative).
    radius: f64,
    /// No move made since compensation was turned on (the next one is the entry).
    first: bool,
    /// Tool centre XY, nm, once the entry move is made.
    current: [f64; 2],
    /// Held output.
    queue: Queue,
    /// The move after G40 must be straight (LinuxCNC's rule: an arc cannot start from
    /// the offset point it was programmed not to start from).
    arc_not_allowed: bool,
    /// Index in the output where this line's commands start that are not yet held.
    mark: usize,
    /// Lengths are in inches (tolerances follow the program's units, as in LinuxCNC).
    inch: bool,
}

impl Comp {
    /// Compensation off.
    pub(crate) fn new() -> Self {
        Comp {
            side: None,
            radius: 0.0,
            first: true,
            current: [0.0; 2],
            queue: Queue::default(),
            arc_not_allowed: false,
            mark: 0,
            inch: false,
        }
    }

    /// Is G41/G42 in force (with any radius)?
    pub(crate) fn on(&self) -> bool {
        self.side.is_some()
    }

    /// Is the path being offset (G41/G42 with a radius above zero)?
    fn offsetting(&self) -> bool {
        self.side.is_some() && self.radius > 0.0
    }

    /// Start of a line: its commands begin at `out.len()`.
    pub(crate) fn start_line(&mut self, out: &[Canon]) {
        self.mark = out.len();
    }

    /// Moves the commands this line emitted so far behind the held moves (they come
    /// after them in the program).
    pub(crate) fn hold(&mut self, out: &mut Vec<Canon>) {
        let from = self.mark.min(out.len());
        if !self.queue.is_empty() {
            self.queue.hold(out.drain(from..));
        }
        self.mark = out.len();
    }

    /// Emits everything held, as it is.
    fn release(&mut self, out: &mut Vec<Canon>, col: u32) -> Res<()> {
        self.queue.release(out, col)?;
        self.mark = out.len();
        Ok(())
    }

    /// Ends the held moves at `at` (the tool centre where the next move starts) and
    /// emits them.
    fn end_held_at(&mut self, at: [f64; 2], out: &mut Vec<Canon>, col: u32) -> Res<()> {
        self.queue.move_end(at, self.inch, col)?;
        self.release(out, col)?;
        self.queue.set_start(at);
        Ok(())
    }
}

/// Why a code cannot run while compensation is on (LinuxCNC refuses the same).
fn forbidden(group: Group, tenths: i32) -> Option<&'static str> {
    Some(match (group, tenths) {
        (Group::ToolChange, 60) => "a tool change (M6)",
        (Group::Plane, _) => "a plane change",
        (Group::ToolLength, _) => "a tool length offset change",
        (Group::System, _) => "a coordinate system change",
        (Group::Path, _) => "a path control mode change",
        (Group::Retract, _) => "a canned-cycle return mode change",
        (Group::NonModal, 280 | 281 | 300 | 301) => "a return to a reference point",
        (Group::NonModal, 520 | 920 | 921 | 922 | 923) => "an axis offset change (G52, G92)",
        (Group::NonModal, 530) => "a move in machine coordinates (G53)",
        (Group::Motion, 730 | 810 | 820 | 830 | 850 | 890) => "a canned cycle",
        _ => return None,
    })
}

impl Interp<'_> {
    /// Refuses, while compensation is on, the codes of the line that LinuxCNC refuses
    /// then. `before`: the codes executed before the compensation phase (tool change,
    /// plane), checked against the state before the line; the others after it.
    pub(super) fn comp_guard(&self, w: &Words, b: &Block, before: bool) -> Res<()> {
        if !self.comp.on() {
            return Ok(());
        }
        let groups: &[Group] = if before {
            &[Group::ToolChange, Group::Plane]
        } else {
            &[
                Group::ToolLength,
                Group::System,
                Group::Path,
                Group::Retract,
                Group::NonModal,
                Group::Motion,
            ]
        };
        for &g in groups {
            let Some(c) = b.codes.get(g) else { continue };
            let same_plane = g == Group::Plane && c.tenths == 170;
            if let Some(what) = forbidden(g, c.tenths).filter(|_| !same_plane) {
                return fail(
                    c.col,
                    ErrorKind::ModeConflict,
                    format!(
                        "{}: {what} is not allowed while cutter compensation is on (G40 first)",
                        code_name(if g == Group::ToolChange { 'M' } else { 'G' }, c.tenths)
                    ),
                );
            }
            // G10 L2/L20 on the coordinate system in force moves the path under the
            // held moves.
            if g == Group::NonModal && c.tenths == 100 {
                self.g10_guard(w, c.col)?;
            }
        }
        let modal_cycle =
            b.codes.get(Group::Motion).is_none() && matches!(self.motion, super::Motion::Cycle(_));
        if !before && modal_cycle && self.line_moves(w) {
            return fail(
                w.first_motion_col.max(1),
                ErrorKind::ModeConflict,
                "a canned cycle is not allowed while cutter compensation is on (G40 first)",
            );
        }
        Ok(())
    }

    /// G10 L2/L20 P (0 or the system in force) while compensation is on.
    fn g10_guard(&self, w: &Words, col: u32) -> Res<()> {
        let l = w.get(b'L').and_then(|l| l.num.whole());
        let p = w.get(b'P').and_then(|p| p.num.whole());
        let current = self.params.numbered(crate::gcode::params::CURRENT_SYSTEM) as i64;
        if matches!(l, Some(2 | 20)) && (p == Some(0) || p == Some(current)) {
            return fail(
                col,
                ErrorKind::ModeConflict,
                "G10: changing the coordinate system in force is not allowed while cutter \
                 compensation is on (G40 first)",
            );
        }
        Ok(())
    }

    /// Does the line move in the motion mode in force (axis or polar words)?
    fn line_moves(&self, w: &Words) -> bool {
        w.present() & super::AXIS_BITS != 0 || w.polar_radius.is_some() || w.polar_angle.is_some()
    }

    /// The cutter compensation phase: G40, G41, G42, G41.1, G42.1.
    pub(super) fn convert_cutter_comp(
        &mut self,
        w: &Words,
        b: &mut Block,
        out: &mut Vec<Canon>,
    ) -> Res<()> {
        let Some(c) = b.codes.get(Group::Cutter) else {
            return Ok(());
        };
        self.comp.hold(out);
        if c.tenths == 400 {
            return self.comp_off(c.col, out);
        }
        let name = code_name('G', c.tenths);
        match self.plane {
            Plane::Xy => {}
            Plane::Zx => {
                return fail(
                    c.col,
                    ErrorKind::Unsupported,
                    unsupported("cutter compensation in the XZ plane (G18: lathe tools)"),
                )
            }
            Plane::Yz => {
                return fail(
                    c.col,
                    ErrorKind::ModeConflict,
                    format!("{name}: cutter compensation needs the XY plane (G17)"),
                )
            }
        }
        if self.comp.on() {
            return fail(
                c.col,
                ErrorKind::ModeConflict,
                format!("{name} while cutter compensation is already on (G40 first)"),
            );
        }
        b.used |= bit(b'D');
        let mut side = if matches!(c.tenths, 410 | 411) {
            Side::Left
        } else {
            Side::Right
        };
        let radius = if c.tenths % 10 == 1 {
            if let Some(l) = w.get(b'L') {
                return fail(
                    l.col,
                    ErrorKind::Unsupported,
                    unsupported("lathe tool orientation (L) with G41.1/G42.1"),
                );
            }
            let Some(d) = w.get(b'D') else {
                return fail(
                    c.col,
                    ErrorKind::MissingValue,
                    format!("{name} needs D (the tool diameter)"),
                );
            };
            self.length(d)? as f64 / 2.0
        } else {
            self.comp_tool_radius(w, &name, c.col)?
        };
        if radius < 0.0 {
            // LinuxCNC: a negative diameter (a tool smaller than the one the path was
            // drawn for) offsets to the other side.
            side = match side {
                Side::Left => Side::Right,
                Side::Right => Side::Left,
            };
        }
        self.comp.side = Some(side);
        self.comp.radius = radius.abs();
        self.comp.first = true;
        self.comp.inch = self.inch;
        Ok(())
    }

    /// Radius of the tool D names (or of the tool in the spindle), nm, signed.
    fn comp_tool_radius(&self, w: &Words, name: &str, col: u32) -> Res<f64> {
        let n = match w.get(b'D') {
            Some(d) => {
                if d.num.is_negative() {
                    return fail(
                        d.col,
                        ErrorKind::Negative,
                        format!("{name}: negative tool number D{}", d.num),
                    );
                }
                whole_in(d, 0, i64::from(u32::MAX), "tool number D")? as u32
            }
            None => 0,
        };
        // D0 (or no D) is the tool in the spindle, as in LinuxCNC; none: radius 0.
        let n = if n == 0 { self.current_tool } else { n };
        match self.tools.get(n) {
            Some(t) => Ok(t.diameter_nm as f64 / 2.0),
            None if n == 0 => Ok(0.0),
            None => {
                let at = w.get(b'D').map_or(col, |d| d.col);
                fail(
                    at,
                    ErrorKind::ToolNumber,
                    format!("{name}: tool {n} is not in the tool table"),
                )
            }
        }
    }

    /// G40: the held moves end at their offset points; the next move leaves from there.
    fn comp_off(&mut self, col: u32, out: &mut Vec<Canon>) -> Res<()> {
        if self.comp.offsetting() && !self.comp.first {
            let at = self.comp.current;
            self.comp.end_held_at(at, out, col)?;
            self.comp.arc_not_allowed = true;
        }
        self.comp.side = None;
        self.comp.first = true;
        Ok(())
    }

    /// M0/M1/M2/M30 and the end of the file: everything held is emitted (the motion
    /// stops there, so the last move ends at its offset point). `end`: the program
    /// ends, and compensation with it.
    pub(super) fn comp_stop(&mut self, end: bool, col: u32, out: &mut Vec<Canon>) -> Res<()> {
        self.comp.hold(out);
        if self.comp.offsetting() && !self.comp.first {
            let at = self.comp.current;
            self.comp.end_held_at(at, out, col)?;
        } else {
            self.comp.release(out, col)?;
        }
        if end {
            self.comp.side = None;
            self.comp.first = true;
        }
        Ok(())
    }

    /// A straight move of line `line` to `target` (programmed): compensated when
    /// compensation is on, emitted as it is otherwise.
    pub(crate) fn straight(
        &mut self,
        line: u32,
        kind: Straight,
        target: [i64; AXES],
        col: u32,
        out: &mut Vec<Canon>,
    ) -> Res<()> {
        self.comp.arc_not_allowed = false;
        if !self.comp.offsetting() {
            out.push(match kind {
                Straight::Rapid => Canon::Rapid { line, target },
                Straight::Feed(feed) => Canon::Linear { line, target, feed },
            });
            self.pos = target;
            return Ok(());
        }
        self.comp.hold(out);
        let done = if self.comp.first {
            self.straight_entry(line, kind, target, col)
        } else {
            self.straight_next(line, kind, target, col, out)
        };
        self.after_comp_move(target, done)
    }

    /// After a compensated move to `target`: the programmed point moves on even when the
    /// move failed (one error is one message).
    fn after_comp_move(&mut self, target: [i64; AXES], done: Res<()>) -> Res<()> {
        self.pos = target;
        done
    }

    /// Refuses an arc right after G40 (LinuxCNC's rule: it would start from the offset
    /// point, not the programmed one its centre was given for).
    pub(crate) fn comp_arc_allowed(&self, col: u32) -> Res<()> {
        if self.comp.arc_not_allowed {
            return fail(
                col,
                ErrorKind::ModeConflict,
                "the move after turning cutter compensation off (G40) must be straight, \
                 not an arc",
            );
        }
        Ok(())
    }

    /// Refuses a spline (G5, G5.1: `name`) while compensation is on, as LinuxCNC
    /// ("Cannot convert spline with cutter radius compensation"). Right after G40 a
    /// spline leaves from the offset point, as a straight move does (its offsets are
    /// relative), and an arc may follow it.
    pub(crate) fn comp_spline_allowed(&mut self, name: &str, col: u32) -> Res<()> {
        if self.comp.on() {
            return fail(
                col,
                ErrorKind::ModeConflict,
                format!(
                    "{name} while cutter radius compensation is on: splines cannot be \
                     compensated (G40 first)"
                ),
            );
        }
        self.comp.arc_not_allowed = false;
        Ok(())
    }

    /// An arc of line `line` (already checked as programmed) about `centre`:
    /// compensated when compensation is on, emitted as it is otherwise (`clockwise`,
    /// `turns`: as for [`Canon::Arc`]).
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn arc_move(
        &mut self,
        line: u32,
        end: [i64; AXES],
        centre: [i64; 2],
        clockwise: bool,
        turns: u32,
        feed: Feed,
        col: u32,
        out: &mut Vec<Canon>,
    ) -> Res<()> {
        self.comp_arc_allowed(col)?;
        if !self.comp.offsetting() {
            out.push(Canon::Arc {
                line,
                target: end,
                center: centre,
                plane: self.plane,
                clockwise,
                turns,
                feed,
            });
            self.pos = end;
            return Ok(());
        }
        let n = i64::from(turns) + 1;
        let arc = ArcMove {
            end,
            centre: [centre[0] as f64, centre[1] as f64],
            turn: if clockwise { -n } else { n },
            feed,
        };
        self.comp.hold(out);
        let done = if self.comp.first {
            self.arc_entry(line, arc, col)
        } else {
            self.arc_next(line, arc, col, out)
        };
        self.after_comp_move(end, done)
    }
}
