//! Coordinate-system rotation about Z (`G10 L2 P R`): machine X Y is
//! R(θ)·(program X Y plus G92 X Y) plus G5x X Y plus the tool offset X Y, as LinuxCNC
//! composes them (its `rotate_and_offset_pos`); the other axes are not turned. θ is the rotation of the
//! system in force (#5230 for G54, 20 more per system).
//!
//! Straight moves (absolute, incremental in the program frame, polar), arc end points
//! and centres in the XY plane, G92, G10 L20 and the position parameters #5420–#5421
//! go through the rotation; arcs in the XZ or YZ plane and canned cycles in a rotated
//! system are refused by name. With θ = 0 none of this runs, and every result is the
//! exact integer sum it was before.
//!
//! Invariants: a rotated position is rounded once to the nanometre; an axis the line
//! does not name keeps its machine position exactly.
//!
//! Source: LinuxCNC G-code reference (G10 L2 R) and its interpreter tests
//! `interp/rotation`, `interp/g10`.

use super::{bounded_round, Interp, Res};

impl Interp<'_> {
    /// Is the coordinate system in force rotated?
    pub(crate) fn rotated(&self) -> bool {
        self.rot_deg != 0.0
    }

    /// Program X Y (in the system in force) to machine X Y; `col` names the words.
    pub(super) fn xy_to_machine(&self, x: i64, y: i64, col: u32) -> Res<(i64, i64)> {
        let (s, c) = self.rot_deg.to_radians().sin_cos();
        let (px, py) = ((x + self.g92[0]) as f64, (y + self.g92[1]) as f64);
        Ok((
            bounded_round(c * px - s * py, col)? + self.shift(0),
            bounded_round(s * px + c * py, col)? + self.shift(1),
        ))
    }

    /// Machine X Y to program X Y in the system in force.
    pub(super) fn xy_to_program(&self, mx: i64, my: i64) -> (i64, i64) {
        let (s, c) = self.rot_deg.to_radians().sin_cos();
        let (dx, dy) = ((mx - self.shift(0)) as f64, (my - self.shift(1)) as f64);
        let round = |v: f64| crate::gcode::lexer::f64_to_i64(v).unwrap_or(0);
        (
            round(c * dx + s * dy) - self.g92[0],
            round(-s * dx + c * dy) - self.g92[1],
        )
    }

    /// What is added after the rotation along X or Y (`i`): the work offset and the
    /// tool offset (LinuxCNC's `rotate_and_offset_pos`).
    fn shift(&self, i: usize) -> i64 {
        self.g5x[i] + self.tool_offset(i)
    }

    /// A vector of the program frame (an arc's I J) in the machine frame.
    pub(super) fn turn_vector(&self, x: f64, y: f64) -> (f64, f64) {
        let (s, c) = self.rot_deg.to_radians().sin_cos();
        (c * x - s * y, s * x + c * y)
    }

    /// G10 L20 with X or Y when a rotation is involved: system `base`'s X and Y offsets
    /// (rotation `rotation`, degrees) such that the current point gets the given X Y,
    /// the one not given keeping its current program value.
    pub(super) fn g20_rotated_xy(
        &mut self,
        w: &crate::gcode::lexer::Words,
        base: usize,
        rotation: f64,
        col: u32,
    ) -> Res<()> {
        let (mut x, mut y) = self.xy_to_program(self.pos[0], self.pos[1]);
        if let Some(word) = w.get(b'X') {
            x = self.axis_value(0, word)?;
        }
        if let Some(word) = w.get(b'Y') {
            y = self.axis_value(1, word)?;
        }
        let (s, c) = rotation.to_radians().sin_cos();
        let (px, py) = ((x + self.g92[0]) as f64, (y + self.g92[1]) as f64);
        let ox = self.pos[0] - bounded_round(c * px - s * py, col)? - self.tool_offset(0);
        let oy = self.pos[1] - bounded_round(s * px + c * py, col)? - self.tool_offset(1);
        let ox = super::check_range(ox, 0, col)?;
        let oy = super::check_range(oy, 1, col)?;
        self.params.set_numbered(base, self.to_user(ox, 0));
        self.params.set_numbered(base + 1, self.to_user(oy, 1));
        Ok(())
    }
}
