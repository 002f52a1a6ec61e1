//! Canonical machining commands: what the G-code interpreter produces and the rest of
//! the host (pre-flight, streaming, plots) consumes.
//!
//! Every position is absolute, in axis units (nm for X Y Z, n° for A B C; see
//! `pkmc::units`), in the workpiece frame after every offset the program set up (work
//! coordinate systems G54–G59, G92, tool length G43) has been applied: the controller
//! only adds the machine's own transforms (rolling table, kinematics). Every command
//! keeps the NC line it came from (1-based).

use pkmc::config::AXES;

/// Arc plane (G17, G18, G19): the protocol's own type, so the two cannot drift.
pub use pkmc::motion::block::Plane;

/// Feed of a feed move.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Feed {
    /// G94: path speed in nm/s along X Y Z (or µ°/s when only rotary axes move, i.e.
    /// degrees per minute × 10⁶/60).
    PerSecond(i64),
    /// G93: the move takes this long, µs.
    InverseTime(u64),
}

/// Spindle state (M3 M4 M5 with S).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Spindle {
    /// M5.
    Off,
    /// M3 at rpm.
    Clockwise(u32),
    /// M4 at rpm.
    CounterClockwise(u32),
}

/// Coolant (M7 M8 M9).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Coolant {
    /// M7.
    Mist,
    /// M8.
    Flood,
    /// M9.
    Off,
}

/// Path blending mode (G61, G61.1, G64).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PathMode {
    /// G61 / G61.1: stop exactly at every block end.
    ExactStop,
    /// G64 P: blend, deviating at most this much from the programmed corner, nm
    /// (`None`: G64 without P, as fast as the limits allow).
    Blend(Option<i64>),
}

/// One canonical command.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Canon {
    /// G0: straight rapid move to `target`.
    Rapid {
        /// NC line.
        line: u32,
        /// End pose.
        target: [i64; AXES],
    },
    /// G1: straight feed move to `target`.
    Linear {
        /// NC line.
        line: u32,
        /// End pose.
        target: [i64; AXES],
        /// Feed.
        feed: Feed,
    },
    /// G2/G3: circular or helical move. The start is the previous command's end; the
    /// end's in-plane distance to `center` equals the start's within the interpreter's
    /// tolerance; the helix axis and A B C move linearly with the angle.
    Arc {
        /// NC line.
        line: u32,
        /// End pose.
        target: [i64; AXES],
        /// Centre, in-plane coordinates (first, second axis of `plane`), nm.
        center: [i64; 2],
        /// Plane.
        plane: Plane,
        /// G2 (clockwise seen from the positive helix axis) when true.
        clockwise: bool,
        /// Extra full turns (P − 1); 0 for the ordinary arc.
        turns: u32,
        /// Feed.
        feed: Feed,
    },
    /// G5: cubic Bézier move (LinuxCNC's cubic spline) from the previous command's end
    /// through the control points start + `c1` and `target` + `c2` to `target`, as
    /// [`pkmc::motion::block::Motion::Cubic`]. Only X and Y move: `c1` and `c2` are zero on
    /// the other axes, and `target` keeps them where they were.
    Cubic {
        /// NC line.
        line: u32,
        /// End pose.
        target: [i64; AXES],
        /// First control point minus the start, axis units.
        c1: [i64; AXES],
        /// Second control point minus `target`, axis units.
        c2: [i64; AXES],
        /// Feed.
        feed: Feed,
    },
    /// G5.1: quadratic Bézier move (LinuxCNC's quadratic B-spline) from the previous
    /// command's end through the control point start + `c` to `target`, as
    /// [`pkmc::motion::block::Motion::Quadratic`]; only X and Y move.
    Quadratic {
        /// NC line.
        line: u32,
        /// End pose.
        target: [i64; AXES],
        /// Control point minus the start, axis units.
        c: [i64; AXES],
        /// Feed.
        feed: Feed,
    },
    /// G38.2–G38.5: a straight probing move toward `target` that stops where the probe
    /// changes as `probing` seeks ([`crate::gcode::interp::probe`]). When its outcome
    /// is known (a run with [`crate::gcode::Options::probes`]) `target` is where the
    /// move stopped and `outcome` says what it found; otherwise it is the last command
    /// of the run.
    Probe {
        /// NC line.
        line: u32,
        /// End pose: the programmed one, or where the move stopped.
        target: [i64; AXES],
        /// Feed.
        feed: Feed,
        /// Which G38.
        probing: crate::gcode::interp::probe::Probing,
        /// What the move found, when known.
        outcome: Option<crate::gcode::interp::probe::ProbeOutcome>,
    },
    /// G4: dwell.
    Dwell {
        /// NC line.
        line: u32,
        /// Duration, ms.
        ms: u32,
    },
    /// Path blending mode from here on.
    PathMode {
        /// NC line.
        line: u32,
        /// Mode.
        mode: PathMode,
    },
    /// Spindle.
    Spindle {
        /// NC line.
        line: u32,
        /// State.
        state: Spindle,
    },
    /// Coolant.
    Coolant {
        /// NC line.
        line: u32,
        /// State.
        state: Coolant,
    },
    /// M6 with the tool selected by T.
    ToolChange {
        /// NC line.
        line: u32,
        /// Tool number.
        tool: u32,
    },
    /// M0 (optional = false) or M1 (optional = true): pause until resumed.
    Pause {
        /// NC line.
        line: u32,
        /// M1.
        optional: bool,
    },
    /// `(MSG, text)`: show text to the operator when this line is reached.
    Message {
        /// NC line.
        line: u32,
        /// Text after "MSG,", trimmed.
        text: String,
    },
    /// M2 / M30: end of program.
    End {
        /// NC line.
        line: u32,
    },
}

impl Canon {
    /// The NC line of the command.
    pub fn line(&self) -> u32 {
        match self {
            Canon::Rapid { line, .. }
            | Canon::Linear { line, .. }
            | Canon::Arc { line, .. }
            | Canon::Cubic { line, .. }
            | Canon::Quadratic { line, .. }
            | Canon::Probe { line, .. }
            | Canon::Dwell { line, .. }
            | Canon::PathMode { line, .. }
            | Canon::Spindle { line, .. }
            | Canon::Coolant { line, .. }
            | Canon::ToolChange { line, .. }
            | Canon::Pause { line, .. }
            | Canon::Message { line, .. }
            | Canon::End { line } => *line,
        }
    }

    /// End pose of a motion command.
    pub fn target(&self) -> Option<&[i64; AXES]> {
        match self {
            Canon::Rapid { target, .. }
            | Canon::Linear { target, .. }
            | Canon::Arc { target, .. }
            | Canon::Cubic { target, .. }
            | Canon::Quadratic { target, .. }
            | Canon::Probe { target, .. } => Some(target),
            _ => None,
        }
    }
}
