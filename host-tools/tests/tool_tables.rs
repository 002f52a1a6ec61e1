//! Tool tables as a user gives them to `nc-send`: `--tools FILE` in LinuxCNC's
//! tool-file form, or `[[tools]]` in the machine file; G43 takes its length from
//! there, and a mistake names its file and line.

mod common;
use common::{json, nc_send, ok, repo, tmp};

const PROGRAM: &str = "G21 G90\nT1 M6 G43\nG0 X10 Y0 Z-20\nM2\n";

fn final_z(out: &std::process::Output) -> f64 {
    ok(out)["final_pose"]["z"].as_f64().unwrap()
}

#[test]
fn a_tool_file_given_with_tools_sets_the_length_g43_applies() {
    let program = tmp("tools-g43.ngc");
    std::fs::write(&program, PROGRAM).unwrap();
    let table = tmp("tools-g43.tbl");
    std::fs::write(&table, "T1 P1 Z12.5 D6 ;end mill\n").unwrap();
    let (p, t) = (program.to_str().unwrap(), table.to_str().unwrap());
    let with = nc_send(&["--check", "--report", "json", "--tools", t, p]);
    assert_eq!(final_z(&with), -7.5, "Z-20 with a 12.5 mm tool");
    // Without a table, tool 1 is unknown: an error at its line, nothing runs.
    let without = nc_send(&["--check", "--report", "json", p]);
    assert_eq!(without.status.code(), Some(2));
    let err = String::from_utf8_lossy(&without.stderr);
    assert!(
        err.contains(":2:") && err.contains("not in the tool table"),
        "{err}"
    );
}

#[test]
fn a_machine_files_tools_are_used_and_a_tool_file_replaces_them() {
    let base =
        std::fs::read_to_string(repo().join("examples/machines/cartesian-xyz.toml")).unwrap();
    let machine = tmp("tools-machine.toml");
    std::fs::write(
        &machine,
        format!("{base}\n[[tools]]\nnumber = 1\nlength = 5\ndiameter = 3\n"),
    )
    .unwrap();
    let program = tmp("tools-machine.ngc");
    std::fs::write(&program, PROGRAM).unwrap();
    let (m, p) = (machine.to_str().unwrap(), program.to_str().unwrap());
    let r = nc_send(&["--check", "--report", "json", "--machine", m, p]);
    assert_eq!(final_z(&r), -15.0, "the machine file's 5 mm tool");
    let table = tmp("tools-machine.tbl");
    std::fs::write(&table, "T1 P1 Z2\n").unwrap();
    let t = table.to_str().unwrap();
    let r = nc_send(&[
        "--check",
        "--report",
        "json",
        "--machine",
        m,
        "--tools",
        t,
        p,
    ]);
    assert_eq!(
        final_z(&r),
        -18.0,
        "--tools replaces the machine file's table"
    );
}

#[test]
fn a_bad_tool_file_or_tool_entry_is_refused_where_it_is() {
    let program = tmp("tools-bad.ngc");
    std::fs::write(&program, PROGRAM).unwrap();
    let table = tmp("tools-bad.tbl");
    std::fs::write(&table, "T1 P1 Z12.5\nT2 P2 Zfoo\n").unwrap();
    let (p, t) = (program.to_str().unwrap(), table.to_str().unwrap());
    let out = nc_send(&["--check", "--report", "json", "--tools", t, p]);
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("tools-bad.tbl:2:"), "{err}");
    assert_eq!(json(&out)["result"], "error");
    let base =
        std::fs::read_to_string(repo().join("examples/machines/cartesian-xyz.toml")).unwrap();
    let machine = tmp("tools-bad.toml");
    std::fs::write(
        &machine,
        format!("{base}\n[[tools]]\nnumber = 1\ndiameter = -1\n"),
    )
    .unwrap();
    let m = machine.to_str().unwrap();
    let out = nc_send(&["--check", "--report", "json", "--machine", m, p]);
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("tools[0].diameter: must not be negative"),
        "{err}"
    );
}
