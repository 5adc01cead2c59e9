"""Branch coverage of the C firmware, measured on the instruction-level MCU.

The firmware ELF's code is decoded for its conditional branches (RV32I ``beq bne blt bge bltu
bgeu`` and RV32C ``c.beqz c.bnez``: the target, and the fall-through after the instruction) and
its calls of ``build_error`` (every place the firmware answers ERROR: ``send_error`` and
``send_nak`` are inlined into their callers, ``build_error`` is not). :class:`BranchCoverage`
hooks unicorn's basic-block callback on an :class:`~.mcu_isa.IsaMcu`: when a block ends with a
conditional branch, the next block's start says which way it went. The report gives, per
function (the ELF's function symbols; static helpers that the compiler inlined count in their
callers), the branches and the outcomes (taken, not taken) reached, and which ERROR call sites
ran.

A measurement tool for ``bench/bench_fw_coverage.py``: the Python hook costs one Python call
per executed block (several times slower than the native core alone). The same decoder gives
the return addresses of a function's calls (:func:`return_addresses`), where the MCU hooks
the end of ``run_lean`` (:mod:`~.mcu_isa`).
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from snan_hil.firmware_emu.fw_image import FirmwareImage

__all__ = ["Branch", "decode", "return_addresses", "BranchCoverage", "FunctionCoverage",
           "ERROR_FUNCTION", "ERROR_CALLS", "error_lines"]

ERROR_FUNCTION = "build_error"
"""The firmware function every ERROR reply is built by (firmware/src/proto.c)."""
ERROR_CALLS = ("send_error(", "send_nak(", "refuse(")
"""The calls in the C sources that answer ERROR (proto.c) or refuse a request with an ERROR
(ops.c, window.c): each call is one ERROR path."""


def error_lines(src: Any) -> list[tuple[str, int, tuple[str, ...]]]:
    """(file, line, message texts) of every call of :data:`ERROR_CALLS` in the C sources of
    folder ``src`` (the definitions left out): the ERROR paths as the source has them, each
    known by the texts its ERROR reply carries (a call spread over lines is read to its
    ``;``). ``send_nak`` calls carry the texts of ``send_nak`` itself."""
    found = []
    for path in sorted(Path(src).glob("*.c")):
        lines = path.read_text().splitlines()
        nak = ()
        for i, line in enumerate(lines):
            if line.startswith("static void send_nak("):
                body = " ".join(lines[i:i + 12])
                nak = tuple(re.findall(r'"([^"]+)"', body.split("}", 1)[0]))
        for i, line in enumerate(lines, 1):
            text = line.strip()
            if not any(c in text for c in ERROR_CALLS) or text.startswith(("static", "*", "/")):
                continue
            call = text
            k = i
            while ";" not in call and k < len(lines):
                call += " " + lines[k].strip()
                k += 1
            texts = tuple(re.findall(r'"([^"]+)"', call)) or (nak if "send_nak(" in call
                                                             else ())
            found.append((path.name, i, texts))
    return found


@dataclass(frozen=True)
class Branch:
    """A conditional branch at ``addr`` (``size`` 2 or 4 bytes) to ``target``."""

    addr: int
    size: int
    target: int

    @property
    def fall(self) -> int:
        return self.addr + self.size


def _sext(value: int, bits: int) -> int:
    return value - (1 << bits) if value & (1 << (bits - 1)) else value


def _decode_one(word: int, addr: int) -> tuple[int, str | None, int]:
    """(size, kind "branch"/"call"/None, target) of the instruction at ``addr``."""
    if word & 3 == 3:                                  # 32-bit
        op = word & 0x7F
        if op == 0x63:
            imm = ((word >> 31) & 1) << 12 | ((word >> 7) & 1) << 11 | \
                ((word >> 25) & 0x3F) << 5 | ((word >> 8) & 0xF) << 1
            return 4, "branch", addr + _sext(imm, 13)
        if op == 0x6F:
            imm = ((word >> 31) & 1) << 20 | ((word >> 12) & 0xFF) << 12 | \
                ((word >> 20) & 1) << 11 | ((word >> 21) & 0x3FF) << 1
            return 4, "call" if (word >> 7) & 0x1F else "jump", addr + _sext(imm, 21)
        return 4, None, 0
    half = word & 0xFFFF
    quadrant, funct3 = half & 3, half >> 13
    if quadrant == 1 and funct3 in (6, 7):             # c.beqz / c.bnez
        imm = ((half >> 12) & 1) << 8 | ((half >> 10) & 3) << 3 | ((half >> 5) & 3) << 6 | \
            ((half >> 3) & 3) << 1 | ((half >> 2) & 1) << 5
        return 2, "branch", addr + _sext(imm, 9)
    if quadrant == 1 and funct3 == 1:                  # c.jal (RV32C)
        imm = ((half >> 12) & 1) << 11 | ((half >> 11) & 1) << 4 | ((half >> 9) & 3) << 8 | \
            ((half >> 8) & 1) << 10 | ((half >> 7) & 1) << 6 | ((half >> 6) & 1) << 7 | \
            ((half >> 3) & 7) << 1 | ((half >> 2) & 1) << 5
        return 2, "call", addr + _sext(imm, 12)
    return 2, None, 0


def _walk(image: FirmwareImage) -> Iterator[tuple[int, int, str | None, int]]:
    """(address, size, kind, target) of every instruction of ``.text`` in order (kind as
    :func:`_decode_one`'s); a far call (``auipc ra, hi; jalr ra, lo(ra)``) is its ``jalr``
    with kind "call" and the target the pair computes."""
    base, text = image.text
    o = 0
    auipc: tuple[int, int, int] | None = None          # (addr, rd, upper immediate)
    while o + 2 <= len(text):
        word = int.from_bytes(text[o:o + 4].ljust(4, b"\0"), "little")
        addr = base + o
        size, kind, target = _decode_one(word, addr)
        if size == 4 and word & 0x7F == 0x67 and auipc is not None \
                and (word >> 15) & 0x1F == auipc[1] and (word >> 7) & 0x1F == 1:
            kind, target = "call", auipc[0] + auipc[2] + _sext(word >> 20, 12)
        yield addr, size, kind, target
        auipc = (addr, (word >> 7) & 0x1F, _sext(word & 0xFFFFF000, 32)) \
            if size == 4 and word & 0x7F == 0x17 else None
        o += size


def decode(image: FirmwareImage) -> tuple[dict[int, Branch], dict[int, int], list[int]]:
    """The branches of ``.text`` by address, the instruction start of every instruction end
    (end address -> start), and the addresses of the calls of :data:`ERROR_FUNCTION`."""
    error = image.symbols.get(ERROR_FUNCTION, (None, 0))[0]
    branches: dict[int, Branch] = {}
    ends: dict[int, int] = {}
    calls = []
    for addr, size, kind, target in _walk(image):
        if kind == "branch":
            branches[addr] = Branch(addr, size, target)
        elif kind == "call" and target == error:
            calls.append(addr)
        ends[addr + size] = addr
    return branches, ends, calls


def return_addresses(image: FirmwareImage, function: str) -> list[int]:
    """The return address of every call of ``function`` (a symbol of the ELF) in ``.text``,
    near (``jal ra`` / ``c.jal``) or far (``auipc ra`` + ``jalr ra``): where the caller goes
    on once ``function`` returns. Empty if the symbol is missing or never called directly."""
    entry = image.symbols.get(function, (None, 0))[0]
    if entry is None:
        return []
    return [addr + size for addr, size, kind, target in _walk(image)
            if kind == "call" and target == entry]


@dataclass
class FunctionCoverage:
    """One function: its branches, outcomes reached (of 2 x branches), blocks run."""

    name: str
    addr: int
    size: int
    branches: int = 0
    outcomes: int = 0
    uncovered: list[str] = field(default_factory=list)

    @property
    def percent(self) -> float | None:
        return 100.0 * self.outcomes / (2 * self.branches) if self.branches else None


class BranchCoverage:
    """Collects the branch outcomes of the firmware ``image`` on the MCUs it is attached to
    (:meth:`attach`, any number, e.g. one per boot of a board)."""

    def __init__(self, image: FirmwareImage) -> None:
        self.image = image
        self.branches, self._ends, self.error_calls = decode(image)
        self.taken: set[int] = set()
        self.fell: set[int] = set()
        self.blocks: set[tuple[int, int]] = set()
        self._pending: Branch | None = None

    def attach(self, mcu: Any) -> None:
        """Hook an :class:`~.mcu_isa.IsaMcu`'s CPU (its blocks from now on). Code translated
        before carries no hook (unicorn compiles hooks into its translated blocks), so the
        translation cache is flushed; code that ran only before (the boot) is seen again after
        :meth:`~.mcu_isa.IsaMcu.press_reset`."""
        from unicorn import UC_HOOK_BLOCK
        self._pending = None
        mcu.cpu.hook_add(UC_HOOK_BLOCK, self._block)
        mcu.cpu.ctl_flush_tb()

    def _block(self, uc: Any, address: int, size: int, user_data: Any) -> None:
        p = self._pending
        if p is not None:
            if address == p.target:
                self.taken.add(p.addr)
            if address == p.fall:
                self.fell.add(p.addr)
        self.blocks.add((address, size))
        start = self._ends.get(address + size)
        self._pending = self.branches.get(start) if start is not None else None

    # ------------------------------------------------------------------ results
    def functions(self) -> list[FunctionCoverage]:
        """Per function symbol in ``.text`` (size > 0), in address order."""
        base, text = self.image.text
        funcs = sorted((addr, size, name) for name, (addr, size) in self.image.symbols.items()
                       if size > 0 and base <= addr < base + len(text))
        out = []
        for addr, size, name in funcs:
            fc = FunctionCoverage(name, addr, size)
            for b in self.branches.values():
                if addr <= b.addr < addr + size:
                    fc.branches += 1
                    for ok, what in ((b.addr in self.taken, "taken"),
                                     (b.addr in self.fell, "not taken")):
                        if ok:
                            fc.outcomes += 1
                        else:
                            fc.uncovered.append(f"0x{b.addr:08x} {what}")
            if fc.branches:
                out.append(fc)
        return out

    def error_sites(self) -> tuple[list[int], list[int]]:
        """(ERROR call sites that ran, those that did not)."""
        ran: list[int] = []
        missed: list[int] = []
        starts = sorted(self.blocks)
        for site in self.error_calls:
            hit = any(a <= site < a + s for a, s in starts if a <= site)
            (ran if hit else missed).append(site)
        return ran, missed

    def total(self) -> tuple[int, int]:
        """(outcomes reached, outcomes) over every branch."""
        n = len(self.branches)
        return len(self.taken) + len(self.fell), 2 * n
