//! O-word lines: `o100 sub`, `o<name> call [1] [2]`, `o101 while [#1 LT 10]`, … The
//! label and keyword are read once, when the program is indexed ([`scan_oword`]); the
//! bracketed values after the keyword are evaluated each time the line runs
//! ([`oword_args`]), against the parameters in force then.
//!
//! Invariants: an O-word is the first word of its line (only blanks, a block-delete
//! slash and an `N` number may precede it); labels are numbers (`o100`) or names
//! (`o<name>`, lower-cased, blanks dropped); at most [`MAX_ARGS`] values follow a
//! keyword; only blanks and comments may follow the values (comments on O-word lines
//! are ignored, messages included).
//!
//! Source: LinuxCNC G-code reference, O codes.

use super::expr::NameBuf;
use super::{Cursor, LexError};
use crate::gcode::params::Params;
use crate::gcode::unsupported;
use crate::gcode::ErrorKind;
use std::fmt;

/// Most values after a keyword: the 30 arguments of a call (#1–#30).
pub const MAX_ARGS: usize = 30;

/// An O-word's label.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub enum Label {
    /// `o100`.
    Num(i64),
    /// `o<name>`, normalised (lower case, no blanks).
    Name(Box<[u8]>),
}

impl fmt::Display for Label {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Label::Num(n) => write!(f, "o{n}"),
            Label::Name(s) => write!(f, "o<{}>", String::from_utf8_lossy(s)),
        }
    }
}

/// The keyword after an O-word's label.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Keyword {
    /// `sub`.
    Sub,
    /// `endsub [value]`.
    Endsub,
    /// `call [arg]…`.
    Call,
    /// `return [value]`.
    Return,
    /// `if [cond]`.
    If,
    /// `elseif [cond]`.
    Elseif,
    /// `else`.
    Else,
    /// `endif`.
    Endif,
    /// `while [cond]` (opening a loop, or closing a `do`).
    While,
    /// `endwhile`.
    Endwhile,
    /// `do`.
    Do,
    /// `repeat [count]`.
    Repeat,
    /// `endrepeat`.
    Endrepeat,
    /// `break`.
    Break,
    /// `continue`.
    Continue,
}

const KEYWORDS: [(&str, Keyword); 15] = [
    ("sub", Keyword::Sub),
    ("endsub", Keyword::Endsub),
    ("call", Keyword::Call),
    ("return", Keyword::Return),
    ("if", Keyword::If),
    ("elseif", Keyword::Elseif),
    ("else", Keyword::Else),
    ("endif", Keyword::Endif),
    ("while", Keyword::While),
    ("endwhile", Keyword::Endwhile),
    ("do", Keyword::Do),
    ("repeat", Keyword::Repeat),
    ("endrepeat", Keyword::Endrepeat),
    ("break", Keyword::Break),
    ("continue", Keyword::Continue),
];

impl Keyword {
    /// The keyword as written.
    pub fn name(self) -> &'static str {
        KEYWORDS
            .iter()
            .find(|(_, k)| *k == self)
            .map_or("?", |(s, _)| s)
    }

    /// How many bracketed values the keyword takes: (least, most).
    pub fn arity(self) -> (usize, usize) {
        match self {
            Keyword::Call => (0, MAX_ARGS),
            Keyword::Endsub | Keyword::Return => (0, 1),
            Keyword::If | Keyword::Elseif | Keyword::While | Keyword::Repeat => (1, 1),
            _ => (0, 0),
        }
    }
}

/// An O-word line's label and keyword.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct OHeader {
    /// Label.
    pub label: Label,
    /// Keyword.
    pub keyword: Keyword,
    /// Column of the `O`, 1-based, in bytes.
    pub col: u32,
    /// Byte index just after the keyword, where its values start.
    pub args_at: usize,
}

/// Reads the O-word at the start of `text[start..]`, if the line has one (after blanks
/// and an optional `N` number): its label and keyword. Values after a keyword that
/// takes none are an error here.
pub fn scan_oword(text: &str, start: usize, params: &Params) -> Result<Option<OHeader>, LexError> {
    let mut c = Cursor {
        b: text.as_bytes(),
        text,
        i: start,
        params,
    };
    if matches!(c.peek(), Some(b'n' | b'N')) {
        let save = c.i;
        c.i += 1;
        let digits_from = c.i;
        while c.peek().is_some_and(|d| d.is_ascii_digit()) {
            c.i += 1;
        }
        if c.i == digits_from || !matches!(c.peek(), Some(b'o' | b'O')) {
            c.i = save;
        }
    }
    if !matches!(c.peek(), Some(b'o' | b'O')) {
        return Ok(None);
    }
    let at = c.i;
    c.i += 1;
    let label = c.label(at)?;
    let kw_at = {
        c.skip_blanks();
        c.i
    };
    let mut word = [0u8; 9];
    let mut n = 0;
    while let Some(l) = c.peek().filter(u8::is_ascii_alphabetic) {
        if n < word.len() {
            word[n] = l.to_ascii_lowercase();
        }
        n += 1;
        c.i += 1;
    }
    if n == 0 {
        return Err(c.err(
            at,
            ErrorKind::Unsupported,
            unsupported(&format!(
                "Fanuc-style numbered programs ({label} without a keyword; M98/M99)"
            )),
        ));
    }
    let keyword = KEYWORDS
        .iter()
        .find(|(s, _)| n <= word.len() && s.as_bytes() == &word[..n])
        .map(|&(_, k)| k)
        .ok_or_else(|| {
            let shown = text.get(kw_at..c.i).unwrap_or("?").replace([' ', '\t'], "");
            c.err(
                kw_at,
                ErrorKind::Flow,
                format!(
                    "unknown O-word keyword '{shown}' (sub, endsub, call, return, if, elseif, \
                     else, endif, while, endwhile, do, repeat, endrepeat, break, continue)"
                ),
            )
        })?;
    let args_at = c.i;
    let (least, most) = keyword.arity();
    if most == 0 || least == 1 {
        // The shape is checked now; values are evaluated when the line runs.
        c.skip_comments()?;
        match (c.b.get(c.i), least) {
            (None, 0) => {}
            (Some(b'['), 1) => {}
            _ => {
                let what = if least == 1 {
                    format!("expected '[' and a value after {}", keyword.name())
                } else {
                    format!("expected the end of the line after {}", keyword.name())
                };
                return Err(c.unexpected(ErrorKind::Flow, &what));
            }
        }
    }
    Ok(Some(OHeader {
        label,
        keyword,
        col: c.col(at),
        args_at,
    }))
}

/// Evaluates the bracketed values of an O-word line from byte `at` (its
/// [`OHeader::args_at`]) into `args`, at most `most` of them; returns how many there
/// were.
pub fn oword_args(
    text: &str,
    at: usize,
    params: &Params,
    most: usize,
    args: &mut [f64; MAX_ARGS],
) -> Result<usize, LexError> {
    let mut c = Cursor {
        b: text.as_bytes(),
        text,
        i: at,
        params,
    };
    let mut n = 0;
    loop {
        c.skip_comments()?;
        match c.b.get(c.i) {
            None => return Ok(n),
            Some(b'[') if n < most.min(MAX_ARGS) => {
                args[n] = c.bracket(1)?;
                n += 1;
            }
            Some(b'[') => {
                return Err(c.err(
                    c.i,
                    ErrorKind::Flow,
                    if most == 1 {
                        "a second value where one is expected".to_string()
                    } else {
                        format!("more than {most} values")
                    },
                ))
            }
            Some(_) => {
                return Err(c.unexpected(
                    ErrorKind::Flow,
                    "expected '[' and a value, or the end of the line",
                ))
            }
        }
    }
}

impl Cursor<'_> {
    /// An O-word's label, after the `O` at byte `at`.
    fn label(&mut self, at: usize) -> Result<Label, LexError> {
        match self.peek() {
            Some(b'<') => {
                let mut buf = NameBuf::new();
                self.name(&mut buf)?;
                Ok(Label::Name(buf.as_slice().into()))
            }
            Some(b'[' | b'#') => Err(self.err(
                at,
                ErrorKind::Unsupported,
                unsupported("computed O-word labels (o[…])"),
            )),
            Some(b'0'..=b'9') => {
                let from = self.i;
                let num = self.literal(from)?;
                match num.whole() {
                    Some(v) if v >= 0 => Ok(Label::Num(v)),
                    _ => Err(self.err(
                        from,
                        ErrorKind::Flow,
                        format!("O-word label {num} is not a whole number"),
                    )),
                }
            }
            _ => Err(self.unexpected(ErrorKind::Flow, "expected a number or <name> after 'O'")),
        }
    }

    /// Skips blanks and comments (`( … )`, and `;` to the end of the line).
    fn skip_comments(&mut self) -> Result<(), LexError> {
        loop {
            match self.peek() {
                Some(b'(') => {
                    let mut ignored = super::Words::default();
                    self.comment(&mut ignored)?;
                }
                Some(b';') => {
                    self.check_text(self.i + 1, self.b.len())?;
                    self.i = self.b.len();
                }
                _ => return Ok(()),
            }
        }
    }
}
