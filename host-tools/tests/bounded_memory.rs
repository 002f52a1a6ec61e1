//! A program run a piece at a time (issue 33, bounded memory) keeps the memory of its
//! look-ahead, not of its length: `nc-send --check` of a zig-zag of short moves
//! peaks at about the same resident size for 100 k lines as for 400 k, where the
//! program compiled whole grows by more than a kilobyte a line. The two-pass path is
//! asked for below its size threshold with `PKMC_STREAM_ABOVE_BYTES`.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;

/// A zig-zag of `n` lines of 0.02 mm moves over a 10 mm field (kept short, so the
/// simulated run is quick).
fn zigzag(path: &Path, n: usize) {
    let mut f = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    writeln!(f, "G21 G90 G64 P0.01\nG0 X0 Y0 Z5\nG1 Z0 F6000").unwrap();
    let (mut x, mut y, mut d) = (0i64, 0i64, 1i64);
    for _ in 3..n - 1 {
        x += 20 * d;
        if !(0..=10_000).contains(&x) {
            x -= 20 * d;
            d = -d;
            y = (y + 50) % 10_000;
        }
        writeln!(
            f,
            "G1 X{}.{:03} Y{}.{:03}",
            x / 1000,
            x % 1000,
            y / 1000,
            y % 1000
        )
        .unwrap();
    }
    writeln!(f, "M2").unwrap();
}

/// Peak resident size of `nc-send --check` of `program` (kB), and its report.
fn peak_kb(program: &Path, stream: bool) -> (i64, String) {
    let machine =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/machines/cartesian-xyz.toml");
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_nc-send"));
    cmd.arg("--machine")
        .arg(&machine)
        .arg(program)
        .args(["--check", "--no-compress", "--report", "json"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null());
    if stream {
        cmd.env("PKMC_STREAM_ABOVE_BYTES", "0");
    } else {
        cmd.env("PKMC_STREAM_ABOVE_BYTES", "100000000000");
    }
    // Reaped below by wait4, which gives its resource usage.
    #[allow(clippy::zombie_processes)]
    let mut child = cmd.spawn().unwrap();
    let mut out = String::new();
    std::io::Read::read_to_string(child.stdout.as_mut().unwrap(), &mut out).unwrap();
    // The child's own peak, from the kernel's account when it is reaped.
    let mut status = 0;
    // SAFETY: an all-zero rusage is a valid value; wait4 writes it for our child.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: waits for the child this test spawned, with valid pointers.
    let pid = unsafe { libc::wait4(child.id() as i32, &mut status, 0, &mut usage) };
    assert_eq!(pid, child.id() as i32);
    assert!(
        libc::WIFEXITED(status) && libc::WEXITSTATUS(status) == 0,
        "{out}"
    );
    (usage.ru_maxrss, out)
}

fn field(report: &str, name: &str) -> serde_json::Value {
    let v: serde_json::Value = serde_json::from_str(report).unwrap();
    v[name].clone()
}

#[test]
fn peak_memory_of_a_program_run_in_pieces_does_not_grow_with_its_length() {
    let dir: PathBuf = std::env::temp_dir().join(format!("pkmc-memory-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (short, long) = (dir.join("100k.ngc"), dir.join("400k.ngc"));
    zigzag(&short, 100_000);
    zigzag(&long, 400_000);
    let (short_kb, _) = peak_kb(&short, true);
    let (long_kb, streamed) = peak_kb(&long, true);
    let (whole_kb, whole) = peak_kb(&long, false);
    eprintln!(
        "peak RSS: 100 k lines {short_kb} kB, 400 k lines {long_kb} kB (whole: {whole_kb} kB)"
    );
    // Four times the lines, at most a sixth more memory (the whole program: far more).
    assert!(
        long_kb < short_kb + short_kb / 6,
        "{short_kb} kB vs {long_kb} kB"
    );
    assert!(
        whole_kb > long_kb + 100_000,
        "{whole_kb} kB whole vs {long_kb} kB"
    );
    // The same run either way.
    for name in [
        "run_time_s",
        "blocks_sent",
        "blocks_executed",
        "final_joint_steps",
    ] {
        assert_eq!(field(&streamed, name), field(&whole, name), "{name}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
