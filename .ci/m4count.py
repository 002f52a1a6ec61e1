#!/usr/bin/env python3
"""Cortex-M4 instruction counts of the kinematics, emulated; fails above the budgets.

    python3 .ci/m4count.py            # build, count, print the table, check budgets
    python3 .ci/m4count.py --no-build # reuse the last ELF (harness debugging only)

Builds perf/m4count (its own workspace, with a copy of the workspace's Cargo.lock)
twice: for thumbv7em-none-eabihf (release, the firmware's profile: opt-level "s", fat
LTO, one codegen unit, -C target-cpu=cortex-m4) and for the host, whose run prints the
benchmark cases with the host's results. Each case is then run in
the unicorn emulator (Cortex-M4 model, FPU on): the measured function is called with
arguments in emulated RAM and its executed instructions are counted by a basic-block
hook, each block's instructions counted once by disassembling it with capstone (cached
per block). Per-instruction hooks are not used: QEMU skips the code hook for
instructions of an IT block whose condition fails, which a block count includes (they
still take an issue slot on the core). Every emulated result must equal the host's.

Needs: Python 3, `pip install unicorn capstone` (tested with unicorn 2.1.4, capstone
5.0.9), the Rust toolchain with the thumbv7em-none-eabihf target.
"""

import os
import shutil
import struct
import subprocess
import sys
import time

try:
    import capstone
    from unicorn import Uc, UcError, UC_ARCH_ARM, UC_MODE_THUMB, UC_MODE_MCLASS, UC_HOOK_BLOCK
    from unicorn import arm_const as A
except ImportError:
    sys.exit("m4count: needs `pip install unicorn capstone`")

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CRATE = os.path.join(ROOT, "perf", "m4count")
TARGET = "thumbv7em-none-eabihf"
TARGET_DIR = os.path.join(CRATE, "target")
ELF = os.path.join(TARGET_DIR, TARGET, "release", "pkmc-m4count")

# Instruction budgets per call (docs/performance.md).
BUDGETS = {"h4_ik": 600, "hexapod_ik": 1000, "servo_ccpm_4axes": 2000, "h4_period": 1500}

FLASH, FLASH_SIZE = 0x0800_0000, 0x8_0000
RAM, RAM_SIZE = 0x2000_0000, 0x2_0000
RET = FLASH + FLASH_SIZE - 0x100  # return address: a `b .` placed at the end of flash
KIN = RAM + 0x1000  # MachineKinematics (1024 bytes reserved)
ARG = RAM + 0x2000  # argument buffers
BANK = RAM + 0x3000  # ServoBank (2048 bytes reserved)
PERIOD = RAM + 0x4000  # Period (64 KiB reserved: up to RAM + 0x14000)
PERIOD_WARMUP, PERIOD_CHUNK = 1600, 200  # as perf/m4count/src/main.rs
STACK_TOP = RAM + RAM_SIZE
MAX_STEPS = 2_000_000  # a runaway run stops here


def build():
    # The workspace's lock file, so the measured build resolves the firmware's exact
    # dependency versions (cargo adds the harness package to this copy).
    shutil.copyfile(os.path.join(ROOT, "Cargo.lock"), os.path.join(CRATE, "Cargo.lock"))
    env = dict(os.environ)
    env.pop("CARGO_TARGET_DIR", None)
    link = os.path.join(CRATE, "link.ld")
    env["RUSTFLAGS"] = f"-C target-cpu=cortex-m4 -C link-arg=-T{link}"
    env[f"CARGO_TARGET_{TARGET.upper().replace('-', '_')}_LINKER"] = "rust-lld"
    subprocess.run(
        ["cargo", "build", "--release", "--target", TARGET, "--target-dir", TARGET_DIR],
        cwd=CRATE, env=env, check=True)


def host_cases():
    out = subprocess.run(
        ["cargo", "run", "--release", "--quiet", "--target-dir", TARGET_DIR],
        cwd=CRATE, check=True, capture_output=True, text=True).stdout
    return [line.split() for line in out.splitlines() if line.strip()]


def read_elf(path):
    """PT_LOAD segments and function symbols of a 32-bit little-endian ELF."""
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


class M4:
    def __init__(self, elf):
        segments, self.symbols = read_elf(elf)
        self.uc = Uc(UC_ARCH_ARM, UC_MODE_THUMB | UC_MODE_MCLASS)
        self.uc.ctl_set_cpu_model(A.UC_CPU_ARM_CORTEX_M4)
        self.uc.mem_map(FLASH, FLASH_SIZE)
        self.uc.mem_map(RAM, RAM_SIZE)
        for vaddr, content, memsz in segments:
            self.uc.mem_write(vaddr, content + b"\0" * (memsz - len(content)))
        self.uc.mem_write(RET, b"\xfe\xe7")  # b .
        # Full access to CP10/CP11 (the FPU), as the firmware's start-up code sets it.
        self.uc.reg_write(A.UC_ARM_REG_C1_C0_2, 0xF << 20)
        self.md = capstone.Cs(capstone.CS_ARCH_ARM, capstone.CS_MODE_THUMB | capstone.CS_MODE_MCLASS)
        self.block_len = {}
        self.count = 0
        self.uc.hook_add(UC_HOOK_BLOCK, self._block)

    def _block(self, uc, address, size, _user):
        key = (address, size)
        n = self.block_len.get(key)
        if n is None:
            code = bytes(uc.mem_read(address, size))
            n = sum(1 for _ in self.md.disasm_lite(code, address))
            self.block_len[key] = n
        self.count += n

    def call(self, name, *args):
        """Calls `name` with up to four word arguments; returns (r0, instructions)."""
        addr, _ = self.symbols[name]
        for reg, v in zip((A.UC_ARM_REG_R0, A.UC_ARM_REG_R1, A.UC_ARM_REG_R2, A.UC_ARM_REG_R3), args):
            self.uc.reg_write(reg, v)
        self.uc.reg_write(A.UC_ARM_REG_SP, STACK_TOP)
        self.uc.reg_write(A.UC_ARM_REG_LR, RET | 1)
        self.count = 0
        try:
            self.uc.emu_start(addr | 1, RET, count=MAX_STEPS)
        except UcError as e:
            pc = self.uc.reg_read(A.UC_ARM_REG_PC)
            sys.exit(f"m4count: {name} faulted at {pc:#x}: {e} (a panic executes `udf`)")
        if self.uc.reg_read(A.UC_ARM_REG_PC) != RET:
            sys.exit(f"m4count: {name} did not return within {MAX_STEPS} blocks")
        # The block hook also counted the `b .` at RET once.
        return struct.unpack("<i", struct.pack("<I", self.uc.reg_read(A.UC_ARM_REG_R0)))[0], self.count - 1

    def write_i64(self, addr, values):
        self.uc.mem_write(addr, struct.pack(f"<{len(values)}q", *values))

    def read_i64(self, addr, n):
        return list(struct.unpack(f"<{n}q", self.uc.mem_read(addr, 8 * n)))

    def read_i32(self, addr, n):
        return list(struct.unpack(f"<{n}i", self.uc.mem_read(addr, 4 * n)))


def main():
    t0 = time.time()
    if "--no-build" not in sys.argv:
        build()
    cases = host_cases()
    m4 = M4(ELF)
    stats = {}

    def record(key, n):
        stats.setdefault(key, []).append(n)

    def check(what, got, want, case):
        if got != want:
            sys.exit(f"m4count: {what} differs from the host: emulated {got}, host {want} ({' '.join(case)})")

    machines = {0: "h4", 1: "hexapod"}
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
            if vals[0] == 0:
                _, n = m4.call("bench_servo_init", BANK)
                record("servo_init", n)
            m4.write_i64(pose_a, vals[1:5])
            _, n = m4.call("bench_servo_ccpm_4axes", BANK, pose_a, out_a)
            dac = list(struct.unpack("<4H", m4.uc.mem_read(out_a, 8)))
            check("DAC codes", dac, vals[5:9], c)
            record("servo_ccpm_4axes", n)
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

    failed = False
    print(f"{'function':28} {'cases':>5} {'min':>6} {'mean':>7} {'max':>6} {'budget':>7}")
    for key in sorted(stats):
        v = stats[key]
        budget = BUDGETS.get(key)
        over = budget is not None and max(v) > budget
        failed |= over
        b = f"{budget:7d}" if budget else "      -"
        print(f"{key:28} {len(v):5d} {min(v):6d} {sum(v) / len(v):7.1f} {max(v):6d} {b}{'  OVER' if over else ''}")
    for key in BUDGETS:
        if key not in stats:
            failed = True
            print(f"m4count: no {key} cases were run")
    print(f"every emulated result equals the host's; {time.time() - t0:.1f} s")
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
