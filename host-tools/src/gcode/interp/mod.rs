//! Modal interpreter: applies one line's [`Words`] to the modal state and emits
//! [`Canon`] commands.
//!
//! This module holds the state and [`Interp::execute`], a short sequence of phases;
//! `modal` knows which modal group each G and M code is in, `convert` holds the phases
//! (`convert_*`, one per step of the order below), `motion` the moves (straight, arcs),
//! `spline` the G5/G5.1 splines and `offsets` the parameters and offsets (G10, G28/G30, G92, parameter settings);
//! canned cycles are [`super::cycles`].
//!
//! Order of execution within a line (LinuxCNC's, with one deliberate change): comments
//! and messages; units G20/G21 (moved first, so that every number on a line with G20 is
//! read in inches: `G20 F10` is 10 in/min, where LinuxCNC would read the F in the old
//! units); feed mode G93/G94; F; S; T; M6/M61; M3/M4/M5; M7/M8/M9; G4 dwell; plane;
//! cutter compensation G40; tool length G43/G49; coordinate system G54–G59.3; path
//! control G61/G61.1/G64; distance modes G90/G91 and G90.1/G91.1; retract mode
//! G98/G99; G10/G28/G30/G92 and friends; motion (G0 G1 G2 G3 G5 G5.1 G73 G81–G89, or the modal
//! motion when a line has only coordinates); stops M0/M1/M2/M30; then the line's
//! parameter settings.
//!
//! Positions: the interpreter keeps the current pose in the output frame (what
//! [`Canon`] carries: the machine pose the program commands, after offsets). The
//! program frame is that minus the sum of the offsets in force: work coordinate system
//! (G54…), G92 offsets and the tool length (Z only). Changing an offset changes the
//! program coordinates of the current point, never the machine's position.
//!
//! Invariants: every position, offset and distance is within
//! [`super::MAX_AXIS_UNITS`], so sums of a few of them never overflow; a line that fails
//! leaves the output as it was before the line (the caller truncates) and does not
//! apply its parameter settings.
//!
//! Source: LinuxCNC G-code and M-code reference; the RS-274/NGC interpreter
//! (`interp_convert.cc`, `interp_find.cc`) for offsets, G28/G30, G10, G92 and polar
//! coordinates.

mod comp;
mod convert;
mod debug;
mod modal;
mod motion;
mod offsets;
pub mod probe;
mod rotation;
mod spline;
pub mod state;
mod tooling;

use super::lexer::{bit, f64_to_i64, Word, Words, DEGREE, INCH, MM};
use super::params::Params;
use super::{ErrorKind, Options, MAX_AXIS_UNITS};
use crate::gcode::canon::Canon;
use crate::gcode::canon::{PathMode, Plane, Spindle};
use convert::{check_unused, Block};
use modal::{Group, Modal};
use pkmc::config::{AXES, AXIS_NAMES};
use pkmc::units::{NDEG_PER_DEG, NM_PER_MM};

/// nm per inch.
pub const NM_PER_INCH: i64 = 25_400_000;

/// An error on a line: column (1-based, in bytes: see [`super::lexer::char_col`]) and
/// message.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LineError {
    /// Column, 1-based.
    pub col: u32,
    /// What kind of fault.
    pub kind: ErrorKind,
    /// What is wrong.
    pub message: String,
}

/// A phase's result. The error is boxed: a `Res<()>` is then one pointer, returned in
/// a register, where a `Result` holding the error itself (32 bytes) went through the
/// stack and was copied at every `?` with loads spanning two stores, which the processor
/// does not forward (see docs/gcode.md, Performance). Errors are rare: one allocation
/// each costs nothing.
pub(crate) type Res<T> = Result<T, Box<LineError>>;

impl LineError {
    /// The error, boxed for [`Res`].
    #[cold]
    pub(crate) fn boxed(col: u32, kind: ErrorKind, message: String) -> Box<LineError> {
        Box::new(LineError { col, kind, message })
    }
}

pub(crate) fn fail<T>(col: u32, kind: ErrorKind, message: impl Into<String>) -> Res<T> {
    Err(LineError::boxed(col, kind, message.into()))
}

/// Canned cycles that are expanded on the host.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Cycle {
    /// G73: chip-breaking peck drilling.
    G73,
    /// G81: drilling.
    G81,
    /// G82: drilling with dwell.
    G82,
    /// G83: peck drilling.
    G83,
    /// G85: boring, feed out.
    G85,
    /// G89: boring, dwell, feed out.
    G89,
}

impl Cycle {
    /// The G code's name.
    pub fn name(self) -> &'static str {
        match self {
            Cycle::G73 => "G73",
            Cycle::G81 => "G81",
            Cycle::G82 => "G82",
            Cycle::G83 => "G83",
            Cycle::G85 => "G85",
            Cycle::G89 => "G89",
        }
    }
}

/// Motion mode (modal group 1).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Motion {
    /// None yet, or G80.
    None,
    /// G0.
    Rapid,
    /// G1.
    Linear,
    /// G2 (clockwise) or G3.
    Arc {
        /// G2.
        clockwise: bool,
    },
    /// G5: cubic spline.
    Cubic,
    /// G5.1: quadratic B-spline.
    Quadratic,
    /// A canned cycle.
    Cycle(Cycle),
    /// G38.2–G38.5: a probing move ([`probe`]).
    Probe(probe::Probing),
}

/// Feed rate set by F in units-per-minute mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct FeedRate {
    /// For moves with X Y or Z motion, nm/s.
    pub linear: i64,
    /// For moves of A B C alone, µ°/s (F read as degrees per minute).
    pub rotary: i64,
}

/// What canned cycles remember between lines (sticky words, initial level).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct CycleMemory {
    /// Level of the cycle axis before the first of a run of cycle lines (G98 retract).
    pub initial_level: Option<i64>,
    /// R as given, axis units.
    pub r: i64,
    /// Z (cycle-axis word) as given, axis units.
    pub z: i64,
    /// P, ms.
    pub p_ms: u32,
    /// Q, axis units.
    pub q: i64,
}

/// The axis letters' bits.
const AXIS_BITS: u32 = bit(b'X') | bit(b'Y') | bit(b'Z') | bit(b'A') | bit(b'B') | bit(b'C');

/// The modal interpreter.
pub struct Interp<'o> {
    pub(crate) opts: &'o Options,
    /// Parameters (the lexer reads them).
    pub params: Params,
    pub(crate) inch: bool,
    pub(crate) absolute: bool,
    arc_absolute: bool,
    pub(crate) plane: Plane,
    pub(crate) inverse_time: bool,
    pub(crate) motion: Motion,
    pub(crate) retract_to_r: bool,
    pub(crate) feed: Option<FeedRate>,
    /// The feed in force was set to F0 (accepted until a feed move needs it).
    feed_zero: bool,
    rpm: u32,
    spindle: Spindle,
    /// Mist (M7) and flood (M8) coolant on.
    coolant: (bool, bool),
    selected_tool: u32,
    current_tool: u32,
    /// Tool offsets in force (G43, G43.1), per pose axis, axis units.
    tool_offsets: [i64; AXES],
    /// The tool table for this run: the options' table, as G10 L1/L10/L11 rewrite it.
    tools: super::ToolTable,
    g5x: [i64; AXES],
    g92: [i64; AXES],
    /// Rotation of the coordinate system in force about Z, degrees (G10 L2 R).
    rot_deg: f64,
    pub(crate) off: [i64; AXES],
    pub(crate) pos: [i64; AXES],
    pub(crate) path: PathMode,
    pub(crate) cycle: CycleMemory,
    /// After a G5 (and until any other move): its −P −Q, program frame, nm — the first
    /// control point offset of a G5 that follows it without I and J.
    g5_tangent: Option<[i64; 2]>,
    /// Cutter radius compensation (G40/G41/G42) and its held moves.
    comp: comp::Comp,
    ended: bool,
    /// Probing moves run so far (their outcomes are [`Options::probes`]).
    probes_done: usize,
    /// The last command is a probing move whose outcome is not known yet: the run
    /// stops there ([`Interp::waiting`]) until it is given ([`Interp::probed`]).
    waiting: Option<probe::Waiting>,
}

impl<'o> Interp<'o> {
    /// The state at program start: G17 G21 G40 G49 G54 G64 G80 G90 G91.1 G94 G99, M5
    /// M9, no feed, tool 0, at `options.start`.
    pub fn new(opts: &'o Options) -> Self {
        let mut s = Self {
            opts,
            params: Params::new(),
            inch: false,
            absolute: true,
            arc_absolute: false,
            plane: Plane::Xy,
            inverse_time: false,
            motion: Motion::None,
            retract_to_r: true,
            feed: None,
            feed_zero: false,
            rpm: 0,
            spindle: Spindle::Off,
            coolant: (false, false),
            selected_tool: 0,
            current_tool: 0,
            tool_offsets: [0; AXES],
            tools: opts.tools.clone(),
            g5x: [0; AXES],
            g92: [0; AXES],
            rot_deg: 0.0,
            off: [0; AXES],
            pos: opts.start.map(|v| v.clamp(-MAX_AXIS_UNITS, MAX_AXIS_UNITS)),
            path: PathMode::Blend(None),
            cycle: CycleMemory::default(),
            g5_tangent: None,
            comp: comp::Comp::new(),
            ended: false,
            probes_done: 0,
            waiting: None,
        };
        s.update_position_params();
        s
    }

    /// Has the program ended (M2/M30)?
    pub fn ended(&self) -> bool {
        self.ended
    }

    /// Is the run stopped at a probing move whose outcome it needs (the last command
    /// out)? Nothing after it can be interpreted until the outcome is known.
    pub fn waiting(&self) -> bool {
        self.waiting.is_some()
    }

    /// Executes one line's words, appending commands to `out`.
    pub fn execute(&mut self, w: &mut Words, line: u32, out: &mut Vec<Canon>) -> Res<()> {
        if w.present() == 0
            && w.g.is_empty()
            && w.m.is_empty()
            && w.polar_radius.is_none()
            && w.polar_angle.is_none()
            && w.assigns.is_empty()
            && w.messages.is_empty()
        {
            return Ok(());
        }
        self.check_axes(w)?;
        let mut b = Block {
            line,
            codes: Modal::EMPTY,
            used: bit(b'N') | AXIS_BITS,
            inverse: None,
        };
        b.codes.fill(w)?;
        self.comp.start_line(out);
        if self.comp.on() {
            self.comp_guard(w, &b, true)?;
        }
        // LinuxCNC's order of execution (`Interp::execute_block` and the `convert_*`
        // functions of emc/rs274ngc/interp_convert.cc), with units moved first (see the
        // module doc). Overrides (M48-M53) are refused, so they have no phase.
        // A phase acts only when its codes or words are on the line: the phases that
        // are not inlined are only called then (a line of coordinates calls none of
        // them, a dozen calls fewer per line).
        let groups = b.codes.groups();
        let has = |g: Group| groups & g.bit() != 0;
        if !w.messages.is_empty() {
            self.convert_comments(w, &b, out);
        }
        self.convert_units(&b);
        self.convert_feed_mode(&b);
        self.convert_feed_rate(w, &mut b)?;
        self.convert_speed(w, &mut b, out)?;
        self.convert_tool_select(w, &mut b)?;
        self.convert_tool_change(w, &mut b, out)?;
        if has(Group::Spindle) {
            self.convert_spindle(&b, out);
        }
        if has(Group::Coolant) {
            self.convert_coolant(w, &b, out);
        }
        let nonmodal = has(Group::NonModal);
        if nonmodal {
            self.convert_dwell(w, &mut b, out)?;
        }
        self.convert_plane(&b);
        if has(Group::Cutter) {
            self.convert_cutter_comp(w, &mut b, out)?;
        }
        if self.comp.on() {
            self.comp_guard(w, &b, false)?;
        }
        if has(Group::ToolLength) {
            self.convert_tool_length(w, &mut b)?;
        }
        if has(Group::System) {
            self.convert_coordinate_system(&b)?;
        }
        if has(Group::Path) {
            self.convert_path_mode(w, &mut b, out)?;
        }
        self.convert_distance_mode(&b);
        self.convert_retract_mode(&b);
        if nonmodal {
            self.convert_nonmodal(w, &mut b, out)?;
        }
        self.convert_motion(w, &mut b, out)?;
        self.comp.hold(out);
        if w.present() & !b.used != 0 {
            check_unused(w, &b)?;
        }
        if !w.assigns.is_empty() {
            self.convert_assignments(w)?;
        }
        if has(Group::Stop) {
            self.convert_stop(&b, out)?;
        }
        self.update_position_params();
        Ok(())
    }

    /// The end of the program text: what cutter compensation still holds is emitted.
    pub fn finish(&mut self, out: &mut Vec<Canon>) -> Res<()> {
        self.comp.start_line(out);
        self.comp_stop(true, 1, out)
    }

    /// Length word in the units in force → nm, bounded.
    #[inline(always)]
    pub(crate) fn length(&self, w: Word) -> Res<i64> {
        let per = if self.inch { INCH } else { MM };
        bounded(w.num.times(per), w)
    }

    /// Refuses the leftmost axis word for an axis the machine lacks, naming the axes
    /// it has.
    fn check_axes(&self, w: &Words) -> Res<()> {
        let lacked = (0..AXES)
            .filter(|&i| !self.opts.axes[i])
            .filter_map(|i| w.get(AXIS_NAMES[i] as u8).map(|word| (i, word)))
            .min_by_key(|(_, word)| word.col);
        let Some((i, word)) = lacked else {
            return Ok(());
        };
        let has: Vec<String> = (0..AXES)
            .filter(|&k| self.opts.axes[k])
            .map(|k| AXIS_NAMES[k].to_string())
            .collect();
        fail(
            word.col,
            ErrorKind::NoSuchAxis,
            format!(
                "{}{}: the machine has no {} axis (its axes: {})",
                AXIS_NAMES[i],
                word.num,
                AXIS_NAMES[i],
                if has.is_empty() {
                    "none".into()
                } else {
                    has.join(" ")
                }
            ),
        )
    }

    /// Axis units of axis `i` per parameter unit (mm or inch, see
    /// [`Options::inch_parameters`]; degrees for A B C).
    pub(crate) fn per_user(&self, i: usize) -> i64 {
        if i >= 3 {
            NDEG_PER_DEG
        } else if self.opts.inch_parameters {
            NM_PER_INCH
        } else {
            NM_PER_MM
        }
    }

    /// Axis units of axis `i` → the parameters' units.
    pub(crate) fn to_user(&self, v: i64, i: usize) -> f64 {
        v as f64 / self.per_user(i) as f64
    }

    /// Axis word `i` → axis units (nm, or n° for A B C), bounded.
    #[inline(always)]
    pub(crate) fn axis_value(&self, i: usize, w: Word) -> Res<i64> {
        if i >= 3 {
            bounded(w.num.times(DEGREE), w)
        } else {
            self.length(w)
        }
    }
}

/// Rounds an `f64` position to axis units, bounded.
#[inline(always)]
pub(crate) fn bounded_round(v: f64, col: u32) -> Res<i64> {
    match f64_to_i64(v) {
        Some(u) if u.abs() <= MAX_AXIS_UNITS => Ok(u),
        _ => fail(
            col,
            ErrorKind::InvalidTarget,
            "computed position out of range",
        ),
    }
}

/// A scaled word value inside the bounds, or an error at the word.
#[inline(always)]
pub(crate) fn bounded(v: Option<i64>, w: Word) -> Res<i64> {
    match v {
        Some(u) if u.abs() <= MAX_AXIS_UNITS => Ok(u),
        _ => fail(
            w.col,
            ErrorKind::OutOfRange,
            format!("value {} out of range", w.num),
        ),
    }
}

/// A position for axis `i` inside the bounds.
#[inline(always)]
pub(crate) fn check_range(v: i64, i: usize, col: u32) -> Res<i64> {
    if v.abs() <= MAX_AXIS_UNITS {
        Ok(v)
    } else {
        fail(
            col,
            ErrorKind::InvalidTarget,
            format!("{} position out of range", AXIS_NAMES[i]),
        )
    }
}

/// A whole number within `lo..=hi`.
pub(crate) fn whole_in(w: Word, lo: i64, hi: i64, what: &str) -> Res<i64> {
    let kind = match w.num.whole() {
        Some(v) if (lo..=hi).contains(&v) => return Ok(v),
        None => ErrorKind::NotInteger,
        Some(v) if v < 0 && lo >= 0 => ErrorKind::Negative,
        Some(_) => ErrorKind::OutOfRange,
    };
    fail(
        w.col,
        kind,
        format!(
            "{what} must be a whole number from {lo} to {hi}, not {}",
            w.num
        ),
    )
}

/// A dwell time P, seconds → ms (G4, and the dwell of G82/G89).
pub(crate) fn dwell_ms(p: Word) -> Res<u32> {
    if p.num.is_negative() {
        return fail(
            p.col,
            ErrorKind::Negative,
            format!("negative dwell time P{}", p.num),
        );
    }
    p.num
        .scaled(1000, 1)
        .and_then(|v| u32::try_from(v).ok())
        .ok_or_else(|| {
            LineError::boxed(
                p.col,
                ErrorKind::OutOfRange,
                format!("dwell time P{} s out of range", p.num),
            )
        })
}
