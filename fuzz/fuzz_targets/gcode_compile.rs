//! The G-code front end: any text must compile to blocks or to diagnostics, never
//! panic (nor hang: libFuzzer's timeout is on).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        // A few tools, so that G43, #5400-#5410 and G10 L1/L10/L11 run on real entries.
        let tools = pkmc_host::gcode::ToolTable::parse("T1 P1 Z12.5 D6\nT2 P2 Z-3 D10\n", "fuzz.tbl")
            .expect("the fuzz target's tool table parses");
        // Loops stop after 1 000 lines beyond the program (the default is 1 000 000):
        // every path of the runaway guard still runs, at a thousandth of the cost of an
        // endless loop under the sanitizers (seconds each, which would leave little
        // time for anything else).
        let options = pkmc_host::gcode::Options {
            tools,
            repeated_lines: 1_000,
            ..pkmc_host::gcode::Options::default()
        };
        let _ = pkmc_host::gcode::compile(text, "fuzz.ngc", &options);
    }
});
