"""Test helpers shipped with the protocol: a lossy transport wrapper and a tiny fake board.

- :class:`LossyTransport` drops, corrupts, duplicates and/or inserts a seeded fraction of the
  bytes going through another transport (issue 5 runs programming over it);
  :class:`CorruptingProxy` does the same to a TCP connection (``bench/bench_link.py``), both
  with :class:`ByteCorrupter`'s damage model for a uniform rate.
- :class:`StaleFloodBoard` answers HELLO, then only floods replies with a stale sequence
  number (a board replaying old replies, or a second program on the port); for the link's
  give-up tests and ``bench/bench_link.py``.
- :class:`FakeBoard` is a minimal deterministic firmware handler (no physics): each cell holds an
  ADC code, SET pulses raise it, RESET pulses lower it. It counts what it executed, so tests can
  prove a pulse was never applied twice. Not the emulator; for protocol tests only.
"""

from __future__ import annotations

import random
import select
import socket
import threading
from dataclasses import dataclass, field

from snan_hil.protocol.board import MEMRICORE, BoardConstants
from snan_hil.protocol.device import DeviceEndpoint
from snan_hil.protocol.errors import (OutOfRangeError, ProtocolError, SafetyLimitError,
                                      UnsupportedRequestError)
from snan_hil.protocol.frames import Frame, FrameDecoder, encode_frame
from snan_hil.protocol.messages import (Capability, Clock, ClockReply, Hello, Info, Polarity,
                                        ProgramCell, ReadCell, ReadCellReply, ReadColumn,
                                        ReadColumnReply, Reply, Request, Reset, ResetReply,
                                        SpikeBatch, SpikeBatchReply, Status, StatusReply,
                                        WritePulse, WritePulseReply)
from snan_hil.protocol.faults import TcpRelay
from snan_hil.protocol.transport import Transport

__all__ = ["LossStats", "DAMAGE_KINDS", "ByteCorrupter", "LossyTransport", "CorruptingProxy",
           "StaleFloodBoard", "FakeBoard"]


@dataclass
class LossStats:
    """Bytes seen, dropped, corrupted, duplicated and inserted by a LossyTransport, per
    direction."""

    written: int = 0
    read: int = 0
    dropped_write: int = 0
    dropped_read: int = 0
    corrupted_write: int = 0
    corrupted_read: int = 0
    duplicated_write: int = 0
    duplicated_read: int = 0
    inserted_write: int = 0
    inserted_read: int = 0

    @property
    def damaged(self) -> int:
        """Bytes damaged in either direction (each kind counted)."""
        return sum(getattr(self, f"{k}_{d}") for k in ("dropped", "corrupted", "duplicated",
                                                        "inserted") for d in ("write", "read"))


DAMAGE_KINDS = ("flip", "drop", "dup", "insert")
"""How :class:`ByteCorrupter` damages a byte: one bit flipped, the byte dropped, the byte sent
twice, a random byte inserted before it."""


class ByteCorrupter:
    """Damages a seeded fraction ``rate`` of the bytes of a stream: each damaged byte gets one
    of ``kinds`` (:data:`DAMAGE_KINDS`, equally likely). Deterministic for a seed and a byte
    sequence, whatever the chunking. ``counts``: damaged bytes per kind."""

    def __init__(self, rate: float, seed: int = 0, kinds: tuple[str, ...] = DAMAGE_KINDS):
        if not 0.0 <= rate <= 1.0:
            raise ValueError(f"rate must be in [0, 1], got {rate}")
        unknown = set(kinds) - set(DAMAGE_KINDS)
        if unknown or not kinds:
            raise ValueError(f"kinds must be some of {DAMAGE_KINDS}, got {kinds}")
        self.rate, self.kinds = float(rate), tuple(kinds)
        self._rng = random.Random(seed)
        self.bytes_in = 0
        self.counts = {k: 0 for k in DAMAGE_KINDS}

    def __call__(self, data: bytes) -> bytes:
        self.bytes_in += len(data)
        if not self.rate:
            return bytes(data)
        rng, out = self._rng, bytearray()
        for b in data:
            if rng.random() >= self.rate:
                out.append(b)
                continue
            kind = self.kinds[rng.randrange(len(self.kinds))]
            self.counts[kind] += 1
            if kind == "flip":
                out.append(b ^ (1 << rng.randrange(8)))
            elif kind == "dup":
                out += bytes((b, b))
            elif kind == "insert":
                out += bytes((rng.randrange(256), b))
            # "drop": nothing
        return bytes(out)


class LossyTransport(Transport):
    """Wraps a transport and damages a seeded fraction of its bytes.

    ``drop``: probability that a byte is removed; ``corrupt``: that one random bit of it is
    flipped; ``duplicate``: that it is sent twice; ``insert``: that a random byte is inserted
    before it. ``directions``: "write", "read" or "both" (bytes the wrapper's user writes /
    reads). Deterministic for a given seed and byte sequence. :meth:`uniform` damages a total
    fraction of the bytes, equally split between the four kinds.
    """

    def __init__(self, inner: Transport, *, drop: float = 0.0, corrupt: float = 0.0,
                 seed: int = 0, directions: str = "both", duplicate: float = 0.0,
                 insert: float = 0.0):
        if directions not in ("write", "read", "both"):
            raise ValueError("directions must be 'write', 'read' or 'both'")
        self.inner = inner
        self.name = f"lossy {inner.name}"
        self.baud = inner.baud
        self.synchronous = inner.synchronous
        self.timeout = inner.timeout
        self.drop, self.corrupt, self.directions = drop, corrupt, directions
        self.duplicate, self.insert = duplicate, insert
        self.stats = LossStats()
        self._rng = random.Random(seed)
        self._uniform: dict[str, ByteCorrupter] = {}

    @classmethod
    def uniform(cls, inner: Transport, rate: float, seed: int = 0,
                directions: str = "both") -> "LossyTransport":
        """Damage ``rate`` of the bytes, each damaged byte flipped, dropped, duplicated or
        preceded by an inserted byte (a :class:`ByteCorrupter` per direction, seeds ``seed``
        for written bytes and ``seed + 1`` for read ones: the model of
        :class:`CorruptingProxy`)."""
        lossy = cls(inner, seed=seed, directions=directions)
        lossy._uniform = {"write": ByteCorrupter(rate, seed), "read": ByteCorrupter(rate, seed + 1)}
        return lossy

    def _count(self, kind: str, direction: str) -> None:
        name = f"{kind}_{direction}"
        setattr(self.stats, name, getattr(self.stats, name) + 1)

    def _damage(self, data: bytes, direction: str) -> bytes:
        if self._uniform and self.directions in (direction, "both"):
            corrupter = self._uniform[direction]
            before = dict(corrupter.counts)
            damaged = corrupter(data)
            for kind, stat in (("flip", "corrupted"), ("drop", "dropped"), ("dup", "duplicated"),
                               ("insert", "inserted")):
                for _ in range(corrupter.counts[kind] - before[kind]):
                    self._count(stat, direction)
            return damaged
        if self.directions not in (direction, "both") or not (
                self.drop or self.corrupt or self.duplicate or self.insert):
            return data
        out = bytearray()
        rng = self._rng
        for b in data:
            if self.drop and rng.random() < self.drop:
                self._count("dropped", direction)
                continue
            if self.corrupt and rng.random() < self.corrupt:
                b ^= 1 << rng.randrange(8)
                self._count("corrupted", direction)
            if self.insert and rng.random() < self.insert:
                out.append(rng.randrange(256))
                self._count("inserted", direction)
            out.append(b)
            if self.duplicate and rng.random() < self.duplicate:
                out.append(b)
                self._count("duplicated", direction)
        return bytes(out)

    def pipeline(self, on: bool) -> None:
        self.inner.pipeline(on)

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


class CorruptingProxy(TcpRelay):
    """A TCP proxy that damages a seeded fraction of the bytes in both directions.

    Listens on ``listen`` (host, port; port 0 picks one: :attr:`url`), connects each client to
    ``target`` (host, port) and relays bytes through a :class:`ByteCorrupter` per direction
    (seeds ``seed`` towards the target, ``seed + 1`` back). One client at a time; runs in a
    daemon thread (``start()`` / ``stop()``, or a ``with`` block).
    """

    def __init__(self, target: tuple[str, int], rate: float, seed: int = 0,
                 listen: tuple[str, int] = ("127.0.0.1", 0),
                 kinds: tuple[str, ...] = DAMAGE_KINDS):
        super().__init__(target, listen)
        self.to_target = ByteCorrupter(rate, seed, kinds)
        self.to_client = ByteCorrupter(rate, seed + 1, kinds)

    def _serve(self, client: socket.socket, upstream: socket.socket) -> None:
        self._relay(client, upstream)

    def _relay(self, client: socket.socket, upstream: socket.socket) -> None:
        pipes = {client: (upstream, self.to_target), upstream: (client, self.to_client)}
        try:
            while not self._stop.is_set():
                ready, _, _ = select.select(list(pipes), [], [], 0.05)
                for src in ready:
                    data = src.recv(65536)
                    if not data:
                        return
                    dst, corrupt = pipes[src]
                    out = corrupt(data)
                    if out:
                        dst.sendall(out)
        except OSError:
            return
        finally:
            client.close()
            upstream.close()


class StaleFloodBoard:
    """A board on ``transport`` (its end of a pipe or pty, served in a daemon thread) that
    answers HELLO like :class:`FakeBoard`, then never answers a request: every ``period_s`` it
    sends a valid reply whose sequence number is 7 below the last request's. ``start()`` /
    ``stop()`` or a ``with`` block."""

    def __init__(self, transport: Transport, period_s: float = 0.002):
        self.transport, self.period_s = transport, period_s
        self.board = FakeBoard()
        self.sent = 0
        self._endpoint = DeviceEndpoint(self.board, boot_nonce=self.board.boot_nonce)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> "StaleFloodBoard":
        self._thread = threading.Thread(target=self._run, name="stale flood", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)

    def __enter__(self) -> "StaleFloodBoard":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _run(self) -> None:
        decoder, stale = FrameDecoder(), b""
        while not self._stop.is_set():
            try:
                data = self.transport.read(65536, self.period_s)
                for frame in decoder.feed(data):
                    if frame.type == Hello.TYPE:
                        self.transport.write(self._endpoint.feed(encode_frame(frame)))
                    else:
                        stale = encode_frame(Frame.of(ReadCellReply(1234),
                                                      (frame.seq - 7) & 0xFFFF,
                                                      self.board.boot_nonce))
                if stale:
                    self.transport.write(stale)
                    self.sent += 1
            except ProtocolError:
                return


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

    def __call__(self, req: Request[Reply]) -> Reply:
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
