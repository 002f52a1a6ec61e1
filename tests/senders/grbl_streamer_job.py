#!/usr/bin/env python3
"""Run one G-code job through the real `grbl-streamer` 2.0.2 package (PyPI)
against a Grbl 1.1 device and print ONE JSON object on stdout.

    python3 grbl_streamer_job.py --port /dev/pts/N --program FILE
        [--mode fast|incremental] [--hold-at SECONDS --resume-at SECONDS]
        [--timeout SECONDS] [--ready-timeout SECONDS] [--baudrate N] [--verbose]

--port also takes a pyserial URL such as socket://127.0.0.1:PORT.
grbl-streamer itself opens `serial.Serial(path, ...)`, which only takes device
paths; for a URL this driver hands grbl-streamer's interface module a
`Serial` that is pyserial's `serial_for_url` (nothing else is changed).

Times (--hold-at, --resume-at and every `t` in the output) are seconds since
`job_run()` was called; earlier entries have negative t.

The sequence is grbl-streamer's own: `cnect()` opens the port and sends
Ctrl-X (0x18); on a line containing "Grbl " it sends `$$`; `poll_start()`
then sends `$#`, `$G`, and `?` every 0.2 s. The job is `load_file()` +
`job_run()` in 'fast' (character counting, 128-byte RX buffer) or
'incremental' (one line per `ok`) mode; hold/resume are `hold()` (`!`) and
`resume()` (`~`). Done when grbl-streamer reports `on_job_completed` (every
line acknowledged) and then a status report taken after that says Idle.

Exit status: 0 completed, 1 Grbl reported error/ALARM, 2 usage, 3 timeout,
4 could not connect / no banner.
"""
import argparse
import json
import os
import re
import signal
import sys
import threading
import time
import types

EXIT_OK, EXIT_JOB_ERROR, EXIT_USAGE, EXIT_TIMEOUT, EXIT_SETUP = 0, 1, 2, 3, 4


def parse_args(argv):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--port", required=True, help="device path (/dev/pts/N) or pyserial URL (socket://host:port)")
    ap.add_argument("--program", required=True)
    ap.add_argument("--mode", choices=["fast", "incremental"], default="fast",
                    help="fast = character counting (default), incremental = send-response")
    ap.add_argument("--hold-at", type=float, default=None)
    ap.add_argument("--resume-at", type=float, default=None)
    ap.add_argument("--timeout", type=float, default=120.0)
    ap.add_argument("--ready-timeout", type=float, default=15.0)
    ap.add_argument("--baudrate", type=int, default=115200)
    ap.add_argument("--verbose", action="store_true", help="log events to stderr")
    a = ap.parse_args(argv)
    if not os.path.isfile(a.program):
        ap.exit(EXIT_USAGE, "grbl_streamer_job: program file not found: %s\n" % a.program)
    if (a.hold_at is None) != (a.resume_at is None):
        ap.exit(EXIT_USAGE, "grbl_streamer_job: --hold-at and --resume-at go together\n")
    if a.hold_at is not None and a.resume_at <= a.hold_at:
        ap.exit(EXIT_USAGE, "grbl_streamer_job: --resume-at must be later than --hold-at\n")
    return a


class Failure(Exception):
    def __init__(self, code, msg):
        super().__init__(msg)
        self.code = code


def use_serial_for_url():
    """Let grbl-streamer's Interface open pyserial URLs (socket://...)."""
    import serial
    import grbl_streamer.interface as iface_mod
    shim = types.SimpleNamespace(**{k: getattr(serial, k) for k in dir(serial) if not k.startswith("__")})
    shim.Serial = lambda *args, **kw: serial.serial_for_url(*args, **kw)
    iface_mod.serial = shim


def parse_status_fields(raw):
    """Ov and Bf from a raw Grbl 1.1 report (grbl-streamer itself ignores them)."""
    out = {"ov": None, "buf": None}
    if not raw:
        return out
    m = re.search(r"\|Ov:(\d+),(\d+),(\d+)", raw)
    if m:
        out["ov"] = [int(x) for x in m.groups()]
    m = re.search(r"\|Bf:(\d+),(\d+)", raw)
    if m:
        out["buf"] = {"planner": int(m.group(1)), "rx": int(m.group(2))}
    return out


class Job:
    def __init__(self, args):
        self.a = args
        self.lock = threading.Condition()
        self.t_launch = time.monotonic()
        self.t_start = None
        self.events_log = []
        self.booted = 0
        self.boot_t = None
        self.oks = 0
        self.oks_at_boot = 0
        self.sys_writes = 0     # $$ / $# / $G written since boot
        self.sys_writes_at_boot = 0
        self.reads = []
        self.writes = []
        self.errors = []
        self.alarms = []
        self.probes = []
        self.timeline = []
        self.actions = []
        self.lines_sent = 0
        self.lines_acked = 0
        self.job_running = False
        self.job_completed_t = None
        self.status_reports = []  # (mono t, raw, cmode)
        self.last_cmode = None
        self.last_ov = None
        self.streamer = None
        self.version = None
        self.thread_crash = None
        threading.excepthook = self.on_thread_exception

    def on_thread_exception(self, hook_args):
        import traceback
        text = "".join(traceback.format_exception(hook_args.exc_type, hook_args.exc_value, hook_args.exc_traceback))
        with self.lock:
            if self.thread_crash is None:
                self.thread_crash = "%s in thread %s: %s" % (
                    hook_args.exc_type.__name__, getattr(hook_args.thread, "name", "?"), hook_args.exc_value)
                self.thread_crash_trace = text
            self.lock.notify_all()

    # -------------------------------------------------------------- utils
    def now(self):
        return time.monotonic()

    def rel(self, t):
        ref = self.t_start if self.t_start is not None else self.t_launch
        return round(t - ref, 3)

    def log(self, msg):
        if self.a.verbose:
            sys.stderr.write("[grbl_streamer_job %.3f] %s\n" % (self.now() - self.t_launch, msg))

    # -------------------------------------------------------------- callbacks
    def callback(self, event, *data):
        t = self.now()
        with self.lock:
            if event == "on_boot":
                self.booted += 1
                self.boot_t = t
                self.oks_at_boot = self.oks
                self.sys_writes_at_boot = self.sys_writes
                self.log("on_boot")
            elif event == "on_read":
                line = str(data[0])
                self.reads.append({"t": t, "line": line})
            elif event == "on_write":
                line = str(data[0])
                self.writes.append({"t": t, "data": line})
                if line.startswith("$"):
                    self.sys_writes += 1
            elif event == "on_rx_buffer_percent":
                # emitted exactly once per `ok` grbl-streamer reads
                self.oks += 1
            elif event == "on_line_sent":
                if self.job_running:
                    self.lines_sent += 1
            elif event == "on_processed_command":
                if self.job_running:
                    self.lines_acked += 1
            elif event == "on_job_completed":
                if self.job_running and self.job_completed_t is None:
                    self.job_completed_t = t
                    self.log("on_job_completed")
            elif event == "on_error":
                line, cmd, ln = data
                self.errors.append({"t": t, "line": str(line), "command": cmd, "line_number": ln})
                self.log("on_error %r" % (data,))
            elif event == "on_probe":
                # a [PRB:x,y,z:c] line (after a probing move, and in `$#`'s answer):
                # grbl-streamer passes its x y z
                self.probes.append({"t": t, "at": list(data[0])})
            elif event == "on_alarm":
                self.alarms.append({"t": t, "line": str(data[0])})
                self.log("on_alarm %r" % (data,))
            elif event == "on_stateupdate":
                cmode = data[0]
                if cmode != self.last_cmode:
                    self.last_cmode = cmode
                    self.timeline.append({"t": t, "state": cmode})
                    self.log("state %s" % cmode)
            elif event == "on_log":
                rec = data[0]
                msg = rec.getMessage() if hasattr(rec, "getMessage") else str(rec)
                self.events_log.append({"t": t, "level": getattr(rec, "levelname", ""), "msg": msg})
                if self.a.verbose and getattr(rec, "levelno", 0) >= 30:
                    self.log("log %s: %s" % (getattr(rec, "levelname", ""), msg))
            self.lock.notify_all()

    def on_status(self, raw, cmode):
        with self.lock:
            self.status_reports.append((self.now(), raw, cmode))
            ov = parse_status_fields(raw)["ov"]
            if ov is not None:
                self.last_ov = ov
            del self.status_reports[:-50]
            self.lock.notify_all()

    def wait_for(self, cond, timeout, what):
        deadline = self.now() + timeout
        with self.lock:
            while True:
                if self.thread_crash:
                    raise Failure(EXIT_JOB_ERROR, "grbl-streamer crashed (its reader thread is dead, it will not read "
                                  "another byte): %s" % self.thread_crash)
                r = cond()
                if r:
                    return r
                left = deadline - self.now()
                if left <= 0:
                    raise Failure(EXIT_TIMEOUT, "timed out waiting for %s" % what)
                self.lock.wait(min(left, 0.1))

    # -------------------------------------------------------------- run
    def make_streamer(self):
        import grbl_streamer
        from grbl_streamer import GrblStreamer
        from importlib.metadata import version
        try:
            self.version = version("grbl-streamer")
        except Exception:  # noqa: BLE001
            self.version = None
        job = self

        stream_lock = threading.Lock()

        class RecordingStreamer(GrblStreamer):
            # grbl-streamer calls back on a state *change* only; to know that a
            # report is fresh we also note every report it parses.
            def _update_state(self, line):
                super()._update_state(line)
                job.on_status(line, self.cmode)

            # grbl-streamer 2.0.2 fills Grbl's receive buffer from two threads with no
            # lock: `job_run()` calls `_stream()` in the caller's thread, and its reader
            # thread calls it on every `ok`. Both can find the current line unsent and
            # write it, or move past one unwritten: under CPU load a line went out
            # twice (a probing program's `G00Z2` after the G38.2 written twice, the
            # machine rightly ending 2 mm higher; a `G90` twice and a G1 skipped on a
            # 1 000-line job). One lock around `_stream()` makes each fill whole;
            # nothing else of the sender changes.
            def _stream(self):
                with stream_lock:
                    super()._stream()

        if "://" in self.a.port:
            use_serial_for_url()
        gs = RecordingStreamer(self.callback, name="job")
        gs.setup_logging()
        _ = grbl_streamer
        return gs

    def run(self):
        a = self.a
        deadline = self.t_launch + a.timeout
        left = lambda: max(0.05, deadline - self.now())  # noqa: E731
        gs = self.streamer = self.make_streamer()
        self.log("cnect(%s, %d)" % (a.port, a.baudrate))
        try:
            gs.cnect(a.port, a.baudrate)   # opens the port, sends Ctrl-X
        except Exception as e:  # noqa: BLE001
            raise Failure(EXIT_SETUP, "grbl-streamer could not open %s: %s" % (a.port, e))
        self.wait_for(lambda: self.booted > 0, min(left(), a.ready_timeout),
                      "the Grbl banner after Ctrl-X (a line containing 'Grbl ')")
        gs.poll_start()                   # $# then $G then ? every 0.2 s
        self.wait_for(lambda: self.status_reports, min(left(), a.ready_timeout),
                      "a status report grbl-streamer can parse (<State|MPos:...|...> or <State|WPos:...|...>)")
        # $$ (sent on boot), $#, $G: every system command answered with ok,
        # and Idle; then quiet for 3 poll periods so that no late `ok` can be
        # taken for a program line's.
        quiet = {"since": self.now(), "sig": None}

        def ready():
            if self.alarms or (self.last_cmode or "").startswith("Alarm"):
                raise Failure(EXIT_JOB_ERROR, "Grbl is in Alarm state")
            sig = (self.oks, self.sys_writes)
            if sig != quiet["sig"]:
                quiet["sig"], quiet["since"] = sig, self.now()
            answered = self.oks - self.oks_at_boot >= self.sys_writes - self.sys_writes_at_boot
            return (self.sys_writes - self.sys_writes_at_boot >= 3 and answered and gs.cmode == "Idle"
                    and self.now() - quiet["since"] >= 0.6)
        self.wait_for(ready, min(left(), a.ready_timeout),
                      "answers (ok) to $$, $# and $G, and an Idle report")

        gs.incremental_streaming = (a.mode == "incremental")
        gs.load_file(a.program)
        self.lines_total = gs.buffer_size
        self.log("loaded %d lines, mode %s" % (gs.buffer_size, a.mode))
        with self.lock:
            self.t_start = self.now()
            self.job_running = True
            self.actions.append({"t": self.t_start, "command": "job_run"})
        timers = []
        if a.hold_at is not None:
            timers.append(threading.Timer(a.hold_at, self.action, ("hold", gs.hold)))
            timers.append(threading.Timer(a.resume_at, self.action, ("resume", gs.resume)))
        for tm in timers:
            tm.daemon = True
            tm.start()
        self.timers = timers
        gs.job_run()

        def done():
            if self.alarms:
                return "alarm"
            if self.errors:
                return "error"
            if self.job_completed_t is None:
                return None
            for t, _raw, cmode in reversed(self.status_reports):
                if t < self.job_completed_t + 0.25:
                    break
                if cmode == "Idle":
                    return "ok"
            return None
        how = self.wait_for(done, left(), "the end of the job (all lines acknowledged, then an Idle report)")
        if how != "ok":
            time.sleep(0.5)  # collect what follows the error
            if self.alarms:
                raise Failure(EXIT_JOB_ERROR, "Grbl raised an alarm: %s" % self.alarms[0]["line"])
            e = self.errors[0]
            raise Failure(EXIT_JOB_ERROR, "Grbl answered %s to %r (buffer line %s); grbl-streamer halted the job"
                          % (e["line"], e["command"], e["line_number"]))

    def action(self, name, fn):
        with self.lock:
            self.actions.append({"t": self.now(), "command": name})
        self.log("action %s" % name)
        fn()

    # -------------------------------------------------------------- output
    def result(self, code, message):
        gs = self.streamer
        last = self.status_reports[-1] if self.status_reports else None
        extra = parse_status_fields(last[1] if last else None)
        if extra["ov"] is None:
            extra["ov"] = self.last_ov   # Grbl sends Ov: only every 10-20 reports

        def rel_list(lst):
            return [dict(e, t=self.rel(e["t"])) for e in lst]
        return {
            "sender": "grbl-streamer",
            "sender_version": self.version,
            "mode": self.a.mode,
            "ok": code == EXIT_OK,
            "result": "completed" if code == EXIT_OK else ("timeout" if code == EXIT_TIMEOUT else "error"),
            "message": message,
            "port": self.a.port,
            "program": self.a.program,
            "lines_total": getattr(self, "lines_total", None),
            "lines_sent": self.lines_sent,
            # Motion lines (G0/G1) grbl-streamer wrote to the port: what the bridge was
            # sent, whatever the sender's own bookkeeping (a race between its reader
            # thread and job_run can write a line twice and skip another).
            "motion_lines_written": sum(
                1 for w in self.writes
                if re.match(r"\s*G0*[01](?![0-9.])", w["data"], re.IGNORECASE)
            ),
            "lines_received": self.lines_acked,
            "errors": rel_list(self.errors),
            "alarms": rel_list(self.alarms),
            "probes": rel_list(self.probes),
            "last_status": None if last is None else {
                "state": gs.cmode if gs else None,
                "mpos": list(gs.cmpos) if gs else None,
                "wpos": list(gs.cwpos) if gs else None,
                "ov": extra["ov"],
                "buf": extra["buf"],
                "raw": last[1],
                "age_s": round(self.now() - last[0], 3),
            },
            "state_timeline": rel_list(self.timeline),
            "actions": rel_list(self.actions),
            "writes": rel_list([w for w in self.writes if w["data"] not in ("?",)][:200]),
            "serial_read_tail": rel_list(self.reads[-60:]),
            "status_reports": len(self.status_reports),
            "job_completed_t": None if self.job_completed_t is None else self.rel(self.job_completed_t),
            "elapsed_s": None if self.t_start is None else round(self.now() - self.t_start, 3),
            "log_tail": rel_list(self.events_log[-30:]) if code != EXIT_OK else None,
            "thread_crash": getattr(self, "thread_crash_trace", None),
        }

    def shutdown(self):
        for tm in getattr(self, "timers", []):
            tm.cancel()
        gs = self.streamer
        if gs is None:
            return
        th = threading.Thread(target=gs.disconnect, daemon=True)
        th.start()
        th.join(5.0)
        if th.is_alive():
            sys.stderr.write("grbl_streamer_job: grbl-streamer did not disconnect within 5 s\n")


def main():
    args = parse_args(sys.argv[1:])
    job = Job(args)

    def on_signal(signum, _frame):
        raise KeyboardInterrupt("signal %d" % signum)
    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGHUP, on_signal)
    code, message = EXIT_OK, None
    watchdog = threading.Timer(args.timeout + 10, lambda: os._exit(EXIT_TIMEOUT))
    watchdog.daemon = True
    watchdog.start()
    try:
        job.run()
    except Failure as e:
        code, message = e.code, str(e)
    except KeyboardInterrupt:
        code, message = EXIT_SETUP, "interrupted"
    except Exception as e:  # noqa: BLE001
        code, message = EXIT_SETUP, "internal error: %r" % (e,)
    out = job.result(code, message)
    job.shutdown()
    if message:
        sys.stderr.write("grbl_streamer_job: %s\n" % message)
    sys.stdout.write(json.dumps(out) + "\n")
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)   # grbl-streamer's threads are not daemons; never hang on exit


if __name__ == "__main__":
    main()
