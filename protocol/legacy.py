"""The board's existing ASCII line protocol ("legacy"): codec, board side and a better host.

Lines are decimal integers separated by commas, ending in ``\\n`` (a ``\\r`` before it is
ignored). Requests::

    7,vol,t_ms,t_us,sign,id,wl,bl   write pulse then read (vol = write-DAC code; 0 = read only)
    9,vol,id,wl,bl                  read one cell at write-DAC code vol (clamped to 0.3 V)
    100                             board information
    7,0,0,0,0,0,0,0                 connect probe (a read-only mode 7 with id 0)

Reply to 7 and 9: ``adc,id``. Reply to 100: comma-separated text fields; this project's board
side answers ``board_id,firmware_version,rows,cols,dac_bits,adc_bits`` (the field list of the
real firmware is not public). ``sign``: 0 = positive pulse (RESET), otherwise negative (SET);
``wl`` is the column (word line), ``bl`` the row (bit line).

**Reading of the existing firmware** (its source is not public; facts from
shared/reference/memricore-board.md and the board's public Raspberry-Pi driver, which declares
the same fields as C integers and does the same clamps). Written into docs/protocol.md section 9:

* a field is one or more ASCII digits ``0-9`` and fits its C type — ``vol``, ``t_ms``, ``t_us``,
  ``id``: 16 bit; ``sign``, ``wl``, ``bl``: 8 bit. A sign, a space, ``_``, an empty field or a
  value too wide makes the line no request: no reply (:func:`parse_request`);
* mode 9 ``vol`` is clamped to the board's read code (``legacy_read_code``: 246 = 0.3004 V);
* mode 7 reads after the pulse at that same fixed code; a RESET amplitude is clamped to
  3.0 V (``reset_clamp_code`` 2457); SET is applied as asked (up to the DAC's full scale);
  ``sign`` other than 0 is SET, as the driver tests ``if (sign)``;
* anything the board cannot do (a cell outside the array, a SET code above the DAC's 12 bits)
  gets no reply: the old firmware has no refusal message.

**Extension** (opt-in on both sides, ``refusals=True``; ``--legacy-refusals``): a refused
request is answered ``-CODE,id`` with the :class:`ErrorCode`. Without the opt-in the board
never sends it and the host never takes a negative number for anything but garbage.

The old protocol has no checksum and no duplicate detection: a resent mode-7 line applies the
pulse again. :class:`LegacyClient` therefore never resends a write: when a write's reply is
lost (or arrives with another id) it reads the cell (mode 9, safe to repeat) and returns that
reading as the "read after", counting the write as uncertain (the pulse was applied once or not
at all, never twice).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

from snan_hil.protocol.client import ClientBase, SpikeBatchResult
from snan_hil.protocol.errors import (BoardError, ErrorCode, FieldRangeError, LinkTimeoutError,
                                      MalformedPayloadError, ProtocolError, UnsupportedError,
                                      board_error)
from snan_hil.protocol.messages import (ClockReply, DecisionWindowReply, Hello, Info,
                                        Polarity, ProgramCellReply,
                                        ReadCell, ReadCellReply, Request, Reply, ResetReply,
                                        SpikeGroup, StatusReply, WritePulse, WritePulseReply)
from snan_hil.protocol.transport import Transport

__all__ = [
    "LEGACY_BAUD", "LEGACY_TIMEOUT_S", "ID_MODULUS", "CONNECT_PROBE", "MAX_LINE", "PROBE_TRIES",
    "LegacyPulse", "LegacyRead", "LegacyInfoRequest", "LegacyReply", "LegacyRequest",
    "format_request", "parse_request", "format_reply", "parse_reply", "format_info",
    "parse_info", "next_id", "LegacyCounters", "LegacyDevice", "LegacyClient",
    "LegacyTimeoutError", "LegacyInfoError",
]

log = logging.getLogger(__name__)

LEGACY_BAUD = 115200
LEGACY_TIMEOUT_S = 0.075      # the old host's read timeout
ID_MODULUS = 4097             # ids 1..4096 then wrap to 0
CONNECT_PROBE = b"7,0,0,0,0,0,0,0\n"
PROBE_TRIES = 20
MAX_LINE = 256                # longer lines without newline are discarded

_U8, _U16 = 0xFF, 0xFFFF
#: C field widths of the request fields (the public driver's declarations), by mode.
_PULSE_FIELDS = (("vol", _U16), ("t_ms", _U16), ("t_us", _U16), ("sign", _U8), ("id", _U16),
                 ("wl", _U8), ("bl", _U8))
_READ_FIELDS = (("vol", _U16), ("id", _U16), ("wl", _U8), ("bl", _U8))


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
    """Mode 9: read one cell at write-DAC code ``vol`` (the board clamps it to its read code)."""

    vol: int
    id: int
    wl: int
    bl: int


@dataclass(frozen=True, slots=True)
class LegacyInfoRequest:
    """Mode 100: board information."""


@dataclass(frozen=True, slots=True)
class LegacyReply:
    """Reply to modes 7 and 9 (``adc`` < 0 only with the opt-in refusal extension:
    -ErrorCode)."""

    adc: int
    id: int


LegacyRequest = LegacyPulse | LegacyRead | LegacyInfoRequest


def _digits(part: bytes, what: str) -> int:
    """An unsigned decimal field: ASCII digits only (``bytes.isdigit`` is ASCII-only)."""
    if not part.isdigit():
        raise MalformedPayloadError(f"{what} {part[:12]!r} is not an unsigned decimal number")
    return int(part)


def _as_bytes(line: bytes | str) -> bytes:
    if isinstance(line, str):
        try:
            return line.encode("ascii")
        except UnicodeEncodeError:
            raise MalformedPayloadError("line is not ASCII") from None
    return bytes(line)


def _fields(line: bytes | str) -> list[bytes]:
    raw = _as_bytes(line)
    if raw.endswith(b"\n"):
        raw = raw[:-1]
    if raw.endswith(b"\r"):
        raw = raw[:-1]
    if not raw:
        raise MalformedPayloadError("empty line")
    return raw.split(b",")


def _check_width(values: Sequence[int], spec: Sequence[tuple[str, int]]) -> None:
    for value, (name, top) in zip(values, spec):
        if not 0 <= value <= top:
            raise FieldRangeError(f"legacy field {name} = {value} outside 0..{top} (its "
                                  f"{top.bit_length()}-bit field)")


def format_request(req: LegacyRequest) -> bytes:
    """The request line (with ``\\n``); FieldRangeError if a field does not fit its C type."""
    fields: tuple[int, ...]
    values: tuple[int, ...]
    if isinstance(req, LegacyPulse):
        values = (req.vol, req.t_ms, req.t_us, req.sign, req.id, req.wl, req.bl)
        _check_width(values, _PULSE_FIELDS)
        fields = (7, *values)
    elif isinstance(req, LegacyRead):
        values = (req.vol, req.id, req.wl, req.bl)
        _check_width(values, _READ_FIELDS)
        fields = (9, *values)
    elif isinstance(req, LegacyInfoRequest):
        fields = (100,)
    else:
        raise TypeError(f"not a legacy request: {req!r}")
    return (",".join(str(int(f)) for f in fields) + "\n").encode("ascii")


def parse_request(line: bytes | str) -> LegacyRequest:
    """Parse a request line as the existing firmware reads it (module docstring):
    MalformedPayloadError for anything that is not a request (the board does not answer it)."""
    parts = _fields(line)
    mode = _digits(parts[0], "mode")
    if mode == 100 and len(parts) == 1:
        return LegacyInfoRequest()
    spec = {7: _PULSE_FIELDS, 9: _READ_FIELDS}.get(mode)
    if spec is None or len(parts) != len(spec) + 1:
        raise MalformedPayloadError(f"unknown legacy request: mode {mode} with {len(parts)} "
                                    "fields")
    values = [_digits(p, name) for p, (name, _top) in zip(parts[1:], spec)]
    try:
        _check_width(values, spec)
    except FieldRangeError as exc:
        raise MalformedPayloadError(str(exc)) from None
    return LegacyPulse(*values) if mode == 7 else LegacyRead(*values)


def format_reply(adc: int, id_: int) -> bytes:
    """``adc,id\\n``."""
    return f"{int(adc)},{int(id_)}\n".encode("ascii")


def parse_reply(line: bytes | str, *, refusals: bool = False) -> LegacyReply:
    """Parse ``adc,id`` (two unsigned decimal fields; MalformedPayloadError otherwise). With
    ``refusals`` (the opt-in extension) ``adc`` may be ``-CODE``."""
    parts = _fields(line)
    if len(parts) != 2:
        raise MalformedPayloadError(f"reply has {len(parts)} fields, expected adc,id")
    adc_text, id_text = parts
    negative = refusals and adc_text.startswith(b"-")
    adc = _digits(adc_text[1:] if negative else adc_text, "adc")
    return LegacyReply(-adc if negative else adc, _digits(id_text, "id"))


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


#: The fields a mode-100 line of this project's board side carries (:func:`format_info`).
INFO_LINE_FIELDS: tuple[str, ...] = ("board_id", "firmware_version", "rows", "cols", "dac_bits",
                                     "adc_bits")

_HW_FACT = ("assumed: the MemriCore board's documented value (protocol/board.py MEMRICORE, from "
            "shared/reference/memricore-board.md); not reported over the line protocol")
#: Where each Info field of a legacy board comes from when its mode-100 line does not carry it
#: (:func:`info_sources`): host defaults, host policy or nothing at all — never the board.
HOST_INFO_SOURCES: dict[str, str] = {
    "protocol_version": "none: the line protocol has no version (0 = legacy)",
    "rows": _HW_FACT, "cols": _HW_FACT, "dac_bits": _HW_FACT, "dac_vref_v": _HW_FACT,
    "write_dac_bits": _HW_FACT, "write_dac_vref_v": _HW_FACT, "adc_bits": _HW_FACT,
    "adc_vref_v": _HW_FACT, "adc_averages": _HW_FACT, "r_load_ohm": _HW_FACT,
    "r_switch_ohm": _HW_FACT, "gain": _HW_FACT, "sum_gain_ohm": _HW_FACT,
    "v_read_v": "host policy: the write-DAC voltage of read_code",
    "read_code": "host policy: the largest write-DAC code at or below max_read_v "
                 "(protocol/board.py)",
    "max_read_v": "host policy: reads at or below 0.3 V (protocol/safety.py); the existing "
                  "firmware reads at any code it is sent",
    "max_write_v": "host policy: the default of --max-write-v (protocol/safety.py); the existing "
                   "firmware applies any amplitude up to its 3.0 V RESET clamp",
    "compliance_a": "assumed: MEMRICORE default, used by the host's write-and-verify; the "
                    "existing firmware has no compliance check (the 1T1R transistor limits "
                    "the current)",
    "max_payload": "none: a framed-protocol field (lines have no payload limit)",
    "capabilities": "none: no SPIKE_BATCH, READ_COLUMN, PROGRAM_CELL, CLOCK or RESET over the "
                    "line protocol",
    "boot_nonce": "none: the line protocol has no boot nonce",
}


def reported_info_fields(line: bytes | str) -> tuple[str, ...]:
    """The Info fields a mode-100 ``line`` itself carries (what :func:`parse_info` takes from
    it): all of :data:`INFO_LINE_FIELDS` from this project's board side, else only
    ``board_id`` and ``firmware_version`` (the raw text of any other firmware)."""
    text = line.decode("utf-8", "replace") if isinstance(line, (bytes, bytearray)) else line
    parts = [p.strip() for p in text.strip().split(",")]
    if len(parts) == len(INFO_LINE_FIELDS):
        try:
            [int(p) for p in parts[2:]]
            return INFO_LINE_FIELDS
        except ValueError:
            pass
    return INFO_LINE_FIELDS[:2]


def info_sources(reported: tuple[str, ...]) -> dict[str, str]:
    """Per Info field of a legacy board, where its value comes from: ``board (mode-100
    line)`` for the ``reported`` fields, else :data:`HOST_INFO_SOURCES`."""
    return {name: ("board (mode-100 line)" if name in reported
                   else HOST_INFO_SOURCES.get(name, "host default"))
            for name in Info.WIRE_FIELDS}


def next_id(current: int) -> int:
    """The old host's id sequence: 1, 2, ..., 4096, 0, 1, ..."""
    return (current + 1) % ID_MODULUS


# --------------------------------------------------------------------------- board side
@dataclass
class LegacyCounters:
    """Counters of either side of the line protocol."""

    lines_in: int = 0
    lines_out: int = 0
    bytes_in: int = 0           # host: bytes received (board: not counted)
    bytes_out: int = 0          # host: bytes sent
    malformed: int = 0          # unparseable lines (board) / non-reply lines (host)
    refusals: int = 0           # board: requests it could not execute; host: -CODE replies
    requests: int = 0
    retries: int = 0            # host: reads resent
    timeouts: int = 0
    stale_lines: int = 0        # host: replies whose id is not the awaited one
    uncertain_writes: int = 0   # host: write reply lost; cell re-read instead of resending
    overlong: int = 0


class LegacyDevice:
    """Sans-IO board side of the line protocol, as the existing firmware handles lines, around
    a request handler (the emulator's dispatcher, or a test board).

    Mode 7 with vol > 0 -> WritePulse (width ``t_ms*1000 + t_us`` us; RESET amplitude clamped to
    the board's ``reset_clamp_code``; read after at its ``legacy_read_code``); vol = 0 ->
    ReadCell at ``legacy_read_code``; mode 9 -> ReadCell with vol clamped to
    ``legacy_read_code``; 100 -> Hello, answered as :func:`format_info`. Lines that are not
    requests (:func:`parse_request`; mode 10 included) are counted and not answered; so are
    requests the handler refuses, unless ``refusals`` (the opt-in ``-CODE,id`` extension).
    """

    def __init__(self, handler: Callable[[Request], Reply], name: str = "legacy device", *,
                 refusals: bool = False):
        self.handler, self.name = handler, name
        self.refusals = bool(refusals)
        self.counters = LegacyCounters()
        self._buf = bytearray()
        self._skip = False          # inside an over-long line: drop up to its newline
        self._info: Info | None = None

    def info(self) -> Info:
        if self._info is None:
            reply = self.handler(Hello())
            self._info = reply if isinstance(reply, Info) else Info()
        return self._info

    def feed(self, data: bytes) -> bytes:
        """Process received bytes; return reply bytes."""
        return b"".join(self.feed_lines(data))

    def feed_lines(self, data: bytes) -> list[bytes]:
        """Process received bytes; return the reply of each complete request line (in order;
        lines that get no reply are left out)."""
        self._buf += data
        out = []
        while True:
            idx = self._buf.find(b"\n")
            if idx < 0:
                if len(self._buf) > MAX_LINE:
                    if not self._skip:
                        self.counters.overlong += 1
                    self._skip = True
                    self._buf.clear()
                break
            line = bytes(self._buf[:idx])
            del self._buf[:idx + 1]
            if self._skip or idx > MAX_LINE:        # the end (or all) of an over-long line
                if not self._skip:
                    self.counters.overlong += 1
                self._skip = False
                continue
            if not line.strip(b"\r"):
                continue
            self.counters.lines_in += 1
            reply = self.handle_line(line)
            if reply:
                self.counters.lines_out += 1
                out.append(reply)
        return out

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
        read_code = info.legacy_read_code
        msg: Request
        if isinstance(req, LegacyPulse):
            if req.vol == 0:
                msg = ReadCell(req.bl, req.wl, read_code)
            else:
                polarity = Polarity.SET if req.sign else Polarity.RESET
                amp = min(req.vol, info.reset_clamp_code) if polarity == Polarity.RESET \
                    else req.vol
                msg = WritePulse(req.bl, req.wl, polarity, amp, req.t_ms * 1000 + req.t_us,
                                 read_code)
        else:
            msg = ReadCell(req.bl, req.wl, min(req.vol, read_code))
        self.counters.requests += 1
        try:
            reply = self.handler(msg)
        except BoardError as exc:
            return self._refuse(exc.code, req.id, str(exc))
        except (ProtocolError, ValueError, OverflowError) as exc:
            return self._refuse(ErrorCode.OUT_OF_RANGE, req.id, str(exc))
        if not isinstance(reply, (ReadCellReply, WritePulseReply)):
            return self._refuse(ErrorCode.INTERNAL, req.id, f"unexpected reply {reply!r}")
        return format_reply(reply.adc, req.id)

    def _refuse(self, code: ErrorCode, id_: int, why: str) -> bytes | None:
        self.counters.refusals += 1
        log.info("%s: request id %d not executed (%s)%s", self.name, id_, why,
                 "" if self.refusals else "; no reply, as the existing firmware")
        return format_reply(-int(code), id_) if self.refusals else None


# --------------------------------------------------------------------------- host side
class LegacyTimeoutError(LinkTimeoutError):
    """No valid reply over the legacy line protocol; ``heard`` says what came instead (lines
    that are not replies, replies with other ids), '' if nothing. ``kind`` (LinkTimeoutError's):
    ``silent`` (nothing came), ``garbled`` (only lines that are not replies), ``corrupting``
    (replies, but with other ids)."""

    def __init__(self, message: str, heard: str = "", kind: str = "silent"):
        super().__init__(message + (f"; {heard}" if heard else ""), kind)
        self.heard = heard


class LegacyInfoError(ProtocolError):
    """The board answers the connect probe but not the board-information request (mode 100)."""


class _Heard:
    """What arrived instead of the awaited reply (for the error message)."""

    def __init__(self) -> None:
        self.garbage = 0
        self.other_ids = 0
        self.garbage_sample = ""
        self.id_sample = ""

    def kind(self) -> str:
        """The LinkTimeoutError kind of what was heard."""
        return "corrupting" if self.other_ids else ("garbled" if self.garbage else "silent")

    def text(self) -> str:
        parts = []
        if self.garbage:
            parts.append(f"it sent {self.garbage} line(s) that are not replies of the line "
                         f"protocol (e.g. {self.garbage_sample!r})")
        if self.other_ids:
            parts.append(f"it answered {self.other_ids} time(s) with another id "
                         f"(e.g. {self.id_sample})")
        return "; ".join(parts)


class LegacyClient(ClientBase):
    """Host client for boards running the old line protocol, with the BoardClient methods.

    Better than the old host: it flushes stale input before each request, accepts only replies
    whose id is one it issued for this request (any other line is counted and dropped, never
    used as data), resends reads a bounded number of times (new id each time), never resends
    a write (see the module docstring), and waits for a pulse as long as the pulse lasts plus
    ``timeout`` (s, per attempt). ``refusals``: understand the ``-CODE,id`` extension (opt-in,
    the board must be started with it too). READ_COLUMN, SPIKE_BATCH, PROGRAM_CELL, STATUS,
    CLOCK and RESET raise UnsupportedError.
    """

    def __init__(self, transport: Transport, *, timeout: float = 0.25, retries: int = 3,
                 first_id: int = 1, defaults: Info | None = None, refusals: bool = False):
        self.transport = transport
        self.timeout, self.retries = float(timeout), int(retries)
        self.refusals = bool(refusals)
        self._id = (first_id - 1) % ID_MODULUS
        self.info: Info | None = None
        #: the Info fields the board's mode-100 line carried (:func:`reported_info_fields`);
        #: the others are host defaults or policy (:func:`info_sources`)
        self.reported_fields: tuple[str, ...] = ()
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
        self.counters.bytes_out += len(line)

    def _lines(self, deadline: float) -> Iterator[bytes]:
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
            # an in-process board answered inside write(): what it sent is read whatever the
            # wall clock says (see LinkClient._await); an empty read means nothing came
            if remaining <= 0 and not self.transport.synchronous:
                return
            data = self.transport.read(4096, max(0.0, remaining))
            if not data and self.transport.synchronous:
                return
            self.counters.bytes_in += len(data)
            self._buf += data

    def _await_reply(self, ids: set[int], deadline: float,
                     heard: _Heard | None = None) -> LegacyReply | None:
        heard = heard if heard is not None else _Heard()
        for line in self._lines(deadline):
            try:
                reply = parse_reply(line, refusals=self.refusals)
            except MalformedPayloadError:
                self.counters.malformed += 1
                heard.garbage += 1
                heard.garbage_sample = heard.garbage_sample or line[:40].decode("ascii",
                                                                                "replace")
                continue
            if reply.id not in ids:
                self.counters.stale_lines += 1
                heard.other_ids += 1
                heard.id_sample = heard.id_sample or (
                    f"'{reply.adc},{reply.id}' while waiting for id {min(ids)}")
                log.debug("%s: discarded reply with id %d (awaiting %s)", self.name, reply.id,
                          sorted(ids))
                continue
            if reply.adc < 0:
                self.counters.refusals += 1
                raise board_error(-reply.adc, f"board on {self.name} refused the request "
                                  f"(legacy reply {reply.adc},{reply.id})")
            return reply
        return None

    def _timeout_error(self, what: str, tries: int, heard: _Heard,
                       wait_s: float | None = None) -> LegacyTimeoutError:
        wait = self.timeout if wait_s is None else wait_s
        return LegacyTimeoutError(
            f"no reply from board on {self.name} to {what} after {tries} tries "
            f"({wait:.2f} s each, legacy protocol"
            f"{f' at {self.transport.baud} baud' if self.transport.baud else ''}); check cable, "
            "power and --baud, then run the command again", heard.text(), heard.kind())

    # ------------------------------------------------------------------ typed methods
    def connect(self) -> None:
        """The old connect probe: send ``7,0,0,0,0,0,0,0`` up to 20 times until a reply."""
        self._flush()
        heard = _Heard()
        for _ in range(PROBE_TRIES):
            self._send(CONNECT_PROBE)
            if self._await_reply({0}, time.monotonic() + self.timeout, heard) is not None:
                return
            self.counters.timeouts += 1
        raise self._timeout_error("the connect probe", PROBE_TRIES, heard)

    def hello(self) -> Info:
        """Connect probe, then mode 100 (sent up to ``1 + retries`` times); returns an Info
        (protocol_version 0, no capabilities, no nonce; the constants not in the mode-100 line
        are the defaults'). :class:`LegacyInfoError` if mode 100 is never answered."""
        self.connect()
        for _ in range(1 + self.retries):
            self._flush()
            self._send(format_request(LegacyInfoRequest()))
            for line in self._lines(time.monotonic() + self.timeout):
                try:
                    parse_reply(line, refusals=self.refusals)
                    self.counters.stale_lines += 1          # a late adc,id reply
                    continue
                except MalformedPayloadError:
                    pass
                if not line.strip() or not all(0x20 <= b < 0x7F for b in line):
                    self.counters.malformed += 1                # not a line of text
                    continue
                self.info = parse_info(line, self.defaults)
                self.reported_fields = reported_info_fields(line)
                return self.info
            self.counters.timeouts += 1
        raise LegacyInfoError(
            f"the board on {self.name} answers the connect probe but not the board-information "
            f"request (mode 100) after {1 + self.retries} tries ({self.timeout:.2f} s each); it "
            "does not behave like the MemriCore firmware: check --port, or use --protocol framed "
            "for new firmware")

    def _info(self) -> Info:
        return self.info or self.defaults

    @property
    def post_pulse_read_code(self) -> int:
        """Write-DAC code of the board's own read after a mode-7 pulse (its fixed read
        voltage, ``legacy_read_code``: 246 on MemriCore); what ``write_pulse(...,
        read_code=0)`` returns a reading at."""
        return self._info().legacy_read_code

    def read_cell(self, row: int, col: int, dac_code: int | None = None) -> int:
        """Mode 9; resent (new id) up to ``retries`` times; any of this call's ids is accepted."""
        vol = self._info().read_code if dac_code is None else int(dac_code)
        self.limits.check_reads((vol,), f"read of cell ({row}, {col})")
        self.counters.requests += 1
        self._flush()
        ids: set[int] = set()
        heard = _Heard()
        tries = 1 + self.retries
        for attempt in range(tries):
            if attempt:
                self.counters.retries += 1
            ids.add(self._new_id())
            self._send(format_request(LegacyRead(vol, self._id, col, row)))
            reply = self._await_reply(ids, time.monotonic() + self.timeout, heard)
            if reply is not None:
                return reply.adc
            self.counters.timeouts += 1
        raise self._timeout_error(f"read of cell ({row}, {col})", tries, heard)

    def write_pulse(self, row: int, col: int, polarity: Polarity, amplitude_code: int,
                    width_us: int, read_code: int = 0) -> int:
        """Mode 7 once, then the ADC code of the cell read after it.

        ``read_code`` 0: the board's own read after the pulse (at ``post_pulse_read_code``);
        another code: one more read (mode 9) at that code, since the old firmware cannot
        read after a pulse at a chosen voltage. The reply is awaited for ``timeout`` plus the
        pulse width. If it is lost, or comes with another id, the pulse is NOT resent: the cell
        is read (mode 9) instead and the write counted as uncertain.
        """
        limits = self.limits
        if amplitude_code <= 0:
            raise FieldRangeError("amplitude_code must be > 0 (0 means read-only in mode 7)")
        limits.check_write(amplitude_code, f"pulse on cell ({row}, {col})")
        if read_code:
            limits.check_reads((read_code,), f"read after the pulse on cell ({row}, {col})")
        if int(width_us) < 0:
            raise FieldRangeError(f"pulse width {width_us} us must be >= 0")
        t_ms, t_us = divmod(int(width_us), 1000)
        # every field checked (FieldRangeError) before an id is used or anything is sent
        format_request(LegacyPulse(int(amplitude_code), t_ms, t_us, int(Polarity(polarity)), 0,
                                   col, row))
        self.counters.requests += 1
        self._flush()
        id_ = self._new_id()
        line = format_request(LegacyPulse(int(amplitude_code), t_ms, t_us,
                                          int(Polarity(polarity)), id_, col, row))
        self._send(line)
        wait = self.timeout + int(width_us) * 1e-6
        heard = _Heard()
        reply = self._await_reply({id_}, time.monotonic() + wait, heard)
        if reply is None:
            self.counters.timeouts += 1
            self.counters.uncertain_writes += 1
            log.warning("%s: no reply with id %d to the write pulse on (%d, %d)%s; not resending "
                        "it, reading the cell instead", self.name, id_, row, col,
                        f" ({heard.text()})" if heard.text() else "")
            return self.read_cell(row, col, read_code or None)
        if read_code and read_code != self.post_pulse_read_code:
            return self.read_cell(row, col, read_code)
        return reply.adc

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

    def decision_window(self, *args: object, **kwargs: object) -> DecisionWindowReply:
        raise self._unsupported("DECISION_WINDOW")

    def status(self) -> StatusReply:
        raise self._unsupported("STATUS")

    def clock(self) -> ClockReply:
        raise self._unsupported("CLOCK")

    def reset(self) -> ResetReply:
        raise self._unsupported("RESET")
