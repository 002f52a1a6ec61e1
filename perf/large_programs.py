#!/usr/bin/env python3
"""Large programs over a port, with peak memory (issue 33).

    python3 perf/large_programs.py [--lines N ...] [--keep DIR]

For each N (default 2 000 000 and 10 000 000) it writes a zig-zag of N lines of
0.2 mm `G1` moves at F3000 (`G64 P0.01`, rows of 100 mm, 0.1 mm zig) for
`examples/machines/cartesian-large.toml`, then

- `nc-send --check` of it, and
- a run over a port: `pkmc-sim` in its own process (as fast as it can run, not real
  time), `nc-send --port PTY` with the default `--link-timeout`,

each under `/usr/bin/time -v`, and prints a table: result, blocks executed, motion
time, peak RSS of nc-send and wall time. It uses the release builds
(`cargo build --release -p pkmc-host`); a run of 10 M lines takes about ten minutes
on two cores.
"""

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MACHINE = os.path.join(ROOT, "examples/machines/cartesian-large.toml")
NC = os.path.join(ROOT, "target/release/nc-send")
SIM = os.path.join(ROOT, "target/release/pkmc-sim")


def write_program(path, lines):
    """The zig-zag of `lines` lines (the three set-up lines, the moves, the two closing ones)."""
    with open(path, "w") as f:
        f.write("G21 G90 G64 P0.01\nG0 X0 Y0 Z5\nG1 Z0 F3000\n")
        n, row, buf = 0, 0, []
        while n < lines - 5:
            y = (row % 200) * 0.5
            for k in range(min(500, lines - 5 - n)):
                x = (k if row % 2 == 0 else 499 - k) * 0.2
                buf.append(f"G1 X{x:.1f} Y{y + (0.1 if k % 2 else 0.0):.1f}\n")
            n += 500
            row += 1
            if len(buf) > 200_000:
                f.write("".join(buf))
                buf = []
        f.write("".join(buf))
        f.write("G0 Z5\nM2\n")


def timed(args):
    """Runs `args` under /usr/bin/time -v: (exit code, stdout, peak RSS MB, wall s)."""
    r = subprocess.run(["/usr/bin/time", "-v"] + args, capture_output=True, text=True)
    rss = re.search(r"Maximum resident set size \(kbytes\): (\d+)", r.stderr)
    wall = re.search(r"Elapsed \(wall clock\) time \(h:mm:ss or m:ss\): ([\d:.]+)", r.stderr)
    secs = 0.0
    for part in wall.group(1).split(":") if wall else []:
        secs = secs * 60 + float(part)
    if r.returncode != 0:
        print(r.stderr[-3000:], file=sys.stderr)
    return r.returncode, r.stdout, int(rss.group(1)) / 1024 if rss else float("nan"), secs


def row(lines, what, code, out, rss, wall):
    try:
        rep = json.loads(out)
    except json.JSONDecodeError:
        rep = {}
    print(f"| {lines:,} | {what} | {code} {rep.get('result', '?')} | {rep.get('blocks_executed', '?'):,} | "
          f"{rep.get('run_time_s', float('nan')):.1f} | {rss:.0f} | {wall:.0f} |", flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--lines", type=int, nargs="*", default=[2_000_000, 10_000_000])
    ap.add_argument("--keep", help="write the programs here and keep them")
    o = ap.parse_args()
    for exe in (NC, SIM):
        if not os.path.exists(exe):
            sys.exit(f"{exe} not found: cargo build --release -p pkmc-host")
    tmp = o.keep or tempfile.mkdtemp()
    print("| lines | what | exit, result | blocks executed | motion s | nc-send peak RSS MB | wall s |")
    print("|---|---|---|---|---|---|---|")
    for lines in o.lines:
        program = os.path.join(tmp, f"zigzag-{lines}.ngc")
        write_program(program, lines)
        row(lines, "`--check`", *timed([NC, "--machine", MACHINE, "--check", "--report", "json", program]))
        sim = subprocess.Popen([SIM, "--machine", MACHINE], stdout=subprocess.PIPE, text=True)
        try:
            port = sim.stdout.readline().strip()
            subprocess.run([NC, "--port", port, "--machine", MACHINE, "reset"], check=True,
                           capture_output=True)
            row(lines, "run over a port", *timed([NC, "--port", port, "--machine", MACHINE,
                                                  "--report", "json", program]))
        finally:
            sim.kill()
            sim.wait()
        if not o.keep:
            os.remove(program)


if __name__ == "__main__":
    main()
