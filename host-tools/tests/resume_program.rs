//! Issue 33: a job is never cut short silently. A program pause (M6 here) with nobody
//! at a terminal leaves the job held on the controller with the program's mark (its
//! hash, how far it was received); `nc-send resume PROGRAM`, from another process,
//! sends the rest and runs it to the program's end; `resume` without the program says
//! how much was never sent and resumes nothing; another program is refused.
//! Over the real pseudo-terminal path: `pkmc-sim`, then `nc-send --port`.

mod common;

use common::{json, repo, tmp, Sim};
use std::path::PathBuf;
use std::process::{Command, Output, Stdio};
use std::time::Duration;

/// No command may take longer than this here.
const BOUND: Duration = Duration::from_secs(120);

/// LinuxCNC's 3D_Chips (a tool change, M6, at line 18 of 4 711), from the shared
/// corpus; `None` (the test says so and passes) when the corpus is absent.
fn chips() -> Option<PathBuf> {
    // The corpus beside the repository (as `corpus_check`), or PKMC_CORPUS.
    let dir = std::env::var_os("PKMC_CORPUS")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/corpus"));
    let p = dir.join("linuxcnc/3D_Chips.ngc");
    if p.is_file() {
        return Some(p);
    }
    eprintln!(
        "SKIPPED: LinuxCNC's 3D_Chips.ngc is absent ({} not found; PKMC_CORPUS names the \
         corpus directory)",
        p.display()
    );
    None
}

/// `nc-send --port PORT --report json ARGS` with `env` set and stdin not a terminal
/// (nobody can press resume), killed (and the test failed) past BOUND.
fn send_with(sim: &Sim, args: &[&str], env: &[(&str, &str)]) -> Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_nc-send"))
        .args(["--port", sim.port.as_str(), "--report", "json"])
        .args(args)
        .envs(env.iter().copied())
        .current_dir(repo())
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("nc-send runs");
    let start = std::time::Instant::now();
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > BOUND {
            let _ = child.kill();
            panic!("nc-send {args:?} still running after {BOUND:?}");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    child.wait_with_output().unwrap()
}

fn err(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

#[test]
fn a_tool_change_with_no_terminal_keeps_the_programs_place_and_resume_program_ends_it() {
    paused_and_resumed(&[]);
}

/// The same with the program compiled and fed a piece at a time (as a file over
/// 16 MiB is: `PKMC_STREAM_ABOVE_BYTES` lowers the threshold): the job carries the
/// program's mark from the first pass, and `resume PROGRAM` checks it and feeds the
/// pieces from the first block the controller never received.
#[test]
fn a_program_fed_a_piece_at_a_time_keeps_its_place_and_resume_program_ends_it() {
    paused_and_resumed(&[("PKMC_STREAM_ABOVE_BYTES", "1")]);
}

/// 3D_Chips streamed with no terminal (`env` set for every nc-send), paused at its
/// M6, then resumed: without the program, with another, and with the program.
fn paused_and_resumed(env: &[(&str, &str)]) {
    let Some(chips) = chips() else { return };
    let chips = chips.to_str().unwrap();
    let send = |sim: &Sim, args: &[&str]| send_with(sim, args, env);
    // The reference: the whole program on `--sim` (its pause resumes by itself).
    let reference = common::ok(&common::nc_send(&["--sim", "--report", "json", chips]));
    let sim = Sim::start(&[]);
    assert_eq!(send(&sim, &["reset"]).status.code(), Some(0));
    let out = send(&sim, &[chips]);
    assert_eq!(out.status.code(), Some(7), "{}", err(&out));
    let r = json(&out);
    assert_eq!(r["result"], "paused", "{r}");
    let total = r["blocks_sent"].as_u64().unwrap();
    let sent = r["link"]["blocks_sent"].as_u64().unwrap();
    assert!(sent < total, "the pause comes before the end is sent: {r}");
    // Without the program: says what was never sent, resumes nothing, not `done`.
    let out = send(&sim, &["resume"]);
    let e = err(&out);
    assert_eq!(out.status.code(), Some(7), "{e}");
    assert!(
        e.contains(&format!(
            "{} of the program's {total} blocks were never sent",
            total - sent
        )),
        "{e}"
    );
    // Where the sent part ends depends on how many blocks the controller's queue
    // took while it waited at the M6 (line 18): the lines missing are the rest.
    let have: u32 = e
        .split("it has the program up to line ")
        .nth(1)
        .and_then(|t| t.split(',').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no last line sent: {e}"));
    assert!(have >= 18, "{e}");
    assert!(
        e.contains(&format!(
            "lines {}..4711 ({} lines) are missing",
            have + 1,
            4711 - have
        )),
        "{e}"
    );
    assert_eq!(json(&out)["result"], "error");
    // Another program (one line changed) is refused by its hash; nothing is sent.
    let text = std::fs::read_to_string(chips).unwrap();
    let other = tmp("3D_Chips-changed.ngc");
    std::fs::write(&other, text.replacen("*-27.725]", "*-27.726]", 1)).unwrap();
    let out = send(&sim, &["resume", other.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(2), "{}", err(&out));
    assert!(
        err(&out).contains("not the held job's program"),
        "{}",
        err(&out)
    );
    // The program: the rest is sent and the job ends at the program's last line,
    // where `--sim` ends.
    let out = send(&sim, &["resume", chips]);
    assert_eq!(out.status.code(), Some(0), "{}", err(&out));
    let end = json(&out);
    assert_eq!(
        (
            end["result"].clone(),
            end["state"].clone(),
            end["line"].clone()
        ),
        ("done".into(), "Idle".into(), 4705.into()),
        "{end}"
    );
    assert_eq!(end["blocks_sent"].as_u64(), Some(total - sent), "{end}");
    assert_eq!(end["pose"], reference["final_pose"], "{end}");
    assert_eq!(end["joints"], reference["final_joints"], "{end}");
    assert!(end["alarm"].is_null(), "{end}");
}

/// `--from LINE` (LinuxCNC's run-from-line): 3D_Chips restarted at line 2400, in the
/// middle of its cut, on `--sim` ends where the whole program ends (pose, joints and
/// drive steps); its pre-flight covers only the restart; a line past the end and line
/// 0 are refused by name.
#[test]
fn a_restart_from_a_middle_line_ends_where_the_whole_program_does() {
    restarted_in_the_middle(&[]);
}

/// The same with the program compiled and fed a piece at a time (as a file over
/// 16 MiB is: `PKMC_STREAM_ABOVE_BYTES` lowers the threshold): the pieces are read up
/// to the restart, and the job is the approach, then the pieces from there on.
#[test]
fn a_restart_of_a_program_fed_a_piece_at_a_time_ends_where_the_whole_program_does() {
    restarted_in_the_middle(&[("PKMC_STREAM_ABOVE_BYTES", "1")]);
}

/// 3D_Chips restarted at line 2400 with `env` set for nc-send.
fn restarted_in_the_middle(env: &[(&str, &str)]) {
    let Some(chips) = chips() else { return };
    let chips = chips.to_str().unwrap();
    let nc_send = |args: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_nc-send"))
            .args(args)
            .envs(env.iter().copied())
            .current_dir(repo())
            .output()
            .expect("nc-send runs")
    };
    let whole = common::ok(&nc_send(&["--sim", "--report", "json", chips]));
    let from = common::ok(&nc_send(&[
        "--sim", "--report", "json", "--from", "2400", chips,
    ]));
    for key in [
        "result",
        "final_state",
        "final_pose",
        "final_joints",
        "final_joint_steps",
    ] {
        assert_eq!(from[key], whole[key], "{key}: {from}");
    }
    let (n, all) = (
        from["blocks_sent"].as_u64().unwrap(),
        whole["blocks_sent"].as_u64().unwrap(),
    );
    assert!(
        n < all / 2 + 20,
        "the restart sends the rest only: {n} of {all}"
    );
    let t = from["run_time_s"].as_f64().unwrap();
    assert!(t < whole["run_time_s"].as_f64().unwrap() * 0.6, "{t}");
    // The dry run's pre-flight starts at the restart.
    let check = |extra: &[&str]| {
        let mut a = vec!["--check", "--report", "json"];
        a.extend_from_slice(extra);
        a.push(chips);
        common::ok(&nc_send(&a))["preflight"]["samples"]
            .as_u64()
            .unwrap()
    };
    assert!(check(&["--from", "2400"]) < check(&[]));
    for (line, says) in [
        ("99999", "no block at or after line 99999"),
        ("0", "lines count from 1"),
    ] {
        let out = nc_send(&["--sim", "--from", line, chips]);
        assert_eq!(out.status.code(), Some(2));
        assert!(String::from_utf8_lossy(&out.stderr).contains(says));
    }
}
