//! End-to-end runs: the real `nc-send` binary streams programs over a pseudo-terminal
//! to the simulated controller, and the results are checked from outside (its JSON
//! report, its CSV trace, its exit code).

use pkmc::config::MachineConfig;
use pkmc_host::job;

mod common;
use common::{joint_steps, json, nc_send, ok, repo, tmp, Sim};

/// Expected final drive positions: the program's last target, in whole steps.
fn expected_steps(program: &str) -> Vec<i64> {
    let m = MachineConfig::cartesian_xyz();
    let text = std::fs::read_to_string(repo().join(program)).unwrap();
    let blocks = job::compile_text(&text, program, &m, m.home).unwrap();
    let end = blocks.last().unwrap().target;
    (0..3).map(|j| m.joints[j].scale.steps_at(end[j])).collect()
}

#[test]
fn nc_send_streams_over_a_pty_and_the_drives_end_on_exact_steps() {
    let out = nc_send(&["--sim", "--report", "json", "examples/square.ngc"]);
    assert_eq!(
        out.status.code(),
        Some(0),
        "stderr: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let r = json(&out);
    let steps = joint_steps(&r);
    assert_eq!(steps, expected_steps("examples/square.ngc"));
    assert_eq!(steps, vec![5000, 2900, 2000]); // X12.5 Y7.25 Z5 at 400 steps/mm
    assert_eq!(r["final_pose"]["x"], 12.5);
    assert_eq!(r["final_pose"]["y"], 7.25);
    assert_eq!(r["blocks_executed"], r["blocks_sent"]);
    assert_eq!(r["drive_violations"], 0);
    assert_eq!(r["final_state"], "Idle");
    assert_eq!(r["alarms"].as_array().unwrap().len(), 0);
}

#[test]
fn the_square_trace_never_exceeds_feed_or_acceleration() {
    let trace = tmp("square.csv");
    let out = nc_send(&[
        "--sim",
        "--trace",
        trace.to_str().unwrap(),
        "examples/square.ngc",
    ]);
    assert_eq!(
        out.status.code(),
        Some(0),
        "stderr: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let m = MachineConfig::cartesian_xyz();
    let text = std::fs::read_to_string(repo().join("examples/square.ngc")).unwrap();
    let blocks = job::compile_text(&text, "square", &m, m.home).unwrap();
    // Allowed path speed per line, mm/s: the feed, or the axis limit for rapids.
    let v_max_axis = m.axes[0].max_velocity as f64 * 1e-6;
    let allowed = |line: u32| -> f64 {
        if line == 0 {
            return 0.0; // the tick before the first block (a new machine's inputs read)
        }
        let b = blocks
            .iter()
            .find(|b| b.line == line)
            .expect("line has a block");
        match b.motion {
            pkmc::motion::block::Motion::Rapid => v_max_axis * 3f64.sqrt(),
            _ => b.feed as f64 * 1e-6,
        }
    };
    let a_max = m.axes[0].max_accel as f64 * 1e-6;
    let csv = std::fs::read_to_string(&trace).unwrap();
    let mut lines = csv.lines();
    let header = lines.next().unwrap();
    assert!(
        header.starts_with("t_s,line,x,y,z,a,b,c,q1,q2,q3"),
        "{header}"
    );
    let rows: Vec<Vec<f64>> = lines
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect();
    assert!(rows.len() > 1000, "one row per period");
    let t = 1e-3;
    // One period's rounding: each axis is rounded to 1 nm, so a speed may be off by
    // 2 nm per period and an acceleration by 4 nm per period².
    let (dv, da) = (2e-6 * 3f64.sqrt() / t, 4e-6 * 3f64.sqrt() / (t * t));
    let (mut prev_v, mut peak_v, mut peak_a) = ([0.0; 3], 0.0f64, 0.0f64);
    let mut prev = [0.0, 0.0, 0.0];
    for r in &rows {
        let p = [r[2], r[3], r[4]];
        let v: Vec<f64> = (0..3).map(|i| (p[i] - prev[i]) / t).collect();
        let speed = v.iter().map(|x| x * x).sum::<f64>().sqrt();
        let acc = (0..3)
            .map(|i| ((v[i] - prev_v[i]) / t).powi(2))
            .sum::<f64>()
            .sqrt();
        let line = r[1] as u32;
        assert!(
            speed <= allowed(line) + dv,
            "t={} line {line}: speed {speed} mm/s",
            r[0]
        );
        // Per axis: the axis acceleration limit; along the path, A.
        assert!(
            acc <= a_max * 3f64.sqrt() + da,
            "t={} line {line}: accel {acc} mm/s²",
            r[0]
        );
        for i in 0..3 {
            assert!(
                ((v[i] - prev_v[i]) / t).abs() <= a_max + da,
                "t={} axis {i} accel",
                r[0]
            );
        }
        peak_v = peak_v.max(speed);
        peak_a = peak_a.max(acc);
        prev = p;
        prev_v = [v[0], v[1], v[2]];
    }
    // The moves really reach their feed (the check above is not vacuous).
    assert!(peak_v > 19.0, "peak speed {peak_v}");
    assert!(peak_a > 0.9 * a_max, "peak accel {peak_a}");
    // Feedback columns (drive positions) end where the commanded joints end.
    let last = rows.last().unwrap();
    assert_eq!(&last[8..11], &last[11..14]);
}

#[test]
fn a_program_with_errors_sends_nothing_and_names_each_place() {
    let prog = tmp("bad.ngc");
    std::fs::write(&prog, "G0 X1\nG1 X2\nG1 X3 F100 (unclosed\n").unwrap();
    let out = nc_send(&["--sim", prog.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("bad.ngc:2:1: G1 without a feed (F)"), "{err}");
    assert!(
        err.contains("bad.ngc:3:12: comment opened here is never closed"),
        "{err}"
    );
    assert!(err.contains("nothing was sent"), "{err}");
}

#[test]
fn a_target_beyond_travel_fails_preflight_with_its_line() {
    let prog = tmp("far.ngc");
    std::fs::write(&prog, "G0 X10\nG0 Z50\n").unwrap();
    let out = nc_send(&["--sim", prog.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(3));
    assert!(String::from_utf8_lossy(&out.stderr).contains("far.ngc:2:"));
}

#[test]
fn a_bad_machine_file_is_refused_naming_the_field() {
    let m = tmp("bad-machine.toml");
    let text =
        std::fs::read_to_string(repo().join("examples/machines/cartesian-xyz.toml")).unwrap();
    std::fs::write(&m, text.replacen("channel = 1", "channel = 0", 1)).unwrap();
    let out = nc_send(&[
        "--sim",
        "--machine",
        m.to_str().unwrap(),
        "examples/square.ngc",
    ]);
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("joints[1] (Y).channel"), "{err}");
}

#[test]
fn pkmc_sim_serves_nc_send_on_a_named_port() {
    let sim = Sim::start(&[]);
    // pkmc-sim comes up locked, as a board after reset: home it first.
    let r = ok(&sim.send(&["--home", "examples/square.ngc"]));
    assert_eq!(r["final_pose"]["x"], 12.5);
    assert_eq!(r["blocks_executed"], r["blocks_sent"]);
}

#[test]
fn servo_joints_follow_the_square_and_settle_on_target() {
    let trace = tmp("servo.csv");
    let out = nc_send(&[
        "--sim",
        "--machine",
        "examples/machines/cartesian-servo.toml",
        "--report",
        "json",
        "--trace",
        trace.to_str().unwrap(),
        "examples/square.ngc",
    ]);
    assert_eq!(
        out.status.code(),
        Some(0),
        "stderr: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let r = json(&out);
    let steps = joint_steps(&r);
    // X and Y are encoder counts (1000/mm) of a plant that settles within a few counts;
    // Z is a stepper and exact.
    assert!((steps[0] - 12_500).abs() <= 5, "X at {} counts", steps[0]);
    assert!((steps[1] - 7_250).abs() <= 5, "Y at {} counts", steps[1]);
    assert_eq!(steps[2], 2000);
    // Following error stays small along the whole path (columns q1, q2 vs fb1, fb2).
    let csv = std::fs::read_to_string(&trace).unwrap();
    let mut worst = 0.0f64;
    for l in csv.lines().skip(1) {
        let v: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
        worst = worst.max((v[8] - v[11]).abs()).max((v[9] - v[12]).abs());
    }
    assert!(worst < 0.5, "worst following error {worst} mm");
    assert!(
        worst > 0.0,
        "the plant is simulated, not copied from the command"
    );
}

#[test]
fn nc_send_loads_its_machine_into_a_controller_that_has_another_and_it_persists() {
    let flash = tmp("flash.bin");
    let _ = std::fs::remove_file(&flash);
    let flash_arg = ["--flash", flash.to_str().unwrap()];
    let job = [
        "--machine",
        "examples/machines/cartesian-servo.toml",
        "--home",
        "examples/square.ngc",
    ];
    // The controller boots with the built-in stepper machine; the job needs servos.
    let r = ok(&Sim::start(&flash_arg).send(&job));
    assert_eq!(r["machine"], "cartesian-servo");
    assert_eq!(r["final_pose"]["x"], 12.5);
    // After a "reset" (a new simulator process on the same flash), the controller
    // comes up with the servo machine it was sent.
    let stored = std::fs::read(&flash).expect("the machine was written to flash");
    let m = pkmc::wire::store::read_record(&stored).unwrap();
    assert_eq!(m.name.as_str(), "cartesian-servo");
    ok(&Sim::start(&flash_arg).send(&job));
}

#[test]
fn an_h4_job_ends_with_exact_table_steps_and_no_drive_timing_violation() {
    let out = nc_send(&[
        "--sim",
        "--machine",
        "examples/machines/h4-table.toml",
        "--report",
        "json",
        "examples/h4-table-tilt.ngc",
    ]);
    assert_eq!(
        out.status.code(),
        Some(0),
        "stderr: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let r = json(&out);
    assert_eq!(r["drive_violations"], 0);
    assert_eq!(r["final_pose"]["a"], 30.0);
    // q5 is the table's stepper: 30° at the machine file's scale, in whole steps.
    let m = pkmc_host::machine_file::load(&repo().join("examples/machines/h4-table.toml")).unwrap();
    let want = m.joints[4].scale.steps_at(30 * pkmc::units::NDEG_PER_DEG);
    assert_eq!(r["final_joint_steps"][4].as_i64(), Some(want));
    assert_eq!(r["blocks_executed"], r["blocks_sent"]);
    // q1..q4 are servo carriages (10 kHz loops on the simulated plants): they settle
    // within two encoder counts of their commanded positions (one DAC step moves the
    // plant 300 counts/s: the loop holds to about a count either side).
    for j in 0..4 {
        let q = r["final_joints"][j].as_f64().unwrap();
        let counts = r["final_joint_steps"][j].as_i64().unwrap();
        let want = (q * 1000.0).round() as i64;
        assert!(
            (counts - want).abs() <= 2,
            "q{}: encoder at {counts}, commanded {want} counts",
            j + 1
        );
    }
}
