//! Real senders that nobody on this project wrote, against `nc-send --sim grbl`:
//! CNCjs (npm) on the pseudo-terminal through its own server API, and grbl-streamer
//! (PyPI) over TCP. The drivers are `tests/senders/` (see its README); `.ci/run`
//! installs both senders. Without them these tests say so and pass only outside CI.

mod common;
mod grbl;

use grbl::Bridge;
use std::path::PathBuf;
use std::process::Command;

fn senders() -> PathBuf {
    common::repo().join("tests/senders")
}

/// Is the sender there? Where it is missing the build script marks its tests ignored
/// (host-tools/build.rs), so a test that runs and finds none fails.
fn have(what: &str, ok: bool) -> bool {
    assert!(
        ok,
        "{what} is not installed: run `npm ci` in tests/senders and \
         `pip install -r tests/senders/requirements.txt` (as .ci/run does)"
    );
    ok
}

fn have_cncjs() -> bool {
    have(
        "CNCjs",
        senders().join("node_modules/cncjs/package.json").exists(),
    )
}

fn have_grbl_streamer() -> bool {
    let ok = Command::new("python3")
        .args(["-c", "import grbl_streamer"])
        .status()
        .is_ok_and(|s| s.success());
    have("grbl-streamer", ok)
}

/// Runs a driver; returns its JSON.
fn driver(program: &str, args: &[&str]) -> serde_json::Value {
    let out = Command::new(program)
        .args(args)
        .current_dir(senders())
        .output()
        .expect("the driver runs");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{program} {args:?} failed: {}\n{text}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_str(text.trim()).unwrap_or_else(|e| panic!("{e}: {text}"))
}

/// CNCjs runs `program` on the bridge's pseudo-terminal; `more`: the driver's options.
fn cncjs(bridge: &Bridge, program: &str, more: &[&str]) -> serde_json::Value {
    let mut args = vec!["cncjs_job.js", "--port", &bridge.pty, "--program", program];
    args.extend_from_slice(more);
    driver("node", &args)
}

/// grbl-streamer runs `program` over the bridge's TCP port; `more`: the driver's options.
fn streamer(bridge: &Bridge, program: &str, more: &[&str]) -> serde_json::Value {
    let url = format!("socket://{}", bridge.tcp);
    let mut args = vec!["grbl_streamer_job.py", "--port", &url, "--program", program];
    args.extend_from_slice(more);
    driver("python3", &args)
}

/// `nc-send --sim` of the same program: the reference.
fn reference(machine: &[&str], program: &str) -> serde_json::Value {
    let mut args = vec!["--sim", "--report", "json"];
    args.extend_from_slice(machine);
    args.push(program);
    common::ok(&common::nc_send(&args))
}

fn assert_same_end(summary: &serde_json::Value, reference: &serde_json::Value) {
    let status = &summary["status"];
    for axis in ["x", "y", "z", "a", "b", "c"] {
        let (got, want) = (
            status["pose"][axis].as_f64().unwrap(),
            reference["final_pose"][axis].as_f64().unwrap(),
        );
        assert!(
            (got - want).abs() < 1e-6,
            "{axis}: {got} vs nc-send --sim {want}"
        );
    }
    let got: Vec<f64> = serde_json::from_value(status["joints"].clone()).unwrap();
    let want: Vec<f64> = serde_json::from_value(reference["final_joints"].clone()).unwrap();
    assert_eq!(got.len(), want.len());
    for (j, (g, w)) in got.iter().zip(&want).enumerate() {
        assert!(
            (g - w).abs() < 1e-6,
            "joint {}: {g} vs nc-send --sim {w}",
            j + 1
        );
    }
}

fn states(job: &serde_json::Value) -> Vec<String> {
    job["state_timeline"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e["state"].as_str().unwrap().to_string())
        .collect()
}

#[test]
#[cfg_attr(
    pkmc_no_cncjs,
    ignore = "needs CNCjs: npm ci in tests/senders (as .ci/run does)"
)]
fn cncjs_runs_the_h4_program_on_the_pseudo_terminal_and_ends_where_nc_send_does() {
    if !have_cncjs() {
        return;
    }
    let machine = ["--machine", "examples/machines/h4-table.toml"];
    let program = common::repo().join("examples/h4-table-tilt.ngc");
    let program = program.to_str().unwrap();
    let bridge = Bridge::start(&machine);
    let job = cncjs(&bridge, program, &["--timeout", "120"]);
    let summary = bridge.stop();
    assert_eq!(job["result"], "completed", "{job}");
    assert_eq!(job["errors"].as_array().unwrap().len(), 0, "{job}");
    assert_eq!(job["lines_sent"], job["lines_received"], "{job}");
    assert_eq!(summary["errors"], 0, "{summary}");
    assert_eq!(
        summary["blocks_executed"], summary["blocks_fed"],
        "{summary}"
    );
    assert_same_end(&summary, &reference(&machine, program));
}

#[test]
#[cfg_attr(
    pkmc_no_cncjs,
    ignore = "needs CNCjs: npm ci in tests/senders (as .ci/run does)"
)]
fn cncjs_hold_resume_and_feed_override_act_on_the_path() {
    if !have_cncjs() {
        return;
    }
    // 80 mm at 600 mm/min: 8 s at 100 %.
    let program = common::tmp("cncjs_long_move.ngc");
    std::fs::write(&program, "G21 G90\nG1 X80 F600\nG1 X0\n").unwrap();
    let program = program.to_str().unwrap();
    let bridge = Bridge::start(&[]);
    let held = cncjs(
        &bridge,
        program,
        &["--hold-at", "2", "--resume-at", "5", "--timeout", "60"],
    );
    assert_eq!(held["result"], "completed", "{held}");
    assert!(
        states(&held).iter().any(|s| s.starts_with("Hold")),
        "{held}"
    );
    let t_held = held["elapsed_s"].as_f64().unwrap();
    // Feed override 200 % from the second second: 2 s + 14 s / 2 ≈ 9 s instead of 16 s.
    let fast = cncjs(
        &bridge,
        program,
        &["--feed-override-at", "2:200", "--timeout", "60"],
    );
    let summary = bridge.stop();
    assert_eq!(fast["result"], "completed", "{fast}");
    let t_fast = fast["elapsed_s"].as_f64().unwrap();
    assert_eq!(fast["last_status"]["ov"][0], 200, "{fast}");
    assert!(
        t_held > 16.0 + 2.5,
        "a 3 s hold makes the 16 s job longer: {t_held} s"
    );
    assert!(
        t_fast < 12.0,
        "200 % from t = 2 s: {t_fast} s, 16 s without"
    );
    assert_eq!(summary["status"]["pose"]["x"], 0.0, "{summary}");
}

#[test]
#[cfg_attr(
    pkmc_no_grbl_streamer,
    ignore = "needs grbl-streamer: pip install -r tests/senders/requirements.txt"
)]
fn grbl_streamer_streams_a_thousand_lines_over_tcp_through_a_faulty_line_losing_nothing() {
    if !have_grbl_streamer() {
        return;
    }
    let program = common::tmp("spiral_1000.ngc");
    let mut text = String::from("G21 G90 G64 P0.01\nG0 X0 Y0 Z0\nF1500\n");
    for i in 1..998 {
        let (a, r) = (i as f64 * 0.05, 5.0 + 0.02 * i as f64);
        text += &format!("G1 X{:.3} Y{:.3}\n", r * a.cos(), r * a.sin());
    }
    std::fs::write(&program, text).unwrap();
    let program = program.to_str().unwrap();
    // grbl-streamer comments out a line with a command Grbl lacks (its `tidy`), so the
    // first line, `G64 P0.01` with it, never reaches the bridge, which then runs in
    // the default `G64`. With `--g64-tolerance 0` nothing is merged or blended there,
    // and every line written is one block, as this test counts them.
    let bridge = Bridge::start(&[
        "--link-faults",
        "0.001",
        "--seed",
        "5",
        "--g64-tolerance",
        "0",
    ]);
    let job = streamer(&bridge, program, &["--timeout", "150"]);
    let summary = bridge.stop();
    assert_eq!(job["result"], "completed", "{job}");
    assert_eq!(job["errors"].as_array().unwrap().len(), 0, "{job}");
    assert_eq!(summary["errors"], 0, "{summary}");
    // 1 000 lines: 997 moves and a rapid are blocks. Every motion line the sender
    // wrote became one block, executed once. (grbl-streamer 2.0.2 itself wrote a line
    // twice and skipped one now and then, a race between its reader thread and
    // `job_run` that the driver closes with a lock: tests/senders/grbl_streamer_job.py.)
    let written = job["motion_lines_written"].as_u64().unwrap();
    assert_eq!(written, 998, "{job}");
    assert_eq!(summary["blocks_fed"], written, "{summary}");
    assert_eq!(summary["blocks_executed"], written, "{summary}");
    assert_eq!(summary["link"]["blocks_sent"], written, "{summary}");
    assert!(
        summary["link"]["resent"].as_u64().unwrap() > 0,
        "the faults bit: {summary}"
    );
    assert_same_end(&summary, &reference(&[], program));
}

#[test]
#[cfg_attr(
    pkmc_no_grbl_streamer,
    ignore = "needs grbl-streamer: pip install -r tests/senders/requirements.txt"
)]
fn grbl_streamer_hold_and_resume_over_tcp_stop_and_restart_the_machine() {
    if !have_grbl_streamer() {
        return;
    }
    let program = common::tmp("streamer_long_move.ngc");
    std::fs::write(&program, "G21 G90\nG1 X40 F600\nG1 X0\n").unwrap();
    let program = program.to_str().unwrap();
    let bridge = Bridge::start(&[]);
    let job = streamer(
        &bridge,
        program,
        &["--hold-at", "1.5", "--resume-at", "4", "--timeout", "60"],
    );
    let summary = bridge.stop();
    assert_eq!(job["result"], "completed", "{job}");
    assert!(states(&job).iter().any(|s| s.starts_with("Hold")), "{job}");
    assert!(
        job["elapsed_s"].as_f64().unwrap_or(0.0) > 8.0 + 2.0,
        "{job}"
    );
    assert_eq!(summary["status"]["pose"]["x"], 0.0, "{summary}");
}

/// grbl-streamer streams a program with a G38.2 onto the simulator's plane: the
/// bridge holds the G38.2's `ok` until the probe has run, grbl-streamer reads the
/// `[PRB:…:1]` before it (its `on_probe`, with the machine position of the contact)
/// and the program goes on from there. (grbl-streamer's preprocessor substitutes
/// `#` parameters itself, so the program does not read #5063: that is the bridge's
/// own test, `grbl_probing`.)
#[test]
#[cfg_attr(
    pkmc_no_grbl_streamer,
    ignore = "needs grbl-streamer: pip install -r tests/senders/requirements.txt"
)]
fn grbl_streamer_runs_a_probing_program_and_reads_the_prb_report() {
    if !have_grbl_streamer() {
        return;
    }
    let program = common::tmp("streamer_probe.ngc");
    std::fs::write(
        &program,
        "G21 G90\nG0 X2 Y1\nG38.2 Z-10 F150\nG91 G0 Z2\nG90 G0 X0 Y0\n",
    )
    .unwrap();
    let program = program.to_str().unwrap();
    let bridge = Bridge::start(&["--probe-plane", "-2.5"]);
    let job = streamer(&bridge, program, &["--timeout", "60"]);
    let summary = bridge.stop();
    assert_eq!(job["result"], "completed", "{job}");
    assert_eq!(job["errors"].as_array().unwrap().len(), 0, "{job}");
    // `$#` at the start says PRB too (zeros); the job's is after t = 0.
    let probes: Vec<&serde_json::Value> = job["probes"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|p| p["t"].as_f64().unwrap() > 0.0)
        .collect();
    assert_eq!(probes.len(), 1, "{job}");
    let at: Vec<f64> = probes[0]["at"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert_eq!(&at[..2], &[2.0, 1.0], "{job}");
    assert!((at[2] + 2.5).abs() <= 0.003, "the plane at -2.5: {job}");
    let end = &summary["status"]["pose"];
    assert_eq!(
        (end["x"].as_f64(), end["y"].as_f64()),
        (Some(0.0), Some(0.0))
    );
    let z = end["z"].as_f64().unwrap();
    // 2 mm up from where the probe stopped, a little past the contact.
    assert!(
        z > at[2] + 1.8 && z < at[2] + 2.0,
        "Z after the probe: {summary}"
    );
}
