"""Test helpers shipped with the protocol: a lossy transport wrapper and a tiny fake board.

- :class:`LossyTransport` drops and/or corrupts a seeded fraction of the bytes going through
  another transport (issue 5 runs programming over it).
- :class:`FakeBoard` is a minimal deterministic firmware handler (no physics): each cell holds an
  ADC code, SET pulses raise it, RESET pulses lower it. It counts what it executed, so tests can
  prove a pulse was never applied twice. Not the emulator; for protocol tests only.
"""

from __future__ import annotations

import random
from dataclasses import dataclass, field

from snan_hil.protocol.board import MEMRICORE, BoardConstants
from snan_hil.protocol.errors import OutOfRangeError, SafetyLimitError, UnsupportedRequestError
from snan_hil.protocol.messages import (Capability, Clock, ClockReply, Hello, Info, Polarity,
                                        ProgramCell, ReadCell, ReadCellReply, ReadColumn,
                                        ReadColumnReply, Reply, Request, Reset, ResetReply,
                                        SpikeBatch, SpikeBatchReply, Status, StatusReply,
                                        WritePulse, WritePulseReply)
from snan_hil.protocol.transport import Transport

__all__ = ["LossStats", "LossyTransport", "FakeBoard"]


@dataclass
class LossStats:
    """Bytes seen, dropped and corrupted by a LossyTransport, per direction."""

    written: int = 0
    read: int = 0
    dropped_write: int = 0
    dropped_read: int = 0
    corrupted_write: int = 0
    corrupted_read: int = 0


class LossyTransport(Transport):
    """Wraps a transport and damages a seeded fraction of its bytes.

    ``drop``: probability that a byte is removed; ``corrupt``: probability that one random bit
    of a byte is flipped. ``directions``: "write", "read" or "both" (bytes the wrapper's user
    writes / reads). Deterministic for a given seed and byte sequence.
    """

    def __init__(self, inner: Transport, *, drop: float = 0.0, corrupt: float = 0.0,
                 seed: int = 0, directions: str = "both"):
        if directions not in ("write", "read", "both"):
            raise ValueError("directions must be 'write', 'read' or 'both'")
        self.inner = inner
        self.name = f"lossy {inner.name}"
        self.baud = inner.baud
        self.synchronous = inner.synchronous
        self.timeout = inner.timeout
        self.drop, self.corrupt, self.directions = drop, corrupt, directions
        self.stats = LossStats()
        self._rng = random.Random(seed)

    def _damage(self, data: bytes, direction: str) -> bytes:
        if self.directions not in (direction, "both") or not (self.drop or self.corrupt):
            return data
        out = bytearray()
        rng = self._rng
        for b in data:
            if self.drop and rng.random() < self.drop:
                setattr(self.stats, f"dropped_{direction}",
                        getattr(self.stats, f"dropped_{direction}") + 1)
                continue
            if self.corrupt and rng.random() < self.corrupt:
                b ^= 1 << rng.randrange(8)
                setattr(self.stats, f"corrupted_{direction}",
                        getattr(self.stats, f"corrupted_{direction}") + 1)
            out.append(b)
        return bytes(out)

    def _read(self, n: int, timeout: float) -> bytes:
        data = self.inner.read(n, timeout)
        self.stats.read += len(data)
        return self._damage(data, "read")

    def write(self, data: bytes) -> None:
        self.stats.written += len(data)
        damaged = self._damage(bytes(data), "write")
        if damaged:
            self.inner.write(damaged)

    def reset_input_buffer(self) -> None:
        self.inner.reset_input_buffer()

    def close(self) -> None:
        self.inner.close()


@dataclass
class FakeBoard:
    """Deterministic stand-in firmware handler for protocol tests (no device physics).

    Cell ``(r, c)`` holds an ADC code (initially ``1000 + 10*r + c``); a SET pulse adds
    ``amplitude_code // 10`` to it, a RESET pulse subtracts it. A read returns the code (cell
    reads ignore the read voltage); a column read returns the sum of
    ``code * dac / dac_full_scale_code``. Reads above the board's ``max_read_code`` and writes
    above its ``max_write_code`` are refused, unless ``interlocks`` is False (a board with the
    existing firmware, which has none: behind a ``LegacyDevice``). ``board``: its constants
    (default MemriCore).
    """

    board: BoardConstants = MEMRICORE
    boot_nonce: int = 0x1234ABCD
    codes: list[list[int]] = field(default_factory=list)
    pulses: int = 0
    executed: dict[str, int] = field(default_factory=dict)
    time_us: int = 0
    interlocks: bool = True

    def __post_init__(self) -> None:
        if not self.codes:
            b = self.board
            self.codes = [[1000 + 10 * r + c for c in range(b.cols)] for r in range(b.rows)]

    def _cell(self, row: int, col: int) -> None:
        b = self.board
        if not (0 <= row < b.rows and 0 <= col < b.cols):
            raise OutOfRangeError(f"cell ({row}, {col}) outside {b.rows}x{b.cols}",
                                  detail=row)

    def info(self) -> Info:
        caps = (Capability.READ_COLUMN | Capability.SPIKE_BATCH | Capability.CLOCK
                | Capability.RESET)
        return Info.from_board(self.board, firmware_version="fake-1", board_id="fake",
                               capabilities=int(caps), boot_nonce=self.boot_nonce)

    def __call__(self, req: Request) -> Reply:
        name = type(req).__name__
        self.executed[name] = self.executed.get(name, 0) + 1
        self.time_us += 100
        if isinstance(req, Hello):
            return self.info()
        if isinstance(req, ReadCell):
            self._cell(req.row, req.col)
            if self.interlocks and req.dac_code > self.board.max_read_code:
                raise SafetyLimitError(f"read code {req.dac_code} > {self.board.max_read_code}",
                                       detail=req.dac_code)
            return ReadCellReply(self.codes[req.row][req.col])
        if isinstance(req, ReadColumn):
            self._cell(0, req.col)
            if len(req.row_codes) != self.board.rows:
                raise OutOfRangeError(f"{len(req.row_codes)} row codes, need {self.board.rows}")
            full = self.board.dac_full_scale_code
            total = sum(self.codes[r][req.col] * c / full for r, c in enumerate(req.row_codes))
            return ReadColumnReply(min(0xFFFF, int(total)))
        if isinstance(req, WritePulse):
            self._cell(req.row, req.col)
            if self.interlocks and req.amplitude_code > self.board.max_write_code:
                raise SafetyLimitError(f"write code {req.amplitude_code} > "
                                       f"{self.board.max_write_code}", detail=req.amplitude_code)
            self.pulses += 1
            step = req.amplitude_code // 10
            sign = 1 if req.polarity == Polarity.SET else -1
            new = self.codes[req.row][req.col] + sign * step
            self.codes[req.row][req.col] = max(0, min(self.board.adc_full_scale_code, new))
            return WritePulseReply(self.codes[req.row][req.col])
        if isinstance(req, SpikeBatch):
            out = []
            full = self.board.dac_full_scale_code
            for _bin, gi in req.spike_order():
                rows = req.groups[gi].rows
                out.append(tuple(min(0xFFFF, sum(self.codes[r][c] * d // full for r, d in rows))
                                 for c in req.columns))
            return SpikeBatchReply(req.first_bin, len(req.columns), tuple(out))
        if isinstance(req, ProgramCell):
            raise UnsupportedRequestError("FakeBoard does not implement PROGRAM_CELL")
        if isinstance(req, Status):
            return StatusReply(pulses_applied=self.pulses,
                               cell_reads=self.executed.get("ReadCell", 0))
        if isinstance(req, Clock):
            return ClockReply(self.time_us, 1e-9 * self.pulses)
        if isinstance(req, Reset):
            old, self.boot_nonce = self.boot_nonce, (self.boot_nonce * 1103515245 + 12345) \
                & 0xFFFFFFFF
            self.time_us = 0
            return ResetReply(old, self.boot_nonce)
        raise UnsupportedRequestError(f"{name} not implemented")
