"""Building the C firmware and loading its ELF (docs/firmware.md): bad, stale and
never-booting ELFs are one line (exit 2) naming the ELF; the build's dependency file names the
Python definitions; build.py's failures (no compiler, a bad output folder, RAM overflow) are
one line; the .bin is the ELF's flash image."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

from snan_hil.tools import cli

ROOT = Path(__file__).resolve().parents[2]
ZIG = [sys.executable, "-m", "ziglang", "cc", "-target", "riscv32-freestanding-none",
       "-mcpu=generic_rv32+m+c"]


def _firmware_missing() -> str | None:
    if importlib.util.find_spec("unicorn") is None:
        return "needs the 'unicorn' package (pip install -e '.[firmware]')"
    if not (ROOT / "build" / "firmware" / "snan-fw.elf").is_file():
        return "firmware ELF not built ('make firmware')"
    return None


needs_firmware = pytest.mark.skipif(_firmware_missing() is not None,
                                    reason=str(_firmware_missing()))
needs_zig = pytest.mark.skipif(importlib.util.find_spec("ziglang") is None,
                               reason="needs the ziglang package")


def _cli_error(argv, capsys) -> str:
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


# -- the ELF ------------------------------------------------------------------------
def _zig_link(tmp_path: Path, name: str, asm: str, script: Path | None = None) -> Path:
    src = tmp_path / f"{name}.S"
    src.write_text(asm)
    out = tmp_path / f"{name}.elf"
    subprocess.run(ZIG + ["-nostdlib", "-T", str(script or ROOT / "firmware" / "link.ld"),
                          "-o", str(out), str(src)], check=True)
    return out


def _info_error(elf: Path, capsys, monkeypatch) -> str:
    monkeypatch.setenv("SNAN_HIL_FIRMWARE_ELF", str(elf))
    return _cli_error(["info", "--port", "emu", "--mcu", "firmware"], capsys)


@needs_firmware
def test_bad_elfs_are_one_line_naming_the_elf(emu, capsys, monkeypatch):
    good = ROOT / "build" / "firmware" / "snan-fw.elf"
    trunc = emu / "trunc.elf"
    for size in (100, 3000):
        trunc.write_bytes(good.read_bytes()[:size])
        line = _info_error(trunc, capsys, monkeypatch)
        assert str(trunc) in line and "truncated" in line
    line = _info_error(emu, capsys, monkeypatch)
    assert "is a directory" in line
    text = emu / "text.elf"
    text.write_text("hello\n")
    assert "not an ELF" in _info_error(text, capsys, monkeypatch)


@needs_firmware
@needs_zig
def test_relocatable_and_misplaced_elfs_are_refused(emu, capsys, monkeypatch):
    src = emu / "loop.S"
    src.write_text(".globl _start\n.section .init\n_start: j _start\n")
    obj = emu / "loop.o"
    subprocess.run(ZIG + ["-nostdlib", "-c", "-o", str(obj), str(src)], check=True)
    line = _info_error(obj, capsys, monkeypatch)
    assert "relocatable" in line and "cannot open port" not in line
    script = emu / "wrong.ld"
    script.write_text((ROOT / "firmware" / "link.ld").read_text()
                      .replace("ORIGIN = 0x80000000", "ORIGIN = 0x10000000"))
    wrong = _zig_link(emu, "wrong", src.read_text(), script)
    line = _info_error(wrong, capsys, monkeypatch)
    assert "0x10000000" in line and "outside" in line and "cannot open port" not in line


@needs_firmware
def test_stale_elf_is_refused(emu, capsys, monkeypatch):
    from snan_hil.firmware_emu.fw_image import HASH_SYMBOL, FirmwareImage, expected_constants_hash
    good = ROOT / "build" / "firmware" / "snan-fw.elf"
    data = bytearray(good.read_bytes())
    img = FirmwareImage.load(good)
    seg = next(s for s in img.segments if s.vaddr <= img.symbols[HASH_SYMBOL][0]
               < s.vaddr + len(s.data))
    digest = expected_constants_hash().encode()
    at = data.index(seg.data) + img.symbols[HASH_SYMBOL][0] - seg.vaddr
    assert data[at:at + 16] == digest
    data[at:at + 16] = b"0" * 16                  # as if built from other definitions
    stale = emu / "stale.elf"
    stale.write_bytes(bytes(data))
    assert _info_error(stale, capsys, monkeypatch) == \
        f"snan-hil info: error: firmware ELF {stale} is stale (built from other constants " \
        "than the Python definitions of this tree): run make firmware"


@needs_firmware
@needs_zig
def test_firmware_that_never_reaches_its_uart_loop_is_refused_quickly(emu, capsys,
                                                                     monkeypatch):
    from snan_hil.firmware_emu.fw_image import expected_constants_hash
    hang = _zig_link(emu, "hang", ".globl _start\n.section .init\n_start: j _start\n"
                     ".section .snan_constants,\"a\"\n.globl snan_constants_hash\n"
                     f"snan_constants_hash: .asciz \"{expected_constants_hash()}\"\n")
    line = _info_error(hang, capsys, monkeypatch)
    assert str(hang) in line and "did not reach its UART loop" in line
    # a firmware that traps at once (an illegal instruction) is refused after a few resets
    trap = _zig_link(emu, "trap", ".globl _start\n.section .init\n_start: .word 0\n"
                     ".section .snan_constants,\"a\"\n.globl snan_constants_hash\n"
                     f"snan_constants_hash: .asciz \"{expected_constants_hash()}\"\n")
    line = _info_error(trap, capsys, monkeypatch)
    assert str(trap) in line and "never reached its UART loop" in line


# -- make's dependencies ------------------------------------------------------------------
def test_depfile_names_every_python_definition_the_header_reads(tmp_path):
    header, dep = tmp_path / "c.h", tmp_path / "fw.d"
    subprocess.run([sys.executable, str(ROOT / "firmware" / "gen_constants.py"), str(header),
                    "--depfile", str(dep), "build/firmware/snan-fw.elf"], check=True)
    first = dep.read_text().splitlines()[0]
    target, _, deps = first.partition(": ")
    assert target == "build/firmware/snan-fw.elf"
    for needed in ("protocol/board.py", "protocol/device.py", "firmware_emu/spi_devices.py",
                   "firmware_emu/config.py", "firmware_emu/chip_identity.py",
                   "firmware/gen_constants.py"):
        assert needed in deps.split(), needed
    assert "CONSTANTS_HASH" in header.read_text()


# -- build.py -------------------------------------------------------------------------------
def _build(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(ROOT / "firmware" / "build.py"), *args],
                          capture_output=True, text=True, timeout=600)


def test_build_errors_are_one_line(tmp_path):
    done = _build("--cc", "no-such-compiler-xyz", "--out", str(tmp_path / "b"))
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert done.stderr.strip() == (
        "firmware build: compiler 'no-such-compiler-xyz' not found; install it or give another "
        "--cc (default: python -m ziglang cc, from pip install -e '.[firmware]')")
    a_file = tmp_path / "file"
    a_file.write_text("x")
    for out in (a_file, a_file / "sub"):
        done = _build("--out", str(out))
        assert done.returncode == 2 and "Traceback" not in done.stderr
        assert len(done.stderr.strip().splitlines()) == 1 and str(out) in done.stderr
    assert a_file.read_text() == "x"


@needs_firmware
@needs_zig
def test_ram_overflow_is_the_linkers_line(tmp_path):
    big = tmp_path / "big.c"
    big.write_text("char big_buf[8192];\n")
    subprocess.run(ZIG + ["-c", str(big), "-o", str(tmp_path / "big.o")], check=True)
    # a compiler wrapper: compiling reuses make firmware's objects (time), the link is real
    # and gets 8 KB more .bss
    wrapper = tmp_path / "cc.py"
    wrapper.write_text(
        "import shutil, subprocess, sys\nfrom pathlib import Path\nargs = sys.argv[1:]\n"
        "if '-c' in args:\n"
        "    out = Path(args[args.index('-o') + 1])\n"
        f"    shutil.copy(Path({str(ROOT / 'build' / 'firmware')!r}) / out.name, out)\n"
        "    sys.exit(0)\n"
        f"args += [{str(tmp_path / 'big.o')!r}, '-Wl,-u,big_buf']\n"
        f"sys.exit(subprocess.call({ZIG!r} + args))\n")
    done = _build("--out", str(tmp_path / "over"), "--cc", f"{sys.executable} {wrapper}")
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert done.stderr.strip().splitlines() == [
        "firmware build: linking failed: ld.lld: error: .data + .bss + .noinit + stack exceed "
        "the 16 KB RAM"]
    assert not (tmp_path / "over" / "snan-fw.elf").exists()


@needs_firmware
def test_the_bin_is_the_elfs_flash_image():
    from snan_hil.firmware_emu.fw_image import FirmwareImage
    built = ROOT / "build" / "firmware"
    img = FirmwareImage.load(built / "snan-fw.elf")
    binary = (built / "snan-fw.bin").read_bytes()
    assert binary
    for seg in img.segments:
        if seg.data:
            off = seg.addr - 0x8000_0000
            assert binary[off:off + len(seg.data)] == seg.data
