"""Build the MIK32 firmware ELF with the pip-installed Zig toolchain (``ziglang``).

``python firmware/build.py [--out build/firmware] [--cc "CMD"]`` generates the shared-constants
header from the Python definitions (gen_constants.py), compiles ``firmware/src`` for RV32IMC
(``-target riscv32-freestanding-none -mcpu=generic_rv32+m+c``, no libc), links with
``firmware/link.ld`` (MIK32 memory map; the link fails if .data + .bss + stack exceed 16 KB)
and prints the text/data/bss sizes. Output: ``build/firmware/snan-fw.elf`` (+ ``.bin``, the
flash image for address 0x80000000). ``--cc`` selects another compiler, e.g.
``riscv64-unknown-elf-gcc -march=rv32imc -mabi=ilp32`` (Debian's package; not needed).
"""

from __future__ import annotations

import argparse
import shlex
import struct
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
SOURCES = ["startup.S", "main.c", "proto.c", "ops.c", "hal_mik32.c"]
ZIG_CC = [sys.executable, "-m", "ziglang", "cc", "-target", "riscv32-freestanding-none",
          "-mcpu=generic_rv32+m+c"]
CFLAGS = ["-std=c11", "-O2", "-ffreestanding", "-fno-builtin", "-nostdlib", "-Wall", "-Wextra",
          "-Werror", "-fno-stack-protector", "-ffunction-sections", "-fdata-sections",
          "-mno-relax", "-g"]


def section_sizes(elf: Path) -> dict[str, int]:
    """text / data / bss / noinit sizes (bytes) from the ELF section headers."""
    data = elf.read_bytes()
    if data[:4] != b"\x7fELF" or data[4] != 1:
        raise SystemExit(f"{elf}: not a 32-bit ELF file")
    shoff, = struct.unpack_from("<I", data, 0x20)
    shentsize, shnum, shstrndx = struct.unpack_from("<HHH", data, 0x2E)
    headers = [struct.unpack_from("<IIIIIIIIII", data, shoff + i * shentsize) for i in range(shnum)]
    strtab = headers[shstrndx][4]
    sizes = {"text": 0, "data": 0, "bss": 0, "noinit": 0, "stack": 0}
    for name_off, _type, _flags, _addr, _off, size, *_ in headers:
        end = data.index(b"\0", strtab + name_off)
        name = data[strtab + name_off:end].decode()
        if name in (".text", ".rodata"):
            sizes["text"] += size
        elif name == ".data":
            sizes["data"] += size
        elif name in (".bss",):
            sizes["bss"] += size
        elif name == ".noinit":
            sizes["noinit"] += size
        elif name == ".stack":
            sizes["stack"] += size
    return sizes


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "build" / "firmware"))
    ap.add_argument("--cc", default=None, help="compiler command instead of python -m ziglang cc")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    header = out / "snan_constants.h"
    subprocess.run([sys.executable, str(HERE / "gen_constants.py"), str(header)], check=True)
    cc = shlex.split(args.cc) if args.cc else ZIG_CC
    objs = []
    for src in SOURCES:
        obj = out / (Path(src).stem + ".o")
        cmd = cc + CFLAGS + ["-I", str(out), "-I", str(HERE / "src"), "-c",
                             str(HERE / "src" / src), "-o", str(obj)]
        subprocess.run(cmd, check=True)
        objs.append(str(obj))
    elf = out / "snan-fw.elf"
    tmp = out / "snan-fw.elf.tmp"
    link = cc + CFLAGS + ["-T", str(HERE / "link.ld"), "-Wl,--gc-sections", "-o", str(tmp)] + \
        objs
    subprocess.run(link, check=True)
    tmp.replace(elf)
    s = section_sizes(elf)
    ram = s["data"] + s["bss"] + s["noinit"] + s["stack"]
    print(f"firmware {elf.relative_to(ROOT) if elf.is_relative_to(ROOT) else elf}: "
          f"text {s['text']} B (flash), data {s['data']} B, bss {s['bss']} B, "
          f"noinit {s['noinit']} B, stack {s['stack']} B; RAM {ram} of 16384 B")
    return 0


if __name__ == "__main__":
    sys.exit(main())
