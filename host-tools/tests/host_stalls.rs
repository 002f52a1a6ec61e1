//! Issue 33: a stall of the host never loses a job. Over the real link — `pkmc-sim
//! --real-time` in its own process serving a pseudo-terminal, `nc-send --port` a
//! child process that the test stops (SIGSTOP) and continues (SIGCONT) in wall-clock
//! time — on the H-4, a coarse program (2 mm moves) and a dense one (0.05 mm chords),
//! streamed as programmed (`--g64-tolerance 0`: one block a move):
//!
//! * stalls of 0.5, 1.5, 5 and 20 s: each job completes with the final joint steps
//!   of an unstalled run, takes longer by at most the stall less the motion buffered,
//!   plus 0.5 s, and its trace shows a stop on the path and a restart, no joint over
//!   its acceleration limit;
//! * a 40 s stall (past the default 30 s host timeout) leaves the job held; the host,
//!   back, resumes it and it completes exactly; a job whose host never comes back is
//!   completed by a new `nc-send resume`;
//! * a foreign `Hello` mid-job (a program that had the port open) ends the host's
//!   session with a clear error and a JSON report, no panic.
//!
//! The runs keep real time, so they are serialised (one lock): side by side on a
//! small machine they would starve each other's queues. About four minutes in all.

mod common;

use common::{json, repo, tmp, Sim};
use std::process::{Child, Command, Output, Stdio};
use std::sync::Mutex;
use std::time::{Duration, Instant};

static REAL_TIME: Mutex<()> = Mutex::new(());

fn machine() -> String {
    repo()
        .join("examples/machines/h4-table.toml")
        .to_str()
        .unwrap()
        .into()
}

/// Back and forth along a sine (amplitude 5 mm, wavelength 20 mm) between X −60 and
/// 60, `passes` times, in chords of `segment` mm at `feed` mm/min.
fn program(name: &str, segment: f64, passes: usize, feed: u32) -> String {
    let k = std::f64::consts::TAU / 20.0;
    let mut p = format!("G21 G90 G17 G64\nG0 X-60 Y0\nG1 F{feed}\n");
    let mut x = -60.0f64;
    for pass in 0..passes {
        let dir = if pass % 2 == 0 { 1.0 } else { -1.0 };
        loop {
            let slope = 5.0 * k * (k * x).cos();
            x += dir * segment / (1.0 + slope * slope).sqrt();
            let done = x * dir >= 60.0;
            x = x.clamp(-60.0, 60.0);
            p += &format!("G1 X{x:.4} Y{:.4}\n", 5.0 * (k * (x + 60.0)).sin());
            if done {
                break;
            }
        }
    }
    let path = tmp(name);
    std::fs::write(&path, p + "M2\n").unwrap();
    path.to_str().unwrap().into()
}

fn coarse() -> String {
    // Back and forth along X, ten times 120 mm in 2 mm moves (600 moves, more than the
    // controller's queue) at 150 mm/s: about 2 s (150 moves) buffered.
    let mut p = String::from("G21 G90 G17 G64\nG0 X-60 Y0\nG1 F9000\n");
    for pass in 0..10 {
        for i in 1..=60 {
            let x = if pass % 2 == 0 {
                -60 + 2 * i
            } else {
                60 - 2 * i
            };
            p += &format!("G1 X{x}\n");
        }
    }
    let path = tmp("coarse.ngc");
    std::fs::write(&path, p + "M2\n").unwrap();
    path.to_str().unwrap().into()
}

fn dense() -> String {
    // 3 × 120 mm of 0.05 mm chords (about 7 600 moves) at 100 mm/s.
    program("dense.ngc", 0.05, 3, 6000)
}

fn signal(child: &Child, sig: i32) {
    // SAFETY: a plain kill(2) of our own child.
    let r = unsafe { libc::kill(child.id() as i32, sig) };
    assert_eq!(r, 0, "kill({sig}) of nc-send");
}

/// One run: a fresh `pkmc-sim --real-time --trace` with `machine`, unlocked; then
/// `nc-send --port … PROGRAM`, stopped for `stall` once `stop_after` has passed.
struct Run {
    out: Output,
    wall: Duration,
    trace: String,
}

fn run(machine: &str, program: &str, stall: Option<(Duration, Duration)>, tag: &str) -> Run {
    let trace = tmp(&format!("{tag}.csv")).to_str().unwrap().to_string();
    let sim = Sim::start(&["--real-time", "--machine", machine, "--trace", &trace]);
    assert_eq!(
        sim.send(&["--machine", machine, "reset"]).status.code(),
        Some(0)
    );
    let start = Instant::now();
    let mut child = Command::new(env!("CARGO_BIN_EXE_nc-send"))
        .args([
            "--port",
            &sim.port,
            "--report",
            "json",
            "--machine",
            machine,
            // The moves go out as programmed, one block each (merged within 1 µm by
            // default, a pass would be one block and the queue would never fill).
            "--g64-tolerance",
            "0",
        ])
        .arg(program)
        .current_dir(repo())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    if let Some((after, length)) = stall {
        std::thread::sleep(after);
        assert!(
            child.try_wait().unwrap().is_none(),
            "{tag}: ended before the stall"
        );
        signal(&child, libc::SIGSTOP);
        std::thread::sleep(length);
        signal(&child, libc::SIGCONT);
    }
    let out = wait_within(child, Duration::from_secs(120), tag);
    let wall = start.elapsed();
    drop(sim);
    Run {
        out,
        wall,
        trace: std::fs::read_to_string(&trace).unwrap(),
    }
}

fn wait_within(mut child: Child, limit: Duration, tag: &str) -> Output {
    let start = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > limit {
            let _ = child.kill();
            panic!("{tag}: nc-send still running after {limit:?}");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    child.wait_with_output().unwrap()
}

/// The trace's rows: time, pose X, Y and the joints.
fn rows(trace: &str) -> Vec<Vec<f64>> {
    trace
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect()
}

/// From a trace: the motion's span (first to last tick that moves, s), the longest
/// standstill inside it (s) and each of the first four joints' largest acceleration
/// (mm/s² or °/s², second differences of the commanded joints, smoothed over 3
/// ticks against quantisation).
fn motion(trace: &str) -> (f64, f64, Vec<f64>) {
    let r = rows(trace);
    // Commanded pose and joints (not the drives' feedback, which settles on).
    // (Per joint: commanded, feedback and true position, in three groups.)
    let cmd = 2..8 + (r[0].len() - 8) / 3;
    let moved = |i: usize| r[i][cmd.clone()] != r[i - 1][cmd.clone()];
    let moving: Vec<usize> = (1..r.len()).filter(|&i| moved(i)).collect();
    let (first, last) = (moving[0], *moving.last().unwrap());
    let gap = moving
        .windows(2)
        .map(|w| r[w[1]][0] - r[w[0]][0])
        .fold(0.0, f64::max);
    let t = 1e-3;
    let n = (r[0].len() - 8) / 3;
    let mut acc = vec![0.0f64; n];
    for i in first.max(3)..(last + 3).min(r.len() - 3) {
        for (j, a) in acc.iter_mut().enumerate() {
            let q = |k: usize| r[k][8 + j];
            let v = (q(i + 3) - 2.0 * q(i) + q(i - 3)) / (9.0 * t * t);
            *a = a.max(v.abs());
        }
    }
    (r[last][0] - r[first][0], gap, acc)
}

/// The final commanded joints (the report's `final_joints`, exact to the unit: a port
/// reports no drive steps) and, from the trace's last row, the drives' feedback in
/// encoder counts (1000 per mm on the H-4's carriages).
fn steps(r: &serde_json::Value, trace: &str) -> (Vec<String>, Vec<i64>) {
    let joints = r["final_joints"]
        .as_array()
        .expect("final_joints")
        .iter()
        .map(|v| v.to_string())
        .collect();
    let last = rows(trace).pop().unwrap();
    let n = (last.len() - 8) / 3;
    let counts = last[8 + n..8 + 2 * n]
        .iter()
        .map(|v| (v * 1000.0).round() as i64)
        .collect();
    (joints, counts)
}

fn done(run: &Run, tag: &str) -> serde_json::Value {
    let r = json(&run.out);
    assert_eq!(
        (run.out.status.code(), r["result"].as_str()),
        (Some(0), Some("done")),
        "{tag}: {r}\nstderr: {}",
        String::from_utf8_lossy(&run.out.stderr)
    );
    r
}

/// The H-4's joint acceleration limits (q1..q4), from its machine file.
const ACCEL_LIMITS: [f64; 4] = [5000.0, 5000.0, 5000.0, 5000.0];

fn stalls_on(name: &str, program: &str, stop_after: Duration) {
    let _one = REAL_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let m = machine();
    let base = run(&m, program, None, &format!("{name}-base"));
    let b = done(&base, name);
    let (span0, gap0, acc0) = motion(&base.trace);
    let buffered = b["link"]["buffered"]["p10_ms"].as_f64().unwrap() / 1000.0;
    eprintln!(
        "{name}: unstalled: wall {:.2} s, motion {span0:.3} s, longest standstill {gap0:.3} s, \
         buffered p10 {buffered:.3} s, steps {:?}, joint accel {acc0:.0?}",
        base.wall.as_secs_f64(),
        steps(&b, &base.trace)
    );
    let (joints0, counts0) = steps(&b, &base.trace);
    for s in [0.5, 1.5, 5.0, 20.0] {
        let tag = format!("{name}-stall-{s}");
        let stall = Duration::from_secs_f64(s);
        let run = run(&m, program, Some((stop_after, stall)), &tag);
        let r = done(&run, &tag);
        let (span, gap, acc) = motion(&run.trace);
        let extra = span - span0;
        let bound = (s - buffered).max(0.0) + 0.5;
        eprintln!(
            "{tag}: wall {:.2} s (+{:.2}), motion {span:.3} s (+{extra:.3}, bound {bound:.3}), \
             longest standstill {gap:.3} s, own gaps {} (longest {:.2} s), joint accel {acc:.0?}",
            run.wall.as_secs_f64(),
            run.wall.as_secs_f64() - base.wall.as_secs_f64(),
            r["link"]["own_gaps"],
            r["link"]["own_gap_max_s"].as_f64().unwrap_or(0.0)
        );
        let (joints, counts) = steps(&r, &run.trace);
        eprintln!(
            "{tag}: final joints {joints:?} (unstalled {joints0:?}), encoders when the \
             simulator was ended {counts:?} (unstalled {counts0:?}: the servos still settling)"
        );
        // The commanded joints, exact to the count: the steps each drive is sent to.
        assert_eq!(joints, joints0, "{tag}: final joints");
        assert!(
            extra <= bound,
            "{tag}: {extra:.3} s longer, bound {bound:.3}"
        );
        for (j, (a, limit)) in acc.iter().zip(ACCEL_LIMITS).enumerate() {
            assert!(
                *a <= limit * 1.05,
                "{tag}: joint {} at {a:.0}, limit {limit}",
                j + 1
            );
        }
        if s > buffered + 0.5 {
            // The queue ran dry: a stop on the path and a restart.
            assert!(
                gap > s - buffered - 0.5,
                "{tag}: standstill {gap:.3} s for a {s} s stall"
            );
        }
        assert!(r["alarm"].is_null(), "{tag}: {r}");
    }
}

#[test]
fn stalls_of_the_host_during_a_coarse_program_never_lose_the_job() {
    stalls_on("coarse", &coarse(), Duration::from_millis(2500));
}

#[test]
fn stalls_of_the_host_during_a_dense_program_never_lose_the_job() {
    stalls_on("dense", &dense(), Duration::from_millis(2500));
}

/// `nc-send --check` of `program`: the exact final joints, in this process's
/// simulator, without a port.
fn checked_joints(machine: &str, program: &str) -> serde_json::Value {
    let out = common::nc_send(&["--check", "--report", "json", "--machine", machine, program]);
    json(&out)["final_joints"].clone()
}

#[test]
fn a_stall_past_the_host_timeout_holds_the_job_and_the_host_back_resumes_it_exactly() {
    let _one = REAL_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let (m, p) = (machine(), coarse());
    let want = checked_joints(&m, &p);
    let run = run(
        &m,
        &p,
        Some((Duration::from_millis(2500), Duration::from_secs(40))),
        "held-40",
    );
    let r = done(&run, "held-40");
    let (span, gap, _) = motion(&run.trace);
    eprintln!(
        "held-40: wall {:.2} s, motion {span:.3} s, standstill {gap:.3} s, resumed after the \
         host timeout {} time(s)",
        run.wall.as_secs_f64(),
        r["link"]["host_timeout_resumes"]
    );
    assert_eq!(r["final_joints"], want, "{r}");
    assert_eq!(
        r["link"]["host_timeout_resumes"], 1,
        "held, then resumed: {r}"
    );
    // Starved once its 2 s of motion ran out, held at 30 s: the simulated clock
    // stops while the job is held at rest.
    assert!(gap > 27.0, "stood still through the stall: {gap:.3} s");
    let err = String::from_utf8_lossy(&run.out.stderr);
    assert!(!err.contains("panicked"), "{err}");
}

#[test]
fn a_job_held_for_a_host_that_never_comes_back_is_completed_by_a_new_resume() {
    let _one = REAL_TIME.lock().unwrap_or_else(|e| e.into_inner());
    // A short host timeout keeps the test short; the whole job is queued at once.
    let m = tmp("h4-timeout-3s.toml");
    let text = std::fs::read_to_string(machine()).unwrap();
    std::fs::write(&m, format!("host_timeout_s = 3\n{text}")).unwrap();
    let m = m.to_str().unwrap();
    let p = tmp("slow.ngc");
    std::fs::write(&p, "G21 G90\nG0 X-60 Y0\nG1 X0 F600\nG1 X30\nM2\n").unwrap();
    let p = p.to_str().unwrap();
    let sim = Sim::start(&["--real-time", "--machine", m]);
    assert_eq!(sim.send(&["--machine", m, "reset"]).status.code(), Some(0));
    let host = Command::new(env!("CARGO_BIN_EXE_nc-send"))
        .args(["--port", &sim.port, "--report", "json", "--machine", m])
        .args(["--g64-tolerance", "0"])
        .args(["--max-buffered-ms", "120000", p])
        .current_dir(repo())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_secs(2));
    signal(&host, libc::SIGSTOP);
    std::thread::sleep(Duration::from_secs(5));
    // It never comes back.
    signal(&host, libc::SIGKILL);
    let mut host = host;
    host.wait().unwrap();
    let s = json(&sim.send(&["--machine", m, "status"]));
    assert_eq!(s["state"], "Hold", "{s}");
    assert!(
        s["alarm"]
            .as_str()
            .unwrap_or("")
            .contains("host silent too long"),
        "{s}"
    );
    assert_eq!(s["held_job"]["host_process"], host.id(), "{s}");
    let x = s["pose"]["x"].as_f64().unwrap();
    assert!(x > -60.0 && x < 0.0, "stopped on the path of line 3: {s}");
    let out = sim.send(&["--machine", m, "resume"]);
    let r = json(&out);
    assert_eq!(
        (out.status.code(), r["result"].clone()),
        (Some(0), "done".into()),
        "{r}"
    );
    assert_eq!(
        (r["pose"]["x"].clone(), r["pose"]["y"].clone()),
        (30.0.into(), 0.0.into())
    );
    assert_eq!(r["joints"], checked_joints(m, p), "{r}");
}

#[test]
fn a_foreign_hello_mid_job_ends_the_session_with_a_clear_error_and_a_report() {
    use std::io::Write;
    let _one = REAL_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let sim = Sim::start(&[]);
    assert_eq!(sim.send(&["reset"]).status.code(), Some(0));
    // A program that had the port open before nc-send took it (no lock stops it).
    let mut foreign = std::fs::OpenOptions::new()
        .write(true)
        .open(&sim.port)
        .unwrap();
    let p = tmp("short-blocks.ngc");
    let mut text = String::from("G21 G90 G64\n");
    for i in 1..=20_000 {
        text += &format!("G1 X{:.2} F600\n", (i % 2000) as f64 * 0.01);
    }
    std::fs::write(&p, text + "M2\n").unwrap();
    let host = Command::new(env!("CARGO_BIN_EXE_nc-send"))
        .args([
            "--port",
            &sim.port,
            "--report",
            "json",
            "--g64-tolerance",
            "0",
        ])
        .arg(&p)
        .current_dir(repo())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let pid = host.id();
    std::thread::sleep(Duration::from_millis(2000));
    let hello = pkmc::wire::HostMsg::Hello {
        version: pkmc::wire::PROTOCOL_VERSION,
        machine: pkmc::wire::store::identity(&pkmc::config::MachineConfig::cartesian_xyz()),
        host: 4242,
    };
    let mut frame = [0u8; pkmc::wire::MAX_FRAME];
    let n = pkmc::wire::encode_frame(0, &hello, &mut frame).unwrap();
    foreign.write_all(&frame[..n]).unwrap();
    let out = wait_within(host, Duration::from_secs(30), "foreign hello");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("panicked"), "{err}");
    assert_eq!(out.status.code(), Some(4), "{err}");
    let r = json(&out);
    assert_eq!(r["result"], "error", "{r}");
    assert!(
        r["error"]
            .as_str()
            .unwrap_or("")
            .contains("another program opened a session on this port"),
        "{r}"
    );
    drop(foreign);
    // The controller's account: the job is the first host's, unfinished.
    let s = json(&sim.send(&["status"]));
    assert_eq!(s["held_job"]["host_process"], pid, "{s}");
}
