//! The LinuxCNC sample programs in the shared corpus, read in place, each run through
//! `nc-send --check` (parse, interpret, pre-flight and plan without moving) on a large
//! Cartesian machine: each must either pass or be refused only for named unsupported
//! features or for axes that X Y Z machine lacks (`cone.ngc` is for a five-axis
//! machine). Skips, with a note, when the corpus folder is absent.

use std::path::{Path, PathBuf};
use std::process::Command;

fn corpus() -> Option<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/corpus/linuxcnc");
    dir.is_dir().then_some(dir)
}

#[test]
fn every_corpus_program_passes_the_check_or_is_refused_by_name() {
    let Some(dir) = corpus() else {
        eprintln!("note: shared corpus not found; skipping");
        return;
    };
    let machine =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/machines/cartesian-large.toml");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "ngc"))
        .collect();
    files.sort();
    assert!(!files.is_empty());
    let mut passed = 0;
    for f in &files {
        let out = Command::new(env!("CARGO_BIN_EXE_nc-send"))
            .arg("--check")
            .arg("--machine")
            .arg(&machine)
            .arg(f)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        let name = f.file_name().unwrap().to_string_lossy();
        match out.status.code() {
            Some(0) => {
                passed += 1;
                eprintln!("{name}: passes the check");
            }
            Some(2) => {
                let diagnostics: Vec<&str> = err.lines().filter(|l| l.contains(".ngc:")).collect();
                assert!(
                    !diagnostics.is_empty(),
                    "{name}: refused without a diagnostic: {err}"
                );
                for d in &diagnostics {
                    assert!(
                        d.contains("unsupported: ") || d.contains(": the machine has no "),
                        "{name}: refused for something other than an unsupported feature \
                         or a missing axis: {d}"
                    );
                }
                eprintln!("{name}: refused: {}", diagnostics[0]);
            }
            other => panic!("{name}: exit {other:?}: {err}"),
        }
    }
    assert!(passed >= 5, "only {passed} corpus programs pass");
}
