#!/usr/bin/env python3
"""The core's own math against `micromath`'s, `fixed`'s and `cordic`'s: accuracy and
emulated Cortex-M4 instructions per call (docs/design.md, "Why not `fixed` and
`micromath`").

    python3 .ci/mathcmp.py              # build, sweep, count, print the table (Markdown)
    python3 .ci/mathcmp.py --no-build   # reuse the last builds

Builds perf/mathcmp (its own workspace, with a copy of the workspace's Cargo.lock; the
compared crates are pinned there) twice, as .ci/m4count.py builds perf/m4count: for
thumbv7em-none-eabihf (release, the firmware's profile: opt-level "s", fat LTO, one
codegen unit, -C target-cpu=cortex-m4) and for the host (profile `host`). The host run
sweeps each function over its domain as the core uses it (2^20 points) against an
`f64` reference and prints the worst error, then 201 sample inputs evenly spaced over
the sweep with the host's results. Each sample is then run in .ci/m4count.py's
emulator (unicorn's Cortex-M4 with the FPU on; instructions counted per executed basic
block, disassembled with capstone): `bench_<name>(input, output)` with both in emulated
RAM, the count including the few loads and stores of that entry point. Every emulated
result must equal the host's bit for bit, so the accuracy swept on the host is the
M4's. The last column names what a call runs beyond its entry point: .ci/m4count.py's
categories of forbidden helpers (soft-float `f64`, 64/128-bit division, software
square roots), then any other function that was not inlined. Not part of CI: the figures are a
design record.

Needs what .ci/m4count.py needs: Python 3, `pip install unicorn capstone`, the Rust
toolchain with the thumbv7em-none-eabihf target.
"""

import importlib.util
import os
import shutil
import statistics
import struct
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CRATE = os.path.join(ROOT, "perf", "mathcmp")
TARGET = "thumbv7em-none-eabihf"
TARGET_DIR = os.path.join(CRATE, "target")
ELF = os.path.join(TARGET_DIR, TARGET, "release", "pkmc-mathcmp")
HOST_BIN = os.path.join(TARGET_DIR, "host", "pkmc-mathcmp")

# The emulator, symbol names and helper categories of .ci/m4count.py (one counting
# method for both tables).
_spec = importlib.util.spec_from_file_location("m4count", os.path.join(ROOT, ".ci", "m4count.py"))
m4count = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(m4count)

IN = m4count.ARG  # input words
OUT = m4count.ARG + 0x400  # result words


def build():
    m4count.build(CRATE, TARGET_DIR)


def versions():
    """Versions of the compared crates, from the lock file cargo resolved."""
    found, name = {}, None
    for line in open(os.path.join(CRATE, "Cargo.lock")):
        if line.startswith("name = "):
            name = line.split('"')[1]
        elif line.startswith("version = ") and name in ("micromath", "fixed", "cordic", "libm"):
            found[name] = line.split('"')[1]
    return found


def main():
    if "--no-build" not in sys.argv:
        build()
    out = subprocess.run([HOST_BIN], cwd=CRATE, check=True, capture_output=True, text=True).stdout
    rows, cases = [], {}
    for line in out.splitlines():
        if line.startswith("fn\t"):
            rows.append(line.split("\t")[1:])
        elif line.startswith("case "):
            f = line.split()
            nin, nout = int(f[2]), int(f[3])
            words = list(map(int, f[4:]))
            cases.setdefault(f[1], []).append((words[:nin], words[nin:nin + nout]))
    m4 = m4count.M4(ELF)
    ver = versions()
    print(f"Crates: micromath {ver.get('micromath')}, fixed {ver.get('fixed')}, "
          f"cordic {ver.get('cordic')} (on fixed), libm {ver.get('libm')}.\n")
    print("| function | crate | domain | worst error | M4 instructions min / median / max | routines it calls |")
    print("| --- | --- | --- | --- | --- | --- |")
    for name, krate, function, domain, unit, worst, _at, points in rows:
        counts, kinds, called = [], set(), set()
        for words_in, want in cases[name]:
            m4.uc.mem_write(IN, struct.pack(f"<{len(words_in)}I", *words_in))
            _, n = m4.call_raw(f"bench_{name}", IN, OUT)
            got = list(struct.unpack(f"<{len(want)}I", bytes(m4.uc.mem_read(OUT, 4 * len(want)))))
            if got != want:
                sys.exit(f"mathcmp: {name}({words_in}) = {got} on the M4, {want} on the host")
            counts.append(n)
            for fname, _k in m4.profile(m4.trace):
                if fname.endswith("::bench") or fname.startswith("bench_"):
                    continue
                kind = m4count.forbidden_kind(fname)
                if kind:
                    kinds.add(kind)
                else:
                    called.add(m4count.short(fname, 40))
            if any(key in m4.wide_div_blocks for key in set(m4.trace)):
                kinds.add("64/128-bit division")
        counts.sort()
        err = f"{float(worst):.2g} {unit}"
        mid = statistics.median_low(counts)
        print(f"| {function} | {krate} | {domain} | {err} | {counts[0]} / {mid} / {counts[-1]} "
              f"| {', '.join(sorted(kinds) + sorted(called)) or '—'} |")
    print(f"\nWorst error over {rows[0][7]} points per function against f64; instructions over "
          f"{len(next(iter(cases.values())))} of them on the emulated Cortex-M4, each result equal to "
          "the host's.")


if __name__ == "__main__":
    main()
