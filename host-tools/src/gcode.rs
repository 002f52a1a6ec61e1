//! G-code front end (skeleton dialect): parser and modal interpreter.
//!
//! Accepts G0 G1, G17 (XY plane, the only one yet), G20 G21, G90 G91, G94, M2 M30, F,
//! N, X Y Z A B C, `( )` and `;` comments, `%` delimiter lines and blank lines.
//! Numbers are read as exact decimals and converted to axis units (nm, n°) with one
//! rounding, so `X10.0001` is exactly 10 000 100 nm. Every error names
//! `file:line:col` and what is wrong; the whole program is checked before anything is
//! sent, and every error found is reported, not just the first.

use pkmc::config::AXES;
use pkmc::protocol::{Block, Motion};
use pkmc::units::{NDEG_PER_DEG, NM_PER_MM};
use std::fmt;

/// Longest line accepted, characters.
pub const MAX_LINE: usize = 256;

/// A decimal number as written: `mantissa / 10^scale`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Decimal {
    /// Digits as an integer, signed.
    pub mantissa: i128,
    /// Digits after the point.
    pub scale: u32,
}

impl Decimal {
    /// `self × factor`, rounded to the nearest integer (ties away from zero).
    pub fn times(&self, factor: i128) -> i128 {
        pkmc::units::div_round(self.mantissa * factor, 10i128.pow(self.scale))
    }
    /// `self × num / den`, rounded to the nearest integer.
    pub fn times_ratio(&self, num: i128, den: i128) -> i128 {
        pkmc::units::div_round(self.mantissa * num, 10i128.pow(self.scale) * den)
    }
    /// Whole-number value, if it is one (as G and M codes must be here).
    pub fn as_int(&self) -> Option<i64> {
        let p = 10i128.pow(self.scale);
        (self.mantissa % p == 0).then(|| (self.mantissa / p) as i64)
    }
    fn as_f64(&self) -> f64 {
        self.mantissa as f64 / 10f64.powi(self.scale as i32)
    }
}

/// One letter-number word with the column it starts at (1-based).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Word {
    /// Upper-case letter.
    pub letter: char,
    /// Its number.
    pub value: Decimal,
    /// Column of the letter, 1-based.
    pub col: usize,
}

/// A located error.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Diagnostic {
    /// File name as given.
    pub file: String,
    /// Line, 1-based.
    pub line: usize,
    /// Column, 1-based.
    pub col: usize,
    /// What is wrong.
    pub message: String,
}

impl fmt::Display for Diagnostic {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}:{}:{}: {}",
            self.file, self.line, self.col, self.message
        )
    }
}

/// Splits one line into words; `Err((col, message))` on bad syntax.
pub fn parse_line(text: &str) -> Result<Vec<Word>, (usize, String)> {
    let chars: Vec<char> = text.chars().collect();
    if chars.len() > MAX_LINE {
        return Err((
            MAX_LINE + 1,
            format!("line longer than {MAX_LINE} characters"),
        ));
    }
    let mut words = Vec::new();
    let mut i = 0;
    while i < chars.len() {
        let c = chars[i];
        let col = i + 1;
        match c {
            ' ' | '\t' | '\r' => i += 1,
            ';' => break,
            '(' => match chars[i..].iter().position(|&c| c == ')') {
                Some(end) => i += end + 1,
                None => return Err((col, "comment opened here is never closed".into())),
            },
            c if c.is_ascii_alphabetic() => {
                let letter = c.to_ascii_uppercase();
                i += 1;
                let (value, used) = parse_number(&chars[i..])
                    .map_err(|m| (i + 1, format!("{m} after '{letter}'")))?;
                i += used;
                words.push(Word { letter, value, col });
            }
            c if c.is_control() || !c.is_ascii() => {
                return Err((col, format!("unexpected character {:?}", c)));
            }
            c => return Err((col, format!("unexpected '{c}'"))),
        }
    }
    Ok(words)
}

/// Reads `[+-]digits[.digits]` (spaces allowed between characters); returns the value
/// and the characters used.
fn parse_number(chars: &[char]) -> Result<(Decimal, usize), String> {
    let mut i = 0;
    let skip = |i: &mut usize| {
        while *i < chars.len() && (chars[*i] == ' ' || chars[*i] == '\t') {
            *i += 1;
        }
    };
    skip(&mut i);
    let mut negative = false;
    if i < chars.len() && (chars[i] == '+' || chars[i] == '-') {
        negative = chars[i] == '-';
        i += 1;
        skip(&mut i);
    }
    let (mut mantissa, mut scale, mut digits, mut point) = (0i128, 0u32, 0, false);
    while i < chars.len() {
        match chars[i] {
            d @ '0'..='9' => {
                if digits >= 30 {
                    return Err("number with too many digits".into());
                }
                mantissa = mantissa * 10 + (d as u8 - b'0') as i128;
                digits += 1;
                if point {
                    scale += 1;
                }
            }
            '.' if !point => point = true,
            '.' => return Err("malformed number (two decimal points)".into()),
            ' ' | '\t' => {}
            _ => break,
        }
        i += 1;
    }
    if digits == 0 {
        return Err("missing number".into());
    }
    if negative {
        mantissa = -mantissa;
    }
    Ok((Decimal { mantissa, scale }, i))
}

/// Units of length in force.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Units {
    Mm,
    Inch,
}

/// Modal state of the interpreter.
#[derive(Clone, Debug)]
pub struct Interpreter {
    units: Units,
    absolute: bool,
    motion: Option<Motion>,
    /// Feed in user units per minute as written (converted per block).
    feed: Option<Decimal>,
    /// Current programmed pose, axis units.
    pub pose: [i64; AXES],
    ended: bool,
}

impl Interpreter {
    /// An interpreter starting at `pose` in mm, G90, G17, G94, no feed.
    pub fn new(pose: [i64; AXES]) -> Self {
        Self {
            units: Units::Mm,
            absolute: true,
            motion: None,
            feed: None,
            pose,
            ended: false,
        }
    }

    /// Interprets one line's words; returns the block it produces, if any.
    pub fn line(&mut self, words: &[Word], line: u32) -> Result<Option<Block>, (usize, String)> {
        let mut motion_word: Option<(Motion, usize)> = None;
        let mut axes: [Option<(Decimal, usize)>; AXES] = [None; AXES];
        let mut units_word: Option<usize> = None;
        let mut distance_word: Option<usize> = None;
        for w in words {
            match w.letter {
                'G' => {
                    let code = w.value.as_int().ok_or((w.col, unsupported("G", w.value)))?;
                    let mut set_motion = |m: Motion| {
                        match motion_word {
                        Some((_, c)) => Err((
                            w.col,
                            format!("G{code} conflicts with the motion code at column {c} (same modal group)"),
                        )),
                        None => {
                            motion_word = Some((m, w.col));
                            Ok(())
                        }
                    }
                    };
                    match code {
                        0 => set_motion(Motion::Rapid)?,
                        1 => set_motion(Motion::Linear)?,
                        17 | 94 => {}
                        20 | 21 => {
                            if let Some(c) = units_word {
                                return Err((
                                    w.col,
                                    format!("G{code} conflicts with the units code at column {c}"),
                                ));
                            }
                            units_word = Some(w.col);
                            self.units = if code == 20 { Units::Inch } else { Units::Mm };
                        }
                        90 | 91 => {
                            if let Some(c) = distance_word {
                                return Err((w.col, format!("G{code} conflicts with the distance-mode code at column {c}")));
                            }
                            distance_word = Some(w.col);
                            self.absolute = code == 90;
                        }
                        _ => return Err((w.col, unsupported("G", w.value))),
                    }
                }
                'M' => match w.value.as_int() {
                    Some(2) | Some(30) => self.ended = true,
                    _ => return Err((w.col, unsupported("M", w.value))),
                },
                'F' => {
                    if w.value.mantissa <= 0 {
                        return Err((w.col, "feed must be positive".into()));
                    }
                    self.feed = Some(w.value);
                }
                'N' => {}
                letter => match pkmc::config::AXIS_NAMES.iter().position(|&a| a == letter) {
                    Some(i) => {
                        if let Some((_, c)) = axes[i] {
                            return Err((
                                w.col,
                                format!("{letter} given twice (first at column {c})"),
                            ));
                        }
                        axes[i] = Some((w.value, w.col));
                    }
                    None => return Err((w.col, format!("unknown word '{letter}'"))),
                },
            }
        }
        if let Some((m, _)) = motion_word {
            self.motion = Some(m);
        }
        let first_axis = axes.iter().flatten().map(|(_, c)| *c).min();
        let Some(axis_col) = first_axis else {
            return Ok(None);
        };
        if self.ended {
            return Err((
                axis_col,
                "motion after the end of the program (M2/M30)".into(),
            ));
        }
        let motion = self.motion.ok_or((
            axis_col,
            "coordinates without a motion mode (G0 or G1)".to_string(),
        ))?;
        let mut target = self.pose;
        for (i, a) in axes.iter().enumerate() {
            if let Some((v, _)) = a {
                let units = if i >= 3 {
                    v.times(NDEG_PER_DEG as i128)
                } else if self.units == Units::Inch {
                    v.times_ratio(254 * NM_PER_MM as i128, 10)
                } else {
                    v.times(NM_PER_MM as i128)
                };
                let units = i64::try_from(units).map_err(|_| {
                    (
                        axis_col,
                        format!(
                            "{} value {} out of range",
                            pkmc::config::AXIS_NAMES[i],
                            v.as_f64()
                        ),
                    )
                })?;
                target[i] = if self.absolute {
                    units
                } else {
                    target[i].saturating_add(units)
                };
            }
        }
        let feed = match motion {
            Motion::Rapid | Motion::Arc { .. } | Motion::Dwell(_) | Motion::Aux(_) => 0,
            Motion::Linear => {
                let f = self.feed.ok_or((
                    motion_word.map_or(axis_col, |(_, c)| c),
                    "G1 without a feed (F)".to_string(),
                ))?;
                let linear_moves = (0..3).any(|i| target[i] != self.pose[i]);
                // nm/s from mm/min (or in/min); rotary-only moves: µ°/s from °/min.
                let per_unit = if self.units == Units::Inch && linear_moves {
                    254 * NM_PER_MM as i128 / 10
                } else {
                    NM_PER_MM as i128
                };
                i64::try_from(f.times_ratio(per_unit, 60))
                    .unwrap_or(i64::MAX)
                    .max(1)
            }
        };
        self.pose = target;
        Ok(Some(Block {
            line,
            motion,
            target,
            feed,
            tolerance_nm: u32::MAX,
        }))
    }
}

fn unsupported(letter: &str, v: Decimal) -> String {
    format!("unsupported code {letter}{}", v.as_f64())
}

/// Parses and interprets a whole program; returns its blocks, or every error found.
pub fn compile(
    source: &str,
    file: &str,
    start: [i64; AXES],
) -> Result<Vec<Block>, Vec<Diagnostic>> {
    let mut interp = Interpreter::new(start);
    let mut blocks = Vec::new();
    let mut errors = Vec::new();
    for (n, raw) in source.split('\n').enumerate() {
        let line = n + 1;
        let text = raw.trim_end_matches('\r');
        if text.trim() == "%" {
            continue;
        }
        let result = parse_line(text).and_then(|w| interp.line(&w, line as u32));
        match result {
            Ok(Some(b)) => blocks.push(b),
            Ok(None) => {}
            Err((col, message)) => errors.push(Diagnostic {
                file: file.to_string(),
                line,
                col,
                message,
            }),
        }
    }
    if errors.is_empty() {
        Ok(blocks)
    } else {
        Err(errors)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn one(src: &str) -> Result<Vec<Block>, Vec<Diagnostic>> {
        compile(src, "t.ngc", [0; AXES])
    }

    #[test]
    fn decimal_coordinates_convert_exactly() {
        let b = one("G1 X10.0001 Y-.5 Z+3 F600").unwrap();
        assert_eq!(b[0].target[..3], [10_000_100, -500_000, 3_000_000]);
        assert_eq!(b[0].feed, 10_000_000);
    }

    #[test]
    fn inch_and_incremental_modes_apply() {
        let b = one("G20 G91 G1 X1 F10\nX1").unwrap();
        assert_eq!(b[0].target[0], 25_400_000);
        assert_eq!(b[1].target[0], 50_800_000);
    }

    #[test]
    fn comments_and_case_are_ignored() {
        let b = one("(start) g0 x1 ; done\n%\n").unwrap();
        assert_eq!(b[0].target[0], 1_000_000);
        assert_eq!(b[0].motion, Motion::Rapid);
    }

    #[test]
    fn feed_move_without_feed_is_rejected_with_its_location() {
        let e = one("G0 X1\nG1 X2").unwrap_err();
        assert_eq!(e[0].to_string(), "t.ngc:2:1: G1 without a feed (F)");
    }

    #[test]
    fn every_error_of_a_program_is_reported() {
        let e = one("G1 X1 F1 (open\nG5 X1\nQ1\nG0 G1 X2\nG1 X1.2.3").unwrap_err();
        let lines: Vec<_> = e.iter().map(|d| (d.line, d.col)).collect();
        assert_eq!(lines, vec![(1, 10), (2, 1), (3, 1), (4, 4), (5, 5)]);
        assert!(e[3].message.contains("modal group"));
    }
}
