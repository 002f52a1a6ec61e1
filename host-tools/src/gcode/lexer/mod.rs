//! Lexer: one line of text into [`Words`]. This module holds the words and the line
//! scanner (words, comments, messages, checksums, parameter settings); `number` reads
//! literal numbers and converts them exactly, `expr` evaluates expressions, functions
//! and parameter reads.
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
//! allocate); recursion is bounded by [`super::MAX_NESTING`]; control characters are errors
//! everywhere, comments included, and are reported at their column.
//!
//! Source: LinuxCNC G-code overview (numbers, parameters, expressions, binary operators
//! and their precedence, functions, comments, messages, checksums).

mod expr;
mod number;
mod oword;

pub(crate) use number::f64_to_i64;
pub use number::{Factor, Num, DEGREE, INCH, MAX_DECIMALS, MM};
pub use oword::{oword_args, scan_oword, Keyword, Label, OHeader, MAX_ARGS};

use super::params::Params;
use super::unsupported;
use super::ErrorKind;
use expr::NameBuf;

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
    /// `(MSG, …)` and `(DEBUG, …)` texts in order.
    pub messages: Vec<Note>,
    /// Column of the first axis, I J K or polar word (0: none).
    pub first_motion_col: u32,
}

/// An operator note in a comment.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Note {
    /// `(MSG, text)`: shown as written.
    Msg(String),
    /// `(DEBUG, text)`: shown with its parameters (`#n`, `#<name>`) filled in, in the
    /// format set by `%d`, `%f`, `%.Nf` before them (LinuxCNC's rules).
    Debug(String),
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
    /// What kind of fault.
    pub kind: ErrorKind,
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

/// The read position in one line, and the parameters values are read against.
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

    fn err(&self, i: usize, kind: ErrorKind, message: impl Into<String>) -> LexError {
        LexError {
            col: self.col(i),
            kind,
            message: message.into(),
        }
    }

    #[inline(always)]
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
    fn unexpected(&self, kind: ErrorKind, what: &str) -> LexError {
        let i = self.i;
        match self.b.get(i) {
            None => self.err(i, kind, format!("{what}, found the end of the line")),
            Some(&c) if c < 0x20 || c == 0x7f => self.control(i),
            Some(_) => {
                let ch = self
                    .text
                    .get(i..)
                    .and_then(|s| s.chars().next())
                    .unwrap_or('?');
                self.err(i, kind, format!("{what}, found '{ch}'"))
            }
        }
    }

    fn control(&self, i: usize) -> LexError {
        let c = self.b.get(i).copied().unwrap_or(0);
        self.err(
            i,
            ErrorKind::ExpectedLetter,
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
                            kind: ErrorKind::RepeatedWord,
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
                _ => {
                    return Err(self.unexpected(
                        ErrorKind::ExpectedLetter,
                        "expected a word (letter and value)",
                    ))
                }
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
                return Err(self.err(
                    at,
                    ErrorKind::Syntax,
                    "an O-word must begin its line (only an N number may come before it)",
                ))
            }
            b'U' | b'V' | b'W' => {
                return Err(self.err(
                    at,
                    ErrorKind::Unsupported,
                    unsupported(&format!("U V W axes ({})", letter as char)),
                ))
            }
            _ => {}
        }
        let known = matches!(
            letter,
            b'A'..=b'F' | b'G' | b'H' | b'I'..=b'N' | b'P'..=b'T' | b'X'..=b'Z'
        );
        if !known {
            return Err(self.err(
                at,
                ErrorKind::UnknownCode,
                format!("unknown word '{}'", letter as char),
            ));
        }
        // The common literal read here, inlined, and stored from registers: a `Num`
        // built on the stack and copied into its slot was read back with a load
        // spanning its separate stores, which the processor does not forward (a stall
        // per word). Any other value by `value` (which reads that literal the same way).
        self.skip_blanks();
        if let Some((mant, scale)) = self.quick_literal_parts() {
            let b = bit(letter);
            if letter != b'G' && letter != b'M' && words.present & b == 0 {
                // `store` for the common word, each field written on its own (in
                // `store` the compiler builds the value on the stack).
                words.present |= b;
                let slot = &mut words.vals[(letter - b'A') as usize];
                slot.num = Num::Lit { mant, scale };
                slot.col = col;
                if b & MOTION_LETTERS != 0 && words.first_motion_col == 0 {
                    words.first_motion_col = col;
                }
                return Ok(());
            }
            return self.store(words, letter, at, col, Num::Lit { mant, scale });
        }
        let num = self.value(letter as char, 0)?;
        self.store(words, letter, at, col, num)
    }

    /// Records the word `letter` (at byte `at`, column `col`) of value `num`.
    #[inline(always)]
    fn store(
        &self,
        words: &mut Words,
        letter: u8,
        at: usize,
        col: u32,
        num: Num,
    ) -> Result<(), LexError> {
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
                        return Err(self.err(
                            at,
                            ErrorKind::UnknownCode,
                            format!("unknown code {}{num}", letter as char),
                        ))
                    }
                }
            }
            _ => {
                let b = bit(letter);
                let slot = (letter - b'A') as usize;
                if words.present & b != 0 {
                    return Err(self.err(
                        at,
                        ErrorKind::RepeatedWord,
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

    /// `( … )`: plain comment, `(MSG, text)` or `(DEBUG, text)` (case-insensitive).
    fn comment(&mut self, words: &mut Words) -> Result<(), LexError> {
        let open = self.i;
        let mut j = open + 1;
        loop {
            match self.b.get(j) {
                None => {
                    return Err(self.err(
                        open,
                        ErrorKind::Syntax,
                        "comment opened here is never closed",
                    ))
                }
                Some(b')') => break,
                Some(b'(') => {
                    return Err(self.err(
                        j,
                        ErrorKind::Syntax,
                        "'(' inside a comment (comments do not nest)",
                    ))
                }
                Some(&c) if (c < 0x20 && c != b'\t') || c == 0x7f => return Err(self.control(j)),
                Some(_) => j += 1,
            }
        }
        self.i = j + 1;
        let body = self.text.get(open + 1..j).unwrap_or("");
        let t = body.trim_start();
        let after = |key: &[u8]| {
            let head = t.as_bytes().get(..key.len())?;
            if !head.eq_ignore_ascii_case(key) {
                return None;
            }
            t[key.len()..].trim_start().strip_prefix(',')
        };
        if let Some(rest) = after(b"MSG") {
            words.messages.push(Note::Msg(rest.trim().to_string()));
        } else if let Some(rest) = after(b"DEBUG") {
            words.messages.push(Note::Debug(rest.trim().to_string()));
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
            _ => {
                return Err(
                    self.unexpected(ErrorKind::Syntax, "expected the checksum number after '*'")
                )
            }
        };
        match given.whole() {
            Some(n) if n == i64::from(sum) => {}
            Some(n) if (0..=255).contains(&n) => {
                return Err(self.err(
                    star,
                    ErrorKind::Syntax,
                    format!("checksum mismatch: the line says *{n} but its bytes give *{sum}"),
                ))
            }
            _ => {
                return Err(self.err(
                    star,
                    ErrorKind::Syntax,
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
                    return Err(self.unexpected(
                        ErrorKind::Syntax,
                        "expected the end of the line after the checksum",
                    ))
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
            return Err(self.unexpected(ErrorKind::Syntax, "expected '=' in a parameter setting"));
        }
        self.i += 1;
        let value = self.value('=', 0)?.to_f64();
        words.assigns.push(Assign { target, value, col });
        Ok(())
    }

    /// The value after a word letter (or `=`): a literal (exact), or anything else
    /// computed in `f64`.
    fn value(&mut self, after: char, depth: usize) -> Result<Num, LexError> {
        self.skip_blanks();
        let start = self.i;
        let Some(&c) = self.b.get(start) else {
            return Err(self.unexpected(
                ErrorKind::BadNumber,
                &format!("expected a value after '{after}'"),
            ));
        };
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
            // The common literal read here, any other by `literal`.
            return match self.quick_literal() {
                Some(num) => Ok(num),
                None => self.literal(start),
            };
        }
        match c {
            b'[' | b'#' | b'+' | b'-' => Ok(Num::Real(self.operand(depth)?)),
            c if c.is_ascii_alphabetic() && self.function_follows() => {
                Ok(Num::Real(self.operand(depth)?))
            }
            _ => Err(self.unexpected(
                ErrorKind::BadNumber,
                &format!("expected a value after '{after}'"),
            )),
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
}
