"""Build the MIK32 firmware ELF with the pip-installed Zig toolchain (``ziglang``).

``python firmware/build.py [--out build/firmware] [--cc "CMD"]`` generates the shared-constants
header from the Python definitions (gen_constants.py), compiles ``firmware/src`` for RV32IMC
(``-target riscv32-freestanding-none -mcpu=generic_rv32+m+c``, no libc), links with
``firmware/link.ld`` (MIK32 memory map; the link fails if .data + .bss + stack exceed 16 KB)
and prints the text/data/bss sizes. Output: ``build/firmware/snan-fw.elf``, ``snan-fw.bin``
(the flash image for address 0x80000000: the ELF's loadable flash contents, gaps 0xFF) and
``snan-fw.d`` (make's dependency file: the Python files the constants come from).
``--cc`` selects another compiler, e.g.
``riscv64-unknown-elf-gcc -march=rv32imc -mabi=ilp32`` (Debian's package; not needed).
A missing compiler or toolchain package, an unusable ``--out`` or a failed compile or link
(e.g. RAM overflow: the linker's own error line) is one line on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import importlib.util
import shlex
import struct
import subprocess
import sys
from pathlib import Path

FLASH_BASE = 0x8000_0000
HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
SOURCES = ["startup.S", "main.c", "proto.c", "ops.c", "window.c", "hal_mik32.c"]
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


class BuildError(Exception):
    """A build step failed; the message is the one line to print."""


def _run(cmd: list[str], what: str, *, diagnostics: bool = True) -> None:
    """Run one toolchain step; BuildError with its first error line when it fails (after the
    step's full output when ``diagnostics`` and it has more than that line)."""
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True)
    except FileNotFoundError:
        raise BuildError(f"compiler {cmd[0]!r} not found; install it or give another --cc "
                         "(default: python -m ziglang cc, from pip install -e '.[firmware]')"
                         ) from None
    except PermissionError:
        raise BuildError(f"compiler {cmd[0]!r} is not executable; give another --cc") from None
    if proc.stdout:
        sys.stdout.write(proc.stdout)
    if proc.returncode == 0 and proc.stderr:
        sys.stderr.write(proc.stderr)
    if proc.returncode:
        lines = [ln.strip() for ln in proc.stderr.splitlines() if ln.strip()]
        errors = [ln for ln in lines if "error" in ln.lower()] or lines or [
            f"exit code {proc.returncode}"]
        if diagnostics and len(lines) > 1:
            sys.stderr.write(proc.stderr)          # the full diagnostics, then the one line
        raise BuildError(f"{what} failed: {errors[0]}")


def flash_image(elf: Path) -> bytes:
    """The flash contents (from FLASH_BASE): every loadable segment's file bytes at its load
    address, gaps 0xFF (erased flash)."""
    from snan_hil.firmware_emu.fw_image import FirmwareImage
    img = FirmwareImage.load(elf, check_constants=False)
    parts = [(seg.addr - FLASH_BASE, seg.data) for seg in img.segments
             if seg.data and seg.addr >= FLASH_BASE]
    end = max((off + len(d) for off, d in parts), default=0)
    out = bytearray(b"\xff") * end
    for off, d in parts:
        out[off:off + len(d)] = d
    return bytes(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "build" / "firmware"))
    ap.add_argument("--cc", default=None, help="compiler command instead of python -m ziglang cc")
    args = ap.parse_args(argv)
    try:
        return build(Path(args.out), args.cc)
    except BuildError as exc:
        print(f"firmware build: {exc}", file=sys.stderr)
        return 2


def build(out: Path, cc_text: str | None) -> int:
    if out.exists() and not out.is_dir():
        raise BuildError(f"--out {out} is not a directory; give a folder for the build")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise BuildError(f"cannot create --out {out}: {exc.strerror or exc}") from None
    if cc_text is not None and not shlex.split(cc_text):
        raise BuildError("--cc is empty; give a compiler command")
    if cc_text is None and importlib.util.find_spec("ziglang") is None:
        raise BuildError("the ziglang package (the cross toolchain) is not installed: run "
                         "make install, or pip install -e '.[firmware]', or give --cc")
    header = out / "snan_constants.h"
    elf = out / "snan-fw.elf"
    target = str(elf.relative_to(ROOT)) if elf.is_relative_to(ROOT) else str(elf)
    _run([sys.executable, str(HERE / "gen_constants.py"), str(header),
          "--depfile", str(out / "snan-fw.d"), target], "generating the constants header")
    cc = shlex.split(cc_text) if cc_text else ZIG_CC
    objs = []
    for src in SOURCES:
        obj = out / (Path(src).stem + ".o")
        cmd = cc + CFLAGS + ["-I", str(out), "-I", str(HERE / "src"), "-c",
                             str(HERE / "src" / src), "-o", str(obj)]
        _run(cmd, f"compiling {src}")
        objs.append(str(obj))
    tmp = out / "snan-fw.elf.tmp"
    link = cc + CFLAGS + ["-T", str(HERE / "link.ld"), "-Wl,--gc-sections", "-o", str(tmp)] + \
        objs
    _run(link, "linking", diagnostics=False)      # e.g. the RAM assertion of link.ld
    binary = flash_image(tmp)
    tmp_bin = out / "snan-fw.bin.tmp"
    tmp_bin.write_bytes(binary)
    tmp.replace(elf)
    tmp_bin.replace(out / "snan-fw.bin")
    s = section_sizes(elf)
    ram = s["data"] + s["bss"] + s["noinit"] + s["stack"]
    print(f"firmware {elf.relative_to(ROOT) if elf.is_relative_to(ROOT) else elf}: "
          f"text {s['text']} B (flash), data {s['data']} B, bss {s['bss']} B, "
          f"noinit {s['noinit']} B, stack {s['stack']} B; RAM {ram} of 16384 B; "
          f"flash image snan-fw.bin {len(binary)} B at 0x{FLASH_BASE:08X}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
