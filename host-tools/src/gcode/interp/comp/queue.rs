//! The held output of cutter compensation: compensated moves whose end waits for the
//! next move, and the commands the program emitted after them.
//!
//! Invariants: the queue is empty or starts with a move; `start` is where the first
//! held move starts (the tool centre), when known (LinuxCNC's `endpoint`): only then
//! are moved ends checked for gouging.

use super::corners::swept;
use super::Straight;
use crate::gcode::canon::{Canon, Feed, Plane};
use crate::gcode::interp::{bounded_round, fail, Res};
use crate::gcode::ErrorKind;
use pkmc::config::AXES;
use pkmc::units::NM_PER_MM;

/// How far a held arc may grow, radians, when its end moves into a concave corner:
/// LinuxCNC compares the swept angles with 0.0254 in millimetre programs and 0.001 in
/// inch programs.
const ARC_GROWTH_MM: f64 = 0.0254;
/// See [`ARC_GROWTH_MM`].
const ARC_GROWTH_INCH: f64 = 0.001;

/// A held move's shape.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Shape {
    /// A straight move; `dir` is the direction its end may move along (never back).
    Straight {
        /// G0 or G1 with its feed.
        kind: Straight,
        /// Direction, any length (zero: no XY motion, never checked).
        dir: [f64; 2],
    },
    /// An arc about `centre`; `swept` is its programmed angle (zero: not checked).
    Arc {
        /// Centre, nm.
        centre: [f64; 2],
        /// Signed turns (see [`super::ArcMove::turn`]).
        turn: i64,
        /// Swept angle, radians, signed.
        swept: f64,
        /// Feed.
        feed: Feed,
    },
}

/// A held move.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Held {
    /// NC line.
    pub line: u32,
    /// Shape.
    pub shape: Shape,
    /// Tool centre XY at the end, nm.
    pub end: [f64; 2],
    /// End pose of the other axes (X and Y are taken from `end`).
    pub pose: [i64; AXES],
}

#[derive(Debug)]
enum Item {
    Move(Held),
    Other(Canon),
}

/// Held output.
#[derive(Debug, Default)]
pub(crate) struct Queue {
    items: Vec<Item>,
    start: Option<[f64; 2]>,
}

impl Queue {
    /// Nothing held?
    pub(crate) fn is_empty(&self) -> bool {
        self.items.is_empty()
    }

    /// Holds `commands` behind the held moves.
    pub(crate) fn hold(&mut self, commands: impl Iterator<Item = Canon>) {
        self.items.extend(commands.map(Item::Other));
    }

    /// Holds a move.
    pub(crate) fn push(&mut self, m: Held) {
        self.items.push(Item::Move(m));
    }

    /// The first held move.
    pub(crate) fn first_move(&self) -> Option<&Held> {
        self.items.iter().find_map(|i| match i {
            Item::Move(m) => Some(m),
            Item::Other(_) => None,
        })
    }

    /// The tool centre where the held moves start.
    pub(crate) fn set_start(&mut self, at: [f64; 2]) {
        self.start = Some(at);
    }

    /// Moves the end of every held move to `at` (LinuxCNC's `move_endpoint_and_flush`,
    /// before the release): an arc stays on its circle and may not sweep further than
    /// programmed; a straight move may not turn back (the offset paths crossed: the
    /// tool would gouge the part).
    pub(crate) fn move_end(&mut self, at: [f64; 2], inch: bool, col: u32) -> Res<()> {
        let start = self.start;
        for item in &mut self.items {
            let Item::Move(m) = item else { continue };
            match m.shape {
                Shape::Arc {
                    centre,
                    turn,
                    swept: programmed,
                    ..
                } => {
                    let r1 = (m.end[0] - centre[0]).hypot(m.end[1] - centre[1]);
                    let r2 = (at[0] - centre[0]).hypot(at[1] - centre[1]);
                    let unit = if inch { 25_400_000.0 } else { NM_PER_MM as f64 };
                    if (r1 - r2).abs() > 0.01 * unit {
                        return fail(
                            col,
                            ErrorKind::InvalidTarget,
                            format!(
                                "cutter compensation: the arc of line {} would leave its \
                                 circle (radius {:.4} mm, end at {:.4} mm from the centre)",
                                m.line,
                                r1 * 1e-6,
                                r2 * 1e-6
                            ),
                        );
                    }
                    if let Some(s) = start.filter(|_| programmed != 0.0) {
                        let grown = swept(s, centre, turn, at);
                        let slack = if inch { ARC_GROWTH_INCH } else { ARC_GROWTH_MM };
                        if grown.abs() > programmed.abs() + slack {
                            return fail(
                                col,
                                ErrorKind::InvalidTarget,
                                format!(
                                    "cutter compensation: the arc of line {} cannot reach \
                                     this concave corner without the tool gouging the part",
                                    m.line
                                ),
                            );
                        }
                    }
                }
                Shape::Straight { kind, dir } => {
                    if let Some(s) = start {
                        if dir[0] * (at[0] - s[0]) + dir[1] * (at[1] - s[1]) < 0.0 {
                            let what = match kind {
                                Straight::Rapid => "rapid",
                                Straight::Feed(_) => "straight feed",
                            };
                            return fail(
                                col,
                                ErrorKind::InvalidTarget,
                                format!(
                                    "cutter compensation: the {what} of line {} is shorter \
                                     than the cut-back this concave corner needs: the tool \
                                     would gouge the part",
                                    m.line
                                ),
                            );
                        }
                    }
                }
            }
            m.end = at;
        }
        Ok(())
    }

    /// Forgets everything held, after a failed join (the program will not run; the
    /// next move then joins the failed move's offset end, so one error is one message).
    pub(crate) fn discard(&mut self) {
        self.items.clear();
        self.start = None;
    }

    /// Emits everything held, in order, and forgets the start.
    pub(crate) fn release(&mut self, out: &mut Vec<Canon>, col: u32) -> Res<()> {
        self.start = None;
        for item in self.items.drain(..) {
            out.push(match item {
                Item::Other(c) => c,
                Item::Move(m) => emit(&m, col)?,
            });
        }
        Ok(())
    }
}

/// The command of a held move, rounded to whole nm.
fn emit(m: &Held, col: u32) -> Res<Canon> {
    let mut target = m.pose;
    target[0] = bounded_round(m.end[0], col)?;
    target[1] = bounded_round(m.end[1], col)?;
    let line = m.line;
    Ok(match m.shape {
        Shape::Straight {
            kind: Straight::Rapid,
            ..
        } => Canon::Rapid { line, target },
        Shape::Straight {
            kind: Straight::Feed(feed),
            ..
        } => Canon::Linear { line, target, feed },
        Shape::Arc {
            centre, turn, feed, ..
        } => Canon::Arc {
            line,
            target,
            center: [
                bounded_round(centre[0], col)?,
                bounded_round(centre[1], col)?,
            ],
            plane: Plane::Xy,
            clockwise: turn < 0,
            turns: u32::try_from(turn.unsigned_abs() - 1).unwrap_or(u32::MAX),
            feed,
        },
    })
}
