//! O-word subroutines and control flow: `sub`/`endsub`/`call`/`return`,
//! `if`/`elseif`/`else`/`endif`, `while`/`endwhile`, `do`/`while`,
//! `repeat`/`endrepeat`, `break`/`continue`.
//!
//! The interpreter still reads one line at a time; this module decides which line runs
//! next. [`Program::index`] makes one pass over the text: it records where each
//! non-blank line starts (honouring `%` and block delete), reads every O-word line's
//! label and keyword, and links each block to its parts (an `if` to its next branch,
//! a loop to its end, a `call` to its `sub`), so that every structural mistake is
//! reported, with its line, before anything runs. [`run`] then executes the lines by
//! index with a control stack of call frames (return line, the caller's #1–#30 and
//! local named parameters) and loop frames (a `repeat`'s remaining count).
//!
//! Invariants: a program with a structural error does not run (its other lines are
//! not checked); a line that never runs (a branch not taken, a subroutine never
//! called) is checked only for its O-word; calls nest at most [`MAX_CALL_DEPTH`] deep
//! (LinuxCNC's limit); the lines executed beyond the program's own length (loop
//! passes and subroutine bodies counted each time) are at most
//! [`MAX_REPEATED_LINES`], so no program loops forever; each line reports at most
//! one error however often it runs.
//!
//! Source: LinuxCNC G-code reference, O codes (numbering, subroutines, looping,
//! conditional, repeat, return values, errors).

pub mod chunked;
mod lines;
pub(crate) mod run;

pub(crate) use run::run;

use super::lexer::{self, Keyword, Label};
use super::params::Params;
use super::{ErrorKind, MAX_LINE};
use lines::Lines;
use std::collections::HashMap;

/// Deepest nesting of subroutine calls (LinuxCNC's).
pub const MAX_CALL_DEPTH: usize = 10;
/// Most lines executed beyond the program's own line count (every pass through a
/// loop and every subroutine body counts again): bounds run time and output.
pub const MAX_REPEATED_LINES: usize = 1_000_000;

/// No O-word on the line.
const PLAIN: u32 = u32::MAX;
/// An O-word line whose label or keyword is wrong (reported; it never runs).
const BAD: u32 = u32::MAX - 1;
/// A link not (yet) made.
const NONE: usize = usize::MAX;

/// One non-blank line of the program.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Line {
    /// Byte range of the line's text in the source (without the line break).
    pub start: usize,
    pub end: usize,
    /// Byte offset in the text where words start (after a block-delete slash).
    pub from: u32,
    /// Line number, 1-based.
    pub number: u32,
    /// Index of its O-word in [`Program::owords`], or [`PLAIN`].
    pub oword: u32,
}

/// An O-word line's keyword and the lines (indices into [`Program::lines`]) it is
/// linked to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Op {
    /// `sub`: the line of its `endsub`.
    Sub {
        end: usize,
    },
    Endsub,
    /// `call`: the line of the `sub`.
    Call {
        sub: usize,
    },
    Return,
    /// `if`: the line of its next branch (`elseif`, `else` or `endif`).
    If {
        next: usize,
    },
    /// `elseif`: its next branch, and the `endif`.
    Elseif {
        next: usize,
        endif: usize,
    },
    /// `else`: the `endif`.
    Else {
        endif: usize,
    },
    Endif,
    /// `while` opening a loop: its `endwhile`.
    While {
        end: usize,
    },
    /// `endwhile`: its `while`.
    Endwhile {
        start: usize,
    },
    /// `do`: the `while` closing it.
    Do {
        end: usize,
    },
    /// `while` closing a `do`: the `do`.
    DoWhile {
        start: usize,
    },
    /// `repeat`: its `endrepeat`.
    Repeat {
        end: usize,
    },
    /// `endrepeat`: its `repeat`.
    Endrepeat {
        start: usize,
    },
    /// `break`, `continue`: the loop's first line.
    Break {
        lp: usize,
    },
    Continue {
        lp: usize,
    },
}

/// An O-word line.
#[derive(Clone, Debug)]
pub(crate) struct OWord {
    pub label: Label,
    pub keyword: Keyword,
    pub op: Op,
    /// Column of the `O`, 1-based, in bytes.
    pub col: u32,
    /// Byte offset in the line's text where its values start.
    pub args_at: usize,
}

/// A located error found while indexing: line number, byte column, message.
pub(crate) type FlowError = (u32, u32, ErrorKind, String);

/// The program's lines and O-word structure.
#[derive(Debug, Default)]
pub(crate) struct Program {
    pub lines: Vec<Line>,
    pub owords: Vec<OWord>,
    /// Line number of an opening `%`, if any.
    pub opening_percent: Option<usize>,
    /// A closing `%` was found.
    pub closed: bool,
    /// Errors in O-word lines and in the block structure.
    pub errors: Vec<FlowError>,
    /// The blocks do not match up: the program cannot run.
    pub broken: bool,
}

/// A block opened and not yet closed while indexing.
struct Open {
    /// Its first line (index into `lines`).
    line: usize,
    /// Its latest `if`/`elseif`/`else` branch line.
    branch: usize,
}

impl Program {
    /// Indexes `source`: its lines, and its O-word lines linked into blocks.
    pub fn index(source: &str, block_delete: bool, params: &Params) -> Program {
        let mut p = Program {
            lines: Vec::with_capacity(source.len() / 24 + 1),
            ..Program::default()
        };
        let mut seen_text = false;
        let mut offset = 0;
        for (n, raw) in Lines::new(source).enumerate() {
            let start = offset;
            offset += raw.len() + 1;
            let number = u32::try_from(n + 1).unwrap_or(u32::MAX);
            // Without its carriage returns (`trim_end_matches('\r')`, by bytes).
            let kept = raw.bytes().rposition(|b| b != b'\r').map_or(0, |p| p + 1);
            let text = raw.get(..kept).unwrap_or(raw);
            let bytes = text.as_bytes();
            let Some(first) = bytes.iter().position(|&b| b != b' ' && b != b'\t') else {
                continue; // blank line
            };
            if bytes[first] == b'%' && bytes[first + 1..].iter().all(|&b| b == b' ' || b == b'\t') {
                if !seen_text {
                    seen_text = true;
                    p.opening_percent = Some(n + 1);
                    continue;
                }
                p.closed = true;
                break;
            }
            seen_text = true;
            let mut from = first;
            if bytes[first] == b'/' {
                if block_delete {
                    continue;
                }
                from += 1;
            }
            if program_name(&bytes[from..]) {
                continue; // `OMyProgram`: a post's program name, ignored as by LinuxCNC
            }
            let mut line = Line {
                start,
                end: start + text.len(),
                from: from as u32, // < MAX_LINE when it matters; the scan checks length
                number,
                oword: PLAIN,
            };
            // An O-word line: the first byte after blanks (and an N number) is O.
            if first_word_may_be_o(&bytes[from..]) {
                p.oword_line(text, &mut line, params);
            }
            p.lines.push(line);
        }
        if p.owords.is_empty() {
            return p;
        }
        p.link();
        p
    }

    /// Reads the O-word of `line` (text `text`), if it has one, into `owords`.
    fn oword_line(&mut self, text: &str, line: &mut Line, params: &Params) {
        if text.len() > MAX_LINE && text.chars().count() > MAX_LINE {
            return; // reported when the line runs
        }
        match lexer::scan_oword(text, line.from as usize, params) {
            Ok(None) => {}
            Ok(Some(h)) => {
                line.oword = self.owords.len() as u32;
                self.owords.push(OWord {
                    label: h.label,
                    keyword: h.keyword,
                    op: Op::Endsub,
                    col: h.col,
                    args_at: h.args_at,
                });
            }
            Err(e) => {
                line.oword = BAD;
                self.errors.push((line.number, e.col, e.kind, e.message));
            }
        }
    }

    /// The text of the line numbered `number` ("" if it is not indexed).
    pub fn text_of<'s>(&self, source: &'s str, number: u32) -> &'s str {
        match self.lines.binary_search_by_key(&number, |l| l.number) {
            Ok(k) => source
                .get(self.lines[k].start..self.lines[k].end)
                .unwrap_or(""),
            Err(_) => "",
        }
    }

    /// The O-word of line `i`, if any.
    pub fn oword(&self, i: usize) -> Option<&OWord> {
        let o = self.lines.get(i)?.oword;
        self.owords.get(o as usize)
    }

    fn error_at(&mut self, i: usize, message: String) {
        self.broken = true;
        let (number, col) = match (self.lines.get(i), self.oword(i)) {
            (Some(l), Some(o)) => (l.number, o.col),
            (Some(l), None) => (l.number, 1),
            _ => (0, 1),
        };
        self.errors.push((number, col, ErrorKind::Flow, message));
    }

    /// Links every block: one pass with a stack of open blocks, then calls to subs.
    fn link(&mut self) {
        let mut stack: Vec<Open> = Vec::new();
        let mut subs: HashMap<Label, usize> = HashMap::new();
        let mut calls = Vec::new();
        for i in 0..self.lines.len() {
            let Some(o) = self.oword(i) else { continue };
            let (label, keyword) = (o.label.clone(), o.keyword);
            let op = match keyword {
                Keyword::Sub => {
                    let op = self.open_sub(i, &label, &stack, &mut subs);
                    stack.push(Open { line: i, branch: i });
                    op
                }
                Keyword::Call => {
                    calls.push(i);
                    Some(Op::Call { sub: NONE })
                }
                Keyword::Return => self.check_return(i, &label, &stack),
                Keyword::Break | Keyword::Continue => self.loop_exit(i, &label, keyword, &stack),
                Keyword::If | Keyword::Do | Keyword::Repeat => {
                    stack.push(Open { line: i, branch: i });
                    Some(match keyword {
                        Keyword::If => Op::If { next: NONE },
                        Keyword::Do => Op::Do { end: NONE },
                        _ => Op::Repeat { end: NONE },
                    })
                }
                Keyword::While => {
                    let closes_do = stack.last().is_some_and(|top| {
                        self.oword(top.line)
                            .is_some_and(|t| t.keyword == Keyword::Do && t.label == label)
                    });
                    if closes_do {
                        self.close(i, &label, keyword, &mut stack)
                    } else {
                        stack.push(Open { line: i, branch: i });
                        Some(Op::While { end: NONE })
                    }
                }
                Keyword::Elseif | Keyword::Else => self.branch(i, &label, keyword, &mut stack),
                Keyword::Endsub | Keyword::Endif | Keyword::Endwhile | Keyword::Endrepeat => {
                    self.close(i, &label, keyword, &mut stack)
                }
            };
            if let Some(op) = op {
                self.set_op(i, op);
            }
        }
        for open in stack {
            let Some(o) = self.oword(open.line) else {
                continue;
            };
            let msg = format!(
                "{} {} opened here is never closed (no {} {})",
                o.label,
                o.keyword.name(),
                o.label,
                closing_name(o.keyword)
            );
            self.error_at(open.line, msg);
        }
        for i in calls {
            let Some(label) = self.oword(i).map(|o| o.label.clone()) else {
                continue;
            };
            match subs.get(&label) {
                Some(&sub) => self.set_op(i, Op::Call { sub }),
                None => self.error_at(
                    i,
                    format!(
                        "{label} call: no {label} sub in this program (subroutines in \
                         separate files are not supported)"
                    ),
                ),
            }
        }
    }

    fn set_op(&mut self, i: usize, op: Op) {
        let oi = self.lines.get(i).map_or(usize::MAX, |l| l.oword as usize);
        if let Some(o) = self.owords.get_mut(oi) {
            o.op = op;
        }
    }

    /// `sub`: not inside another block, and defined once.
    fn open_sub(
        &mut self,
        i: usize,
        label: &Label,
        stack: &[Open],
        subs: &mut HashMap<Label, usize>,
    ) -> Option<Op> {
        if let Some(outer) = stack.last() {
            let (n, what) = self.described(outer.line);
            self.error_at(
                i,
                format!(
                    "{label} sub inside {what} (line {n}): subroutines may not be defined \
                     inside another block"
                ),
            );
            return None;
        }
        if let Some(&first) = subs.get(label) {
            let n = self.lines.get(first).map_or(0, |l| l.number);
            self.error_at(i, format!("{label} sub: already defined at line {n}"));
            return None;
        }
        subs.insert(label.clone(), i);
        Some(Op::Sub { end: NONE })
    }

    /// `return`: inside the definition of the sub of the same label.
    fn check_return(&mut self, i: usize, label: &Label, stack: &[Open]) -> Option<Op> {
        let sub = stack.first().and_then(|s| self.oword(s.line));
        match sub {
            Some(s) if s.keyword == Keyword::Sub && s.label == *label => Some(Op::Return),
            Some(s) if s.keyword == Keyword::Sub => {
                let msg = format!("{label} return inside {} sub (labels differ)", s.label);
                self.error_at(i, msg);
                None
            }
            _ => {
                self.error_at(i, format!("{label} return outside a subroutine definition"));
                None
            }
        }
    }

    /// `break`/`continue`: inside a loop of the same label, in the same subroutine.
    fn loop_exit(&mut self, i: usize, label: &Label, kw: Keyword, stack: &[Open]) -> Option<Op> {
        for open in stack.iter().rev() {
            let Some(o) = self.oword(open.line) else {
                continue;
            };
            if o.keyword == Keyword::Sub {
                break;
            }
            let is_loop = matches!(o.keyword, Keyword::While | Keyword::Do | Keyword::Repeat);
            if is_loop && o.label == *label {
                return Some(if kw == Keyword::Break {
                    Op::Break { lp: open.line }
                } else {
                    Op::Continue { lp: open.line }
                });
            }
        }
        self.error_at(
            i,
            format!(
                "{label} {}: not inside loop {label} (while, do or repeat)",
                kw.name()
            ),
        );
        None
    }

    /// `elseif`/`else`: the innermost open block is the `if` of the same label, with no
    /// `else` yet.
    fn branch(&mut self, i: usize, label: &Label, kw: Keyword, stack: &mut [Open]) -> Option<Op> {
        let Some(top) = stack.last_mut() else {
            self.error_at(i, format!("{label} {} without {label} if", kw.name()));
            return None;
        };
        let (open_line, prev) = (top.line, top.branch);
        let opener = self.oword(open_line).map(|o| (o.keyword, o.label.clone()));
        let prev_kw = self.oword(prev).map(|o| o.keyword);
        match opener {
            Some((Keyword::If, l)) if l == *label => {
                if prev_kw == Some(Keyword::Else) {
                    let n = self.lines.get(prev).map_or(0, |l| l.number);
                    self.error_at(
                        i,
                        format!("{label} {} after {label} else (line {n})", kw.name()),
                    );
                    return None;
                }
                top.branch = i;
                self.link_branch(prev, i);
                Some(if kw == Keyword::Else {
                    Op::Else { endif: NONE }
                } else {
                    Op::Elseif {
                        next: NONE,
                        endif: NONE,
                    }
                })
            }
            _ => {
                self.mismatch(i, label, kw, open_line);
                None
            }
        }
    }

    /// Points branch line `prev` (`if`/`elseif`) at its next branch `next`.
    fn link_branch(&mut self, prev: usize, next: usize) {
        let op = match self.oword(prev).map(|o| o.op) {
            Some(Op::If { .. }) => Op::If { next },
            Some(Op::Elseif { endif, .. }) => Op::Elseif { next, endif },
            Some(other) => other,
            None => return,
        };
        self.set_op(prev, op);
    }

    /// A closing line (`endsub`, `endif`, `endwhile`, `endrepeat`, or `while` after a
    /// `do`): the innermost open block must be its opener, of the same label.
    fn close(&mut self, i: usize, label: &Label, kw: Keyword, stack: &mut Vec<Open>) -> Option<Op> {
        let Some(top) = stack.last() else {
            let msg = format!("{label} {} without {label} {}", kw.name(), opening_name(kw));
            self.error_at(i, msg);
            return None;
        };
        let (start, branch) = (top.line, top.branch);
        let opener = self.oword(start).map(|o| (o.keyword, o.label.clone()));
        let matches = match &opener {
            Some((open_kw, l)) => {
                l == label
                    && match kw {
                        Keyword::Endsub => *open_kw == Keyword::Sub,
                        Keyword::Endif => *open_kw == Keyword::If,
                        Keyword::Endwhile => *open_kw == Keyword::While,
                        Keyword::Endrepeat => *open_kw == Keyword::Repeat,
                        _ => *open_kw == Keyword::Do,
                    }
            }
            None => false,
        };
        if !matches {
            self.mismatch(i, label, kw, start);
            return None;
        }
        stack.pop();
        match kw {
            Keyword::Endsub => {
                self.set_op(start, Op::Sub { end: i });
                Some(Op::Endsub)
            }
            Keyword::Endif => {
                self.link_branch(branch, i);
                // Every branch after the first jumps to the endif when reached from the
                // branch before it.
                let mut b = self.oword(start).map_or(NONE, |o| match o.op {
                    Op::If { next } => next,
                    _ => NONE,
                });
                while b != i && b != NONE {
                    match self.oword(b).map(|o| o.op) {
                        Some(Op::Elseif { next, .. }) => {
                            self.set_op(b, Op::Elseif { next, endif: i });
                            b = next;
                        }
                        Some(Op::Else { .. }) => {
                            self.set_op(b, Op::Else { endif: i });
                            b = i;
                        }
                        _ => b = NONE,
                    }
                }
                Some(Op::Endif)
            }
            Keyword::Endwhile => {
                self.set_op(start, Op::While { end: i });
                Some(Op::Endwhile { start })
            }
            Keyword::Endrepeat => {
                self.set_op(start, Op::Repeat { end: i });
                Some(Op::Endrepeat { start })
            }
            _ => {
                self.set_op(start, Op::Do { end: i });
                Some(Op::DoWhile { start })
            }
        }
    }

    /// "line N: o100 while" for the block opened at line index `i`.
    fn described(&self, i: usize) -> (u32, String) {
        let n = self.lines.get(i).map_or(0, |l| l.number);
        let what = self
            .oword(i)
            .map_or_else(String::new, |o| format!("{} {}", o.label, o.keyword.name()));
        (n, what)
    }

    /// A closing or branch line that does not match the innermost open block.
    fn mismatch(&mut self, i: usize, label: &Label, kw: Keyword, open: usize) {
        let (n, what) = self.described(open);
        self.error_at(
            i,
            format!(
                "{label} {} does not match {what} opened at line {n}",
                kw.name()
            ),
        );
    }
}

/// Does `bytes` start (after blanks, and an N number) with an O?
#[inline]
fn first_word_may_be_o(bytes: &[u8]) -> bool {
    let mut i = 0;
    while let Some(b' ' | b'\t') = bytes.get(i) {
        i += 1;
    }
    match bytes.get(i) {
        Some(b'o' | b'O') => true,
        Some(b'n' | b'N') => bytes[i + 1..]
            .iter()
            .find(|&&b| !(b.is_ascii_digit() || b == b' ' || b == b'\t'))
            .is_some_and(|&b| b == b'o' || b == b'O'),
        _ => false,
    }
}

/// The keyword that closes a block opened by `kw`.
fn closing_name(kw: Keyword) -> &'static str {
    match kw {
        Keyword::Sub => "endsub",
        Keyword::If | Keyword::Elseif | Keyword::Else => "endif",
        Keyword::While => "endwhile",
        Keyword::Do => "while",
        Keyword::Repeat => "endrepeat",
        _ => "end",
    }
}

/// The keyword that opens a block closed by `kw`.
fn opening_name(kw: Keyword) -> &'static str {
    match kw {
        Keyword::Endsub => "sub",
        Keyword::Endif => "if",
        Keyword::Endwhile => "while",
        Keyword::Endrepeat => "repeat",
        _ => "do",
    }
}

/// Is this line a program name as some posts write it (SprutCAM's Mach post: `O` and a
/// name, `OMyProgram`)? LinuxCNC runs such a program, treating the line as nothing
/// (its `sprutcam-mach-post-bug` test); an O-word proper has a number or `<name>`.
fn program_name(words: &[u8]) -> bool {
    matches!(words, [b'o' | b'O', l, ..] if l.is_ascii_alphabetic())
}
