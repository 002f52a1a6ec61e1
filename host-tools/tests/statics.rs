//! Statics as a user asks for it: `nc-send --check --wrench` (or `--wrench-file`) on
//! the hexapod reports each leg's largest force with its NC line; a machine file that
//! gives the legs a force limit (directly, or as cylinder area × supply pressure)
//! refuses a program that would exceed it, naming the line, before anything runs.
//! The forces themselves are checked against an independent computation from the
//! legs' geometry in `analysis::statics`'s unit tests.

mod common;
use common::{nc_send, ok, repo, tmp};

const PROGRAM: &str = "G21 G90 G94 F600\nG1 X20 Y10 Z450\nG1 X-20 Z440 A3\nM2\n";

fn hexapod_with(extra_top: &str, per_joint: &str, name: &str) -> String {
    let base = std::fs::read_to_string(repo().join("examples/machines/hexapod.toml")).unwrap();
    let text = format!(
        "{extra_top}\n{}",
        base.replace("[[joints]]\n", &format!("[[joints]]\n{per_joint}"))
    );
    let path = tmp(name);
    std::fs::write(&path, text).unwrap();
    path.to_str().unwrap().to_string()
}

fn program(name: &str) -> String {
    let p = tmp(name);
    std::fs::write(&p, PROGRAM).unwrap();
    p.to_str().unwrap().to_string()
}

#[test]
fn a_cutting_load_reports_each_legs_largest_force_with_its_line() {
    let m = repo().join("examples/machines/hexapod.toml");
    let p = program("statics-report.ngc");
    let out = nc_send(&[
        "--check",
        "--report",
        "json",
        "--machine",
        m.to_str().unwrap(),
        "--wrench",
        "0,0,-1000",
        &p,
    ]);
    let r = ok(&out);
    let peaks = r["statics"]["peaks"]
        .as_array()
        .expect("statics in the report");
    assert_eq!(peaks.len(), 6);
    for peak in peaks {
        let f = peak["force"].as_f64().unwrap();
        // 1000 N down on six legs: each carries more than a sixth, pushing.
        assert!(f > 1000.0 / 6.0 && f < 1000.0, "{peak}");
        assert!([2, 3].contains(&peak["line"].as_u64().unwrap()), "{peak}");
    }
}

#[test]
fn a_leg_over_its_hydraulic_force_limit_refuses_the_program_at_its_line() {
    // 100 mm² at 2 MPa: 200 N per leg.
    let m = hexapod_with(
        "supply_pressure = 2",
        "cylinder_area = 100\n",
        "statics-limit.toml",
    );
    let p = program("statics-limit.ngc");
    let out = nc_send(&["--check", "--machine", &m, "--wrench", "0 0 -1000", &p]);
    assert_eq!(out.status.code(), Some(3), "{out:?}");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("statics-limit.ngc:2: joint q1 would carry")
            && err.contains("over its limit of 200 N"),
        "{err}"
    );
    assert!(err.contains("nothing was sent"), "{err}");
    // Half the load fits.
    let out = nc_send(&["--check", "--machine", &m, "--wrench", "0,0,-500", &p]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn a_wrench_file_loads_only_the_lines_it_names() {
    let m = repo().join("examples/machines/hexapod.toml");
    let p = program("statics-file.ngc");
    let loads = tmp("statics-file.loads");
    std::fs::write(&loads, "# from line 3 on: 800 N down\n3 0 0 -800\n").unwrap();
    let out = nc_send(&[
        "--check",
        "--report",
        "json",
        "--machine",
        m.to_str().unwrap(),
        "--wrench-file",
        loads.to_str().unwrap(),
        &p,
    ]);
    let r = ok(&out);
    for peak in r["statics"]["peaks"].as_array().unwrap() {
        assert_eq!(peak["line"].as_u64(), Some(3), "{peak}");
    }
    std::fs::write(&loads, "3 0 0\n").unwrap();
    let out = nc_send(&["--check", "--wrench-file", loads.to_str().unwrap(), &p]);
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("statics-file.loads:1:3: a wrench is"), "{err}");
}

#[test]
fn mistakes_in_force_limits_and_unsupported_machines_are_named() {
    let m = hexapod_with("", "cylinder_area = 100\n", "statics-nopressure.toml");
    let p = program("statics-mistakes.ngc");
    let out = nc_send(&["--check", "--machine", &m, "--wrench", "0,0,-10", &p]);
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains(
            "joints[0].cylinder_area: a cylinder area needs the machine's supply_pressure"
        ),
        "{err}"
    );
    let h4 = repo().join("examples/machines/h4-table.toml");
    let p = tmp("statics-h4.ngc");
    std::fs::write(&p, "G21 G91 G94 F600\nG1 X1\nM2\n").unwrap();
    let p = p.to_str().unwrap();
    let out = nc_send(&[
        "--check",
        "--machine",
        h4.to_str().unwrap(),
        "--wrench",
        "0,0,-10",
        p,
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("unsupported: statics for the H-4"), "{err}");
}
