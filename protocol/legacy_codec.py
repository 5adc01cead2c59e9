"""The board's existing ASCII line protocol ("legacy"): the line codec (requests, replies, the
mode-100 board information) and the counters both sides keep.

The board side is :mod:`snan_hil.protocol.legacy_device`, the host client
:mod:`snan_hil.protocol.legacy_client` (the framed protocol splits the same way: frames and
messages, device, link).

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
pulse again (why :class:`~snan_hil.protocol.legacy_client.LegacyClient` never resends a write).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

from snan_hil.protocol.errors import FieldRangeError, MalformedPayloadError
from snan_hil.protocol.messages import Info

__all__ = [
    "LEGACY_BAUD", "LEGACY_TIMEOUT_S", "ID_MODULUS", "CONNECT_PROBE", "MAX_LINE",
    "LegacyPulse", "LegacyRead", "LegacyInfoRequest", "LegacyReply", "LegacyRequest",
    "format_request", "parse_request", "format_reply", "parse_reply", "format_info",
    "parse_info", "INFO_LINE_FIELDS", "HOST_INFO_SOURCES", "reported_info_fields",
    "info_sources", "next_id", "LegacyCounters",
]

LEGACY_BAUD = 115200
LEGACY_TIMEOUT_S = 0.075      # the old host's read timeout
ID_MODULUS = 4097             # ids 1..4096 then wrap to 0
CONNECT_PROBE = b"7,0,0,0,0,0,0,0\n"
MAX_LINE = 256                # longer lines without newline are discarded

_U8, _U16 = 0xFF, 0xFFFF
#: C field widths of the request fields (the public driver's declarations), by mode.
_PULSE_FIELDS = (("vol", _U16), ("t_ms", _U16), ("t_us", _U16), ("sign", _U8), ("id", _U16),
                 ("wl", _U8), ("bl", _U8))
_READ_FIELDS = (("vol", _U16), ("id", _U16), ("wl", _U8), ("bl", _U8))


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
