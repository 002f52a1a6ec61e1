//! The G-code front end: any text must compile to blocks or to diagnostics, never
//! panic.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        let options = pkmc_host::gcode::Options::default();
        let _ = pkmc_host::gcode::compile(text, "fuzz.ngc", &options);
    }
});
