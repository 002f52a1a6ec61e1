#!/usr/bin/env python3
"""pkmc and LinuxCNC 2.9 on the same programs and the same limits (issue 34).

    python3 perf/side_by_side.py [--nc-send PATH] [--only NAME ...] [--skip-linuxcnc]

For each program of the comparison set it runs

- LinuxCNC 2.9 (Debian's linuxcnc-uspace), headless, on a Cartesian X Y Z machine
  with the limits of examples/machines/cartesian-large.toml (100 mm/s and 1000 mm/s^2
  on every axis, 1 ms servo period, LinuxCNC's default blending). A HAL sampler in the
  servo thread records the commanded X Y Z every period; the motion time is the span
  from the first period the commanded position changes to the last, in periods, so
  it does not depend on how late the non-realtime host runs the thread;
- `nc-send --check --report json --trace` on the same machine file: the controller
  core's motion time (`run_time_s`) and its commanded X Y Z every 1 ms;

and measures both samples' largest distance from the programmed path: LinuxCNC's
own interpreter (`rs274`) turns the program into canonical moves (lines, rapids and
arcs), which are the path both runs are held to. It prints one Markdown table: the two
times, their ratio, the two largest deviations, and the geometric mean of the ratios.

The machine's own examples (H-4, hexapod, hexapod-xy) run on pkmc only, with their
machine files. Dense curves (sines, circles, spirals of 0.01–0.1 mm chords at F6000,
with and without G64 P) are generated here.

It runs under Debian's /usr/bin/python3 (re-started there if the Python it was started
with lacks numpy). LinuxCNC runs in real time: the whole set takes about 10 minutes.
Run it as root (as
LinuxCNC's uspace build needs a non-root RTAPI_UID then, this script sets one) with
nothing else running LinuxCNC. Without `linuxcnc`, or with --skip-linuxcnc, only the
pkmc column is filled.
"""
import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CORPUS = os.path.join(os.path.dirname(ROOT), "shared", "corpus", "linuxcnc")
MACHINE = os.path.join(ROOT, "examples", "machines", "cartesian-large.toml")
# The limits of cartesian-large.toml, for LinuxCNC's configuration.
VMAX, AMAX = 100.0, 1000.0
TRAVEL = {"X": (-500.0, 500.0), "Y": (-500.0, 500.0), "Z": (-300.0, 300.0)}
# The Python that linuxcnc-uspace brings its `linuxcnc` module and numpy for.
DEBIAN_PYTHON = "/usr/bin/python3"


# ---------------------------------------------------------------- LinuxCNC's side

def ini_text(run, driver):
    """A LinuxCNC 2.9 configuration: trivkins X Y Z, joint position loops closed in
    HAL (commanded = measured), immediate homing, feed override fixed at 100 %."""
    out = [
        "[EMC]", "VERSION = 1.1", "MACHINE = pkmc-side-by-side",
        "[DISPLAY]", f"DISPLAY = {driver} --drive", "MAX_FEED_OVERRIDE = 1.0",
        "[TASK]", "TASK = milltask", "CYCLE_TIME = 0.001",
        "[RS274NGC]", f"PARAMETER_FILE = {run}/params.var",
        "[EMCMOT]", "EMCMOT = motmod", "COMM_TIMEOUT = 1.0", "SERVO_PERIOD = 1000000",
        "[EMCIO]", "EMCIO = io", "CYCLE_TIME = 0.100", f"TOOL_TABLE = {run}/tool.tbl",
        "[HAL]", f"HALFILE = {run}/machine.hal",
        "[KINS]", "KINEMATICS = trivkins coordinates=XYZ", "JOINTS = 3",
        "[TRAJ]", "COORDINATES = X Y Z", "LINEAR_UNITS = mm", "ANGULAR_UNITS = degree",
        f"DEFAULT_LINEAR_VELOCITY = {VMAX}", f"MAX_LINEAR_VELOCITY = {VMAX}",
        f"DEFAULT_LINEAR_ACCELERATION = {AMAX}", f"MAX_LINEAR_ACCELERATION = {AMAX}",
    ]
    for j, axis in enumerate("XYZ"):
        lo, hi = TRAVEL[axis]
        limits = [f"MAX_VELOCITY = {VMAX}", f"MAX_ACCELERATION = {AMAX}",
                  f"MIN_LIMIT = {lo}", f"MAX_LIMIT = {hi}"]
        out += [f"[AXIS_{axis}]"] + limits
        out += [f"[JOINT_{j}]", "TYPE = LINEAR", "HOME = 0", "HOME_OFFSET = 0",
                "HOME_SEARCH_VEL = 0", "HOME_LATCH_VEL = 0", "HOME_SEQUENCE = 0",
                "FERROR = 10", "MIN_FERROR = 10"] + limits
    return "\n".join(out) + "\n"


HAL = """loadrt [KINS]KINEMATICS
loadrt [EMCMOT]EMCMOT servo_period_nsec=[EMCMOT]SERVO_PERIOD num_joints=[KINS]JOINTS
loadrt sampler depth=20000 cfg=fff
addf motion-command-handler servo-thread
addf motion-controller servo-thread
addf sampler.0 servo-thread
setp sampler.0.enable 0
net j0 joint.0.motor-pos-cmd => joint.0.motor-pos-fb
net j1 joint.1.motor-pos-cmd => joint.1.motor-pos-fb
net j2 joint.2.motor-pos-cmd => joint.2.motor-pos-fb
net on iocontrol.0.user-enable-out => iocontrol.0.emc-enable-in
net prep iocontrol.0.tool-prepare => iocontrol.0.tool-prepared
net change iocontrol.0.tool-change => iocontrol.0.tool-changed
net x axis.x.pos-cmd => sampler.0.pin.0
net y axis.y.pos-cmd => sampler.0.pin.1
net z axis.z.pos-cmd => sampler.0.pin.2
"""


def tool_table(path):
    """T1..T99, length and diameter 0 (G43 and cutter compensation change nothing)."""
    with open(path, "w") as f:
        for t in range(1, 100):
            f.write(f"T{t} P{t} Z0 D0\n")


def drive():
    """LinuxCNC's display program: machine on, home, run the program once with the
    sampler on, then leave (the launcher then shuts LinuxCNC down)."""
    import linuxcnc
    run = os.environ["SBS_RUN"]
    s, c, err = linuxcnc.stat(), linuxcnc.command(), linuxcnc.error_channel()
    messages = []

    def wait(cond, limit, what):
        end = time.time() + limit
        while time.time() < end:
            s.poll()
            m = err.poll()
            if m:
                messages.append(m[1])
            if cond():
                return
            time.sleep(0.01)
        raise RuntimeError(f"timed out: {what}")

    result = {"ok": False}
    sampler = None
    try:
        wait(lambda: True, 5, "status")
        c.state(linuxcnc.STATE_ESTOP_RESET)
        c.state(linuxcnc.STATE_ON)
        wait(lambda: s.task_state == linuxcnc.STATE_ON, 10, "machine on")
        c.mode(linuxcnc.MODE_MANUAL)
        c.home(-1)
        wait(lambda: all(s.homed[:3]), 10, "homing")
        c.mode(linuxcnc.MODE_AUTO)
        wait(lambda: s.task_mode == linuxcnc.MODE_AUTO, 5, "auto mode")
        c.program_open(os.environ["SBS_PROGRAM"])
        sampler = subprocess.Popen(["halsampler", "-t"], stdout=open(f"{run}/samples.txt", "w"))
        subprocess.run(["halcmd", "setp", "sampler.0.enable", "1"], check=True)
        c.auto(linuxcnc.AUTO_RUN, 0)
        wait(lambda: s.interp_state != linuxcnc.INTERP_IDLE, 5, "the program starts")
        wait(lambda: s.interp_state == linuxcnc.INTERP_IDLE and s.queue == 0 and s.inpos,
             float(os.environ.get("SBS_TIMEOUT", "1800")), "the program ends")
        result["ok"] = True
    except Exception as e:  # reported in run.json, the caller fails the run
        result["error"] = str(e)
    finally:
        subprocess.run(["halcmd", "setp", "sampler.0.enable", "0"])
        time.sleep(0.5)
        if sampler:
            sampler.terminate()
            sampler.wait()
        result["messages"] = messages
        json.dump(result, open(f"{run}/run.json", "w"))


def run_linuxcnc(program, timeout):
    """LinuxCNC's commanded X Y Z every servo period while it ran `program`."""
    run = tempfile.mkdtemp(prefix="sbs-lcnc-")
    os.chmod(run, 0o755)
    with open(f"{run}/machine.ini", "w") as f:
        f.write(ini_text(run, os.path.abspath(__file__)))
    with open(f"{run}/machine.hal", "w") as f:
        f.write(HAL)
    open(f"{run}/params.var", "w").close()
    tool_table(f"{run}/tool.tbl")
    env = dict(os.environ, SBS_RUN=run, SBS_PROGRAM=os.path.abspath(program),
               SBS_TIMEOUT=str(timeout), HOME=f"{run}/home",
               PATH="/usr/bin:/bin:/usr/sbin:/sbin", RTAPI_FIFO_PATH=f"{run}/rtapi/fifo")
    os.makedirs(f"{run}/home")
    os.makedirs(f"{run}/rtapi")
    if os.getuid() == 0:
        # As root, uspace's rtapi_app wants a non-root user to fall back to.
        env["RTAPI_UID"] = "65534"
        os.chown(f"{run}/rtapi", 65534, -1)
    with open(f"{run}/linuxcnc.log", "w") as log:
        subprocess.run(["linuxcnc", "-r", f"{run}/machine.ini"], env=env, stdout=log,
                       stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, timeout=timeout + 120)
    try:
        result = json.load(open(f"{run}/run.json"))
    except (OSError, ValueError):
        result = {"ok": False, "error": f"no result (see {run}/linuxcnc.log)"}
    if not result.get("ok"):
        raise RuntimeError(f"LinuxCNC: {result.get('error')} {result.get('messages')} ({run})")
    samples = []
    for line in open(f"{run}/samples.txt"):
        v = line.split()
        if len(v) == 4:
            samples.append((int(v[0]), float(v[1]), float(v[2]), float(v[3])))
    numbers = [s[0] for s in samples]
    if numbers != list(range(numbers[0], numbers[0] + len(numbers))):
        raise RuntimeError(f"LinuxCNC: samples lost ({run})")
    shutil.rmtree(run, ignore_errors=True)
    return [s[1:] for s in samples], result["messages"]


def motion_span(points):
    """Periods from the first change of the commanded position to the last, inclusive."""
    moved = [k for k in range(1, len(points)) if points[k] != points[k - 1]]
    return (moved[-1] - moved[0] + 1) if moved else 0


# ---------------------------------------------------------------- the programmed path

def canon(program):
    """rs274's canonical moves of `program` in machine coordinates: a polyline of
    (point, is_feed), arcs cut into chords within 0.05 um. The canon gives positions in
    program units without the work offsets (LinuxCNC's task adds G5x and G92 to them):
    inches are scaled, the offsets added. None where an XY rotation is in force."""
    home = tempfile.mkdtemp(prefix="sbs-rs274-")
    tool_table(f"{home}/tool.tbl")
    out = subprocess.run(["rs274", "-g", "-t", f"{home}/tool.tbl", program], capture_output=True,
                         text=True, env=dict(os.environ, HOME=home), timeout=600)
    shutil.rmtree(home, ignore_errors=True)
    pts = [((0.0, 0.0, 0.0), False)]
    plane, scale = "XY", 1.0
    g5x, g92 = [0.0] * 3, [0.0] * 3

    def machine(p):
        return tuple(scale * p[k] + g5x[k] + g92[k] for k in range(3))

    for line in out.stdout.splitlines():
        head, _, rest = line.partition("(")
        name = head.split()[-1] if head.split() else ""
        args = [a.strip() for a in rest.rstrip(")").split(",")] if rest else []
        if name == "USE_LENGTH_UNITS":
            scale = 25.4 if "INCH" in args[0] else 1.0
        elif name == "SET_G5X_OFFSET":
            g5x = [scale * float(a) for a in args[1:4]]
        elif name == "SET_G92_OFFSET":
            g92 = [scale * float(a) for a in args[0:3]]
        elif name == "SET_XY_ROTATION" and abs(float(args[0])) > 1e-9:
            return None
        elif name == "SELECT_PLANE":
            plane = args[0].split("_")[-1]
        elif name in ("STRAIGHT_TRAVERSE", "STRAIGHT_FEED"):
            pts.append((machine([float(a) for a in args[:3]]), name == "STRAIGHT_FEED"))
        elif name == "ARC_FEED":
            a = [float(v) for v in args[:6]]
            # The arc in program units from the previous end, then to machine.
            prev = tuple((pts[-1][0][k] - g5x[k] - g92[k]) / scale for k in range(3))
            pts += [(machine(q), True) for q, _ in arc_points(prev, a, plane)]
    return pts


def arc_points(start, a, plane):
    """The chords of an ARC_FEED(first_end, second_end, first_centre, second_centre,
    rotation, axis_end) in `plane` (XY: X Y about Z; YZ: Y Z about X; XZ: Z X about Y)."""
    i1, i2, i3 = {"XY": (0, 1, 2), "YZ": (1, 2, 0), "XZ": (2, 0, 1)}[plane]
    c1, c2, turns = a[2], a[3], int(a[4])
    r = math.hypot(start[i1] - c1, start[i2] - c2)
    a0 = math.atan2(start[i2] - c2, start[i1] - c1)
    a1 = math.atan2(a[1] - c2, a[0] - c1)
    sweep = a1 - a0
    # The canon prints 4 decimals: an arc that ends where it starts (a full circle, as
    # rs274 ran it) may come out a hair apart, which is a full turn, not a sliver.
    if math.hypot(a[0] - start[i1], a[1] - start[i2]) < 2e-4 < r:
        sweep = 0.0
    if turns > 0:
        while sweep <= 1e-12:
            sweep += 2 * math.pi
        sweep += 2 * math.pi * (turns - 1)
    else:
        while sweep >= -1e-12:
            sweep -= 2 * math.pi
        sweep -= 2 * math.pi * (-turns - 1)
    tol = 5e-5 / 25.4  # in the arc's own units (the stricter of mm and inch)
    step = 2 * math.acos(max(-1.0, 1 - tol / r)) if r > tol else math.pi
    n = max(1, int(math.ceil(abs(sweep) / step)))
    out = []
    for k in range(1, n + 1):
        t = k / n
        p = [0.0, 0.0, 0.0]
        p[i1] = c1 + r * math.cos(a0 + sweep * t)
        p[i2] = c2 + r * math.sin(a0 + sweep * t)
        p[i3] = start[i3] + (a[5] - start[i3]) * t
        out.append((tuple(p), True))
    return out


def deviation(samples, path):
    """The largest distance of the samples (in time order) from the path's segments,
    over all samples and over those nearest a feed segment, mm. The search follows the
    path forward from the segment of the previous sample, and of segments equally near
    (within 1 nm: a path that comes back over itself, as a retract up the plunge's
    line) takes the first, so that it does not skip ahead past the rest of the path."""
    import numpy as np
    if not path or len(path) < 2 or not samples:
        return None, None
    p = np.array([q for q, _ in path])
    a, b = p[:-1], p[1:]
    feed = np.array([f for _, f in path[1:]])
    d = b - a
    dd = np.maximum((d * d).sum(axis=1), 1e-30)
    worst = worst_feed = 0.0
    at = 0
    for s in np.array(samples):
        lo, hi = max(0, at - 20), min(len(a), at + 2000)
        t = np.clip(((s - a[lo:hi]) * d[lo:hi]).sum(axis=1) / dd[lo:hi], 0, 1)
        dist = np.linalg.norm(a[lo:hi] + t[:, None] * d[lo:hi] - s, axis=1)
        k = first_nearest(dist)
        if dist[k] > 0.5:  # lost: look along the whole path
            t = np.clip(((s - a) * d).sum(axis=1) / dd, 0, 1)
            dist = np.linalg.norm(a + t[:, None] * d - s, axis=1)
            lo, k = 0, first_nearest(dist)
        at = lo + k
        worst = max(worst, float(dist[k]))
        if feed[at]:
            worst_feed = max(worst_feed, float(dist[k]))
    return worst, worst_feed


def first_nearest(dist):
    """The first index whose distance is within 1 nm of the smallest."""
    import numpy as np
    return int(np.argmax(dist <= dist.min() + 1e-6))


# ---------------------------------------------------------------- pkmc's side

def run_pkmc(nc, program, machine):
    """nc-send --check: the core's motion time and its commanded X Y Z every 1 ms."""
    trace = tempfile.mktemp(suffix=".csv")
    r = subprocess.run([nc, "--check", "--report", "json", "--trace", trace, "--machine", machine,
                        program], capture_output=True, text=True, timeout=3600)
    try:
        rep = json.loads(r.stdout)
    except ValueError:
        raise RuntimeError(f"nc-send: exit {r.returncode}: {r.stderr[-800:]}")
    if rep.get("result") != "done":
        raise RuntimeError(f"nc-send: {rep.get('result')}: {r.stderr[-800:]}")
    samples = []
    if os.path.exists(trace):
        with open(trace) as f:
            next(f)
            for line in f:
                v = line.split(",")
                samples.append((float(v[2]), float(v[3]), float(v[4])))
        os.unlink(trace)
    return rep["run_time_s"], samples


# ---------------------------------------------------------------- the programs

def curve(kind, step, feed, mode):
    """A dense curve of `step` mm chords at `feed` mm/min in path mode `mode`."""
    pts = []
    if kind == "sine":
        x = 0.0
        while x < 120.0:
            pts.append((x, 10 * math.sin(x / 15)))
            x += step / math.sqrt(1 + (10 / 15 * math.cos(x / 15)) ** 2)
    elif kind == "circle":
        r = 25.0
        n = int(2 * math.pi * r / step)
        pts = [(r * math.cos(2 * math.pi * k / n), r * math.sin(2 * math.pi * k / n))
               for k in range(n + 1)]
    else:  # an Archimedean spiral from r = 5 to 30 mm, 4 turns
        th = 0.0
        while True:
            r = 5 + 25 * th / (8 * math.pi)
            if r > 30:
                break
            pts.append((r * math.cos(th), r * math.sin(th)))
            th += step / math.hypot(r, 25 / (8 * math.pi))
    text = [f"G21 G90 G17 {mode}", f"G0 X{pts[0][0]:.4f} Y{pts[0][1]:.4f} Z0", f"F{feed}"]
    text += [f"G1 X{x:.4f} Y{y:.4f}" for x, y in pts[1:]]
    return "\n".join(text + ["M2"]) + "\n"


def programs(tmp):
    """(name, path, machine or None for the comparison machine, LinuxCNC too?)."""
    out = []
    for name in sorted(os.listdir(CORPUS)) if os.path.isdir(CORPUS) else []:
        if name.endswith(".ngc"):
            out.append((name[:-4], os.path.join(CORPUS, name), MACHINE, True))
    for kind in ("sine", "circle", "spiral"):
        for step in (0.01, 0.05, 0.1):
            for mode, tag in (("G64", "G64"), ("G64 P0.01", "P0.01")):
                path = os.path.join(tmp, f"{kind}-{step}-{tag.replace('.', '')}.ngc")
                with open(path, "w") as f:
                    f.write(curve(kind, step, 6000, mode))
                out.append((f"{kind} {step} mm {tag}", path, MACHINE, True))
    ex = os.path.join(ROOT, "examples")
    for prog, machine in (("h4-table-tilt.ngc", "h4-table.toml"), ("hexapod-orbit.ngc", "hexapod.toml"),
                          ("helix-b.ngc", "hexapod-xy.toml")):
        out.append((prog[:-4], os.path.join(ex, prog), os.path.join(ex, "machines", machine), False))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--drive", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("-ini", help=argparse.SUPPRESS)
    ap.add_argument("--nc-send", default=os.path.join(ROOT, "target", "release", "nc-send"))
    ap.add_argument("--only", nargs="*", help="run only the programs whose name starts so")
    ap.add_argument("--skip-linuxcnc", action="store_true")
    ap.add_argument("--timeout", type=float, default=1800)
    o = ap.parse_args()
    if o.drive:
        return drive()
    try:
        import numpy  # noqa: F401 (the deviation needs it)
    except ImportError:
        if os.path.exists(DEBIAN_PYTHON) and sys.executable != DEBIAN_PYTHON:
            os.execv(DEBIAN_PYTHON, [DEBIAN_PYTHON] + sys.argv)
        sys.exit("numpy is needed (Debian: python3-numpy, which linuxcnc-uspace brings)")
    if not os.path.exists(o.nc_send):
        sys.exit(f"no nc-send at {o.nc_send}: cargo build --release -p pkmc-host --bin nc-send")
    lcnc = not o.skip_linuxcnc and shutil.which("linuxcnc") is not None
    if not os.path.isdir(CORPUS):
        print(f"note: {CORPUS} is absent: LinuxCNC's example programs are left out")
    if not lcnc:
        print("note: LinuxCNC is not run (--skip-linuxcnc, or no linuxcnc: apt-get install linuxcnc-uspace)")
    tmp = tempfile.mkdtemp(prefix="sbs-")
    print("| program | LinuxCNC s | pkmc s | pkmc / LinuxCNC | LinuxCNC largest deviation mm (feed) "
          "| pkmc largest deviation mm (feed) |")
    print("|---|---|---|---|---|---|")
    ratios = []
    for name, path, machine, both in programs(tmp):
        if o.only and not any(name.startswith(p) for p in o.only):
            continue
        path_pts = canon(path) if both and shutil.which("rs274") else None
        try:
            t_p, s_p = run_pkmc(o.nc_send, path, machine)
        except RuntimeError as e:
            why = str(e).splitlines()[0].replace("|", "/")[:120]
            print(f"| {name} | – | refused: {why} | – | – | – |", flush=True)
            continue
        dev_p = deviation(s_p, path_pts) if path_pts else (None, None)
        row = [name, "–", f"{t_p:.3f}", "–", "–", fmt(dev_p)]
        if both and lcnc:
            s_l, msgs = run_linuxcnc(path, o.timeout)
            t_l = motion_span(s_l) / 1000.0
            ratios.append(t_p / t_l)
            dev_l = deviation(s_l, path_pts) if path_pts else (None, None)
            row[1], row[3], row[4] = f"{t_l:.3f}", f"{t_p / t_l:.3f}", fmt(dev_l)
            if msgs:
                row[0] += f" (LinuxCNC said: {'; '.join(msgs)[:80]})"
        print("| " + " | ".join(row) + " |", flush=True)
    if ratios:
        g = math.exp(sum(math.log(r) for r in ratios) / len(ratios))
        print(f"\ngeometric mean of pkmc / LinuxCNC over {len(ratios)} programs: {g:.3f}; "
              f"worst {max(ratios):.3f}")
    shutil.rmtree(tmp, ignore_errors=True)


def fmt(dev):
    if dev[0] is None:
        return "n/a"
    return f"{dev[0]:.4f} ({dev[1]:.4f})"


if __name__ == "__main__":
    main()
