#!/usr/bin/env python3
"""Structure budget of the core (src/, the firmware included) and of the host tools
(host-tools/src): no source file over 700 lines and no function over 120 lines,
except where the file says why; and the rooms import only what docs/architecture.md
allows. The core's rooms are ordered from the bottom (CORE_ORDER below): a room may
import only rooms before it, so no import runs upward and there is no circle between
rooms; the firmware (src/bin) sits on top. The host's rooms import only what ALLOWED
lists (the client never imports the simulator, the front end nothing but itself).

A file opts out of a limit with a line `// structure: <reason>` (the reason is
printed). Functions are measured from their `fn` line to the line of the brace
that closes them. Exit status 1 when a limit is broken.
"""
import pathlib
import re
import sys

MAX_FILE = 700
MAX_FN = 120
ROOT = pathlib.Path(__file__).resolve().parent.parent
# Room -> the rooms of the crate its code (tests aside) may name.
ALLOWED = {
    "gcode": set(),
    "link": set(),
    "input": set(),
    "control": set(),
    "cli": {"link"},
    "sim": {"link", "control"},
    "machine_file": {"input", "control", "analysis", "gcode"},
    "analysis": {"sim", "gcode"},
    "contour_study": {"control", "machine_file", "analysis"},
    "job": {"gcode", "link", "sim", "control", "analysis", "machine_file", "input"},
    "grbl": {"gcode", "link", "analysis", "job"},
    "station": {"gcode", "link", "job", "input", "analysis", "scope"},
    "calibrate": {"machine_file", "analysis", "input", "control", "gcode"},
    "scope": {"link", "job", "analysis", "control", "machine_file", "input", "gcode"},
}
# The core's rooms, from the bottom: each may import only the rooms before it.
CORE_ORDER = [
    "units", "math", "place", "config", "kinematics", "drive", "motion", "wire",
    "controller", "wording",
]
CRATE_PATH = re.compile(r"\bcrate::([a-z_]+)")
FN = re.compile(r"^\s*(pub(\([a-z]+\))?\s+)?(const\s+)?(async\s+)?(unsafe\s+)?fn\s+(\w+)")


def functions(lines):
    """Yield (name, first line, length) for every fn with a body."""
    i = 0
    while i < len(lines):
        m = FN.match(lines[i])
        if not m:
            i += 1
            continue
        depth, started, j = 0, False, i
        while j < len(lines):
            code = re.sub(r'"(\\.|[^"\\])*"', '""', lines[j].split("//")[0])
            code = re.sub(r"'(\\.|[^'\\])'", "''", code)
            for ch in code:
                if ch == "{":
                    depth += 1
                    started = True
                elif ch == "}":
                    depth -= 1
            if not started and code.rstrip().endswith(";"):
                break  # a declaration without a body
            if started and depth == 0:
                yield m.group(6), i + 1, j - i + 1
                break
            j += 1
        i += 1


def rooms_named(rel, room, allowed, lines, what):
    """Does every `crate::room` that the file's code (before its tests) names lie in
    `allowed` (or its own room)? Prints each that does not."""
    ok = True
    for n, line in enumerate(lines, 1):
        if line.startswith("#[cfg(test)]"):
            break
        code = line.split("//")[0]
        for other in CRATE_PATH.findall(code):
            if other != room and other not in allowed:
                print(f"{rel}:{n}: {what} may not import crate::{other}")
                ok = False
    return ok


def imports_ok(path, rel, lines):
    """Is every `crate::room` that `path`'s code (before its tests) names allowed? In
    the core, only the rooms below the file's own; in the host, what ALLOWED lists."""
    if rel.parts[0] == "src":
        room = rel.parts[1].removesuffix(".rs")  # src/<room>/...
        if room not in CORE_ORDER:
            return True  # lib.rs; the firmware (src/bin) is its own crate, on top
        below = set(CORE_ORDER[: CORE_ORDER.index(room)])
        return rooms_named(rel, room, below, lines, f"the core's {room} room (only rooms below it)")
    room = rel.parts[2].removesuffix(".rs")  # host-tools/src/<room>/...
    if room not in ALLOWED:
        return True  # lib.rs, the binaries
    return rooms_named(rel, room, ALLOWED[room], lines, f"the {room} room")


def main():
    failed = False
    paths = sorted((ROOT / "src").rglob("*.rs")) + sorted((ROOT / "host-tools" / "src").rglob("*.rs"))
    for path in paths:
        text = path.read_text()
        lines = text.splitlines()
        rel = path.relative_to(ROOT)
        if not imports_ok(path, rel, lines):
            failed = True
        why = re.search(r"// structure: (.*)", text)
        if why:
            print(f"{rel}: exempt ({why.group(1).strip()})")
            continue
        if len(lines) > MAX_FILE:
            print(f"{rel}: {len(lines)} lines (limit {MAX_FILE})")
            failed = True
        for name, at, n in functions(lines):
            if n > MAX_FN:
                print(f"{rel}:{at}: fn {name} is {n} lines (limit {MAX_FN})")
                failed = True
    if failed:
        sys.exit(1)
    print(
        f"src and host-tools/src: no file over {MAX_FILE} lines, no function over {MAX_FN}, "
        "every room imports only what it may (the core's only rooms below it)"
    )


if __name__ == "__main__":
    main()
