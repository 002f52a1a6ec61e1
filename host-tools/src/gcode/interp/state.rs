//! The interpreter's state as a sender asks for it line by line (the Grbl bridge):
//! the modal codes in force, the work offset, stored positions, and moving the
//! interpreter to where the machine is after motion it did not command (a jog).

use super::{Interp, Motion};
use crate::gcode::canon::{Plane, Spindle};
use crate::gcode::params;
use pkmc::config::AXES;

/// Stored positions and offsets, machine units (nm, n°), for a sender's `$#`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Offsets {
    /// G54 … G59.3: the nine work coordinate systems.
    pub systems: [[i64; AXES]; 9],
    /// G28 and G30 stored positions.
    pub g28: [i64; AXES],
    /// See `g28`.
    pub g30: [i64; AXES],
    /// G92 offset in force (zero when G92.2 suspended it).
    pub g92: [i64; AXES],
    /// Tool offsets in force (G43, G43.1).
    pub tool: [i64; AXES],
}

impl Interp<'_> {
    /// The modal codes in force, in the order Grbl's `$G` lists them: motion,
    /// coordinate system, plane, units, distance, feed mode, spindle, coolant, tool,
    /// feed (in the program's units per minute) and speed, e.g.
    /// `G1 G54 G17 G21 G90 G94 M3 M9 T1 F500 S12000`.
    pub fn modal_words(&self) -> String {
        let motion = match self.motion {
            Motion::None => "G80",
            Motion::Rapid => "G0",
            Motion::Linear => "G1",
            Motion::Arc { clockwise: true } => "G2",
            Motion::Arc { clockwise: false } => "G3",
            Motion::Cubic => "G5",
            Motion::Quadratic => "G5.1",
            Motion::Cycle(c) => c.name(),
            Motion::Probe(p) => p.name(),
        };
        let system = match self.system() {
            n @ 1..=6 => format!("G{}", 53 + n),
            n => format!("G59.{}", n - 6),
        };
        let plane = match self.plane {
            Plane::Xy => "G17",
            Plane::Zx => "G18",
            Plane::Yz => "G19",
        };
        let units = if self.inch { "G20" } else { "G21" };
        let distance = if self.absolute { "G90" } else { "G91" };
        let feed_mode = if self.inverse_time { "G93" } else { "G94" };
        let spindle = match self.spindle {
            Spindle::Off => "M5",
            Spindle::Clockwise(_) => "M3",
            Spindle::CounterClockwise(_) => "M4",
        };
        let coolant = match self.coolant {
            (false, false) => "M9".to_string(),
            (true, false) => "M7".to_string(),
            (false, true) => "M8".to_string(),
            (true, true) => "M7 M8".to_string(),
        };
        let per_min = if self.inch { 25_400_000.0 } else { 1_000_000.0 } / 60.0;
        let feed = self.feed.map_or(0.0, |f| f.linear as f64 / per_min);
        format!(
            "{motion} {system} {plane} {units} {distance} {feed_mode} {spindle} {coolant} T{} F{} S{}",
            self.current_tool,
            trim(feed),
            self.rpm
        )
    }

    /// Work offset in force, machine units: the machine position minus this is the
    /// position in the program's coordinates (Grbl's `WCO`). The rotation of a
    /// coordinate system (G10 L2 R) is not part of it.
    pub fn work_offset(&self) -> [i64; AXES] {
        self.off
    }

    /// Stored offsets and positions, machine units.
    pub fn offsets(&self) -> Offsets {
        let read = |base: usize| -> [i64; AXES] {
            std::array::from_fn(|i| self.param_units(base + i, i, 0).unwrap_or(0))
        };
        Offsets {
            systems: std::array::from_fn(|s| read(params::SYSTEM_BASE + 20 * s)),
            g28: read(params::G28_POSITION),
            g30: read(params::G30_POSITION),
            g92: self.g92,
            tool: self.tool_offsets,
        }
    }

    /// The machine is at `pose` (machine frame) after motion this interpreter did not
    /// command (a jog, homing): the next move starts there.
    pub fn set_position(&mut self, pose: [i64; AXES]) {
        self.pos = pose;
        // A probing move still waiting for its outcome did not run (line by line: an
        // alarm or a reset came first).
        self.waiting = None;
        // A G5 after this is the first of a series.
        self.g5_tangent = None;
        self.update_position_params();
    }
}

/// A number with at most three decimals and no trailing zeros.
fn trim(v: f64) -> String {
    let s = format!("{v:.3}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" {
        "0".into()
    } else {
        s.into()
    }
}
