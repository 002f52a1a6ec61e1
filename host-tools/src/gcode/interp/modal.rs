//! Modal groups: which modal group each G and M code is in, and the codes of one line
//! sorted into their groups.
//!
//! Invariants: [`group_of`] is the one place that knows a code's group, or why the code
//! is refused (unknown, or a LinuxCNC feature not implemented, by name); a line holds at
//! most one code per group, except G80 beside another motion code (LinuxCNC's safety
//! lines `G0 G17 G40 G49 G80 G90`: the other code is the motion) and M7 with M8 (mist
//! and flood). Codes are checked in line order, G codes before M codes, so the first
//! error of a line is the same whatever else the line holds.
//!
//! Source: LinuxCNC G-code overview (modal groups) and its interpreter's
//! `interp_array.cc` (`_gees`, `_ems`).

use super::{fail, LineError, Res};
use crate::gcode::lexer::{Code, Words};
use crate::gcode::unsupported;
use crate::gcode::ErrorKind;

/// A modal group of G codes (the first 14) or M codes (the last 4).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Group {
    /// G4 G10 G28 G28.1 G30 G30.1 G53 G92 G92.1 G92.2 G92.3.
    NonModal,
    /// G0 G1 G2 G3 G5 G5.1 G73 G80 G81 G82 G83 G85 G89.
    Motion,
    /// G17 G18 G19.
    Plane,
    /// G90 G91.
    Distance,
    /// G90.1 G91.1.
    ArcDistance,
    /// G93 G94.
    FeedMode,
    /// G20 G21.
    Units,
    /// G40 G41 G41.1 G42 G42.1.
    Cutter,
    /// G43 G49.
    ToolLength,
    /// G98 G99.
    Retract,
    /// G54 … G59.3.
    System,
    /// G61 G61.1 G64.
    Path,
    /// G97.
    SpindleMode,
    /// G8.
    LatheMode,
    /// M0 M1 M2 M30.
    Stop,
    /// M6 M61.
    ToolChange,
    /// M3 M4 M5.
    Spindle,
    /// M7 M8 M9.
    Coolant,
}

impl Group {
    /// The group's bit in [`Modal::groups`].
    #[inline(always)]
    pub(crate) const fn bit(self) -> u32 {
        1 << self as usize
    }
}

/// Number of groups.
const GROUPS: usize = 18;

/// Names of the groups, in the order of [`Group`].
const GROUP_NAMES: [&str; GROUPS] = [
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
    "stopping",
    "tool-change",
    "spindle",
    "coolant",
];

/// `G28.1` from ten times the number.
pub(crate) fn code_name(letter: char, tenths: i32) -> String {
    if tenths % 10 == 0 {
        format!("{letter}{}", tenths / 10)
    } else {
        format!("{letter}{}.{}", tenths / 10, tenths % 10)
    }
}

/// The modal group of code `letter` (`G` or `M`) `tenths` (ten times its number), or
/// why it is refused.
pub(crate) fn group_of(letter: char, tenths: i32) -> Result<Group, (ErrorKind, String)> {
    use Group::*;
    Ok(match (letter, tenths) {
        ('G', 0 | 10 | 20 | 30 | 50 | 51 | 382..=385 | 730 | 800 | 810 | 820 | 830 | 850 | 890) => {
            Motion
        }
        ('G', 170 | 180 | 190) => Plane,
        ('G', 900 | 910) => Distance,
        ('G', 901 | 911) => ArcDistance,
        ('G', 930 | 940) => FeedMode,
        ('G', 200 | 210) => Units,
        ('G', 400 | 410 | 411 | 420 | 421) => Cutter,
        ('G', 430 | 431 | 490) => ToolLength,
        ('G', 980 | 990) => Retract,
        ('G', 540 | 550 | 560 | 570 | 580 | 590 | 591 | 592 | 593) => System,
        ('G', 610 | 611 | 640) => Path,
        ('G', 40 | 100 | 280 | 281 | 300 | 301 | 520 | 530 | 920 | 921 | 922 | 923) => NonModal,
        ('G', 970) => SpindleMode,
        ('G', 80) => LatheMode,
        ('M', 0 | 10 | 20 | 300) => Stop,
        ('M', 60 | 610) => ToolChange,
        ('M', 30 | 40 | 50) => Spindle,
        ('M', 70 | 80 | 90) => Coolant,
        _ => return Err(refusal(letter, tenths)),
    })
}

/// Why code `letter` `tenths`, which is in no group here, is refused.
fn refusal(letter: char, tenths: i32) -> (ErrorKind, String) {
    let feature = match (letter, tenths) {
        ('G', 52) => "G5.2 NURBS blocks",
        ('G', 53) => "G5.3 NURBS blocks",
        ('G', 70) => "G7 lathe diameter mode",
        ('G', 171 | 181 | 191) => "G17.1 G18.1 G19.1 (UVW planes)",
        ('G', 330 | 331) => "G33 spindle-synchronized motion",
        ('G', 432) => "G43.2 additional tool length offset",
        ('G', 700 | 710 | 711 | 712 | 720 | 721 | 722) => "G70-G72 lathe cycles",
        ('G', 740 | 840) => "G74/G84 tapping cycles",
        ('G', 760) => "G76 threading cycle",
        ('G', 860 | 870 | 880) => "G86-G88 boring cycles",
        ('G', 950) => "G95 feed per revolution",
        ('G', 960) => "G96 constant surface speed",
        ('M', 190) => "M19 spindle orientation",
        ('M', 480..=530) => "M48-M53 override control",
        ('M', 600) => "M60 pallet change",
        ('M', 620..=680) => "M62-M68 digital and analog I/O",
        ('M', 700..=730) => "M70-M73 modal state save and restore",
        ('M', 1000..=1990) => "M100-M199 user-defined M codes",
        ('M', 980 | 990) => "M98/M99 subprogram calls (Fanuc style)",
        ('M', 270) => "M27 (a machine-specific code some posts write; not in LinuxCNC)",
        _ => {
            return (
                ErrorKind::UnknownCode,
                format!("unknown code {}", code_name(letter, tenths)),
            )
        }
    };
    (ErrorKind::Unsupported, unsupported(feature))
}

/// Which of two codes of `group` on one line the group keeps, or `None` when they
/// conflict.
fn kept(group: Group, first: Code, next: Code) -> Option<Code> {
    match (group, first.tenths, next.tenths) {
        // G80 with another motion code: the other code is the motion.
        (Group::Motion, 800, _) => Some(next),
        (Group::Motion, _, 800) => Some(first),
        // M7 and M8 may share a line.
        (Group::Coolant, 70, 80) | (Group::Coolant, 80, 70) => Some(next),
        _ => None,
    }
}

/// The G and M codes of one line, by modal group.
///
/// A bit per group says whether it has a code; the code itself is only read when it
/// does, so a line's twenty-odd questions "is there a code of this group?" read one
/// word. (An array of `Option<Code>`, each tag tested, was cleared by a `memset` call
/// per line and cost about 3 % more of the compile time of arcspiral.ngc.)
#[derive(Clone, Copy, Debug)]
pub(crate) struct Modal {
    /// Groups with a code on the line, bit `group as usize`.
    present: u32,
    /// The code of each group in `present`.
    codes: [Code; GROUPS],
}

impl Modal {
    /// No code in any group.
    pub(crate) const EMPTY: Modal = Modal {
        present: 0,
        codes: [Code { tenths: 0, col: 0 }; GROUPS],
    };

    /// Sorts the line's G codes, then its M codes, into their groups in `self` (which
    /// must be [`Modal::EMPTY`]); a refused code or a second code of one group is an
    /// error at its column. In place: the interpreter builds each line's block without
    /// copying the groups through a `Result` (a few hundred bytes a line, 5 % of the
    /// parse time).
    pub(crate) fn fill(&mut self, w: &Words) -> Res<()> {
        for (letter, list) in [('G', &w.g), ('M', &w.m)] {
            for &c in list {
                self.add(letter, c)?;
            }
        }
        Ok(())
    }

    fn add(&mut self, letter: char, c: Code) -> Res<()> {
        let group = group_of(letter, c.tenths)
            .map_err(|(kind, message)| LineError::boxed(c.col, kind, message))?;
        let bit = 1 << group as usize;
        let slot = &mut self.codes[group as usize];
        *slot = match self.present & bit {
            0 => c,
            _ => match kept(group, *slot, c) {
                Some(keep) => keep,
                None => {
                    let first = *slot;
                    return fail(
                        c.col,
                        ErrorKind::ModalGroup,
                        format!(
                            "{} conflicts with {} at column {} (both in the {} modal group)",
                            code_name(letter, c.tenths),
                            code_name(letter, first.tenths),
                            first.col,
                            GROUP_NAMES[group as usize]
                        ),
                    );
                }
            },
        };
        self.present |= bit;
        Ok(())
    }

    /// The groups with a code on the line, one bit each ([`Group::bit`]).
    #[inline(always)]
    pub(crate) fn groups(&self) -> u32 {
        self.present
    }

    /// The line's code of `group`, if it has one.
    #[inline]
    pub(crate) fn get(&self, group: Group) -> Option<Code> {
        (self.present & 1 << group as usize != 0).then(|| self.codes[group as usize])
    }
}
