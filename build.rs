//! Build script: link setup for the MCU firmware.
//!
//! For `target_os = "none"` (the STM32G474 build) it puts the repository root, where
//! `memory.x` lives, on the linker search path and passes the cortex-m-rt (`link.x`)
//! and defmt (`defmt.x`) linker scripts plus `--nmagic` to the binaries. For the host
//! (`cargo test`, the simulator, the firmware's host-side launcher) it emits nothing
//! but its `rerun-if-changed` lines.

use std::env;

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-changed=memory.x");
    if env::var("CARGO_CFG_TARGET_OS").as_deref() != Ok("none") {
        return;
    }
    let root = env::var("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR");
    println!("cargo:rustc-link-search={root}");
    println!("cargo:rustc-link-arg-bins=--nmagic");
    println!("cargo:rustc-link-arg-bins=-Tlink.x");
    println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
}
