//! Lexer and expression evaluator: one line of text into [`Words`].
//!
//! A word is a letter and a value: a literal number (kept as an exact decimal, see
//! [`Num`]), a `[bracketed expression]`, a parameter read (`#1`, `#<name>`,
//! `#<_global>`, `##1`) or a unary function (`X SIN[30]`). Expressions are evaluated
//! while the line is read, against the parameter values from before the line: a
//! parameter setting (`#1=…`) is only recorded here and applied by the interpreter
//! after the line's other words (the RS-274/NGC rule). Spaces and tabs may appear
//! anywhere outside comments, even inside numbers and names (`G 1 X1 0` is `G1 X10`);
//! letters, names and operators are case-insensitive.
//!
//! Invariants: the lexer never allocates per word (the [`Words`] buffer is reused for
//! every line; only comments shown to the operator and named-parameter settings
//! allocate); recursion is bounded by [`MAX_NESTING`]; control characters are errors
//! everywhere, comments included, and are reported at their column.
//!
//! Source: LinuxCNC G-code overview (numbers, parameters, expressions, binary operators
//! and their precedence, functions, comments, messages, checksums).

use super::params::{Params, NUM_PARAMS};
use super::{unsupported, MAX_NESTING};
use std::fmt;

/// Powers of ten that fit an `i64`.
const POW10: [i64; 19] = [
    1,
    10,
    100,
    1_000,
    10_000,
    100_000,
    1_000_000,
    10_000_000,
    100_000_000,
    1_000_000_000,
    10_000_000_000,
    100_000_000_000,
    1_000_000_000_000,
    10_000_000_000_000,
    100_000_000_000_000,
    1_000_000_000_000_000,
    10_000_000_000_000_000,
    100_000_000_000_000_000,
    1_000_000_000_000_000_000,
];

/// Most digits after the decimal point of a literal.
pub const MAX_DECIMALS: u32 = 18;

/// Tolerance within which a computed value counts as a whole number (LinuxCNC's).
const WHOLE_TOLERANCE: f64 = 1e-4;

/// A word's value: an exact decimal as written, or a value computed in `f64`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Num {
    /// `mant / 10^scale`, exactly as written.
    Lit {
        /// Digits as a signed integer.
        mant: i64,
        /// Digits after the decimal point (at most [`MAX_DECIMALS`]).
        scale: u32,
    },
    /// Computed by an expression or read from a parameter.
    Real(f64),
}

impl Num {
    /// The value as `f64`.
    #[inline]
    pub fn to_f64(self) -> f64 {
        match self {
            Num::Lit { mant, scale } => mant as f64 / POW10[scale as usize] as f64,
            Num::Real(v) => v,
        }
    }

    /// `self × num / den` rounded to the nearest integer (ties away from zero), or
    /// `None` when that does not fit an `i64`. `den > 0`.
    #[inline]
    pub fn scaled(self, num: i64, den: i64) -> Option<i64> {
        match self {
            Num::Lit { mant, scale } => {
                if den == 1 {
                    if let Some(n) = mant.checked_mul(num) {
                        return Some(div_round_pow10(n, scale));
                    }
                } else if let (Some(n), Some(d)) = (
                    mant.checked_mul(num),
                    POW10[scale as usize].checked_mul(den),
                ) {
                    return Some(div_round_i64(n, d));
                }
                let p = POW10[scale as usize] as i128;
                let q = pkmc::units::div_round(mant as i128 * num as i128, p * den as i128);
                i64::try_from(q).ok()
            }
            Num::Real(v) => f64_to_i64(v * num as f64 / den as f64),
        }
    }

    /// The value as a whole number, if it is one (exactly for literals, within
    /// LinuxCNC's 0.0001 for computed values).
    pub fn whole(self) -> Option<i64> {
        match self {
            Num::Lit { mant, scale } => {
                let p = POW10[scale as usize];
                (mant % p == 0).then_some(mant / p)
            }
            Num::Real(v) => {
                let r = v.round();
                if (v - r).abs() < WHOLE_TOLERANCE {
                    f64_to_i64(r)
                } else {
                    None
                }
            }
        }
    }

    /// Ten times the value, if that is a whole number (G and M codes: `G28.1` is 281).
    pub fn tenths(self) -> Option<i64> {
        match self {
            Num::Lit { mant, scale: 0 } => mant.checked_mul(10),
            Num::Lit { mant, scale } => {
                let p = POW10[scale as usize - 1];
                (mant % p == 0).then_some(mant / p)
            }
            Num::Real(v) => {
                let t = v * 10.0;
                let r = t.round();
                if (t - r).abs() < 1e-3 {
                    f64_to_i64(r)
                } else {
                    None
                }
            }
        }
    }

    /// Is the value zero?
    pub fn is_zero(self) -> bool {
        match self {
            Num::Lit { mant, .. } => mant == 0,
            Num::Real(v) => v == 0.0,
        }
    }

    /// Is the value below zero?
    pub fn is_negative(self) -> bool {
        match self {
            Num::Lit { mant, .. } => mant < 0,
            Num::Real(v) => v < 0.0,
        }
    }
}

impl fmt::Display for Num {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Num::Lit { mant, scale: 0 } => write!(f, "{mant}"),
            Num::Lit { mant, scale } => {
                let p = POW10[scale as usize].unsigned_abs();
                let sign = if mant < 0 { "-" } else { "" };
                let m = mant.unsigned_abs();
                write!(
                    f,
                    "{sign}{}.{:0width$}",
                    m / p,
                    m % p,
                    width = scale as usize
                )
            }
            Num::Real(v) => write!(f, "{v}"),
        }
    }
}

/// Rounds `n / d` to the nearest integer, ties away from zero; `d > 0`.
#[inline(always)]
fn div_round_i64(n: i64, d: i64) -> i64 {
    let q = n / d;
    let r = n % d;
    // |r| >= d/2 rounds away from zero; compare without overflow.
    if r.unsigned_abs() >= d.unsigned_abs() - r.unsigned_abs() {
        if n < 0 {
            q - 1
        } else {
            q + 1
        }
    } else {
        q
    }
}

/// [`div_round_i64`] by a constant, which the compiler turns into a multiplication.
#[inline(always)]
fn div_round_const<const D: i64>(n: i64) -> i64 {
    div_round_i64(n, D)
}

/// Rounds `n / 10^scale` to the nearest integer, ties away from zero.
fn div_round_pow10(n: i64, scale: u32) -> i64 {
    match scale {
        0 => n,
        1 => div_round_const::<10>(n),
        2 => div_round_const::<100>(n),
        3 => div_round_const::<1_000>(n),
        4 => div_round_const::<10_000>(n),
        5 => div_round_const::<100_000>(n),
        6 => div_round_const::<1_000_000>(n),
        7 => div_round_const::<10_000_000>(n),
        8 => div_round_const::<100_000_000>(n),
        9 => div_round_const::<1_000_000_000>(n),
        s => div_round_i64(n, POW10[(s as usize).min(18)]),
    }
}

/// Rounds a finite `f64` to the nearest `i64` (ties away from zero), or `None` when it
/// is not finite or out of range.
#[inline]
pub(crate) fn f64_to_i64(v: f64) -> Option<i64> {
    // 2^63 is exactly representable; everything strictly inside converts. Rounding by
    // hand avoids a libm call on baseline x86-64.
    const LIMIT: f64 = 9_223_372_036_854_775_000.0;
    if !(v > -LIMIT && v < LIMIT) {
        return None;
    }
    let t = v as i64;
    let frac = v - t as f64;
    Some(if frac >= 0.5 {
        t + 1
    } else if frac <= -0.5 {
        t - 1
    } else {
        t
    })
}

/// A letter word's value and where it starts.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Word {
    /// Value.
    pub num: Num,
    /// Column of the letter, 1-based.
    pub col: u32,
}

/// A G or M word: ten times its number (`G28.1` is 281) and its column.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Code {
    /// Ten times the code number.
    pub tenths: i32,
    /// Column of the letter, 1-based.
    pub col: u32,
}

/// Which parameter a setting writes.
#[derive(Clone, Debug, PartialEq)]
pub enum ParamRef {
    /// `#n`.
    Numbered(usize),
    /// `#<name>`, normalised (lower case, no blanks).
    Named(Box<[u8]>),
}

/// A parameter setting, applied after the line.
#[derive(Clone, Debug, PartialEq)]
pub struct Assign {
    /// Parameter.
    pub target: ParamRef,
    /// New value.
    pub value: f64,
    /// Column of the `#`, 1-based.
    pub col: u32,
}

/// The words of one line. Reused for every line: [`scan_line`] clears it.
#[derive(Clone, Debug)]
pub struct Words {
    present: u32,
    vals: [Word; 26],
    /// G words in order.
    pub g: Vec<Code>,
    /// M words in order.
    pub m: Vec<Code>,
    /// `@` polar radius.
    pub polar_radius: Option<Word>,
    /// `^` polar angle, degrees.
    pub polar_angle: Option<Word>,
    /// Parameter settings in order.
    pub assigns: Vec<Assign>,
    /// `(MSG, …)` texts in order.
    pub messages: Vec<String>,
    /// Column of the first axis, I J K or polar word (0: none).
    pub first_motion_col: u32,
}

impl Default for Words {
    fn default() -> Self {
        Self {
            present: 0,
            vals: [Word {
                num: Num::Real(0.0),
                col: 0,
            }; 26],
            g: Vec::new(),
            m: Vec::new(),
            polar_radius: None,
            polar_angle: None,
            assigns: Vec::new(),
            messages: Vec::new(),
            first_motion_col: 0,
        }
    }
}

/// Bit of a letter in [`Words::present`].
pub const fn bit(letter: u8) -> u32 {
    1 << (letter - b'A')
}

/// Letters of words that position a move: X Y Z A B C I J K.
const MOTION_LETTERS: u32 = bit(b'X')
    | bit(b'Y')
    | bit(b'Z')
    | bit(b'A')
    | bit(b'B')
    | bit(b'C')
    | bit(b'I')
    | bit(b'J')
    | bit(b'K');

impl Words {
    fn clear(&mut self) {
        self.present = 0;
        self.g.clear();
        self.m.clear();
        self.polar_radius = None;
        self.polar_angle = None;
        self.assigns.clear();
        self.messages.clear();
        self.first_motion_col = 0;
    }

    /// The word of `letter` (upper case, not G or M), if the line has one.
    #[inline]
    pub fn get(&self, letter: u8) -> Option<Word> {
        (self.present & bit(letter) != 0).then(|| self.vals[(letter - b'A') as usize])
    }

    /// Letters present, one bit each (A = bit 0).
    pub fn present(&self) -> u32 {
        self.present
    }
}

/// The column in characters (1-based) of byte column `byte_col` (1-based) of `text`.
pub fn char_col(text: &str, byte_col: u32) -> usize {
    let i = (byte_col as usize).saturating_sub(1);
    match text.get(..i) {
        Some(before) if !before.is_ascii() => before.chars().count() + 1,
        _ => i + 1,
    }
}

/// A lexical error: column (1-based, in bytes: see [`char_col`]) and message.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LexError {
    /// Column, 1-based.
    pub col: u32,
    /// What is wrong.
    pub message: String,
}

/// Reads `text[start..]` (the line without its block-delete slash; columns count from
/// the start of `text`) into `words`, evaluating values against `params`.
pub fn scan_line(
    text: &str,
    start: usize,
    params: &Params,
    words: &mut Words,
) -> Result<(), LexError> {
    words.clear();
    let mut c = Cursor {
        b: text.as_bytes(),
        text,
        i: start,
        params,
    };
    c.line(words)
}

/// Binary operators.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Op {
    Pow,
    Mul,
    Div,
    Mod,
    Add,
    Sub,
    Eq,
    Ne,
    Gt,
    Ge,
    Lt,
    Le,
    And,
    Or,
    Xor,
}

impl Op {
    /// LinuxCNC's precedence: logical 2, comparison 3, additive 4, multiplicative 5,
    /// power 6; all left-associative.
    fn precedence(self) -> u8 {
        match self {
            Op::And | Op::Or | Op::Xor => 2,
            Op::Eq | Op::Ne | Op::Gt | Op::Ge | Op::Lt | Op::Le => 3,
            Op::Add | Op::Sub => 4,
            Op::Mul | Op::Div | Op::Mod => 5,
            Op::Pow => 6,
        }
    }
}

/// Tolerance of EQ and NE (LinuxCNC's).
const EQUAL_TOLERANCE: f64 = 1e-6;

struct Cursor<'a> {
    b: &'a [u8],
    text: &'a str,
    i: usize,
    params: &'a Params,
}

impl Cursor<'_> {
    /// Column of byte `i`, 1-based, counted in bytes: [`char_col`] turns it into a
    /// column in characters when a diagnostic is made (only then, to keep the hot loop
    /// free of UTF-8 counting).
    #[inline]
    fn col(&self, i: usize) -> u32 {
        u32::try_from(i + 1).unwrap_or(u32::MAX)
    }

    fn err(&self, i: usize, message: impl Into<String>) -> LexError {
        LexError {
            col: self.col(i),
            message: message.into(),
        }
    }

    fn skip_blanks(&mut self) {
        while let Some(b' ' | b'\t') = self.b.get(self.i) {
            self.i += 1;
        }
    }

    /// The next non-blank byte (consumes the blanks).
    fn peek(&mut self) -> Option<u8> {
        self.skip_blanks();
        self.b.get(self.i).copied()
    }

    /// Error for an unexpected byte at `self.i`.
    fn unexpected(&self, what: &str) -> LexError {
        let i = self.i;
        match self.b.get(i) {
            None => self.err(i, format!("{what}, found the end of the line")),
            Some(&c) if c < 0x20 || c == 0x7f => self.control(i),
            Some(_) => {
                let ch = self
                    .text
                    .get(i..)
                    .and_then(|s| s.chars().next())
                    .unwrap_or('?');
                self.err(i, format!("{what}, found '{ch}'"))
            }
        }
    }

    fn control(&self, i: usize) -> LexError {
        let c = self.b.get(i).copied().unwrap_or(0);
        self.err(
            i,
            format!("control character U+{c:04X} (binary data, not G-code text)"),
        )
    }

    /// Checks that `self.b[from..to]` holds no control character.
    fn check_text(&self, from: usize, to: usize) -> Result<(), LexError> {
        match self.b[from..to]
            .iter()
            .position(|&c| (c < 0x20 && c != b'\t') || c == 0x7f)
        {
            Some(p) => Err(self.control(from + p)),
            None => Ok(()),
        }
    }

    fn line(&mut self, words: &mut Words) -> Result<(), LexError> {
        while self.i < self.b.len() {
            let c = self.b[self.i];
            match c {
                b' ' | b'\t' => self.i += 1,
                b'(' => self.comment(words)?,
                b';' => {
                    self.check_text(self.i + 1, self.b.len())?;
                    return Ok(());
                }
                b'*' => return self.checksum(),
                b'#' => self.assignment(words)?,
                b'@' | b'^' => {
                    let col = self.col(self.i);
                    self.i += 1;
                    let num = self.value(c as char, 0)?;
                    let slot = if c == b'@' {
                        &mut words.polar_radius
                    } else {
                        &mut words.polar_angle
                    };
                    if let Some(first) = slot {
                        return Err(LexError {
                            col,
                            message: format!(
                                "{} given twice (first at column {})",
                                c as char, first.col
                            ),
                        });
                    }
                    *slot = Some(Word { num, col });
                    if words.first_motion_col == 0 {
                        words.first_motion_col = col;
                    }
                }
                c if c.is_ascii_alphabetic() => self.word(words)?,
                c if c < 0x20 || c == 0x7f => return Err(self.control(self.i)),
                _ => return Err(self.unexpected("expected a word (letter and value)")),
            }
        }
        Ok(())
    }

    fn word(&mut self, words: &mut Words) -> Result<(), LexError> {
        let at = self.i;
        let col = self.col(at);
        let letter = self.b[at].to_ascii_uppercase();
        self.i += 1;
        match letter {
            b'O' => {
                return Err(self.err(at, unsupported("O-word subroutines and control flow (O…)")))
            }
            b'U' | b'V' | b'W' => {
                return Err(self.err(at, unsupported(&format!("U V W axes ({})", letter as char))))
            }
            _ => {}
        }
        let known = matches!(
            letter,
            b'A'..=b'F' | b'G' | b'H' | b'I'..=b'N' | b'P'..=b'T' | b'X'..=b'Z'
        );
        if !known {
            return Err(self.err(at, format!("unknown word '{}'", letter as char)));
        }
        let num = self.value(letter as char, 0)?;
        match letter {
            b'G' | b'M' => {
                let tenths = num.tenths().filter(|t| (0..=99_990).contains(t));
                match tenths {
                    Some(tenths) => {
                        let tenths = tenths as i32; // 0..=99_990
                        let list = if letter == b'G' {
                            &mut words.g
                        } else {
                            &mut words.m
                        };
                        list.push(Code { tenths, col });
                    }
                    None => {
                        return Err(self.err(at, format!("unknown code {}{num}", letter as char)))
                    }
                }
            }
            _ => {
                let b = bit(letter);
                let slot = (letter - b'A') as usize;
                if words.present & b != 0 {
                    return Err(self.err(
                        at,
                        format!(
                            "{} given twice (first at column {})",
                            letter as char, words.vals[slot].col
                        ),
                    ));
                }
                words.present |= b;
                words.vals[slot] = Word { num, col };
                if b & MOTION_LETTERS != 0 && words.first_motion_col == 0 {
                    words.first_motion_col = col;
                }
            }
        }
        Ok(())
    }

    /// `( … )`: plain comment, or `(MSG, text)`.
    fn comment(&mut self, words: &mut Words) -> Result<(), LexError> {
        let open = self.i;
        let mut j = open + 1;
        loop {
            match self.b.get(j) {
                None => return Err(self.err(open, "comment opened here is never closed")),
                Some(b')') => break,
                Some(b'(') => {
                    return Err(self.err(j, "'(' inside a comment (comments do not nest)"))
                }
                Some(&c) if (c < 0x20 && c != b'\t') || c == 0x7f => return Err(self.control(j)),
                Some(_) => j += 1,
            }
        }
        self.i = j + 1;
        let body = self.text.get(open + 1..j).unwrap_or("");
        let t = body.trim_start();
        if t.len() >= 3 && t.as_bytes()[..3].eq_ignore_ascii_case(b"MSG") {
            if let Some(rest) = t[3..].trim_start().strip_prefix(',') {
                words.messages.push(rest.trim().to_string());
            }
        }
        Ok(())
    }

    /// `*n` checksum: the XOR of every byte before the `*` must equal n; only blanks
    /// and comments may follow.
    fn checksum(&mut self) -> Result<(), LexError> {
        let star = self.i;
        let sum = self.b[..star].iter().fold(0u8, |a, &b| a ^ b);
        self.i += 1;
        let given = match self.peek() {
            Some(b'0'..=b'9') => self.literal(star + 1)?,
            _ => return Err(self.unexpected("expected the checksum number after '*'")),
        };
        match given.whole() {
            Some(n) if n == i64::from(sum) => {}
            Some(n) if (0..=255).contains(&n) => {
                return Err(self.err(
                    star,
                    format!("checksum mismatch: the line says *{n} but its bytes give *{sum}"),
                ))
            }
            _ => {
                return Err(self.err(
                    star,
                    format!("checksum *{given} is not a whole number from 0 to 255"),
                ))
            }
        }
        loop {
            match self.peek() {
                None => return Ok(()),
                Some(b'(') => {
                    let mut ignored = Words::default();
                    self.comment(&mut ignored)?;
                }
                Some(b';') => return self.check_text(self.i + 1, self.b.len()),
                Some(_) => {
                    return Err(self.unexpected("expected the end of the line after the checksum"))
                }
            }
        }
    }

    /// `#n = value` or `#<name> = value`.
    fn assignment(&mut self, words: &mut Words) -> Result<(), LexError> {
        let at = self.i;
        let col = self.col(at);
        self.i += 1;
        let target = if self.peek() == Some(b'<') {
            let mut buf = NameBuf::new();
            self.name(&mut buf)?;
            ParamRef::Named(buf.as_slice().into())
        } else {
            ParamRef::Numbered(self.param_index(1)?)
        };
        if self.peek() != Some(b'=') {
            return Err(self.unexpected("expected '=' in a parameter setting"));
        }
        self.i += 1;
        let value = self.value('=', 0)?.to_f64();
        words.assigns.push(Assign { target, value, col });
        Ok(())
    }

    /// The value after a word letter (or `=`): a literal (exact), or anything else
    /// computed in `f64`.
    fn value(&mut self, after: char, depth: usize) -> Result<Num, LexError> {
        if self.peek().is_none() {
            return Err(self.unexpected(&format!("expected a value after '{after}'")));
        }
        let start = self.i;
        let c = self.b[start];
        let literal = match c {
            b'0'..=b'9' | b'.' => true,
            b'+' | b'-' => {
                // A sign starts a literal when a digit or point follows it.
                let mut j = start + 1;
                while let Some(b' ' | b'\t') = self.b.get(j) {
                    j += 1;
                }
                matches!(self.b.get(j), Some(b'0'..=b'9' | b'.'))
            }
            _ => false,
        };
        if literal {
            return self.literal(start);
        }
        match c {
            b'[' | b'#' | b'+' | b'-' => Ok(Num::Real(self.operand(depth)?)),
            c if c.is_ascii_alphabetic() && self.function_follows() => {
                Ok(Num::Real(self.operand(depth)?))
            }
            _ => Err(self.unexpected(&format!("expected a value after '{after}'"))),
        }
    }

    /// Do letters (and blanks) then `[` follow the cursor, as in a function call?
    fn function_follows(&self) -> bool {
        let mut j = self.i;
        while let Some(&c) = self.b.get(j) {
            if c.is_ascii_alphabetic() || c == b' ' || c == b'\t' {
                j += 1;
            } else {
                return c == b'[';
            }
        }
        false
    }

    /// `[+-] digits [. digits]`, blanks allowed between characters; starts at
    /// `self.i` (already at the sign or first digit). `col_at` is where a malformed
    /// number is reported.
    fn literal(&mut self, col_at: usize) -> Result<Num, LexError> {
        let start = self.i;
        let mut negative = false;
        if let Some(&s @ (b'+' | b'-')) = self.b.get(self.i) {
            negative = s == b'-';
            self.i += 1;
        }
        // The mantissa stays below 10^18 (18 significant digits), so it never overflows.
        const MANT_LIMIT: i64 = 99_999_999_999_999_999;
        let (mut mant, mut digits, mut point_at) = (0i64, 0u32, None);
        loop {
            while let Some(&c @ b'0'..=b'9') = self.b.get(self.i) {
                if mant > MANT_LIMIT {
                    return Err(self.err(start, "number with too many digits"));
                }
                mant = mant * 10 + i64::from(c - b'0');
                digits += 1;
                self.i += 1;
            }
            match self.b.get(self.i) {
                Some(b'.') if point_at.is_none() => point_at = Some(digits),
                Some(b'.') => {
                    return Err(self.err(col_at.min(start), "malformed number (two decimal points)"))
                }
                Some(b' ' | b'\t') => {}
                _ => break,
            }
            self.i += 1;
        }
        let scale = point_at.map_or(0, |p| digits - p);
        if scale > MAX_DECIMALS {
            return Err(self.err(
                start,
                format!("number with more than {MAX_DECIMALS} decimals"),
            ));
        }
        if digits == 0 {
            return Err(self.err(start, "malformed number (no digits)"));
        }
        Ok(Num::Lit {
            mant: if negative { -mant } else { mant },
            scale,
        })
    }

    /// One operand of an expression: number, `[expr]`, parameter, signed operand or
    /// function call.
    fn operand(&mut self, depth: usize) -> Result<f64, LexError> {
        if depth >= MAX_NESTING {
            return Err(self.err(
                self.i,
                format!("expression nested more than {MAX_NESTING} deep"),
            ));
        }
        match self.peek() {
            Some(b'0'..=b'9' | b'.') => {
                let at = self.i;
                Ok(self.literal(at)?.to_f64())
            }
            Some(b'[') => self.bracket(depth + 1),
            Some(b'#') => self.param_read(depth + 1),
            Some(b'-') => {
                self.i += 1;
                Ok(-self.operand(depth + 1)?)
            }
            Some(b'+') => {
                self.i += 1;
                self.operand(depth + 1)
            }
            Some(c) if c.is_ascii_alphabetic() => self.function(depth + 1),
            _ => Err(self.unexpected("expected a value")),
        }
    }

    /// `[ expr ]`, at the `[`.
    fn bracket(&mut self, depth: usize) -> Result<f64, LexError> {
        let open = self.i;
        self.i += 1;
        let v = self.binary(0, depth, open)?;
        match self.peek() {
            Some(b']') => {
                self.i += 1;
                Ok(v)
            }
            None => Err(self.err(open, "'[' opened here is never closed")),
            Some(_) => Err(self.unexpected("expected an operator or ']'")),
        }
    }

    /// Precedence climbing over binary operators, left-associative.
    fn binary(&mut self, min_prec: u8, depth: usize, open: usize) -> Result<f64, LexError> {
        let mut lhs = self.operand(depth)?;
        loop {
            let at = self.i;
            let Some((op, len)) = self.peek_op(open)? else {
                return Ok(lhs);
            };
            let prec = op.precedence();
            if prec < min_prec {
                self.i = at;
                return Ok(lhs);
            }
            self.i += len;
            let op_at = self.i - len;
            let rhs = self.binary(prec + 1, depth + 1, open)?;
            lhs = self.apply(op, lhs, rhs, op_at)?;
        }
    }

    /// The operator at the cursor (after blanks) and its length in bytes; `None` at
    /// `]`.
    fn peek_op(&mut self, open: usize) -> Result<Option<(Op, usize)>, LexError> {
        let c = match self.peek() {
            None => return Err(self.err(open, "'[' opened here is never closed")),
            Some(c) => c,
        };
        let start = self.i;
        let op = match c {
            b']' => return Ok(None),
            b'*' => {
                let mut j = start + 1;
                while let Some(b' ' | b'\t') = self.b.get(j) {
                    j += 1;
                }
                if self.b.get(j) == Some(&b'*') {
                    return Ok(Some((Op::Pow, j + 1 - start)));
                }
                Op::Mul
            }
            b'/' => Op::Div,
            b'+' => Op::Add,
            b'-' => Op::Sub,
            c if c.is_ascii_alphabetic() => {
                // Up to three letters, blanks allowed between them.
                let mut letters = [0u8; 3];
                let mut ends = [0usize; 3];
                let mut n = 0;
                let mut j = start;
                while n < 3 {
                    while let Some(b' ' | b'\t') = self.b.get(j) {
                        j += 1;
                    }
                    match self.b.get(j) {
                        Some(&l) if l.is_ascii_alphabetic() => {
                            letters[n] = l.to_ascii_uppercase();
                            j += 1;
                            ends[n] = j;
                            n += 1;
                        }
                        _ => break,
                    }
                }
                let three = match &letters[..n.min(3)] {
                    [b'M', b'O', b'D'] => Some(Op::Mod),
                    [b'A', b'N', b'D'] => Some(Op::And),
                    [b'X', b'O', b'R'] => Some(Op::Xor),
                    _ => None,
                };
                if let Some(op) = three {
                    return Ok(Some((op, ends[2] - start)));
                }
                let two = if n >= 2 {
                    match [letters[0], letters[1]] {
                        [b'E', b'Q'] => Some(Op::Eq),
                        [b'N', b'E'] => Some(Op::Ne),
                        [b'G', b'T'] => Some(Op::Gt),
                        [b'G', b'E'] => Some(Op::Ge),
                        [b'L', b'T'] => Some(Op::Lt),
                        [b'L', b'E'] => Some(Op::Le),
                        [b'O', b'R'] => Some(Op::Or),
                        _ => None,
                    }
                } else {
                    None
                };
                return match two {
                    Some(op) => Ok(Some((op, ends[1] - start))),
                    None => Err(self.unexpected("expected an operator or ']'")),
                };
            }
            _ => return Err(self.unexpected("expected an operator or ']'")),
        };
        Ok(Some((op, 1)))
    }

    fn apply(&self, op: Op, a: f64, b: f64, at: usize) -> Result<f64, LexError> {
        let bool = |v: bool| if v { 1.0 } else { 0.0 };
        let v = match op {
            Op::Pow => {
                if a < 0.0 && b.fract() != 0.0 {
                    return Err(self.err(at, "negative number raised to a fractional power"));
                }
                a.powf(b)
            }
            Op::Mul => a * b,
            Op::Div => {
                if b == 0.0 {
                    return Err(self.err(at, "division by zero"));
                }
                a / b
            }
            Op::Mod => {
                if b == 0.0 {
                    return Err(self.err(at, "division by zero (MOD 0)"));
                }
                let r = a % b;
                if r < 0.0 {
                    r + b.abs()
                } else {
                    r
                }
            }
            Op::Add => a + b,
            Op::Sub => a - b,
            Op::Eq => bool((a - b).abs() < EQUAL_TOLERANCE),
            Op::Ne => bool((a - b).abs() >= EQUAL_TOLERANCE),
            Op::Gt => bool(a > b),
            Op::Ge => bool(a >= b),
            Op::Lt => bool(a < b),
            Op::Le => bool(a <= b),
            Op::And => bool(a != 0.0 && b != 0.0),
            Op::Or => bool(a != 0.0 || b != 0.0),
            Op::Xor => bool((a != 0.0) != (b != 0.0)),
        };
        if v.is_finite() {
            Ok(v)
        } else {
            Err(self.err(at, "expression result out of range"))
        }
    }

    /// `NAME[expr]`, `ATAN[y]/[x]` or `EXISTS[#<name>]`, at the first letter.
    fn function(&mut self, depth: usize) -> Result<f64, LexError> {
        let at = self.i;
        let mut name = [0u8; 6];
        let mut n = 0;
        loop {
            self.skip_blanks();
            match self.b.get(self.i) {
                Some(&l) if l.is_ascii_alphabetic() => {
                    if n == name.len() {
                        return Err(self.err(at, "unknown function"));
                    }
                    name[n] = l.to_ascii_uppercase();
                    n += 1;
                    self.i += 1;
                }
                _ => break,
            }
        }
        let name = &name[..n];
        let shown = String::from_utf8_lossy(name).into_owned();
        let known = matches!(
            name,
            b"ABS"
                | b"ACOS"
                | b"ASIN"
                | b"ATAN"
                | b"COS"
                | b"EXP"
                | b"FIX"
                | b"FUP"
                | b"LN"
                | b"ROUND"
                | b"SIN"
                | b"SQRT"
                | b"TAN"
                | b"EXISTS"
        );
        if !known {
            return Err(self.err(at, format!("unknown function {shown}")));
        }
        if self.peek() != Some(b'[') {
            return Err(self.unexpected(&format!("expected '[' after {shown}")));
        }
        if name == b"EXISTS" {
            let open = self.i;
            self.i += 1;
            if self.peek() != Some(b'#') {
                return Err(self.unexpected("expected #<name> or #number in EXISTS[…]"));
            }
            self.i += 1;
            if self.peek().is_some_and(|c| c.is_ascii_digit()) {
                // A numbered parameter: #1 … #5601 always exist (they read as 0 until
                // set), as in LinuxCNC.
                let start = self.i;
                while self.peek().is_some_and(|c| c.is_ascii_digit()) {
                    self.i += 1;
                }
                let n: u64 = std::str::from_utf8(&self.b[start..self.i])
                    .ok()
                    .and_then(|d| d.parse().ok())
                    .unwrap_or(u64::MAX);
                return match self.peek() {
                    Some(b']') => {
                        self.i += 1;
                        Ok(f64::from(
                            (1..crate::gcode::params::NUM_PARAMS as u64).contains(&n) as u8,
                        ))
                    }
                    None => Err(self.err(open, "'[' opened here is never closed")),
                    Some(_) => Err(self.unexpected("expected ']'")),
                };
            }
            if self.peek() != Some(b'<') {
                return Err(self.unexpected("expected #<name> or #number in EXISTS[…]"));
            }
            let mut buf = NameBuf::new();
            self.name(&mut buf)?;
            return match self.peek() {
                Some(b']') => {
                    self.i += 1;
                    Ok(if self.params.named(buf.as_slice()).is_some() {
                        1.0
                    } else {
                        0.0
                    })
                }
                None => Err(self.err(open, "'[' opened here is never closed")),
                Some(_) => Err(self.unexpected("expected ']'")),
            };
        }
        let x = self.bracket(depth)?;
        let deg = |v: f64| v.to_radians();
        let v = match name {
            b"ABS" => x.abs(),
            b"ACOS" | b"ASIN" => {
                if !(-1.0..=1.0).contains(&x) {
                    return Err(self.err(at, format!("{shown} of {x}: outside -1 to 1")));
                }
                if name == b"ACOS" {
                    x.acos().to_degrees()
                } else {
                    x.asin().to_degrees()
                }
            }
            b"ATAN" => {
                if self.peek() != Some(b'/') {
                    return Err(self.unexpected("expected '/' in ATAN[y]/[x]"));
                }
                self.i += 1;
                if self.peek() != Some(b'[') {
                    return Err(self.unexpected("expected '[' in ATAN[y]/[x]"));
                }
                let d = self.bracket(depth)?;
                x.atan2(d).to_degrees()
            }
            b"COS" => deg(x).cos(),
            b"EXP" => x.exp(),
            b"FIX" => x.floor(),
            b"FUP" => x.ceil(),
            b"LN" => {
                if x <= 0.0 {
                    return Err(self.err(at, format!("LN of {x}: not above zero")));
                }
                x.ln()
            }
            b"ROUND" => x.round(),
            b"SIN" => deg(x).sin(),
            b"SQRT" => {
                if x < 0.0 {
                    return Err(self.err(at, format!("SQRT of {x}: below zero")));
                }
                x.sqrt()
            }
            _ => deg(x).tan(),
        };
        if v.is_finite() {
            Ok(v)
        } else {
            Err(self.err(at, format!("{shown} result out of range")))
        }
    }

    /// `#…` read, at the `#`.
    fn param_read(&mut self, depth: usize) -> Result<f64, LexError> {
        let at = self.i;
        self.i += 1;
        if self.peek() == Some(b'<') {
            let mut buf = NameBuf::new();
            self.name(&mut buf)?;
            return self.params.named(buf.as_slice()).ok_or_else(|| {
                self.err(
                    at,
                    format!(
                        "unknown parameter #<{}> (read before it was set)",
                        String::from_utf8_lossy(buf.as_slice())
                    ),
                )
            });
        }
        let n = self.param_index(depth)?;
        Ok(self.params.numbered(n))
    }

    /// The index after `#` of a numbered parameter (a value, itself possibly a
    /// parameter or expression), checked against the parameter range.
    fn param_index(&mut self, depth: usize) -> Result<usize, LexError> {
        let at = self.i;
        let v = match self.peek() {
            Some(b'0'..=b'9' | b'.') => self.literal(at)?,
            Some(b'[' | b'#') => Num::Real(self.operand(depth)?),
            _ => return Err(self.unexpected("expected a parameter number or <name> after '#'")),
        };
        match v.whole() {
            Some(n) if n >= 1 && (n as u64) < NUM_PARAMS as u64 => Ok(n as usize),
            _ => Err(self.err(
                at,
                format!(
                    "parameter number {v} out of range (1 to {})",
                    NUM_PARAMS - 1
                ),
            )),
        }
    }

    /// `<name>`, at the `<`: lower-cased, blanks dropped, into `buf`.
    fn name(&mut self, buf: &mut NameBuf) -> Result<(), LexError> {
        let open = self.i;
        self.i += 1;
        loop {
            match self.b.get(self.i) {
                None => return Err(self.err(open, "'<' of a parameter name is never closed")),
                Some(b'>') => {
                    self.i += 1;
                    break;
                }
                Some(b' ' | b'\t') => {}
                Some(&c) if c < 0x20 || c == 0x7f => return Err(self.control(self.i)),
                Some(&c) => buf.push(c.to_ascii_lowercase()),
            }
            self.i += 1;
        }
        if buf.len == 0 {
            return Err(self.err(open, "empty parameter name"));
        }
        Ok(())
    }
}

/// A parameter name on the stack (names are shorter than a line).
struct NameBuf {
    bytes: [u8; super::MAX_LINE],
    len: usize,
}

impl NameBuf {
    fn new() -> Self {
        Self {
            bytes: [0; super::MAX_LINE],
            len: 0,
        }
    }
    fn push(&mut self, c: u8) {
        if let Some(slot) = self.bytes.get_mut(self.len) {
            *slot = c;
            self.len += 1;
        }
    }
    fn as_slice(&self) -> &[u8] {
        &self.bytes[..self.len]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scan(text: &str) -> Result<Words, LexError> {
        let p = Params::new();
        let mut w = Words::default();
        scan_line(text, 0, &p, &mut w).map(|_| w)
    }

    fn val(text: &str) -> f64 {
        scan(text).unwrap().get(b'X').unwrap().num.to_f64()
    }

    #[test]
    fn literals_keep_their_exact_decimal_digits() {
        let w = scan("x-0 1.25 0").unwrap();
        assert_eq!(
            w.get(b'X').unwrap().num,
            Num::Lit {
                mant: -1_250,
                scale: 3
            }
        );
    }

    #[test]
    fn operators_follow_linuxcnc_precedence() {
        assert_eq!(val("X[1+2*3]"), 7.0);
        assert_eq!(val("X[2**3**2]"), 64.0); // left-associative, as LinuxCNC
        assert_eq!(val("X[7 mod 3 + 1]"), 2.0);
        assert_eq!(val("X[-7 MOD 3]"), 2.0);
        assert_eq!(val("X[1 lt 2 AND 3 GT 2]"), 1.0);
        assert_eq!(val("X[1 + 1 EQ 2]"), 1.0);
        assert_eq!(val("X[1 OR 0 XOR 1]"), 0.0);
    }

    #[test]
    fn functions_work_in_degrees() {
        assert!((val("X[SIN[30]]") - 0.5).abs() < 1e-12);
        assert!((val("XCOS[60]") - 0.5).abs() < 1e-12);
        assert_eq!(val("X[ATAN[1]/[1]]"), 45.0);
        assert_eq!(val("X[FIX[-1.5]+FUP[1.2]+ROUND[2.5]+ABS[-1]]"), 4.0);
        assert_eq!(val("X[SQRT[16]]"), 4.0);
        assert_eq!(val("X[EXISTS[#<nope>]]"), 0.0);
    }

    #[test]
    fn division_by_zero_is_reported_at_the_operator() {
        let e = scan("G1 X[1/0]").unwrap_err();
        assert_eq!((e.col, e.message.as_str()), (7, "division by zero"));
    }

    #[test]
    fn deep_nesting_is_refused_not_overflowing_the_stack() {
        let text = format!("X{}1{}", "[".repeat(200), "]".repeat(200));
        let e = scan(&text).unwrap_err();
        assert!(e.message.contains("nested"), "{}", e.message);
        let minus = format!("X[{}1]", "-".repeat(200));
        assert!(scan(&minus).is_err());
    }

    #[test]
    fn control_characters_are_reported_at_their_column() {
        let e = scan("G1 X1\u{0}").unwrap_err();
        assert_eq!(e.col, 6);
        assert!(e.message.contains("U+0000"));
        let e = scan("(a\u{7}b)").unwrap_err();
        assert_eq!(e.col, 3);
    }

    #[test]
    fn columns_count_characters_not_bytes() {
        let text = "(°) Q1 U2";
        let e = scan(text).unwrap_err();
        assert_eq!(char_col(text, e.col), 8);
    }

    #[test]
    fn scaling_rounds_half_away_from_zero() {
        let n = Num::Lit { mant: 15, scale: 1 };
        assert_eq!(n.scaled(1, 1), Some(2));
        let n = Num::Lit {
            mant: -15,
            scale: 1,
        };
        assert_eq!(n.scaled(1, 1), Some(-2));
        assert_eq!(Num::Real(1e300).scaled(1_000_000, 1), None);
        let inch = Num::Lit {
            mant: 1_234_567,
            scale: 6,
        };
        assert_eq!(inch.scaled(25_400_000, 1), Some(31_358_002));
    }
}
