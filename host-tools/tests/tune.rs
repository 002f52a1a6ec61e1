//! `nc-send tune` end to end (issue 35): the real binary against the simulator
//! (`--sim`, the real link), on a servo joint of every servo example machine. The
//! plants of the machine files are the unknown plants; the test's copy of each file
//! adds encoder noise (`plant.encoder_noise`, σ = 0.3 count; the Cartesian and H-4
//! joints get the simulator's default plant written out, so that it can carry the
//! noise). From what `tune` prints, the test checks:
//!
//! * (a) the identified model's closed-loop step under the file's present gains lies
//!   within 10 % of the TRUE plant's (`tune::step_error`, as in `tune_ident.rs`:
//!   ∫₀^{t₉₀}|ŷ − y| / ∫₀^{t₉₀}|y_∞ − y|);
//! * (b) the designed gains keep ≥ 45° of phase margin and a stable loop on the TRUE
//!   plant;
//! * (c) `--write` changes only that joint's servo gains (one comment line giving the
//!   old line, the `servo` line), and for a joint that runs LQG (the hexapod-xy's
//!   legs) its `lqg` and `lqg_gains` lines the same way and an added `lqg_model`
//!   line, in every joint that shares its design; the written file loads (its
//!   `lqg_gains` checked against the design on `lqg_model`) and runs a job; the written
//!   LQG design keeps a stable loop and |S|max ≤ 1.307 (so ≥ 45° of phase margin) on
//!   the TRUE plant;
//! * refusals name the problem: a stepper joint, a joint that does not exist.
//!
//! Run with `--nocapture` for the figures (docs/tuning.md).

use pkmc_host::control::lqg;
use pkmc_host::control::plant::TransferFunction;
use pkmc_host::control::tune;
use pkmc_host::machine_file::lqg::LawKind;
use pkmc_host::machine_file::{read_file, DriveKind};
use std::path::{Path, PathBuf};
use std::process::Command;

const H: f64 = 1e-4;
const NOISE: f64 = 0.3;

fn machine(name: &str) -> String {
    let path = format!(
        "{}/../examples/machines/{name}.toml",
        env!("CARGO_MANIFEST_DIR")
    );
    std::fs::read_to_string(path).unwrap()
}

/// `text` with encoder noise on every servo joint's plant (the default plant written
/// out where the file has none).
fn with_noise(text: &str) -> String {
    let mf = read_file(text, "example").unwrap();
    let mut out = String::new();
    let mut joint = None::<usize>;
    let mut seen = 0;
    for line in text.lines() {
        let t = line.trim_start();
        if t.starts_with("[[joints]]") {
            joint = Some(seen);
            seen += 1;
        } else if t.starts_with('[') {
            joint = None;
        }
        if t.starts_with("plant") && joint.is_some() {
            let end = line.rfind('}').unwrap();
            out.push_str(&format!(
                "{}, encoder_noise = {NOISE} }}\n",
                &line[..end].trim_end()
            ));
            continue;
        }
        out.push_str(line);
        out.push('\n');
        let servo_line = t.starts_with("servo") && t[5..].trim_start().starts_with('=');
        if let (true, Some(j)) = (servo_line, joint) {
            let jf = &mf.joints[j];
            if jf.drive == DriveKind::Servo && jf.plant.is_none() {
                let k = pkmc_host::sim::DEFAULT_PLANT_GAIN / jf.steps_per_unit;
                let tau = pkmc_host::sim::DEFAULT_PLANT_TAU_S;
                out.push_str(&format!(
                    "plant = {{ num = [{k}], den = [{tau}, 1.0, 0.0], input_per_count = 1.0, \
                     encoder_noise = {NOISE} }}\n"
                ));
            }
        }
    }
    out
}

/// `text` cut into its tables: each header line with the lines after it up to the next
/// header (the lines before the first header as the first).
fn sections(text: &str) -> Vec<Vec<&str>> {
    let mut out: Vec<Vec<&str>> = vec![Vec::new()];
    for line in text.lines() {
        if line.trim_start().starts_with('[') {
            out.push(Vec::new());
        }
        out.last_mut().unwrap().push(line);
    }
    out
}

fn temp(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("tune");
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

fn nc_send(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_nc-send"))
        .args(args)
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// The numbers of `[a, b, …]` after `key = ` on the line starting `prefix`.
fn array(stdout: &str, prefix: &str, key: &str) -> Vec<f64> {
    let line = stdout.lines().find(|l| l.starts_with(prefix)).unwrap();
    let at = line.find(&format!("{key} = [")).unwrap() + key.len() + 4;
    let end = at + line[at..].find(']').unwrap();
    line[at..end]
        .split(',')
        .map(|s| s.trim().parse().unwrap())
        .collect()
}

fn scalar(stdout: &str, prefix: &str, key: &str) -> f64 {
    let line = stdout.lines().find(|l| l.starts_with(prefix)).unwrap();
    let at = line.find(&format!(" {key} = ")).unwrap() + key.len() + 4;
    line[at..]
        .split_whitespace()
        .next()
        .unwrap()
        .parse()
        .unwrap()
}

/// Tunes `joint` of example machine `file` with `--write`; checks (a), (b), (c).
fn tune_one(file: &str, joint: &str) {
    let original = with_noise(&machine(file));
    let path = temp(&format!("{file}-{joint}.toml"));
    std::fs::write(&path, &original).unwrap();
    let p = path.to_str().unwrap();
    let plot = temp(&format!("{file}-{joint}.svg"));
    let (ok, stdout, stderr) = nc_send(&[
        "--sim",
        "--machine",
        p,
        "tune",
        joint,
        "--write",
        "--plot",
        plot.to_str().unwrap(),
    ]);
    assert!(ok, "{file} {joint}: {stderr}");
    let mf = read_file(&original, p).unwrap();
    let config = mf.to_config().unwrap();
    let (j, jf) = mf
        .joints
        .iter()
        .enumerate()
        .find(|(_, j)| j.name == joint)
        .unwrap();
    let plant = jf.plant.as_ref().unwrap();
    let truth = TransferFunction::new(&plant.num, &plant.den).unwrap();
    let model = TransferFunction::new(
        &array(&stdout, "model:", "num"),
        &array(&stdout, "model:", "den"),
    )
    .unwrap();
    let cpu = jf.steps_per_unit;
    let g = config.servo.gains[jf.channel as usize];
    let present = [g.kp as f64, g.ki as f64, g.kd as f64];
    let n = 20_000;
    let y = tune::closed_loop_step(&truth, cpu, H, present, n);
    let yhat = tune::closed_loop_step(&model, cpu, H, present, n);
    let a = tune::step_error(&y, &yhat, H);
    let designed = ["kp", "ki", "kd"].map(|k| scalar(&stdout, "designed:", k));
    let m = tune::margins(&truth, cpu, H, designed).unwrap();
    println!("{file} {joint}:");
    for l in stdout.lines().take_while(|l| !l.starts_with("idle")) {
        println!("  {l}");
    }
    println!(
        "  (a) identified vs true closed-loop step, present gains: {:.2} % (t90 {:.4} s)",
        100.0 * a.ratio,
        a.rise_s
    );
    println!(
        "  (b) designed gains on the true plant: PM {:.1}° at {:.1} rad/s, GM {:.1} dB, stable {}",
        m.phase_margin_deg,
        m.phase_margin_at_rad_s,
        m.gain_margin_db(),
        m.stable
    );
    assert!(a.ratio < 0.10, "{file} {joint}: {a:?}");
    assert!(
        m.stable && m.phase_margin_deg >= 45.0,
        "{file} {joint}: {m:?}"
    );
    // (c) What changed: the joint's servo line, and for an LQG joint its `lqg` and
    // `lqg_gains` lines, each under a comment giving the old one, and an added
    // `lqg_model` line; the same in the joints that share its LQG design; nothing else.
    let lqg = jf.servo.as_ref().unwrap().law == LawKind::Lqg;
    let set: Vec<usize> = if lqg {
        (0..mf.joints.len())
            .filter(|&k| {
                let o = &mf.joints[k];
                o.lqg_gains == jf.lqg_gains
                    && o.servo.as_ref().is_some_and(|s| s.law == LawKind::Lqg)
            })
            .collect()
    } else {
        vec![j]
    };
    let keys: &[&str] = if lqg {
        &["servo", "lqg", "lqg_gains"]
    } else {
        &["servo"]
    };
    let written = std::fs::read_to_string(&path).unwrap();
    let (old, new) = (sections(&original), sections(&written));
    assert_eq!(old.len(), new.len());
    let mut joint_no = None::<usize>;
    let mut count = 0;
    for (o, n) in old.iter().zip(&new) {
        if o[0].trim_start().starts_with("[[joints]]") {
            joint_no = Some(count);
            count += 1;
        } else if o[0].trim_start().starts_with('[') {
            joint_no = None;
        }
        if !joint_no.is_some_and(|k| set.contains(&k)) {
            assert_eq!(o, n, "{file} {joint}: a table that was not tuned changed");
            continue;
        }
        let key_of = |l: &str| l.split('=').next().unwrap().trim().to_string();
        let mut expect = Vec::new();
        for l in o {
            let k = key_of(l);
            if !l.trim_start().starts_with('#') && keys.contains(&k.as_str()) {
                expect.push(format!("# nc-send tune: was {}", l.trim_start()));
                let line = n.iter().find(|m| key_of(m) == k).unwrap();
                expect.push(line.to_string());
            } else {
                expect.push(l.to_string());
            }
        }
        let models: Vec<&&str> = n.iter().filter(|m| key_of(m) == "lqg_model").collect();
        assert_eq!(models.len(), usize::from(lqg), "{file} {joint}: {n:?}");
        let rest: Vec<String> = n
            .iter()
            .filter(|m| key_of(m) != "lqg_model")
            .map(|m| m.to_string())
            .collect();
        assert_eq!(rest, expect, "{file} {joint}");
    }
    let wf = read_file(&written, p).unwrap();
    for &k in &set {
        let s = wf.joints[k].servo.as_ref().unwrap();
        for (key, v) in [
            ("kp", s.kp),
            ("ki", s.ki),
            ("kd", s.kd),
            ("kvff", s.kvff),
            ("kaff", s.kaff),
        ] {
            let want = scalar(&stdout, "designed:", key);
            assert!(
                (v as f64 - want).abs() <= 1e-4 * want.abs() + 1e-12,
                "{key}: {v} {want}"
            );
        }
    }
    if lqg {
        // (b) for the LQG law: the written design (the loader has checked it is that
        // of the written weights on the written model) on the TRUE plant: stable,
        // and |S|max at most 1/(2·sin 22.5°), which keeps 45° of phase margin.
        let w = wf.joints[j].lqg.unwrap();
        let m = wf.joints[j].lqg_model.as_ref().unwrap();
        let model = TransferFunction::new(&m.num, &m.den).unwrap();
        let f = lqg::design(&model, cpu, H, &w)
            .unwrap()
            .loop_figures(&truth, cpu)
            .unwrap();
        let bound = 1.0 / (2.0 * (22.5f64).to_radians().sin());
        println!(
            "  (b) the written LQG design on the true plant: |S|max {:.3} (≤ {bound:.3} keeps PM ≥ 45°), crossover {:.1} rad/s, largest pole {:.6}",
            f.peak_sensitivity, f.crossover_rad_s, f.max_pole
        );
        assert!(f.max_pole < 1.0 && f.peak_sensitivity <= bound, "{f:?}");
        assert!(
            set.len() == 6,
            "{file} {joint}: the six legs share the design: {set:?}"
        );
    }
    let prog = temp(&format!("{file}-{joint}.ngc"));
    std::fs::write(&prog, "G4 P0.05\nM2\n").unwrap();
    let (ok, _, stderr) = nc_send(&["--sim", "--machine", p, prog.to_str().unwrap()]);
    assert!(
        ok,
        "{file} {joint}: the written file does not run a job: {stderr}"
    );
}

#[test]
fn tune_cartesian_servo() {
    tune_one("cartesian-servo", "X");
}

#[test]
fn tune_h4_table() {
    tune_one("h4-table", "q1");
}

#[test]
fn tune_seed_b() {
    for j in ["X", "Y", "Z (leg)"] {
        tune_one("seed-b", j);
    }
}

#[test]
fn tune_hexapod_xy() {
    tune_one("hexapod-xy", "leg1");
}

#[test]
fn refusals_name_the_problem() {
    let path = temp("refusals.toml");
    std::fs::write(&path, machine("cartesian-servo")).unwrap();
    let p = path.to_str().unwrap();
    let (ok, _, stderr) = nc_send(&["--sim", "--machine", p, "tune", "Z"]);
    println!("stepper: {stderr}");
    assert!(!ok && stderr.contains("stepper joint") && stderr.contains("(Z)"));
    let (ok, _, stderr) = nc_send(&["--sim", "--machine", p, "tune", "W"]);
    println!("no such joint: {stderr}");
    assert!(!ok && stderr.contains("no joint `W`") && stderr.contains("X, Y, Z"));
    let (ok, _, stderr) = nc_send(&["--sim", "--machine", p, "tune", "X", "--phase-margin", "30"]);
    println!("phase margin: {stderr}");
    assert!(!ok && stderr.contains("--phase-margin 30"));
    assert_eq!(
        std::fs::read_to_string(&path).unwrap(),
        machine("cartesian-servo")
    );
}
