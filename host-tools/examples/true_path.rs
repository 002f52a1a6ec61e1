//! The true contour errors of a simulated run (`calibrate::true_path`), for the figures
//! of docs/tuning.md ("The true contour errors"):
//!
//! ```sh
//! nc-send --sim --machine M.toml --trace T.csv PROGRAM
//! cargo run --release -p pkmc-host --example true_path -- M.toml T.csv
//! ```
//!
//! Prints the maximum and RMS of the path and direction errors (over the run and while
//! the path moves), their maxima per half second, and the ten largest single-tick kicks
//! of the path error (the tick's error less the mean of its neighbours) with how many
//! ticks after the last change of NC line each came.

use pkmc_host::calibrate::true_path::true_errors;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let [_, machine, trace] = &args[..] else {
        eprintln!("usage: true_path MACHINE.toml TRACE.csv");
        std::process::exit(2);
    };
    let config = pkmc_host::machine_file::load(std::path::Path::new(machine))
        .unwrap_or_else(|e| panic!("{machine}: {e}"));
    let text = std::fs::read_to_string(trace).unwrap_or_else(|e| panic!("{trace}: {e}"));
    let errors = true_errors(&config, &text).unwrap_or_else(|e| panic!("{trace}: {e}"));
    let lines: Vec<u32> = text
        .lines()
        .skip(1)
        .map(|l| {
            l.split(',')
                .nth(1)
                .and_then(|v| v.parse().ok())
                .unwrap_or(0)
        })
        .collect();
    let stats = |v: &[f64]| {
        let max = v.iter().copied().fold(0.0, f64::max);
        (
            max,
            (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt(),
        )
    };
    let nm: Vec<f64> = errors.iter().map(|e| e.path_mm * 1e6).collect();
    let udeg: Vec<f64> = errors.iter().map(|e| e.direction_deg * 1e6).collect();
    let moving: Vec<usize> = (0..errors.len()).filter(|&i| errors[i].moving).collect();
    let pick = |v: &[f64]| moving.iter().map(|&i| v[i]).collect::<Vec<_>>();
    for (name, v) in [("path, nm", &nm), ("direction, µ°", &udeg)] {
        let (max, rms) = stats(v);
        let (mmax, mrms) = stats(&pick(v));
        println!("{name}: max {max:.3} RMS {rms:.3}; while moving max {mmax:.3} RMS {mrms:.3}");
    }
    println!("per half second (t from, path max nm, direction max µ°):");
    for chunk in errors.chunks(500) {
        let p = chunk.iter().map(|e| e.path_mm * 1e6).fold(0.0, f64::max);
        let d = chunk
            .iter()
            .map(|e| e.direction_deg * 1e6)
            .fold(0.0, f64::max);
        println!("  {:.3} {p:.1} {d:.3}", chunk[0].t_s);
    }
    let mut kicks: Vec<(f64, usize)> = (1..errors.len().saturating_sub(1))
        .filter(|&i| errors[i - 1].moving && errors[i].moving && errors[i + 1].moving)
        .map(|i| (nm[i] - 0.5 * (nm[i - 1] + nm[i + 1]), i))
        .collect();
    kicks.sort_by(|a, b| b.0.total_cmp(&a.0));
    println!("largest single-tick kicks while moving (t, nm, ticks since the NC line changed):");
    for &(k, i) in kicks.iter().take(10) {
        let since = (1..=i).find(|&d| lines[i - d + 1] != lines[i - d]);
        let since = since.map_or("-".into(), |d| (d - 1).to_string());
        println!("  {:.3} {k:.1} {since}", errors[i].t_s);
    }
}
