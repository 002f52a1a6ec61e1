//! What the job runner tells its caller and asks it: how a job ended, the hooks a
//! caller gives a job (statuses, controls, blocks fed as they come, the recorder), and
//! what they may look at.

use pkmc::motion::block::Block;
use pkmc::wire::{Alarm, Control, Status};

/// How a job ended.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum JobEnd {
    /// Every block executed; the controller is idle.
    Done,
    /// The controller raised an alarm.
    Alarm(Alarm),
    /// The operator aborted: the controller stopped on the path and dropped its queue.
    Aborted,
    /// The operator stopped immediately: the controller is in alarm (`Aborted`).
    Stopped,
    /// A resumed job stopped at rest again in a pause or tool change (M0, M1, M6) at
    /// this NC line; `nc-send resume` continues it.
    Paused(u32),
}

/// A fed job's blocks from some block on and where that block starts, or why they
/// cannot be had ([`JobHooks::rewind`]).
pub type Rewound = Result<(Vec<Block>, [i64; 6]), String>;

/// What the job runner tells its caller, and asks it.
pub trait JobHooks {
    /// Every status received.
    fn status(&mut self, _status: &Status) {}
    /// Asked on every turn of the loop: a control command to send now (operator keys,
    /// Ctrl-C). `Abort` and `Stop` end the job once they have taken effect.
    fn control(&mut self, _link: &LinkView) -> Option<Control> {
        None
    }
    /// Does a program pause (M0, M1, M6) end the job here, leaving it held on the
    /// controller ([`JobEnd::Paused`]), because no operator can resume it from this
    /// host? (Otherwise the job waits for [`JobHooks::control`] to resume it.)
    fn ends_at_pause(&self) -> bool {
        false
    }
    /// Called every few milliseconds while the link plans blocks the job was given or
    /// fed, so that the hooks go on answering their own clients meanwhile (the Grbl
    /// bridge's `?`). Controls wanted then wait for [`JobHooks::control`].
    fn meanwhile(&mut self) {}
    /// Asked on every turn of the loop while the job is open: blocks to add to the
    /// job (a job fed line by line, as the Grbl bridge does), appended to `out`.
    /// Returns whether more may come; once it returns `false` it is not asked again,
    /// and the job ends when every block has executed. By default a job is closed: it
    /// is the blocks [`Link::run_job`] was given.
    fn feed(&mut self, _link: &LinkView, _out: &mut Vec<Block>) -> bool {
        false
    }
    /// A fed job taken over again from its block `to` (after a replug): its blocks from
    /// `to` on as its source gives them again (the first of them; [`JobHooks::feed`]
    /// then goes on after them), and where block `to` starts. `None`: the job's blocks
    /// are all in hand (a job whose blocks are fed as they come cannot be rewound).
    fn rewind(&mut self, _to: usize) -> Option<Rewound> {
        None
    }
    /// The recorder's streamed pieces received so far while a job or a move runs
    /// (its continuous mode), asked on every turn of the loop: hooks that show them as
    /// they come take them out of `pieces`; what they leave stays on the link for
    /// [`Link::record_take`] after the job.
    fn recorded(&mut self, _pieces: &mut Vec<super::record::Piece>) {}
    /// Asked on every turn of a streamed job's loop: the offset of a read of the
    /// recorder's capture to send now, beside the job's blocks (`None`: none). Its
    /// answer comes to [`JobHooks::record_answer`]; a lost one is asked again.
    fn record_ask(&mut self) -> Option<u32> {
        None
    }
    /// A recorder answer to a read (not a streamed piece) received while a streamed
    /// job runs: its header and its bytes.
    fn record_answer(&mut self, _reply: &pkmc::drive::recorder::Reply, _data: &[u8]) {}
    /// Asked on every turn of a job's or a move's loop: a recorder request to arm now,
    /// beside the job (`None`: none). It goes as the control it is, sent again until
    /// acknowledged; [`JobHooks::record_armed`] then hears how it went.
    fn record_arm(&mut self) -> Option<pkmc::drive::recorder::Setup> {
        None
    }
    /// The request of [`JobHooks::record_arm`] acknowledged: armed (`None`), or the
    /// controller's refusal in its words.
    fn record_armed(&mut self, _refused: Option<String>) {}
    /// Something the operator should know that is not an error (the job was held for
    /// this host's silence and is resumed, ...).
    fn note(&mut self, _text: &str) {}
    /// A warning the operator must see even when no progress is shown (a line so bad
    /// that motion slows down): on stderr unless the hooks show it elsewhere.
    fn warn(&mut self, text: &str) {
        eprintln!("warning: {text}");
    }
}

/// Hooks that do nothing.
pub struct NoHooks;
impl JobHooks for NoHooks {}

/// What [`JobHooks::control`] may look at.
#[derive(Clone, Debug, Default)]
pub struct LinkView {
    /// Last status.
    pub status: Option<Status>,
    /// Blocks acknowledged so far in this job.
    pub acked: usize,
    /// Blocks in the job (so far, while it is fed).
    pub total: usize,
    /// Blocks of this job the controller has executed (by its last status).
    pub executed: usize,
    /// Is a control command still waiting for its acknowledgement?
    pub control_pending: bool,
}
