//! G-code one line at a time, with the modal state kept between lines: what a sender
//! streaming a program line by line (the Grbl bridge) or an operator typing MDI
//! lines needs. A line is read and executed exactly as a line of a program file is;
//! O-word flow control needs the whole program and is refused here.

use super::canon::Canon;
use super::interp::probe::ProbeOutcome;
use super::interp::{Interp, LineError};
use super::lexer::{self, Words};
use super::{flow, Diagnostic, ErrorKind, Options};
use pkmc::config::AXES;

/// An interpreter fed line by line.
pub struct LineSession<'o> {
    opts: &'o Options,
    interp: Interp<'o>,
    words: Words,
    file: String,
}

impl<'o> LineSession<'o> {
    /// A session at program start (see [`Interp::new`]); errors name `file`.
    pub fn new(opts: &'o Options, file: &str) -> Self {
        Self {
            opts,
            interp: Interp::new(opts),
            words: Words::default(),
            file: file.to_string(),
        }
    }

    /// The interpreter, for its state.
    pub fn interp(&self) -> &Interp<'o> {
        &self.interp
    }

    /// Moves the interpreter to `pose` (machine frame), where the machine now is.
    pub fn set_position(&mut self, pose: [i64; AXES]) {
        self.interp.set_position(pose);
    }

    /// Has M2 or M30 ended the program?
    pub fn ended(&self) -> bool {
        self.interp.ended()
    }

    /// Back to the state at program start at `pose`, keeping the parameters (work
    /// offsets, G92, stored positions): a soft reset, or the line after M2/M30.
    pub fn restart(&mut self, pose: [i64; AXES]) {
        let params = std::mem::take(&mut self.interp.params);
        self.interp = Interp::new(self.opts);
        self.interp.params = params;
        let mut out = Vec::new();
        // Selecting G54 loads the offsets from the parameters kept.
        let _ = self.line("G54", 0, &mut out);
        self.interp.set_position(pose);
    }

    /// Executes one line (without its line break), numbered `number` in messages;
    /// appends its commands to `out`. On an error nothing of the line is appended.
    pub fn line(
        &mut self,
        text: &str,
        number: u32,
        out: &mut Vec<Canon>,
    ) -> Result<(), Diagnostic> {
        let fail = |col: usize, kind: ErrorKind, message: String| Diagnostic {
            file: self.file.clone(),
            line: number as usize,
            col,
            kind,
            message,
        };
        if self.interp.waiting() {
            return Err(fail(
                1,
                ErrorKind::ModeConflict,
                "a probing move waits for its outcome: nothing runs before it is given".into(),
            ));
        }
        let program = flow::Program::index(text, false, &self.interp.params);
        if let Some((_, col, kind, message)) = program.errors.first() {
            return Err(fail(lexer::char_col(text, *col), *kind, message.clone()));
        }
        if !program.owords.is_empty() {
            let col = text
                .find(['o', 'O'])
                .map_or(1, |c| lexer::char_col(text, c as u32));
            return Err(fail(
                col,
                ErrorKind::Flow,
                "O-word flow control (subroutines, loops, branches) works only in a whole \
                 program (nc-send FILE), not line by line"
                    .into(),
            ));
        }
        let Some(line) = program.lines.first() else {
            return Ok(());
        };
        flow::run::execute_line(
            &mut self.interp,
            &mut self.words,
            text,
            line.from as usize,
            number,
            out,
        )
        .map_err(|(col, kind, message)| fail(col, kind, message))
    }

    /// Is the last line stopped at a probing move (G38.2–G38.5, with
    /// [`Options::probing`]) whose outcome it needs? Its command is the last one the
    /// line emitted; no line runs until [`Self::probed`] gives the outcome.
    pub fn waiting(&self) -> bool {
        self.interp.waiting()
    }

    /// The outcome of the probing move on line `number` that the session waits for
    /// ([`crate::gcode::interp::Interp::probed`]): the position becomes where the
    /// machine stopped and #5061–#5070 are set; a G38.2 or G38.4 without the change
    /// is refused at its column (the position and parameters set all the same).
    pub fn probed(&mut self, outcome: &ProbeOutcome, number: u32) -> Result<(), Diagnostic> {
        self.interp.probed(outcome).map_err(|e| self.diagnostic(number, *e))
    }

    fn diagnostic(&self, number: u32, e: LineError) -> Diagnostic {
        Diagnostic {
            file: self.file.clone(),
            line: number as usize,
            col: e.col as usize,
            kind: e.kind,
            message: e.message,
        }
    }

    /// Emits what cutter compensation still holds (the end of the stream).
    pub fn finish(&mut self, number: u32, out: &mut Vec<Canon>) -> Result<(), Diagnostic> {
        self.interp
            .finish(out)
            .map_err(|e| self.diagnostic(number, *e))
    }
}
