#!/usr/bin/env python3
"""Flash and RAM use of the firmware ELF, checked against the project budget.

Reads the ELF32 section headers (no tools needed). Flash = every allocated section
with file contents (PROGBITS: .vector_table, .text, .rodata, ... and the load image
of .data); RAM = allocated sections placed in RAM (.data, .bss, .uninit, ...; the
stack is what flip-link leaves below them and is not counted). Exits 1 when over
128 KB flash or 64 KB RAM.

Usage: size.py [path/to/firmware.elf]
"""
import struct
import sys

FLASH = (0x0800_0000, 512 * 1024)
RAM = (0x2000_0000, 128 * 1024)
FLASH_BUDGET = 128 * 1024
RAM_BUDGET = 64 * 1024
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
    print(f"ram   {ram} B ({ram / 1024:.1f} KiB of {RAM_BUDGET // 1024} KiB budget, stack not counted)")
    if flash > FLASH_BUDGET or ram > RAM_BUDGET:
        print("over budget")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
