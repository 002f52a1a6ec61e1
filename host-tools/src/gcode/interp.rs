//! Modal interpreter: applies one line's [`Words`] to the modal state and emits
//! [`Canon`] commands.
//!
//! Order of execution within a line (LinuxCNC's, with one deliberate change): comments
//! and messages; units G20/G21 (moved first, so that every number on a line with G20 is
//! read in inches: `G20 F10` is 10 in/min, where LinuxCNC would read the F in the old
//! units); feed mode G93/G94; F; S; T; M6/M61; M3/M4/M5; M7/M8/M9; G4 dwell; plane;
//! cutter compensation G40; tool length G43/G49; coordinate system G54–G59.3; path
//! control G61/G61.1/G64; distance modes G90/G91 and G90.1/G91.1; retract mode
//! G98/G99; G10/G28/G30/G92 and friends; motion (G0 G1 G2 G3 G73 G81–G89, or the modal
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

use super::arcs;
use super::lexer::{bit, Code, ParamRef, Word, Words};
use super::params::{self, Params};
use super::{unsupported, Options, MAX_AXIS_UNITS};
use crate::gcode::canon::{Canon, Coolant, Feed, PathMode, Plane, Spindle};
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
    /// What is wrong.
    pub message: String,
}

pub(crate) type Res<T> = Result<T, LineError>;

pub(crate) fn fail<T>(col: u32, message: impl Into<String>) -> Res<T> {
    Err(LineError {
        col,
        message: message.into(),
    })
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
    /// A canned cycle.
    Cycle(Cycle),
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

// Modal groups of G codes, as slots of `group_g`.
const NONMODAL: usize = 0;
const MOTION: usize = 1;
const PLANE: usize = 2;
const DISTANCE: usize = 3;
const ARC_DISTANCE: usize = 4;
const FEED_MODE: usize = 5;
const UNITS: usize = 6;
const CUTTER: usize = 7;
const TOOL_LENGTH: usize = 8;
const RETRACT: usize = 9;
const SYSTEM: usize = 10;
const PATH: usize = 11;
const SPINDLE_MODE: usize = 12;
const LATHE_MODE: usize = 13;
const G_GROUPS: usize = 14;
const G_GROUP_NAMES: [&str; G_GROUPS] = [
    "non-modal",
    "motion",
    "plane",
    "distance-mode",
    "arc-distance-mode",
    "feed-mode",
    "units",
    "cutter-compensation",
    "tool-length-offset",
    "canned-cycle-return",
    "coordinate-system",
    "path-control",
    "spindle-speed-mode",
    "lathe-diameter-mode",
];

// Modal groups of M codes.
const STOP: usize = 0;
const TOOL_CHANGE: usize = 1;
const SPINDLE: usize = 2;
const COOLANT: usize = 3;
const M_GROUPS: usize = 4;
const M_GROUP_NAMES: [&str; M_GROUPS] = ["stopping", "tool-change", "spindle", "coolant"];

/// The axis letters' bits.
const AXIS_BITS: u32 = bit(b'X') | bit(b'Y') | bit(b'Z') | bit(b'A') | bit(b'B') | bit(b'C');

/// `G28.1` from ten times the number.
pub(crate) fn code_name(letter: char, tenths: i32) -> String {
    if tenths % 10 == 0 {
        format!("{letter}{}", tenths / 10)
    } else {
        format!("{letter}{}.{}", tenths / 10, tenths % 10)
    }
}

/// The modal group of a G code, or why it is refused.
fn g_group(tenths: i32) -> Result<usize, String> {
    Ok(match tenths {
        0 | 10 | 20 | 30 | 730 | 800 | 810 | 820 | 830 | 850 | 890 => MOTION,
        170 | 180 | 190 => PLANE,
        900 | 910 => DISTANCE,
        901 | 911 => ARC_DISTANCE,
        930 | 940 => FEED_MODE,
        200 | 210 => UNITS,
        400 => CUTTER,
        430 | 490 => TOOL_LENGTH,
        980 | 990 => RETRACT,
        540 | 550 | 560 | 570 | 580 | 590 | 591 | 592 | 593 => SYSTEM,
        610 | 611 | 640 => PATH,
        40 | 100 | 280 | 281 | 300 | 301 | 530 | 920 | 921 | 922 | 923 => NONMODAL,
        970 => SPINDLE_MODE,
        80 => LATHE_MODE,
        _ => {
            let feature = match tenths {
                50 => "G5 cubic splines",
                51 => "G5.1 quadratic B-splines",
                52 => "G5.2 NURBS blocks",
                53 => "G5.3 NURBS blocks",
                70 => "G7 lathe diameter mode",
                171 | 181 | 191 => "G17.1 G18.1 G19.1 (UVW planes)",
                330 | 331 => "G33 spindle-synchronized motion",
                382..=385 => "G38 probing",
                410 | 411 | 420 | 421 => "G41/G42 cutter radius compensation",
                431 => "G43.1 dynamic tool length offset",
                432 => "G43.2 additional tool length offset",
                520 => "G52 local coordinate offsets",
                700 | 710 | 711 | 712 | 720 | 721 | 722 => "G70-G72 lathe cycles",
                740 | 840 => "G74/G84 tapping cycles",
                760 => "G76 threading cycle",
                860 | 870 | 880 => "G86-G88 boring cycles",
                950 => "G95 feed per revolution",
                960 => "G96 constant surface speed",
                _ => return Err(format!("unknown code {}", code_name('G', tenths))),
            };
            return Err(unsupported(feature));
        }
    })
}

/// The modal group of an M code, or why it is refused.
fn m_group(tenths: i32) -> Result<usize, String> {
    Ok(match tenths {
        0 | 10 | 20 | 300 => STOP,
        60 | 610 => TOOL_CHANGE,
        30 | 40 | 50 => SPINDLE,
        70 | 80 | 90 => COOLANT,
        _ => {
            let feature = match tenths {
                190 => "M19 spindle orientation",
                480..=530 => "M48-M53 override control",
                600 => "M60 pallet change",
                620..=680 => "M62-M68 digital and analog I/O",
                700..=730 => "M70-M73 modal state save and restore",
                1000..=1990 => "M100-M199 user-defined M codes",
                980 | 990 => "M98/M99 subprogram calls (Fanuc style)",
                270 => "M27 (a machine-specific code some posts write; not in LinuxCNC)",
                _ => return Err(format!("unknown code {}", code_name('M', tenths))),
            };
            return Err(unsupported(feature));
        }
    })
}

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
    selected_tool: u32,
    current_tool: u32,
    tool_length: i64,
    g5x: [i64; AXES],
    g92: [i64; AXES],
    pub(crate) off: [i64; AXES],
    pub(crate) pos: [i64; AXES],
    pub(crate) path: PathMode,
    pub(crate) cycle: CycleMemory,
    ended: bool,
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
            selected_tool: 0,
            current_tool: 0,
            tool_length: 0,
            g5x: [0; AXES],
            g92: [0; AXES],
            off: [0; AXES],
            pos: opts.start.map(|v| v.clamp(-MAX_AXIS_UNITS, MAX_AXIS_UNITS)),
            path: PathMode::Blend(None),
            cycle: CycleMemory::default(),
            ended: false,
        };
        s.update_position_params();
        s
    }

    /// Has the program ended (M2/M30)?
    pub fn ended(&self) -> bool {
        self.ended
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
        let g = if w.g.is_empty() {
            [None; G_GROUPS]
        } else {
            group_g(&w.g)?
        };
        let m = if w.m.is_empty() {
            [None; M_GROUPS]
        } else {
            group_m(&w.m)?
        };
        let mut used = bit(b'N') | AXIS_BITS;

        if !w.messages.is_empty() {
            for text in w.messages.drain(..) {
                out.push(Canon::Message { line, text });
            }
        }
        if let Some(c) = g[UNITS] {
            self.inch = c.tenths == 200;
        }
        if let Some(c) = g[FEED_MODE] {
            let inverse = c.tenths == 930;
            if inverse != self.inverse_time {
                // F must be given again in the new mode.
                self.feed = None;
            }
            self.inverse_time = inverse;
        }
        let mut line_inverse = None;
        if let Some(f) = w.get(b'F') {
            used |= bit(b'F');
            if self.inverse_time {
                line_inverse = Some(inverse_time_us(f)?);
            } else if f.num.is_zero() {
                // F0 is accepted where nothing moves at feed (LinuxCNC does); a feed
                // move at F0 is the error, named there.
                self.feed = None;
                self.feed_zero = true;
            } else {
                self.feed = Some(self.feed_rate(f)?);
                self.feed_zero = false;
            }
        }
        if let Some(s) = w.get(b'S') {
            used |= bit(b'S');
            self.rpm = spindle_rpm(s)?;
            if m[SPINDLE].is_none() {
                let state = match self.spindle {
                    Spindle::Off => None,
                    Spindle::Clockwise(_) => Some(Spindle::Clockwise(self.rpm)),
                    Spindle::CounterClockwise(_) => Some(Spindle::CounterClockwise(self.rpm)),
                };
                if let Some(state) = state.filter(|&s| s != self.spindle) {
                    self.spindle = state;
                    out.push(Canon::Spindle { line, state });
                }
            }
        }
        if let Some(t) = w.get(b'T') {
            used |= bit(b'T');
            self.selected_tool = whole_in(t, 0, i64::from(u32::MAX), "tool number T")? as u32;
        }
        if let Some(c) = m[TOOL_CHANGE] {
            if c.tenths == 60 {
                out.push(Canon::ToolChange {
                    line,
                    tool: self.selected_tool,
                });
                self.current_tool = self.selected_tool;
            } else {
                used |= bit(b'Q');
                let Some(q) = w.get(b'Q') else {
                    return fail(c.col, "M61 needs Q (the tool now in the spindle)");
                };
                self.current_tool = whole_in(q, 0, i64::from(u32::MAX), "tool number Q")? as u32;
            }
            self.update_tool_params();
        }
        if let Some(c) = m[SPINDLE] {
            let state = match c.tenths {
                30 => Spindle::Clockwise(self.rpm),
                40 => Spindle::CounterClockwise(self.rpm),
                _ => Spindle::Off,
            };
            self.spindle = state;
            out.push(Canon::Spindle { line, state });
        }
        if m[COOLANT].is_some() {
            for c in &w.m {
                let state = match c.tenths {
                    70 => Coolant::Mist,
                    80 => Coolant::Flood,
                    90 => Coolant::Off,
                    _ => continue,
                };
                out.push(Canon::Coolant { line, state });
            }
        }
        let nonmodal = g[NONMODAL];
        if let Some(c) = nonmodal.filter(|c| c.tenths == 40) {
            used |= bit(b'P');
            let Some(p) = w.get(b'P') else {
                return fail(c.col, "G4 needs P (dwell time, seconds)");
            };
            if p.num.is_negative() {
                return fail(p.col, format!("negative dwell time P{}", p.num));
            }
            let ms = p
                .num
                .scaled(1000, 1)
                .and_then(|v| u32::try_from(v).ok())
                .ok_or_else(|| LineError {
                    col: p.col,
                    message: format!("dwell time P{} s out of range", p.num),
                })?;
            out.push(Canon::Dwell { line, ms });
        }
        if let Some(c) = g[PLANE] {
            self.plane = match c.tenths {
                170 => Plane::Xy,
                180 => Plane::Zx,
                _ => Plane::Yz,
            };
        }
        if let Some(c) = g[TOOL_LENGTH] {
            if c.tenths == 430 {
                used |= bit(b'H');
                let n = match w.get(b'H') {
                    Some(h) => whole_in(h, 0, i64::from(u32::MAX), "tool number H")? as u32,
                    None => self.current_tool,
                };
                self.tool_length = match self.opts.tools.get(n) {
                    Some(t) => t.length_nm,
                    None if n == 0 => 0,
                    None => {
                        let at = w.get(b'H').map_or(c.col, |h| h.col);
                        return fail(at, format!("G43: tool {n} is not in the tool table"));
                    }
                };
            } else {
                self.tool_length = 0;
            }
            self.update_tool_params();
            self.refresh_offsets(c.col)?;
        }
        if let Some(c) = g[SYSTEM] {
            let n = match c.tenths {
                540 => 1,
                550 => 2,
                560 => 3,
                570 => 4,
                580 => 5,
                590 => 6,
                591 => 7,
                592 => 8,
                _ => 9,
            };
            self.params
                .set_numbered(params::CURRENT_SYSTEM, f64::from(n));
            self.refresh_offsets(c.col)?;
        }
        if let Some(c) = g[PATH] {
            let mode = if c.tenths == 640 {
                used |= bit(b'P') | bit(b'Q');
                match w.get(b'P') {
                    Some(p) => {
                        if p.num.is_negative() {
                            return fail(p.col, format!("negative blending tolerance P{}", p.num));
                        }
                        PathMode::Blend(Some(self.length(p)?))
                    }
                    None => PathMode::Blend(None),
                }
            } else {
                PathMode::ExactStop
            };
            self.path = mode;
            out.push(Canon::PathMode { line, mode });
        }
        if let Some(c) = g[DISTANCE] {
            self.absolute = c.tenths == 900;
        }
        if let Some(c) = g[ARC_DISTANCE] {
            self.arc_absolute = c.tenths == 901;
        }
        if let Some(c) = g[RETRACT] {
            self.retract_to_r = c.tenths == 990;
        }

        let has_axes = w.present() & AXIS_BITS != 0;
        let has_polar = w.polar_radius.is_some() || w.polar_angle.is_some();
        let nm_axes = nonmodal.filter(|c| matches!(c.tenths, 100 | 280 | 300 | 920));
        let g53 = nonmodal.filter(|c| c.tenths == 530);
        if let Some(c) = nonmodal {
            match c.tenths {
                100 => self.g10(w, c, &mut used)?,
                280 | 300 => self.home(w, c, line, out)?,
                281 | 301 => {
                    let base = if c.tenths == 281 {
                        params::G28_POSITION
                    } else {
                        params::G30_POSITION
                    };
                    for i in 0..AXES {
                        self.params.set_numbered(base + i, to_user(self.pos[i], i));
                    }
                }
                920 => self.g92(w, c)?,
                921..=923 => {
                    if c.tenths == 923 {
                        self.params.set_numbered(params::G92_ACTIVE, 1.0);
                    } else {
                        self.params.set_numbered(params::G92_ACTIVE, 0.0);
                        if c.tenths == 921 {
                            for i in 0..AXES {
                                self.params.set_numbered(params::G92_OFFSETS + i, 0.0);
                            }
                        }
                    }
                    self.refresh_offsets(c.col)?;
                }
                _ => {}
            }
        }

        let explicit = g[MOTION];
        if let (Some(c), Some(n)) = (explicit.filter(|c| c.tenths != 800), nm_axes) {
            return fail(
                c.col,
                format!(
                    "{} and {} on one line: both would use the axis words",
                    code_name('G', c.tenths),
                    code_name('G', n.tenths)
                ),
            );
        }
        let previous = self.motion;
        if let Some(c) = explicit {
            self.motion = match c.tenths {
                0 => Motion::Rapid,
                10 => Motion::Linear,
                20 => Motion::Arc { clockwise: true },
                30 => Motion::Arc { clockwise: false },
                730 => Motion::Cycle(Cycle::G73),
                810 => Motion::Cycle(Cycle::G81),
                820 => Motion::Cycle(Cycle::G82),
                830 => Motion::Cycle(Cycle::G83),
                850 => Motion::Cycle(Cycle::G85),
                890 => Motion::Cycle(Cycle::G89),
                _ => Motion::None,
            };
        }
        if !matches!(self.motion, Motion::Cycle(_)) {
            self.cycle.initial_level = None;
        }
        let ijk = w.present() & (bit(b'I') | bit(b'J') | bit(b'K')) != 0;
        let run = nm_axes.is_none()
            && match explicit {
                Some(_) => match self.motion {
                    Motion::None | Motion::Rapid | Motion::Linear => has_axes || has_polar,
                    Motion::Arc { .. } | Motion::Cycle(_) => true,
                },
                None => has_axes || has_polar || (ijk && matches!(self.motion, Motion::Arc { .. })),
            };
        let first_motion_col = w.first_motion_col.max(1);
        if nm_axes.is_some() && has_polar {
            let at = w.polar_radius.or(w.polar_angle).map_or(1, |p| p.col);
            return fail(at, "polar coordinates (@ ^) only go with motion");
        }
        if let Some(c) = g53 {
            let ok = run && matches!(self.motion, Motion::Rapid | Motion::Linear);
            if !ok {
                return fail(
                    c.col,
                    "G53 needs G0 or G1 (on its line or in force) and axis words",
                );
            }
            if !self.absolute {
                return fail(c.col, "G53 needs absolute distance mode (G90)");
            }
            if has_polar {
                return fail(c.col, "G53 cannot take polar coordinates (@ ^)");
            }
        }
        if run {
            let col = explicit.map_or(first_motion_col, |c| c.col);
            match self.motion {
                Motion::None => {
                    let what = if explicit.is_some() {
                        "G80 cancels the motion mode: its line cannot move"
                    } else {
                        "coordinates without a motion mode (G0, G1, G2, G3 or a canned cycle)"
                    };
                    return fail(first_motion_col, what);
                }
                Motion::Rapid => {
                    let t = self.target(w, g53.is_some())?;
                    self.rapid(line, t, out);
                }
                Motion::Linear => {
                    let t = self.target(w, g53.is_some())?;
                    let feed = self.feed_for(&t, false, line_inverse, "G1", col)?;
                    out.push(Canon::Linear {
                        line,
                        target: t,
                        feed,
                    });
                    self.pos = t;
                }
                Motion::Arc { clockwise } => {
                    used |= bit(b'I') | bit(b'J') | bit(b'K') | bit(b'R') | bit(b'P');
                    self.arc(w, clockwise, line, line_inverse, col, out)?;
                }
                Motion::Cycle(kind) => {
                    used |= bit(b'R') | bit(b'L') | bit(b'P') | bit(b'Q');
                    self.cycle(w, kind, previous, line, col, out)?;
                }
            }
        }
        if nonmodal.is_some_and(|c| c.tenths == 100) {
            used |= bit(b'L') | bit(b'P') | bit(b'R');
        }
        let unused = w.present() & !used;
        if unused != 0 {
            let at = first_col(w, unused);
            let letter = (b'A'..=b'Z')
                .find(|&l| unused & bit(l) != 0 && w.get(l).is_some_and(|x| x.col == at))
                .unwrap_or(b'?');
            return fail(
                at,
                format!(
                    "{} word with no G or M code on its line that uses it",
                    letter as char
                ),
            );
        }
        if !w.assigns.is_empty() {
            self.apply_assigns(w)?;
        }
        // Stops last: after the line's motion, and only once nothing on it can fail.
        if let Some(c) = m[STOP] {
            match c.tenths {
                0 | 10 => out.push(Canon::Pause {
                    line,
                    optional: c.tenths == 10,
                }),
                _ => {
                    out.push(Canon::End { line });
                    self.ended = true;
                }
            }
        }
        self.update_position_params();
        Ok(())
    }

    /// Applies the line's parameter settings, in order.
    fn apply_assigns(&mut self, w: &mut Words) -> Res<()> {
        let mut refresh = None;
        for a in w.assigns.drain(..) {
            match a.target {
                ParamRef::Numbered(n) => {
                    if n >= params::READ_ONLY_FROM {
                        return fail(a.col, format!("parameter #{n} is read-only"));
                    }
                    if n == params::CURRENT_SYSTEM
                        && !(a.value.fract() == 0.0 && (1.0..=9.0).contains(&a.value))
                    {
                        return fail(
                            a.col,
                            format!(
                                "parameter #{n} (the coordinate system in force) takes 1 to 9 \
                                 (G54 to G59.3), not {}",
                                a.value
                            ),
                        );
                    }
                    if (params::G92_ACTIVE..params::READ_ONLY_FROM).contains(&n) {
                        refresh = Some(a.col);
                    }
                    self.params.set_numbered(n, a.value);
                }
                ParamRef::Named(name) => {
                    if params::Params::read_only_name(&name) {
                        return fail(
                            a.col,
                            format!(
                                "parameter #<{}> is read-only (LinuxCNC maintains it)",
                                String::from_utf8_lossy(&name)
                            ),
                        );
                    }
                    self.params.set_named(&name, a.value)
                }
            }
        }
        match refresh {
            Some(col) => self.refresh_offsets(col),
            None => Ok(()),
        }
    }

    /// Length word in the units in force → nm, bounded.
    #[inline]
    pub(crate) fn length(&self, w: Word) -> Res<i64> {
        let per = if self.inch { NM_PER_INCH } else { NM_PER_MM };
        bounded(w.num.scaled(per, 1), w)
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

    /// Axis word `i` → axis units (nm, or n° for A B C), bounded.
    #[inline]
    pub(crate) fn axis_value(&self, i: usize, w: Word) -> Res<i64> {
        if i >= 3 {
            bounded(w.num.scaled(NDEG_PER_DEG, 1), w)
        } else {
            self.length(w)
        }
    }

    /// End pose of a straight move from the axis and polar words.
    pub(crate) fn target(&self, w: &Words, machine: bool) -> Res<[i64; AXES]> {
        let mut t = self.pos;
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
        Ok(t)
    }

    /// Program X Y from the polar words `@` (radius) and `^` (angle, degrees) and the
    /// current program X Y, as LinuxCNC: absolute words measure from the origin; in G91
    /// `@` adds to the current distance from the origin and `^` to the current angle.
    pub(crate) fn polar(&self, w: &Words, x: i64, y: i64) -> Res<(i64, i64)> {
        let col = w.polar_radius.or(w.polar_angle).map_or(1, |p| p.col);
        if self.plane != Plane::Xy {
            return fail(col, "polar coordinates (@ ^) need the XY plane (G17)");
        }
        if let Some(xy) = w.get(b'X').or(w.get(b'Y')) {
            return fail(xy.col, "polar coordinates (@ ^) and X or Y on one line");
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
                    return fail(col, "@ without ^ at the origin: the angle is undefined")
                }
                None => yf.atan2(xf),
            };
            (r, theta)
        } else {
            if at_origin {
                return fail(
                    col,
                    "incremental polar motion (G91 @ ^) is undefined at the origin",
                );
            }
            (
                xf.hypot(yf) + radius.map_or(0.0, |r| r.0),
                yf.atan2(xf) + angle.map_or(0.0, |a| a.0),
            )
        };
        let px = pkmc_round(r * theta.cos(), col)?;
        let py = pkmc_round(r * theta.sin(), col)?;
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
                    format!("{code} in inverse-time mode (G93) needs F on its line"),
                ),
            };
        }
        let Some(f) = self.feed else {
            if self.feed_zero {
                return fail(
                    col,
                    format!("{code} at feed F0: a feed move needs F above zero"),
                );
            }
            return fail(col, format!("{code} without a feed (F)"));
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
    fn feed_rate(&self, f: Word) -> Res<FeedRate> {
        if f.num.is_negative() || f.num.is_zero() {
            return fail(f.col, format!("feed F{} must be above zero", f.num));
        }
        let per = if self.inch { NM_PER_INCH } else { NM_PER_MM };
        let range = |v: Option<i64>| match v {
            Some(v) if (1..=MAX_AXIS_UNITS).contains(&v) => Ok(v),
            Some(v) if v < 1 => fail(f.col, format!("feed F{} too small", f.num)),
            _ => fail(f.col, format!("feed F{} out of range", f.num)),
        };
        Ok(FeedRate {
            linear: range(f.num.scaled(per, 60))?,
            rotary: range(f.num.scaled(1_000_000, 60))?,
        })
    }

    /// A G2/G3 move.
    fn arc(
        &mut self,
        w: &Words,
        clockwise: bool,
        line: u32,
        line_inverse: Option<u64>,
        col: u32,
        out: &mut Vec<Canon>,
    ) -> Res<()> {
        let end = self.target(w, false)?;
        let done = self.arc_to(end, w, clockwise, line, line_inverse, col, out);
        if done.is_err() {
            // A refused arc still ends where it was programmed to: later lines (their
            // G91 moves, their arc centres) start there, so one bad arc is one message,
            // not a cascade of knock-on errors.
            self.pos = end;
        }
        done
    }

    #[allow(clippy::too_many_arguments)]
    fn arc_to(
        &mut self,
        end: [i64; AXES],
        w: &Words,
        clockwise: bool,
        line: u32,
        line_inverse: Option<u64>,
        col: u32,
        out: &mut Vec<Canon>,
    ) -> Res<()> {
        let name = if clockwise { "G2" } else { "G3" };
        let (a, b, h) = self.plane.axes();
        let offset_letter = |axis: usize| b"IJK"[axis];
        let plane_name = match self.plane {
            Plane::Xy => "XY plane (G17)",
            Plane::Zx => "XZ plane (G18)",
            Plane::Yz => "YZ plane (G19)",
        };
        if let Some(k) = w.get(offset_letter(h)) {
            return fail(
                k.col,
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
                    format!("{name} with both a radius (R) and a centre (I J K)"),
                )
            }
            (None, false) => {
                return fail(
                    col,
                    format!("{name} without a centre (I J K) or a radius (R)"),
                )
            }
            (Some(r), false) => {
                let radius = self.length(r)?;
                if radius == 0 {
                    return fail(r.col, format!("{name} with radius R0"));
                }
                let c = arcs::centre_from_radius(s, e, radius as f64, clockwise, tol)
                    .map_err(|m| LineError { col, message: m })?;
                [pkmc_round(c[0], col)?, pkmc_round(c[1], col)?]
            }
            (None, true) => {
                let mut c = [0i64; 2];
                for (k, (axis, word)) in [(a, wa), (b, wb)].into_iter().enumerate() {
                    let v = match word {
                        Some(word) => self.length(word)?,
                        None if self.arc_absolute => {
                            return fail(
                                col,
                                format!(
                                    "{} word missing for an absolute centre (G90.1)",
                                    offset_letter(axis) as char
                                ),
                            )
                        }
                        None => 0,
                    };
                    let base = if self.arc_absolute {
                        self.off[axis]
                    } else {
                        start[axis]
                    };
                    c[k] = check_range(base + v, axis, word.map_or(col, |x| x.col))?;
                }
                let abs = if self.inch {
                    arcs::CENTRE_ARC_ABS_NM_INCH
                } else {
                    arcs::CENTRE_ARC_ABS_NM_MM
                };
                arcs::check_end(s, e, [c[0] as f64, c[1] as f64], abs)
                    .map_err(|m| LineError { col, message: m })?;
                c
            }
        };
        let radius = (s[0] - centre[0] as f64).hypot(s[1] - centre[1] as f64);
        if radius > pkmc::geometry::MAX_ARC_RADIUS_NM as f64 {
            let at = w.get(b'R').map_or(col, |r| r.col);
            return fail(
                at,
                format!(
                    "{name} with a radius of {:.3} mm: larger than the {} mm the controller \
                     interpolates exactly",
                    radius * 1e-6,
                    pkmc::geometry::MAX_ARC_RADIUS_NM / 1_000_000
                ),
            );
        }
        let turns = match w.get(b'P') {
            Some(p) => (whole_in(p, 1, i64::from(u32::MAX), "turns P")? - 1) as u32,
            None => 0,
        };
        let feed = self.feed_for(&end, true, line_inverse, name, col)?;
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
        Ok(())
    }

    /// G28 / G30: rapid through the intermediate point (if axis words are given) to the
    /// stored position (only the axes named, or all of them).
    fn home(&mut self, w: &Words, c: Code, line: u32, out: &mut Vec<Canon>) -> Res<()> {
        let base = if c.tenths == 280 {
            params::G28_POSITION
        } else {
            params::G30_POSITION
        };
        let mut stored = [0i64; AXES];
        for (i, s) in stored.iter_mut().enumerate() {
            *s = self.param_units(base + i, i, c.col)?;
        }
        if w.present() & AXIS_BITS == 0 {
            self.rapid(line, stored, out);
            return Ok(());
        }
        let mid = self.target(w, false)?;
        self.rapid(line, mid, out);
        let mut end = mid;
        for (i, e) in end.iter_mut().enumerate() {
            if w.get(AXIS_NAMES[i] as u8).is_some() {
                *e = stored[i];
            }
        }
        self.rapid(line, end, out);
        Ok(())
    }

    /// G92: offsets that make the current point have the given coordinates.
    fn g92(&mut self, w: &Words, c: Code) -> Res<()> {
        if w.present() & AXIS_BITS == 0 {
            return fail(c.col, "G92 needs axis words");
        }
        for (i, &letter) in AXIS_NAMES.iter().enumerate() {
            let Some(word) = w.get(letter as u8) else {
                continue;
            };
            let v = self.axis_value(i, word)?;
            let o = check_range(
                self.pos[i] - self.g5x[i] - self.tool_offset(i) - v,
                i,
                word.col,
            )?;
            self.params
                .set_numbered(params::G92_OFFSETS + i, to_user(o, i));
        }
        // Axes not named keep their offsets (active ones, as stored).
        for (i, &letter) in AXIS_NAMES.iter().enumerate() {
            if w.get(letter as u8).is_none() {
                self.params
                    .set_numbered(params::G92_OFFSETS + i, to_user(self.g92[i], i));
            }
        }
        self.params.set_numbered(params::G92_ACTIVE, 1.0);
        self.refresh_offsets(c.col)
    }

    /// G10 L2 / L20: set a coordinate system's offsets.
    fn g10(&mut self, w: &Words, c: Code, used: &mut u32) -> Res<()> {
        *used |= bit(b'L') | bit(b'P') | bit(b'R');
        let Some(l) = w.get(b'L') else {
            return fail(c.col, "G10 needs L2 or L20");
        };
        let l20 = match l.num.whole() {
            Some(2) => false,
            Some(20) => true,
            Some(1 | 10 | 11) => {
                return fail(l.col, unsupported("G10 L1/L10/L11 tool table editing"))
            }
            _ => return fail(l.col, format!("G10 L{}: only L2 and L20 exist here", l.num)),
        };
        let Some(p) = w.get(b'P') else {
            return fail(
                c.col,
                "G10 L2/L20 needs P (coordinate system 1-9, 0 for the current)",
            );
        };
        let mut n = whole_in(p, 0, 9, "coordinate system P")? as usize;
        if n == 0 {
            n = self.system();
        }
        if let Some(r) = w.get(b'R') {
            if !r.num.is_zero() {
                return fail(r.col, unsupported("coordinate system rotation (G10 L2 R)"));
            }
        }
        if w.polar_radius.is_some() || w.polar_angle.is_some() {
            return fail(c.col, "G10 cannot take polar coordinates (@ ^)");
        }
        let base = params::SYSTEM_BASE + 20 * (n - 1);
        for (i, &letter) in AXIS_NAMES.iter().enumerate() {
            let Some(word) = w.get(letter as u8) else {
                continue;
            };
            let v = self.axis_value(i, word)?;
            let o = if l20 {
                check_range(
                    self.pos[i] - self.g92[i] - self.tool_offset(i) - v,
                    i,
                    word.col,
                )?
            } else {
                v
            };
            self.params.set_numbered(base + i, to_user(o, i));
        }
        self.refresh_offsets(c.col)
    }

    /// Coordinate system in force, 1–9.
    fn system(&self) -> usize {
        (self.params.numbered(params::CURRENT_SYSTEM) as usize).clamp(1, 9)
    }

    fn tool_offset(&self, i: usize) -> i64 {
        if i == 2 {
            self.tool_length
        } else {
            0
        }
    }

    /// Parameter `n` (mm or degrees for axis `i`) in axis units, bounded.
    fn param_units(&self, n: usize, i: usize, col: u32) -> Res<i64> {
        let v = self.params.numbered(n);
        let per = if i >= 3 { NDEG_PER_DEG } else { NM_PER_MM };
        match super::lexer::f64_to_i64(v * per as f64) {
            Some(u) if u.abs() <= MAX_AXIS_UNITS => Ok(u),
            _ => fail(col, format!("parameter #{n} = {v} out of range")),
        }
    }

    /// Recomputes the offsets in force from the parameters and the tool length.
    fn refresh_offsets(&mut self, col: u32) -> Res<()> {
        let base = params::SYSTEM_BASE + 20 * (self.system() - 1);
        let g92_active = self.params.numbered(params::G92_ACTIVE) != 0.0;
        for i in 0..AXES {
            self.g5x[i] = self.param_units(base + i, i, col)?;
            self.g92[i] = if g92_active {
                self.param_units(params::G92_OFFSETS + i, i, col)?
            } else {
                0
            };
            self.off[i] = self.g5x[i] + self.g92[i] + self.tool_offset(i);
        }
        Ok(())
    }

    fn update_tool_params(&mut self) {
        let p = &mut self.params;
        p.set_numbered(params::TOOL_NUMBER, f64::from(self.current_tool));
        p.set_numbered(params::TOOL_LENGTH, to_user(self.tool_length, 2));
        let d = self
            .opts
            .tools
            .get(self.current_tool)
            .map_or(0, |t| t.diameter_nm);
        p.set_numbered(params::TOOL_DIAMETER, to_user(d, 0));
    }

    /// #5420–#5425: the current position in program units (computed when read).
    fn update_position_params(&mut self) {
        for i in 0..AXES {
            self.params.position[i] = self.pos[i] - self.off[i];
        }
        self.params.inch = self.inch;
    }
}

/// Axis units → mm or degrees, for parameters.
fn to_user(v: i64, i: usize) -> f64 {
    if i >= 3 {
        v as f64 / NDEG_PER_DEG as f64
    } else {
        v as f64 / NM_PER_MM as f64
    }
}

/// Rounds an `f64` position to axis units, bounded.
#[inline]
fn pkmc_round(v: f64, col: u32) -> Res<i64> {
    match super::lexer::f64_to_i64(v) {
        Some(u) if u.abs() <= MAX_AXIS_UNITS => Ok(u),
        _ => fail(col, "computed position out of range"),
    }
}

#[inline]
fn bounded(v: Option<i64>, w: Word) -> Res<i64> {
    match v {
        Some(u) if u.abs() <= MAX_AXIS_UNITS => Ok(u),
        _ => fail(w.col, format!("value {} out of range", w.num)),
    }
}

/// A position for axis `i` inside the bounds.
#[inline]
pub(crate) fn check_range(v: i64, i: usize, col: u32) -> Res<i64> {
    if v.abs() <= MAX_AXIS_UNITS {
        Ok(v)
    } else {
        fail(col, format!("{} position out of range", AXIS_NAMES[i]))
    }
}

/// A whole number within `lo..=hi`.
pub(crate) fn whole_in(w: Word, lo: i64, hi: i64, what: &str) -> Res<i64> {
    match w.num.whole() {
        Some(v) if (lo..=hi).contains(&v) => Ok(v),
        _ => fail(
            w.col,
            format!(
                "{what} must be a whole number from {lo} to {hi}, not {}",
                w.num
            ),
        ),
    }
}

/// G93 F: the move takes 1/F minutes → µs.
fn inverse_time_us(f: Word) -> Res<u64> {
    if f.num.is_negative() || f.num.is_zero() {
        return fail(
            f.col,
            format!("inverse-time feed F{} must be above zero", f.num),
        );
    }
    let us = 60e6 / f.num.to_f64();
    match super::lexer::f64_to_i64(us) {
        Some(v) if v >= 1 => Ok(v as u64),
        _ => fail(f.col, format!("inverse-time feed F{} out of range", f.num)),
    }
}

/// Column of the leftmost word among `mask` (and the polar words), or 1.
fn first_col(w: &Words, mask: u32) -> u32 {
    let mut col = u32::MAX;
    let mut bits = w.present() & mask;
    while bits != 0 {
        let letter = b'A' + bits.trailing_zeros() as u8;
        bits &= bits - 1;
        if let Some(x) = w.get(letter) {
            col = col.min(x.col);
        }
    }
    for p in [w.polar_radius, w.polar_angle].into_iter().flatten() {
        col = col.min(p.col);
    }
    if col == u32::MAX {
        1
    } else {
        col
    }
}

/// S in rpm: any number from 0 to 2³² − 1, kept to the nearest whole rpm (posts write
/// S4696.94; LinuxCNC takes it as written, the spindle output resolves whole rpm).
fn spindle_rpm(s: Word) -> Res<u32> {
    let v = s.num.to_f64();
    if !(0.0..=f64::from(u32::MAX)).contains(&v) {
        return fail(
            s.col,
            format!("spindle speed S{} must be from 0 to 4294967295 rpm", s.num),
        );
    }
    Ok(v.round() as u32)
}

/// G codes by modal group; conflicts and refusals are errors.
fn group_g(codes: &[Code]) -> Res<[Option<Code>; G_GROUPS]> {
    let mut g: [Option<Code>; G_GROUPS] = [None; G_GROUPS];
    for &c in codes {
        let group = g_group(c.tenths).map_err(|m| LineError {
            col: c.col,
            message: m,
        })?;
        if let Some(first) = g[group] {
            // G80 with another motion code on one line is allowed (LinuxCNC's safety
            // lines `G0 G17 G40 G49 G80 G90`): the other code is the motion.
            if group == MOTION && (first.tenths == 800 || c.tenths == 800) {
                if first.tenths == 800 {
                    g[group] = Some(c);
                }
                continue;
            }
            return fail(
                c.col,
                format!(
                    "{} conflicts with {} at column {} (both in the {} modal group)",
                    code_name('G', c.tenths),
                    code_name('G', first.tenths),
                    first.col,
                    G_GROUP_NAMES[group]
                ),
            );
        }
        g[group] = Some(c);
    }
    Ok(g)
}

/// M codes by modal group (M7 and M8 may share a line).
fn group_m(codes: &[Code]) -> Res<[Option<Code>; M_GROUPS]> {
    let mut m: [Option<Code>; M_GROUPS] = [None; M_GROUPS];
    for &c in codes {
        let group = m_group(c.tenths).map_err(|msg| LineError {
            col: c.col,
            message: msg,
        })?;
        if let Some(first) = m[group] {
            let mist_and_flood =
                group == COOLANT && matches!((first.tenths, c.tenths), (70, 80) | (80, 70));
            if !mist_and_flood {
                return fail(
                    c.col,
                    format!(
                        "{} conflicts with {} at column {} (both in the {} modal group)",
                        code_name('M', c.tenths),
                        code_name('M', first.tenths),
                        first.col,
                        M_GROUP_NAMES[group]
                    ),
                );
            }
        }
        m[group] = Some(c);
    }
    Ok(m)
}
