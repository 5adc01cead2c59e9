"""A faulty board on purpose: hardware faults the emulator can be told to have (tests, demos).

Each fault lives in the emulated *hardware* - an SPI chip, the analog front end or the UART -
never in either firmware (the Python MCU model or the C firmware on the instruction-level MCU),
so both MCUs meet the same fault and a self-test (``snan-hil selftest``) must find it from the
outside, as on a real board. ``snan-hil emu --fault SPEC`` (repeatable), ``--port emu --fault
SPEC`` and ``emu://?fault=SPEC[,SPEC...]`` turn them on; docs/emulator.md lists them.

SPEC is ``NAME[:ARG[:ARG]]``:

=====================  ======================  ==================================================
name                   arguments (default)     what the hardware does
=====================  ======================  ==================================================
``adc-stuck-bit``      ``BIT:VALUE`` (6:1)     TLC3541 output bit BIT (0-13) reads VALUE (0/1)
``gain``               ``FACTOR`` (0.8)        the ADC amplifier's gain is FACTOR x nominal (the
                                               board still announces the nominal gain)
``swap-col-lines``     ``A:B`` (4:5)           outputs A and B of the column 74HC595 swapped on
                                               the board (4:5 = SUM_PATH <-> POL_SET)
``slow-dac``           ``DACk:TAU_US`` (DAC1:40)  row DAC k's outputs settle exponentially with
                                               time constant TAU_US (AD5328: ~6 us to 1/2 LSB)
``uart-drop``          ``P`` (0.02)            the UART loses each byte (both ways) with
                                               probability P (seeded by the emulator's seed)
``dead-cells``         ``R0-R1:C0-C1`` (8-15:2-3)  the cells of rows R0..R1, columns C0..C1 are
                                               open: no read current, pulses do nothing
=====================  ======================  ==================================================

A faulty board runs every ADC frame through the per-frame path of the device models (the
emulator's fast paths - batched readings, the one-pass SPIKE_BATCH, the ISA MCU's native column
kernel - assume healthy hardware and are switched off), so it is slower, not different in
kind.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass, field, replace
from typing import Any

from snan_hil.common.errors import UserError
from snan_hil.firmware_emu import registers as reg

__all__ = ["FAULT_NAMES", "BoardFaults", "parse_faults", "apply_faults", "UartDropper"]

FAULT_NAMES = ("adc-stuck-bit", "gain", "swap-col-lines", "slow-dac", "uart-drop", "dead-cells")
"""The fault names a SPEC may start with."""

_FORM = ("NAME[:ARG[:ARG]] with NAME one of " + ", ".join(FAULT_NAMES)
         + " (docs/emulator.md, 'Faulty boards')")


@dataclass(frozen=True)
class BoardFaults:
    """The hardware faults of one emulated board (all off by default).

    ``adc_stuck_bit``: (bit 0..13, value 0/1); ``gain_factor``: actual / nominal amplifier
    gain; ``swapped_col_lines``: two outputs (0..7) of the column register exchanged;
    ``slow_dac``: (row DAC index 0..3, settling time constant in us); ``uart_drop``: probability
    of losing one UART byte; ``dead_cells``: (row0, row1, col0, col1), inclusive.
    ``specs``: the SPEC strings it was parsed from (for INFO-independent provenance)."""

    adc_stuck_bit: tuple[int, int] | None = None
    gain_factor: float = 1.0
    swapped_col_lines: tuple[int, int] | None = None
    slow_dac: tuple[int, float] | None = None
    uart_drop: float = 0.0
    dead_cells: tuple[int, int, int, int] | None = None
    specs: tuple[str, ...] = field(default=(), compare=False)

    @property
    def any(self) -> bool:
        """Whether any fault is on."""
        return self.analog or self.uart_drop > 0.0

    @property
    def analog(self) -> bool:
        """Whether a fault of the SPI chips or the front end is on (fast paths switched off)."""
        return (self.adc_stuck_bit is not None or self.gain_factor != 1.0
                or self.swapped_col_lines is not None or self.slow_dac is not None
                or self.dead_cells is not None)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able description (the SPEC strings)."""
        return {"faults": list(self.specs)}

    def merged(self, other: BoardFaults) -> BoardFaults:
        """These faults with ``other``'s set ones added (other wins)."""
        changes: dict[str, Any] = {}
        for name in ("adc_stuck_bit", "swapped_col_lines", "slow_dac", "dead_cells"):
            if getattr(other, name) is not None:
                changes[name] = getattr(other, name)
        if other.gain_factor != 1.0:
            changes["gain_factor"] = other.gain_factor
        if other.uart_drop:
            changes["uart_drop"] = other.uart_drop
        return replace(self, specs=self.specs + other.specs, **changes)


def _ints(spec: str, args: list[str], n: int) -> list[int]:
    try:
        return [int(a) for a in args[:n]]
    except ValueError:
        raise UserError(f"fault {spec!r}: arguments must be integers; {_FORM}") from None


def _range(spec: str, text: str, hi: int) -> tuple[int, int]:
    a, sep, b = text.partition("-")
    try:
        lo_v, hi_v = int(a), int(b if sep else a)
    except ValueError:
        raise UserError(f"fault {spec!r}: give a range like 8-15") from None
    if not 0 <= lo_v <= hi_v < hi:
        raise UserError(f"fault {spec!r}: range {text} outside 0..{hi - 1}")
    return lo_v, hi_v


def _adc_stuck_bit(spec: str, args: list[str]) -> BoardFaults:
    bit, value = _ints(spec, args, 2) + [6, 1][len(args):]
    if not (0 <= bit <= 13 and value in (0, 1)) or len(args) > 2:
        raise UserError(f"fault {spec!r}: give adc-stuck-bit:BIT:VALUE, BIT 0..13, "
                        "VALUE 0 or 1")
    return BoardFaults(adc_stuck_bit=(bit, value))


def _float(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        return float("nan")


def _gain(spec: str, args: list[str]) -> BoardFaults:
    factor = _float(args[0]) if args else 0.8
    if not (math.isfinite(factor) and 0.0 < factor <= 10.0) or len(args) > 1:
        raise UserError(f"fault {spec!r}: give gain:FACTOR with 0 < FACTOR <= 10")
    return BoardFaults(gain_factor=factor)


def _swap(spec: str, args: list[str]) -> BoardFaults:
    a, b = _ints(spec, args, 2) + [4, 5][len(args):]
    if not (0 <= a <= 7 and 0 <= b <= 7 and a != b) or len(args) > 2:
        raise UserError(f"fault {spec!r}: give swap-col-lines:A:B, two lines 0..7")
    return BoardFaults(swapped_col_lines=(a, b))


def _slow_dac(spec: str, args: list[str]) -> BoardFaults:
    dac = args[0] if args else "DAC1"
    if dac not in reg.CS_ROW_DAC:
        raise UserError(f"fault {spec!r}: the DAC is one of {', '.join(reg.CS_ROW_DAC)}")
    tau = _float(args[1]) if len(args) > 1 else 40.0
    if not (math.isfinite(tau) and 0.0 < tau <= 1e6) or len(args) > 2:
        raise UserError(f"fault {spec!r}: give slow-dac:DACk:TAU_US, 0 < TAU_US <= 1e6")
    return BoardFaults(slow_dac=(reg.CS_ROW_DAC.index(dac), tau))


def _uart_drop(spec: str, args: list[str]) -> BoardFaults:
    p = _float(args[0]) if args else 0.02
    if not (0.0 < p < 1.0) or len(args) > 1:
        raise UserError(f"fault {spec!r}: give uart-drop:P with 0 < P < 1")
    return BoardFaults(uart_drop=p)


def _dead_cells(spec: str, args: list[str]) -> BoardFaults:
    from snan_hil.protocol.board import MEMRICORE
    rows = _range(spec, args[0], MEMRICORE.rows) if args else (8, 15)
    cols = _range(spec, args[1], MEMRICORE.cols) if len(args) > 1 else (2, 3)
    if len(args) > 2:
        raise UserError(f"fault {spec!r}: give dead-cells:R0-R1:C0-C1")
    return BoardFaults(dead_cells=(*rows, *cols))


_PARSERS = {"adc-stuck-bit": _adc_stuck_bit, "gain": _gain, "swap-col-lines": _swap,
            "slow-dac": _slow_dac, "uart-drop": _uart_drop, "dead-cells": _dead_cells}


def _one(spec: str) -> BoardFaults:
    name, *args = spec.strip().split(":")
    parser = _PARSERS.get(name)
    if parser is None:
        raise UserError(f"unknown fault {spec!r}; {_FORM}")
    return parser(spec, args)


def parse_faults(specs: str | list[str] | tuple[str, ...] | None) -> BoardFaults:
    """The faults of ``specs`` (SPEC strings, each possibly several joined by commas; see the
    module docstring). UserError (one line naming the SPEC) if one is malformed."""
    if specs is None:
        return BoardFaults()
    if isinstance(specs, str):
        specs = [specs]
    faults = BoardFaults()
    for text in specs:
        for spec in text.split(","):
            if spec.strip():
                one = _one(spec.strip())
                faults = faults.merged(replace(one, specs=(spec.strip(),)))
    return faults


class UartDropper:
    """The UART of a board that loses bytes: each byte, in either direction, is lost with
    probability ``p`` (a seeded stream)."""

    def __init__(self, p: float, seed: int):
        self.p = float(p)
        self._rng = random.Random(seed)
        self.dropped = 0

    def __call__(self, data: bytes) -> bytes:
        if not data or self.p <= 0.0:
            return data
        kept = bytearray()
        for byte in data:
            if self._rng.random() < self.p:
                self.dropped += 1
            else:
                kept.append(byte)
        return bytes(kept)


def apply_faults(board: Any, faults: BoardFaults) -> None:
    """Wire ``faults`` into ``board`` (:class:`~snan_hil.firmware_emu.board.Board`): the ADC's
    stuck bit, the front end's gain, dead cells and slow row DAC, the column register's wiring.
    The UART is the emulator's (:class:`UartDropper`)."""
    if faults.adc_stuck_bit is not None:
        bit, value = faults.adc_stuck_bit
        board.adc.stuck_bit = (1 << bit, value << bit)
    fe = board.front_end
    if faults.gain_factor != 1.0:
        fe.config = replace(fe.config, gain=fe.config.gain * faults.gain_factor)
    if faults.swapped_col_lines is not None:
        board.sr_col.wiring = faults.swapped_col_lines
    if faults.slow_dac is not None:
        fe.slow_dac = faults.slow_dac
    if faults.dead_cells is not None:
        fe.dead_cells = faults.dead_cells
    if faults.analog:
        fe.invalidate_array()
