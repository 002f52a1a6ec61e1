//! Tool table: tool number → offsets and diameter.
//!
//! Read from a LinuxCNC-style tool file (`tool.tbl`), one tool per line:
//! `T1 P1 Z12.5 D6.0 ;comment`, lengths in mm, angles in degrees. `T` (required) is the
//! tool number, `P` the pocket (ignored: there is no changer to drive), `X Y Z A B C`
//! the offsets G43 applies (`Z` is the tool length), `D` the diameter (#5410, and the
//! radius of cutter compensation). `U V W` are refused by name (the machines have no
//! such axes); the lathe fields `I J Q` (front and back angle,
//! orientation) are accepted and ignored. Blank lines and `;` comments are skipped.
//!
//! Invariants: offsets are in axis units (nm, n°) and diameters in nm, bounded by
//! [`super::MAX_AXIS_UNITS`]; diameters are not negative; each tool appears once.

use super::lexer::{char_col, scan_line, Num, Words};
use super::params::Params;
use super::{Diagnostic, ErrorKind, MAX_AXIS_UNITS, MAX_LINE};
use pkmc::config::AXES;
use pkmc::units::{NDEG_PER_DEG, NM_PER_MM};
use std::collections::BTreeMap;

/// One tool.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Tool {
    /// Offsets G43 applies, per pose axis: X Y Z in nm (Z is the tool length), A B C in
    /// n°.
    pub offset: [i64; AXES],
    /// Diameter, nm.
    pub diameter_nm: i64,
}

/// Tools by number.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ToolTable {
    tools: BTreeMap<u32, Tool>,
}

impl ToolTable {
    /// An empty table.
    pub fn new() -> Self {
        Self::default()
    }

    /// The tool numbered `n`, if the table has it.
    pub fn get(&self, n: u32) -> Option<Tool> {
        self.tools.get(&n).copied()
    }

    /// Adds or replaces tool `n`.
    pub fn insert(&mut self, n: u32, tool: Tool) {
        self.tools.insert(n, tool);
    }

    /// Number of tools.
    pub fn len(&self) -> usize {
        self.tools.len()
    }

    /// Does the table have no tools?
    pub fn is_empty(&self) -> bool {
        self.tools.is_empty()
    }

    /// Tools in number order.
    pub fn iter(&self) -> impl Iterator<Item = (u32, Tool)> + '_ {
        self.tools.iter().map(|(&n, &t)| (n, t))
    }

    /// Parses a tool file; `origin` names it in the diagnostic of the first error.
    pub fn parse(text: &str, origin: &str) -> Result<ToolTable, Diagnostic> {
        let mut table = ToolTable::new();
        let params = Params::new();
        let mut words = Words::default();
        for (n, raw) in text.split('\n').enumerate() {
            let line = n + 1;
            let text = raw.trim_end_matches('\r');
            let err = |col: u32, kind: ErrorKind, message: String| Diagnostic {
                file: origin.to_string(),
                line,
                col: char_col(text, col),
                kind,
                message,
            };
            if text.chars().count() > MAX_LINE {
                return Err(Diagnostic {
                    file: origin.to_string(),
                    line,
                    col: MAX_LINE + 1,
                    kind: ErrorKind::LineTooLong,
                    message: format!("line longer than {MAX_LINE} characters"),
                });
            }
            scan_line(text, 0, &params, &mut words).map_err(|e| err(e.col, e.kind, e.message))?;
            let stray = words.g.first().or(words.m.first()).map(|c| c.col);
            if let Some(col) = stray.or(words.assigns.first().map(|a| a.col)) {
                return Err(err(
                    col,
                    ErrorKind::UnusedWords,
                    "a tool line holds T P X Y Z A B C D I J Q words only".into(),
                ));
            }
            if words.present() == 0 {
                continue;
            }
            let Some(t) = words.get(b'T') else {
                return Err(err(
                    1,
                    ErrorKind::MissingValue,
                    "tool line without a tool number (T)".into(),
                ));
            };
            let number = t
                .num
                .whole()
                .and_then(|v| u32::try_from(v).ok())
                .ok_or_else(|| {
                    err(
                        t.col,
                        ErrorKind::NotInteger,
                        format!("tool number T{} is not a whole number ≥ 0", t.num),
                    )
                })?;
            if table.tools.contains_key(&number) {
                return Err(err(
                    t.col,
                    ErrorKind::RepeatedWord,
                    format!("tool T{number} listed twice"),
                ));
            }
            let units = |num: Num, col: u32, what: &str, per: i64, unit: &str| {
                num.scaled(per, 1)
                    .filter(|v| v.abs() <= MAX_AXIS_UNITS)
                    .ok_or_else(|| {
                        err(
                            col,
                            ErrorKind::OutOfRange,
                            format!("{what} {num} {unit} out of range"),
                        )
                    })
            };
            let mm = |num: Num, col: u32, what: &str| units(num, col, what, NM_PER_MM, "mm");
            let mut tool = Tool::default();
            for letter in b'A'..=b'Z' {
                let Some(w) = words.get(letter) else { continue };
                match letter {
                    b'T' | b'P' | b'I' | b'J' | b'Q' => {}
                    b'X' | b'Y' | b'Z' => {
                        let i = usize::from(letter - b'X');
                        tool.offset[i] = mm(w.num, w.col, &format!("offset {}", letter as char))?;
                    }
                    b'A' | b'B' | b'C' => {
                        let i = 3 + usize::from(letter - b'A');
                        let what = format!("offset {}", letter as char);
                        tool.offset[i] = units(w.num, w.col, &what, NDEG_PER_DEG, "°")?;
                    }
                    b'D' => {
                        tool.diameter_nm = mm(w.num, w.col, "diameter D")?;
                        if tool.diameter_nm < 0 {
                            return Err(err(
                                w.col,
                                ErrorKind::Negative,
                                format!("negative diameter D{}", w.num),
                            ));
                        }
                    }
                    _ => {
                        return Err(err(
                            w.col,
                            ErrorKind::UnusedWords,
                            format!("unknown tool field '{}'", letter as char),
                        ))
                    }
                }
            }
            table.tools.insert(number, tool);
        }
        Ok(table)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_linuxcnc_tool_file_reads_lengths_and_diameters_in_mm() {
        let t = ToolTable::parse(
            "T1 P1 Z12.5 D6.0 ;end mill\n\nt2 p2 z-0.0005 d.5\n",
            "tools",
        )
        .unwrap();
        assert_eq!(
            t.get(1),
            Some(Tool {
                offset: [0, 0, 12_500_000, 0, 0, 0],
                diameter_nm: 6_000_000
            })
        );
        assert_eq!(t.get(2).unwrap().offset[2], -500);
        assert_eq!(t.len(), 2);
    }

    #[test]
    fn a_tool_listed_twice_is_rejected_with_its_line() {
        let e = ToolTable::parse("T1 Z1\nT1 Z2\n", "tools").unwrap_err();
        assert_eq!(e.to_string(), "tools:2:1: tool T1 listed twice");
    }

    #[test]
    fn codes_in_a_tool_file_are_rejected() {
        let e = ToolTable::parse("T1 Z1\nG0 X1\n", "tools").unwrap_err();
        assert_eq!(
            e.to_string(),
            "tools:2:1: a tool line holds T P X Y Z A B C D I J Q words only"
        );
    }

    #[test]
    fn offsets_along_every_pose_axis_are_read_and_uvw_refused_by_name() {
        let t = ToolTable::parse("T3 X1 Y-2 Z3 A4 B5.5 C-6\n", "tools").unwrap();
        let off = t.get(3).unwrap().offset;
        assert_eq!(
            off,
            [
                1_000_000,
                -2_000_000,
                3_000_000,
                4_000_000_000,
                5_500_000_000,
                -6_000_000_000
            ]
        );
        let e = ToolTable::parse("T3 U1 Z1\n", "tools").unwrap_err();
        assert!(e.message.starts_with("unsupported: U V W axes"), "{e}");
        assert_eq!(e.col, 4);
    }
}
