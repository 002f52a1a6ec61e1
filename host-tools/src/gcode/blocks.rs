//! Canonical commands to protocol blocks: what is streamed to the controller.
//!
//! Motion keeps its geometry (lines, native arcs, G5/G5.1 splines as Bézier blocks);
//! an arc the controller would not run exactly (the one rule both share,
//! `pkmc::motion::geometry::Path::checked`) goes as chords within 0.1 µm of it
//! ([`crate::gcode::arcs::chords`]), never refused;
//! G93 inverse-time feeds become path speeds from the block's exact length (measured
//! with the core's own geometry, so host and controller agree; for a spline that length
//! is the one the controller runs the curve's parameter over, so the move takes the
//! time G93 asked for); the path mode (G61/G64 P) becomes each block's blending
//! tolerance; spindle, coolant, tool changes and pauses become auxiliary blocks that
//! execute in order. Operator messages stay on the host, keyed by NC line, and are
//! shown when that line starts executing.

use crate::gcode::canon::{Canon, Coolant, Feed, PathMode, Spindle};
use pkmc::config::AXES;
use pkmc::motion::block::{Aux, Block, Motion};
use pkmc::motion::geometry::Path;
use std::collections::BTreeMap;

/// A program ready to stream.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Program {
    /// Blocks in order.
    pub blocks: Vec<Block>,
    /// `(MSG, …)` texts by NC line.
    pub messages: BTreeMap<u32, String>,
}

/// Blending tolerance streamed for G64 without P: as fast as the limits allow.
pub const BLEND_ANY: u32 = u32::MAX;

/// Converts canonical commands starting at `start` (axis units).
pub fn from_canon(commands: &[Canon], start: [i64; AXES]) -> Program {
    let mut program = Program::default();
    Converter::new(start).push(commands, &mut program);
    program
}

/// Canonical commands to blocks a piece at a time: what [`from_canon`] carries from
/// one command to the next (the pose, the path mode), kept between pieces.
#[derive(Clone, Copy, Debug)]
pub struct Converter {
    pose: [i64; AXES],
    tolerance: u32,
}

impl Converter {
    /// At the program's start, `start`.
    pub fn new(start: [i64; AXES]) -> Self {
        // LinuxCNC starts in G64 (blending) unless told otherwise.
        Self {
            pose: start,
            tolerance: BLEND_ANY,
        }
    }

    /// Where the blocks so far end.
    pub fn pose(&self) -> [i64; AXES] {
        self.pose
    }

    /// Appends the blocks and messages of `commands`, the next ones, to `program`.
    pub fn push(&mut self, commands: &[Canon], program: &mut Program) {
        let (pose, tolerance) = (&mut self.pose, &mut self.tolerance);
        push_into(commands, pose, tolerance, program);
    }
}

fn push_into(
    commands: &[Canon],
    pose_at: &mut [i64; AXES],
    tolerance_at: &mut u32,
    program: &mut Program,
) {
    let mut pose = *pose_at;
    let mut tolerance = *tolerance_at;
    let aux = |line: u32, aux: Aux, pose: [i64; AXES]| Block {
        line,
        motion: Motion::Aux(aux),
        target: pose,
        feed: 0,
        tolerance_nm: 0,
    };
    for c in commands {
        let block = match c {
            Canon::Rapid { .. }
            | Canon::Linear { .. }
            | Canon::Arc { .. }
            | Canon::Cubic { .. }
            | Canon::Quadratic { .. }
            | Canon::Probe { .. } => move_block(c, tolerance, &pose),
            Canon::Dwell { line, ms } => Some(Block {
                line: *line,
                motion: Motion::Dwell(*ms),
                target: pose,
                feed: 0,
                tolerance_nm: 0,
            }),
            Canon::PathMode { mode, .. } => {
                tolerance = match mode {
                    PathMode::ExactStop => 0,
                    PathMode::Blend(None) => BLEND_ANY,
                    PathMode::Blend(Some(p)) => (*p).clamp(1, u32::MAX as i64 - 1) as u32,
                };
                None
            }
            Canon::Spindle { line, state } => Some(aux(
                *line,
                match state {
                    Spindle::Off => Aux::SpindleOff,
                    Spindle::Clockwise(r) => Aux::SpindleCw(*r),
                    Spindle::CounterClockwise(r) => Aux::SpindleCcw(*r),
                },
                pose,
            )),
            Canon::Coolant { line, state } => Some(aux(
                *line,
                match state {
                    Coolant::Mist => Aux::Mist,
                    Coolant::Flood => Aux::Flood,
                    Coolant::Off => Aux::CoolantOff,
                },
                pose,
            )),
            Canon::ToolChange { line, tool } => Some(aux(*line, Aux::ToolChange(*tool), pose)),
            Canon::Pause { line, optional } => Some(aux(*line, Aux::Pause(*optional), pose)),
            Canon::Message { line, text } => {
                program.messages.insert(*line, text.clone());
                None
            }
            Canon::End { .. } => None,
        };
        // An arc the controller would not run as it is goes as chords along it.
        if let Some(b) = block.filter(|b| matches!(b.motion, Motion::Arc { .. })) {
            if Path::checked(&b, &pose).is_err() {
                program.blocks.extend(crate::gcode::arcs::chords(&b, &pose));
                pose = b.target;
                continue;
            }
        }
        if let Some(b) = block {
            if matches!(
                b.motion,
                Motion::Rapid
                    | Motion::Linear
                    | Motion::Arc { .. }
                    | Motion::Cubic { .. }
                    | Motion::Quadratic { .. }
            ) {
                pose = b.target;
            }
            program.blocks.push(b);
        }
    }
    (*pose_at, *tolerance_at) = (pose, tolerance);
}

/// The block of a move command (`None` for the others) from `pose`, with the blending
/// `tolerance` in force.
fn move_block(c: &Canon, tolerance: u32, pose: &[i64; AXES]) -> Option<Block> {
    match c {
        Canon::Rapid { line, target } => Some(Block {
            line: *line,
            motion: Motion::Rapid,
            target: *target,
            feed: 0,
            tolerance_nm: tolerance,
        }),
        Canon::Linear { line, target, feed } => Some(feed_block(
            *line,
            Motion::Linear,
            *target,
            *feed,
            tolerance,
            pose,
        )),
        Canon::Arc {
            line,
            target,
            center,
            plane,
            clockwise,
            turns,
            feed,
        } => Some(feed_block(
            *line,
            Motion::Arc {
                center: *center,
                plane: *plane,
                clockwise: *clockwise,
                turns: (*turns).min(u16::MAX as u32) as u16,
            },
            *target,
            *feed,
            tolerance,
            pose,
        )),
        Canon::Cubic {
            line,
            target,
            c1,
            c2,
            feed,
        } => Some(spline_block(
            *line,
            Motion::Cubic { c1: *c1, c2: *c2 },
            *target,
            *feed,
            tolerance,
            pose,
        )),
        Canon::Quadratic {
            line,
            target,
            c,
            feed,
        } => Some(spline_block(
            *line,
            Motion::Quadratic { c: *c },
            *target,
            *feed,
            tolerance,
            pose,
        )),
        // The probing move as it ran (the controller runs it as `Control::Probe`, never
        // as a block: see `crate::job::probing`), stopping at its end.
        Canon::Probe {
            line, target, feed, ..
        } => Some(feed_block(*line, Motion::Linear, *target, *feed, 0, pose)),
        _ => None,
    }
}

/// A spline's block. A curve the controller's geometry refuses is sent as a straight
/// move to its end: that is only a curve that does not move at all (a G5 whose control
/// points and end are its start), since the interpreter refuses curves too large for
/// the controller.
fn spline_block(
    line: u32,
    motion: Motion,
    target: [i64; AXES],
    feed: Feed,
    tolerance: u32,
    from: &[i64; AXES],
) -> Block {
    let curve = Block {
        line,
        motion,
        target,
        feed: 1,
        tolerance_nm: tolerance,
    };
    let motion = match Path::new(&curve, from) {
        Ok(_) => motion,
        Err(_) => Motion::Linear,
    };
    feed_block(line, motion, target, feed, tolerance, from)
}

/// A feed move; inverse-time feeds become path speeds over the block's exact length.
fn feed_block(
    line: u32,
    motion: Motion,
    target: [i64; AXES],
    feed: Feed,
    tolerance: u32,
    from: &[i64; AXES],
) -> Block {
    let mut b = Block {
        line,
        motion,
        target,
        feed: 0,
        tolerance_nm: tolerance,
    };
    b.feed = match feed {
        Feed::PerSecond(v) => v.max(1),
        Feed::InverseTime(us) => {
            let length = Path::new(&b, from).map_or(0, |p| p.length) as i128;
            // units/s = length / (us · 1e-6); rotary-only moves are streamed in µ°/s.
            let rotary_only = (0..3).all(|i| target[i] == from[i]);
            let per_s = length * 1_000_000 / (us.max(1) as i128);
            let per_s = if rotary_only { per_s / 1000 } else { per_s };
            per_s.clamp(1, i64::MAX as i128) as i64
        }
    };
    b
}

#[cfg(test)]
mod tests {
    use super::*;
    use pkmc::motion::block::Plane;

    #[test]
    fn inverse_time_feed_becomes_the_speed_that_takes_that_long() {
        // 10 mm in 0.5 s (G93 F120): 20 mm/s.
        let c = [Canon::Linear {
            line: 3,
            target: [10_000_000, 0, 0, 0, 0, 0],
            feed: Feed::InverseTime(500_000),
        }];
        let p = from_canon(&c, [0; AXES]);
        assert_eq!(p.blocks[0].feed, 20_000_000);
    }

    #[test]
    fn an_inverse_time_spline_runs_its_parameter_length_in_the_time_asked() {
        // The controller runs a spline's parameter over its length at the feed: G93's
        // time is length / feed, whatever the curve's shape.
        let mm = 1_000_000;
        let c = [Canon::Cubic {
            line: 1,
            target: [10 * mm, 0, 0, 0, 0, 0],
            c1: [0, 5 * mm, 0, 0, 0, 0],
            c2: [0, 5 * mm, 0, 0, 0, 0],
            feed: Feed::InverseTime(2_000_000),
        }];
        let p = from_canon(&c, [0; AXES]);
        let b = p.blocks[0];
        assert!(matches!(b.motion, Motion::Cubic { .. }));
        let length = Path::new(&b, &[0; AXES]).unwrap().length;
        assert!(length > 10 * mm, "a curve is longer than its chord");
        assert_eq!(b.feed, length / 2);
    }

    #[test]
    fn path_mode_sets_the_tolerance_of_later_blocks_and_aux_blocks_stop() {
        let t = [1_000_000, 0, 0, 0, 0, 0];
        let c = [
            Canon::PathMode {
                line: 1,
                mode: PathMode::Blend(Some(50_000)),
            },
            Canon::Rapid { line: 2, target: t },
            Canon::Spindle {
                line: 3,
                state: Spindle::Clockwise(1200),
            },
            Canon::PathMode {
                line: 4,
                mode: PathMode::ExactStop,
            },
            Canon::Arc {
                line: 5,
                target: [-1_000_000, 0, 0, 0, 0, 0],
                center: [0, 0],
                plane: Plane::Xy,
                clockwise: false,
                turns: 0,
                feed: Feed::PerSecond(5_000_000),
            },
            Canon::Message {
                line: 6,
                text: "check the clamp".into(),
            },
        ];
        let p = from_canon(&c, [0; AXES]);
        assert_eq!(p.blocks.len(), 3);
        assert_eq!(p.blocks[0].tolerance_nm, 50_000);
        assert_eq!(p.blocks[1].motion, Motion::Aux(Aux::SpindleCw(1200)));
        assert_eq!(p.blocks[1].target, t, "aux blocks stay where the tool is");
        assert_eq!(p.blocks[2].tolerance_nm, 0);
        assert_eq!(p.messages[&6], "check the clamp");
    }
}
