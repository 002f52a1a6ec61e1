//! Issue 33: a streamed job's host going silent starves the job (it stops on the path
//! at the end of its queue and goes on when blocks come) and, after the job's host
//! timeout, holds it for take-over; never drops it. Jogs and MDI keep the short watch.

use super::*;
use crate::motion::block::{Block, Motion};
use crate::wire::{AlarmCause, Control, CtrlMsg, HostMsg, PROTOCOL_VERSION};

use super::tests::{frame, replies};

/// A line along X from `from_mm` to `x_mm` at `feed_mm_s` on the Cartesian machine,
/// planned by the host (alone: from rest to rest).
fn line(from_mm: i64, x_mm: i64, feed_mm_s: i64, line: u32) -> HostMsg {
    let m = MachineConfig::cartesian_xyz();
    let b = Block {
        line,
        motion: Motion::Linear,
        target: [x_mm * 1_000_000, 0, 0, 0, 0, 0],
        feed: feed_mm_s * 1_000_000,
        tolerance_nm: u32::MAX,
    };
    let kin = MachineKinematics::new(&m);
    let mut out = [crate::motion::planner::PlanBlock::default()];
    let start = [from_mm * 1_000_000, 0, 0, 0, 0, 0];
    crate::motion::planner::plan_into(&[b], start, &m, &kin, 1, &mut out).unwrap();
    HostMsg::Block(crate::motion::block::PlannedBlock {
        block: b,
        plan: out[0].plan(),
    })
}

fn hello(c: &Controller, host: u32) -> HostMsg {
    HostMsg::Hello {
        version: PROTOCOL_VERSION,
        machine: c.machine_id(),
        host,
    }
}

fn control(c: &mut Controller, id: u16, cmd: Control) {
    c.receive(&frame(0, &HostMsg::Control { id, cmd }));
}

/// A session of host 1 that begins a streamed job with a host timeout of `ms`.
fn streaming(ms: u32) -> Controller {
    let mut c = Controller::new(MachineConfig::cartesian_xyz()).unwrap();
    c.unlock();
    c.receive(&frame(0, &hello(&c, 1)));
    control(
        &mut c,
        1,
        Control::BeginJob {
            host_timeout_ms: ms,
            mark: JobMark::default(),
        },
    );
    c
}

fn silent(c: &mut Controller, ticks: u32) {
    for _ in 0..ticks {
        c.tick(&Inputs::default());
    }
}

#[test]
fn a_silent_host_starves_a_streamed_job_on_the_path_and_blocks_continue_it_at_once() {
    let mut c = streaming(30_000);
    c.receive(&frame(1, &line(0, 10, 50, 7)));
    // 10 mm at 50 mm/s: well under a second; then five seconds of silence.
    silent(&mut c, 5_000);
    assert_eq!(c.state(), State::Starved);
    assert_eq!(c.status().alarm, None, "starvation is no alarm");
    assert_eq!(c.pose()[0], 10_000_000, "stopped at the end of the queue");
    assert_eq!(c.status().speed, 0);
    assert!(c.has_work(), "the host-timeout watch runs");
    // Blocks come: it runs on at once.
    c.receive(&frame(2, &line(10, 20, 50, 8)));
    c.tick(&Inputs::default());
    assert_eq!(c.state(), State::Running);
    silent(&mut c, 2_000);
    assert_eq!((c.state(), c.pose()[0]), (State::Starved, 20_000_000));
    // The host says the job is complete: idle, and the next job is short-watched
    // unless it says otherwise.
    control(&mut c, 2, Control::EndJob);
    assert_eq!(c.state(), State::Idle);
    assert_eq!(c.silence_limit(), LINK_LOSS_TICKS);
}

#[test]
fn a_host_silent_past_its_host_timeout_leaves_the_job_held_for_take_over() {
    let mut c = streaming(3_000);
    c.receive(&frame(1, &line(0, 10, 50, 7)));
    silent(&mut c, 2_990);
    assert_eq!(c.state(), State::Starved);
    silent(&mut c, 20);
    assert_eq!(c.state(), State::Hold);
    let alarm = c.status().alarm.expect("the hold says why");
    assert_eq!((alarm.cause, alarm.line), (AlarmCause::HostTimeout, 7));
    assert!(!c.has_work(), "held at rest: nothing to time");
    // A new host is told of the held job; blocks of its own are refused.
    c.receive(&frame(0, &hello(&c, 2)));
    let held = replies(&mut c)
        .into_iter()
        .find_map(|m| match m {
            CtrlMsg::HelloAck { held, .. } => held,
            _ => None,
        })
        .expect("HelloAck names the held job");
    assert_eq!((held.host, held.state, held.line), (1, State::Hold, 7));
    assert!(c.status().orphan);
    // It resumes it: the job is the new host's, complete with what was queued.
    control(&mut c, 5, Control::Resume);
    assert_eq!(c.state(), State::Idle);
    assert_eq!(c.status().alarm, None);
    assert!(!c.status().orphan);
}

#[test]
fn the_same_host_back_from_its_silence_resumes_its_held_job_and_streams_on() {
    let mut c = streaming(3_000);
    c.receive(&frame(1, &line(0, 10, 50, 7)));
    silent(&mut c, 3_500);
    assert_eq!(c.state(), State::Hold);
    // Blocks sent while held are queued, not run.
    c.receive(&frame(2, &line(10, 20, 50, 8)));
    silent(&mut c, 100);
    assert_eq!((c.state(), c.pose()[0]), (State::Hold, 10_000_000));
    control(&mut c, 5, Control::Resume);
    assert_eq!(c.state(), State::Running);
    silent(&mut c, 2_000);
    assert_eq!((c.state(), c.pose()[0]), (State::Starved, 20_000_000));
    assert_eq!(c.status().alarm, None);
}

#[test]
fn a_running_job_whose_host_is_silent_past_its_host_timeout_stops_on_the_path() {
    let mut c = streaming(2_000);
    // 100 mm at 10 mm/s: ten seconds queued.
    c.receive(&frame(1, &line(0, 100, 10, 3)));
    silent(&mut c, 1_500);
    assert_eq!(c.state(), State::Running, "no link loss for a streamed job");
    silent(&mut c, 500);
    assert_eq!(c.state(), State::Hold);
    assert_eq!(
        c.status().alarm.map(|a| a.cause),
        Some(AlarmCause::HostTimeout)
    );
    silent(&mut c, 1_000);
    assert_eq!(c.status().speed, 0);
    let x = c.pose()[0];
    assert!(x > 15_000_000 && x < 25_000_000, "stopped on the path: {x}");
    // Queue kept: a resume (this host back) finishes the move.
    control(&mut c, 5, Control::Resume);
    for _ in 0..120 {
        // The host's heartbeat.
        c.receive(&frame(0, &HostMsg::StatusRequest));
        silent(&mut c, 100);
    }
    assert_eq!((c.state(), c.pose()[0]), (State::Starved, 100_000_000));
}

#[test]
fn a_job_without_a_host_timeout_keeps_the_short_watch() {
    let mut c = streaming(0);
    c.receive(&frame(1, &line(0, 80, 50, 4)));
    silent(&mut c, LINK_LOSS_TICKS);
    assert_eq!(
        c.status().alarm.map(|a| a.cause),
        Some(AlarmCause::LinkLoss)
    );
    assert_eq!(c.state(), State::Alarm);
}

#[test]
fn a_host_timeout_is_clamped_into_its_range() {
    let mut c = streaming(1);
    assert_eq!(c.patience_ticks(), MIN_HOST_TIMEOUT_MS);
    control(
        &mut c,
        2,
        Control::BeginJob {
            host_timeout_ms: u32::MAX,
            mark: JobMark::default(),
        },
    );
    assert_eq!(c.patience_ticks(), MAX_HOST_TIMEOUT_MS);
}

#[test]
fn an_abort_of_a_starved_job_ends_it_where_it_stands() {
    let mut c = streaming(30_000);
    c.receive(&frame(1, &line(0, 10, 50, 7)));
    silent(&mut c, 1_500);
    assert_eq!(c.state(), State::Starved);
    control(&mut c, 5, Control::Abort);
    silent(&mut c, 2);
    assert_eq!((c.state(), c.pose()[0]), (State::Idle, 10_000_000));
    assert_eq!(c.silence_limit(), LINK_LOSS_TICKS);
}

/// Issue 33: a held job keeps its program's mark (hash, next block never received);
/// a new host that sends the rest of the same program adopts the job and streams on,
/// one with another program or another block index leaves it held.
#[test]
fn a_held_job_reports_how_far_its_program_came_and_its_rest_continues_it() {
    let mut c = Controller::new(MachineConfig::cartesian_xyz()).unwrap();
    c.unlock();
    c.receive(&frame(0, &hello(&c, 1)));
    let mark = JobMark {
        program: 0xfeed,
        next_block: 0,
        total_blocks: 3,
        last_line: 0,
        total_lines: 9,
    };
    let begin = |mark| Control::BeginJob {
        host_timeout_ms: 2_000,
        mark,
    };
    control(&mut c, 1, begin(mark));
    c.receive(&frame(1, &line(0, 10, 50, 4)));
    c.receive(&frame(2, &line(10, 20, 50, 6)));
    silent(&mut c, 3_000);
    assert_eq!((c.state(), c.pose()[0]), (State::Hold, 20_000_000));
    c.receive(&frame(0, &hello(&c, 2)));
    let got = replies(&mut c)
        .into_iter()
        .find_map(|m| match m {
            CtrlMsg::HelloAck { mark, .. } => mark,
            _ => None,
        })
        .expect("HelloAck carries the held job's mark");
    let expect = JobMark {
        next_block: 2,
        last_line: 6,
        ..mark
    };
    assert_eq!(got, expect);
    // Another program, or a block index that skips or repeats: still held.
    for (i, wrong) in [
        JobMark {
            program: 0xbeef,
            ..expect
        },
        JobMark {
            next_block: 1,
            ..expect
        },
        JobMark::default(),
    ]
    .into_iter()
    .enumerate()
    {
        control(&mut c, 10 + i as u16, begin(wrong));
        assert!(c.status().orphan, "{wrong:?}");
    }
    // The rest of the same program: adopted; its block runs after the resume.
    control(&mut c, 20, begin(expect));
    assert!(!c.status().orphan);
    c.receive(&frame(1, &line(20, 30, 50, 9)));
    control(&mut c, 21, Control::Resume);
    // Within the host timeout (2 s): starved at the end of the new block.
    silent(&mut c, 1_000);
    assert_eq!((c.state(), c.pose()[0]), (State::Starved, 30_000_000));
    control(&mut c, 22, Control::EndJob);
    assert_eq!(c.state(), State::Idle);
}
