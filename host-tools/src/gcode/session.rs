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
        self.interp
            .probed(outcome)
            .map_err(|e| self.diagnostic(number, *e))
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

#[cfg(test)]
mod tests {
    use super::*;

    const PROGRAM: [&str; 4] = [
        "G10 L2 P1 X1 Y2",
        "G20",
        "G38.2 Z-0.5 F10",
        "G0 X[#5061] Y[#5070] Z[#5063 + 0.1]",
    ];

    fn outcome(changed: bool) -> ProbeOutcome {
        ProbeOutcome {
            changed,
            probed: [3_000_000, 4_000_000, -5_080_000, 0, 0, 0],
            stopped: [3_000_000, 4_000_000, -5_200_000, 0, 0, 0],
        }
    }

    fn last_target(canon: &[Canon]) -> [i64; AXES] {
        match canon.last() {
            Some(Canon::Rapid { target, .. }) => *target,
            other => panic!("not a rapid: {other:?}"),
        }
    }

    /// A session stops at the probing move; given its outcome it goes on with the
    /// same #5061–#5070 and position as a program compiled with that outcome.
    #[test]
    fn a_probing_moves_outcome_given_line_by_line_is_the_programs() {
        let opts = Options {
            probing: true,
            start: [3_000_000, 4_000_000, 0, 0, 0, 0],
            ..Options::default()
        };
        let mut s = LineSession::new(&opts, "MDI");
        let mut out = Vec::new();
        for (n, l) in PROGRAM[..3].iter().enumerate() {
            s.line(l, n as u32 + 1, &mut out).unwrap();
        }
        assert!(s.waiting());
        assert!(matches!(
            out.last(),
            Some(Canon::Probe { outcome: None, .. })
        ));
        let refused = s.line("G0 X0", 4, &mut out).unwrap_err();
        assert!(
            refused.message.contains("waits for its outcome"),
            "{refused}"
        );
        s.probed(&outcome(true), 3).unwrap();
        assert!(!s.waiting());
        assert_eq!(s.interp().pos, outcome(true).stopped);
        out.clear();
        s.line(PROGRAM[3], 4, &mut out).unwrap();
        let by_line = last_target(&out);

        let file = Options {
            probes: vec![outcome(true)],
            ..opts.clone()
        };
        let canon = crate::gcode::compile_canon(&PROGRAM.join("\n"), "p", &file).unwrap();
        assert_eq!(by_line, last_target(&canon));
        // Program coordinates in inches (G20, G54 X1 Y2 mm): #5061 is X 3 mm less
        // 1 mm, back at machine X 3 mm; Y is #5070 = 1 inch past G54's 2 mm; #5063 is
        // -5.08 mm = -0.2 inch, and 0.1 inch up from it is -2.54 mm.
        assert_eq!(by_line[..3], [3_000_000, 27_400_000, -2_540_000]);
    }

    /// G38.2 without contact is refused at its column once the outcome says so; the
    /// position is where the machine stopped and #5070 is 0 all the same.
    #[test]
    fn a_g38_2_without_contact_is_refused_at_its_column() {
        let opts = Options {
            probing: true,
            ..Options::default()
        };
        let mut s = LineSession::new(&opts, "MDI");
        let mut out = Vec::new();
        s.line("G21 G38.2 Z-5 F10", 7, &mut out).unwrap();
        let e = s.probed(&outcome(false), 7).unwrap_err();
        assert_eq!((e.line, e.col), (7, 5), "{e}");
        assert!(
            e.message.contains("G38.2: the move ended without contact"),
            "{e}"
        );
        assert_eq!(s.interp().pos, outcome(false).stopped);
        assert_eq!(s.interp().params.numbered(5070), 0.0);
        let again = s.probed(&outcome(true), 7).unwrap_err();
        assert!(again.message.contains("no probing move waiting"), "{again}");
    }
}
