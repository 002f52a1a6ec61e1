//! Merging in the bridge: a sender's runs of short `G1` moves in `G64 P` become the
//! curves `nc-send` makes of the same program ([`crate::gcode::compress`], with the
//! same settings), so that a sender gets nc-send's motion.
//!
//! A sender streams line by line, so the bridge cannot see a whole run at once: it
//! answers each line `ok` at once (Grbl's `ok` says the line is in the planner
//! buffer) and holds the line's mergeable moves back. While more lines may come, a
//! merge is *open*: it hands out only the curves the moves to come cannot change
//! ([`compress::Resume`]), and keeps the rest held, with the few moves before them
//! that the next merge's tangents look back on. Open merges run on a thread of their
//! own, so that lines are answered meanwhile; one follows another while lines come
//! and the machine moves, and the first at rest waits [`LONGEST_HOLD`] for the
//! sender. So the curves are the ones nc-send makes of the whole program.
//!
//! A *closed* merge cuts the runs at the last held move. It comes at:
//! - a block that cannot join a run (a rapid, an arc, a dwell, an auxiliary function,
//!   `G61`, `G64` without P): the held moves are merged and sent before it;
//! - the controller about to run out ([`LOW_QUEUE`] blocks or fewer left to run;
//!   at rest with nothing queued it cannot);
//! - the sender quiet for [`QUIET`] with nothing more waiting;
//! - an open merge at rest that could hand out nothing.
//!
//! Closed merges run on the merge thread as well. A block that cannot join a run
//! waits behind the merge of the moves before it, with every block that comes after
//! it, and all go in order once the merge is handed out: the sender's lines are
//! answered meanwhile (a merge of 2 048 held moves takes about a second).
//!
//! A run cut by a closed merge ends at a vertex of the programmed polyline, as any
//! run does at a corner: the curves on either side meet there. The next merge's first
//! curve leaves that vertex as the last one arrived (its direction, and the ratio of
//! the tool's speed to the path speed: [`compress::Lead`]), unless the polyline turns
//! a corner there, so that the junction passes at speed as within one merge. Corners
//! are blended as
//! `nc-send` blends them ([`compress::blend`]), those between two merges too: as
//! `nc-send` does between the pieces of a streamed program, the last blendable block of
//! a merge is kept back (the [`Blender`] holds it) until the next merge brings the
//! block after its corner. It goes alone, its end unblended, when the controller is
//! about to run out or the sender has been quiet, or before a block that cannot be
//! blended. A reset (0x18) or an alarm drops what is held, as Grbl drops its planner
//! buffer.

use crate::gcode::compress::blend::Blender;
use crate::gcode::compress::{self, Compressed, Lead, Resume, Settings};
use pkmc::config::AXES;
use pkmc::motion::block::{Block, Motion};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Most moves held back for one merge: more than two curves may reach
/// ([`Settings::max_chords`], 400, each; a curve is handed out once the one after it
/// is known), so that a merge of them hands out the curves the whole program gives up
/// to that far before the last.
const MOST_HELD: usize = 1024;
/// The longest a move is held back.
const LONGEST_HOLD: Duration = Duration::from_millis(150);
/// Held moves go once the sender has been quiet this long.
const QUIET: Duration = Duration::from_millis(40);
/// Held moves go once the controller has this few blocks or fewer left to run...
const LOW_QUEUE: usize = 3;
/// ... and less motion than this, ms, by its last status (short blocks run out fast).
const LOW_MS: u32 = 120;

/// The moves held back for merging.
pub(super) struct Merger {
    /// The compressor's settings for the machine; `None`: every block goes as it is.
    settings: Option<Settings>,
    held: Vec<Block>,
    /// The first `done` of `held` were merged already: the points before the next
    /// curve that its run's tangents look back on ([`compress::context_from`]).
    done: usize,
    /// Where the held run starts: the end of the programmed moves before it.
    start: [i64; AXES],
    /// The corners' blender, across merges (with `settings`).
    blender: Option<Blender>,
    /// How the last merge's curves ended, for the next merge to continue them.
    lead: Option<Lead>,
    /// When the oldest move held (in `held` or by the blender) came.
    since: Option<Instant>,
    /// When the last line's blocks came.
    last_line: Instant,
    /// Moves merged, and the blocks made of them (for the summary).
    pub(super) merged: (u64, u64),
    /// A merge under way on another thread (so that the sender's lines are taken
    /// meanwhile), of the moves held when it started; it has the blender meanwhile.
    under_way: Option<JoinHandle<Merged>>,
    /// The last open merge merged nothing (its runs go on past what is held).
    idle: bool,
    /// Moves taken since the last open merge started.
    fresh: usize,
    /// A block that cannot join a run came with moves held: they are being merged
    /// (closed) on the thread, and it waits in `behind` with every block after it.
    closing: bool,
    /// The blocks taken while `closing`, in order, taken up again once the merge
    /// before them is handed out.
    behind: Vec<Block>,
}

/// What a merge of held moves gives: the blocks, blended; how the last curve ended;
/// how many of the moves they stand for; and the blender, which the merge took along
/// (it blends on the merge's thread too, with the corner it keeps for the next).
struct Merged {
    blocks: Compressed,
    lead: Option<Lead>,
    merged: usize,
    blender: Option<Blender>,
}

/// Merges `held` (from `start`, going on as `resume` says) and blends the merged
/// blocks with `blender` (but for the last blendable one, which it keeps).
fn merge_and_blend(
    held: &[Block],
    start: [i64; AXES],
    s: &Settings,
    resume: Resume,
    mut blender: Option<Blender>,
) -> Merged {
    let (runs, lead, merged) = compress::compress_runs_after(held, start, s, resume);
    let mut blocks = Compressed::default();
    if let Some(b) = &mut blender {
        b.push(held, &runs, 0, &mut blocks);
    }
    Merged {
        blocks,
        lead,
        merged,
        blender,
    }
}

/// May `b` be part of a run? A feed move the compressor merges within a tolerance
/// (`compress::merge_tolerance`; it decides the rest: length, feed, corners).
fn candidate(b: &Block, s: &Settings) -> bool {
    b.motion == Motion::Linear && compress::merge_tolerance(b, s).is_some()
}

impl Merger {
    /// A merger with `settings` (already set for the machine), starting at `start`.
    pub(super) fn new(settings: Option<Settings>, start: [i64; AXES]) -> Self {
        Self {
            blender: settings.map(|s| Blender::new(&s, start)),
            lead: None,
            settings,
            held: Vec::new(),
            done: 0,
            start,
            since: None,
            last_line: Instant::now(),
            merged: (0, 0),
            under_way: None,
            idle: false,
            fresh: 0,
            closing: false,
            behind: Vec::new(),
        }
    }

    /// Drops anything held; the next block starts at `pose` (a job's first line
    /// went straight to the controller, a reset, an alarm).
    pub(super) fn restart_at(&mut self, pose: [i64; AXES]) {
        // A merge under way is of moves dropped: its result is too. Its thread is
        // left to end on its own (detached), so a reset does not wait for it.
        self.under_way = None;
        self.idle = false;
        self.closing = false;
        self.behind.clear();
        self.held.clear();
        self.done = 0;
        self.since = None;
        self.start = pose;
        self.lead = None;
        self.blender = self.settings.map(|s| Blender::new(&s, pose));
    }

    /// Nothing is held.
    pub(super) fn is_empty(&self) -> bool {
        self.held.len() == self.done
            && self.under_way.is_none()
            && !self.closing
            && !self.blender.as_ref().is_some_and(Blender::holds)
    }

    /// Takes a line's blocks: mergeable moves are held; anything else goes after what
    /// is held, merged on the thread (closed) meanwhile ([`Merger::settle`] hands
    /// them out in order).
    pub(super) fn take(&mut self, blocks: Vec<Block>, out: &mut Vec<Block>) {
        self.last_line = Instant::now();
        self.take_blocks(blocks, out);
    }

    fn take_blocks(&mut self, blocks: Vec<Block>, out: &mut Vec<Block>) {
        for b in blocks {
            if self.closing {
                self.behind.push(b);
            } else if self.settings.is_some_and(|s| candidate(&b, &s)) {
                self.since.get_or_insert_with(Instant::now);
                self.held.push(b);
                self.fresh += 1;
                if self.held.len() - self.done >= MOST_HELD {
                    self.collect(false, out);
                    self.start_merge(true);
                }
            } else if self.held.len() > self.done || self.under_way.is_some() {
                // The held moves are merged first, on the thread, so that lines are
                // still answered meanwhile (a merge of 2 048 moves takes about 1 s).
                self.closing = true;
                self.behind.push(b);
                self.collect(false, out);
                self.start_merge(false);
            } else {
                self.flush(out);
                if !matches!(b.motion, Motion::Dwell(_) | Motion::Aux(_)) {
                    self.start = b.target;
                }
                self.held.clear();
                self.done = 0;
                out.push(b);
                self.lead = None;
                // The next blend starts after this block.
                self.blender = self.settings.map(|s| Blender::new(&s, self.start));
            }
        }
    }

    /// Merges what is held and appends it to `out`, but for the last blendable block,
    /// which the blender keeps for the corner after it; a merge under way first. The
    /// merge is closed: the runs are cut at the last held move.
    fn merge(&mut self, out: &mut Vec<Block>) {
        self.settle(true, out);
        let (Some(s), true) = (self.settings, self.held.len() > self.done) else {
            return;
        };
        let blender = self.blender.take();
        let result = merge_and_blend(&self.held, self.start, &s, self.resume(false), blender);
        self.apply(result, out);
    }

    /// Starts a merge of what is held on another thread, unless one is under way.
    /// `open`: a run that reaches the last held move goes only as far as its curves
    /// are the whole program's (`compress::compress_runs_after`); the rest stays held.
    /// Closed: the runs are cut at the last held move.
    fn start_merge(&mut self, open: bool) {
        let (Some(s), None, true) = (self.settings, &self.under_way, self.held.len() > self.done)
        else {
            return;
        };
        let (held, start, resume) = (self.held.clone(), self.start, self.resume(open));
        let blender = self.blender.take();
        self.fresh = 0;
        let job = std::thread::spawn(move || merge_and_blend(&held, start, &s, resume, blender));
        self.under_way = Some(job);
    }

    /// How a merge goes on from the last one's curves (after the moves kept for
    /// context, or at a vertex where a merge was cut).
    fn resume(&self, open: bool) -> Resume {
        Resume {
            done: self.done,
            lead: self.lead,
            open,
        }
    }

    /// Hands out the merge under way once it is done (`wait`: waits for it); when it
    /// was the closed merge before a block that cannot join a run (`closing`), merges
    /// what is still held, then hands out the blender's block and takes up the blocks
    /// behind. With `wait`, nothing is under way or closing after it.
    fn settle(&mut self, wait: bool, out: &mut Vec<Block>) {
        loop {
            self.collect(wait, out);
            if self.under_way.is_some() || !self.closing {
                return;
            }
            if self.held.len() > self.done {
                self.start_merge(false);
                continue;
            }
            self.closing = false;
            let behind = std::mem::take(&mut self.behind);
            self.take_blocks(behind, out);
        }
    }

    /// Hands out the merge under way once it is done (`wait`: waits for it).
    fn collect(&mut self, wait: bool, out: &mut Vec<Block>) {
        if !self
            .under_way
            .as_ref()
            .is_some_and(|h| wait || h.is_finished())
        {
            return;
        }
        let Some(job) = self.under_way.take() else {
            return;
        };
        let result = job.join().expect("a merge of held moves");
        self.idle = result.merged == self.done;
        self.apply(result, out);
    }

    /// Appends the merged and blended blocks to `out` (the blender, back from the
    /// merge, keeps the last blendable one for the corner after it); keeps the moves
    /// after them, and those before them that the next merge's tangents look back on.
    fn apply(&mut self, m: Merged, out: &mut Vec<Block>) {
        self.blender = m.blender;
        let merged = m.merged;
        let (Some(s), Some(blender)) = (&self.settings, &self.blender) else {
            return;
        };
        self.lead = m.lead;
        self.merged.0 += (merged - self.done) as u64;
        self.merged.1 += m.blocks.blocks.len() as u64;
        out.extend(m.blocks.blocks);
        let keep = compress::context_from(&self.held, merged, s);
        if keep > 0 {
            self.start = self.held[keep - 1].target;
        }
        self.held.drain(..keep);
        self.done = merged - keep;
        // What the blender keeps, and moves still held, go within the longest hold
        // from now.
        self.since = (blender.holds() || self.held.len() > self.done).then(Instant::now);
    }

    /// Merges what is held and appends it to `out`, the blender's block too: nothing
    /// is held after it.
    pub(super) fn flush(&mut self, out: &mut Vec<Block>) {
        self.merge(out);
        if let Some(blender) = &mut self.blender {
            let mut c = Compressed::default();
            blender.finish(&mut c);
            self.merged.1 += c.blocks.len() as u64;
            out.extend(c.blocks);
        }
        self.since = None;
    }

    /// Sends what should go now: everything when the controller is about to run out
    /// (`queued`: blocks it has yet to run, or is about to get) or the sender has been
    /// quiet (`lines_waiting`: the sender's lines not yet taken); what is held, but the
    /// blender's block, once the oldest has waited [`LONGEST_HOLD`].
    ///
    /// "About to run out" is [`LOW_QUEUE`] blocks or fewer, with less than [`LOW_MS`]
    /// of motion buffered (`buffered_ms`, by the controller's last status). A machine
    /// at rest (`at_rest`: nothing queued, not moving) cannot run out: there the moves
    /// are held for a longer first merge, as long as the sender keeps sending.
    pub(super) fn send_due(
        &mut self,
        (queued, at_rest, buffered_ms): (usize, bool, u32),
        lines_waiting: bool,
        out: &mut Vec<Block>,
    ) {
        self.settle(false, out);
        if self.closing {
            return;
        }
        let Some(since) = self.since else {
            return;
        };
        let low = queued <= LOW_QUEUE && buffered_ms < LOW_MS && !at_rest;
        let quiet = !lines_waiting && self.last_line.elapsed() >= QUIET;
        // Every merge runs on its thread, so that lines and status requests are still
        // answered meanwhile; a merge under way hands out its blocks first.
        if self.under_way.is_some() {
            return;
        }
        if self.held.len() == self.done {
            // Only the blender's block is held.
            if low || quiet || since.elapsed() >= LONGEST_HOLD {
                self.flush(out);
            }
        } else if low || quiet {
            // The controller needs blocks now, or the sender has stopped: what is
            // held goes, the runs cut.
            self.start_merge(false);
        } else if since.elapsed() >= LONGEST_HOLD {
            // At rest, the first merge goes even where it must cut a run.
            self.start_merge(!(self.idle && at_rest));
        } else if !at_rest && self.fresh > 0 {
            // While the machine moves, one open merge follows another as long as
            // moves come: each hands out what the moves since allow.
            self.start_merge(true);
        }
    }

    /// Are so many moves held that no more lines should be taken until a merge has
    /// handed some out? (The sender then waits for its answers, as for a full
    /// Grbl planner buffer.)
    pub(super) fn full(&self) -> bool {
        self.held.len() - self.done + self.behind.len() >= 2 * MOST_HELD
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn g1(x: i64, y: i64, line: u32) -> Block {
        Block {
            line,
            motion: Motion::Linear,
            target: [x, y, 0, 0, 0, 0],
            feed: 50_000_000,
            tolerance_nm: 10_000,
        }
    }

    /// A sine's chords of 0.05 mm, as a sender would send them, a line each.
    fn chords(n: usize) -> Vec<Block> {
        (1..=n)
            .map(|i| {
                let x = i as f64 * 0.05;
                let y = 5.0 * (x / 10.0).sin();
                g1((x * 1e6) as i64, (y * 1e6) as i64, i as u32)
            })
            .collect()
    }

    /// A profile sampled unevenly, as CAM output often is (3D_Chips' steps of 0.5, 1
    /// and 2 mm in turn, here a tenth of them), within P0.01.
    fn uneven_chords(n: usize) -> Vec<Block> {
        let steps = [0.1, 0.1, 0.05, 0.05, 0.1, 0.2, 0.1, 0.05];
        let mut x = 0.0f64;
        (1..=n)
            .map(|i| {
                x += steps[i % steps.len()];
                let y = 0.8 * (x / 0.6).cos() + 0.3 * (x / 1.7).sin();
                g1((x * 1e6) as i64, (y * 1e6) as i64, i as u32)
            })
            .collect()
    }

    #[test]
    fn held_moves_become_the_curves_nc_send_makes() {
        let s = Settings::default();
        let mut m = Merger::new(Some(s), [0; AXES]);
        let mut out = Vec::new();
        let blocks = chords(200);
        for b in &blocks {
            m.take(vec![*b], &mut out);
        }
        assert!(out.is_empty(), "all held: {}", out.len());
        // A rapid sends the run first, merged as compress merges the whole program.
        // The merge runs on the thread: the rapid, and a move after it, wait behind
        // it (lines are answered meanwhile) and go after its curves.
        let rapid = Block {
            motion: Motion::Rapid,
            target: [0; AXES],
            line: 201,
            ..blocks[0]
        };
        m.take(vec![rapid], &mut out);
        let after = g1(1_000_000, 0, 202);
        m.take(vec![after], &mut out);
        assert!(out.is_empty() && m.under_way.is_some() && !m.is_empty());
        assert_eq!(m.behind, [rapid, after]);
        while m.closing {
            m.settle(false, &mut out);
            std::thread::yield_now();
        }
        let whole = compress::compress(&blocks, [0; AXES], &s);
        assert_eq!(out[..out.len() - 1], whole.blocks[..]);
        assert_eq!(out.last(), Some(&rapid));
        assert!(whole.blocks.len() < 20, "{} curves", whole.blocks.len());
        assert_eq!(m.merged, (200, whole.blocks.len() as u64));
        // The move after the rapid is held for a run of its own.
        assert_eq!(m.held, [after]);
        m.flush(&mut out);
        assert_eq!(out.last(), Some(&after));
        assert!(m.is_empty());
        let n = out.len();
        m.send_due((0, false, 0), false, &mut out);
        assert_eq!(out.len(), n, "nothing more to send");
    }

    #[test]
    fn a_flush_hands_out_a_closing_merge_and_everything_behind_it_in_order() {
        // Runs with rapids between them, taken at once: each rapid waits behind the
        // run before it; a flush (as before a probing move) hands out all of it in
        // the program's order, as nc-send merges it.
        let s = Settings::default();
        let mut blocks = chords(900);
        for k in [300, 600] {
            blocks[k].motion = Motion::Rapid;
        }
        let mut m = Merger::new(Some(s), [0; AXES]);
        let mut out = Vec::new();
        m.take(blocks.clone(), &mut out);
        assert!(m.closing && !m.behind.is_empty());
        m.flush(&mut out);
        assert!(m.is_empty());
        assert_eq!(out, compress::compress(&blocks, [0; AXES], &s).blocks);
    }

    #[test]
    fn without_settings_every_block_goes_at_once() {
        let mut m = Merger::new(None, [0; AXES]);
        let mut out = Vec::new();
        m.take(chords(3), &mut out);
        assert_eq!(out, chords(3));
    }

    #[test]
    fn held_moves_go_when_the_controller_runs_low_or_the_most_are_held() {
        let mut m = Merger::new(Some(Settings::default()), [0; AXES]);
        let mut out = Vec::new();
        m.take(chords(10), &mut out);
        m.send_due((10, false, 0), true, &mut out);
        assert!(out.is_empty() && !m.is_empty());
        // At rest with nothing queued, the sender still sending: held for more.
        m.send_due((0, true, 0), true, &mut out);
        assert!(out.is_empty() && !m.is_empty());
        // Few blocks but much motion in them: held (an open merge, moving, hands out
        // nothing of so short a run).
        m.send_due((LOW_QUEUE, false, LOW_MS), true, &mut out);
        m.collect(true, &mut out);
        assert!(out.is_empty() && !m.is_empty());
        // About to run out: a closed merge, on its thread; then the blender's block.
        let low = (LOW_QUEUE, false, LOW_MS - 1);
        m.send_due(low, true, &mut out);
        assert!(m.under_way.is_some());
        m.collect(true, &mut out);
        m.send_due(low, true, &mut out);
        assert!(!out.is_empty() && m.is_empty());
        assert_eq!(out.last().map(|b| b.target), Some(chords(10)[9].target));
        // A long run is merged at MOST_HELD moves, but for the curves that could
        // depend on what follows: the moves after the last curve handed out stay
        // held, and what goes is what the whole program gives.
        let s = Settings::default();
        let mut m = Merger::new(Some(s), [0; AXES]);
        let mut out = Vec::new();
        let blocks = chords(MOST_HELD + 5);
        m.take(blocks.clone(), &mut out);
        // The merge runs on another thread: the moves to come are taken meanwhile.
        assert!(m.under_way.is_some() && !m.is_empty());
        m.collect(true, &mut out);
        // What it merged went to the blender, which keeps the last curve for the
        // corner after it.
        assert!(m.done > 0);
        let rest = m.held.len() - m.done;
        assert!(rest > 0 && rest <= 2 * s.max_chords + 1, "{rest} held");
        assert!(!m.is_empty());
        m.flush(&mut out);
        assert!(m.is_empty());
        assert_eq!(out, compress::compress(&blocks, [0; AXES], &s).blocks);
    }

    #[test]
    fn merges_that_go_on_open_runs_give_the_curves_of_the_whole_program() {
        // An unevenly sampled profile over several runs (a rapid between them), taken
        // line by line and merged open after every 23 lines: each merge hands out only
        // curves whose fit the lines still to come cannot change, so the blocks are
        // those of the whole program however it is cut. With cartesian-xyz's figures
        // (1000 mm/s², 100 mm/s an axis) some junctions between its curves turn
        // (`compress::meet`, 16 of them), and some merges go on from a curve whose end
        // turned (3 of them; without fitting the next curve from that end, the blocks
        // differ from the whole program's).
        let s = Settings {
            accel: 1e9,
            max_speed: 1e8,
            bend_accel: 1e9 * 3f64.sqrt() * 2.0 / 3.0,
            ..Settings::default()
        };
        let mut blocks = uneven_chords(3000);
        blocks[1700].motion = Motion::Rapid;
        let mut m = Merger::new(Some(s), [0; AXES]);
        let mut out = Vec::new();
        let mut sent = vec![];
        for (k, b) in blocks.iter().enumerate() {
            m.take(vec![*b], &mut out);
            if k % 23 == 22 {
                let before = out.len();
                m.start_merge(true);
                m.settle(true, &mut out);
                sent.push(out.len() - before);
            }
        }
        m.flush(&mut out);
        let whole = compress::compress(&blocks[..1700], [0; AXES], &s);
        let rest = compress::compress(&blocks[1701..], blocks[1700].target, &s);
        let mut want = whole.blocks.clone();
        want.push(blocks[1700]);
        want.extend(rest.blocks);
        assert!(sent.iter().filter(|&&n| n > 0).count() >= 5, "{sent:?}");
        assert_eq!(out, want);
    }

    #[test]
    fn a_corner_between_two_merges_is_blended_as_in_the_whole_program() {
        // A zigzag of 5 mm lines at right angles, P0.01: no run to merge, a blend at
        // every corner. MOST_HELD cuts it into merges; every corner, those between
        // merges too, is blended as nc-send blends the whole program.
        let n = MOST_HELD * 2 + 40;
        let blocks: Vec<Block> = (1..=n)
            .map(|i| {
                let (x, y) = (i as i64 * 5_000_000, if i % 2 == 1 { 5_000_000 } else { 0 });
                g1(x, y, i as u32)
            })
            .collect();
        let s = Settings::default();
        let whole = compress::compress(&blocks, [0; AXES], &s);
        let mut m = Merger::new(Some(s), [0; AXES]);
        let mut out = Vec::new();
        for b in &blocks {
            m.take(vec![*b], &mut out);
        }
        m.flush(&mut out);
        let cubics = |v: &[Block]| {
            v.iter()
                .filter(|b| matches!(b.motion, Motion::Cubic { .. }))
                .count()
        };
        assert_eq!(cubics(&whole.blocks), n - 1, "a blend at every corner");
        assert_eq!(out, whole.blocks);
    }
}
