#!/usr/bin/env python3
"""Flash and RAM use of the firmware ELF, checked against the project budget.

Reads the ELF32 section headers (no tools needed). Flash = every allocated section
with file contents (PROGBITS: .vector_table, .text, .rodata, ... and the load image
of .data); RAM = allocated sections placed in RAM (.data, .bss, .uninit, ...; the
stack is what flip-link leaves below them). Exits 1 when over 224 KiB flash or 96 KiB
of static RAM, or when one function reserves more than 16 KiB of stack in its prologue
(`sub sp, #N`, found by disassembling every function symbol with capstone when it is
installed): the MCU has 128 KiB of RAM in all, and the stack gets what the statics
leave, so a whole controller or its queue built as a temporary would overflow it.

Usage: size.py [path/to/firmware.elf]
"""
import struct
import sys

FLASH = (0x0800_0000, 512 * 1024)
RAM = (0x2000_0000, 128 * 1024)
# The program must stay in flash bank 1 (256 KB in dual-bank mode) so that storing a
# machine in bank 2 never stalls it (memory.x); 224 KiB keeps 32 KiB of that bank
# in reserve.
FLASH_BUDGET = 224 * 1024
RAM_BUDGET = 96 * 1024
FRAME_BUDGET = 16 * 1024
SHF_ALLOC, SHT_PROGBITS, SHT_NOBITS = 0x2, 1, 8


def sections(path):
    data = open(path, "rb").read()
    if data[:4] != b"\x7fELF" or data[4] != 1 or data[5] != 1:
        sys.exit(f"{path}: not a little-endian ELF32 file")
    shoff, = struct.unpack_from("<I", data, 0x20)
    shentsize, shnum, shstrndx = struct.unpack_from("<HHH", data, 0x2E)
    hdrs = [struct.unpack_from("<IIIIIIIIII", data, shoff + i * shentsize) for i in range(shnum)]
    strtab = hdrs[shstrndx][4]
    for name, typ, flags, addr, _off, size, *_ in hdrs:
        end = data.index(b"\0", strtab + name)
        yield data[strtab + name:end].decode(), typ, flags, addr, size


def functions(path):
    """(name, address, size) of every function symbol, and the flash image."""
    data = open(path, "rb").read()
    shoff, = struct.unpack_from("<I", data, 0x20)
    shentsize, shnum, _ = struct.unpack_from("<HHH", data, 0x2E)
    hdrs = [struct.unpack_from("<IIIIIIIIII", data, shoff + i * shentsize) for i in range(shnum)]
    funcs = []
    for h in hdrs:
        if h[1] != 2:  # SHT_SYMTAB
            continue
        strtab = hdrs[h[6]]
        for off in range(h[4], h[4] + h[5], 16):
            st_name, value, size, info = struct.unpack_from("<IIIB", data, off)
            if info & 0xF == 2 and size > 0:
                start = strtab[4] + st_name
                funcs.append((data[start:data.index(b"\0", start)].decode(), value & ~1, size))
    return data, hdrs, funcs


def largest_frames(path, top=5):
    """The largest stack reservations (`sub sp, #N`) of the ELF's functions, or None
    without capstone."""
    try:
        import capstone
    except ImportError:
        return None
    data, hdrs, funcs = functions(path)
    md = capstone.Cs(capstone.CS_ARCH_ARM, capstone.CS_MODE_THUMB | capstone.CS_MODE_MCLASS)
    frames = []
    for name, addr, size in funcs:
        for h in hdrs:
            if h[1] == SHT_PROGBITS and h[3] <= addr < h[3] + h[5]:
                code = data[h[4] + addr - h[3]:h[4] + addr - h[3] + size]
                biggest = 0
                for insn in md.disasm_lite(code, addr):
                    if insn[2].startswith("sub") and insn[3].startswith("sp,") and "#" in insn[3]:
                        biggest = max(biggest, int(insn[3].split("#")[1], 0))
                frames.append((biggest, name))
                break
    return sorted(frames, reverse=True)[:top]


def inside(addr, region):
    return region[0] <= addr < region[0] + region[1]


def main():
    path = sys.argv[1] if len(sys.argv) > 1 else "target/thumbv7em-none-eabihf/release/firmware"
    flash = ram = 0
    for name, typ, flags, addr, size in sections(path):
        if not flags & SHF_ALLOC or size == 0:
            continue
        if typ == SHT_PROGBITS:
            flash += size  # in flash, or its load image is (.data)
        if inside(addr, RAM) and typ in (SHT_PROGBITS, SHT_NOBITS):
            ram += size
        elif not inside(addr, FLASH):
            print(f"note: section {name} at {addr:#x} is outside flash and RAM")
    print(f"flash {flash} B ({flash / 1024:.1f} KiB of {FLASH_BUDGET // 1024} KiB budget)")
    print(f"ram   {ram} B ({ram / 1024:.1f} KiB of {RAM_BUDGET // 1024} KiB budget, static)")
    over = flash > FLASH_BUDGET or ram > RAM_BUDGET
    frames = largest_frames(path)
    if frames is None:
        print("stack frames: not checked (pip install capstone)")
    else:
        print(f"largest stack frames (budget {FRAME_BUDGET // 1024} KiB each):")
        for size, name in frames:
            print(f"  {size:6d} B  {name[:100]}")
        over |= frames[0][0] > FRAME_BUDGET
    if over:
        print("over budget")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
