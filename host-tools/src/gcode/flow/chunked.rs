//! A program without O-words run in pieces of whole lines, with bounded state: the
//! lines are indexed and executed as [`super::Program::index`] and [`super::run`] do
//! for the whole text (`%`, block delete, a post's program name, M2/M30, every error
//! at its line and column), but nothing of a piece is kept once it has run. A
//! program that has an O-word (a subroutine, a branch, a loop) needs the whole text:
//! [`Chunked::feed`] says so, and the caller compiles it whole
//! ([`crate::gcode::compile_canon`]).

use super::lines::Lines;
use super::{first_word_may_be_o, program_name};
use crate::gcode::canon::Canon;
use crate::gcode::interp::Interp;
use crate::gcode::lexer::{self, Words};
use crate::gcode::{Diagnostic, ErrorKind, Options};

/// The program has an O-word line: it runs only as a whole
/// ([`crate::gcode::compile_canon`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct NeedsWhole;

/// The front end over a program fed in pieces.
pub struct Chunked<'o> {
    interp: Interp<'o>,
    words: Words,
    file: String,
    block_delete: bool,
    /// Lines read so far (the number of the last one).
    number: usize,
    /// Non-blank lines indexed (what a whole program's index holds).
    indexed: usize,
    seen_text: bool,
    opening_percent: Option<usize>,
    closed: bool,
    /// Every error found, in line order.
    pub errors: Vec<Diagnostic>,
}

impl<'o> Chunked<'o> {
    /// The front end at the start of a program named `file`, with `options`.
    pub fn new(options: &'o Options, file: &str) -> Self {
        Self {
            interp: Interp::new(options),
            words: Words::default(),
            file: file.to_string(),
            block_delete: options.block_delete,
            number: 0,
            indexed: 0,
            seen_text: false,
            opening_percent: None,
            closed: false,
            errors: Vec::new(),
        }
    }

    /// The interpreter, for its state (where the program stands).
    pub fn interp(&self) -> &Interp<'o> {
        &self.interp
    }

    fn error(&mut self, line: usize, col: usize, kind: ErrorKind, message: String) {
        self.errors.push(Diagnostic {
            file: self.file.clone(),
            line,
            col,
            kind,
            message,
        });
    }

    /// Runs `piece`, the program's next lines: whole lines, each ended by a line feed
    /// but the program's last (an empty last piece is the end after a final line
    /// feed). Appends the commands to `out`.
    pub fn feed(
        &mut self,
        piece: &str,
        last: bool,
        out: &mut Vec<Canon>,
    ) -> Result<(), NeedsWhole> {
        let body = match (last, piece.strip_suffix('\n')) {
            (false, Some(b)) => b,
            _ => piece,
        };
        for raw in Lines::new(body) {
            self.number += 1;
            if self.closed {
                continue;
            }
            let number = u32::try_from(self.number).unwrap_or(u32::MAX);
            let kept = raw.bytes().rposition(|b| b != b'\r').map_or(0, |p| p + 1);
            let text = raw.get(..kept).unwrap_or(raw);
            let bytes = text.as_bytes();
            let Some(first) = bytes.iter().position(|&b| b != b' ' && b != b'\t') else {
                continue;
            };
            if bytes[first] == b'%' && bytes[first + 1..].iter().all(|&b| b == b' ' || b == b'\t') {
                if !self.seen_text {
                    self.seen_text = true;
                    self.opening_percent = Some(self.number);
                    continue;
                }
                self.closed = true;
                continue;
            }
            self.seen_text = true;
            let mut from = first;
            if bytes[first] == b'/' {
                if self.block_delete {
                    continue;
                }
                from += 1;
            }
            if program_name(&bytes[from..]) {
                continue;
            }
            self.indexed += 1;
            if first_word_may_be_o(&bytes[from..])
                && !(text.len() > crate::gcode::MAX_LINE
                    && text.chars().count() > crate::gcode::MAX_LINE)
            {
                match lexer::scan_oword(text, from, &self.interp.params) {
                    Ok(None) => {}
                    Ok(Some(_)) => return Err(NeedsWhole),
                    Err(e) => {
                        // A broken O-word line never runs.
                        let col = lexer::char_col(text, e.col);
                        self.error(self.number, col, e.kind, e.message);
                        continue;
                    }
                }
            }
            if self.interp.ended() {
                continue; // indexed, not run: the program ended at M2/M30
            }
            let run = super::run::execute_line(
                &mut self.interp,
                &mut self.words,
                text,
                from,
                number,
                out,
            );
            if let Err((col, kind, message)) = run {
                self.error(self.number, col, kind, message);
            }
        }
        Ok(())
    }

    /// The end of the program: what cutter compensation still holds, and the checks
    /// of the whole (an opening `%` never closed). Returns every error, in line order.
    pub fn finish(&mut self, out: &mut Vec<Canon>) -> &[Diagnostic] {
        if let Err(e) = self.interp.finish(out) {
            let line = self.indexed.max(1);
            self.error(line, e.col as usize, e.kind, e.message);
        }
        if let Some(open) = self.opening_percent {
            if !self.closed && !self.interp.ended() {
                self.error(
                    open,
                    1,
                    ErrorKind::Flow,
                    "program opened with '%' is never closed by a '%' line".into(),
                );
            }
        }
        self.errors.sort_by_key(|d| (d.line, d.col));
        &self.errors
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `text` run in pieces of `lines` lines, or `None` if it needs the whole text.
    fn in_pieces(text: &str, lines: usize) -> Option<Result<Vec<Canon>, Vec<Diagnostic>>> {
        let options = Options::default();
        let mut c = Chunked::new(&options, "p.ngc");
        let mut out = Vec::new();
        let mut rest = text;
        loop {
            let cut = rest.match_indices('\n').nth(lines - 1).map(|(i, _)| i + 1);
            let (piece, last) = match cut {
                Some(i) => (&rest[..i], false),
                None => (rest, true),
            };
            c.feed(piece, last, &mut out).ok()?;
            if last {
                break;
            }
            rest = &rest[piece.len()..];
        }
        let errors = c.finish(&mut out).to_vec();
        Some(if errors.is_empty() {
            Ok(out)
        } else {
            Err(errors)
        })
    }

    fn programs() -> Vec<(String, String)> {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples");
        let mut v: Vec<(String, String)> = std::fs::read_dir(&root)
            .unwrap()
            .filter_map(|e| {
                let p = e.ok()?.path();
                let t = std::fs::read_to_string(&p).ok()?;
                Some((p.display().to_string(), t))
            })
            .collect();
        let cases = [
            "%\nG21 G90\nG1 X1 F100\n/G1 X2\nG1 X3 Q\nG2 X4 R0.1\n%\nG1 X9\n",
            "%\nG1 X1 F10\n",
            "G1 X1 F10\nM2\nG1 X2 Y\n\n",
            "G41 D1\nG1 X1 F10\nG1 Y1\r\nO100 (bad\nG1 X5 Y5",
            "O sub\nG1 X1 F10\n",
            "g1 x1 f10\nO100 sub\nG1 X2\nO100 endsub\nO100 call\nM2\n",
        ];
        v.extend(cases.iter().map(|c| ("case".to_string(), c.to_string())));
        v
    }

    #[test]
    fn a_program_in_pieces_gives_the_commands_and_errors_of_the_whole() {
        for (name, text) in programs() {
            let whole = crate::gcode::compile_canon(&text, "p.ngc", &Options::default());
            for lines in [1, 2, 7, 1000] {
                match in_pieces(&text, lines) {
                    Some(pieces) => assert_eq!(pieces, whole, "{name} in pieces of {lines}"),
                    None => assert!(text.contains("sub"), "{name}: only O-words need the whole"),
                }
            }
        }
    }
}
