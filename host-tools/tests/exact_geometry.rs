//! Issue 16: no geometry loses position silently. Random arcs (radius 0.01 mm to
//! 10⁹ mm, every plane, helical or not) and random lines on the Cartesian default,
//! each run by `nc-send --check`'s path (compiled by the G-code front end, pre-checked,
//! streamed to the controller core with its simulated drives): each is either refused
//! by name at its `file:line:col` (tiny arcs whose four-decimal end lies off their
//! circle by more than LinuxCNC accepts; nothing else: since issue 34 an arc above
//! `geometry::MAX_ARC_RADIUS_NM` runs as chords), or runs with no drive timing
//! violation, ends with every drive exactly on the programmed end, and every
//! interpolated pose within [`TOLERANCE_MM`] of the exact geometry ([`CHORDS_MM`] for
//! an arc the controller does not run exactly).

use pkmc::config::MachineConfig;
use pkmc::kinematics::{Kinematics, MachineKinematics};
use pkmc_host::job::{self, RunOptions, SimSetup, Target};
use pkmc_host::link::{LinkOptions, NoHooks};
use proptest::prelude::*;

/// How far an interpolated pose may be from the exact path, mm: 10 nm (the stated
/// bound for arcs up to the largest radius is 7 nm; lines are exact to a nanometre);
/// for an arc, beyond the band between its programmed start and end radii (the
/// controller moves the radius linearly between them, as LinuxCNC does).
const TOLERANCE_MM: f64 = 0.000_01;

/// The same for an arc above the controller's exact range, sent as chords: 0.1 µm.
const CHORDS_MM: f64 = 0.000_1;

/// Where every program starts, mm.
const START: [f64; 3] = [0.0, 0.0, -30.0];

fn run(text: &str, name: &str) -> Result<job::RunResult, job::Failure> {
    let dir = std::env::temp_dir().join(format!("pkmc-exact-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join(format!("{name}.ngc"));
    std::fs::write(&path, text).unwrap();
    let machine = MachineConfig::cartesian_xyz();
    let opts = RunOptions {
        target: Target::Sim,
        sim: SimSetup {
            record_path: true,
            ..SimSetup::default()
        },
        link: LinkOptions::default(),
        home: false,
        tools: Default::default(),
        statics: None,
        compress: None,
    };
    job::check(&machine, &path, &opts, &mut NoHooks)
}

/// The drive positions the programmed end `xyz` (mm) calls for.
fn steps_of(xyz: [f64; 3]) -> Vec<i64> {
    let machine = MachineConfig::cartesian_xyz();
    let kin = MachineKinematics::new(&machine);
    let mut pose = [0i64; 6];
    for (p, v) in pose.iter_mut().zip(xyz) {
        *p = (v * 1e6).round() as i64;
    }
    let mut q = [0i64; pkmc::config::MAX_JOINTS];
    kin.inverse(&pose, &mut q).unwrap();
    (0..machine.joints.len())
        .map(|j| machine.joints[j].scale.steps_at(q[j]))
        .collect()
}

/// Checks a finished run: no violation, drives on `end`, every pose of line 3 within
/// `off(pose) ≤ tol` of the path.
fn check_run(
    r: &job::RunResult,
    end: [f64; 3],
    off: impl Fn([f64; 3]) -> f64,
    tol: f64,
) -> Result<(), TestCaseError> {
    let report = &r.report;
    prop_assert_eq!(&report.result, "done", "{:?}", report.alarms);
    prop_assert_eq!(report.drive_violations, Some(0));
    prop_assert_eq!(report.final_joint_steps.clone(), Some(steps_of(end)));
    let sim = r.sim.as_ref().unwrap();
    let mut worst = 0.0f64;
    let mut n = 0;
    for s in sim.recorder.samples.iter().filter(|s| s.line == 3) {
        worst = worst.max(off(s.xyz));
        n += 1;
    }
    prop_assert!(n > 0, "no pose of line 3 was recorded");
    prop_assert!(worst <= tol, "{worst} mm off the path (tolerance {tol} mm)");
    Ok(())
}

/// 4 decimals, as CAM posts write millimetres.
fn mm(v: f64) -> String {
    format!("{v:.4}")
}

proptest! {
    // Random cases locally; in CI (`CI` set) a fixed seed, so that a landing does not
    // depend on luck (the cases found by random runs are kept as tests of their own).
    #![proptest_config(ProptestConfig {
        cases: 64,
        rng_seed: if std::env::var_os("CI").is_some() {
            proptest::test_runner::RngSeed::Fixed(0x16)
        } else {
            proptest::test_runner::RngSeed::Random
        },
        ..ProptestConfig::default()
    })]

    #[test]
    fn every_arc_is_refused_by_name_or_runs_exactly(
        log_r in -2.0f64..9.0, a0 in 0.0f64..360.0, sweep in 1.0f64..360.0,
        helix in prop_oneof![Just(0.0), -8.0f64..8.0], cw in any::<bool>(), plane in 0usize..3,
    ) {
        let r = 10f64.powf(log_r);
        // Arcs stay within 40 mm of the start (the machine's travel).
        let sweep = sweep.min((40.0 / r).to_degrees());
        let (g, (i, j, k)) = [("G17", (0, 1, 2)), ("G18", (2, 0, 1)), ("G19", (1, 2, 0))][plane];
        let a1 = if cw { a0 - sweep } else { a0 + sweep };
        let c = [START[i] - r * a0.to_radians().cos(), START[j] - r * a0.to_radians().sin()];
        let mut end = START;
        end[i] = c[0] + r * a1.to_radians().cos();
        end[j] = c[1] + r * a1.to_radians().sin();
        end[k] += helix;
        // What the program says, rounded as written.
        let end: [f64; 3] = end.map(|v| mm(v).parse().unwrap());
        let offsets = ["I", "J", "K"];
        let text = format!(
            "G21 G90 {g}\nG0 X{} Y{} Z{}\n{} X{} Y{} Z{} {}{} {}{} F3000\nM2\n",
            START[0], START[1], START[2],
            if cw { "G2" } else { "G3" },
            mm(end[0]), mm(end[1]), mm(end[2]),
            offsets[i], mm(c[0] - START[i]), offsets[j], mm(c[1] - START[j]),
        );
        let written = [
            START[i] + mm(c[0] - START[i]).parse::<f64>().unwrap(),
            START[j] + mm(c[1] - START[j]).parse::<f64>().unwrap(),
        ];
        let r0 = (START[i] - written[0]).hypot(START[j] - written[1]);
        let r1 = (end[i] - written[0]).hypot(end[j] - written[1]);
        match run(&text, "arc") {
            Err(f) => {
                // Refused only by name: (tiny arcs written to four decimals) an end off
                // its circle by more than LinuxCNC accepts.
                let off = (r1 - r0).abs();
                let off_circle = off > 0.028_284 || off / r0.max(r1) > 0.001;
                prop_assert!(off_circle, "refused with radius {r0} mm: {}", f.message);
                prop_assert!(f.message.contains("arc.ngc:3:"), "{}", f.message);
                prop_assert!(f.message.contains("radius"), "{}", f.message);
            }
            Ok(res) => {
                let tol = if r0 * 1e6 <= pkmc::motion::geometry::MAX_ARC_RADIUS_NM as f64 + 1.0 {
                    TOLERANCE_MM
                } else {
                    CHORDS_MM
                };
                let off = |p: [f64; 3]| {
                    let d = (p[i] - written[0]).hypot(p[j] - written[1]);
                    // Between the two radii (the controller's spiral), else how far out.
                    (d - r0.max(r1)).max(r0.min(r1) - d).max(0.0)
                };
                check_run(&res, end, off, tol)?;
            }
        }
    }

    #[test]
    fn every_line_runs_exactly(
        x in -60.0f64..60.0, y in -60.0f64..60.0, z in -70.0f64..10.0, rapid in any::<bool>(),
    ) {
        let end: [f64; 3] = [x, y, z].map(|v| mm(v).parse().unwrap());
        let text = format!(
            "G21 G90\nG0 X{} Y{} Z{}\n{} X{} Y{} Z{} F3000\nM2\n",
            START[0], START[1], START[2], if rapid { "G0" } else { "G1" },
            mm(end[0]), mm(end[1]), mm(end[2]),
        );
        let res = run(&text, "line").map_err(|f| TestCaseError::fail(f.message))?;
        let d: Vec<f64> = (0..3).map(|a| end[a] - START[a]).collect();
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let off = |p: [f64; 3]| {
            let v: Vec<f64> = (0..3).map(|a| p[a] - START[a]).collect();
            let t = ((v[0] * d[0] + v[1] * d[1] + v[2] * d[2]) / (len * len)).clamp(0.0, 1.0);
            (0..3).map(|a| (v[a] - t * d[a]).powi(2)).sum::<f64>().sqrt()
        };
        check_run(&res, end, off, TOLERANCE_MM)?;
    }
}
