//! The client's protocol rules, against the real controller core running in this
//! process on the simulated clock ([`InProcess`]): credits in milliseconds, refusals
//! that no resend can cure, and control commands during a job.

use pkmc::config::MachineConfig;
use pkmc::motion::block::{Block, Motion, Plane};
use pkmc::wire::{Control, Status};
use pkmc_host::link::{JobEnd, JobHooks, Link, LinkError, LinkOptions, LinkView, NoHooks};
use pkmc_host::sim::serve::InProcess;
use pkmc_host::sim::Simulator;

fn machine() -> MachineConfig {
    pkmc_host::machine_file::parse(pkmc_host::machine_file::DEFAULT_MACHINE, "built-in machine")
        .unwrap()
}

fn link(opts: LinkOptions) -> Link<InProcess> {
    let m = machine();
    let mut sim = Simulator::new(m.clone()).unwrap();
    sim.ctrl.unlock();
    Link::connect(InProcess::new(sim, Box::new(|_| {})), &m, opts).unwrap()
}

fn line_to(x_mm: f64, y_mm: f64, line: u32, feed_mm_s: i64) -> Block {
    Block {
        line,
        motion: Motion::Linear,
        target: [(x_mm * 1e6) as i64, (y_mm * 1e6) as i64, 0, 0, 0, 0],
        feed: feed_mm_s * 1_000_000,
        tolerance_nm: u32::MAX,
    }
}

/// Records every status.
#[derive(Default)]
struct Statuses(Vec<Status>);

impl JobHooks for Statuses {
    fn status(&mut self, s: &Status) {
        self.0.push(s.clone());
    }
}

#[test]
fn the_client_keeps_no_more_motion_buffered_than_the_limit_allows() {
    let mut l = link(LinkOptions {
        max_buffered_ms: 300,
        ..LinkOptions::default()
    });
    // Twenty moves of 10 mm at 10 mm/s: one second each.
    let blocks: Vec<Block> = (0..20)
        .map(|i| line_to(if i % 2 == 0 { 10.0 } else { 0.0 }, 5.0, i + 1, 10))
        .collect();
    let mut seen = Statuses::default();
    assert_eq!(l.run_job(&blocks, &mut seen).unwrap(), JobEnd::Done);
    let capacity = l.capacity();
    let most_queued = seen
        .0
        .iter()
        .map(|s| capacity - s.free_slots)
        .max()
        .unwrap();
    // A block goes out only while less than 300 ms is buffered: with one-second
    // blocks, the one executing and at most one behind it.
    assert!(most_queued <= 2, "{most_queued} blocks queued");
    let most_buffered = seen.0.iter().map(|s| s.buffered_ms).max().unwrap();
    assert!(most_buffered <= 300 + 2000, "{most_buffered} ms buffered");
    assert_eq!(seen.0.last().unwrap().blocks_done, 20);
}

#[test]
fn without_the_millisecond_limit_the_queue_fills_to_its_slots() {
    let mut l = link(LinkOptions {
        max_buffered_ms: u32::MAX,
        ..LinkOptions::default()
    });
    // More blocks than the queue holds.
    let n = 2 * pkmc::controller::QUEUE_CAPACITY as u32;
    let blocks: Vec<Block> = (0..n)
        .map(|i| line_to(if i % 2 == 0 { 10.0 } else { 0.0 }, 5.0, i + 1, 50))
        .collect();
    let mut seen = Statuses::default();
    assert_eq!(l.run_job(&blocks, &mut seen).unwrap(), JobEnd::Done);
    let least_free = seen.0.iter().map(|s| s.free_slots).min().unwrap();
    assert_eq!(least_free, 0, "credits in slots are used to the last one");
}

#[test]
fn a_malformed_block_ends_the_job_naming_its_line() {
    let mut l = link(LinkOptions::default());
    let bad_arc = Block {
        line: 7,
        motion: Motion::Arc {
            center: [5_000_000, 0],
            plane: Plane::Xy,
            clockwise: false,
            turns: 0,
        },
        // The start (home) and this end are not on one circle about the centre.
        target: [40_000_000, 1_000_000, 0, 0, 0, 0],
        feed: 10_000_000,
        tolerance_nm: u32::MAX,
    };
    let blocks = vec![line_to(1.0, 0.0, 6, 10), bad_arc];
    match l.run_job(&blocks, &mut NoHooks) {
        Err(e @ LinkError::BadBlock { line: 7, .. }) => {
            assert!(e.to_string().contains("line 7"), "{e}");
        }
        other => panic!("expected BadBlock on line 7, got {other:?}"),
    }
}

/// Sends one control command once the job is under way.
struct OneControl {
    cmd: Option<Control>,
    after_acked: usize,
}

impl JobHooks for OneControl {
    fn control(&mut self, view: &LinkView) -> Option<Control> {
        if view.acked >= self.after_acked {
            self.cmd.take()
        } else {
            None
        }
    }
}

#[test]
fn an_abort_during_a_job_stops_streaming_and_ends_it_at_rest() {
    let mut l = link(LinkOptions::default());
    let blocks: Vec<Block> = (0..200)
        .map(|i| line_to(if i % 2 == 0 { 10.0 } else { 0.0 }, 5.0, i + 1, 20))
        .collect();
    let mut hooks = OneControl {
        cmd: Some(Control::Abort),
        after_acked: 10,
    };
    assert_eq!(l.run_job(&blocks, &mut hooks).unwrap(), JobEnd::Aborted);
    let s = l.request_status().unwrap();
    assert_eq!(s.state, pkmc::wire::State::Idle);
    assert_eq!(s.free_slots, l.capacity(), "the queue was dropped");
    assert!((s.blocks_done as usize) < blocks.len());
    assert!(
        l.stats.blocks_sent < blocks.len() as u64,
        "streaming stopped"
    );
}

#[test]
fn an_immediate_stop_ends_the_job_in_alarm() {
    let mut l = link(LinkOptions::default());
    let blocks: Vec<Block> = (0..100)
        .map(|i| line_to(if i % 2 == 0 { 10.0 } else { 0.0 }, 5.0, i + 1, 20))
        .collect();
    let mut hooks = OneControl {
        cmd: Some(Control::Stop),
        after_acked: 5,
    };
    assert_eq!(l.run_job(&blocks, &mut hooks).unwrap(), JobEnd::Stopped);
    let s = l.request_status().unwrap();
    assert_eq!(s.state, pkmc::wire::State::Alarm);
    // A new job on a controller in alarm ends at once, reporting it.
    assert!(matches!(
        l.run_job(&blocks[..1], &mut NoHooks).unwrap(),
        JobEnd::Alarm(_)
    ));
    l.control(Control::AlarmReset).unwrap();
    assert_eq!(l.run_job(&blocks[..2], &mut NoHooks).unwrap(), JobEnd::Done);
}
