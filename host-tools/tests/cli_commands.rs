//! `nc-send`'s commands and options, run as a user would: against `pkmc-sim` on its
//! pseudo-terminal (the controller keeps its state between commands) or with `--sim`
//! and `--check`, checked from outside (exit code, JSON on stdout, files written).

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

mod common;
use common::{json, nc_send, ok, repo, tmp, Sim};

#[test]
fn status_jog_home_mdi_and_reset_act_on_a_running_controller() {
    let sim = Sim::start(&[]);
    // After its reset the controller is locked: it does not know where the machine is.
    let out = sim.send(&["status"]);
    let s = json(&out);
    assert_eq!(s["state"], "Alarm");
    assert_eq!(s["alarm"], "not homed");
    let out = sim.send(&["jog", "X", "5"]);
    assert_eq!(
        out.status.code(),
        Some(5),
        "a locked controller does not jog"
    );
    // Homing finds the switches and ends at the home pose.
    let h = ok(&sim.send(&["home"]));
    assert_eq!(h["state"], "Idle");
    let home_x = h["pose"]["x"].as_f64().unwrap();
    assert_eq!(home_x, 0.0);

    let j = ok(&sim.send(&["jog", "X", "5", "--feed", "1200"]));
    assert_eq!(j["result"], "done");
    assert_eq!(j["pose"]["x"].as_f64().unwrap(), home_x + 5.0);
    let j = ok(&sim.send(&["jog", "y", "-2.5"]));
    assert_eq!(j["state"], "Idle");
    let after_jogs = j["pose"].clone();

    let s = ok(&sim.send(&["status"]));
    assert_eq!(
        s["pose"], after_jogs,
        "the controller keeps its pose between sessions"
    );

    let m = ok(&sim.send(&["mdi", "G1 X10 Y12 F600"]));
    assert_eq!(m["result"], "done");
    assert_eq!(m["blocks_sent"], 1);
    assert_eq!(m["pose"]["x"], 10.0);
    assert_eq!(m["pose"]["y"], 12.0);
    // MDI starts from where the machine stands: a relative move adds to it.
    let m = ok(&sim.send(&["mdi", "G91 G1 X-1 F600"]));
    assert_eq!(m["pose"]["x"], 9.0);

    let h = ok(&sim.send(&["home"]));
    assert_eq!(h["pose"]["x"].as_f64().unwrap(), home_x);

    let r = ok(&sim.send(&["reset"]));
    assert_eq!(r["state"], "Idle");
    assert_eq!(r["alarm"], serde_json::Value::Null);
}

#[test]
fn a_bad_mdi_line_or_axis_is_refused_before_anything_moves() {
    let sim = Sim::start(&[]);
    let out = sim.send(&["mdi", "G1 X10"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("MDI:1:"));
    let out = sim.send(&["jog", "Q", "1"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("unknown axis"));
}

#[test]
fn commands_also_run_on_the_built_in_simulator() {
    let out = nc_send(&["--sim", "--report", "json", "status"]);
    assert_eq!(
        json(&out)["alarm"],
        "not homed",
        "a fresh controller is locked"
    );
    // A move on the simulator unlocks it where it stands first.
    let j = ok(&nc_send(&["--sim", "--report", "json", "jog", "Z", "1"]));
    assert_eq!(j["result"], "done");
}

#[test]
fn check_plans_the_job_without_a_port_and_agrees_with_the_simulator() {
    let sim = ok(&nc_send(&[
        "--sim",
        "--report",
        "json",
        "examples/square.ngc",
    ]));
    let check = ok(&nc_send(&[
        "--check",
        "--report",
        "json",
        "examples/square.ngc",
    ]));
    assert_eq!(check["result"], "done");
    assert_eq!(check["blocks_executed"], sim["blocks_executed"]);
    assert_eq!(check["final_joint_steps"], sim["final_joint_steps"]);
    // The simulator's clock runs free while the host reacts in real time, so its
    // motion time can differ a little from the planned one (a late block means a
    // different blend); the check itself is deterministic.
    let (planned, ran) = (
        check["run_time_s"].as_f64().unwrap(),
        sim["run_time_s"].as_f64().unwrap(),
    );
    assert!(planned > 1.0);
    assert!(
        (planned - ran).abs() < 0.03 * planned,
        "{planned} s vs {ran} s"
    );
    // Deterministic, and traced like a simulator run: one row per planned period.
    let trace = tmp("check.csv");
    let again = ok(&nc_send(&[
        "--check",
        "--report",
        "json",
        "--trace",
        trace.to_str().unwrap(),
        "examples/square.ngc",
    ]));
    assert_eq!(again["run_time_s"], check["run_time_s"]);
    let csv = std::fs::read_to_string(&trace).unwrap();
    assert!(csv.starts_with("t_s,line,x,y,z,a,b,c,q1,q2,q3,fb1,fb2,fb3,tq1,tq2,tq3\n"));
    let rows = csv.lines().count() - 1;
    assert!((rows as f64 - planned * 1000.0).abs() < 2.0, "{rows} rows");
    // Without --report, a readable summary says it was only checked.
    let out = nc_send(&["--check", "examples/square.ngc"]);
    assert_eq!(out.status.code(), Some(0));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("done (checked)"), "{text}");
    assert!(text.contains("planned"), "{text}");
}

#[test]
fn check_reports_a_program_error_with_its_line() {
    let prog = tmp("far.ngc");
    std::fs::write(&prog, "G0 X10\nG0 Z500\n").unwrap();
    let out = nc_send(&["--check", prog.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(3));
    assert!(String::from_utf8_lossy(&out.stderr).contains("far.ngc:2:"));
}

#[test]
fn a_stretch_out_of_travel_is_reported_once_with_its_first_and_last_line() {
    let prog = tmp("stretch.ngc");
    // Line 1 inside, lines 2-51 end beyond X's travel (100 mm), line 52 comes back
    // from there (it starts outside too).
    let mut text = String::from("G1 X10 F600\n");
    for i in 0..50 {
        text.push_str(&format!("G1 X{}\n", 110 + i));
    }
    text.push_str("G1 X20\n");
    std::fs::write(&prog, text).unwrap();
    // The same merged into one curve (`--g64-tolerance`): named at the moves, not at
    // the curve's first line; and from a restart.
    for extra in [
        &[][..],
        &["--g64-tolerance", "0.001"],
        &["--g64-tolerance", "0.001", "--from", "1"],
    ] {
        let mut args = vec!["--check"];
        args.extend_from_slice(extra);
        args.push(prog.to_str().unwrap());
        let out = nc_send(&args);
        assert_eq!(out.status.code(), Some(3), "{extra:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains("stretch.ngc:2: joint q1 would leave its travel"),
            "{extra:?}: {err}"
        );
        assert!(
            err.contains("stretch.ngc:52 (51 lines)"),
            "{extra:?}: {err}"
        );
        assert!(err.contains("51 pre-flight problem(s)"), "{extra:?}: {err}");
        assert!(err.lines().count() < 6, "one line for the stretch: {err}");
    }
}

#[test]
fn plots_are_written_as_svg_and_png() {
    let svg = tmp("square.svg");
    let png = tmp("square.png");
    ok(&nc_send(&[
        "--sim",
        "--report",
        "json",
        "--plot",
        svg.to_str().unwrap(),
        "examples/square.ngc",
    ]));
    let text = std::fs::read_to_string(&svg).unwrap();
    assert!(text.starts_with("<svg"), "{}", &text[..100.min(text.len())]);
    for title in [
        "top (XY)",
        "front (XZ)",
        "side (YZ)",
        "path speed",
        "joints",
    ] {
        assert!(text.contains(title), "no {title} in the SVG");
    }
    ok(&nc_send(&[
        "--check",
        "--report",
        "json",
        "--plot",
        png.to_str().unwrap(),
        "examples/square.ngc",
    ]));
    let bytes = std::fs::read(&png).unwrap();
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n");
    assert!(
        bytes.len() > 10_000,
        "a real picture, {} bytes",
        bytes.len()
    );
}

#[test]
fn a_plot_needs_a_simulated_run_and_a_known_format() {
    let out = nc_send(&[
        "--port",
        "/dev/null",
        "--plot",
        "x.svg",
        "examples/square.ngc",
    ]);
    assert_eq!(out.status.code(), Some(2));
    let out = nc_send(&["--sim", "--plot", "x.jpg", "examples/square.ngc"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains(".svg or .png"));
}

#[test]
fn without_port_or_sim_the_board_is_looked_for_on_usb() {
    // No board is attached to a test machine.
    let out = nc_send(&["examples/square.ngc"]);
    assert_eq!(out.status.code(), Some(3));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("no pkmc controller found"), "{err}");
    assert!(err.contains("1209:0001"), "{err}");
}

#[test]
fn a_port_that_does_not_exist_is_a_link_failure_naming_it() {
    let out = nc_send(&["--port", "/dev/pkmc-nowhere", "examples/square.ngc"]);
    assert_eq!(out.status.code(), Some(4));
    assert!(String::from_utf8_lossy(&out.stderr).contains("/dev/pkmc-nowhere: cannot open"));
}

#[test]
fn nc_send_runs_a_job_through_pkmc_sim_on_a_faulty_line() {
    let sim = Sim::start(&["--link-faults", "0.01", "--seed", "5"]);
    let r = ok(&sim.send(&["--home", "examples/square.ngc"]));
    assert_eq!(r["result"], "done");
    assert_eq!(r["final_pose"]["x"], 12.5);
    assert_eq!(r["blocks_executed"], r["blocks_sent"]);
}

/// A job that moves slowly enough (simulated time) to be interrupted.
fn slow_program() -> PathBuf {
    let prog = tmp("slow.ngc");
    std::fs::write(&prog, "G1 X100 F0.5\nG1 X0\n").unwrap();
    prog
}

/// Waits until `child` catches SIGINT (its handler is installed), as Linux reports
/// in `/proc/PID/status`, so that the test's signal is not the default, fatal one.
fn wait_for_handler(child: &Child) {
    let path = format!("/proc/{}/status", child.id());
    for _ in 0..1000 {
        let caught = std::fs::read_to_string(&path)
            .ok()
            .and_then(|s| {
                s.lines()
                    .find_map(|l| l.strip_prefix("SigCgt:"))
                    .and_then(|m| u64::from_str_radix(m.trim(), 16).ok())
            })
            .unwrap_or(0);
        if caught & (1 << (libc::SIGINT - 1)) != 0 {
            return;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    panic!("nc-send never installed its Ctrl-C handler");
}

fn interrupt_after(child: &Child, delay: Duration) {
    wait_for_handler(child);
    std::thread::sleep(delay);
    // SAFETY: sends SIGINT to our own child process.
    unsafe {
        libc::kill(child.id() as libc::pid_t, libc::SIGINT);
    }
}

fn spawn_job(prog: &Path) -> Child {
    Command::new(env!("CARGO_BIN_EXE_nc-send"))
        .args(["--sim", "--report", "json", prog.to_str().unwrap()])
        .current_dir(repo())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

#[test]
fn ctrl_c_holds_then_aborts_the_job() {
    let child = spawn_job(&slow_program());
    interrupt_after(&child, Duration::from_millis(700));
    let out = child.wait_with_output().unwrap();
    assert_eq!(
        out.status.code(),
        Some(6),
        "stderr: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let r = json(&out);
    assert_eq!(r["result"], "aborted");
    assert_eq!(r["final_state"], "Idle");
    let x = r["final_pose"]["x"].as_f64().unwrap();
    assert!((0.0..100.0).contains(&x), "stopped on the way, at X {x}");
    assert!(r["blocks_executed"].as_u64().unwrap() < 2);
}

#[test]
fn ctrl_c_stops_a_jog_under_control() {
    let child = Command::new(env!("CARGO_BIN_EXE_nc-send"))
        .args([
            "--sim", "--report", "json", "jog", "X", "50", "--feed", "0.5",
        ])
        .current_dir(repo())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    interrupt_after(&child, Duration::from_millis(300));
    let out = child.wait_with_output().unwrap();
    assert_eq!(
        out.status.code(),
        Some(6),
        "stderr: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let r = json(&out);
    assert_eq!(r["result"], "aborted");
    assert_eq!(r["state"], "Idle");
    assert!(r["pose"]["x"].as_f64().unwrap() < 50.0);
}

#[test]
fn a_second_ctrl_c_stops_at_once() {
    let child = spawn_job(&slow_program());
    interrupt_after(&child, Duration::from_millis(700));
    interrupt_after(&child, Duration::from_millis(1));
    let out = child.wait_with_output().unwrap();
    let r = json(&out);
    assert_eq!(out.status.code(), Some(6));
    // Either the hold had already brought it to rest and the abort ended the job, or
    // the immediate stop did (the controller is then in alarm).
    let result = r["result"].as_str().unwrap();
    assert!(result == "stopped" || result == "aborted", "{r}");
    if result == "stopped" {
        assert_eq!(r["final_state"], "Alarm");
    }
}

/// Issue 17: every wait is interruptible. Against a port where nothing answers, with a
/// link timeout of an hour, three Ctrl-C end `nc-send` at once (exit 6).
#[test]
fn three_ctrl_c_end_any_wait_at_once() {
    let (_master, slave) = serialport::TTYPort::pair().unwrap();
    let port = serialport::SerialPort::name(&slave).unwrap();
    let child = Command::new(env!("CARGO_BIN_EXE_nc-send"))
        .args(["--port", &port, "--link-timeout", "3600", "status"])
        .current_dir(repo())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    wait_for_handler(&child);
    let start = std::time::Instant::now();
    for _ in 0..3 {
        // SAFETY: sends SIGINT to our own child process.
        unsafe {
            libc::kill(child.id() as libc::pid_t, libc::SIGINT);
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let out = child.wait_with_output().unwrap();
    assert!(
        start.elapsed() < Duration::from_secs(2),
        "{:?}",
        start.elapsed()
    );
    assert_eq!(out.status.code(), Some(6));
    assert!(String::from_utf8_lossy(&out.stderr).contains("Ctrl-C three times"));
}
