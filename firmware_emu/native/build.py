"""Build the native peripheral core of the instruction-level MCU (a host shared library).

``python firmware_emu/native/build.py [--out build/firmware]`` writes ``mcu_state.h`` from
``snan_hil.firmware_emu.mik32_state`` (the one definition of the state layout) and compiles
``mik32_periph.c`` for this machine with the pip-installed Zig toolchain (``python -m ziglang
cc``, the ``[firmware]`` extra), linked with the installed numpy's ``libnpyrandom.a`` (the
normal generator numpy's ``Generator`` uses), into ``libmik32periph.so``. ``make firmware``
runs it; the emulator falls back to the Python reference core (slow) when the library is
missing or stale (``snan_hil.firmware_emu.mik32_native``). ``--cc`` selects another compiler
(e.g. ``cc``).
"""

from __future__ import annotations

import argparse
import shlex
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent
LIB_NAME = "libmik32periph.so"
ZIG_CC = [sys.executable, "-m", "ziglang", "cc"]
# -mcpu=baseline: the generic instruction set of this architecture (zig cc defaults to the
# build machine's own CPU, which another machine of the same architecture may not have)
# -ffp-contract=off: no fused multiply-add (the native column-read kernel must round as numpy)
CFLAGS = ["-std=c11", "-O2", "-mcpu=baseline", "-ffp-contract=off", "-shared", "-fPIC", "-Wall",
          "-Wextra", "-Werror"]


def numpy_random_lib() -> tuple[Path, str]:
    """numpy's libnpyrandom.a (its normal generator, for the column-read kernel) and the
    numpy version it belongs to."""
    import numpy
    lib = Path(numpy.__file__).parent / "random" / "lib" / "libnpyrandom.a"
    if not lib.is_file():
        raise SystemExit(f"{lib} not found: this numpy does not ship its random C library")
    return lib, numpy.__version__


def main(argv: list[str] | None = None) -> int:
    from snan_hil.firmware_emu import mik32_state
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "build" / "firmware"))
    ap.add_argument("--cc", default=None, help="compiler command instead of python -m ziglang cc")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    header = out / "mcu_state.h"
    text = mik32_state.c_header()
    if not header.is_file() or header.read_text() != text:
        header.write_text(text)
    cc = shlex.split(args.cc) if args.cc else ZIG_CC
    lib = out / LIB_NAME
    tmp = out / (LIB_NAME + ".tmp")
    npyrandom, np_version = numpy_random_lib()
    cmd = cc + CFLAGS + [f'-DNUMPY_VERSION="{np_version}"', "-I", str(out),
                         str(HERE / "mik32_periph.c"), str(npyrandom), "-o", str(tmp), "-lm"]
    subprocess.run(cmd, check=True)
    tmp.replace(lib)
    print(f"native MCU core {lib.relative_to(ROOT) if lib.is_relative_to(ROOT) else lib} "
          f"(state layout {mik32_state.layout_hash()})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
