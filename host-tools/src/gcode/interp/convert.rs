//! The phases of one line, one `convert_*` function each, called by
//! [`Interp::execute`] in LinuxCNC's order of execution (`Interp::execute_block` and the
//! `convert_*` functions of `interp_convert.cc`), with units moved first (see the
//! module doc of [`super`]).
//!
//! Invariants: a phase only acts when its words or codes are on the line; a phase that
//! reads a letter marks it used in [`Block::used`], and a word no phase used is an error
//! ([`check_unused`]); the first failing phase ends the line with its error, so the
//! order of the phases is the order of the checks a user sees.
//!
//! Source: LinuxCNC's RS-274/NGC interpreter, `interp_convert.cc` (`convert_comment`,
//! `convert_feed_mode`, `convert_feed_rate`, `convert_speed`, `convert_tool_select`,
//! `convert_tool_change`, `convert_m`, `convert_g`, `convert_dwell`, `convert_set_plane`,
//! `convert_tool_length_offset`, `convert_coordinate_system`, `convert_control_mode`,
//! `convert_distance_mode`, `convert_retract_mode`, `convert_modal_0`, `convert_motion`,
//! `convert_stop`).

use super::comp::Straight;
use super::modal::{code_name, Group, Modal};
use super::{dwell_ms, fail, whole_in, Cycle, Interp, Motion, Res};
use crate::gcode::canon::{Canon, Coolant, PathMode, Plane, Spindle};
use crate::gcode::lexer::{bit, f64_to_i64, Code, Note, Word, Words};
use crate::gcode::params;
use crate::gcode::unsupported;
use crate::gcode::ErrorKind;
use pkmc::config::AXES;

/// What the phases of one line share.
pub(super) struct Block {
    /// Line number.
    pub line: u32,
    /// The line's G and M codes by modal group.
    pub codes: Modal,
    /// Letters some phase has used, one bit each (see [`bit`]).
    pub used: u32,
    /// The move time of an F word in inverse-time mode (G93), µs.
    pub inverse: Option<u64>,
}

impl Interp<'_> {
    /// Comments: the line's `(MSG, …)` and `(DEBUG, …)` texts, in order.
    pub(super) fn convert_comments(&mut self, w: &mut Words, b: &Block, out: &mut Vec<Canon>) {
        for note in w.messages.drain(..) {
            let text = match note {
                Note::Msg(text) => text,
                Note::Debug(text) => super::debug::expand(&self.params, &text),
            };
            out.push(Canon::Message { line: b.line, text });
        }
    }

    /// Units G20/G21 (first, so that every number on the line is read in them).
    pub(super) fn convert_units(&mut self, b: &Block) {
        if let Some(c) = b.codes.get(Group::Units) {
            self.inch = c.tenths == 200;
        }
    }

    /// Feed mode G93/G94: a change forgets the feed (F must be given again).
    pub(super) fn convert_feed_mode(&mut self, b: &Block) {
        if let Some(c) = b.codes.get(Group::FeedMode) {
            let inverse = c.tenths == 930;
            if inverse != self.inverse_time {
                self.feed = None;
            }
            self.inverse_time = inverse;
        }
    }

    /// Feed rate F: per minute (G94), or the move time of this line's move (G93).
    pub(super) fn convert_feed_rate(&mut self, w: &Words, b: &mut Block) -> Res<()> {
        let Some(f) = w.get(b'F') else {
            return Ok(());
        };
        b.used |= bit(b'F');
        if self.inverse_time {
            b.inverse = Some(inverse_time_us(f)?);
        } else if f.num.is_zero() {
            // F0 is accepted where nothing moves at feed (LinuxCNC does); a feed move at
            // F0 is the error, named there.
            self.feed = None;
            self.feed_zero = true;
        } else {
            self.feed = Some(self.feed_rate(f)?);
            self.feed_zero = false;
        }
        Ok(())
    }

    /// Spindle speed S: a running spindle changes speed unless M3/M4/M5 is on the line.
    pub(super) fn convert_speed(
        &mut self,
        w: &Words,
        b: &mut Block,
        out: &mut Vec<Canon>,
    ) -> Res<()> {
        let Some(s) = w.get(b'S') else {
            return Ok(());
        };
        b.used |= bit(b'S');
        self.rpm = spindle_rpm(s)?;
        if b.codes.get(Group::Spindle).is_none() {
            let state = match self.spindle {
                Spindle::Off => None,
                Spindle::Clockwise(_) => Some(Spindle::Clockwise(self.rpm)),
                Spindle::CounterClockwise(_) => Some(Spindle::CounterClockwise(self.rpm)),
            };
            if let Some(state) = state.filter(|&s| s != self.spindle) {
                self.spindle = state;
                out.push(Canon::Spindle {
                    line: b.line,
                    state,
                });
            }
        }
        Ok(())
    }

    /// Tool select T.
    pub(super) fn convert_tool_select(&mut self, w: &Words, b: &mut Block) -> Res<()> {
        if let Some(t) = w.get(b'T') {
            b.used |= bit(b'T');
            self.selected_tool = whole_in(t, 0, i64::from(u32::MAX), "tool number T")? as u32;
        }
        Ok(())
    }

    /// Tool change M6 (the selected tool), or M61 Q (set the tool in the spindle).
    pub(super) fn convert_tool_change(
        &mut self,
        w: &Words,
        b: &mut Block,
        out: &mut Vec<Canon>,
    ) -> Res<()> {
        let Some(c) = b.codes.get(Group::ToolChange) else {
            return Ok(());
        };
        if c.tenths == 60 {
            out.push(Canon::ToolChange {
                line: b.line,
                tool: self.selected_tool,
            });
            self.current_tool = self.selected_tool;
        } else {
            b.used |= bit(b'Q');
            let Some(q) = w.get(b'Q') else {
                return fail(
                    c.col,
                    ErrorKind::MissingValue,
                    "M61 needs Q (the tool now in the spindle)",
                );
            };
            self.current_tool = whole_in(q, 0, i64::from(u32::MAX), "tool number Q")? as u32;
        }
        self.update_tool_params();
        Ok(())
    }

    /// Spindle M3/M4/M5, at the speed in force.
    pub(super) fn convert_spindle(&mut self, b: &Block, out: &mut Vec<Canon>) {
        if let Some(c) = b.codes.get(Group::Spindle) {
            let state = match c.tenths {
                30 => Spindle::Clockwise(self.rpm),
                40 => Spindle::CounterClockwise(self.rpm),
                _ => Spindle::Off,
            };
            self.spindle = state;
            out.push(Canon::Spindle {
                line: b.line,
                state,
            });
        }
    }

    /// Coolant M7/M8/M9, each in line order (M7 and M8 may share a line).
    pub(super) fn convert_coolant(&mut self, w: &Words, b: &Block, out: &mut Vec<Canon>) {
        if b.codes.get(Group::Coolant).is_none() {
            return;
        }
        for c in &w.m {
            let state = match c.tenths {
                70 => Coolant::Mist,
                80 => Coolant::Flood,
                90 => Coolant::Off,
                _ => continue,
            };
            self.coolant = match state {
                Coolant::Mist => (true, self.coolant.1),
                Coolant::Flood => (self.coolant.0, true),
                Coolant::Off => (false, false),
            };
            out.push(Canon::Coolant {
                line: b.line,
                state,
            });
        }
    }

    /// Dwell G4 P (seconds).
    pub(super) fn convert_dwell(
        &mut self,
        w: &Words,
        b: &mut Block,
        out: &mut Vec<Canon>,
    ) -> Res<()> {
        let Some(c) = b.codes.get(Group::NonModal).filter(|c| c.tenths == 40) else {
            return Ok(());
        };
        b.used |= bit(b'P');
        let Some(p) = w.get(b'P') else {
            return fail(
                c.col,
                ErrorKind::MissingValue,
                "G4 needs P (dwell time, seconds)",
            );
        };
        let ms = dwell_ms(p)?;
        out.push(Canon::Dwell { line: b.line, ms });
        Ok(())
    }

    /// Plane G17/G18/G19.
    pub(super) fn convert_plane(&mut self, b: &Block) {
        if let Some(c) = b.codes.get(Group::Plane) {
            self.plane = match c.tenths {
                170 => Plane::Xy,
                180 => Plane::Zx,
                _ => Plane::Yz,
            };
        }
    }

    /// Tool length offset G43 [H], G43.1 (given on the line) / G49.
    pub(super) fn convert_tool_length(&mut self, w: &Words, b: &mut Block) -> Res<()> {
        let Some(c) = b.codes.get(Group::ToolLength) else {
            return Ok(());
        };
        if c.tenths == 430 {
            b.used |= bit(b'H');
            let n = match w.get(b'H') {
                Some(h) => whole_in(h, 0, i64::from(u32::MAX), "tool number H")? as u32,
                None => self.current_tool,
            };
            self.tool_offsets = match self.tools.get(n) {
                Some(t) => t.offset,
                None if n == 0 => [0; AXES],
                None => {
                    let at = w.get(b'H').map_or(c.col, |h| h.col);
                    return fail(
                        at,
                        ErrorKind::ToolNumber,
                        format!("G43: tool {n} is not in the tool table"),
                    );
                }
            };
        } else if c.tenths == 431 {
            self.tool_offsets = self.dynamic_tool_offsets(w, c.col)?;
            b.used |= super::AXIS_BITS;
        } else {
            self.tool_offsets = [0; AXES];
        }
        self.update_tool_params();
        self.refresh_offsets(c.col)
    }

    /// Coordinate system G54 … G59.3.
    pub(super) fn convert_coordinate_system(&mut self, b: &Block) -> Res<()> {
        let Some(c) = b.codes.get(Group::System) else {
            return Ok(());
        };
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
        self.refresh_offsets(c.col)
    }

    /// Path control G61/G61.1 (exact stop) or G64 [P] (blending).
    pub(super) fn convert_path_mode(
        &mut self,
        w: &Words,
        b: &mut Block,
        out: &mut Vec<Canon>,
    ) -> Res<()> {
        let Some(c) = b.codes.get(Group::Path) else {
            return Ok(());
        };
        let mode = if c.tenths == 640 {
            // LinuxCNC's G64 R (the planner's peak-scale mode), unless the line's own
            // motion code (an R arc or cycle) takes the R.
            if let (Some(r), None) = (w.get(b'R'), b.codes.get(Group::Motion)) {
                return fail(
                    r.col,
                    ErrorKind::Unsupported,
                    unsupported("G64 R (trajectory planner mode)"),
                );
            }
            b.used |= bit(b'P') | bit(b'Q');
            match w.get(b'P') {
                Some(p) => {
                    if p.num.is_negative() {
                        return fail(
                            p.col,
                            ErrorKind::Negative,
                            format!("negative blending tolerance P{}", p.num),
                        );
                    }
                    PathMode::Blend(Some(self.length(p)?))
                }
                None => PathMode::Blend(None),
            }
        } else {
            PathMode::ExactStop
        };
        self.path = mode;
        out.push(Canon::PathMode { line: b.line, mode });
        Ok(())
    }

    /// Distance modes G90/G91 and arc distance modes G90.1/G91.1.
    pub(super) fn convert_distance_mode(&mut self, b: &Block) {
        if let Some(c) = b.codes.get(Group::Distance) {
            self.absolute = c.tenths == 900;
        }
        if let Some(c) = b.codes.get(Group::ArcDistance) {
            self.arc_absolute = c.tenths == 901;
        }
    }

    /// Canned-cycle return G98/G99.
    pub(super) fn convert_retract_mode(&mut self, b: &Block) {
        if let Some(c) = b.codes.get(Group::Retract) {
            self.retract_to_r = c.tenths == 990;
        }
    }

    /// Non-modal codes: G10, G28/G30, G28.1/G30.1, G52, G92 and G92.1–G92.3 (G4 is the dwell
    /// phase, G53 goes with the motion).
    pub(super) fn convert_nonmodal(
        &mut self,
        w: &Words,
        b: &mut Block,
        out: &mut Vec<Canon>,
    ) -> Res<()> {
        let Some(c) = b.codes.get(Group::NonModal) else {
            return Ok(());
        };
        match c.tenths {
            100 => self.g10(w, c, &mut b.used),
            280 | 300 => {
                self.g5_tangent = None;
                self.home(w, c, b.line, out)
            }
            281 | 301 => {
                self.store_home(c);
                Ok(())
            }
            520 => self.g52(w, c),
            920 => self.g92(w, c),
            921..=923 => self.g92_switch(c),
            _ => Ok(()),
        }
    }

    /// Motion: sets the motion mode (group 1), then moves if the line moves (in the mode
    /// in force when the line has coordinates but no motion code).
    pub(super) fn convert_motion(
        &mut self,
        w: &Words,
        b: &mut Block,
        out: &mut Vec<Canon>,
    ) -> Res<()> {
        let nonmodal = b.codes.get(Group::NonModal);
        let nm_axes = nonmodal
            .filter(|c| matches!(c.tenths, 100 | 280 | 300 | 520 | 920))
            .or(b.codes.get(Group::ToolLength).filter(|c| c.tenths == 431));
        let g53 = nonmodal.filter(|c| c.tenths == 530);
        let explicit = b.codes.get(Group::Motion);
        if let (Some(c), Some(n)) = (explicit.filter(|c| c.tenths != 800), nm_axes) {
            return fail(
                c.col,
                ErrorKind::TwoAxisCommands,
                format!(
                    "{} and {} on one line: both would use the axis words",
                    code_name('G', c.tenths),
                    code_name('G', n.tenths)
                ),
            );
        }
        let previous = self.motion;
        if let Some(c) = explicit {
            self.motion = motion_of(c.tenths);
        }
        if !matches!(self.motion, Motion::Cycle(_)) {
            self.cycle.initial_level = None;
        }
        let has_axes = w.present() & super::AXIS_BITS != 0;
        let has_polar = w.polar_radius.is_some() || w.polar_angle.is_some();
        let ijk = w.present() & (bit(b'I') | bit(b'J') | bit(b'K')) != 0;
        let run = nm_axes.is_none()
            && match explicit {
                Some(_) => match self.motion {
                    Motion::None | Motion::Rapid | Motion::Linear => has_axes || has_polar,
                    // G5 and G5.1 without an end point are an error (LinuxCNC's "all
                    // axes missing with motion code"), named by the spline.
                    Motion::Arc { .. }
                    | Motion::Cycle(_)
                    | Motion::Cubic
                    | Motion::Quadratic
                    | Motion::Probe(_) => true,
                },
                None => has_axes || has_polar || (ijk && matches!(self.motion, Motion::Arc { .. })),
            };
        if nm_axes.is_some() && has_polar {
            let at = w.polar_radius.or(w.polar_angle).map_or(1, |p| p.col);
            return fail(
                at,
                ErrorKind::UnusedAxisWords,
                "polar coordinates (@ ^) only go with motion",
            );
        }
        if let Some(c) = g53 {
            let ok = run && matches!(self.motion, Motion::Rapid | Motion::Linear);
            if !ok {
                return fail(
                    c.col,
                    ErrorKind::G53Motion,
                    "G53 needs G0 or G1 (on its line or in force) and axis words",
                );
            }
            if !self.absolute {
                return fail(
                    c.col,
                    ErrorKind::ModeConflict,
                    "G53 needs absolute distance mode (G90)",
                );
            }
            if has_polar {
                return fail(
                    c.col,
                    ErrorKind::ModeConflict,
                    "G53 cannot take polar coordinates (@ ^)",
                );
            }
        }
        if run {
            self.move_in_mode(w, b, explicit, g53.is_some(), previous, out)?;
        }
        Ok(())
    }

    /// The move of a line in the motion mode in force (`explicit`: the line's motion
    /// code; `machine`: G53; `previous`: the mode before the line).
    fn move_in_mode(
        &mut self,
        w: &Words,
        b: &mut Block,
        explicit: Option<Code>,
        machine: bool,
        previous: Motion,
        out: &mut Vec<Canon>,
    ) -> Res<()> {
        let line = b.line;
        let first_motion_col = w.first_motion_col.max(1);
        let col = explicit.map_or(first_motion_col, |c| c.col);
        // Any move ends a series of G5s; a G5 continues it.
        let g5_tangent = self.g5_tangent.take();
        match self.motion {
            Motion::None => {
                let what = if explicit.is_some() {
                    "G80 cancels the motion mode: its line cannot move"
                } else {
                    "coordinates without a motion mode (G0, G1, G2, G3 or a canned cycle)"
                };
                return fail(first_motion_col, ErrorKind::UnusedAxisWords, what);
            }
            Motion::Rapid => {
                let mut t = [0; AXES];
                self.target_into(w, machine, &mut t)?;
                self.straight(line, Straight::Rapid, t, col, out)?;
            }
            Motion::Linear => {
                let mut t = [0; AXES];
                self.target_into(w, machine, &mut t)?;
                let feed = self.feed_for(&t, false, b.inverse, "G1", col)?;
                self.straight(line, Straight::Feed(feed), t, col, out)?;
            }
            Motion::Arc { clockwise } => {
                b.used |= bit(b'I') | bit(b'J') | bit(b'K') | bit(b'R') | bit(b'P');
                self.arc(w, clockwise, b, col, out)?;
            }
            Motion::Cubic => {
                b.used |= bit(b'I') | bit(b'J') | bit(b'P') | bit(b'Q');
                self.spline(w, false, g5_tangent, b, col, out)?;
            }
            Motion::Quadratic => {
                b.used |= bit(b'I') | bit(b'J');
                self.spline(w, true, None, b, col, out)?;
            }
            Motion::Cycle(kind) => {
                b.used |= bit(b'R') | bit(b'L') | bit(b'P') | bit(b'Q');
                self.cycle(w, kind, previous, line, col, out)?;
            }
            Motion::Probe(kind) => self.probe(w, kind, b, col, out)?,
        }
        Ok(())
    }

    /// Parameter settings, in order (after everything else on the line that can fail
    /// but the stops, as the RS-274/NGC rule reads them: with the values from before the
    /// line).
    pub(super) fn convert_assignments(&mut self, w: &mut Words) -> Res<()> {
        if w.assigns.is_empty() {
            return Ok(());
        }
        self.apply_assigns(w)
    }

    /// Stops M0/M1 (pause, optional pause) and M2/M30 (end), after the line's motion
    /// and only once nothing on the line can fail.
    pub(super) fn convert_stop(&mut self, b: &Block, out: &mut Vec<Canon>) -> Res<()> {
        let Some(c) = b.codes.get(Group::Stop) else {
            return Ok(());
        };
        let line = b.line;
        self.comp_stop(matches!(c.tenths, 20 | 300), c.col, out)?;
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
        Ok(())
    }
}

/// The motion mode of motion code `tenths` (G80: none).
fn motion_of(tenths: i32) -> Motion {
    match tenths {
        0 => Motion::Rapid,
        10 => Motion::Linear,
        20 => Motion::Arc { clockwise: true },
        30 => Motion::Arc { clockwise: false },
        50 => Motion::Cubic,
        51 => Motion::Quadratic,
        382..=385 => Motion::Probe(super::probe::Probing::of(tenths)),
        730 => Motion::Cycle(Cycle::G73),
        810 => Motion::Cycle(Cycle::G81),
        820 => Motion::Cycle(Cycle::G82),
        830 => Motion::Cycle(Cycle::G83),
        850 => Motion::Cycle(Cycle::G85),
        890 => Motion::Cycle(Cycle::G89),
        _ => Motion::None,
    }
}

/// Refuses the leftmost word that no phase of the line used.
pub(super) fn check_unused(w: &Words, b: &Block) -> Res<()> {
    let unused = w.present() & !b.used;
    if unused == 0 {
        return Ok(());
    }
    let at = first_col(w, unused);
    let letter = (b'A'..=b'Z')
        .find(|&l| unused & bit(l) != 0 && w.get(l).is_some_and(|x| x.col == at))
        .unwrap_or(b'?');
    fail(
        at,
        ErrorKind::UnusedWords,
        format!(
            "{} word with no G or M code on its line that uses it",
            letter as char
        ),
    )
}

/// G93 F: the move takes 1/F minutes → µs.
fn inverse_time_us(f: Word) -> Res<u64> {
    if f.num.is_negative() || f.num.is_zero() {
        return fail(
            f.col,
            ErrorKind::Negative,
            format!("inverse-time feed F{} must be above zero", f.num),
        );
    }
    let us = 60e6 / f.num.to_f64();
    match f64_to_i64(us) {
        Some(v) if v >= 1 => Ok(v as u64),
        _ => fail(
            f.col,
            ErrorKind::OutOfRange,
            format!("inverse-time feed F{} out of range", f.num),
        ),
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
            if v < 0.0 {
                ErrorKind::Negative
            } else {
                ErrorKind::OutOfRange
            },
            format!("spindle speed S{} must be from 0 to 4294967295 rpm", s.num),
        );
    }
    Ok(v.round() as u32)
}
