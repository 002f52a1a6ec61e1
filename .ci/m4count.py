#!/usr/bin/env python3
"""Cortex-M4 instruction counts, emulated: the kinematics, the servo period and whole
controller calls over whole programs; fails above the budgets.

    python3 .ci/m4count.py                     # build, count, print the tables, check budgets
    python3 .ci/m4count.py --enforce-realtime  # also fail above the real-time budgets (issue 9)
    python3 .ci/m4count.py --enforce-realtime=tick,period,lock,helpers   # those only (CI)
    M4COUNT_FULL=1 ...                         # every function of the worst calls, with counts
    M4COUNT_WATCH='<regex>' ...                # who calls the matching symbols in the worst calls
    python3 .ci/m4count.py --no-build          # reuse the last builds (harness debugging only)
    M4COUNT_ONLY='<regex>' ...                 # replay only the matching programs (debugging only)

Builds perf/m4count (its own workspace, with a copy of the workspace's Cargo.lock)
twice: for thumbv7em-none-eabihf (release, the firmware's profile: opt-level "s", fat
LTO, one codegen unit, -C target-cpu=cortex-m4) and for the host (profile `host`),
whose run prints the benchmark cases with the host's results and, with `--record`,
records whole programs call by call (perf/m4count/src/record.rs). Each case is then run in
the unicorn emulator (Cortex-M4 model, FPU on): the measured function is called with
arguments in emulated RAM and its executed instructions are counted by a basic-block
hook, each block's instructions counted once by disassembling it with capstone (cached
per block). Per-instruction hooks are not used: QEMU skips the code hook for
instructions of an IT block whose condition fails, which a block count includes (they
still take an issue slot on the core). Every emulated result must equal the host's.

Servo periods: `ServoBank::period_into` of whole banks (`servo_*`, perf/m4count/src/servo.rs)
and the servo interrupt's whole `ServoPacer::period` on the same banks (`pacer_*`,
pacer.rs): the tick edge's command (read in place, as from the firmware's mailbox),
the bank, the DAC sums, the snapshot and, `_rec8`, the data recorder staging 8 signals
every period; the staged samples must equal the host's too.

Whole calls: each recorded program is replayed on one emulated `Controller`, built in
emulated RAM for its machine, call by call in the recorded order: `receive` of each
USB packet, `tick` with the recorded inputs, `record_servo` with the servo-period
samples the simulator handed to the data recorder after a tick (programs that record
every servo period), `transmit` into 64-byte buffers. Every tick's outputs and every
transmitted byte must equal the host's. Counted per call:
the whole `Controller::receive`, `tick`, `record_servo` or `transmit` call including
the few instructions of its C-ABI wrapper (`bench_ctrl_*`); a tick's budget is the tick
with the `record_servo` calls after it (the firmware makes them under the same lock). A receive is also split at the
frames it completes (per frame: from the call's start, or the end of the previous
frame's work, to the first read of the byte after the frame's delimiter, found by a
memory-read hook on the packet). The worst 1 ms period is one tick plus every
receive and transmit call between it and the previous tick plus the ten servo periods
of one tick of the program's machine, as the servo interrupt runs them
(SERVO_OF_MACHINE: the sum of the ten measured periods of `pacer_ccpm_4axes` for the
H-4 and the hexapod, of `pacer_hexapod_xy_8ch` for the hexapod-xy: the first period of a
tick takes the command and computes the path frame, the other nine reuse it; a program
may name another bench, as those recording every servo period name the pacer staging
the recorder's signals); the lock-held
figure is the longest single call (a tick with its `record_servo` calls as one) (the firmware makes each under the controller's
lock). Executed symbols of every counted call are checked for soft-float `f64`
helpers, 64/128-bit division (the helpers, and LLVM's inline expansion of 128-bit
division, recognised as a block that loops on itself with six or more
subtract-with-carry instructions) and software square roots.

The harness assumes no number of machines or servo channels: machines and servo
benches are indices (MACHINES, SERVO_BENCHES, as the Rust side), and the word counts
of the logged tick inputs and outputs come from the host run's first line (`wire`),
checked against the image's `bench_wire_words`.

Needs: Python 3, `pip install unicorn capstone` (tested with unicorn 2.1.4, capstone
5.0.9), the Rust toolchain with the thumbv7em-none-eabihf target.
"""

import bisect
import os
import re
import shutil
import struct
import subprocess
import sys
import time

try:
    import capstone
    from unicorn import Uc, UcError, UC_ARCH_ARM, UC_MODE_THUMB, UC_MODE_MCLASS, UC_HOOK_BLOCK, UC_HOOK_MEM_READ
    from unicorn import arm_const as A
except ImportError:
    sys.exit("m4count: needs `pip install unicorn capstone`")

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CRATE = os.path.join(ROOT, "perf", "m4count")
TARGET = "thumbv7em-none-eabihf"
TARGET_DIR = os.path.join(CRATE, "target")
ELF = os.path.join(TARGET_DIR, TARGET, "release", "pkmc-m4count")
HOST_BIN = os.path.join(TARGET_DIR, "host", "pkmc-m4count")
CALLS_DIR = os.path.join(TARGET_DIR, "calls")  # recorded programs (perf/m4count/src/record.rs)

# Instruction budgets per call (docs/performance.md).
# The servo banks are budgeted per tick, the sum of a tick's ten periods (`*_tick`: the
# servo work of one 1 ms period; the first period of a tick computes the path frame).
# The 4-axis bank is back within issue 9's 20 000 (10 x 2 000) since the period runs in
# one pass (docs/performance.md); the hexapod-xy's bank (six LQG legs, two PID table
# axes, CCPM through the pose map): its measurement + ~10 %. The servo interrupt's whole
# work (the pacer benches: the edge's command read in place, the bank, the DAC sums, the
# snapshot and, `_rec8`, the data recorder staging 8 signals every period, issue 35)
# keeps within its bank's budget.
BUDGETS = {"h4_ik": 600, "hexapod_ik": 1000, "servo_ccpm_4axes_tick": 20_000, "h4_period": 1500,
           "hexapod_xy_ik": 2000, "servo_hexapod_xy_8ch_tick": 36_000,
           "pacer_ccpm_4axes_tick": 20_000, "pacer_ccpm_4axes_rec8_tick": 20_000,
           "pacer_hexapod_xy_8ch_tick": 36_000, "pacer_hexapod_xy_8ch_rec8_tick": 36_000}
# Machines whose whole-call real-time budgets --enforce-realtime enforces (all of them;
# a machine left out would be printed with its verdict but not fail the run).
ENFORCED_MACHINES = {0, 1, 2}
# Machines and servo benches by index, as perf/m4count/src/main.rs (`machine`) and
# servo.rs (`bank`).
MACHINES = {0: "h4", 1: "hexapod", 2: "hexapod_xy"}
SERVO_BENCHES = {0: "servo_ccpm_4axes", 1: "servo_hexapod_xy_8ch"}
# The pacer benches by index, as perf/m4count/src/pacer.rs (`pacer`), and the servo bench
# whose feedback each runs.
PACER_BENCHES = {0: "pacer_ccpm_4axes", 1: "pacer_ccpm_4axes_rec8", 2: "pacer_hexapod_xy_8ch",
                 3: "pacer_hexapod_xy_8ch_rec8"}
# The servo interrupt whose worst tick stands for a machine's ten servo periods in its
# 1 ms figure: the pacer bench of its bank (the hexapod has no servo channel: the 4-axis
# bank's stands for it), unless the program names its own (the recording programs that
# sample every servo period: the pacer staging the recorder's signals).
SERVO_OF_MACHINE = {0: "pacer_ccpm_4axes", 1: "pacer_ccpm_4axes", 2: "pacer_hexapod_xy_8ch"}
# Real-time budgets of whole controller calls (issue 9), instructions; enforced with
# --enforce-realtime only.
RT_BUDGETS = [
    ("tick", "any tick (+ its record_servo)", 10_000),
    ("frame", "any receive of one frame", 5_000),
    ("period", "worst 1 ms period", 102_000),
    ("lock", "lock held (longest single call)", 20_000),
]
SERVO_PER_TICK = 10  # 10 kHz servo periods per 1 kHz tick

FLASH, FLASH_SIZE = 0x0800_0000, 0x8_0000
RAM, RAM_SIZE = 0x2000_0000, 0x10_0000  # 1 MiB: more than the MCU, room for the controller
RET = FLASH + FLASH_SIZE - 0x100  # return address: a `b .` placed at the end of flash
KIN = RAM + 0x1000  # MachineKinematics (1024 bytes reserved)
ARG = RAM + 0x2000  # argument buffers
BANK = RAM + 0x3000  # ServoBank (4096 bytes reserved)
PERIOD = RAM + 0x4000  # Period (96 KiB reserved: up to RAM + 0x1C000)
PERIOD_WARMUP, PERIOD_CHUNK = 1600, 200  # as perf/m4count/src/main.rs
PACER = RAM + 0x6_0000  # BenchPacer (8192 bytes reserved, PACER_BYTES in pacer.rs)
MAX_SIGNALS = 8  # the recorder's signals (record_servo's rows)
CALL = RAM + 0x1_C000  # whole-call buffers: a packet, input words (up to 128), output
# words (up to 256), one `Inputs` (INPUTS_BYTES, as perf/m4count/src/main.rs), a
# transmit buffer, record_servo's ids and rows (up to 16 rows)
PACKET, IN_WORDS_A, OUT_WORDS_A, INPUTS, TXBUF = CALL, CALL + 0x100, CALL + 0x500, CALL + 0xD00, CALL + 0x1500
REC_IDS, REC_ROWS = CALL + 0x1600, CALL + 0x1640
CTRL = RAM + 0x2_0000  # Controller (CTRL_BYTES reserved)
CTRL_BYTES = 192 * 1024  # as perf/m4count/src/main.rs
STACK_TOP = RAM + RAM_SIZE  # the stack grows down from the end of RAM (to CTRL + CTRL_BYTES)
# Words of a tick's inputs and outputs, channels (MAX_SERVOS) and pose axes of the
# contour error: from the host run's `wire` line (perf/m4count/src/wire.rs).
WIRE = {}
USB_PACKET = 64
MAX_STEPS = 20_000_000  # instructions: a runaway call stops here


def build(crate=CRATE, target_dir=TARGET_DIR):
    """Builds the harness at `crate` (its own workspace, with its own link.ld) for the
    M4 and for the host (profile `host`) into `target_dir`."""
    # The workspace's lock file, so the measured build resolves the firmware's exact
    # dependency versions (cargo adds the harness package to this copy).
    shutil.copyfile(os.path.join(ROOT, "Cargo.lock"), os.path.join(crate, "Cargo.lock"))
    env = dict(os.environ)
    env.pop("CARGO_TARGET_DIR", None)
    link = os.path.join(crate, "link.ld")
    env["RUSTFLAGS"] = f"-C target-cpu=cortex-m4 -C link-arg=-T{link}"
    env[f"CARGO_TARGET_{TARGET.upper().replace('-', '_')}_LINKER"] = "rust-lld"
    subprocess.run(
        ["cargo", "build", "--release", "--target", TARGET, "--target-dir", target_dir],
        cwd=crate, env=env, check=True)
    env.pop("RUSTFLAGS")
    subprocess.run(["cargo", "build", "--profile", "host", "--target-dir", target_dir],
                   cwd=crate, env=env, check=True)


def host_cases():
    out = subprocess.run([HOST_BIN], cwd=CRATE, check=True, capture_output=True, text=True).stdout
    cases = [line.split() for line in out.splitlines() if line.strip()]
    if not cases or cases[0][0] != "wire":
        sys.exit("m4count: the host run did not start with its `wire` line")
    WIRE.update(zip(("inputs", "outputs", "servos", "pose_axes"), map(int, cases[0][1:5])))
    if WIRE["inputs"] > 128 or WIRE["outputs"] > 256:
        sys.exit(f"m4count: {WIRE} words do not fit the buffers at CALL")
    return cases[1:]


def record_programs():
    """Runs the programs through nc-send's client on the host; returns, per program,
    (name, machine, log path, blocks, servo bench of its 1 ms figure or None, whether it
    arms the data recorder)."""
    out = subprocess.run([HOST_BIN, "--record", CALLS_DIR], cwd=CRATE, check=True,
                         capture_output=True, text=True).stdout
    programs = []
    for line in out.splitlines():
        f = line.split()
        if f and f[0] == "program":
            programs.append((f[1], int(f[2]), f[3], int(f[4]), None if f[9] == "-" else f[9],
                             f[10] == "armed"))
    return programs


def read_elf(path):
    """PT_LOAD segments and function symbols (name: (address, size)) of a 32-bit
    little-endian ELF."""
    data = open(path, "rb").read()
    if data[:4] != b"\x7fELF" or data[4] != 1 or data[5] != 1:
        sys.exit(f"m4count: {path} is not a 32-bit little-endian ELF")
    (e_phoff, e_shoff) = struct.unpack_from("<II", data, 28)
    (e_phentsize, e_phnum, e_shentsize, e_shnum, e_shstrndx) = struct.unpack_from("<HHHHH", data, 42)
    segments = []
    for i in range(e_phnum):
        p_type, p_offset, p_vaddr, _p_paddr, p_filesz, p_memsz = struct.unpack_from(
            "<IIIIII", data, e_phoff + i * e_phentsize)
        if p_type == 1:
            segments.append((p_vaddr, data[p_offset:p_offset + p_filesz], p_memsz))
    sections = [struct.unpack_from("<IIIIIIIIII", data, e_shoff + i * e_shentsize) for i in range(e_shnum)]
    symbols = {}
    for s in sections:
        if s[1] != 2:  # SHT_SYMTAB
            continue
        strtab = sections[s[6]]
        for off in range(s[4], s[4] + s[5], 16):
            st_name, st_value, st_size, st_info = struct.unpack_from("<IIIB", data, off)
            name_off = strtab[4] + st_name
            name = data[name_off:data.index(b"\0", name_off)].decode()
            if st_info & 0xF == 2:  # STT_FUNC
                symbols[name] = (st_value, st_size)
    return segments, symbols


# --- Rust symbol names -----------------------------------------------------------

LEGACY_ESCAPES = {"$SP$": "@", "$BP$": "*", "$RF$": "&", "$LT$": "<", "$GT$": ">", "$LP$": "(",
                  "$RP$": ")", "$C$": ",", "$u20$": " ", "$u27$": "'", "$u5b$": "[", "$u5d$": "]",
                  "$u7b$": "{", "$u7d$": "}", "$u3b$": ";", "$u2b$": "+", "$u22$": '"', "$u7e$": "~"}


def demangle(name):
    """Readable form of a Rust symbol (legacy `_ZN…E` or the simple v0 `_R` paths that
    compiler_builtins uses); other names unchanged."""
    if name.startswith("_ZN") and name.endswith("E"):
        parts, i, body = [], 0, name[3:-1]
        while i < len(body) and body[i].isdigit():
            j = i
            while body[j].isdigit():
                j += 1
            n = int(body[i:j])
            parts.append(body[j:j + n])
            i = j + n
        if parts and re.fullmatch(r"h[0-9a-f]{16}", parts[-1]):
            parts.pop()
        text = "::".join(parts)
        for k, v in LEGACY_ESCAPES.items():
            text = text.replace(k, v)
        text = text.replace("..", "::")
        return text[1:] if text.startswith("_<") else text
    if name.startswith("_R"):
        try:
            idents, _ = v0_path(name, 2)
            return "::".join(idents)
        except (IndexError, ValueError):
            return name
    return name


def v0_path(s, i):
    """Identifiers of a v0 nested path at s[i:] (`C` crate roots and `N` nested paths
    only, what compiler_builtins' symbols use); raises ValueError on anything else."""
    c = s[i]
    if c == "C":
        i = v0_ident(s, v0_disambiguator(s, i + 1))
        return [i[0]], i[1]
    if c == "N":
        parent, i = v0_path(s, i + 2)
        ident, i = v0_ident(s, v0_disambiguator(s, i))
        return parent + [ident], i
    raise ValueError(s)


def v0_disambiguator(s, i):
    return s.index("_", i) + 1 if s[i] == "s" else i


def v0_ident(s, i):
    if s[i] == "u":
        i += 1
    j = i
    while s[j].isdigit():
        j += 1
    if j == i:
        raise ValueError(s)
    n = int(s[i:j])
    if s[j] == "_":
        j += 1
    return s[j:j + n], j + n


# Helpers that must not run in a counted tick or receive (issue 9), by category.
SOFT_DOUBLE = re.compile(r"^_+(aeabi_(d[a-z0-9]+|f2d|i2d|ui2d|l2d|ul2d)|\w*df\d?|\w*df\w*)$")
WIDE_DIV = {"__aeabi_ldivmod", "__aeabi_uldivmod", "__udivmoddi4", "__divmoddi4", "__divdi3",
            "__udivdi3", "__moddi3", "__umoddi3", "__udivti3", "__divti3", "__umodti3",
            "__modti3", "__udivmodti4", "__divmodti4"}
# The C names of f64 math functions (compiler_builtins exports some, unmangled).
C_MATH_F64 = {"fmin", "fmax", "floor", "ceil", "trunc", "round", "fabs", "fma", "atan", "atan2",
              "sin", "cos", "exp", "log", "pow", "hypot", "cbrt", "fmod"}
INLINE_WIDE_DIV = "inline 128-bit division loop"
# Longest loop (instructions, and bytes from the branch's target to the branch) taken for
# LLVM's inline 128-bit division loop; the canary (`bench_wide_division`) checks that a
# real one is still recognised.
WIDE_DIV_MAX_BLOCK = 120
WIDE_DIV_MAX_BYTES = 400


def forbidden_kind(name):
    """Category of a forbidden helper, or None; `name` demangled."""
    last = name.split("::")[-1]
    if last in WIDE_DIV or "specialized_div_rem" in name:
        return "64/128-bit division"
    if last in ("sqrt", "sqrtf") or (name.startswith("libm::") and "sqrt" in name):
        return "software square root"
    if SOFT_DOUBLE.match(last):
        return "soft-float f64"
    if (name.startswith("libm::") and not last.endswith("f")) or name in C_MATH_F64:
        return "soft-float f64"  # libm's f64 functions (atan2, round, fmin, ...)
    return None


class M4:
    def __init__(self, elf):
        segments, self.symbols = read_elf(elf)
        self.uc = Uc(UC_ARCH_ARM, UC_MODE_THUMB | UC_MODE_MCLASS)
        self.uc.ctl_set_cpu_model(A.UC_CPU_ARM_CORTEX_M4)
        self.uc.mem_map(FLASH, FLASH_SIZE)
        self.uc.mem_map(RAM, RAM_SIZE)
        for vaddr, content, memsz in segments:
            if RAM <= vaddr < RAM + RAM_SIZE and vaddr + memsz > KIN:
                sys.exit("m4count: the image's static data overlaps the benchmark buffers")
            self.uc.mem_write(vaddr, content + b"\0" * (memsz - len(content)))
        self.uc.mem_write(RET, b"\xfe\xe7")  # b .
        # Full access to CP10/CP11 (the FPU), as the firmware's start-up code sets it.
        self.uc.reg_write(A.UC_ARM_REG_C1_C0_2, 0xF << 20)
        self.md = capstone.Cs(capstone.CS_ARCH_ARM, capstone.CS_MODE_THUMB | capstone.CS_MODE_MCLASS)
        self.block_len = {}
        self.wide_div_blocks = set()
        self.count = 0
        self.trace = []  # blocks of the current call, in order
        self.uc.hook_add(UC_HOOK_BLOCK, self._block)
        # Debugging aid (M4COUNT_WATCH=<regex of symbols>): who calls them in the worst
        # calls, with r1 and r2 (memcpy/memclr: source or size, size or fill).
        self.mem_watch = None
        self.mem_calls = []
        if os.environ.get("M4COUNT_WATCH"):
            self.mem_watch = {a & ~1: n for n, (a, _) in self.symbols.items()
                              if re.search(os.environ["M4COUNT_WATCH"], n)}
        # Functions by address, for attributing blocks (Thumb bit cleared).
        funcs = sorted(((a & ~1, sz, demangle(n)) for n, (a, sz) in self.symbols.items()), key=lambda f: f[0])
        self.func_starts = [f[0] for f in funcs]
        self.funcs = funcs
        self.reads = None  # (offset, count) of packet bytes read, while a receive runs
        self.uc.hook_add(UC_HOOK_MEM_READ, self._read, begin=PACKET, end=PACKET + USB_PACKET - 1)

    def _block(self, uc, address, size, _user):
        key = (address, size)
        n = self.block_len.get(key)
        if n is None:
            n = self._learn(uc, key)
        self.count += n
        self.trace.append(key)
        if self.mem_watch is not None and address in self.mem_watch:
            lr = uc.reg_read(A.UC_ARM_REG_LR) & ~1
            self.mem_calls.append((self.mem_watch[address], self.function_of(lr), lr,
                                   uc.reg_read(A.UC_ARM_REG_R2), uc.reg_read(A.UC_ARM_REG_R1)))

    def _learn(self, uc, key):
        """Instructions of a new block; notes LLVM's inline wide-division loop."""
        address, size = key
        code = bytes(uc.mem_read(address, size))
        insns = list(self.md.disasm_lite(code, address))
        n = len(insns)
        self.block_len[key] = n
        if insns:
            _, _, mnemonic, op = insns[-1]
            m = re.fullmatch(r"#(0x[0-9a-f]+)", op.strip())
            loops = mnemonic.split(".")[0] in ("b", "beq", "bne", "bhs", "blo", "bhi", "bls", "bge",
                                              "blt", "bgt", "ble", "bmi", "bpl", "bcs", "bcc")
            # A loop: a branch back to this block or to code before it. The emulator splits
            # LLVM's division loop where other branches join it, so the block that closes
            # the loop may hold none of its arithmetic: the whole range from the branch's
            # target to the branch is read.
            target = int(m.group(1), 16) if m else None
            if loops and target is not None and address + size - WIDE_DIV_MAX_BYTES <= target < address + size:
                start = min(target, address)
                body = list(self.md.disasm_lite(bytes(uc.mem_read(start, address + size - start)), start))
                # LLVM's shift-and-subtract loop is short (about 60 instructions on the
                # M4): a 128-bit shift left by one (limbs joined with `lsr #31`), a
                # 128-bit compare, subtract and a wide counter counted down by one (its
                # upper limbs borrow with `sbc rX, rX, #0`).
                # Other 64-bit arithmetic has carries too and is not counted: a two-pass
                # sincos of 64-bit angles, or i64 magnitudes (`asr #31` sign masks) ahead of
                # a spline's loop, were once taken for it.
                carries = sum(1 for i in body if i[2].split(".")[0] in ("sbc", "sbcs"))
                joins = sum(1 for i in body if i[3].replace(" ", "").endswith("lsr#31"))
                borrows = sum(1 for i in body if i[2].split(".")[0] in ("sbc", "sbcs")
                              and i[3].replace(" ", "").endswith(",#0"))
                if carries >= 6 and joins >= 3 and borrows >= 2 and len(body) <= WIDE_DIV_MAX_BLOCK:
                    self.wide_div_blocks.add(key)
        return n

    def _read(self, uc, access, address, size, value, _user):
        if self.reads is not None:
            self.reads.append((address - PACKET, self.count))

    def function_of(self, address):
        i = bisect.bisect_right(self.func_starts, address) - 1
        if i >= 0:
            start, size, name = self.funcs[i]
            if address < start + max(size, 2):
                return name
        return f"?{address:#x}"

    def profile(self, trace):
        """Flat profile of a call: instructions per function (each executed block
        attributed to the function containing it)."""
        hits = {}
        for key in trace:
            hits[key] = hits.get(key, 0) + 1
        per = {}
        for key, k in hits.items():
            f = self.function_of(key[0])
            per[f] = per.get(f, 0) + k * self.block_len[key]
        return sorted(per.items(), key=lambda kv: -kv[1])

    def call_raw(self, name, *args):
        """Calls `name` with up to four word arguments; returns (r0 unsigned, instructions)."""
        addr, _ = self.symbols[name]
        for reg, v in zip((A.UC_ARM_REG_R0, A.UC_ARM_REG_R1, A.UC_ARM_REG_R2, A.UC_ARM_REG_R3), args):
            self.uc.reg_write(reg, v)
        self.uc.reg_write(A.UC_ARM_REG_SP, STACK_TOP)
        self.uc.reg_write(A.UC_ARM_REG_LR, RET | 1)
        self.count = 0
        self.trace = []
        self.mem_calls = []
        try:
            self.uc.emu_start(addr | 1, RET, count=MAX_STEPS)
        except UcError as e:
            pc = self.uc.reg_read(A.UC_ARM_REG_PC)
            sys.exit(f"m4count: {name} faulted at {pc:#x} ({self.function_of(pc)}): {e} (a panic executes `udf`)")
        if self.uc.reg_read(A.UC_ARM_REG_PC) != RET:
            sys.exit(f"m4count: {name} did not return within {MAX_STEPS} instructions")
        # The block hook also counted the `b .` at RET once.
        self.trace.pop()
        return self.uc.reg_read(A.UC_ARM_REG_R0), self.count - 1

    def call(self, name, *args):
        """Calls `name`; returns (r0 signed, instructions)."""
        r0, n = self.call_raw(name, *args)
        return struct.unpack("<i", struct.pack("<I", r0))[0], n

    def write_i64(self, addr, values):
        self.uc.mem_write(addr, struct.pack(f"<{len(values)}q", *values))

    def read_i64(self, addr, n):
        return list(struct.unpack(f"<{n}q", self.uc.mem_read(addr, 8 * n)))

    def read_i32(self, addr, n):
        return list(struct.unpack(f"<{n}i", self.uc.mem_read(addr, 4 * n)))


def kinematics_cases(m4, cases):
    """The per-function cases (kinematics, servo period, interpolation period); returns
    the instruction counts per key."""
    stats = {}

    def record(key, n):
        stats.setdefault(key, []).append(n)

    def check(what, got, want, case):
        if got != want:
            sys.exit(f"m4count: {what} differs from the host: emulated {got}, host {want} ({' '.join(case)})")

    machines = MACHINES
    initialised = None
    pose_a, joints_a, guess_a, out_a = ARG, ARG + 0x100, ARG + 0x200, ARG + 0x300
    for c in cases:
        kind, vals = c[0], [int(v) for v in c[1:]]
        if kind in ("ik", "fk"):
            m = vals[0]
            if initialised != m:
                _, n = m4.call("bench_init", m, KIN)
                record(f"{machines[m]}_init", n)
                initialised = m
        if kind == "ik":
            pose, rc, joints = vals[1:7], vals[7], vals[8:19]
            m4.write_i64(pose_a, pose)
            m4.write_i64(joints_a, [0] * 11)
            got, n = m4.call("bench_ik", KIN, pose_a, joints_a)
            check("inverse result", got, rc, c)
            check("joints", m4.read_i64(joints_a, 11), joints, c)
            record(f"{machines[m]}_ik", n)
        elif kind == "fk":
            joints, guess, rc, pose = vals[1:12], vals[12:18], vals[18], vals[19:25]
            m4.write_i64(joints_a, joints)
            m4.write_i64(guess_a, guess)
            m4.write_i64(out_a, [0] * 6)
            got, n = m4.call("bench_fk", KIN, joints_a, guess_a, out_a)
            check("forward iterations", got, rc, c)
            check("pose", m4.read_i64(out_a, 6), pose, c)
            record(f"{machines[m]}_fk_{rc}_iterations", n)
        elif kind == "sincos":
            m4.write_i64(pose_a, [vals[0]])
            _, n = m4.call("bench_sincos", pose_a, out_a)
            check("sin/cos", m4.read_i32(out_a, 2), vals[1:3], c)
            record("sincos" if abs(vals[0]) <= 180 * 10**9 else "sincos_beyond_180deg", n)
        elif kind == "isqrt":
            m4.uc.mem_write(pose_a, struct.pack("<Q", vals[0]))
            _, n = m4.call("bench_isqrt", pose_a, out_a)
            check("isqrt", struct.unpack("<Q", m4.uc.mem_read(out_a, 8))[0], vals[1], c)
            record("isqrt", n)
        elif kind == "servo":
            # servo B k f[S] d[S] e[P]: bench B's period k, feedback, DAC codes and the
            # contour error's f32 bits (perf/m4count/src/servo.rs, `PeriodResult`).
            s, p = WIRE["servos"], WIRE["pose_axes"]
            bench, k, f, dac, err = vals[0], vals[1], vals[2:2 + s], vals[2 + s:2 + 2 * s], vals[2 + 2 * s:]
            name = SERVO_BENCHES[bench]
            if k == 0:
                _, n = m4.call("bench_servo_init", bench, BANK)
                record(f"{name}_init", n)
            m4.write_i64(pose_a, f)
            _, n = m4.call("bench_servo_period", BANK, pose_a, out_a)
            bench_profile(m4, name, k, n)
            got = m4.uc.mem_read(out_a, 2 * s + 4 * p)
            check("DAC codes", list(struct.unpack(f"<{s}H", got[:2 * s])), dac, c)
            check("contour error", list(struct.unpack(f"<{p}I", got[2 * s:])), err, c)
            record(name, n)
            if k == SERVO_PER_TICK - 1:
                record(f"{name}_tick", sum(stats[name][-SERVO_PER_TICK:]))
        elif kind == "pacer":
            # pacer P k f[S] d[S] e[P]: as servo, on pacer bench P (perf/m4count/src/pacer.rs)
            s, p = WIRE["servos"], WIRE["pose_axes"]
            bench, k, f, dac, err = vals[0], vals[1], vals[2:2 + s], vals[2 + s:2 + 2 * s], vals[2 + 2 * s:]
            name = PACER_BENCHES[bench]
            if k == 0:
                _, n = m4.call("bench_pacer_init", bench, PACER)
                record(f"{name}_init", n)
            m4.write_i64(pose_a, f)
            _, n = m4.call("bench_pacer_period", PACER, pose_a, out_a)
            bench_profile(m4, name, k, n)
            got = m4.uc.mem_read(out_a, 2 * s + 4 * p)
            check("DAC codes", list(struct.unpack(f"<{s}H", got[:2 * s])), dac, c)
            check("contour error", list(struct.unpack(f"<{p}I", got[2 * s:])), err, c)
            record(name, n)
            if k == SERVO_PER_TICK - 1:
                record(f"{name}_tick", sum(stats[name][-SERVO_PER_TICK:]))
        elif kind == "staged":
            # staged P ids[8] rows[10 x 8]: one more period (the feedback still the last
            # case's, at pose_a), then the measured tick's staged samples.
            m4.call("bench_pacer_staged", PACER, pose_a, out_a)
            n_rows = SERVO_PER_TICK * MAX_SIGNALS
            got = m4.uc.mem_read(out_a, MAX_SIGNALS + 4 * n_rows)
            check("staged ids", list(got[:MAX_SIGNALS]), vals[1:1 + MAX_SIGNALS], c)
            check("staged samples", list(struct.unpack(f"<{n_rows}i", got[MAX_SIGNALS:])),
                  vals[1 + MAX_SIGNALS:], c)
        elif kind == "period":
            if vals[0] == 0:
                _, n = m4.call("bench_period_init", PERIOD)
                record("h4_period_init", n)
                for _ in range(PERIOD_WARMUP // PERIOD_CHUNK):
                    m4.call("bench_period_advance", PERIOD, PERIOD_CHUNK)
            m4.write_i64(joints_a, [0] * 11)
            got, n = m4.call("bench_period", PERIOD, joints_a)
            check("period result", got, vals[1], c)
            check("period joints", m4.read_i64(joints_a, 11), vals[2:13], c)
            record("h4_period", n)
    return stats


# --- whole calls ------------------------------------------------------------------

def read_log(path):
    """The recorded calls: ("R", bytes) | ("T", input words, output words) |
    ("S", ids, rows bytes, rows) | ("X", bytes)."""
    data = open(path, "rb").read()
    magic = b"PKMC-M4-CALLS-3"
    if not data.startswith(magic):
        sys.exit(f"m4count: {path} is not a call log")
    calls, i = [], len(magic)
    while i < len(data):
        kind = data[i:i + 1]
        i += 1
        if kind in (b"R", b"X"):
            (n,) = struct.unpack_from("<H", data, i)
            calls.append((kind.decode(), data[i + 2:i + 2 + n]))
            i += 2 + n
        elif kind == b"T":
            n_in, n_out = WIRE["inputs"], WIRE["outputs"]
            words = struct.unpack_from(f"<{n_in + n_out}q", data, i)
            calls.append(("T", words[:n_in], list(words[n_in:])))
            i += 8 * (n_in + n_out)
        elif kind == b"S":
            ids, n = data[i:i + MAX_SIGNALS], data[i + MAX_SIGNALS]
            i += MAX_SIGNALS + 1
            calls.append(("S", ids, data[i:i + 4 * MAX_SIGNALS * n], n))
            i += 4 * MAX_SIGNALS * n
        else:
            sys.exit(f"m4count: {path}: bad record {kind!r} at byte {i - 1}")
    return calls


def percentile(sorted_values, q):
    """Nearest-rank percentile."""
    if not sorted_values:
        return 0
    k = max(0, min(len(sorted_values) - 1, -(-len(sorted_values) * q // 100) - 1))
    return sorted_values[int(k)]


class Replay:
    """One program replayed on the emulated controller: counts, worst calls, symbols."""

    def __init__(self, name, machine, blocks):
        self.name, self.machine, self.blocks = name, machine, blocks
        # tick: the tick call alone; record_servo: each handover of servo-period samples
        # to the recorder; locked: a tick with its handovers (the firmware makes them
        # under one lock: the tick's budget).
        self.counts = {"tick": [], "record_servo": [], "locked": [], "receive": [], "frame": [],
                       "transmit": [], "period": []}
        self.seconds = 0.0
        self.period = (0, None)  # worst: (instructions, composition)
        self.lock = (0, None)  # longest single call (a tick with its record_servo calls)
        self.period_of_tick = []  # composition of the last tick's 1 ms period
        self.worst = {}  # kind -> (instructions, call index, profile)
        self.worst_mem = {}  # kind -> memcpy/memclr calls (M4COUNT_MEMCPY only)
        self.armed = False  # the program arms the data recorder
        self.executed = {"tick": set(), "record_servo": set(), "receive": set(),
                         "transmit": set()}  # blocks run


def replay(m4, name, machine, path, blocks, servo_period):
    t0 = time.time()
    r = Replay(name, machine, blocks)
    calls = read_log(path)
    rc, _ = m4.call("bench_ctrl_init", machine, CTRL)
    if rc != 0:
        sys.exit(f"m4count: {name}: the emulated controller refused machine {machine}")
    since = {"receive": 0, "transmit": 0, "frames": 0, "packets": 0, "sends": []}
    for index, call in enumerate(calls):
        kind = call[0]
        if kind == "R":
            packet = call[1]
            m4.uc.mem_write(PACKET, packet)
            m4.reads = []
            _, n = m4.call("bench_ctrl_receive", CTRL, PACKET, len(packet))
            reads, m4.reads = m4.reads, None
            what = "receive"
            # Per frame: from the previous boundary to the first read of the byte after
            # the frame's delimiter (or the call's end).
            first_read = {}
            for off, at in reads:
                first_read.setdefault(off, at)
            start = 0
            for d in [i for i, b in enumerate(packet) if b == 0]:
                end = first_read.get(d + 1, n) if d + 1 < len(packet) else n
                r.counts["frame"].append(end - start)
                if end - start > r.worst.get("frame", (-1,))[0]:
                    r.worst["frame"] = (end - start, index, None)
                start = end
                since["frames"] += 1
            since["packets"] += 1
            since["receive"] += n
        elif kind == "S":
            if not r.counts["locked"]:
                sys.exit(f"m4count: {name}: record_servo (call {index}) before any tick")
            _, ids, rows, n_rows = call
            if n_rows > 16:
                sys.exit(f"m4count: {name}: record_servo (call {index}) of {n_rows} rows")
            m4.uc.mem_write(REC_IDS, bytes(ids))
            m4.uc.mem_write(REC_ROWS, bytes(rows))
            _, n = m4.call_raw("bench_ctrl_record_servo", CTRL, REC_IDS, REC_ROWS, n_rows)
            what = "record_servo"
        elif kind == "T":
            m4.write_i64(IN_WORDS_A, call[1])
            m4.call("bench_ctrl_inputs", IN_WORDS_A, INPUTS)
            out_ptr, n = m4.call_raw("bench_ctrl_tick", CTRL, INPUTS)
            trace, mem_calls = m4.trace, m4.mem_calls
            m4.call("bench_ctrl_outputs", out_ptr, CTRL, OUT_WORDS_A)
            m4.trace, m4.mem_calls = trace, mem_calls
            got = m4.read_i64(OUT_WORDS_A, WIRE["outputs"])
            if got != call[2]:
                sys.exit(f"m4count: {name}: tick outputs (call {index}) differ from the host's:\n"
                         f"  emulated {got}\n  host     {call[2]}")
            what = "tick"
        else:
            want = call[1]
            sent, n = m4.call_raw("bench_ctrl_transmit", CTRL, TXBUF, USB_PACKET)
            got = bytes(m4.uc.mem_read(TXBUF, sent))
            if got != want:
                sys.exit(f"m4count: {name}: transmitted bytes (call {index}) differ from the host's:\n"
                         f"  emulated {got.hex()}\n  host     {want.hex()}")
            what = "transmit"
        r.counts[what].append(n)
        if what == "transmit":
            since["transmit"] += n
            since["sends"].append(n)
        r.executed[what].update(m4.trace)
        if what == "tick":
            r.counts["locked"].append(n)
        elif what == "record_servo":
            # Under the lock of the tick before it, in its 1 ms period.
            r.counts["locked"][-1] += n
            r.counts["period"][-1] += n
            r.period_of_tick[-1]["record_servo"] += n
            if r.counts["period"][-1] > r.period[0]:
                r.period = (r.counts["period"][-1], r.period_of_tick[-1])
        locked = r.counts["locked"][-1] if what in ("tick", "record_servo") else n
        if locked > r.lock[0]:
            r.lock = (locked, "tick + record_servo" if what == "record_servo" else what)
        if n > r.worst.get(what, (-1,))[0]:
            r.worst[what] = (n, index, m4.profile(m4.trace))
            if m4.mem_watch is not None:
                r.worst_mem[what] = list(m4.mem_calls)
        if what == "tick":
            servo = servo_period
            total = since["receive"] + since["transmit"] + n + servo
            r.counts["period"].append(total)
            r.period_of_tick = [dict(since, tick=n, servo=servo, record_servo=0)]
            if total > r.period[0]:
                r.period = (total, r.period_of_tick[-1])
            since = {"receive": 0, "transmit": 0, "frames": 0, "packets": 0, "sends": []}
    r.seconds = time.time() - t0
    return r


def categories(m4, executed):
    """Forbidden helpers among the executed blocks: {category: set of functions}."""
    seen = {}
    for key in executed:
        f = m4.function_of(key[0])
        kind = forbidden_kind(f)
        if key in m4.wide_div_blocks:
            seen.setdefault("64/128-bit division", set()).add(f"{INLINE_WIDE_DIV} in {f}")
        if kind:
            seen.setdefault(kind, set()).add(f)
    return seen


def bench_profile(m4, name, k, n):
    """With M4COUNT_FULL: the flat profile of a servo or pacer bench's tick edge (period
    0) and of its first period after the edge."""
    if os.environ.get("M4COUNT_FULL") and k in (0, 1):
        parts = [f"{short(f, 48)} ({c})" for f, c in m4.profile(m4.trace)]
        print(f"  {name} period {k} {n}: " + "; ".join(parts))


def short(name, width=60):
    """`name` without the module paths inside `<… as …>` and at most `width` long."""
    name = re.sub(r"<([^<>]*)>", lambda m: "<" + re.sub(r"\b[a-z_][a-z0-9_]*::", "", m.group(1)) + ">", name)
    return name if len(name) <= width else name[:width - 1] + "…"


def report_whole_calls(m4, replays, servo_periods):
    print()
    print("whole controller calls, instructions per call (tick, receive and transmit include their C-ABI")
    print("wrapper; receive = one USB packet; frame = the part of a receive that completes one frame;")
    print(f"period = a tick + the receive and transmit calls since the previous tick + "
          f"the {SERVO_PER_TICK} servo periods of a tick of the machine ("
          + ", ".join(f"{MACHINES[m]}: {SERVO_OF_MACHINE[m]} sum {servo_periods[m]}"
                      for m in sorted(k for k in servo_periods if isinstance(k, int)))
          + "".join(f"; {b} sum {servo_periods[b]} for the programs that name it"
                    for b in sorted(k for k in servo_periods if not isinstance(k, int)))
          + "); record_servo = one handover of servo-period samples to the recorder, after")
    print("the tick, under its lock; tick+rec = a tick with its handovers; lock = the longest single call,")
    print("a tick with its handovers counted as one)")
    print(f"{'program':24} {'blocks':>6} {'call':8} {'calls':>6} {'min':>7} {'median':>7} {'p99':>7} {'max':>7}")
    for r in replays:
        first = True
        for kind in ("tick", "record_servo", "locked", "receive", "frame", "transmit", "period"):
            if kind in ("record_servo", "locked") and not r.counts["record_servo"]:
                continue
            v = sorted(r.counts[kind])
            label = f"{r.name:24} {r.blocks:6d}" if first else " " * 31
            first = False
            print(f"{label} {'tick+rec' if kind == 'locked' else kind[:8]:8} {len(v):6d} {v[0]:7d} {percentile(v, 50):7d} "
                  f"{percentile(v, 99):7d} {v[-1]:7d}")
        p, c = r.period
        print(f"{'':31} worst period: tick {c['tick']} + record_servo {c['record_servo']} + "
              f"{c['packets']} receives {c['receive']} "
              f"({c['frames']} frames) + transmits {c['transmit']} ({len(c['sends'])} calls: "
              f"{len([k for k in c['sends'] if k > 200])} that send, {max(c['sends'], default=0)} the "
              f"dearest) + servo {c['servo']}; "
              f"lock held {r.lock[0]} ({r.lock[1]}); replayed in {r.seconds:.1f} s")
    print()
    print("functions of the worst calls (flat: each function's own instructions; Controller::tick and")
    print("Controller::receive are inlined into the bench_ctrl_* wrappers, as into the firmware's callers)")
    for r in replays:
        for kind in ("tick", "record_servo", "receive", "transmit"):
            if kind not in r.worst:
                continue
            n, index, prof = r.worst[kind]
            top = len(prof) if os.environ.get("M4COUNT_FULL") else 6
            parts = [f"{100 * k / n:.0f}% {short(f, 48)}" + (f" ({k})" if top > 6 else "")
                     for f, k in prof[:top]]
            print(f"  {r.name} worst {kind} {n} (call {index}): " + "; ".join(parts))
            for m in getattr(r, "worst_mem", {}).get(kind, []):
                print(f"      {m[0]} from {m[1]} @{m[2]:#x} r2={m[3]} r1={m[4]}")
    print()
    print("forbidden helpers executed in counted calls (soft-float f64, 64/128-bit division, software sqrt):")
    # Per group: the machines whose budgets are enforced, then each other machine.
    seen_by = {}
    for r in replays:
        group = "" if r.machine in ENFORCED_MACHINES else MACHINES[r.machine]
        any_seen, kinds, programs = seen_by.setdefault(group, ({}, {}, {}))
        for kind, blocks in r.executed.items():
            for k, fs in categories(m4, blocks).items():
                any_seen.setdefault(k, set()).update(fs)
                kinds.setdefault(k, set()).add(kind)
                programs.setdefault(k, set()).add(r.name)
    for group, (any_seen, kinds, programs) in sorted(seen_by.items()):
        prefix = f"{group}: " if group else ""
        if not any_seen:
            print(f"  {prefix}none")
        for k, fs in sorted(any_seen.items()):
            print(f"  {prefix}{k} (in {', '.join(sorted(kinds[k]))}; {len(programs[k])} of {len(replays)} programs): "
                  f"{', '.join(sorted(short(f, 90) for f in fs))}")
    return {g: v[0] for g, v in seen_by.items()}


def main():
    t0 = time.time()
    if "--no-build" not in sys.argv:
        build()
    cases = host_cases()
    programs = record_programs()
    m4 = M4(ELF)
    stats = kinematics_cases(m4, cases)
    failed = False
    print(f"{'function':28} {'cases':>5} {'min':>6} {'mean':>7} {'max':>6} {'budget':>7}")
    for key in sorted(stats):
        v = stats[key]
        budget = BUDGETS.get(key)
        over = budget is not None and max(v) > budget
        failed |= over
        b = f"{budget:7d}" if budget else "      -"
        flag = "  OVER" if over else ""
        print(f"{key:28} {len(v):5d} {min(v):6d} {sum(v) / len(v):7.1f} {max(v):6d} {b}{flag}")
    for key in BUDGETS:
        if key not in stats:
            failed = True
            print(f"m4count: no {key} cases were run")
    t1 = time.time()

    # The detector of inline 128-bit division must see a real one (the canary divides
    # two u128 values; it is never counted).
    m4.write_i64(ARG, [123_456_789_012_345, 0, 7_777, 0])
    m4.call("bench_wide_division", ARG, ARG + 16, ARG + 32)
    if (m4.read_i64(ARG + 32, 2) != [123_456_789_012_345 // 7_777, 0]
            or not categories(m4, set(m4.trace)).get("64/128-bit division")):
        sys.exit("m4count: the canary's u128 division was not recognised as one: the detector is broken")
    m4.wide_div_blocks -= set(m4.trace)

    size, _ = m4.call_raw("bench_ctrl_size")
    if size > CTRL_BYTES:
        sys.exit(f"m4count: Controller is {size} bytes, more than the {CTRL_BYTES} reserved")
    words = m4.call_raw("bench_wire_words")[0]
    if (words & 0xFFFF, words >> 16) != (WIRE["inputs"], WIRE["outputs"]):
        sys.exit(f"m4count: the image's wire words {words & 0xFFFF}, {words >> 16} are not the host's {WIRE}")
    # The ten measured periods are one tick's (perf/m4count/src/servo.rs): their sum is
    # the servo work of one 1 ms period.
    servo_periods = {m: max(stats[SERVO_OF_MACHINE[m] + "_tick"]) for m in sorted({p[1] for p in programs})}
    for bench in {p[4] for p in programs if p[4]}:
        if bench + "_tick" not in stats:
            sys.exit(f"m4count: a program names the servo bench {bench}, which was not run")
        servo_periods[bench] = max(stats[bench + "_tick"])
    replays = []
    t2 = time.time()
    # Harness debugging only (M4COUNT_ONLY=<regex of program names>): replay those.
    only = os.environ.get("M4COUNT_ONLY")
    programs = [p for p in programs if not only or re.search(only, p[0])]
    for name, machine, path, blocks, bench, armed in programs:
        replays.append(replay(m4, name, machine, path, blocks, servo_periods[bench or machine]))
        replays[-1].armed = armed
    replayed = sum(sum(r.counts[k]) for r in replays for k in ("tick", "receive", "transmit"))
    t3 = time.time()
    seen = report_whole_calls(m4, replays, servo_periods)

    print()
    print(f"{'real-time budget (issue 9)':34} {'worst':>8} {'budget':>8}  where")
    # --enforce-realtime: every real-time budget fails the run; --enforce-realtime=a,b:
    # those named (tick, frame, period, lock, helpers).
    enforced = set()
    for arg in sys.argv[1:]:
        if arg == "--enforce-realtime":
            enforced = {k for k, _, _ in RT_BUDGETS} | {"helpers"}
        elif arg.startswith("--enforce-realtime="):
            enforced = set(arg.split("=", 1)[1].split(","))
            unknown = enforced - {k for k, _, _ in RT_BUDGETS} - {"helpers"}
            if unknown:
                sys.exit(f"m4count: unknown budget(s) {sorted(unknown)}")
    rt_failed = False
    over_free = []
    every = {k for k, _, _ in RT_BUDGETS}
    groups = [("", [r for r in replays if r.machine in ENFORCED_MACHINES and not r.armed], every)]
    others = sorted({r.machine for r in replays} - ENFORCED_MACHINES)
    groups += [(f"{MACHINES[m]}: ", [r for r in replays if r.machine == m and not r.armed], set())
               for m in others]
    # The programs that arm the data recorder (issue 35): the same budgets, all enforced
    # (docs/recorder.md, "Real time").
    if any(r.armed for r in replays):
        groups.append(("recorder armed: ", [r for r in replays if r.armed], every))
    for prefix, rs, enforceable_keys in groups:
        if not rs:  # M4COUNT_ONLY left none
            continue
        for key, label, budget in RT_BUDGETS:
            if key == "period":
                worst = max((r.period[0], r.name) for r in rs)
            elif key == "lock":
                worst = max((r.lock[0], r.name) for r in rs)
            elif key == "tick":
                # A tick with the recorder's handovers after it, under the same lock.
                worst = max((max(r.counts["locked"]), r.name) for r in rs)
            else:
                worst = max((max(r.counts[key]), r.name) for r in rs)
            over = worst[0] > budget
            enforceable = key in enforceable_keys
            counted = enforceable and key in enforced
            if over and counted:
                rt_failed = True
            elif over:
                over_free.append(prefix + key)
            verdict = "PASS" if not over else ("OVER" if counted else
                                               "OVER (not enforced)" if enforceable else
                                               "OVER (not enforced)")
            print(f"{prefix + label:34} {worst[0]:8d} {budget:8d}  {verdict} ({worst[1]})")
    helpers = sorted(f for fs in seen.get("", {}).values() for f in fs)
    helper_verdict = "PASS" if not helpers else ("OVER" if "helpers" in enforced else "OVER (not enforced)")
    print(f"{'forbidden helpers executed':34} {len(helpers):8d} {0:8d}  {helper_verdict}")
    for group in sorted(g for g in seen if g):
        n = sum(len(fs) for fs in seen[group].values())
        verdict = "PASS" if not n else "OVER (not enforced)"
        print(f"{group + ': forbidden helpers executed':34} {n:8d} {0:8d}  {verdict}")
    if helpers and "helpers" in enforced:
        rt_failed = True
    elif helpers:
        over_free.append("helpers")
    print(f"every emulated result equals the host's (Controller: {size} bytes on the M4); "
          f"{t1 - t0:.1f} s to the kinematics, {replayed / 1e6:.0f} million instructions of whole "
          f"calls replayed in {t3 - t2:.0f} s, {time.time() - t0:.1f} s in all"
          + (f"; over budget but not enforced: {', '.join(over_free)}" if over_free else ""))
    sys.exit(1 if failed or rt_failed else 0)


if __name__ == "__main__":
    main()
