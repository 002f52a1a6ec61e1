//! Build script: which outside programs the tests can use.
//!
//! The operator station's tests drive a real Chromium through chromedriver, and the
//! senders' tests run CNCjs (npm, in `tests/senders`) and grbl-streamer (PyPI), and the
//! G-code oracle test runs LinuxCNC's interpreter `rs274` (Debian: linuxcnc-uspace). Where
//! one is missing, this script sets a `cfg` that marks its tests `#[ignore]` with the
//! reason, so `cargo test`'s own summary counts them as ignored and says why (run
//! `cargo test -- --ignored` to see them fail for want of it). Under CI (`CI` set)
//! every one must be there: the build stops, naming what is missing.
//!
//! The script runs again when `PATH` or `CI` changes, when a program it found
//! changes, or when the place a missing one would be installed to changes.

use std::path::{Path, PathBuf};
use std::process::Command;

/// `name` in a directory of `PATH`.
fn on_path(name: &str) -> Option<PathBuf> {
    let paths = std::env::var_os("PATH")?;
    std::env::split_paths(&paths)
        .map(|d| d.join(name))
        .find(|p| p.is_file())
}

/// The directories of `PATH` that exist (a missing one would make Cargo run this
/// script on every build).
fn path_dirs() -> Vec<PathBuf> {
    std::env::var_os("PATH")
        .map(|p| std::env::split_paths(&p).filter(|d| d.is_dir()).collect())
        .unwrap_or_default()
}

fn watch(p: &Path) {
    println!("cargo::rerun-if-changed={}", p.display());
}

/// Python's answer to `code`, trimmed; `None` if it failed.
fn python(code: &str) -> Option<String> {
    let out = Command::new("python3").args(["-c", code]).output().ok()?;
    out.status
        .success()
        .then(|| String::from_utf8_lossy(&out.stdout).trim().to_string())
}

fn main() {
    for cfg in [
        "pkmc_no_browser",
        "pkmc_no_cncjs",
        "pkmc_no_grbl_streamer",
        "pkmc_no_rs274",
    ] {
        println!("cargo::rustc-check-cfg=cfg({cfg})");
    }
    watch(Path::new("build.rs"));
    println!("cargo::rerun-if-env-changed=PATH");
    println!("cargo::rerun-if-env-changed=CI");
    let mut missing = Vec::new();

    let chromium = on_path("chromium").or_else(|| on_path("chromium-browser"));
    match (chromium, on_path("chromedriver")) {
        (Some(c), Some(d)) => {
            watch(&c);
            watch(&d);
        }
        _ => {
            path_dirs().iter().for_each(|d| watch(d));
            println!("cargo::rustc-cfg=pkmc_no_browser");
            missing.push("Chromium and chromedriver (Debian: chromium, chromium-driver)");
        }
    }

    let senders = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/senders");
    let cncjs = senders.join("node_modules/cncjs/package.json");
    if cncjs.is_file() {
        watch(&cncjs);
    } else {
        watch(&senders);
        println!("cargo::rustc-cfg=pkmc_no_cncjs");
        missing.push("CNCjs (npm ci in tests/senders)");
    }

    let streamer = "import grbl_streamer, os; print(os.path.dirname(grbl_streamer.__file__))";
    match python(streamer) {
        Some(dir) if Path::new(&dir).is_dir() => watch(Path::new(&dir)),
        _ => {
            let site = "import sysconfig; print(sysconfig.get_paths()['purelib'])";
            if let Some(dir) = python(site).filter(|d| Path::new(d).is_dir()) {
                watch(Path::new(&dir));
            }
            println!("cargo::rustc-cfg=pkmc_no_grbl_streamer");
            missing.push("grbl-streamer (pip install -r tests/senders/requirements.txt)");
        }
    }

    match on_path("rs274") {
        Some(p) => watch(&p),
        None => {
            path_dirs().iter().for_each(|d| watch(d));
            println!("cargo::rustc-cfg=pkmc_no_rs274");
            missing.push("LinuxCNC's rs274 (Debian: linuxcnc-uspace)");
        }
    }

    if std::env::var_os("CI").is_some() && !missing.is_empty() {
        panic!(
            "CI runs every test, and these are missing: {} (.ci/run installs them)",
            missing.join("; ")
        );
    }
}
