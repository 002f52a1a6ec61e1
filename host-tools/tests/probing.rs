//! Issue 36: probing (G38.2–G38.5) through `nc-send --check`'s path: the program is
//! compiled a stage at a time, each probing move runs on the controller core as
//! `Control::Probe` against the simulator's probe model (a sphere or a plane), and
//! the latched joints come back through the machine's forward kinematics into
//! #5061–#5070 and the report.

use pkmc::config::MachineConfig;
use pkmc_host::job::{self, RunOptions, SimSetup, Target};
use pkmc_host::link::{LinkOptions, NoHooks};
use pkmc_host::sim::probe::{ProbeModel, Target as Surface};
use std::path::PathBuf;

fn file(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../examples/machines")
        .join(format!("{name}.toml"))
}

fn machine(name: &str) -> MachineConfig {
    pkmc_host::machine_file::load(&file(name)).unwrap()
}

fn run(
    m: &MachineConfig,
    text: &str,
    name: &str,
    model: ProbeModel,
) -> Result<job::RunResult, job::Failure> {
    let dir = std::env::temp_dir().join(format!("pkmc-probing-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join(format!("{name}.ngc"));
    std::fs::write(&path, text).unwrap();
    // The servo joints' plants from the machine file, as nc-send takes them.
    let plants = MACHINES
        .iter()
        .find(|(n, ..)| machine(n).name == m.name)
        .map(|(n, ..)| pkmc_host::machine_file::load_plants(&file(n)).unwrap())
        .unwrap_or_default();
    let opts = RunOptions {
        target: Target::Sim,
        sim: SimSetup {
            plants,
            probe: Some(model),
            ..SimSetup::default()
        },
        link: LinkOptions::default(),
        home: false,
        tools: Default::default(),
        statics: None,
        compress: None,
    };
    job::check(m, &path, &opts, &mut NoHooks)
}

fn sphere(centre: [f64; 3], radius: f64, noise_um: f64, seed: u64) -> ProbeModel {
    ProbeModel {
        targets: vec![Surface::Sphere { centre, radius }],
        noise_mm: noise_um / 1000.0,
        delay_us: 20.0,
        seed,
    }
}

/// A program touching a sphere at `centre` of `radius` from `dirs` (unit vectors
/// from the centre): a rapid to 4 mm outside, a G38.2 to 3 mm inside, back out; then
/// prints nothing, but keeps each probed point in #1000 + 3k … (checked by the
/// report).
fn touches(centre: [f64; 3], radius: f64, feed: f64, dirs: &[[f64; 3]]) -> String {
    let mut t = String::from("G21 G90\n");
    for u in dirs {
        let n = (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt();
        let at = |d: f64| -> [f64; 3] { std::array::from_fn(|i| centre[i] + u[i] / n * d) };
        let (s, e) = (at(radius + 4.0), at(radius - 3.0));
        t += &format!("G0 X{:.4} Y{:.4} Z{:.4}\n", s[0], s[1], s[2]);
        t += &format!("G38.2 X{:.4} Y{:.4} Z{:.4} F{feed}\n", e[0], e[1], e[2]);
        t += &format!("G0 X{:.4} Y{:.4} Z{:.4}\n", s[0], s[1], s[2]);
    }
    t + "M2\n"
}

const DIRS: [[f64; 3]; 5] = [
    [0.0, 0.0, 1.0],
    [1.0, 0.0, 1.0],
    [0.0, -1.0, 1.0],
    [-1.0, 1.0, 2.0],
    [1.0, 1.0, 0.3],
];

/// Each machine, a sphere within its reach, and its actuators' resolution, mm (a
/// probed point can be no better than the position the actuators report).
const MACHINES: [(&str, [f64; 3], f64); 4] = [
    ("cartesian-servo", [0.0, 0.0, -20.0], 0.001),
    ("h4-table", [0.0, 0.0, -96.0], 0.001),
    ("hexapod", [0.0, 0.0, 435.0], 0.0025),
    ("hexapod-xy", [0.0, 0.0, 260.0], 0.001),
];

#[test]
fn g38_2_latches_a_point_on_the_sphere_within_1_um_plus_the_noise_up_to_300_mm_min() {
    let noise_um = 0.5;
    for (name, centre, resolution) in MACHINES {
        let m = machine(name);
        for feed in [60.0, 300.0] {
            let text = touches(centre, 6.0, feed, &DIRS);
            let r = run(&m, &text, name, sphere(centre, 6.0, noise_um, 7))
                .unwrap_or_else(|f| panic!("{name} F{feed}: {}", f.message));
            let why = (&r.report.alarm_cause, r.report.alarm_line);
            assert_eq!(r.report.result, "done", "{name} F{feed}: {why:?}");
            assert_eq!(r.report.probes.len(), DIRS.len(), "{name}");
            // 1 µm (or the actuators' resolution, where coarser) plus 4 σ of noise.
            let bound = 0.001f64.max(resolution) + 4.0 * noise_um / 1000.0;
            let mut worst = 0.0f64;
            for p in &r.report.probes {
                assert!(p.contact, "{name}: {p:?}");
                let d = (0..3)
                    .map(|i| (p.position[i] - centre[i]).powi(2))
                    .sum::<f64>();
                let off = d.sqrt() - 6.0;
                assert!(
                    off.abs() <= bound,
                    "{name} F{feed}: probed {:?}, {:.2} µm off the sphere (bound {:.2})",
                    p.position,
                    off * 1000.0,
                    bound * 1000.0
                );
                // It stopped past the surface, within the probe's stopping distance.
                let s = (0..3)
                    .map(|i| (p.stopped[i] - centre[i]).powi(2))
                    .sum::<f64>();
                let past = 6.0 - s.sqrt();
                assert!(
                    past > 0.0 && past < 0.2,
                    "{name} F{feed}: stopped {past} mm in"
                );
                worst = worst.max(off.abs());
            }
            println!(
                "| {name} | {feed} | {} | {:.2} | {:.2} |",
                r.report.probes.len(),
                worst * 1000.0,
                bound * 1000.0
            );
        }
    }
}

fn plane_model(z: f64) -> ProbeModel {
    ProbeModel {
        targets: vec![Surface::Plane { z }],
        noise_mm: 0.0,
        delay_us: 0.0,
        seed: 1,
    }
}

/// Runs `text` on the Cartesian default with a plane at Z −3.25.
fn on_plane(text: &str, name: &str) -> Result<job::RunResult, job::Failure> {
    run(
        &MachineConfig::cartesian_xyz(),
        text,
        name,
        plane_model(-3.25),
    )
}

#[test]
fn the_probed_position_lands_in_5061_to_5070_in_program_coordinates_and_units() {
    // G55 shifted by Z −1, in inches: #5063 is the plane's height in G55 inches; the
    // next move goes 0.1 in above it, which the final pose shows.
    let text = "G21 G10 L2 P2 X0 Y0 Z-1\nG55 G20 G90\nG0 X0.5 Y0.5 Z0.1\n\
                G38.2 Z-1 F10\nG0 Z[#5063 + 0.1]\nG0 X[#5061] Y[#5062 + #5070]\nM2\n";
    let r = on_plane(text, "params").unwrap_or_else(|f| panic!("{}", f.message));
    assert_eq!(r.report.result, "done");
    let z = r.report.final_pose["z"];
    assert!((z - (-3.25 + 2.54)).abs() < 0.0011, "final Z {z}");
    assert!((r.report.final_pose["x"] - 12.7).abs() < 1e-6);
    assert!(
        (r.report.final_pose["y"] - 12.7 - 25.4).abs() < 1e-6,
        "#5070 = 1"
    );
}

#[test]
fn g38_3_without_contact_goes_on_with_5070_at_0_and_g38_2_without_contact_stops() {
    let text = "G21 G90\nG0 Z5\nG38.3 Z0 F300\nG0 X[10 + #5070] Z[#5063]\nM2\n";
    let r = on_plane(text, "miss3").unwrap_or_else(|f| panic!("{}", f.message));
    assert_eq!(r.report.result, "done");
    assert!(!r.report.probes[0].contact);
    assert!((r.report.final_pose["x"] - 10.0).abs() < 1e-6, "#5070 = 0");
    assert!(
        r.report.final_pose["z"].abs() < 1e-6,
        "#5063: the move's end"
    );
    let text = "G21 G90\nG0 Z5\nG38.2 Z0 F300\nG0 X10\nM2\n";
    let f = on_plane(text, "miss2")
        .err()
        .expect("G38.2 without contact fails");
    assert!(
        f.message
            .contains("miss2.ngc:3:1: G38.2: the move ended without contact"),
        "{}",
        f.message
    );
}

#[test]
fn g38_4_and_g38_5_stop_where_contact_is_lost() {
    // Down into contact, then up until it is lost.
    let text = "G21 G90\nG0 Z5\nG38.2 Z-5 F300\nG38.4 Z0 F60\nG0 Z[#5063 + 1]\nM2\n";
    let r = on_plane(text, "release").unwrap_or_else(|f| panic!("{}", f.message));
    assert_eq!(r.report.result, "done");
    let lost = &r.report.probes[1];
    assert_eq!((lost.code, lost.contact), ("G38.4", true));
    assert!(
        (lost.position[2] + 3.25).abs() < 0.0026,
        "{:?}",
        lost.position
    );
    // G38.5 that never loses contact: no error, #5070 = 0.
    let text = "G21 G90\nG0 Z5\nG38.2 Z-5 F300\nG38.5 Z-3.6 F60\nG0 X[#5070]\nM2\n";
    let r = on_plane(text, "release5").unwrap_or_else(|f| panic!("{}", f.message));
    assert_eq!(r.report.result, "done");
    assert!(!r.report.probes[1].contact);
    // G38.4 that never loses contact is an error at its line.
    let text = "G21 G90\nG0 Z5\nG38.2 Z-5 F300\nG38.4 Z-3.6 F60\nM2\n";
    let f = on_plane(text, "release4")
        .err()
        .expect("G38.4 must lose contact");
    assert!(
        f.message.contains("release4.ngc:4:1: G38.4"),
        "{}",
        f.message
    );
}

#[test]
fn a_probe_already_in_the_sought_state_is_an_alarm_and_the_move_does_not_run() {
    // Below the plane: touching from the start.
    let text = "G21 G90\nG0 Z-4\nG38.2 Z-6 F300\nM2\n";
    let r = on_plane(text, "tripped").unwrap_or_else(|f| panic!("{}", f.message));
    assert_eq!(r.report.result, "alarm");
    assert_eq!(r.report.alarm_cause.as_deref(), Some("ProbeAtStart"));
    assert!((r.report.final_pose["z"] + 4.0).abs() < 1e-6);
    // Above it, G38.4 (which needs contact) is the same alarm.
    let text = "G21 G90\nG0 Z2\nG38.4 Z4 F300\nM2\n";
    let r = on_plane(text, "clear").unwrap_or_else(|f| panic!("{}", f.message));
    assert_eq!(r.report.alarm_cause.as_deref(), Some("ProbeAtStart"));
}

#[test]
fn probing_moves_are_refused_where_they_cannot_run_and_when_malformed() {
    let m = MachineConfig::cartesian_xyz();
    let bad = [
        (
            "G21 G90\nG93 G38.2 Z-5 F1\nM2\n",
            "2:5: G38.2 cannot be used with inverse-time",
        ),
        (
            "G21 G90\nG38.2 Z0 F100\nM2\n",
            "2:1: G38.2: the move goes nowhere",
        ),
        ("G21 G90\nG38.2 Z-5\nM2\n", "2:1:"),
        (
            "G21 G90 G41.1 D2\nG38.2 Z-5 F100\nM2\n",
            "2:1: G38.2 cannot be used with cutter",
        ),
    ];
    for (k, (text, want)) in bad.iter().enumerate() {
        let f = run(&m, text, &format!("bad{k}"), plane_model(-3.25))
            .err()
            .unwrap_or_else(|| panic!("{text} must be refused"));
        assert!(f.message.contains(want), "{text}: {}", f.message);
    }
    // The H-4's table is an A axis.
    let h4 = machine("h4-table");
    let f = run(
        &h4,
        "G21 G90\nG38.3 A5 F100\nM2\n",
        "rotary",
        plane_model(-200.0),
    );
    let f = f.err().expect("refused");
    assert!(
        f.message.contains("2:1: G38.3 cannot move the rotary axes"),
        "{}",
        f.message
    );
    // An MDI line (the front end without a probing run) refuses it by name.
    let e = job::compile_text("G38.2 Z-5 F100", "MDI", &m, m.home).expect_err("refused");
    assert!(
        e.message
            .contains("MDI:1:1: unsupported: G38.2 probing here"),
        "{}",
        e.message
    );
}
