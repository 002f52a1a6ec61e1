#!/usr/bin/env python3
"""Dense curves at F6000 through the real link: how close the path speed stays to the
feed in the steady middle of each curve (issue 34, "Dense curves at F6000").

    python3 perf/dense_curves.py [--nc-send PATH] [--only TEXT ...]

For each machine (the built-in cartesian-xyz, and the H-4 with its table,
examples/machines/h4-table.toml), each curve (a sine y = 10 sin(x/15) over 120 mm of
X, a circle of radius 20 mm, an Archimedean spiral from radius 5 to 25 mm over four
turns), each chord (0.01, 0.05 and 0.1 mm) and each path mode (G64 with
`--g64-tolerance 0`, every chord a block as programmed; G64, its chords merged within
nc-send's default 1 µm; and G64 P0.01), it streams the program to the built-in
simulated controller (`nc-send --sim --trace`, the real serial link) and reads the commanded tool position every 1 ms tick. The
steady middle is the feed moves less the first and last 10 % of their ticks (the
acceleration from rest and the stop). It prints, per run: the motion time, the path
speed over the feed in the steady middle (minimum, median, mean) and the share of its
ticks at 0.95 of the feed or more; and what curvature allows: the feed is within
reach of the axes' acceleration where v²/r ≤ a, and within the planner's share of it
for a bend (a half on lines, docs/performance.md) where v²/r ≤ a/2, r the curve's
smallest radius.

It is a benchmark, not a test: it asserts nothing. It takes a few minutes (the
simulator runs the ticks in real time while it streams).
"""
import argparse
import csv
import math
import os
import statistics
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FEED = 6000.0  # mm/min

# (name, nc-send machine arguments, the tool's Z, the axes' acceleration mm/s^2)
MACHINES = [
    ("cartesian-xyz", [], 0.0, 1000.0),
    ("h4-table", ["--machine", os.path.join(ROOT, "examples", "machines", "h4-table.toml")], -80.0, 2000.0),
]


def points(kind, step):
    """The curve's points, `step` mm apart along it, and its smallest radius, mm."""
    pts = []
    if kind == "sine":
        x = -60.0
        while x < 60.0:
            pts.append((x, 10 * math.sin(x / 15)))
            x += step / math.sqrt(1 + (10 / 15 * math.cos(x / 15)) ** 2)
        return pts, 15 * 15 / 10  # at a crest: 1/|y''| = 22.5 mm
    if kind == "circle":
        r = 20.0
        n = int(2 * math.pi * r / step)
        return [(r * math.cos(2 * math.pi * k / n), r * math.sin(2 * math.pi * k / n))
                for k in range(n + 1)], r
    th = 0.0
    pitch = 20 / (8 * math.pi)
    while True:
        r = 5 + pitch * th
        if r > 25:
            break
        pts.append((r * math.cos(th), r * math.sin(th)))
        th += step / math.hypot(r, pitch)
    return pts, 5.0


def program(pts, z, mode):
    text = [f"G21 G90 G17 {mode}", f"G0 X{pts[0][0]:.4f} Y{pts[0][1]:.4f} Z{z:.4f}",
            f"F{FEED:.0f}"]
    text += [f"G1 X{x:.4f} Y{y:.4f}" for x, y in pts[1:]]
    return "\n".join(text + ["M2"]) + "\n"


def steady(trace, first_feed_line):
    """Path speed (mm/s) of each tick of the feed moves' steady middle, and the motion
    time of the feed moves, s."""
    rows = []
    with open(trace) as f:
        for r in csv.DictReader(f):
            rows.append((float(r["t_s"]), int(r["line"]), float(r["x"]), float(r["y"]),
                         float(r["z"])))
    speeds = []
    for a, b in zip(rows, rows[1:]):
        if b[1] >= first_feed_line:
            speeds.append(math.dist(a[2:], b[2:]) / (b[0] - a[0]))
    # From the first tick that moves to the last (the trace goes on while the link
    # reports the end).
    on = [k for k, v in enumerate(speeds) if v > 0]
    speeds = speeds[on[0]:on[-1] + 1] if on else []
    n = len(speeds)
    return speeds[n // 10: n - n // 10], n * 1e-3


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--nc-send", default=os.path.join(ROOT, "target", "release", "nc-send"))
    ap.add_argument("--only", nargs="*", help="run only the rows whose name contains one of these")
    args = ap.parse_args()
    if not os.path.exists(args.nc_send):
        sys.exit(f"{args.nc_send}: no such nc-send (build it: cargo build --release -p pkmc-host --bin nc-send)")
    feed = FEED / 60.0
    print(f"F{FEED:.0f} ({feed:.0f} mm/s); steady middle: the feed moves less their first and last 10 % of ticks")
    print()
    print("| machine | curve | chord mm | mode | time s | speed / feed: min / median / mean | ticks ≥ 0.95 | curvature allows (a, a/2) |")
    print("|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for mname, margs, z, accel in MACHINES:
            for kind in ("sine", "circle", "spiral"):
                for step in (0.01, 0.05, 0.1):
                    for label, mode, extra in (("G64, --g64-tolerance 0", "G64",
                                                ["--g64-tolerance", "0"]),
                                               ("G64", "G64", []),
                                               ("G64 P0.01", "G64 P0.01", [])):
                        name = f"{mname} {kind} {step} {label}"
                        if args.only and not any(o in name for o in args.only):
                            continue
                        pts, rmin = points(kind, step)
                        path = os.path.join(tmp, "curve.ngc")
                        with open(path, "w") as f:
                            f.write(program(pts, z, mode))
                        trace = os.path.join(tmp, "trace.csv")
                        run = subprocess.run([args.nc_send, "--sim", *margs, *extra, "--trace", trace, path],
                                             capture_output=True, text=True)
                        if run.returncode != 0:
                            last = (run.stderr.strip().splitlines() or ["?"])[-1]
                            print(f"| {mname} | {kind} | {step} | {label} | failed: {last} | | | |")
                            continue
                        v, t = steady(trace, 4)
                        ratios = [x / feed for x in v]
                        full = math.sqrt(accel * rmin) >= feed
                        half = math.sqrt(accel / 2 * rmin) >= feed
                        allows = ("feed" if full else f"{math.sqrt(accel * rmin):.0f} mm/s") + ", " + \
                                 ("feed" if half else f"{math.sqrt(accel / 2 * rmin):.0f} mm/s")
                        share = sum(r >= 0.95 for r in ratios) / max(len(ratios), 1)
                        print(f"| {mname} | {kind} | {step} | {label} | {t:.3f} | "
                              f"{min(ratios):.3f} / {statistics.median(ratios):.3f} / {statistics.mean(ratios):.3f} | "
                              f"{100 * share:.0f} % | {allows} |", flush=True)


if __name__ == "__main__":
    main()
