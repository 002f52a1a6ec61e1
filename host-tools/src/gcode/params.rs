//! Numbered and named parameters.
//!
//! Numbered parameters #1–#5601 hold `f64` and read as 0 until set, as in LinuxCNC
//! (which would load them from its variable file; this interpreter starts from zero
//! every run). Named parameters (`#<name>`, and globals `#<_name>`) must be set before
//! they are read; names are case-insensitive and blanks in them are ignored. Names
//! without a leading underscore are local: each subroutine call starts with none and
//! the caller's come back when it returns ([`Params::enter_scope`],
//! [`Params::leave_scope`]); globals (`#<_name>`) are shared by every level.
//!
//! Parameters the interpreter maintains (see [`crate::gcode::interp`]), in mm (or
//! inches: `Options::inch_parameters`) for X Y Z and degrees for A B C whatever G20/G21
//! is in force:
//! #5021–#5026 the current machine position (the G53 frame: no work, G92 or tool
//! offset; in program units, read-only), #5161–#5166 G28 position, #5181–#5186 G30 position (machine frame),
//! #5210 G92 offsets active (1/0), #5211–#5216 G92 offsets, #5220 coordinate system in
//! force (1–9), #5221 + 20·(n − 1) + axis: offsets of coordinate system n (G54 = 1 …
//! G59.3 = 9; +9 is its rotation about Z, degrees), #5400 tool in the spindle,
//! #5401–#5406 its offsets in the table (#5403 its length), #5410 its diameter,
//! #5081–#5086 the tool offsets in force (G43, G43.1), #5420–#5425 the current position in program
//! units (read-only).
//!
//! Invariants: every value is finite; names are stored normalised.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

/// Numbered parameters are #1 to #`NUM_PARAMS - 1` (LinuxCNC's range).
pub const NUM_PARAMS: usize = 5602;
/// First parameter of the G28 position.
pub const G28_POSITION: usize = 5161;
/// First parameter of the G30 position.
pub const G30_POSITION: usize = 5181;
/// G92 offsets active.
pub const G92_ACTIVE: usize = 5210;
/// First G92 offset.
pub const G92_OFFSETS: usize = 5211;
/// Coordinate system in force, 1–9.
pub const CURRENT_SYSTEM: usize = 5220;
/// First parameter of coordinate system 1 (G54); system n starts 20 further per step.
pub const SYSTEM_BASE: usize = 5221;
/// Offset of a coordinate system's rotation about Z (degrees) from its X parameter:
/// #5230 for G54.
pub const ROTATION: usize = 9;
/// First parameter at or above which settings are refused (read-only).
pub const READ_ONLY_FROM: usize = 5400;
/// Tool in the spindle.
pub const TOOL_NUMBER: usize = 5400;
/// #5401–#5406: the table offsets along X Y Z A B C of the tool in the spindle
/// (#5403 is its length).
pub const TOOL_OFFSETS: usize = 5401;
/// #5081–#5086: the tool offsets in force (G43, G43.1) along X Y Z A B C.
pub const APPLIED_TOOL_OFFSETS: usize = 5081;
/// Diameter of the tool in the spindle, mm.
pub const TOOL_DIAMETER: usize = 5410;
/// First parameter of the current position.
pub const POSITION: usize = 5420;
/// First parameter of the current machine position (G53 frame).
pub const MACHINE_POSITION: usize = 5021;

/// FNV-1a: names are short, and the table is never exposed to adversarial sizes.
#[derive(Default)]
struct Fnv(u64);

impl Hasher for Fnv {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        let mut h = if self.0 == 0 {
            0xcbf2_9ce4_8422_2325
        } else {
            self.0
        };
        for &b in bytes {
            h ^= u64::from(b);
            h = h.wrapping_mul(0x0100_0000_01b3);
        }
        self.0 = h;
    }
}

/// Numbered parameters per block of storage. A block is allocated when one of its
/// parameters is first set: a run pays for the parameters it uses (a program a few of
/// #1–#30, the interpreter a few of #5161–#5410), not for zeroing all 5 602 (45 KB, a
/// few per cent of compiling a short program).
const BLOCK: usize = 256;
/// Blocks of all numbered parameters.
const BLOCKS: usize = NUM_PARAMS.div_ceil(BLOCK);

/// The parameter store.
#[derive(Clone, Debug)]
pub struct Params {
    /// #n is `numbered[n / BLOCK][n % BLOCK]`; a block never set reads as zeros.
    numbered: [Option<Box<[f64; BLOCK]>>; BLOCKS],
    /// Current position in the program frame, axis units (for #5420–#5425).
    pub(crate) position: [i64; 6],
    /// Current machine position (G53 frame), axis units (for #5021–#5026).
    pub(crate) machine: [i64; 6],
    /// G20 in force (the unit of #5420–#5422).
    pub(crate) inch: bool,
    /// Local named parameters of the running (sub)program.
    locals: Names,
    /// Global named parameters (`_` first).
    globals: Names,
}

type Names = HashMap<Box<[u8]>, f64, BuildHasherDefault<Fnv>>;

/// A caller's local named parameters, kept while a subroutine runs.
#[derive(Clone, Debug, Default)]
pub struct Scope(Names);

impl Default for Params {
    fn default() -> Self {
        Self::new()
    }
}

/// A position on pose axis `i` (axis units) as a position parameter reads it: mm, or
/// inches under G20 (`inch`), for X Y Z; degrees for A B C.
pub(crate) fn user_units(units: i64, i: usize, inch: bool) -> f64 {
    let v = units as f64;
    if i >= 3 {
        v / 1e9
    } else if inch {
        v / 25.4e6
    } else {
        v / 1e6
    }
}

impl Params {
    /// All numbered parameters 0, no named ones; coordinate system 1 in force.
    pub fn new() -> Self {
        let mut globals = Names::default();
        // Subroutine return values (LinuxCNC's predefined parameters): none yet.
        globals.insert(b"_value"[..].into(), 0.0);
        globals.insert(b"_value_returned"[..].into(), 0.0);
        let mut params = Self {
            numbered: std::array::from_fn(|_| None),
            position: [0; 6],
            machine: [0; 6],
            inch: false,
            locals: Names::default(),
            globals,
        };
        params.set_numbered(CURRENT_SYSTEM, 1.0);
        params
    }

    /// Value of #`n` (`n` already checked to be in 1..NUM_PARAMS; 0 otherwise).
    #[inline]
    pub fn numbered(&self, n: usize) -> f64 {
        if (POSITION..POSITION + 6).contains(&n) {
            return self.position_param(self.position[n - POSITION], n - POSITION);
        }
        if (MACHINE_POSITION..MACHINE_POSITION + 6).contains(&n) {
            return self.position_param(self.machine[n - MACHINE_POSITION], n - MACHINE_POSITION);
        }
        match self.numbered.get(n / BLOCK) {
            Some(Some(block)) if n < NUM_PARAMS => block[n % BLOCK],
            _ => 0.0,
        }
    }

    #[cold]
    fn position_param(&self, units: i64, i: usize) -> f64 {
        user_units(units, i, self.inch)
    }

    /// Sets #`n` (ignored out of range; the lexer checks the range).
    pub fn set_numbered(&mut self, n: usize, v: f64) {
        if n >= NUM_PARAMS {
            return;
        }
        if let Some(block) = self.numbered.get_mut(n / BLOCK) {
            block.get_or_insert_with(|| Box::new([0.0; BLOCK]))[n % BLOCK] = v;
        }
    }

    /// Value of `#<name>` (normalised name), if set.
    #[inline]
    pub fn named(&self, name: &[u8]) -> Option<f64> {
        self.names(name).get(name).copied()
    }

    /// The table `name` lives in.
    #[inline]
    fn names(&self, name: &[u8]) -> &Names {
        if name.first() == Some(&b'_') {
            &self.globals
        } else {
            &self.locals
        }
    }

    /// Starts a subroutine's scope: no local named parameters; returns the caller's.
    pub fn enter_scope(&mut self) -> Scope {
        Scope(std::mem::take(&mut self.locals))
    }

    /// Ends a subroutine's scope: its locals are dropped and the caller's come back.
    pub fn leave_scope(&mut self, caller: Scope) {
        self.locals = caller.0;
    }

    /// Is `#<name>` (normalised name) one LinuxCNC maintains itself, so that a program
    /// may not set it: the INI values `#<_ini[section]name>` and the predefined
    /// parameters (`#<_x>`, `#<_feed>`, `#<_current_tool>`, …, LinuxCNC's G-code
    /// reference, "Predefined Named Parameters")?
    pub fn read_only_name(name: &[u8]) -> bool {
        const PREDEFINED: &[&str] = &[
            "_vmajor",
            "_vminor",
            "_line",
            "_motion_mode",
            "_plane",
            "_ccomp",
            "_metric",
            "_imperial",
            "_absolute",
            "_incremental",
            "_inverse_time",
            "_units_per_minute",
            "_units_per_rev",
            "_coord_system",
            "_tool_offset",
            "_retract_r",
            "_retract_old_z",
            "_spindle_rpm_mode",
            "_spindle_css_mode",
            "_ijk_absolute_mode",
            "_lathe_diameter_mode",
            "_lathe_radius_mode",
            "_spindle_on",
            "_spindle_cw",
            "_mist",
            "_flood",
            "_speed_override",
            "_feed_override",
            "_adaptive_feed",
            "_feed_hold",
            "_feed",
            "_rpm",
            "_x",
            "_y",
            "_z",
            "_a",
            "_b",
            "_c",
            "_u",
            "_v",
            "_w",
            "_abs_x",
            "_abs_y",
            "_abs_z",
            "_abs_a",
            "_abs_b",
            "_abs_c",
            "_current_tool",
            "_current_pocket",
            "_selected_tool",
            "_selected_pocket",
            "_value",
            "_value_returned",
            "_task",
            "_call_level",
            "_remap_level",
        ];
        name.starts_with(b"_ini[")
            || name.starts_with(b"_hal[")
            || PREDEFINED.iter().any(|p| p.as_bytes() == name)
    }

    /// Sets `#<name>` (normalised name).
    pub fn set_named(&mut self, name: &[u8], v: f64) {
        let names = if name.first() == Some(&b'_') {
            &mut self.globals
        } else {
            &mut self.locals
        };
        match names.get_mut(name) {
            Some(slot) => *slot = v,
            None => {
                names.insert(name.into(), v);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbered_parameters_read_zero_until_set_in_every_block() {
        let mut p = Params::new();
        assert_eq!(p.numbered(CURRENT_SYSTEM), 1.0);
        for n in [1, 30, BLOCK - 1, BLOCK, 5161, 5399, NUM_PARAMS - 1] {
            assert_eq!(p.numbered(n), 0.0, "#{n}");
            p.set_numbered(n, n as f64 + 0.5);
        }
        for n in [1, 30, BLOCK - 1, BLOCK, 5161, 5399, NUM_PARAMS - 1] {
            assert_eq!(p.numbered(n), n as f64 + 0.5, "#{n}");
        }
        assert_eq!(p.numbered(2), 0.0);
        assert_eq!(p.numbered(BLOCK + 1), 0.0);
        // Beyond the range: ignored, and read as 0.
        p.set_numbered(NUM_PARAMS, 7.0);
        p.set_numbered(BLOCKS * BLOCK, 7.0);
        assert_eq!(p.numbered(NUM_PARAMS), 0.0);
        assert_eq!(p.numbered(usize::MAX), 0.0);
        // The position parameters are computed, never stored.
        p.position[0] = 2_000_000;
        assert_eq!(p.numbered(POSITION), 2.0);
    }
}
