//! The `seed-b` machine file: the report's transfer functions, and feed-forward gains
//! that are the models' low-frequency inverses.

use pkmc::config::{ContourMode, Drive};
use pkmc_host::contour_study::{StudyMachine, SEED_B};
use pkmc_host::machine_file::{parse, MachineFile};

#[test]
fn the_seed_b_machine_loads_with_ccpm_and_three_servo_plants() {
    let m = parse(SEED_B, "seed-b.toml").unwrap();
    assert_eq!(m.servo.contour.mode, ContourMode::Ccpm);
    let servos = m
        .joints
        .iter()
        .filter(|j| matches!(j.drive, Drive::Servo { .. }))
        .count();
    assert_eq!(servos, 3);
}

#[test]
fn each_axis_feed_forward_is_its_model_s_inverse_at_low_frequency() {
    let file: MachineFile = toml::from_str(SEED_B).unwrap();
    let m = StudyMachine::new(&file).unwrap();
    for axis in 0..3 {
        let c = m.model(axis).unwrap().inverse_series();
        let g = &m.config.servo.gains[axis];
        // Gains per count at 1000 counts/mm.
        let (kvff, kaff) = (g.kvff as f64 * 1000.0, g.kaff as f64 * 1000.0);
        assert!(
            (kvff / c[1] - 1.0).abs() < 1e-4,
            "axis {axis}: {kvff} vs {}",
            c[1]
        );
        assert!(
            (kaff / c[2] - 1.0).abs() < 1e-3,
            "axis {axis}: {kaff} vs {}",
            c[2]
        );
    }
}

#[test]
fn an_unknown_contour_mode_is_refused_with_its_field() {
    let text = SEED_B.replace("mode = \"ccpm\"", "mode = \"ccc\"");
    let e = parse(&text, "m.toml").unwrap_err().to_string();
    assert!(e.contains("contour.mode"), "{e}");
}
