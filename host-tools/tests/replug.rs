//! Issue 33: a replugged port resumes the job. `pkmc-sim --real-time --link PATH`
//! serves through a symbolic link; SIGUSR1 closes its pseudo-terminal and removes the
//! link for `--replug-secs` (2 s) while the machine runs on, then serves a new one at
//! the same path. `nc-send --port PATH`, in the middle of a job, waits for the port,
//! reconnects, takes its own job over and finishes it exactly, with no operator.

mod common;

use common::{json, repo, tmp};
use std::io::BufRead;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

#[test]
fn a_port_closed_for_two_seconds_mid_job_is_waited_for_and_the_job_completes_exactly() {
    replugged_mid_job("replug", &[]);
}

/// The same with the program fed a piece at a time (as a file over 16 MiB is:
/// `PKMC_STREAM_ABOVE_BYTES` lowers the threshold): the job carries the program's
/// mark, and after the replug its pieces are fed again from the first block the
/// controller never received.
#[test]
fn a_program_fed_a_piece_at_a_time_is_taken_up_again_after_a_replug() {
    replugged_mid_job("replug-pieces", &[("PKMC_STREAM_ABOVE_BYTES", "1")]);
}

/// The program run by `nc-send --port` (with `env`) and the port closed for 2 s in
/// the middle of it: the job ends where `--sim` ends it.
fn replugged_mid_job(name: &str, env: &[(&str, &str)]) {
    let p = common::ten_second_program(&format!("{name}.ngc"));
    let p = p.to_str().unwrap();
    let reference = common::ok(&common::nc_send(&["--sim", "--report", "json", p]));
    let link = tmp(&format!("{name}-port"));
    let _ = std::fs::remove_file(&link);
    let mut sim = Command::new(env!("CARGO_BIN_EXE_pkmc-sim"))
        .args(["--real-time", "--replug-secs", "2", "--link"])
        .arg(&link)
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let mut first = String::new();
    std::io::BufReader::new(sim.stdout.take().unwrap())
        .read_line(&mut first)
        .unwrap();
    let port = first.trim().to_string();
    assert_eq!(port, link.to_str().unwrap());
    let send = |args: &[&str]| {
        let mut all = vec!["--port", port.as_str(), "--report", "json"];
        all.extend_from_slice(args);
        common::nc_send_within(Duration::from_secs(90), &all)
    };
    assert_eq!(send(&["reset"]).status.code(), Some(0));
    let host = Command::new(env!("CARGO_BIN_EXE_nc-send"))
        .args(["--port", port.as_str(), p])
        .envs(env.iter().copied())
        .current_dir(repo())
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_millis(1500));
    let unplugged = Instant::now();
    unsafe { libc::kill(sim.id() as i32, libc::SIGUSR1) };
    std::thread::sleep(Duration::from_millis(300));
    assert!(!link.exists(), "the port is gone while unplugged");
    let out = host.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(0), "{err}");
    assert!(unplugged.elapsed() >= Duration::from_secs(2), "{err}");
    assert!(
        err.contains("the port went away") && err.contains("the port is back"),
        "{err}"
    );
    let s = json(&send(&["status"]));
    let _ = sim.kill();
    let _ = sim.wait();
    assert_eq!(
        (s["state"].clone(), s["line"].clone()),
        ("Idle".into(), reference["final_line"].clone()),
        "{s}"
    );
    assert!(s["alarm"].is_null() && s["held_job"].is_null(), "{s}");
    assert_eq!(s["pose"], reference["final_pose"], "{s}");
    assert_eq!(s["joints"], reference["final_joints"], "{s}");
}
