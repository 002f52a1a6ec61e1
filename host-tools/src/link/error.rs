//! Why the link failed: [`LinkError`], each variant naming the port.

use pkmc::wire::{State, PROTOCOL_VERSION};
use std::fmt;
use std::io;
use std::time::Duration;

/// Why the link failed. Every variant names the port.
#[derive(Debug)]
pub enum LinkError {
    /// The port could not be opened.
    Open {
        /// Port.
        port: String,
        /// Why.
        source: serialport::Error,
    },
    /// Reading or writing the port failed.
    Io {
        /// Port.
        port: String,
        /// "read" or "write".
        op: &'static str,
        /// Why.
        source: io::Error,
    },
    /// Nothing answered the handshake.
    NoAnswer {
        /// Port.
        port: String,
        /// How long we tried.
        waited: Duration,
    },
    /// The controller speaks another protocol version.
    Version {
        /// Port.
        port: String,
        /// The controller's version, when it said.
        theirs: Option<u16>,
    },
    /// The controller stopped answering.
    Lost {
        /// Port.
        port: String,
        /// Time since the last valid frame.
        silent: Duration,
        /// Time waited for the answer (or the progress) that never came.
        waited: Duration,
        /// What we were doing.
        during: &'static str,
    },
    /// The controller no longer knows the session (it restarted); the blocks it had
    /// queued are gone.
    SessionLost {
        /// Port.
        port: String,
    },
    /// The controller refused a block as malformed.
    BadBlock {
        /// Port.
        port: String,
        /// NC line of the block.
        line: u32,
    },
    /// The controller holds an earlier host's unfinished job: nothing new is queued
    /// behind it.
    JobHeld {
        /// Port.
        port: String,
        /// The job.
        job: pkmc::wire::HeldJob,
    },
    /// The controller refused our machine configuration.
    MachineRefused {
        /// Port.
        port: String,
        /// Why, as the controller said.
        error: String,
    },
    /// The controller runs another machine than ours and refuses to move.
    MachineMismatch {
        /// Port.
        port: String,
    },
    /// A simulated controller said it was moving but made no progress for
    /// [`STALL_TICKS`] (plus the dwell it was executing) of simulated time.
    Stalled {
        /// Port.
        port: String,
        /// NC line it was on.
        line: u32,
        /// Its state.
        state: State,
        /// Simulated time without progress.
        still: Duration,
    },
    /// Another program opened a session on the port (it said `Hello`) in the middle
    /// of our job: our session is over; the controller keeps the job as ours, an
    /// earlier host's unfinished job.
    Superseded {
        /// Port.
        port: String,
        /// How it showed.
        seen: &'static str,
    },
    /// The controller's recorder refused a request.
    Recorder {
        /// Port.
        port: String,
        /// Why.
        error: pkmc::drive::recorder::RecorderError,
    },
    /// A message did not fit in a frame (a bug).
    Frame {
        /// Port.
        port: String,
        /// The message.
        what: String,
    },
}

impl fmt::Display for LinkError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LinkError::Open { port, source } => write!(f, "{port}: cannot open: {source}"),
            LinkError::Io { port, op, source } => write!(f, "{port}: {op} failed: {source}"),
            LinkError::NoAnswer { port, waited } => write!(
                f,
                "{port}: no answer to the handshake for {:.1} s: is a pkmc controller on this port?",
                waited.as_secs_f64()
            ),
            LinkError::Version { port, theirs } => match theirs {
                Some(v) => write!(
                    f,
                    "{port}: the controller speaks protocol version {v}, nc-send {PROTOCOL_VERSION}"
                ),
                None => write!(
                    f,
                    "{port}: the controller refused protocol version {PROTOCOL_VERSION}"
                ),
            },
            LinkError::Lost {
                port,
                silent,
                waited,
                during,
            } if *waited > *silent + Duration::from_millis(100) => write!(
                f,
                "{port}: link lost: waited {:.1} s while {during} (frames kept arriving, \
                 damaged or not the answer; the last valid one {:.1} s ago)",
                waited.as_secs_f64(),
                silent.as_secs_f64()
            ),
            LinkError::Lost {
                port,
                silent,
                during,
                ..
            } => write!(
                f,
                "{port}: link lost: no answer from the controller for {:.1} s while {during}",
                silent.as_secs_f64()
            ),
            LinkError::SessionLost { port } => write!(
                f,
                "{port}: the controller lost the session (did it restart?); the blocks it had queued are gone"
            ),
            LinkError::BadBlock { port, line } => write!(
                f,
                "{port}: the controller refused the block of line {line} as malformed"
            ),
            LinkError::JobHeld { port, job } => write!(
                f,
                "{port}: the controller holds an unfinished job of another host (process {}, \
                 gone): {} at line {}, {} blocks done, {} still queued; `nc-send resume` \
                 continues it, `nc-send abort` drops it",
                job.host, job.state, job.line, job.done, job.queued
            ),
            LinkError::MachineRefused { port, error } => write!(
                f,
                "{port}: the controller refused the machine configuration: {error}"
            ),
            LinkError::MachineMismatch { port } => write!(
                f,
                "{port}: the controller runs another machine and refuses to move"
            ),
            LinkError::Stalled {
                port,
                line,
                state,
                still,
            } => {
                write!(f, "{port}: stalled")?;
                if *line != 0 {
                    write!(f, " at line {line}")?;
                }
                write!(
                    f,
                    ": the controller has been {state:?} for {:.1} s of simulated time with no \
                     block ending and nothing moving; run stopped",
                    still.as_secs_f64()
                )
            }
            LinkError::Superseded { port, seen } => write!(
                f,
                "{port}: another program opened a session on this port in the middle of the \
                 job (it said Hello; seen by {seen}): this host's session is over and it \
                 sends nothing more. The controller keeps the job as this host's unfinished \
                 job: once the other program has let go of the port, `nc-send status` shows \
                 it, `nc-send resume` continues what is queued, `nc-send abort` drops it"
            ),
            LinkError::Frame { port, what } => write!(f, "{port}: cannot frame {what}"),
            LinkError::Recorder { port, error } => {
                write!(f, "{port}: the controller's recorder refused the request: {error}")
            }
        }
    }
}

impl std::error::Error for LinkError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            LinkError::Open { source, .. } => Some(source),
            LinkError::Io { source, .. } => Some(source),
            _ => None,
        }
    }
}
