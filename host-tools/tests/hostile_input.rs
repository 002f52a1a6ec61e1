//! Issue 17: `nc-send` and `pkmc-sim` under hostile input, run as a user would; each
//! case exits with a clear message within a bound (never hangs, never panics, never
//! accepts silently).

mod common;

use common::nc_send_within;
use std::process::Command;
use std::time::Duration;

const LIMIT: Duration = Duration::from_secs(30);

/// Runs nc-send; returns (exit code, stderr).
fn nc(args: &[&str]) -> (Option<i32>, String) {
    let out = nc_send_within(LIMIT, args);
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn an_endless_device_as_program_or_machine_file_is_refused_at_its_first_byte() {
    for args in [
        vec!["--check", "/dev/zero"],
        vec!["--sim", "/dev/zero"],
        vec!["--check", "--machine", "/dev/zero", "examples/square.ngc"],
    ] {
        let (code, err) = nc(&args);
        assert_eq!(code, Some(2), "{args:?}: {err}");
        assert!(err.contains("/dev/zero:1:1: NUL byte"), "{args:?}: {err}");
    }
    let out = Command::new(env!("CARGO_BIN_EXE_pkmc-sim"))
        .args(["--machine", "/dev/zero"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("/dev/zero:1:1: NUL byte"));
}

#[test]
fn a_dry_run_that_homes_first_finishes() {
    let out = nc_send_within(
        LIMIT,
        &[
            "--check",
            "--home",
            "--report",
            "json",
            "examples/square.ngc",
        ],
    );
    let r = common::ok(&out);
    assert_eq!(r["result"], "done", "{r}");
}

#[test]
fn options_that_could_never_work_are_refused_by_name() {
    for (args, want) in [
        (
            vec!["--sim", "--max-buffered-ms", "0", "examples/square.ngc"],
            "--max-buffered-ms 0",
        ),
        (
            vec!["--check", "--link-timeout", "inf", "examples/square.ngc"],
            "--link-timeout inf",
        ),
        (
            vec!["--check", "--link-timeout", "1e30", "examples/square.ngc"],
            "--link-timeout",
        ),
        (
            vec!["--check", "--link-faults", "0.01", "examples/square.ngc"],
            "--link-faults needs --sim",
        ),
        (vec!["--sim", "jog", "X", "NaN"], "distance NaN"),
        (
            vec!["--sim", "jog", "X", "1", "--feed", "inf"],
            "--feed inf",
        ),
    ] {
        let (code, err) = nc(&args);
        assert_eq!(code, Some(2), "{args:?}: {err}");
        assert!(err.contains(want), "{args:?}: {err}");
    }
}

#[test]
fn a_report_is_printed_on_every_exit() {
    let out = nc_send_within(
        LIMIT,
        &["--port", "/dev/null/none", "--report", "json", "status"],
    );
    assert_eq!(out.status.code(), Some(4));
    let r = common::json(&out);
    assert_eq!(r["result"], "error", "{r}");
    assert_eq!(r["exit_code"], 4, "{r}");
    assert!(
        r["error"].as_str().unwrap().contains("/dev/null/none"),
        "{r}"
    );
}
