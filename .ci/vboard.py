#!/usr/bin/env python3
"""Jobs on the virtual board (docs/vboard.md) against the simulator.

    python3 .ci/vboard.py [--elf FIRMWARE] [--nc-send PATH] [--vboard PATH] [CASE ...]

Each case starts `pkmc-vboard` (the firmware's release ELF on the virtual
STM32G474RE) with a machine file, streams a program to it with `nc-send --port`,
asks the board for its report (drive steps, encoder counts, timing figures), and runs
the same program with `nc-send --sim`. It fails on:

- a difference in blocks executed, alarms, final joints (the controller's own
  figures), or a stepper's final drive steps;
- a servo joint's encoder count, at the instant the simulator stopped (the two runs
  aligned on their traces), more than SERVO_SETTLE counts from the simulator's: the
  axes stand still to within a count or two before a job starts, and how long they
  stood (wall-clock time, in the simulator as on the board) moves the end by as much;
  five --sim runs of square8 alone ended on three neighbouring counts of a leg
  (docs/vboard.md, "Comparing with --sim");
- any drive timing violation, any unmodelled access, hard fault or panic (the board
  exits non-zero);
- a broken budget: the worst 1 ms period over 60 % busy while streaming, less than
  4 KiB of stack never touched, servo-interrupt start jitter over 2 µs.

Cases: square (cartesian-xyz), dense (0.05 mm segments at F6000 on the H-4),
estop (an e-stop through its pin during a job), unplug (the USB cable pulled during a
job: the job starves and is held for take-over), stall (nc-send stopped for 5 s during a
job: it completes exactly), replug (the cable pulled for 2 s with a port that goes away
and comes back: nc-send reconnects by itself and the job completes exactly),
replug-serial (as replug, the board found by nc-send through a by-id directory and
back under a new port name: found again by its USB serial number), persist (the machine survives a pin reset and a watchdog reset),
determinism (two free runs agree), replay (a recorded job replays exactly).
"""
import json
import math
import re
import os
import subprocess
import sys
import tempfile
import threading
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SERVO_SETTLE = 3
MOVE_COUNTS = 20
BUSY_BUDGET = 60.0
STACK_BUDGET = 4096
JITTER_BUDGET_US = 2.0


def die(msg):
    print(f"vboard: FAIL: {msg}", flush=True)
    sys.exit(1)


class Board:
    """A running pkmc-vboard with its stdin as a command line."""

    def __init__(self, vboard, elf, machine, tag, extra=()):
        self.err = open(os.path.join(tempfile.gettempdir(), f"vboard-{tag}.log"), "w+")
        args = [vboard, "--elf", elf] + list(extra)
        if machine:
            args += ["--machine", machine]
        self.p = subprocess.Popen(args, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                  stderr=self.err, text=True, bufsize=1)
        self.lines = []
        self.cond = threading.Condition()
        threading.Thread(target=self._read, daemon=True).start()
        self.port = self._next_line(30)
        if not self.port:
            self.fail("no port printed")

    def _read(self):
        for line in self.p.stdout:
            with self.cond:
                self.lines.append(line.strip())
                self.cond.notify_all()

    def _next_line(self, timeout):
        end = time.time() + timeout
        with self.cond:
            while not self.lines:
                left = end - time.time()
                if left <= 0 or self.p.poll() is not None and not self.lines:
                    return None
                self.cond.wait(min(left, 0.5))
            return self.lines.pop(0)

    def command(self, cmd):
        self.p.stdin.write(cmd + "\n")
        self.p.stdin.flush()

    def report(self):
        self.command("report")
        line = self._next_line(60)
        if line is None:
            self.fail("no report")
        return json.loads(line)

    def log(self):
        self.err.seek(0)
        return self.err.read()

    def fail(self, msg):
        print(self.log()[-4000:])
        self.close()
        die(msg)

    def close(self):
        if self.p.poll() is None:
            self.command("quit")
            try:
                self.p.wait(30)
            except subprocess.TimeoutExpired:
                self.p.kill()
        return self.p.returncode


def nc_send(nc, args, timeout=900):
    r = subprocess.run([nc] + args, capture_output=True, text=True, timeout=timeout)
    return r


def job_json(r, what):
    try:
        return json.loads(r.stdout)
    except json.JSONDecodeError:
        die(f"{what}: no JSON report (exit {r.returncode}): {r.stderr[-2000:]}")


def joint_kinds(machine):
    """'stepper' or 'servo' per joint, from the machine file."""
    kinds = []
    text = open(machine).read()
    for block in text.split("[[joints]]")[1:]:
        kinds.append("servo" if 'drive = "servo"' in block else "stepper")
    return kinds


def read_trace(path):
    rows = []
    with open(path) as f:
        next(f)
        for line in f:
            v = line.strip().split(",")
            rows.append([float(x) for x in v])
    return rows


def aligned_servo_check(kinds, sim, sim_trace, board_trace):
    """The servo joints' encoder counts on the board at the instant the simulator
    stopped, the two runs aligned at their first encoder count change: the simulator
    stops once every servo axis is within a count of its target, the board's plants
    run on (docs/vboard.md). Returns (errors, note)."""
    servos = [j for j, k in enumerate(kinds) if k == "servo"]
    steps = sim.get("final_joint_steps") or []
    srows = read_trace(sim_trace)
    n = len(kinds)
    fb0 = 8 + n  # t_s, line, x..c, q1..qN, then fb1..fbN (tq1..tqN after them)
    scale = []
    for j in range(n):
        last = srows[-1][fb0 + j]
        scale.append(steps[j] / last if last else 1.0)
    sim_counts = [[round(r[fb0 + j] * scale[j]) for j in range(n)] for r in srows]
    brows = read_trace(board_trace)
    board_counts = [[int(x) for x in r[1:]] for r in brows]

    # The first row where a servo joint has moved more than MOVE_COUNTS from where
    # it stood: the job's motion (servo axes may creep by a few counts before it).
    def first_move(rows):
        for i, r in enumerate(rows):
            if any(abs(r[j] - rows[0][j]) > MOVE_COUNTS for j in servos):
                return i
        return None
    si, bi = first_move(sim_counts), first_move(board_counts)
    if si is None or bi is None:
        return [f"no servo motion found (sim {si}, board {bi})"], ""

    # Both traces are sampled at tick edges: the runs line up at a whole number of
    # ticks. The threshold crossing finds it to within a tick or two; the offset with
    # the smallest largest difference over the motion is taken.
    def worst_at(b0):
        w = 0
        for off in range(len(sim_counts) - si):
            if b0 + off >= len(board_counts):
                return None
            a, b = sim_counts[si + off], board_counts[b0 + off]
            w = max(w, max(abs(a[j] - b[j]) for j in servos))
        return w
    candidates = [(worst_at(bi + d), bi + d) for d in range(-3, 4) if bi + d >= 0]
    candidates = [c for c in candidates if c[0] is not None]
    if not candidates:
        return [f"the board's trace ends before the simulator's end"], ""
    worst, bi = min(candidates)
    k = bi + (len(sim_counts) - 1 - si)
    errors = []
    for j in servos:
        if abs(sim_counts[-1][j] - board_counts[k][j]) > SERVO_SETTLE:
            errors.append(f"joint {j} at the simulator's end: sim {sim_counts[-1][j]} board {board_counts[k][j]}")
    note = (f"servo joints aligned where one first moved {MOVE_COUNTS} counts: largest difference over "
            f"{len(sim_counts) - si} ms {worst} counts; at the simulator's end board "
            f"{[board_counts[k][j] for j in servos]} = sim {[sim_counts[-1][j] for j in servos]}")
    return errors, note


def compare(name, machine, program, sim, port_job, rep):
    errors = []
    for k in ("blocks_executed", "final_joints", "alarms", "result"):
        if sim.get(k) != port_job.get(k):
            errors.append(f"{k}: sim {sim.get(k)} board {port_job.get(k)}")
    kinds = joint_kinds(machine) if machine else ["stepper"] * 3
    steps_sim = sim.get("final_joint_steps") or []
    steps_board = rep["final_joint_steps"]
    for j, (a, b) in enumerate(zip(steps_sim, steps_board)):
        if kinds[j] != "servo" and a != b:
            errors.append(f"joint {j} ({kinds[j]}): sim {a} board {b}")
    if (sim.get("drive_violations") or 0) != 0 or rep["drive_violations"] != 0:
        errors.append(f"drive violations: sim {sim.get('drive_violations')} board {rep['drive_violations']}")
    return errors


def budgets(name, rep):
    errors = []
    busy = rep["busy_percent_streaming"]
    if busy["periods"] and busy["max"] > BUSY_BUDGET:
        errors.append(f"busiest 1 ms while streaming {busy['max']} % > {BUSY_BUDGET} %: {rep['busiest_periods_ms']}")
    if rep["stack"]["untouched"] < STACK_BUDGET:
        errors.append(f"stack never touched {rep['stack']['untouched']} B < {STACK_BUDGET} B")
    if rep["servo_latency_us"]["jitter"] > JITTER_BUDGET_US:
        errors.append(f"servo jitter {rep['servo_latency_us']['jitter']} µs > {JITTER_BUDGET_US} µs: "
                      f"{rep['worst_servo_latency_us']}")
    return errors


# The dense jobs stream their segments as programmed, a block each (nc-send merges
# G64's short moves within 1 µm by default, and they would be a few curves).
AS_PROGRAMMED = ["--g64-tolerance", "0"]


def run_job(o, name, machine, program, wiring):
    m = ["--machine", machine] if machine else []
    if os.path.basename(program).startswith("dense"):
        m += AS_PROGRAMMED
    tmp = tempfile.gettempdir()
    sim_trace = os.path.join(tmp, f"vboard-{name}-sim.csv")
    board_trace = os.path.join(tmp, f"vboard-{name}-board.csv")
    sim = job_json(nc_send(o.nc, ["--sim", "--report", "json", "--trace", sim_trace] + m + [program]),
                   f"{name} on --sim")
    elf = o.elf8 if wiring == "servo8" else o.elf
    b = Board(o.vboard, elf, machine, name, ["--trace", board_trace, "--wiring", wiring])
    r = nc_send(o.nc, ["--port", b.port] + m + ["reset"])
    if r.returncode != 0:
        b.fail(f"{name}: reset: {r.stderr}")
    # The machine `reset` loaded is written to flash within 100 ms or so (the store
    # task, docs/vboard.md); the figures are the job's, from here on.
    time.sleep(0.5)
    b.command("mark")
    t0 = time.time()
    job = job_json(nc_send(o.nc, ["--port", b.port, "--report", "json"] + m + [program]), f"{name} on the board")
    wall = time.time() - t0
    # Let the board run at least as long after the job as the simulator settled, in
    # its own virtual time (a loaded machine may run it slower than the wall clock).
    settle = read_trace(sim_trace)[-1][0] - (sim.get("run_time_s") or 0)
    until = b.report()["virtual_s"] + max(1.0, settle + 0.5)
    deadline = time.time() + 120
    while True:
        rep = b.report()
        if rep["virtual_s"] >= until:
            break
        if time.time() > deadline:
            b.fail(f"{name}: the board did not reach {until:.1f} s of virtual time in 120 s")
        time.sleep(min(1.0, until - rep["virtual_s"] + 0.05))
    if b.close() != 0:
        print(b.log()[-4000:])
        die(f"{name}: the board stopped with an error")
    errors = compare(name, machine, program, sim, job, rep) + budgets(name, rep)
    kinds = joint_kinds(machine) if machine else ["stepper"] * 3
    note = ""
    if "servo" in kinds:
        e, note = aligned_servo_check(kinds, sim, sim_trace, board_trace)
        if wiring == "servo8":
            note += f"; channel 7's PWM codes {rep['pwm_code_range']}"
        if sim.get("run_time_s") == job.get("run_time_s"):
            errors += e
        else:  # noqa: the branch below compares the reports' final counts instead
            # The controller's motion itself differed (blocks arrived at other ticks:
            # a queue the link could not keep full): only the settle tolerance holds.
            note += (f"; motion time sim {sim.get('run_time_s')} s, board {job.get('run_time_s')} s: "
                     f"compared within the settle tolerance of {SERVO_SETTLE} counts")
            for j, k in enumerate(kinds):
                a, b = (sim.get("final_joint_steps") or [])[j], rep["final_joint_steps"][j]
                if k == "servo" and abs(a - b) > SERVO_SETTLE:
                    errors.append(f"joint {j} (servo): sim {a} board {b}")
    return sim, job, rep, wall, errors, note


# Jobs: machine file (None: the built-in cartesian-xyz), program (a path, or a
# generator's name), wiring.
JOBS = {
    "square": (None, "examples/square.ngc", "default"),
    "dense": ("examples/machines/h4-table.toml", "dense-h4", "default"),
    "h4": ("examples/machines/h4-table.toml", "examples/h4-table-tilt.ngc", "default"),
    "hexapod": ("examples/machines/hexapod.toml", "examples/hexapod-orbit.ngc", "default"),
    "chips": ("examples/machines/h4-table.toml", "chips-no-m6", "default"),
    "square8": ("examples/machines/hexapod-xy.toml", "square-xy", "servo8"),
    "dense8": ("examples/machines/hexapod-xy.toml", "dense-xy", "servo8"),
    "helix8": ("examples/machines/hexapod-xy.toml", "examples/helix-b.ngc", "servo8"),
}


def dense_program(path, x0=0.0, z=-80.0):
    """A 60 mm sine of 0.05 mm G1 segments at F6000 from X`x0` at height `z`."""
    lines = ["G21 G90 G94", f"G0 X{x0:.4f} Y0 Z{z:.4f}", "G1 F6000"]
    n = 1200
    for i in range(1, n + 1):
        x = i * 0.05
        y = 5.0 * math.sin(2 * math.pi * x / 20.0)
        lines.append(f"X{x0 + x:.4f} Y{y:.4f}")
    lines.append("M2")
    open(path, "w").write("\n".join(lines) + "\n")


def square_program(path, z):
    """A 20 mm square at F600 at height `z` (the hexapod-xy's work space)."""
    lines = ["G21 G90 G94", f"G0 X-10 Y-10 Z{z:.4f}", "G1 F600", "X10", "Y10", "X-10", "Y-10",
             "G0 X0 Y0", "M2"]
    open(path, "w").write("\n".join(lines) + "\n")


def chips_without_tool_change(path):
    """LinuxCNC's 3D_Chips.ngc (read in place from ../shared/corpus) without its one
    tool change (line 18, `T#<toolno> M6`): a board stops there for an operator
    (docs/nc-send.md, exit 7), the simulator resumes by itself; the change moves
    nothing."""
    src = os.path.join(ROOT, "../shared/corpus/linuxcnc/3D_Chips.ngc")
    if not os.path.exists(src):
        return False
    lines = open(src).read().splitlines()
    out = [line for line in lines if "M6" not in line.upper().replace(" ", "")]
    if len(lines) - len(out) != 1:
        die(f"chips: expected one tool change in 3D_Chips.ngc, found {len(lines) - len(out)}")
    open(path, "w").write("\n".join(out) + "\n")
    return True


GENERATED = {
    "chips-no-m6": chips_without_tool_change,
    "dense-h4": lambda p: dense_program(p),
    "dense-xy": lambda p: dense_program(p, x0=-30.0, z=260.0),
    "square-xy": lambda p: square_program(p, 260.0),
}


def case_record(o):
    """The data recorder on the board (docs/recorder.md): the dense H-4 job streamed
    twice by `nc-send record --trigger stream`, first with the path speed alone
    streamed (4 bytes a millisecond) then with eight signals every tick. Fails when a
    sample is lost on the way, when the eight-signal run's motion (the time the
    streamed path speed is above zero) is more than 10 ms longer than the first's (the
    stream starved the blocks), or on the budgets; reports the bytes a second each
    way. Then a capture every servo period (10 kHz) of joint 0's following error, DAC
    code, commanded and measured position during the dense job again, checked for
    periods that differ within a tick."""
    machine = os.path.join(ROOT, "examples/machines/h4-table.toml")
    tmp = tempfile.mkdtemp()
    program = os.path.join(tmp, "dense-h4.ngc")
    dense_program(program)
    m = ["--machine", machine] + AS_PROGRAMMED
    b = Board(o.vboard, o.elf, machine, "record")
    if nc_send(o.nc, ["--port", b.port] + m + ["reset"]).returncode != 0:
        b.fail("record: reset failed")
    time.sleep(0.5)
    b.command("mark")

    def run(args):
        before = b.report()
        t0 = before["virtual_s"]
        r = nc_send(o.nc, ["--port", b.port] + m + args)
        after = b.report()
        if r.returncode != 0:
            b.fail(f"record: nc-send {' '.join(args[:3])}: exit {r.returncode}: {r.stderr[-1500:]}")
        span = after["virtual_s"] - t0
        moved = [x - y for x, y in zip(after["usb_bytes_in_out"], before["usb_bytes_in_out"])]
        return r, span, moved, after

    alone_csv = os.path.join(tmp, "alone.csv")
    # The job once to take the machine to its end, so that both measured runs start
    # there (the program's first move, a rapid back to the start, is then the same).
    run([program])

    def motion_ms(path):
        """The time the path speed (the last column) is above 0, first to last, ms."""
        rows = [line.split(",") for line in open(path).read().splitlines()[1:]]
        moving = [i for i, x in enumerate(rows) if int(x[-1]) > 0]
        return (moving[-1] - moving[0] + 1 if moving else 0), rows

    # The job with the path speed alone streamed (4 bytes a millisecond): its motion
    # time is the reference.
    _, span0, bytes0, rep0 = run(["record", "--signals", "speed", "--trigger", "stream",
                                  "--during", program, "--csv", alone_csv])
    motion0, _ = motion_ms(alone_csv)
    csv = os.path.join(tmp, "stream.csv")
    signals = "cmd:0,cmd:1,cmd:2,cmd:3,ferr:0,ferr:1,out:0,speed"
    r, span1, bytes1, rep1 = run(["record", "--signals", signals, "--trigger", "stream",
                                  "--during", program, "--csv", csv])
    motion1, rows = motion_ms(csv)
    numbers = [int(x[0]) for x in rows]
    lost = numbers[-1] - numbers[0] + 1 - len(numbers) if numbers else -1
    errors = budgets("record", rep1)
    if lost != 0 or "were lost" in r.stderr:
        errors.append(f"{lost} samples lost: {r.stderr[-500:]}")
    # A stream that starved the job's blocks would stretch its motion.
    if motion1 > motion0 + 10:
        errors.append(f"the streamed job moved for {motion1} ms against {motion0} ms")
    servo_csv = os.path.join(tmp, "servo.csv")
    r2, _, _, rep2 = run(["record", "--signals", "ferr:0,out:0,cmd:0,meas:0", "--servo",
                          "--trigger", "line:600", "--pre", "50", "--during", program,
                          "--csv", servo_csv])
    srows = [list(map(int, line.split(",")[2:])) for line in open(servo_csv).read().splitlines()[1:]]
    cmd = [x[2] for x in srows]
    changes = sum(1 for a, c in zip(cmd, cmd[1:]) if a != c)
    errors += budgets("record (servo period)", rep2)
    if len(srows) < 100 or changes < len(srows) // 3:
        errors.append(f"servo-period capture: {len(srows)} samples, commanded position changed "
                      f"{changes} times")
    b.close()
    if errors:
        die("record: " + "; ".join(errors))
    secs = max(span1, 1e-9)
    busy1 = rep1["busy_percent_streaming"]
    return (f"record: the dense H-4 job with 8 signals streamed every tick: {len(rows)} samples, 0 lost, "
            f"motion {motion1} ms against {motion0} ms with the path speed alone streamed; "
            f"{span1:.3f} s from start to end against {span0:.3f} s; from the board {bytes1[0]} B "
            f"({bytes1[0] / secs / 1000:.1f} kB/s) against {bytes0[0]} B with the speed alone "
            f"({bytes0[0] / max(span0, 1e-9) / 1000:.1f} kB/s), "
            f"to the board {bytes1[1]} B ({bytes1[1] / secs / 1000:.1f} kB/s) against {bytes0[1]} B; "
            f"busiest 1 ms {busy1['max']} %, servo start jitter {rep1['servo_latency_us']['jitter']} µs; "
            f"a servo-period capture of the same job from line 600 ({len(srows)} samples at 10 kHz, "
            f"commanded position changing in {changes} of its periods), servo start jitter "
            f"{rep2['servo_latency_us']['jitter']} µs")


def table_row(name, sim, job, rep, wall):
    busy = rep["busy_percent_streaming"] if rep["busy_percent_streaming"]["periods"] else rep["busy_percent"]
    lat = rep["servo_latency_us"]
    rt = job.get("run_time_s") or 0
    return (f"| {name} | {job.get('blocks_executed')} | {rt:.3f} | {busy['min']:.1f} / {busy['median']:.1f} / "
            f"{busy['p99']:.1f} / {busy['max']:.1f} | {lat['min']:.2f} / {lat['median']:.2f} / {lat['p99']:.2f} / "
            f"{lat['max']:.2f} | {rep['stack']['deepest']} / {rep['stack']['untouched']} | "
            f"{(job.get('blocks_executed') or 0) / rt if rt else 0:.0f} | {rep['frames_per_s_peak_100ms']} | "
            f"{rep['speed']:.2f} |")


def case_estop(o):
    """An e-stop pressed 1.5 s into the square job: the controller stops on the path
    and reports EStop at the line it was on."""
    b = Board(o.vboard, o.elf, None, "estop")
    nc_send(o.nc, ["--port", b.port, "reset"])
    def press():
        time.sleep(2.5)
        b.command("estop on")
    threading.Thread(target=press, daemon=True).start()
    r = nc_send(o.nc, ["--port", b.port, "--report", "json", os.path.join(ROOT, "examples/square.ngc")])
    job = job_json(r, "estop job")
    rep = b.report()
    b.close()
    causes = [a.get("cause") if isinstance(a, dict) else a for a in job.get("alarms") or []]
    if r.returncode != 5 or "EStop" not in json.dumps(job.get("alarms")) and job.get("alarm_cause") != "EStop":
        die(f"estop: exit {r.returncode}, alarms {job.get('alarms')}, cause {job.get('alarm_cause')}")
    if rep["drive_violations"] != 0:
        die(f"estop: {rep['drive_violations']} drive violations")
    return f"e-stop through PA10: exit {r.returncode}, alarm {job.get('alarm_cause')} at line {job.get('alarm_line')}, {causes}"


def pin_fault(o, name, machine, program, command, cause):
    """`command` on the board's pins 2.5 s into a job: the controller names `cause`
    and stops; the drives end where the controller believes its joints are."""
    m = ["--machine", machine] if machine else []
    b = Board(o.vboard, o.elf, machine, name)
    nc_send(o.nc, ["--port", b.port] + m + ["reset"])
    def act():
        time.sleep(2.5)
        b.command(command)
    threading.Thread(target=act, daemon=True).start()
    r = nc_send(o.nc, ["--port", b.port, "--report", "json"] + m + [program])
    job = job_json(r, f"{name} job")
    time.sleep(1.0)
    st = nc_send(o.nc, ["--port", b.port, "--report", "json"] + m + ["status"])
    rep = b.report()
    b.close()
    if r.returncode != 5 or job.get("alarm_cause") != cause:
        die(f"{name}: exit {r.returncode}, alarm {job.get('alarm_cause')}, expected {cause}: {job.get('alarms')}")
    if rep["drive_violations"] != 0:
        die(f"{name}: {rep['drive_violations']} drive violations")
    return (f"{name} (`{command}`): exit {r.returncode}, alarm {cause} at line {job.get('alarm_line')}, "
            f"joint {job.get('alarm_joint')}; drives {rep['final_joint_steps']}")


def case_limit(o):
    return pin_fault(o, "limit", None, os.path.join(ROOT, "examples/square.ngc"), "limit 0 on", "LimitSwitch")


def case_ampfault(o):
    return pin_fault(o, "ampfault", os.path.join(ROOT, "examples/machines/h4-table.toml"),
                     os.path.join(ROOT, "examples/h4-table-tilt.ngc"), "fault 0 on", "DriveFault")


def case_jam(o):
    return pin_fault(o, "jam", os.path.join(ROOT, "examples/machines/h4-table.toml"),
                     os.path.join(ROOT, "examples/h4-table-tilt.ngc"), "jam 1", "FollowingError")


def case_determinism(o):
    """Two runs of the same 1.5 s (boot, USB enumeration, an e-stop injected at
    1.0 s through the simulator's fault syntax), free-running: the same instructions,
    interrupts, drive positions and figures."""
    reps = []
    for k in range(2):
        r = subprocess.run([o.vboard, "--elf", o.elf, "--seconds", "1.5", "--free-run", "--quiet-log",
                            "--inject", "estop@1.0"], capture_output=True, text=True, timeout=300,
                           stdin=subprocess.DEVNULL)
        if r.returncode != 0:
            die(f"determinism: run {k + 1} exit {r.returncode}: {r.stderr[-2000:]}")
        rep = json.loads(r.stdout.strip().splitlines()[-1])
        for key in ("wall_s", "speed"):
            rep.pop(key)
        reps.append(rep)
    if reps[0] != reps[1]:
        diff = {k: (reps[0][k], reps[1].get(k)) for k in reps[0] if reps[0][k] != reps[1].get(k)}
        die(f"determinism: the two runs differ: {diff}")
    return (f"determinism: two free runs of 1.5 s agree on all {len(reps[0])} figures "
            f"({reps[0]['instructions']} instructions, exceptions {reps[0]['exceptions']})")


def case_replay(o):
    """The square job streamed by a real nc-send, recorded (--record); replayed twice
    (--replay) without a host or the wall clock: the device writes the recorded bytes
    at the recorded times (the board checks), and the three traces and reports are
    identical."""
    tmp = tempfile.gettempdir()
    rec = os.path.join(tmp, "vboard-replay.rec")
    live = os.path.join(tmp, "vboard-replay-live.csv")
    b = Board(o.vboard, o.elf, None, "replay", ["--record", rec, "--trace", live, "--quiet-log"])
    r = nc_send(o.nc, ["--port", b.port, "reset"])
    job = nc_send(o.nc, ["--port", b.port, "--report", "json", os.path.join(ROOT, "examples/square.ngc")])
    time.sleep(0.5)
    if b.close() != 0 or r.returncode != 0 or job.returncode != 0:
        print(b.log()[-3000:])
        die(f"replay: the recorded run failed: reset exit {r.returncode}, job exit {job.returncode}: "
            f"{job.stderr[-1000:]}")
    with b.cond:
        reports = [json.loads(line) for line in b.lines if line.startswith("{")]
    if not reports:
        die("replay: the recorded run printed no report")
    reports = [reports[-1]]
    traces = [open(live).read()]
    for k in range(2):
        path = os.path.join(tmp, f"vboard-replay-{k}.csv")
        p = subprocess.run([o.vboard, "--elf", o.elf, "--replay", rec, "--trace", path, "--quiet-log"],
                           capture_output=True, text=True, timeout=600, stdin=subprocess.DEVNULL)
        if p.returncode != 0:
            die(f"replay {k + 1}: exit {p.returncode}: {p.stderr[-2000:]}")
        reports.append(json.loads(p.stdout.strip().splitlines()[-1]))
        traces.append(open(path).read())
    for rep_ in reports:
        for key in ("wall_s", "speed"):
            rep_.pop(key)
    for k in (1, 2):
        if reports[k] != reports[0]:
            diff = {x: (reports[0][x], reports[k].get(x)) for x in reports[0] if reports[0][x] != reports[k].get(x)}
            die(f"replay {k}: the report differs from the recorded run's: {diff}")
        if traces[k] != traces[0]:
            lines = [(i, a, c) for i, (a, c) in enumerate(zip(traces[0].splitlines(), traces[k].splitlines()))
                     if a != c]
            die(f"replay {k}: the trace differs from the recorded run's, first at row {lines[:1]}")
    rows = traces[0].count("\n") - 1
    return (f"replay: the square job (nc-send, {job_json(job, 'replay')['blocks_executed']} blocks) recorded, "
            f"replayed twice: traces identical ({rows} rows), reports identical "
            f"({reports[0]['instructions']} instructions, final steps {reports[0]['final_joint_steps']})")


def case_unplug(o):
    """The USB cable pulled 2.5 s into the square job for 3 s. The controller runs out
    what it has queued and waits, starved, for its host (docs/safety.md, host
    silence); the streaming nc-send gives up on the dead port. Plugged in again, a new
    nc-send finds the job held for take-over (`status`), and `abort` drops it
    (docs/nc-send.md, take-over): the controller is then idle with no job."""
    b = Board(o.vboard, o.elf, None, "unplug")
    nc_send(o.nc, ["--port", b.port, "reset"])
    def pull():
        time.sleep(2.5)
        b.command("unplug")
        time.sleep(3.0)
        b.command("plug")
    threading.Thread(target=pull, daemon=True).start()
    r = nc_send(o.nc, ["--port", b.port, "--report", "json", os.path.join(ROOT, "examples/square.ngc")])
    time.sleep(4.0)
    st = nc_send(o.nc, ["--port", b.port, "status"])
    ab = nc_send(o.nc, ["--port", b.port, "abort"])
    after = nc_send(o.nc, ["--port", b.port, "status"])
    b.close()
    said = st.stdout + st.stderr
    if r.returncode == 0:
        die(f"unplug: the job reported success: {r.stdout[-500:]}")
    if "HELD" not in said or "starved" not in said.lower():
        die(f"unplug: status after replug does not show the starved job held: {said}")
    if "HELD" in after.stdout + after.stderr or "idle" not in after.stdout.lower():
        die(f"unplug: after abort the controller is not idle without a job: {after.stdout} {after.stderr}")
    first = said.strip().splitlines()
    return (f"unplug: job exit {r.returncode}; after replug: {' / '.join(first)}; "
            f"abort exit {ab.returncode}; then: {after.stdout.strip().splitlines()[0]}")


def disturbed_square(o, name, disturb, link=False, by_id=False):
    """The square job on the board (steppers: exact steps) with `disturb(board,
    nc_send_process)` run beside it from its start; the job must complete and end
    exactly where --sim's undisturbed run ends. `link`: the port is a fixed path that
    exists while the device is enumerated; `by_id`: nc-send finds the board by its USB
    identity in a by-id directory (its port's name changes at each enumeration)."""
    program = os.path.join(ROOT, "examples/square.ngc")
    sim = job_json(nc_send(o.nc, ["--sim", "--report", "json", program]), f"{name} on --sim")
    extra, env, where = [], None, None
    if link:
        node = os.path.join(tempfile.mkdtemp(), "ttyACM-vboard")
        extra = ["--link", node]
    if by_id:
        named = tempfile.mkdtemp()
        extra = ["--by-id", named]
        env = dict(os.environ, PKMC_SERIAL_BY_ID=named)
    b = Board(o.vboard, o.elf, None, name, extra)
    r = nc_send(o.nc, ["--port", b.port, "reset"])
    if r.returncode != 0:
        b.fail(f"{name}: reset: {r.stderr}")
    time.sleep(0.5)
    if by_id:
        where = os.listdir(named)
        if len(where) != 1 or os.path.realpath(os.path.join(named, where[0])) != os.path.realpath(b.port):
            b.fail(f"{name}: the by-id directory names {where}, not the board's port {b.port}")
    t0 = time.time()
    port = [] if by_id else ["--port", b.port]
    p = subprocess.Popen([o.nc] + port + ["--report", "json", program],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    what = disturb(b, p)
    try:
        out, err = p.communicate(timeout=300)
    except subprocess.TimeoutExpired:
        p.kill()
        b.fail(f"{name}: the job did not end within 300 s")
    wall = time.time() - t0
    if p.returncode != 0:
        b.fail(f"{name}: the job failed (exit {p.returncode}): {err[-2000:]}")
    job = job_json(subprocess.CompletedProcess(p.args, p.returncode, out, err), f"{name} on the board")
    until = b.report()["virtual_s"] + 0.5
    while b.report()["virtual_s"] < until:
        time.sleep(0.1)
    rep = b.report()
    log = b.log()
    if b.close() != 0:
        print(log[-4000:])
        die(f"{name}: the board stopped with an error")
    errors = compare(name, None, program, sim, job, rep)
    if by_id:
        back = re.findall(r"vboard: (\S+) back \(device enumerated\)", log)
        if not back or os.path.realpath(back[-1]) == os.path.realpath(b.port):
            errors.append(f"the port did not come back under another name ({b.port}, then {back})")
        else:
            what += f"; the port {b.port} came back as {back[-1]} ({where[0]})"
        if job.get("link", {}).get("reconnects", 0) < 1:
            errors.append("nc-send did not reconnect")
    if errors:
        print(log[-3000:])
        die(f"{name}: " + "; ".join(errors))
    return (f"{name}: {what}; the square job completed (exit 0, {job['blocks_executed']} blocks, "
            f"{wall:.1f} s wall against --sim's {sim['run_time_s']} s of motion), final steps "
            f"{rep['final_joint_steps']} equal to --sim's; link: {json.dumps(job.get('link', {}).get('reconnects'))} reconnects")


def case_stall(o):
    """nc-send stopped (SIGSTOP) for 5 s, 2 s into the square job, then continued:
    far past the 1 s link watch and the 2 s of buffered motion. The controller runs
    out its queue, waits starved (docs/safety.md, host silence), and runs on when
    blocks come again; the job completes exactly."""
    import signal

    def stall(b, p):
        time.sleep(2.0)
        p.send_signal(signal.SIGSTOP)
        time.sleep(5.0)
        p.send_signal(signal.SIGCONT)
        return "nc-send stopped for 5 s at 2 s"
    return disturbed_square(o, "stall", stall)


def pull_cable(b, p):
    """The USB cable pulled 2.5 s into a job and plugged in again 2 s later."""
    time.sleep(2.5)
    b.command("unplug")
    time.sleep(2.0)
    b.command("plug")
    return "cable pulled at 2.5 s for 2 s"


def case_replug(o):
    """The USB cable pulled 2.5 s into the square job and plugged in again 2 s later,
    with the port named by --link, which exists only while the device is enumerated
    (as a CDC-ACM port's device node does): nc-send reads an error when it goes,
    waits for the same path, reconnects, takes its own held job over and streams the
    rest (docs/nc-send.md, replug); the job completes exactly."""
    return disturbed_square(o, "replug", pull_cable, link=True)


def case_replug_serial(o):
    """As `replug`, with the board found on USB by nc-send (no --port), through a by-id
    directory of the form udev keeps (`usb-<manufacturer>_<product>_<serial>-if00`,
    named from the string descriptors the virtual host read from the firmware); the
    port comes back under a new name after the replug (a new pseudo-terminal, as
    /dev/ttyACM0 may come back as /dev/ttyACM1), and nc-send finds it by its USB serial
    number; the job completes exactly."""
    return disturbed_square(o, "replug-serial", pull_cable, by_id=True)



def case_persist(o):
    """The machine loaded by nc-send survives a reset by NRST, one by the watchdog and
    a reset request (AIRCR.SYSRESETREQ, as a debugger makes it)."""
    machine = os.path.join(ROOT, "examples/machines/h4-table.toml")
    b = Board(o.vboard, o.elf, machine, "persist")
    nc_send(o.nc, ["--port", b.port, "--machine", machine, "reset"])
    time.sleep(1.0)
    b.command("reset")
    time.sleep(2.0)
    b.command("hold 100")
    time.sleep(2.0)
    b.command("sysreset")
    time.sleep(2.0)
    rep = b.report()
    log = b.log()
    b.close()
    if log.count("machine from flash: h4-table") < 3:
        die(f"persist: the machine was not read back after the three resets:\n{log[-3000:]}")
    resets = (rep["pin_resets"], rep["watchdog_resets"], rep["software_resets"])
    if resets != (1, 1, 1) or rep.get("flash_machine") != "h4-table":
        die(f"persist: resets (pin, watchdog, software) {resets}, flash holds {rep.get('flash_machine')}")
    return ("persist: h4-table read back after an NRST reset, a watchdog reset and a reset request "
            "(SYSRESETREQ); flash pages decode to h4-table")


# The probe case's machine: the built-in cartesian-xyz (steppers on channels 0-2,
# 400 steps/mm on every axis, src/config/builtin.rs). Feed 1500 mm/min: 25 mm/s,
# 10 steps of Z per 1 ms tick, so a latch taken at the sample instead of the edge
# would be off by up to 10 steps.
PROBE_STEPS_PER_MM = 400
PROBE_FEED = 1500
# The latch against the drive's steps at the edge, steps: the drive's count is whole
# steps (a step under way not yet counted) and the latch interpolates between tick
# starts (at constant speed the steps are evenly spread: within a step); the
# capture's own uncertainty (0.65 us, docs/probing.md) is 0.007 step here.
PROBE_TOLERANCE_STEPS = 1.5
# probe8: the latch against the encoders' motion interpolated to the edge, counts: the
# leg scales count 10 nm, the legs move about 0.8 counts/us here, so the capture's
# 0.65 us is 0.5 count; one count of rounding each in the latch and the expectation,
# and the plants' speed changing within the tick.
PROBE8_TOLERANCE_COUNTS = 3.0
# The edge's instant after a tick edge, us: mid-tick, not on a boundary.
PROBE_EDGE_US = 437.3


def probe_job(o, b, name, text, tmp):
    path = os.path.join(tmp, f"{name}.ngc")
    with open(path, "w") as f:
        f.write(text)
    return nc_send(o.nc, ["--port", b.port, "--report", "json", path])


def wait_moving(b, name, joint=2, timeout=30, by=1):
    """Until the board's drive of `joint` has moved `by` steps or counts from where it
    stood."""
    start = b.report()["final_joint_steps"][joint]
    end = time.time() + timeout
    while time.time() < end:
        if abs(b.report()["final_joint_steps"][joint] - start) >= by:
            return
        time.sleep(0.02)
    b.fail(f"{name}: the probing move did not start within {timeout} s")


def case_probe(o):
    """The touch probe on PA2 (TIM2 CH3's input capture, default wiring) through
    nc-send's G38 moves: (1) a probe touching at the start: alarm ProbeAtStart,
    nothing moves; (2) G38.2 down Z at 1500 mm/min, the pin switched PROBE_EDGE_US
    after a tick edge mid-move: the latched Z equals the drive's steps at that instant
    within PROBE_TOLERANCE_STEPS, and the move stops just past it; (3) G38.3 with a
    1.2 ms touch, shorter than the three-sample debounce: no latch, the move runs to
    its end."""
    tmp = tempfile.mkdtemp()
    b = Board(o.vboard, o.elf, None, "probe")
    if nc_send(o.nc, ["--port", b.port, "reset"]).returncode != 0:
        b.fail("probe: reset refused")
    # (1) Touching before the move.
    b.command("probe on")
    time.sleep(0.2)
    r = probe_job(o, b, "probe-at-start", "G21 G90\nG38.2 Z-10 F1500\nM2\n", tmp)
    job = job_json(r, "probe at start")
    steps = b.report()["final_joint_steps"]
    if r.returncode != 5 or job.get("alarm_cause") != "ProbeAtStart":
        b.fail(f"probe at start: exit {r.returncode}, alarm {job.get('alarm_cause')}, expected ProbeAtStart")
    if steps != [0, 0, 0]:
        b.fail(f"probe at start: the drives moved: {steps}")
    at_start = f"exit {r.returncode}, alarm {job.get('alarm_cause')}, drives {steps}"
    b.command("probe off")
    time.sleep(0.2)
    if nc_send(o.nc, ["--port", b.port, "reset"]).returncode != 0:
        b.fail("probe: reset after ProbeAtStart refused")

    # (2) Contact mid-move, at a sub-tick instant.
    result = {}
    def run():
        result["r"] = probe_job(o, b, "probe-touch", f"G21 G90\nG38.2 Z-60 F{PROBE_FEED}\nM2\n", tmp)
    t = threading.Thread(target=run)
    t.start()
    wait_moving(b, "probe touch")
    time.sleep(0.3)  # past the acceleration (25 ms at 1000 mm/s^2): constant speed
    b.command(f"probe on {PROBE_EDGE_US}")
    t.join(120)
    r = result.get("r")
    if r is None:
        b.fail("probe touch: nc-send did not end")
    job = job_json(r, "probe touch")
    rep = b.report()
    if r.returncode != 0:
        b.fail(f"probe touch: exit {r.returncode}: {r.stderr[-1500:]}")
    edges = rep["probe_edges"]
    probes = job.get("probes") or []
    if len(edges) != 3 or not edges[2]["touching"] or len(probes) != 1:
        b.fail(f"probe touch: edges {edges}, probes {probes}")
    edge, probe = edges[2], probes[0]
    if abs(edge["in_tick_us"] - PROBE_EDGE_US) > 0.01:
        b.fail(f"probe touch: the edge came {edge['in_tick_us']} us into its tick, not {PROBE_EDGE_US}")
    latched = [round(v * PROBE_STEPS_PER_MM, 3) for v in probe["joints"]]
    off = [l - e for l, e in zip(latched, edge["joint_steps"])]
    stopped_z = probe["stopped"][2]
    final = rep["final_joint_steps"]
    errors = []
    if not probe["contact"]:
        errors.append("no contact reported")
    if any(abs(d) > PROBE_TOLERANCE_STEPS for d in off):
        errors.append(f"latched {latched} steps, the drives at the edge {edge['joint_steps']}: "
                      f"off by {off}, more than {PROBE_TOLERANCE_STEPS}")
    # Stopped past the contact by the confirmation (two ticks) and the deceleration
    # (25 mm/s at 1000 mm/s^2: 0.31 mm), far from the move's end; the drives there.
    past = probe["joints"][2] - stopped_z
    if not 0.0 < past < 0.5:
        errors.append(f"stopped {past:.4f} mm past the contact")
    if final[2] != round(stopped_z * PROBE_STEPS_PER_MM):
        errors.append(f"drive Z at {final[2]} steps, the controller stopped at {stopped_z} mm")
    if rep["drive_violations"] != 0:
        errors.append(f"{rep['drive_violations']} drive violations")
    if errors:
        b.fail("probe touch: " + "; ".join(errors))
    touch = (f"edge {edge['in_tick_us']:.3f} us into a tick at {edge['t_s']:.6f} s, drives then "
             f"{edge['joint_steps']}, latched {latched} steps (off by {[round(d, 3) for d in off]}); "
             f"stopped {past:.3f} mm past it, drives {final}")

    # (3) A bounce: touching for 1.2 ms, less than the debounce's three samples.
    b.command("probe off")
    time.sleep(0.2)
    end_z = -75
    result = {}
    def run3():
        result["r"] = probe_job(o, b, "probe-bounce", f"G21 G90\nG38.3 Z{end_z} F{PROBE_FEED}\nM2\n", tmp)
    t = threading.Thread(target=run3)
    t.start()
    wait_moving(b, "probe bounce")
    time.sleep(0.2)
    # Both at the same tick edge if the board takes them together; else the release
    # comes a tick later (a 2.2 ms touch, still under the debounce).
    b.command("probe on 300\nprobe off 1500")
    t.join(120)
    r = result.get("r")
    if r is None:
        b.fail("probe bounce: nc-send did not end")
    job = job_json(r, "probe bounce")
    rep = b.report()
    b.close()
    edges = rep["probe_edges"][4:]
    probes = job.get("probes") or []
    if r.returncode != 0 or len(probes) != 1 or probes[0]["contact"]:
        die(f"probe bounce: exit {r.returncode}, probes {probes}: a 1.2 ms touch latched")
    if len(edges) != 2 or round((edges[1]["t_s"] - edges[0]["t_s"]) * 1e6) not in (1200, 2200):
        die(f"probe bounce: the pin's edges {edges}")
    if rep["final_joint_steps"][2] != end_z * PROBE_STEPS_PER_MM:
        die(f"probe bounce: drive Z at {rep['final_joint_steps'][2]}, not the move's end")
    return (f"probe (PA2, TIM2 CH3 capture): at start: {at_start}; touch: {touch}; "
            f"bounce of 1.2 ms: no contact, drives at the end {rep['final_joint_steps']}")


def case_probe8(o):
    """The touch probe on PA2 through TIM15 CH1's capture (eight-servo wiring), on
    the hexapod-xy: G38.2 down Z at 600 mm/min, the pin switched PROBE_EDGE_US after
    a tick edge. The board's plants move at the servo timer's update events (every
    100 us), so a joint's position at the edge is its encoder then plus the share of
    the servo period elapsed since the last update (PROBE_EDGE_US mod 100 us) of the
    counts it moves in a servo period, a tenth of what it moved over that tick (the
    board's trace). The latch must equal that within PROBE8_TOLERANCE_COUNTS (a latch
    at the sample would be off by 5.6 servo periods' motion)."""
    machine = os.path.join(ROOT, "examples/machines/hexapod-xy.toml")
    tmp = tempfile.mkdtemp()
    trace = os.path.join(tmp, "probe8.csv")
    b = Board(o.vboard, o.elf8, machine, "probe8", ["--wiring", "servo8", "--trace", trace])
    m = ["--machine", machine]
    if nc_send(o.nc, ["--port", b.port] + m + ["reset"]).returncode != 0:
        b.fail("probe8: reset refused")
    time.sleep(0.5)
    result = {}
    path = os.path.join(tmp, "probe8.ngc")
    with open(path, "w") as f:
        f.write("G21 G90\nG38.2 Z250 F600\nM2\n")
    def run():
        result["r"] = nc_send(o.nc, ["--port", b.port, "--report", "json"] + m + [path])
    t = threading.Thread(target=run)
    t.start()
    # Past a servo's standstill dither: 0.1 mm of leg 1.
    wait_moving(b, "probe8", joint=0, by=10000)
    time.sleep(0.5)
    b.command(f"probe on {PROBE_EDGE_US}")
    t.join(120)
    r = result.get("r")
    rep = b.report()
    b.close()
    if r is None or r.returncode != 0:
        die(f"probe8: nc-send: {r and r.stderr[-1500:]}")
    job = job_json(r, "probe8")
    probes, edges = job.get("probes") or [], rep["probe_edges"]
    if len(probes) != 1 or not probes[0]["contact"] or len(edges) != 1:
        die(f"probe8: probes {probes}, edges {edges}")
    rows = read_trace(trace)
    te = edges[0]["t_s"]
    before = [r for r in rows if r[0] <= te][-1]
    after = [r for r in rows if r[0] > te][0]
    per_unit = [100000] * 6 + [1000] * 2  # counts per mm (the machine file)
    latched = [v * k for v, k in zip(probes[0]["joints"], per_unit)]
    share = (edges[0]["in_tick_us"] % 100.0) / 100.0
    errors, offs = [], []
    # Moving at the edge: every leg at least 100 counts (1 um) a tick, so that a latch
    # at the sample would be off by over 50.
    moved = [abs(after[1 + j] - before[1 + j]) for j in range(6)]
    if min(moved) < 100:
        die(f"probe8: the legs moved {moved} counts over the edge's tick: not a probe in motion")
    for j, (l, e) in enumerate(zip(latched, edges[0]["joint_steps"])):
        expected = e + share * (after[1 + j] - before[1 + j]) / 10
        offs.append(round(l - expected, 2))
        if abs(l - expected) > PROBE8_TOLERANCE_COUNTS:
            errors.append(f"joint {j}: latched {l:.1f} counts, expected {expected:.1f}")
    if errors:
        die("probe8: " + "; ".join(errors))
    return (f"probe8 (PA2, TIM15 CH1 capture, hexapod-xy): edge {edges[0]['in_tick_us']:.3f} us into a tick; "
            f"encoders then {edges[0]['joint_steps']}, latched minus expected {offs} counts")


def main():
    import argparse
    ap = argparse.ArgumentParser()
    ap.add_argument("--elf", default=os.path.join(ROOT, "target/thumbv7em-none-eabihf/release/firmware"))
    ap.add_argument("--elf-servo8", dest="elf8",
                    default=os.path.join(ROOT, "target/vboard-firmware-servo8.elf"))
    ap.add_argument("--nc-send", dest="nc", default=os.path.join(ROOT, "target/debug/nc-send"))
    ap.add_argument("--vboard", default=os.path.join(ROOT, "vboard/target/release/pkmc-vboard"))
    ap.add_argument("cases", nargs="*", default=["square", "dense", "square8", "dense8", "estop", "limit",
                                                 "ampfault", "jam", "unplug", "stall", "replug", "replug-serial", "persist", "determinism",
                                                 "replay", "probe", "probe8", "record"])
    o = ap.parse_args()
    for what, path in (("nc-send", o.nc), ("pkmc-vboard", o.vboard), ("firmware ELF", o.elf)):
        if not os.path.exists(path):
            die(f"{what} not found at {path} (build it first: see .ci/run)")
    rows, notes, failed = [], [], []
    skipped = 0
    tmp = tempfile.mkdtemp()
    for case in o.cases:
        t = time.time()
        if case in JOBS:
            machine, program, wiring = JOBS[case]
            machine = machine and os.path.join(ROOT, machine)
            if program in GENERATED:
                path = os.path.join(tmp, f"{program}.ngc")
                if GENERATED[program](path) is False:
                    print(f"vboard: {case}: SKIPPED (its program comes from ../shared/corpus, "
                          f"which is not beside the repository)", flush=True)
                    skipped += 1
                    continue
                program = path
            else:
                program = os.path.join(ROOT, program)
            sim, job, rep, wall, errors, note = run_job(o, case, machine, program, wiring)
            rows.append(table_row(case, sim, job, rep, wall))
            if note:
                notes.append(f"{case}: {note}")
            chain = [f.split("::{{closure}}")[0] for f in rep["stack"]["lowest_sp_chain"]]
            notes.append(f"{case}: the deepest stack ({rep['stack']['deepest']} B), unwound: "
                         + " ← ".join(chain))
            print(f"vboard: {case}: {wall:.1f} s wall, board {json.dumps(rep['final_joint_steps'])}, "
                  f"sim {json.dumps(sim.get('final_joint_steps'))}", flush=True)
            if errors:
                failed += [f"{case}: {e}" for e in errors]
        else:
            notes.append({"estop": case_estop, "unplug": case_unplug, "persist": case_persist,
                          "limit": case_limit, "ampfault": case_ampfault, "jam": case_jam,
                          "determinism": case_determinism, "replay": case_replay,
                          "stall": case_stall, "replug": case_replug,
                          "replug-serial": case_replug_serial, "probe": case_probe,
                          "probe8": case_probe8, "record": case_record}[case](o))
        print(f"vboard: {case} done in {time.time() - t:.1f} s", flush=True)
    print("\n| job | blocks | motion s | busy % per 1 ms (min / median / p99 / max) | servo start µs "
          "(min / median / p99 / max) | stack deepest / untouched B | blocks/s executed | frames/s accepted "
          "(most in 100 ms) | speed × real time |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(r)
    for n in notes:
        print(f"- {n}")
    if failed:
        for f in failed:
            print(f"vboard: FAIL: {f}")
        sys.exit(1)
    print(f"{len(o.cases) - skipped} passed, 0 failed" + (f", {skipped} skipped" if skipped else ""))


if __name__ == "__main__":
    main()
