//! What the end-to-end test files share: running `nc-send` and `pkmc-sim` as a user
//! would, reading their JSON reports, and a scratch folder per test process.

// Each test file uses its own subset of these helpers.
#![allow(dead_code)]

use std::io::{BufRead, Read};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

/// The repository root (examples and machine files are named from there).
pub fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// Runs `nc-send` with `args` from the repository root.
pub fn nc_send(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_nc-send"))
        .args(args)
        .current_dir(repo())
        .output()
        .expect("nc-send runs")
}

/// Runs `nc-send` with `args` from the repository root, killing it and failing the
/// test if it has not exited within `limit`: a run that hangs fails instead of
/// hanging the suite.
pub fn nc_send_within(limit: Duration, args: &[&str]) -> Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_nc-send"))
        .args(args)
        .current_dir(repo())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("nc-send runs");
    // Drain both pipes while waiting, so a chatty run cannot block on a full pipe.
    let drain = |mut pipe: Box<dyn Read + Send>| {
        std::thread::spawn(move || {
            let mut bytes = Vec::new();
            let _ = pipe.read_to_end(&mut bytes);
            bytes
        })
    };
    let stdout = drain(Box::new(child.stdout.take().expect("stdout piped")));
    let stderr = drain(Box::new(child.stderr.take().expect("stderr piped")));
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().expect("nc-send can be waited for") {
            break status;
        }
        if start.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            panic!(
                "nc-send {args:?} still running after {limit:?} (hangs)\nstderr: {}",
                String::from_utf8_lossy(&stderr.join().unwrap_or_default())
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    Output {
        status,
        stdout: stdout.join().expect("stdout read"),
        stderr: stderr.join().expect("stderr read"),
    }
}

/// The JSON report on stdout.
pub fn json(out: &Output) -> serde_json::Value {
    serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!(
            "not JSON ({e}): {}\nstderr: {}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        )
    })
}

/// The JSON report of a run that must have exited 0.
pub fn ok(out: &Output) -> serde_json::Value {
    assert_eq!(
        out.status.code(),
        Some(0),
        "stdout: {}\nstderr: {}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    json(out)
}

/// A path in this test process's scratch folder.
pub fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("pkmc-tests-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

/// A program of 81 moves, about 10 s of motion on the built-in machine (ending at line
/// 82), written to the temporary file `name`. Its collinear runs are merged within
/// 1 µm by default, so it streams fewer blocks than moves.
pub fn ten_second_program(name: &str) -> PathBuf {
    let p = tmp(name);
    let mut text = String::from("G21 G90\nG0 X-60 Y0\n");
    for i in 1..=80 {
        text += &format!("G1 X{}.5 Y{} F1200\n", i - 60, i % 7);
    }
    std::fs::write(&p, text + "M2\n").unwrap();
    p
}

/// `pkmc-sim` on a pseudo-terminal, killed when dropped.
pub struct Sim {
    child: Child,
    /// The port it serves.
    pub port: String,
}

impl Sim {
    /// Starts `pkmc-sim` with `args` and reads the port it prints.
    pub fn start(args: &[&str]) -> Self {
        let mut child = Command::new(env!("CARGO_BIN_EXE_pkmc-sim"))
            .args(args)
            .stdout(Stdio::piped())
            .spawn()
            .unwrap();
        let mut port = String::new();
        std::io::BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut port)
            .unwrap();
        Sim {
            child,
            port: port.trim().to_string(),
        }
    }

    /// Runs `nc-send --port PORT --report json` with `args`.
    pub fn send(&self, args: &[&str]) -> Output {
        let mut all = vec!["--port", self.port.as_str(), "--report", "json"];
        all.extend_from_slice(args);
        nc_send(&all)
    }
}

impl Drop for Sim {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The report's `final_joint_steps`: drive steps or encoder counts per joint.
pub fn joint_steps(report: &serde_json::Value) -> Vec<i64> {
    report["final_joint_steps"]
        .as_array()
        .expect("final_joint_steps")
        .iter()
        .map(|v| v.as_i64().expect("whole steps"))
        .collect()
}

/// A sine along X, amplitude 5 mm and wavelength 20 mm, `length` mm long from
/// (`x0`, 0), as `G1` segments `segment` mm long (chords: the step in X shrinks where
/// the sine is steep) at `feed` mm/min, in path mode `mode` (`G64`, `G64 P0.01`, …);
/// coordinates to 0.1 µm, as a CAM program.
pub fn sine(length: f64, segment: f64, feed: u32, x0: f64, mode: &str) -> String {
    let k = std::f64::consts::TAU / 20.0;
    let y = |x: f64| 5.0 * (k * (x - x0)).sin();
    let end = x0 + length;
    let mut p = format!("G21 G90 G17 {mode}\nG0 X{x0} Y0\n");
    let mut x = x0;
    let mut first = true;
    while x < end {
        let slope = 5.0 * k * (k * (x - x0)).cos();
        x = (x + segment / (1.0 + slope * slope).sqrt()).min(end);
        p += &format!("G1 X{x:.4} Y{:.4}", y(x));
        if first {
            p += &format!(" F{feed}");
            first = false;
        }
        p += "\n";
    }
    p + "M2\n"
}
