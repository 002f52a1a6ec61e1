//! The tool table during a run: G10 L1 (set an entry), G10 L10 and L11 (set it so that
//! the current point gets given coordinates), and G43.1 (tool offsets given on the line
//! instead of taken from the table).
//!
//! A tool carries offsets along X Y Z A B C (Z is its length) and a diameter. A change
//! to the table applies from the next G43 (LinuxCNC's rule: the offset in force is not
//! reloaded by G10). The table is the run's copy of the options' table; the file it
//! came from is never written.
//!
//! Source: LinuxCNC G-code reference (G10 L1, G10 L10, G10 L11, G43.1) and its
//! interpreter's `convert_setup_tool`.

use super::{bounded_round, check_range, fail, whole_in, Interp, Res, AXIS_BITS};
use crate::gcode::lexer::{Code, Words};
use crate::gcode::ErrorKind;
use crate::gcode::{params, Tool};
use pkmc::config::{AXES, AXIS_NAMES};

impl Interp<'_> {
    /// G10 L1 / L10 / L11 P<tool> X Y Z A B C R: rewrites tool P's entry. L1 sets the
    /// offsets to the values given; L10 sets each named one so that, with the offsets
    /// in force (G5x and G52/G92) and the machine where it is, the current coordinate
    /// becomes the given one; L11 does the same as if G59.3 were in force without
    /// G52/G92. R sets the radius (the diameter is twice it). I, J and Q (lathe angles
    /// and orientation) are read and ignored.
    pub(super) fn g10_tool(&mut self, w: &Words, c: Code, l: u8) -> Res<()> {
        let Some(p) = w.get(b'P') else {
            return fail(
                c.col,
                ErrorKind::MissingValue,
                format!("G10 L{l} needs P (the tool number)"),
            );
        };
        let n = whole_in(p, 0, i64::from(u32::MAX), "tool number P")? as u32;
        if w.polar_radius.is_some() || w.polar_angle.is_some() {
            return fail(
                c.col,
                ErrorKind::ModeConflict,
                "G10 cannot take polar coordinates (@ ^)",
            );
        }
        let mut tool = self.tools.get(n).unwrap_or_default();
        if l != 1 {
            self.tool_xy_from_position(w, l, &mut tool, c.col)?;
        }
        for (i, &letter) in AXIS_NAMES.iter().enumerate() {
            let Some(word) = w.get(letter as u8) else {
                continue;
            };
            let v = self.axis_value(i, word)?;
            let o = match l {
                1 => v,
                _ if i < 2 => continue,
                10 => self.pos[i] - self.g5x[i] - self.g92[i] - v,
                _ => self.pos[i] - self.g59_3(i, c.col)? - v,
            };
            tool.offset[i] = check_range(o, i, word.col)?;
        }
        if let Some(r) = w.get(b'R') {
            let radius = self.length(r)?;
            if radius < 0 {
                return fail(
                    r.col,
                    ErrorKind::Negative,
                    "G10: the tool radius R cannot be negative",
                );
            }
            tool.diameter_nm = check_range(2 * radius, 0, r.col)?;
        }
        self.tools.insert(n, tool);
        self.update_tool_params();
        Ok(())
    }

    /// G10 L10/L11 with X or Y: the tool's X Y offset such that the current point has
    /// the given X or Y in the destination system (the one in force for L10; G59.3
    /// without G52/G92 for L11), whose rotation may turn it. The offset is added after
    /// the rotation, so it is found in the system's frame and turned back; an axis not
    /// given keeps the old offset's component along it (LinuxCNC's
    /// `convert_setup_tool`).
    fn tool_xy_from_position(&self, w: &Words, l: u8, tool: &mut Tool, col: u32) -> Res<()> {
        let (xw, yw) = (w.get(b'X'), w.get(b'Y'));
        if xw.is_none() && yw.is_none() {
            return Ok(());
        }
        let system = if l == 10 { self.system() } else { 9 };
        let base = params::SYSTEM_BASE + 20 * (system - 1);
        let g5x = [
            self.param_units(base, 0, col)?,
            self.param_units(base + 1, 1, col)?,
        ];
        let g92 = if l == 10 {
            [self.g92[0], self.g92[1]]
        } else {
            [0; 2]
        };
        let theta = self.params.numbered(base + params::ROTATION).to_radians();
        let (s, c) = theta.sin_cos();
        let (dx, dy) = ((self.pos[0] - g5x[0]) as f64, (self.pos[1] - g5x[1]) as f64);
        // The current point in the system's frame without the tool offset.
        let here = [
            c * dx + s * dy - g92[0] as f64,
            -s * dx + c * dy - g92[1] as f64,
        ];
        let (ox, oy) = (tool.offset[0] as f64, tool.offset[1] as f64);
        let mut local = [c * ox + s * oy, -s * ox + c * oy];
        for (k, word) in [xw, yw].into_iter().enumerate() {
            if let Some(word) = word {
                local[k] = here[k] - self.axis_value(k, word)? as f64;
            }
        }
        let turned = [c * local[0] - s * local[1], s * local[0] + c * local[1]];
        for k in 0..2 {
            let at = [xw, yw][k].map_or(col, |w| w.col);
            tool.offset[k] = check_range(bounded_round(turned[k], at)?, k, at)?;
        }
        Ok(())
    }

    /// Offset of coordinate system 9 (G59.3) along axis `i`, axis units.
    fn g59_3(&self, i: usize, col: u32) -> Res<i64> {
        self.param_units(params::SYSTEM_BASE + 20 * 8 + i, i, col)
    }

    /// G43.1 X Y Z A B C: the tool offsets given on the line (program units); an axis
    /// not named has none.
    pub(super) fn dynamic_tool_offsets(&self, w: &Words, col: u32) -> Res<[i64; AXES]> {
        if w.present() & AXIS_BITS == 0 {
            return fail(
                col,
                ErrorKind::NoAxisWords,
                "G43.1 needs an offset (X Y Z A B C; Z is the length)",
            );
        }
        let mut offsets = [0; AXES];
        for (i, &letter) in AXIS_NAMES.iter().enumerate() {
            if let Some(word) = w.get(letter as u8) {
                offsets[i] = check_range(self.axis_value(i, word)?, i, word.col)?;
            }
        }
        Ok(offsets)
    }
}
