"""Putting this project's firmware on a real MemriCore board, safely (docs/firmware.md).

Three steps, each refusing with one :class:`UserError` line before anything is written:

1. :func:`check_image`: the ELF is this tree's firmware for this MCU - a 32-bit RISC-V
   executable (:class:`~snan_hil.firmware_emu.fw_image.FirmwareImage`), built from the Python
   constants of this tree (the embedded constants hash), its loadable bytes inside the MIK32's
   8 MB SPIFI flash, its RAM (``.data + .bss + .noinit + stack``) inside the 16 KB, its entry
   point ``_start`` at the start of SPIFI flash (where the boot ROM jumps in SPIFI boot mode),
   and its trap vector (``mtvec``, set by ``startup.S`` to ``trap_entry``) inside the code and
   4-byte aligned (direct mode). The boot mode it needs follows: SPIFI.
2. :func:`find_uploader` / :func:`uploader_command`: the MIK32 vendor's uploader
   (MikronMIK32/mik32-uploader, ``mik32_upload.py``: OpenOCD over the board's JTAG adapter;
   it takes Intel HEX with absolute addresses, ``--boot-mode spifi``, ``--mcu-type MIK32V2``,
   ``--run-openocd`` with ``--openocd-exec``/``--openocd-interface``/``--openocd-target``,
   ``--adapter-speed`` in kHz - its README), given as ``--uploader`` or
   ``$SNAN_HIL_MIK32_UPLOADER``, else found on the PATH; none: one line, nothing written.
3. :func:`check_boot`: after the uploader has reset the board, HELLO on its serial port: the
   INFO of this firmware (protocol version, firmware name, MemriCore constants).

Nothing here was ever run against a real MIK32 (docs/firmware.md, "Flashing a real board"): the
uploader is driven as its public README documents it; the tests use a stand-in uploader.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from snan_hil.common.errors import UserError
from snan_hil.firmware_emu.fw_image import FLASH, HASH_SYMBOL, RAM, FirmwareImage, \
    expected_constants_hash
from snan_hil.protocol.board import MEMRICORE, BoardConstants
from snan_hil.protocol.messages import PROTOCOL_VERSION, Info

__all__ = ["UPLOADER_ENV", "FIRMWARE_NAME", "ImageCheck", "ImageReport", "check_image",
           "intel_hex", "find_uploader", "UploaderOptions", "uploader_command", "run_uploader",
           "check_boot"]

UPLOADER_ENV = "SNAN_HIL_MIK32_UPLOADER"
FIRMWARE_NAME = "snan-fw"
"""The firmware name INFO reports (``firmware/gen_constants.py`` FW_NAME)."""
_UPLOADER_NAMES = ("mik32_upload", "mik32_upload.py")


@dataclass(frozen=True)
class ImageCheck:
    """One check of the image: ``ok``, what was found and what is needed."""

    name: str
    ok: bool
    measured: str
    expected: str


@dataclass(frozen=True)
class ImageReport:
    """The checks of one ELF; ``image`` None when it could not be read at all."""

    path: Path
    image: FirmwareImage | None
    checks: tuple[ImageCheck, ...]
    boot_mode: str = "spifi"

    @property
    def ok(self) -> bool:
        return self.image is not None and all(c.ok for c in self.checks)

    def first_problem(self) -> str:
        bad = next((c for c in self.checks if not c.ok), None)
        if bad is None:
            return ""
        return f"{bad.name}: {bad.measured} (needs {bad.expected})"

    def to_dict(self) -> dict[str, Any]:
        return {"elf": str(self.path), "boot_mode": self.boot_mode, "ok": self.ok,
                "checks": [c.__dict__ for c in self.checks]}


def _flash_bytes(image: FirmwareImage) -> int:
    return sum(len(s.data) for s in image.segments if FLASH[0] <= s.addr < FLASH[0] + FLASH[1])


def check_image(path: str | os.PathLike[str] | None) -> ImageReport:
    """Check the ELF at ``path`` (None: ``build/firmware/snan-fw.elf``); see the module
    docstring. Unreadable or not a MIK32 firmware at all: one UserError line."""
    image = FirmwareImage.load(path, check_constants=False)
    checks = []
    expected_hash = expected_constants_hash()
    sym = image.symbols.get(HASH_SYMBOL)
    got = image.read(sym[0], 16) if sym else None
    checks.append(ImageCheck(
        "constants hash", got is not None and (expected_hash is None
                                               or got == expected_hash.encode()),
        "none" if got is None else got.decode(errors="replace"),
        expected_hash or "any (no source tree to compare with)"))
    flash = _flash_bytes(image)
    checks.append(ImageCheck("flash size", 0 < flash <= FLASH[1], f"{flash} B",
                             f"<= {FLASH[1]} B of SPIFI flash"))
    top = image.symbols.get("__stack_top")
    ram_used = (top[0] - RAM[0]) if top else max(
        (s.vaddr + s.memsz - RAM[0] for s in image.segments
         if RAM[0] <= s.vaddr < RAM[0] + RAM[1]), default=0)
    checks.append(ImageCheck("RAM", 0 <= ram_used <= RAM[1], f"{ram_used} B (data, bss, "
                             "noinit, stack)", f"<= {RAM[1]} B"))
    outside = [s for s in image.segments if s.data and not (
        FLASH[0] <= s.addr and s.addr + len(s.data) <= FLASH[0] + FLASH[1])]
    checks.append(ImageCheck("load addresses", not outside,
                             "all in SPIFI flash" if not outside else
                             ", ".join(f"0x{s.addr:08x}+{len(s.data)}" for s in outside),
                             f"every loaded byte in 0x{FLASH[0]:08x}..0x"
                             f"{FLASH[0] + FLASH[1] - 1:08x} (SPIFI boot)"))
    start = image.symbols.get("_start")
    checks.append(ImageCheck("entry point", image.entry == FLASH[0]
                             and (start is None or start[0] == image.entry),
                             f"0x{image.entry:08x}" + ("" if start is None
                                                      else f" (_start 0x{start[0]:08x})"),
                             f"0x{FLASH[0]:08x}, where the boot ROM jumps in SPIFI boot mode"))
    trap = image.symbols.get("trap_entry")
    text_lo, text = image.text
    checks.append(ImageCheck(
        "trap vector", trap is not None and text_lo <= trap[0] < text_lo + len(text)
        and trap[0] % 4 == 0,
        "no trap_entry" if trap is None else f"trap_entry 0x{trap[0]:08x}",
        "trap_entry in .text, 4-byte aligned (mtvec direct mode, set by startup.S)"))
    return ImageReport(image.path, image, tuple(checks))


def intel_hex(image: FirmwareImage) -> str:
    """The image's bytes in flash as Intel HEX (extended linear address records, 16 data
    bytes a record, the start address, end of file): what the vendor's uploader reads."""
    lines = []

    def record(kind: int, addr: int, data: bytes) -> None:
        body = bytes((len(data), (addr >> 8) & 0xFF, addr & 0xFF, kind)) + data
        lines.append(":" + body.hex().upper() + f"{(-sum(body)) & 0xFF:02X}")

    upper = -1
    for seg in sorted(image.segments, key=lambda s: s.addr):
        if not seg.data or not FLASH[0] <= seg.addr < FLASH[0] + FLASH[1]:
            continue
        for off in range(0, len(seg.data), 16):
            addr = seg.addr + off
            if addr >> 16 != upper:
                upper = addr >> 16
                record(0x04, 0, upper.to_bytes(2, "big"))
            chunk = seg.data[off:off + 16]
            if (addr & 0xFFFF) + len(chunk) > 0x10000:        # never across a 64 KB page
                first = 0x10000 - (addr & 0xFFFF)
                record(0x00, addr & 0xFFFF, chunk[:first])
                upper = (addr + first) >> 16
                record(0x04, 0, upper.to_bytes(2, "big"))
                record(0x00, 0, chunk[first:])
            else:
                record(0x00, addr & 0xFFFF, chunk)
    record(0x05, 0, image.entry.to_bytes(4, "big"))
    record(0x01, 0, b"")
    return "\n".join(lines) + "\n"


def find_uploader(explicit: str | None = None) -> list[str] | None:
    """The command that runs the vendor's uploader: ``explicit`` (a path or command name),
    else ``$SNAN_HIL_MIK32_UPLOADER``, else ``mik32_upload`` / ``mik32_upload.py`` on the
    PATH; a ``.py`` runs with this Python. None when there is none (or the given one is not a
    file or command)."""
    given = explicit or os.environ.get(UPLOADER_ENV)
    names = [given] if given else list(_UPLOADER_NAMES)
    for name in names:
        path = Path(name).expanduser()
        found = str(path) if path.is_file() else shutil.which(name)
        if found:
            return [sys.executable, found] if found.endswith(".py") else [found]
    return None


@dataclass(frozen=True)
class UploaderOptions:
    """How the uploader reaches the MCU (its README's options): OpenOCD's executable, scripts
    folder, interface and target configs (None: the uploader's defaults), adapter speed (kHz),
    MCU type."""

    openocd: str | None = None
    openocd_scripts: str | None = None
    interface: str | None = None
    target: str | None = None
    adapter_speed_khz: int | None = None
    mcu_type: str = "MIK32V2"


def uploader_command(prefix: list[str], hex_path: Path, opts: UploaderOptions,
                     boot_mode: str = "spifi") -> list[str]:
    """The uploader's command line for ``hex_path``: runs OpenOCD itself, maps ``boot_mode``
    onto the boot area, resets and runs the MCU afterwards (its default post-action)."""
    cmd = [*prefix, str(hex_path), "--run-openocd", f"--boot-mode={boot_mode}",
           f"--mcu-type={opts.mcu_type}"]
    for flag, value in (("--openocd-exec", opts.openocd),
                        ("--openocd-scripts", opts.openocd_scripts),
                        ("--openocd-interface", opts.interface),
                        ("--openocd-target", opts.target),
                        ("--adapter-speed", opts.adapter_speed_khz)):
        if value is not None:
            cmd.append(f"{flag}={value}")
    return cmd


def run_uploader(cmd: list[str], timeout_s: float = 300.0) -> subprocess.CompletedProcess[str]:
    """Run the uploader; UserError (one line with its last output line) when it fails."""
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s,
                              check=False)
    except FileNotFoundError as exc:
        raise UserError(f"the MIK32 uploader could not be started ({exc.strerror}: "
                        f"{cmd[0]}); nothing was written") from None
    except subprocess.TimeoutExpired:
        raise UserError(f"the MIK32 uploader did not finish within {timeout_s:g} s; the flash "
                        "may be partly written: run it again, or recover as docs/firmware.md "
                        "says") from None
    if proc.returncode != 0:
        last = (proc.stderr.strip() or proc.stdout.strip() or "no output").splitlines()[-1]
        raise UserError(f"the MIK32 uploader failed (exit {proc.returncode}): {last}; the "
                        "flash may be partly written: check the JTAG adapter and the boot "
                        "pins, then run it again (docs/firmware.md, recovery)")
    return proc


def check_boot(info: Info) -> list[str]:
    """What is wrong with the INFO a freshly flashed board answered (empty: it runs this
    firmware): the protocol version, the firmware name, MemriCore's constants."""
    problems = []
    if info.protocol_version != PROTOCOL_VERSION:
        problems.append(f"protocol version {info.protocol_version} (this firmware: "
                        f"{PROTOCOL_VERSION})")
    if not info.firmware_version.startswith(FIRMWARE_NAME):
        problems.append(f"firmware {info.firmware_version!r} (expected {FIRMWARE_NAME} ...)")
    for name in BoardConstants.__dataclass_fields__:
        if getattr(info, name) != getattr(MEMRICORE, name):
            problems.append(f"{name} {getattr(info, name)!r} (MemriCore: "
                            f"{getattr(MEMRICORE, name)!r})")
    return problems
