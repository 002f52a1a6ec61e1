//! G38.2–G38.5, straight probing, with LinuxCNC's semantics: a feed move toward the
//! target that stops where the probe makes contact (G38.2, G38.3) or loses it
//! (G38.4, G38.5); G38.2 and G38.4 are errors when the move ends without the change.
//! After the move #5061–#5066 hold the probed position (X Y Z A B C, program
//! coordinates and units; #5067–#5069, U V W, are 0) and #5070 is 1 on success, 0
//! otherwise; the move ends where the machine stopped.
//!
//! What the move finds is known only once it has run, and what follows may depend on
//! it (#5061 in an expression, a branch on #5070). So a run stops at a probing move
//! whose outcome it does not have ([`super::Interp::waiting`]); the host runs the
//! program up to it, probes, and runs the program again with the outcomes so far
//! ([`crate::gcode::Options::probes`]), which then go on past it. A front end fed
//! line by line (the Grbl bridge, MDI) is given the outcome instead
//! ([`super::Interp::probed`]) and goes on from there; both ways apply it with the
//! same code.
//!
//! Refused as LinuxCNC refuses them: a probing move with inverse-time feed (G93), with
//! cutter compensation on, that moves A B or C, that goes nowhere, or without a feed.

use super::{Interp, Res};
use crate::gcode::canon::Canon;
use crate::gcode::lexer::Words;
use crate::gcode::ErrorKind;
use pkmc::config::AXES;

/// First parameter of the probed position (#5061: X).
pub const PROBED: usize = 5061;
/// The probe's success flag (#5070).
pub const PROBE_SUCCESS: usize = 5070;

/// Which probing move.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Probing {
    /// It seeks contact (G38.2, G38.3); otherwise its loss (G38.4, G38.5).
    pub toward: bool,
    /// Ending without the change is an error (G38.2, G38.4).
    pub must_change: bool,
}

impl Probing {
    /// The move of G38.x for `tenths` 382 ..= 385.
    pub fn of(tenths: i32) -> Self {
        Self {
            toward: tenths <= 383,
            must_change: tenths == 382 || tenths == 384,
        }
    }

    /// Its G code.
    pub fn name(self) -> &'static str {
        match (self.toward, self.must_change) {
            (true, true) => "G38.2",
            (true, false) => "G38.3",
            (false, true) => "G38.4",
            (false, false) => "G38.5",
        }
    }
}

/// A probing move the run waits at for its outcome.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Waiting {
    /// Which move.
    probing: Probing,
    /// Its column, for a refusal once the outcome is known.
    col: u32,
}

/// What a probing move found (from the controller's latch, through the kinematics).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ProbeOutcome {
    /// The probe changed as sought.
    pub changed: bool,
    /// The pose where it changed (or where the move ended without a change), axis
    /// units, machine frame (as block targets).
    pub probed: [i64; AXES],
    /// Where the machine stopped, axis units, machine frame.
    pub stopped: [i64; AXES],
}

impl Interp<'_> {
    /// A probing move on this line (see the module documentation).
    pub(super) fn probe(
        &mut self,
        w: &Words,
        probing: Probing,
        b: &super::Block,
        col: u32,
        out: &mut Vec<Canon>,
    ) -> Res<()> {
        let name = probing.name();
        if !self.opts.probing {
            return super::fail(
                col,
                ErrorKind::Unsupported,
                crate::gcode::unsupported(&format!(
                    "{name} probing here (probing runs in programs run by nc-send or the station, in the station's MDI and through the Grbl bridge)"
                )),
            );
        }
        if self.inverse_time {
            return super::fail(
                col,
                ErrorKind::ModeConflict,
                format!("{name} cannot be used with inverse-time feed (G93)"),
            );
        }
        if self.comp.on() {
            return super::fail(
                col,
                ErrorKind::ModeConflict,
                format!("{name} cannot be used with cutter radius compensation on"),
            );
        }
        let target = self.target(w, false)?;
        if target[3..] != self.pos[3..] {
            return super::fail(
                col,
                ErrorKind::InvalidTarget,
                format!("{name} cannot move the rotary axes A B C"),
            );
        }
        if target == self.pos {
            return super::fail(
                col,
                ErrorKind::InvalidTarget,
                format!("{name}: the move goes nowhere (its end is where it starts)"),
            );
        }
        let feed = self.feed_for(&target, false, b.inverse, name, col)?;
        let outcome = self.opts.probes.get(self.probes_done).copied();
        let line = b.line;
        out.push(Canon::Probe {
            line,
            target: outcome.map_or(target, |o| o.stopped),
            feed,
            probing,
            outcome,
        });
        let Some(o) = outcome else {
            self.waiting = Some(Waiting { probing, col });
            return Ok(());
        };
        self.probes_done += 1;
        self.apply_outcome(probing, col, &o)
    }

    /// The outcome of the probing move the run waits for ([`Interp::waiting`]): a
    /// front end fed line by line is given it once the move has run, as a program
    /// compiled again is given it in [`crate::gcode::Options::probes`]. The position
    /// becomes where the machine stopped, #5061–#5070 are set, and a G38.2 or G38.4
    /// that ended without the change is refused at its column, as in a program.
    pub fn probed(&mut self, o: &ProbeOutcome) -> Res<()> {
        let Some(w) = self.waiting.take() else {
            return super::fail(
                1,
                ErrorKind::ModeConflict,
                "a probing outcome was given with no probing move waiting for one",
            );
        };
        let r = self.apply_outcome(w.probing, w.col, o);
        self.update_position_params();
        r
    }

    /// What the probing move `probing` (at column `col`) found, applied: the position
    /// where the machine stopped, #5061–#5070, and the refusal of a G38.2 or G38.4
    /// without the change (the one code of both ways an outcome comes).
    fn apply_outcome(&mut self, probing: Probing, col: u32, o: &ProbeOutcome) -> Res<()> {
        self.pos = o.stopped;
        let probed = self.program_position(&o.probed);
        for (i, v) in probed.iter().enumerate() {
            self.params.set_numbered(PROBED + i, *v);
        }
        for k in AXES..9 {
            self.params.set_numbered(PROBED + k, 0.0);
        }
        self.params
            .set_numbered(PROBE_SUCCESS, if o.changed { 1.0 } else { 0.0 });
        if probing.must_change && !o.changed {
            let what = if probing.toward {
                "contact"
            } else {
                "losing contact"
            };
            return super::fail(
                col,
                ErrorKind::InvalidTarget,
                format!("{}: the move ended without {what}", probing.name()),
            );
        }
        Ok(())
    }

    /// `pose` (machine frame, axis units) in program coordinates and units, as the
    /// position parameters read it.
    fn program_position(&self, pose: &[i64; AXES]) -> [f64; AXES] {
        let p = self.program_frame(pose);
        std::array::from_fn(|i| crate::gcode::params::user_units(p[i], i, self.inch))
    }
}
