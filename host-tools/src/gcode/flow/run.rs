//! Running an indexed [`Program`]: lines by index, with a control stack.
//!
//! A plain line is scanned and executed as it always was; an O-word line moves the
//! index. Call frames keep the line to return to, the caller's #1–#30 and its local
//! named parameters; loop frames keep a loop's first line and, for `repeat`, the passes
//! left. `break` and `continue` pop the frames of the loops inside theirs; `return`
//! pops every loop frame of its subroutine.
//!
//! Invariants: an error on an O-word line never stops the run: a condition that
//! fails to evaluate counts as false (the branch is skipped, the loop ends), a call
//! whose arguments fail is skipped, a return value that fails is not returned; each
//! line reports at most one error; the run stops at M2/M30, at the end of the
//! program, or when `Options::repeated_lines` (default [`MAX_REPEATED_LINES`]) lines
//! have run beyond the program's length.

#[cfg(doc)]
use super::MAX_REPEATED_LINES;
use super::{Line, Op, Program, MAX_CALL_DEPTH, PLAIN};
use crate::gcode::canon::Canon;
use crate::gcode::interp::Interp;
use crate::gcode::lexer::{self, Words, MAX_ARGS};
use crate::gcode::params::Scope;
use crate::gcode::{Diagnostic, ErrorKind, MAX_LINE};
use std::collections::HashSet;

/// What a subroutine call keeps to return.
struct CallFrame {
    /// Line index to go on at.
    ret: usize,
    /// The caller's #1–#30.
    saved: [f64; MAX_ARGS],
    /// The caller's local named parameters.
    scope: Scope,
}

/// One entry of the control stack.
enum Frame {
    Call(Box<CallFrame>),
    /// A loop started at line index `start`; `left`: passes left of a `repeat`.
    Loop {
        start: usize,
        left: i64,
    },
}

/// The run's state.
struct Runner<'a, 'o> {
    p: &'a Program,
    source: &'a str,
    file: &'a str,
    interp: &'a mut Interp<'o>,
    out: &'a mut Vec<Canon>,
    words: Words,
    stack: Vec<Frame>,
    depth: usize,
    /// Per O-word: a `sub` the run has passed (defined).
    defined: Vec<bool>,
    args: [f64; MAX_ARGS],
    errors: &'a mut Vec<Diagnostic>,
    /// Lines that reported an error already.
    failed: HashSet<u32>,
}

/// Runs `p` (indexed from `source`), appending commands to `out` and errors to
/// `errors`.
pub(crate) fn run(
    p: &Program,
    source: &str,
    file: &str,
    interp: &mut Interp<'_>,
    out: &mut Vec<Canon>,
    errors: &mut Vec<Diagnostic>,
) {
    let mut r = Runner {
        p,
        source,
        file,
        interp,
        out,
        words: Words::default(),
        stack: Vec::new(),
        depth: 0,
        defined: vec![false; p.owords.len()],
        args: [0.0; MAX_ARGS],
        errors,
        failed: HashSet::new(),
    };
    let budget = p.lines.len().saturating_add(r.interp.opts.repeated_lines);
    let mut executed = 0usize;
    let mut i = 0;
    while let Some(line) = p.lines.get(i) {
        executed += 1;
        if executed > budget {
            r.runaway(i);
            return;
        }
        if line.oword == PLAIN {
            r.plain(line);
            if r.interp.ended() || r.interp.waiting() {
                return;
            }
            i += 1;
        } else {
            i = r.oword(i);
        }
    }
}

impl Runner<'_, '_> {
    fn text(&self, line: &Line) -> &str {
        self.source.get(line.start..line.end).unwrap_or("")
    }

    /// Records an error at line `number`, column `col` (characters), unless the line
    /// has one already.
    fn error(&mut self, number: u32, col: usize, kind: ErrorKind, message: String) {
        if self.failed.insert(number) {
            self.errors.push(Diagnostic {
                file: self.file.to_string(),
                line: number as usize,
                col,
                kind,
                message,
            });
        }
    }

    /// An error on line index `i` at byte column `col`.
    fn error_at(&mut self, i: usize, col: u32, message: String) {
        let Some(&line) = self.p.lines.get(i) else {
            return;
        };
        let col = lexer::char_col(self.text(&line), col);
        self.error(line.number, col, ErrorKind::Flow, message);
    }

    /// An error on O-word line `i`, at its O.
    fn oword_error(&mut self, i: usize, message: String) {
        let col = self.p.oword(i).map_or(1, |o| o.col);
        self.error_at(i, col, message);
    }

    /// A line without an O-word: scanned and executed.
    #[inline]
    fn plain(&mut self, line: &Line) {
        let text = self.source.get(line.start..line.end).unwrap_or("");
        if let Err((col, kind, message)) = execute_line(
            self.interp,
            &mut self.words,
            text,
            line.from as usize,
            line.number,
            self.out,
        ) {
            self.error(line.number, col, kind, message);
        }
    }

    /// Runs O-word line `i`; returns the index of the next line to run.
    fn oword(&mut self, i: usize) -> usize {
        let p = self.p;
        let Some(o) = p.oword(i) else {
            return i + 1;
        };
        let (op, oi) = (o.op, p.lines[i].oword as usize);
        match op {
            Op::Sub { end } => {
                if let Some(d) = self.defined.get_mut(oi) {
                    *d = true;
                }
                end.saturating_add(1)
            }
            Op::Endsub | Op::Return => {
                let value = match self.values(i, 1) {
                    Ok(1) => Some(self.args[0]),
                    _ => None,
                };
                self.ret(i, value)
            }
            Op::Call { sub } => self.call(i, sub),
            Op::If { next } => {
                if self.condition(i) {
                    i + 1
                } else {
                    self.next_branch(next)
                }
            }
            // Reached from the branch before: that branch has run.
            Op::Elseif { endif, .. } | Op::Else { endif } => endif.saturating_add(1),
            Op::Endif => i + 1,
            Op::While { end } => {
                if self.condition(i) {
                    self.stack.push(Frame::Loop { start: i, left: 0 });
                    i + 1
                } else {
                    end.saturating_add(1)
                }
            }
            Op::Endwhile { start } => self.again(start, i, start),
            Op::Do { .. } => {
                self.stack.push(Frame::Loop { start: i, left: 0 });
                i + 1
            }
            Op::DoWhile { start } => self.again(i, i, start),
            Op::Repeat { end } => {
                let count = match self.values(i, 1) {
                    Ok(_) if self.args[0] >= 1.0 => self.args[0].min(i64::MAX as f64) as i64,
                    _ => 0,
                };
                if count > 0 {
                    self.stack.push(Frame::Loop {
                        start: i,
                        left: count,
                    });
                    i + 1
                } else {
                    end.saturating_add(1)
                }
            }
            Op::Endrepeat { start } => {
                if let Some(Frame::Loop { left, .. }) = self.stack.last_mut() {
                    *left -= 1;
                    if *left > 0 {
                        return start + 1;
                    }
                }
                self.pop_loop();
                i + 1
            }
            Op::Break { lp } => {
                self.unwind_to(lp);
                self.pop_loop();
                self.loop_end(lp).saturating_add(1)
            }
            Op::Continue { lp } => {
                self.unwind_to(lp);
                self.loop_end(lp)
            }
        }
    }

    /// The end of a `while` or `do` loop (at line `at`, whose condition is on line
    /// `cond`, first line `start`): another pass, or out.
    fn again(&mut self, cond: usize, at: usize, start: usize) -> usize {
        if self.condition(cond) {
            start + 1
        } else {
            self.pop_loop();
            at + 1
        }
    }

    /// The closing line of the loop opened at line `lp`.
    fn loop_end(&self, lp: usize) -> usize {
        match self.p.oword(lp).map(|o| o.op) {
            Some(Op::While { end } | Op::Do { end } | Op::Repeat { end }) => end,
            _ => lp,
        }
    }

    /// Pops the loop frames above the one of the loop opened at line `lp`.
    fn unwind_to(&mut self, lp: usize) {
        while let Some(Frame::Loop { start, .. }) = self.stack.last() {
            if *start == lp {
                return;
            }
            self.stack.pop();
        }
    }

    /// Pops the innermost frame if it is a loop's.
    fn pop_loop(&mut self) {
        if let Some(Frame::Loop { .. }) = self.stack.last() {
            self.stack.pop();
        }
    }

    /// After a false `if`/`elseif` condition: the first true branch after it (from
    /// line `b`), the `else`, or past the `endif`.
    fn next_branch(&mut self, mut b: usize) -> usize {
        loop {
            match self.p.oword(b).map(|o| o.op) {
                Some(Op::Elseif { next, .. }) => {
                    if self.condition(b) {
                        return b + 1;
                    }
                    b = next;
                }
                _ => return b.saturating_add(1),
            }
        }
    }

    /// The condition on O-word line `i`: true when nonzero; an error is reported and
    /// counts as false.
    fn condition(&mut self, i: usize) -> bool {
        matches!(self.values(i, 1), Ok(1)) && self.args[0] != 0.0
    }

    /// Evaluates the values of O-word line `i` (at most `most`) into `self.args`;
    /// reports an error.
    fn values(&mut self, i: usize, most: usize) -> Result<usize, ()> {
        let p = self.p;
        let (Some(&line), Some(o)) = (p.lines.get(i), p.oword(i)) else {
            return Err(());
        };
        let text = self.source.get(line.start..line.end).unwrap_or("");
        match lexer::oword_args(text, o.args_at, &self.interp.params, most, &mut self.args) {
            Ok(n) => Ok(n),
            Err(e) => {
                let col = lexer::char_col(text, e.col);
                let message = format!("{} {}: {}", o.label, o.keyword.name(), e.message);
                self.error(line.number, col, e.kind, message);
                Err(())
            }
        }
    }

    /// `call` on line `i` of the `sub` on line `sub`: returns the next line to run.
    fn call(&mut self, i: usize, sub: usize) -> usize {
        let Ok(n) = self.values(i, MAX_ARGS) else {
            return i + 1;
        };
        let label = self.p.oword(i).map(|o| o.label.clone());
        let label = label.as_ref().map_or_else(String::new, ToString::to_string);
        if self.depth >= MAX_CALL_DEPTH {
            let msg =
                format!("{label} call: subroutine calls nested more than {MAX_CALL_DEPTH} deep");
            self.oword_error(i, msg);
            return i + 1;
        }
        let defined = self
            .p
            .lines
            .get(sub)
            .and_then(|l| self.defined.get(l.oword as usize));
        if defined != Some(&true) {
            let at = self.p.lines.get(sub).map_or(0, |l| l.number);
            let msg = format!(
                "{label} call: {label} sub (line {at}) is not defined yet when this call runs \
                 (a subroutine may only be called after its definition)"
            );
            self.oword_error(i, msg);
            return i + 1;
        }
        let params = &mut self.interp.params;
        let mut saved = [0.0; MAX_ARGS];
        for (k, slot) in saved.iter_mut().enumerate() {
            *slot = params.numbered(k + 1);
        }
        // #1…#n are the arguments; #n+1…#30 keep their values (LinuxCNC's rule).
        for (k, &v) in self.args[..n].iter().enumerate() {
            params.set_numbered(k + 1, v);
        }
        params.set_named(b"_value", 0.0);
        params.set_named(b"_value_returned", 0.0);
        let scope = params.enter_scope();
        self.stack.push(Frame::Call(Box::new(CallFrame {
            ret: i + 1,
            saved,
            scope,
        })));
        self.depth += 1;
        sub + 1
    }

    /// `return` or `endsub` on line `i`, with its value: back to the caller.
    fn ret(&mut self, i: usize, value: Option<f64>) -> usize {
        while let Some(frame) = self.stack.pop() {
            let Frame::Call(call) = frame else { continue };
            let params = &mut self.interp.params;
            for (k, &v) in call.saved.iter().enumerate() {
                params.set_numbered(k + 1, v);
            }
            params.leave_scope(call.scope);
            if let Some(v) = value {
                params.set_named(b"_value", v);
                params.set_named(b"_value_returned", 1.0);
            }
            self.depth -= 1;
            return call.ret;
        }
        // Unreachable for an indexed program (a sub's body runs only when called).
        self.oword_error(i, "return outside a subroutine call".into());
        i + 1
    }

    /// The run went on too long: an error at the innermost loop (or call), which
    /// ends the run.
    fn runaway(&mut self, i: usize) {
        let at = self.stack.last().map_or(i, |f| match f {
            Frame::Loop { start, .. } => *start,
            Frame::Call(c) => c.ret.saturating_sub(1),
        });
        let what = self.p.oword(at).map_or_else(
            || "the program".to_string(),
            |o| format!("{} {}", o.label, o.keyword.name()),
        );
        let message = format!(
            "{what}: stopped after running {} lines more than the program \
             has (an endless loop?)",
            self.interp.opts.repeated_lines
        );
        self.failed
            .remove(&self.p.lines.get(at).map_or(0, |l| l.number));
        self.oword_error(at, message);
    }
}

/// Reads and executes one plain line (`text`, its words from byte `from`), numbered
/// `number`: its commands are appended to `out`, or, on an error, nothing of it and
/// the error's character column and message are returned. Shared by whole programs
/// and by [`crate::gcode::LineSession`].
pub(crate) fn execute_line(
    interp: &mut Interp<'_>,
    words: &mut Words,
    text: &str,
    from: usize,
    number: u32,
    out: &mut Vec<Canon>,
) -> Result<(), (usize, ErrorKind, String)> {
    if text.len() > MAX_LINE && text.chars().count() > MAX_LINE {
        return Err((
            MAX_LINE + 1,
            ErrorKind::LineTooLong,
            format!("line longer than {MAX_LINE} characters"),
        ));
    }
    lexer::scan_line(text, from, &interp.params, words)
        .map_err(|e| (lexer::char_col(text, e.col), e.kind, e.message))?;
    let before = out.len();
    interp.execute(words, number, out).map_err(|e| {
        out.truncate(before);
        (lexer::char_col(text, e.col), e.kind, e.message)
    })
}
