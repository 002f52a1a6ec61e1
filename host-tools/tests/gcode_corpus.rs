//! The LinuxCNC sample programs in the shared corpus (`shared/corpus/linuxcnc`, beside
//! the repository), read in place: each must compile, or be refused only for features
//! named as unsupported (every diagnostic starts with "unsupported: "). Skips, with a
//! note, when the corpus is not there.

use pkmc_host::gcode::{compile, Diagnostic, Options, UNSUPPORTED};
use std::path::PathBuf;

fn corpus() -> Option<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/corpus/linuxcnc");
    dir.is_dir().then_some(dir)
}

/// Compiles one corpus file; `None` when the corpus is absent.
fn run(name: &str) -> Option<Result<usize, Vec<Diagnostic>>> {
    let Some(dir) = corpus() else {
        eprintln!("note: {name}: corpus folder shared/corpus/linuxcnc not found; skipped");
        return None;
    };
    let text = std::fs::read_to_string(dir.join(name)).expect("corpus file readable");
    let result = compile(&text, name, &Options::default()).map(|c| c.len());
    match &result {
        Ok(n) => println!("{name}: {n} canonical commands"),
        Err(e) => println!("{name}: refused ({} diagnostics): {}", e.len(), e[0]),
    }
    Some(result)
}

fn compiles(name: &str) {
    if let Some(result) = run(name) {
        let n = result.unwrap_or_else(|e| {
            let all: Vec<String> = e.iter().map(|d| d.to_string()).collect();
            panic!("{name} should compile:\n{}", all.join("\n"))
        });
        assert!(n > 0, "{name} produced no commands");
    }
}

fn refused_for(name: &str, feature: &str) {
    if let Some(result) = run(name) {
        let errors = result
            .err()
            .unwrap_or_else(|| panic!("{name} should be refused"));
        for d in &errors {
            assert!(
                d.message.starts_with(UNSUPPORTED),
                "{name}: not a refusal by name: {d}"
            );
        }
        assert!(
            errors.iter().any(|d| d.message.contains(feature)),
            "{name}: no refusal mentions {feature}"
        );
    }
}

#[test]
fn three_d_chips_with_named_parameters_compiles() {
    compiles("3D_Chips.ngc");
}

#[test]
fn three_d_test_with_full_circles_in_three_planes_compiles() {
    compiles("3dtest.ngc");
}

#[test]
fn arcspiral_with_radius_arcs_in_inches_compiles() {
    compiles("arcspiral.ngc");
}

#[test]
fn cone_is_refused_only_for_the_w_axis_not_its_subroutines_or_g43_1() {
    refused_for("cone.ngc", "U V W axes");
}

#[test]
fn hole_circle_with_polar_canned_cycles_compiles() {
    compiles("hole-circle.ngc");
}

#[test]
fn polar_with_polar_canned_cycles_compiles() {
    compiles("polar.ngc");
}

#[test]
fn spiral_with_a_repeat_loop_of_polar_moves_compiles() {
    compiles("spiral.ngc");
}

#[test]
fn tort_with_helices_and_a_message_compiles() {
    compiles("tort.ngc");
}

#[test]
fn every_corpus_file_has_a_test_here() {
    let Some(dir) = corpus() else {
        eprintln!("note: corpus folder shared/corpus/linuxcnc not found; skipped");
        return;
    };
    let this = include_str!("gcode_corpus.rs");
    for entry in std::fs::read_dir(dir).unwrap() {
        let name = entry.unwrap().file_name().to_string_lossy().into_owned();
        if name.ends_with(".ngc") {
            assert!(
                this.contains(&format!("\"{name}\"")),
                "corpus file {name} has no test in gcode_corpus.rs"
            );
        }
    }
}

/// LinuxCNC's own interpreter tests for O-words (`shared/corpus/linuxcnc-tests`), read
/// in place; skipped with a note when absent.
fn linuxcnc_test(path: &str) -> Option<String> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/corpus/linuxcnc-tests");
    let file = dir.join(path);
    if !file.is_file() {
        eprintln!("note: {path}: shared/corpus/linuxcnc-tests not found; skipped");
        return None;
    }
    Some(std::fs::read_to_string(file).expect("test program readable"))
}

#[test]
fn linuxcnc_sub_0_restores_the_callers_parameters_after_a_nested_call() {
    let Some(text) = linuxcnc_test("oword/sub.0/test.ngc") else {
        return;
    };
    let commands = compile(&text, "sub.0/test.ngc", &Options::default())
        .unwrap_or_else(|e| panic!("sub.0 should compile: {}", e[0]));
    // Its expected output: STRAIGHT_TRAVERSE(1, 2, 3, …) twice, then the program end.
    let mm = 1_000_000;
    let targets: Vec<[i64; 6]> = commands
        .iter()
        .filter_map(|c| match c {
            pkmc_host::gcode::canon::Canon::Rapid { target, .. } => Some(*target),
            _ => None,
        })
        .collect();
    assert_eq!(targets, vec![[mm, 2 * mm, 3 * mm, 0, 0, 0]; 2]);
    assert!(matches!(
        commands.last(),
        Some(pkmc_host::gcode::canon::Canon::End { .. })
    ));
}

#[test]
fn linuxcnc_m98_m99_basics_is_refused_by_name() {
    let Some(text) = linuxcnc_test("interp/m98m99/01-basics/test.ngc") else {
        return;
    };
    let errors = compile(&text, "01-basics/test.ngc", &Options::default())
        .expect_err("M98/M99 are not supported");
    for d in &errors {
        assert!(
            d.message.starts_with(UNSUPPORTED),
            "not a refusal by name: {d}"
        );
    }
}
