"""The board's existing ASCII line protocol ("legacy"): codec, board side and a better host.

Lines are decimal integers separated by commas, ending in ``\\n`` (a ``\\r`` before it is
ignored). Requests::

    7,vol,t_ms,t_us,sign,id,wl,bl   write pulse then read (vol = write-DAC code; 0 = read only)
    9,vol,id,wl,bl                  read one cell at row-DAC code vol (board clamps to 0.3 V)
    100                             board information
    7,0,0,0,0,0,0,0                 connect probe (a read-only mode 7 with id 0)

Reply to 7 and 9: ``adc,id``. Reply to 100: comma-separated text fields; this project's board
side answers ``board_id,firmware_version,rows,cols,dac_bits,adc_bits`` (the field list of the
real firmware is not public). ``sign``: 0 = positive pulse (RESET), 1 = negative (SET);
``wl`` is the column (word line), ``bl`` the row (bit line).

Extension of this project's board side: a refused request (safety limit, out of range) is
answered ``-CODE,id`` with the :class:`ErrorCode`; the old firmware sends nothing then.

The old protocol has no checksum and no duplicate detection: a resent mode-7 line applies the
pulse again. :class:`LegacyClient` therefore never resends a write: when a write's reply is lost
it reads the cell (mode 9, safe to repeat) and returns that reading as the "read after", counting
the write as uncertain (the pulse was applied once or not at all, never twice).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from snan_hil.protocol.client import ClientBase, SpikeBatchResult
from snan_hil.protocol.errors import (BoardError, ErrorCode, FieldRangeError, LinkTimeoutError,
                                      MalformedPayloadError, ProtocolError, UnsupportedError,
                                      board_error)
from snan_hil.protocol.messages import (ClockReply, Hello, Info, Polarity, ProgramCellReply,
                                        ReadCell, ReadCellReply, Request, Reply, ResetReply,
                                        SpikeGroup, StatusReply, WritePulse, WritePulseReply)
from snan_hil.protocol.transport import Transport

__all__ = [
    "LEGACY_BAUD", "LEGACY_TIMEOUT_S", "ID_MODULUS", "CONNECT_PROBE", "MAX_LINE",
    "LegacyPulse", "LegacyRead", "LegacyInfoRequest", "LegacyReply", "LegacyRequest",
    "format_request", "parse_request", "format_reply", "parse_reply", "format_info",
    "parse_info", "next_id", "LegacyCounters", "LegacyDevice", "LegacyClient",
]

log = logging.getLogger(__name__)

LEGACY_BAUD = 115200
LEGACY_TIMEOUT_S = 0.075      # the old host's read timeout
ID_MODULUS = 4097             # ids 1..4096 then wrap to 0
CONNECT_PROBE = b"7,0,0,0,0,0,0,0\n"
PROBE_TRIES = 20
MAX_LINE = 256                # longer lines without newline are discarded


# --------------------------------------------------------------------------- codec
@dataclass(frozen=True, slots=True)
class LegacyPulse:
    """Mode 7: write pulse (``vol`` write-DAC code; 0 = read only) then read."""

    vol: int
    t_ms: int
    t_us: int
    sign: int
    id: int
    wl: int
    bl: int


@dataclass(frozen=True, slots=True)
class LegacyRead:
    """Mode 9: read one cell at row-DAC code ``vol``."""

    vol: int
    id: int
    wl: int
    bl: int


@dataclass(frozen=True, slots=True)
class LegacyInfoRequest:
    """Mode 100: board information."""


@dataclass(frozen=True, slots=True)
class LegacyReply:
    """Reply to modes 7 and 9 (``adc`` < 0: this project's refusal extension, -ErrorCode)."""

    adc: int
    id: int


LegacyRequest = LegacyPulse | LegacyRead | LegacyInfoRequest


def _ints(line: bytes | str) -> list[int]:
    text = line.decode("ascii") if isinstance(line, (bytes, bytearray)) else line
    text = text.strip()
    if not text:
        raise MalformedPayloadError("empty line")
    try:
        return [int(part) for part in text.split(",")]
    except ValueError:
        raise MalformedPayloadError(f"not a line of integers: {text[:40]!r}") from None


def format_request(req: LegacyRequest) -> bytes:
    """The request line (with ``\\n``)."""
    fields: tuple[int, ...]
    if isinstance(req, LegacyPulse):
        fields = (7, req.vol, req.t_ms, req.t_us, req.sign, req.id, req.wl, req.bl)
    elif isinstance(req, LegacyRead):
        fields = (9, req.vol, req.id, req.wl, req.bl)
    elif isinstance(req, LegacyInfoRequest):
        fields = (100,)
    else:
        raise TypeError(f"not a legacy request: {req!r}")
    if any(f < 0 for f in fields):
        raise FieldRangeError(f"legacy fields must be >= 0: {fields}")
    return (",".join(str(int(f)) for f in fields) + "\n").encode("ascii")


def parse_request(line: bytes | str) -> LegacyRequest:
    """Parse a request line (MalformedPayloadError if it is not one)."""
    try:
        f = _ints(line)
    except UnicodeDecodeError:
        raise MalformedPayloadError("line is not ASCII") from None
    if f[0] == 7 and len(f) == 8:
        return LegacyPulse(*f[1:])
    if f[0] == 9 and len(f) == 5:
        return LegacyRead(*f[1:])
    if f == [100]:
        return LegacyInfoRequest()
    raise MalformedPayloadError(f"unknown legacy request: mode {f[0]} with {len(f)} fields")


def format_reply(adc: int, id_: int) -> bytes:
    """``adc,id\\n``."""
    return f"{int(adc)},{int(id_)}\n".encode("ascii")


def parse_reply(line: bytes | str) -> LegacyReply:
    """Parse ``adc,id`` (MalformedPayloadError otherwise)."""
    try:
        f = _ints(line)
    except UnicodeDecodeError:
        raise MalformedPayloadError("line is not ASCII") from None
    if len(f) != 2:
        raise MalformedPayloadError(f"reply has {len(f)} fields, expected adc,id")
    return LegacyReply(f[0], f[1])


def format_info(info: Info) -> bytes:
    """Mode-100 reply of this project's board side."""
    fields = [info.board_id, info.firmware_version, info.rows, info.cols, info.dac_bits,
              info.adc_bits]
    text = ",".join(str(f).replace(",", " ").replace("\n", " ") for f in fields)
    return (text + "\n").encode("utf-8")


def parse_info(line: bytes | str, defaults: Info | None = None) -> Info:
    """Build an Info from a mode-100 line; unknown/missing fields keep the defaults.

    Understands this project's field order; from any other firmware the raw text becomes
    ``board_id`` (first field) and ``firmware_version`` (the rest).
    """
    text = line.decode("utf-8", "replace") if isinstance(line, (bytes, bytearray)) else line
    parts = [p.strip() for p in text.strip().split(",")]
    base = defaults or Info()
    base = dataclasses.replace(base, protocol_version=0, capabilities=0, boot_nonce=0)
    if len(parts) == 6:
        try:
            rows, cols, dac_bits, adc_bits = (int(p) for p in parts[2:])
            return dataclasses.replace(base, board_id=parts[0][:64], firmware_version=parts[1][:64],
                                       rows=rows, cols=cols, dac_bits=dac_bits,
                                       adc_bits=adc_bits)
        except ValueError:
            pass
    return dataclasses.replace(base, board_id=parts[0][:64],
                               firmware_version=",".join(parts[1:])[:64])


def next_id(current: int) -> int:
    """The old host's id sequence: 1, 2, ..., 4096, 0, 1, ..."""
    return (current + 1) % ID_MODULUS


def _read_code(info: Info) -> int:
    """The read code of mode 9 requests (host) and of this board's reads (device)."""
    return info.read_code


# --------------------------------------------------------------------------- board side
@dataclass
class LegacyCounters:
    """Counters of either side of the line protocol."""

    lines_in: int = 0
    lines_out: int = 0
    malformed: int = 0          # unparseable lines (board) / non-reply lines (host)
    refusals: int = 0
    requests: int = 0
    retries: int = 0            # host: reads resent
    timeouts: int = 0
    stale_lines: int = 0        # host: replies whose id is not the awaited one
    uncertain_writes: int = 0   # host: write reply lost; cell re-read instead of resending
    overlong: int = 0


class LegacyDevice:
    """Sans-IO board side of the line protocol around the same handler as the framed one.

    Mode 7 with vol > 0 -> WritePulse (width t_ms*1000 + t_us us, read at the nominal read
    code); vol = 0 -> ReadCell at the nominal read code; mode 9 -> ReadCell with vol clamped to
    the max read voltage (as the old firmware); 100 -> Hello, answered as :func:`format_info`.
    Unparseable lines (including mode 10) are counted and not answered.
    """

    def __init__(self, handler: Callable[[Request], Reply], name: str = "legacy device"):
        self.handler, self.name = handler, name
        self.counters = LegacyCounters()
        self._buf = bytearray()
        self._info: Info | None = None

    def info(self) -> Info:
        if self._info is None:
            reply = self.handler(Hello())
            self._info = reply if isinstance(reply, Info) else Info()
        return self._info

    def feed(self, data: bytes) -> bytes:
        """Process received bytes; return reply bytes."""
        self._buf += data
        out = []
        while True:
            idx = self._buf.find(b"\n")
            if idx < 0:
                if len(self._buf) > MAX_LINE:
                    self.counters.overlong += 1
                    self._buf.clear()
                break
            line = bytes(self._buf[:idx]).rstrip(b"\r")
            del self._buf[:idx + 1]
            if not line.strip():
                continue
            self.counters.lines_in += 1
            reply = self.handle_line(line)
            if reply:
                self.counters.lines_out += 1
                out.append(reply)
        return b"".join(out)

    def handle_line(self, line: bytes) -> bytes | None:
        """Answer one line (without newline); None = no answer."""
        try:
            req = parse_request(line)
        except MalformedPayloadError:
            self.counters.malformed += 1
            return None
        if isinstance(req, LegacyInfoRequest):
            self._info = None
            return format_info(self.info())
        info = self.info()
        if isinstance(req, LegacyPulse):
            if req.vol == 0:
                msg: Request = ReadCell(req.bl, req.wl, _read_code(info))
            else:
                if req.sign not in (0, 1):
                    return self._refuse(ErrorCode.OUT_OF_RANGE, req.id)
                msg = WritePulse(req.bl, req.wl, Polarity(req.sign), req.vol,
                                 req.t_ms * 1000 + req.t_us, 0)
        else:
            msg = ReadCell(req.bl, req.wl, min(req.vol, _read_code(info)))
        self.counters.requests += 1
        try:
            reply = self.handler(msg)
        except BoardError as exc:
            return self._refuse(exc.code, req.id)
        except (ProtocolError, ValueError, OverflowError):
            return self._refuse(ErrorCode.OUT_OF_RANGE, req.id)
        if not isinstance(reply, (ReadCellReply, WritePulseReply)):
            return self._refuse(ErrorCode.INTERNAL, req.id)
        return format_reply(reply.adc, req.id)

    def _refuse(self, code: ErrorCode, id_: int) -> bytes:
        self.counters.refusals += 1
        return format_reply(-int(code), id_)


# --------------------------------------------------------------------------- host side
class LegacyClient(ClientBase):
    """Host client for boards running the old line protocol, with the BoardClient methods.

    Better than the old host: it flushes stale input before each request, accepts only replies
    whose id is one it issued for this request, resends reads a bounded number of times (new id
    each time), and never resends a write (see the module docstring). ``timeout`` (s) per attempt.
    READ_COLUMN, SPIKE_BATCH, PROGRAM_CELL, STATUS, CLOCK and RESET raise UnsupportedError.
    """

    def __init__(self, transport: Transport, *, timeout: float = 0.25, retries: int = 3,
                 first_id: int = 1, defaults: Info | None = None):
        self.transport = transport
        self.timeout, self.retries = float(timeout), int(retries)
        self._id = (first_id - 1) % ID_MODULUS
        self.info: Info | None = None
        self.defaults = defaults or Info()
        self.counters = LegacyCounters()
        self._buf = bytearray()

    def _new_id(self) -> int:
        self._id = next_id(self._id)
        return self._id

    # ------------------------------------------------------------------ line I/O
    def _flush(self) -> None:
        self.transport.reset_input_buffer()
        if self._buf:
            self.counters.stale_lines += 1
        self._buf.clear()

    def _send(self, line: bytes) -> None:
        self.transport.write(line)
        self.counters.lines_out += 1

    def _lines(self, deadline: float):
        """Yield received lines until the deadline."""
        while True:
            idx = self._buf.find(b"\n")
            if idx >= 0:
                line = bytes(self._buf[:idx]).rstrip(b"\r")
                del self._buf[:idx + 1]
                self.counters.lines_in += 1
                yield line
                continue
            if len(self._buf) > MAX_LINE:
                self.counters.overlong += 1
                self._buf.clear()
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return
            data = self.transport.read(4096, remaining)
            if not data and self.transport.synchronous:
                return
            self._buf += data

    def _await_reply(self, ids: set[int], deadline: float) -> LegacyReply | None:
        for line in self._lines(deadline):
            try:
                reply = parse_reply(line)
            except MalformedPayloadError:
                self.counters.malformed += 1
                continue
            if reply.id not in ids:
                self.counters.stale_lines += 1
                log.debug("%s: discarded reply with id %d (awaiting %s)", self.name, reply.id,
                          sorted(ids))
                continue
            if reply.adc < 0:
                self.counters.refusals += 1
                raise board_error(-reply.adc, f"board on {self.name} refused the request "
                                  f"(legacy reply {reply.adc},{reply.id})")
            return reply
        return None

    def _timeout_error(self, what: str, tries: int) -> LinkTimeoutError:
        return LinkTimeoutError(
            f"no reply from board on {self.name} to {what} after {tries} tries "
            f"({self.timeout:.2f} s each, legacy protocol"
            f"{f' at {self.transport.baud} baud' if self.transport.baud else ''}); check cable, "
            "power and --baud, or use --protocol framed for new firmware")

    # ------------------------------------------------------------------ typed methods
    def connect(self) -> None:
        """The old connect probe: send ``7,0,0,0,0,0,0,0`` up to 20 times until a reply."""
        self._flush()
        for _ in range(PROBE_TRIES):
            self._send(CONNECT_PROBE)
            if self._await_reply({0}, time.monotonic() + self.timeout) is not None:
                return
            self.counters.timeouts += 1
        raise self._timeout_error("the connect probe", PROBE_TRIES)

    def hello(self) -> Info:
        """Connect probe, then mode 100; returns an Info (protocol_version 0, no nonce)."""
        self.connect()
        self._flush()
        self._send(format_request(LegacyInfoRequest()))
        deadline = time.monotonic() + self.timeout
        for line in self._lines(deadline):
            try:
                parse_reply(line)
                self.counters.stale_lines += 1
                continue
            except MalformedPayloadError:
                pass
            self.info = parse_info(line, self.defaults)
            return self.info
        # Old firmware that does not answer mode 100: keep the defaults.
        self.info = dataclasses.replace(self.defaults, protocol_version=0, capabilities=0,
                                        board_id="legacy", firmware_version="unknown",
                                        boot_nonce=0)
        return self.info

    def _info(self) -> Info:
        return self.info or self.defaults

    def read_cell(self, row: int, col: int, dac_code: int | None = None) -> int:
        """Mode 9; resent (new id) up to ``retries`` times; any of this call's ids is accepted."""
        vol = _read_code(self._info()) if dac_code is None else int(dac_code)
        self.limits.check_reads((vol,), f"read of cell ({row}, {col})")
        self.counters.requests += 1
        self._flush()
        ids: set[int] = set()
        tries = 1 + self.retries
        for attempt in range(tries):
            if attempt:
                self.counters.retries += 1
            ids.add(self._new_id())
            self._send(format_request(LegacyRead(vol, self._id, col, row)))
            reply = self._await_reply(ids, time.monotonic() + self.timeout)
            if reply is not None:
                return reply.adc
            self.counters.timeouts += 1
        raise self._timeout_error(f"read of cell ({row}, {col})", tries)

    def write_pulse(self, row: int, col: int, polarity: Polarity, amplitude_code: int,
                    width_us: int, read_code: int = 0) -> int:
        """Mode 7 once; if the reply is lost, read the cell instead of resending the pulse."""
        if read_code not in (0, _read_code(self._info())):
            raise UnsupportedError("the legacy protocol reads after a pulse at the board's "
                                   "fixed read voltage; read_code must be 0")
        if amplitude_code <= 0:
            raise FieldRangeError("amplitude_code must be > 0 (0 means read-only in mode 7)")
        self.limits.check_write(amplitude_code, f"pulse on cell ({row}, {col})")
        self.counters.requests += 1
        self._flush()
        id_ = self._new_id()
        t_ms, t_us = divmod(int(width_us), 1000)
        self._send(format_request(LegacyPulse(int(amplitude_code), t_ms, t_us,
                                              int(Polarity(polarity)), id_, col, row)))
        reply = self._await_reply({id_}, time.monotonic() + self.timeout)
        if reply is not None:
            return reply.adc
        self.counters.timeouts += 1
        self.counters.uncertain_writes += 1
        log.warning("%s: reply to write pulse on (%d, %d) lost; not resending it, reading the "
                    "cell instead", self.name, row, col)
        return self.read_cell(row, col)

    def _unsupported(self, what: str) -> UnsupportedError:
        return UnsupportedError(f"{what} is not available over the legacy line protocol "
                                f"(board on {self.name}); use --protocol framed")

    def read_column(self, col: int, row_codes: Sequence[int]) -> int:
        raise self._unsupported("READ_COLUMN")

    def spike_batch(self, groups: Sequence[SpikeGroup], columns: Sequence[int],
                    n_bins: int = 1000, bin_us: int = 1000,
                    paced: bool = False) -> SpikeBatchResult:
        raise self._unsupported("SPIKE_BATCH")

    def program_cell(self, row: int, col: int, target_adc: int, tolerance_adc: int,
                     **kwargs: object) -> ProgramCellReply:
        raise self._unsupported("PROGRAM_CELL")

    def status(self) -> StatusReply:
        raise self._unsupported("STATUS")

    def clock(self) -> ClockReply:
        raise self._unsupported("CLOCK")

    def reset(self) -> ResetReply:
        raise self._unsupported("RESET")
