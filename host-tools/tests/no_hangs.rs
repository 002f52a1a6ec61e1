//! Dry runs (`--check`) and simulations (`--sim`) always end: programs that once made
//! them spin forever (a pause just before the program end, an axis the machine lacks),
//! a dwell the stall guard must not mistake for a stall, and the stall guard itself on
//! motion the controller cannot make. Every run has a time limit, so a regression fails
//! instead of hanging the suite.

use pkmc::config::MachineConfig;
use pkmc::motion::block::{Block, Motion};
use pkmc::wire::Control;
use pkmc_host::job::{self, exit, RunOptions, SimSetup, Target};
use pkmc_host::link::{JobEnd, Link, LinkError, LinkOptions, NoHooks};
use pkmc_host::sim::serve::InProcess;
use pkmc_host::sim::Simulator;
use std::process::Output;
use std::sync::mpsc;
use std::time::Duration;

mod common;
use common::{nc_send_within, ok, tmp};

/// Longest a run here may take (the dwell test simulates 30 s; on a busy machine
/// `--sim` runs a few times faster than real time).
const LIMIT: Duration = Duration::from_secs(60);

/// Writes `text` as program `name` in the scratch folder; returns its path.
fn program(name: &str, text: &str) -> String {
    let path = tmp(name);
    std::fs::write(&path, text).unwrap();
    path.display().to_string()
}

/// Runs `program` with `mode` (`--check` or `--sim`) and `extra` options, JSON report.
fn run(mode: &str, program: &str, extra: &[&str]) -> Output {
    let mut args = vec![mode, "--report", "json"];
    args.extend_from_slice(extra);
    args.push(program);
    nc_send_within(LIMIT, &args)
}

/// Both modes finish with every block executed; returns the reports.
fn finishes_in_both_modes(name: &str, text: &str) -> Vec<serde_json::Value> {
    let path = program(name, text);
    ["--check", "--sim"]
        .iter()
        .map(|mode| {
            let r = ok(&run(mode, &path, &[]));
            assert_eq!(r["result"], "done", "{mode} {name}");
            assert_eq!(r["final_state"], "Idle", "{mode} {name}");
            assert_eq!(r["blocks_executed"], r["blocks_sent"], "{mode} {name}");
            r
        })
        .collect()
}

#[test]
fn a_program_ending_in_m1_then_m2_finishes() {
    for r in finishes_in_both_modes("m1-m2.ngc", "G0 X1\nM1\nM2\n") {
        assert_eq!(r["final_pose"]["x"], 1.0);
    }
}

#[test]
fn a_program_ending_in_m0_then_m30_finishes() {
    finishes_in_both_modes("m0-m30.ngc", "G0 X1 Y2\nM0\nM30\n");
}

#[test]
fn a_program_whose_last_line_is_m0_finishes() {
    finishes_in_both_modes("m0-last.ngc", "G0 X1\nM0\n");
}

#[test]
fn a_pause_in_the_middle_still_resumes_by_itself_with_no_operator() {
    let path = program("m0-middle.ngc", "G0 X1\nM0\nG0 X2\nM1\nG0 X3\nM2\n");
    for mode in ["--check", "--sim"] {
        let out = nc_send_within(LIMIT, &[mode, &path]);
        assert_eq!(out.status.code(), Some(0), "{mode}");
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(
            stderr.contains("at line 2: resumed automatically")
                && stderr.contains("at line 4: resumed automatically"),
            "{mode}: {stderr}"
        );
        let stdout = String::from_utf8_lossy(&out.stdout);
        assert!(stdout.contains("5 of 5 blocks"), "{mode}: {stdout}");
        assert!(stdout.contains("final pose X 3.0000"), "{mode}: {stdout}");
    }
}

#[test]
fn an_axis_the_machine_lacks_is_refused_at_its_line_and_column() {
    let path = program("rotary.ngc", "G0 X1\nG1 X2 Y1 A4 F100\nM2\n");
    let name = std::path::Path::new(&path)
        .file_name()
        .unwrap()
        .to_string_lossy()
        .into_owned();
    for mode in ["--check", "--sim"] {
        let out = run(mode, &path, &[]);
        assert_eq!(out.status.code(), Some(exit::BAD_INPUT), "{mode}");
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(
            stderr.contains(&format!(
                "{name}:2:10: A4: the machine has no A axis (its axes: X Y Z)"
            )),
            "{mode}: {stderr}"
        );
        assert!(stderr.contains("nothing was sent"), "{mode}: {stderr}");
        // The report says what failed (nothing ran).
        let report = common::json(&out);
        assert_eq!(report["result"], "error", "{mode}: {report}");
        assert_eq!(report["exit_code"], exit::BAD_INPUT, "{mode}: {report}");
    }
    // The H-4 has A (its table) and C (its head) but no B.
    let h4 = program("tilted.ngc", "G0 A10 C5\nG0 B3\nM2\n");
    let out = run(
        "--check",
        &h4,
        &["--machine", "examples/machines/h4-table.toml"],
    );
    assert_eq!(out.status.code(), Some(exit::BAD_INPUT));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains(":2:4: B3: the machine has no B axis (its axes: X Y Z A C)"),
        "{stderr}"
    );
}

#[test]
fn a_long_dwell_is_not_taken_for_a_stall() {
    let reports = finishes_in_both_modes("dwell.ngc", "G0 X1\nG4 P30\nG0 X2\nM2\n");
    for r in reports {
        let t = r["run_time_s"].as_f64().unwrap();
        assert!(t > 30.0, "the dwell ran its 30 s: {t}");
    }
}

/// Runs `f` in a thread; fails the test if it has not returned within [`LIMIT`].
fn within<R: Send + 'static>(f: impl FnOnce() -> R + Send + 'static) -> R {
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(f());
    });
    rx.recv_timeout(LIMIT)
        .expect("still running after the time limit (hangs)")
}

/// A move of X on line 1, then one of A, which the Cartesian X Y Z machine has no
/// speed for, on line 2 (the compiler refuses such a program: these blocks are made
/// by hand).
fn blocks_moving_a_missing_axis() -> Vec<Block> {
    let block = |line, target| Block {
        line,
        motion: Motion::Rapid,
        target,
        feed: 0,
        tolerance_nm: 0,
    };
    vec![
        block(1, [1_000_000, 0, 0, 0, 0, 0]),
        block(2, [1_000_000, 0, 0, 4_000_000_000, 0, 0]),
    ]
}

#[test]
fn a_dry_run_that_makes_no_progress_stops_as_stalled_at_its_line() {
    let err = within(|| {
        let machine = MachineConfig::cartesian_xyz();
        let sim = Simulator::new(machine.clone()).unwrap();
        let io = InProcess::new(sim, Box::new(|_| {}));
        let mut link = Link::connect(io, &machine, LinkOptions::default()).unwrap();
        link.control(Control::AlarmReset).unwrap();
        link.run_job(&blocks_moving_a_missing_axis(), &mut NoHooks)
            .map(|end| format!("{end:?}"))
            .map_err(|e| e.to_string())
    });
    let message = err.expect_err("the job cannot finish");
    assert!(message.contains("stalled at line 2"), "{message}");
}

#[test]
fn a_simulation_that_makes_no_progress_exits_as_stalled_at_its_line() {
    let failure = within(|| {
        let machine = MachineConfig::cartesian_xyz();
        let opts = RunOptions {
            target: Target::Sim,
            sim: SimSetup::default(),
            link: LinkOptions::default(),
            home: false,
            tools: Default::default(),
            statics: None,
            compress: None,
        };
        let blocks = blocks_moving_a_missing_axis();
        job::run_blocks(&machine, "stall", &blocks, &opts, &mut NoHooks)
            .map(|r| r.report.result)
            .map_err(|f| (f.code, f.message))
    });
    let (code, message) = failure.expect_err("the job cannot finish");
    assert_eq!(code, exit::STALLED, "{message}");
    assert_eq!(exit::STALLED, exit::ALARM, "documented as the alarm code");
    assert!(message.contains("stalled at line 2"), "{message}");
    assert!(message.contains("simulated time"), "{message}");
}

#[test]
fn a_simulated_jog_that_cannot_move_stops_as_stalled() {
    let failure = within(|| {
        let machine = MachineConfig::cartesian_xyz();
        let opts = RunOptions {
            target: Target::Sim,
            sim: SimSetup::default(),
            link: LinkOptions::default(),
            home: false,
            tools: Default::default(),
            statics: None,
            compress: None,
        };
        job::with_link(&machine, &opts, |link| {
            link.control(Control::AlarmReset)?;
            // Planned as the core plans any jog, without nc-send's own refusal of an
            // axis the machine lacks: the controller is given a move it cannot make.
            let kin = pkmc::kinematics::MachineKinematics::new(&machine);
            let from = link.request_status()?.pose;
            let planned = pkmc::motion::planner::plan_jog(
                &machine,
                &kin,
                &from,
                3,
                5_000_000_000,
                1_000_000_000,
            )
            .expect("a well-formed jog");
            job::move_and_wait(link, Control::Jog(planned), &mut NoHooks)
        })
        .map(|end| end == JobEnd::Done)
        .map_err(|f| (f.code, f.message))
    });
    let (code, message) = failure.expect_err("the jog cannot finish");
    assert_eq!(code, exit::STALLED, "{message}");
    assert!(message.contains("stalled: "), "{message}");
}

#[test]
fn the_stall_error_names_its_line_and_the_simulated_time() {
    let e = LinkError::Stalled {
        port: "in-process simulator".into(),
        line: 12,
        state: pkmc::wire::State::Running,
        still: Duration::from_millis(10_500),
    };
    assert_eq!(
        e.to_string(),
        "in-process simulator: stalled at line 12: the controller has been Running for \
         10.5 s of simulated time with no block ending and nothing moving; run stopped"
    );
}
