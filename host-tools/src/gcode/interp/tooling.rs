//! The tool table during a run: G10 L1 (set an entry), G10 L10 and L11 (set it so that
//! the current point gets given coordinates), and G43.1 (a tool length offset given on
//! the line instead of taken from the table).
//!
//! Only the Z length offset and the diameter are kept (the table's rule,
//! [`crate::gcode::tools`]): an offset along another axis is refused by name unless
//! zero. A change to the table applies from the next G43 (LinuxCNC's rule: the offset
//! in force is not reloaded by G10). The table is the run's copy of the options'
//! table; the file it came from is never written.
//!
//! Source: LinuxCNC G-code reference (G10 L1, G10 L10, G10 L11, G43.1).

use super::{check_range, fail, whole_in, Interp, Res, AXIS_BITS};
use crate::gcode::lexer::{Code, Words};
use crate::gcode::{params, unsupported};
use pkmc::config::AXIS_NAMES;

/// Index of Z among the pose axes.
const Z: usize = 2;

impl Interp<'_> {
    /// G10 L1 / L10 / L11 P<tool> Z<..> R<radius>: rewrites tool P's entry. L1 sets the
    /// length offset to Z; L10 sets it so that, with the offsets in force (G5x and
    /// G52/G92) and the machine where it is, the current Z becomes the given one;
    /// L11 does the same as if G59.3 were in force without G52/G92. R sets the radius
    /// (the diameter is twice it). I, J and Q (lathe angles and orientation) are read
    /// and ignored.
    pub(super) fn g10_tool(&mut self, w: &Words, c: Code, l: u8) -> Res<()> {
        let Some(p) = w.get(b'P') else {
            return fail(c.col, format!("G10 L{l} needs P (the tool number)"));
        };
        let n = whole_in(p, 0, i64::from(u32::MAX), "tool number P")? as u32;
        if w.polar_radius.is_some() || w.polar_angle.is_some() {
            return fail(c.col, "G10 cannot take polar coordinates (@ ^)");
        }
        only_z_offset(w)?;
        let mut tool = self.tools.get(n).unwrap_or_default();
        if let Some(z) = w.get(b'Z') {
            let v = self.axis_value(Z, z)?;
            tool.length_nm = check_range(
                match l {
                    1 => v,
                    10 => self.pos[Z] - self.g5x[Z] - self.g92[Z] - v,
                    _ => self.pos[Z] - self.g59_3_z(c.col)? - v,
                },
                Z,
                z.col,
            )?;
        }
        if let Some(r) = w.get(b'R') {
            let radius = self.length(r)?;
            if radius < 0 {
                return fail(r.col, "G10: the tool radius R cannot be negative");
            }
            tool.diameter_nm = check_range(2 * radius, 0, r.col)?;
        }
        self.tools.insert(n, tool);
        self.update_tool_params();
        Ok(())
    }

    /// Z offset of coordinate system 9 (G59.3), axis units.
    fn g59_3_z(&self, col: u32) -> Res<i64> {
        self.param_units(params::SYSTEM_BASE + 20 * 8 + Z, Z, col)
    }

    /// G43.1 Z<..>: the tool length offset given on the line (program units); axis
    /// words other than Z must be zero (only the Z length offset is applied).
    pub(super) fn dynamic_tool_length(&self, w: &Words, col: u32) -> Res<i64> {
        if w.present() & AXIS_BITS == 0 {
            return fail(col, "G43.1 needs Z (the tool length offset)");
        }
        only_z_offset(w)?;
        match w.get(b'Z') {
            Some(z) => check_range(self.axis_value(Z, z)?, Z, z.col),
            None => Ok(0),
        }
    }
}

/// Refuses by name a nonzero tool offset along any axis but Z (only the Z length offset
/// is applied).
fn only_z_offset(w: &Words) -> Res<()> {
    for (i, &letter) in AXIS_NAMES.iter().enumerate() {
        if let Some(word) = w.get(letter as u8).filter(|_| i != Z) {
            if !word.num.is_zero() {
                let feature =
                    format!("tool offsets along {letter} (only the Z length offset is applied)");
                return fail(word.col, unsupported(&feature));
            }
        }
    }
    Ok(())
}
