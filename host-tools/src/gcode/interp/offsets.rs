//! Offsets and parameters: the parameter settings of a line, G10 L2/L20, G28/G30 (and
//! their stored positions), G52, G92, the offsets in force and the parameters the
//! interpreter maintains (tool, position).
//!
//! The offsets in force are recomputed from the parameters ([`Interp::refresh_offsets`])
//! whenever a parameter they depend on may have changed, so the parameters are the one
//! source of the coordinate systems, the G92 offsets and the stored positions (in mm or
//! degrees, machine frame, as LinuxCNC keeps them).
//!
//! Invariants: an offset read from a parameter is within
//! [`crate::gcode::MAX_AXIS_UNITS`] or the line fails; read-only parameters (#5400 and
//! above, and the names LinuxCNC maintains) are never set by a program; changing an
//! offset never moves the machine.
//!
//! Source: LinuxCNC G-code reference (G10, G28, G30, G53, G54-G59.3, G92, parameters) and
//! its interpreter's `interp_convert.cc` (`convert_setup`, `convert_home`,
//! `convert_axis_offsets`).

use super::{check_range, fail, whole_in, Interp, Res, AXIS_BITS};
use crate::gcode::canon::Canon;
use crate::gcode::lexer::{bit, f64_to_i64, Code, ParamRef, Words};
use crate::gcode::params;
use crate::gcode::ErrorKind;
use crate::gcode::MAX_AXIS_UNITS;
use pkmc::config::{AXES, AXIS_NAMES};

impl Interp<'_> {
    /// Applies the line's parameter settings, in order.
    pub(super) fn apply_assigns(&mut self, w: &mut Words) -> Res<()> {
        let mut refresh = None;
        for a in w.assigns.drain(..) {
            match a.target {
                ParamRef::Numbered(n) => {
                    if n >= params::READ_ONLY_FROM {
                        return fail(
                            a.col,
                            ErrorKind::Parameter,
                            format!("parameter #{n} is read-only"),
                        );
                    }
                    if n == params::CURRENT_SYSTEM
                        && !(a.value.fract() == 0.0 && (1.0..=9.0).contains(&a.value))
                    {
                        return fail(
                            a.col,
                            ErrorKind::Parameter,
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
                            ErrorKind::Parameter,
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

    /// G28 / G30: rapid through the intermediate point (if axis words are given) to the
    /// stored position (only the axes named, or all of them).
    pub(super) fn home(&mut self, w: &Words, c: Code, line: u32, out: &mut Vec<Canon>) -> Res<()> {
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
            // The intermediate point is the current one, as LinuxCNC emits it (a move of
            // length zero): the canonical output stays move for move LinuxCNC's.
            self.rapid(line, self.pos, out);
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

    /// G28.1 / G30.1: store the current position (machine frame) as the G28 or G30
    /// position.
    pub(super) fn store_home(&mut self, c: Code) {
        let base = if c.tenths == 281 {
            params::G28_POSITION
        } else {
            params::G30_POSITION
        };
        for i in 0..AXES {
            self.params
                .set_numbered(base + i, self.to_user(self.pos[i], i));
        }
    }

    /// G92.1 (cancel and clear), G92.2 (suspend) and G92.3 (restore) the G92 offsets.
    pub(super) fn g92_switch(&mut self, c: Code) -> Res<()> {
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
        self.refresh_offsets(c.col)
    }

    /// G92: offsets that make the current point have the given coordinates.
    pub(super) fn g92(&mut self, w: &Words, c: Code) -> Res<()> {
        if w.present() & AXIS_BITS == 0 {
            return fail(c.col, ErrorKind::NoAxisWords, "G92 needs axis words");
        }
        // Where the current point is, offsets but G92's taken away: in the rotated
        // frame for X and Y.
        let mut here = [0i64; AXES];
        for (i, h) in here.iter_mut().enumerate() {
            *h = self.pos[i] - self.g5x[i] - self.tool_offset(i);
        }
        if self.rotated() {
            let (x, y) = self.xy_to_program(self.pos[0], self.pos[1]);
            here[0] = x + self.g92[0];
            here[1] = y + self.g92[1];
        }
        for (i, &letter) in AXIS_NAMES.iter().enumerate() {
            let Some(word) = w.get(letter as u8) else {
                continue;
            };
            let v = self.axis_value(i, word)?;
            let o = check_range(here[i] - v, i, word.col)?;
            self.params
                .set_numbered(params::G92_OFFSETS + i, self.to_user(o, i));
        }
        // Axes not named keep their offsets (active ones, as stored).
        for (i, &letter) in AXIS_NAMES.iter().enumerate() {
            if w.get(letter as u8).is_none() {
                self.params
                    .set_numbered(params::G92_OFFSETS + i, self.to_user(self.g92[i], i));
            }
        }
        self.params.set_numbered(params::G92_ACTIVE, 1.0);
        self.refresh_offsets(c.col)
    }

    /// G52: the local offsets, which share G92's registers (#5211–#5216): each axis
    /// named gets the value given (program units), the others keep theirs; #5210 is
    /// set, as by G92. `G52 X0 Y0` takes the X and Y offsets away.
    pub(super) fn g52(&mut self, w: &Words, c: Code) -> Res<()> {
        if w.present() & AXIS_BITS == 0 {
            return fail(c.col, ErrorKind::NoAxisWords, "G52 needs axis words");
        }
        for (i, &letter) in AXIS_NAMES.iter().enumerate() {
            let o = match w.get(letter as u8) {
                Some(word) => check_range(self.axis_value(i, word)?, i, word.col)?,
                None => self.g92[i],
            };
            self.params
                .set_numbered(params::G92_OFFSETS + i, self.to_user(o, i));
        }
        self.params.set_numbered(params::G92_ACTIVE, 1.0);
        self.refresh_offsets(c.col)
    }

    /// G10 L2 / L20: set a coordinate system's offsets.
    pub(super) fn g10(&mut self, w: &Words, c: Code, used: &mut u32) -> Res<()> {
        *used |= bit(b'L') | bit(b'P') | bit(b'R');
        let Some(l) = w.get(b'L') else {
            return fail(
                c.col,
                ErrorKind::MissingValue,
                "G10 needs L1, L2, L10, L11 or L20",
            );
        };
        let l20 = match l.num.whole() {
            Some(2) => false,
            Some(20) => true,
            Some(n @ (1 | 10 | 11)) => return self.g10_tool(w, c, n as u8),
            _ => {
                return fail(
                    l.col,
                    ErrorKind::UnknownCode,
                    format!("G10 L{}: only L1, L2, L10, L11 and L20 exist", l.num),
                )
            }
        };
        let Some(p) = w.get(b'P') else {
            return fail(
                c.col,
                ErrorKind::MissingValue,
                "G10 L2/L20 needs P (coordinate system 1-9, 0 for the current)",
            );
        };
        let mut n = whole_in(p, 0, 9, "coordinate system P")? as usize;
        if n == 0 {
            n = self.system();
        }
        if w.polar_radius.is_some() || w.polar_angle.is_some() {
            return fail(
                c.col,
                ErrorKind::ModeConflict,
                "G10 cannot take polar coordinates (@ ^)",
            );
        }
        let base = params::SYSTEM_BASE + 20 * (n - 1);
        if let Some(r) = w.get(b'R') {
            let deg = r.num.to_f64();
            if !deg.is_finite() || deg.abs() > 1e9 {
                return fail(
                    r.col,
                    ErrorKind::OutOfRange,
                    format!("rotation R{} out of range", r.num),
                );
            }
            self.params.set_numbered(base + params::ROTATION, deg);
        }
        let xy_given = w.get(b'X').is_some() || w.get(b'Y').is_some();
        let rotation = self.params.numbered(base + params::ROTATION);
        // L20's X and Y, when a rotation is involved, are set together (see rotation.rs).
        let turned_xy = l20 && xy_given && (self.rotated() || rotation != 0.0);
        if turned_xy {
            self.g20_rotated_xy(w, base, rotation, c.col)?;
        }
        for (i, &letter) in AXIS_NAMES.iter().enumerate() {
            let Some(word) = w.get(letter as u8) else {
                continue;
            };
            if turned_xy && i < 2 {
                continue;
            }
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
            self.params.set_numbered(base + i, self.to_user(o, i));
        }
        self.refresh_offsets(c.col)
    }

    /// Coordinate system in force, 1–9.
    pub(super) fn system(&self) -> usize {
        (self.params.numbered(params::CURRENT_SYSTEM) as usize).clamp(1, 9)
    }

    pub(super) fn tool_offset(&self, i: usize) -> i64 {
        self.tool_offsets[i]
    }

    /// Parameter `n` (in the parameters' units for axis `i`) in axis units, bounded.
    pub(super) fn param_units(&self, n: usize, i: usize, col: u32) -> Res<i64> {
        let v = self.params.numbered(n);
        match f64_to_i64(v * self.per_user(i) as f64) {
            Some(u) if u.abs() <= MAX_AXIS_UNITS => Ok(u),
            _ => fail(
                col,
                ErrorKind::Parameter,
                format!("parameter #{n} = {v} out of range"),
            ),
        }
    }

    /// Recomputes the offsets in force from the parameters and the tool length.
    pub(super) fn refresh_offsets(&mut self, col: u32) -> Res<()> {
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
        let r = self.params.numbered(base + params::ROTATION);
        if !r.is_finite() || r.abs() > 1e9 {
            return fail(
                col,
                ErrorKind::Parameter,
                format!("parameter #{} = {r} out of range", base + params::ROTATION),
            );
        }
        self.rot_deg = r;
        Ok(())
    }

    /// #5400 the tool in the spindle, #5401–#5406 and #5410 its table entry (as
    /// stored: refreshed by M6, M61 and G10 L1/L10/L11), #5081–#5086 the offsets in
    /// force (G43, G43.1), as LinuxCNC keeps them.
    pub(super) fn update_tool_params(&mut self) {
        let entry = self.tools.get(self.current_tool).unwrap_or_default();
        for i in 0..AXES {
            let stored = self.to_user(entry.offset[i], i);
            let applied = self.to_user(self.tool_offsets[i], i);
            self.params.set_numbered(params::TOOL_OFFSETS + i, stored);
            self.params
                .set_numbered(params::APPLIED_TOOL_OFFSETS + i, applied);
        }
        let d = self.to_user(entry.diameter_nm, 0);
        let p = &mut self.params;
        p.set_numbered(params::TOOL_NUMBER, f64::from(self.current_tool));
        p.set_numbered(params::TOOL_DIAMETER, d);
    }

    /// #5420–#5425 and #5021–#5026: the current position in program units, in the
    /// program and the machine frame (computed when read).
    pub(super) fn update_position_params(&mut self) {
        self.params.position = self.program_frame(&self.pos);
        self.params.machine = self.pos;
        self.params.inch = self.inch;
    }

    /// `pose` (machine frame, axis units) in the program frame: offsets taken off, the
    /// rotation turned back.
    pub(super) fn program_frame(&self, pose: &[i64; AXES]) -> [i64; AXES] {
        let mut p: [i64; AXES] = std::array::from_fn(|i| pose[i] - self.off[i]);
        if self.rotated() {
            (p[0], p[1]) = self.xy_to_program(pose[0], pose[1]);
        }
        p
    }
}
