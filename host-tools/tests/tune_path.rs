//! Tuned against present gains along a path (issue 35): on the H-4's five-axis
//! example (`h4-table-tilt.ngc`, the four servo carriages q1–q4 tuned) and report B's
//! helix on the hexapod-xy (`helix-b.ngc`, the table's X and Y tuned; the legs run
//! LQG, which `tune` does not write), the following error of every tuned joint and the
//! contour errors with the tuned gains are compared with those of the machine file's
//! present gains.
//!
//! Through the real `nc-send` on `--sim` (no encoder noise added): each joint is
//! tuned with the defaults and `--write` on a copy of the machine file, then the
//! program runs on the present file and on the tuned copy with the recorder
//! streaming every servo period (`record --servo --trigger stream --during PROGRAM`):
//! the loop's own following error `ferr:J` (commanded − measured in the period, counts)
//! and the contour errors `contour` (nm) and `direction` (µ°). The maximum and the RMS
//! of each over the run are printed for both (`--nocapture`). Asserted: the tuned
//! gains' following error, max and RMS, of every tuned joint is at most the present
//! gains'. Printed only: the contour error (set by the LQG legs, which `tune` does not
//! write: the tuned table lowers its RMS by about 1 nm of 804, less than it varies
//! from run to run, and its maximum varies by 150 nm from run to run) and the
//! direction error, which the tuned table makes worse in the path's last 2 ms
//! (docs/tuning.md, "Tuned against present gains", "What is left").

use std::path::{Path, PathBuf};
use std::process::Command;

fn repo(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(rel)
}

fn temp(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("tune-path");
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

fn nc_send(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_nc-send"))
        .args(args)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "nc-send {args:?}: {stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    stdout
}

/// One signal over a run.
#[derive(Clone, Debug)]
struct Figure {
    name: String,
    max: f64,
    rms: f64,
}

/// Max and RMS of every signal of a recorder CSV (its first two columns are the
/// sample and the time).
fn figures(csv: &Path) -> Vec<Figure> {
    let text = std::fs::read_to_string(csv).unwrap();
    let mut lines = text.lines();
    let names: Vec<&str> = lines.next().unwrap().split(',').skip(2).collect();
    let rows: Vec<Vec<f64>> = lines
        .filter(|l| !l.is_empty())
        .map(|l| l.split(',').skip(2).map(|v| v.parse().unwrap()).collect())
        .collect();
    assert!(
        rows.len() > 1000,
        "{}: {} samples",
        csv.display(),
        rows.len()
    );
    names
        .iter()
        .enumerate()
        .map(|(i, n)| {
            let v: Vec<f64> = rows.iter().map(|r| r[i].abs()).collect();
            Figure {
                name: n.to_string(),
                max: v.iter().copied().fold(0.0, f64::max),
                rms: (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt(),
            }
        })
        .collect()
}

/// Runs `program` on `machine` with the recorder streaming `signals` every servo
/// period.
fn run(machine: &Path, program: &str, signals: &str, tag: &str) -> Vec<Figure> {
    let csv = temp(&format!("{tag}.csv"));
    let program = repo(&format!("examples/{program}"));
    nc_send(&[
        "--sim",
        "--machine",
        machine.to_str().unwrap(),
        "record",
        "--servo",
        "--signals",
        signals,
        "--trigger",
        "stream",
        "--during",
        program.to_str().unwrap(),
        "--csv",
        csv.to_str().unwrap(),
    ]);
    figures(&csv)
}

/// Tunes `joints` of `machine` on a copy, runs `program` on the file and the copy;
/// prints both tables and returns the signals where the tuned gains do worse.
fn compare(machine: &str, program: &str, joints: &[&str], signals: &str) -> Vec<String> {
    let present = repo(&format!("examples/machines/{machine}.toml"));
    let tuned = temp(&format!("{machine}-tuned.toml"));
    std::fs::copy(&present, &tuned).unwrap();
    let t = tuned.to_str().unwrap();
    for j in joints {
        let out = nc_send(&["--sim", "--machine", t, "tune", j, "--write"]);
        for l in out
            .lines()
            .filter(|l| l.starts_with("designed") || l.starts_with("written"))
        {
            println!("{machine} {j}: {l}");
        }
    }
    let before = run(&present, program, signals, &format!("{machine}-present"));
    let after = run(&tuned, program, signals, &format!("{machine}-tuned"));
    println!("{machine}, {program} (every servo period; |x| max / RMS):");
    println!("| signal | present gains | tuned gains |");
    let mut worse = Vec::new();
    for (b, a) in before.iter().zip(&after) {
        println!(
            "| {} | {:.0} / {:.2} | {:.0} / {:.2} |",
            b.name, b.max, b.rms, a.max, a.rms
        );
        let ferr = b.name.starts_with("ferr");
        if ferr && a.max > b.max {
            worse.push(format!("{machine} {} max {} > {}", b.name, a.max, b.max));
        }
        if ferr && a.rms > b.rms {
            worse.push(format!(
                "{machine} {} RMS {:.3} > {:.3}",
                b.name, a.rms, b.rms
            ));
        }
    }
    worse
}

#[test]
fn tuned_gains_follow_both_programs_at_least_as_well_as_the_present_ones() {
    let mut worse = compare(
        "h4-table",
        "h4-table-tilt.ngc",
        &["q1", "q2", "q3", "q4"],
        "ferr:0,ferr:1,ferr:2,ferr:3",
    );
    worse.extend(compare(
        "hexapod-xy",
        "helix-b.ngc",
        &["table X", "table Y"],
        "ferr:6,ferr:7,contour,direction",
    ));
    assert!(worse.is_empty(), "tuned worse than present: {worse:#?}");
}
