"""Typed messages of the framed protocol: one frozen dataclass per message.

Every message knows its one-byte type code (``TYPE``), encodes its payload to bytes
(:meth:`Message.encode`, fixed-width little-endian) and decodes it back exactly
(:meth:`Message.decode`). Requests have ``TYPE < 0x80`` and name their reply class in ``REPLY``;
the reply's code is ``request code | 0x80``; :class:`ErrorReply` (0xFF) may answer any request.
The byte layouts are specified in ``docs/protocol.md``.

Units: voltages V, resistances Ohm, current A, time us, energy J. Analog values on the wire are
DAC/ADC codes; the board's constants in :class:`Info` (a
:class:`~snan_hil.protocol.board.BoardConstants`) convert them.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, fields, replace
from enum import IntFlag
from typing import Any, ClassVar, Generic, TypeVar, cast, get_args, get_origin

from snan_hil.common.polarity import Polarity
from snan_hil.protocol.board import BoardConstants
from snan_hil.protocol.errors import (ErrorCode, FieldRangeError, MalformedPayloadError,
                                      UnknownTypeError)

__all__ = ["BASE_CAPABILITIES", "PIPELINE_BYTES", "PIPELINE_REPLY_MAX",
    "PROTOCOL_VERSION", "MAX_PAYLOAD", "MAX_TEXT", "Polarity", "Capability", "ErrorCode",
    "Message", "Request", "Reply", "ReplyT",
    "Hello", "Info", "ReadCell", "ReadCellReply", "ReadColumn", "ReadColumnReply",
    "WritePulse", "WritePulseReply", "SpikeGroup", "SpikeBatch", "SpikeBatchReply",
    "ProgramCell", "ProgramCellReply", "Status", "StatusReply", "Clock", "ClockReply",
    "Reset", "ResetReply", "ErrorReply",
    "MESSAGE_TYPES", "REQUEST_TYPES", "message_class", "decode_message", "spike_batch_reply_size",
]

PROTOCOL_VERSION = 1
"""Version byte of every frame of this specification."""

MAX_PAYLOAD = 4096
"""Largest payload in bytes either side may send (a board may announce less in Info)."""

MAX_TEXT = 64
"""Longest text field in bytes (UTF-8)."""


PIPELINE_BYTES = 128
"""A board with the PIPELINE capability receives up to this many bytes of further requests
(whole frames, COBS and delimiters counted) while it executes one, and answers a resent
request from its cache when its reply payload is at most :data:`PIPELINE_REPLY_MAX` bytes: a
host may then keep a second request outstanding whose frame fits (docs/protocol.md section 4,
"Two requests outstanding")."""
PIPELINE_REPLY_MAX = 160
"""Largest reply payload a PIPELINE board caches for every request (bytes)."""


class Capability(IntFlag):
    """Optional requests a board implements (Info.capabilities)."""

    NONE = 0
    READ_COLUMN = 1
    SPIKE_BATCH = 2
    PROGRAM_CELL = 4
    CLOCK = 8
    RESET = 16
    DECISION_WINDOW = 32    #: one decision window on the board (issue 23)
    READ_PLAN = 64          #: DECISION_WINDOW's lean read plan (``DecisionParams.conversions``)
    PIPELINE = 128          #: takes PIPELINE_BYTES of the next request while it runs one
    LEARN = 256             #: on-board learning (issue 34; :mod:`snan_hil.protocol.learn_messages`)


BASE_CAPABILITIES = int(Capability.READ_COLUMN | Capability.SPIKE_BATCH
                        | Capability.PROGRAM_CELL | Capability.CLOCK | Capability.RESET
                        | Capability.DECISION_WINDOW | Capability.READ_PLAN
                        | Capability.PIPELINE)
"""What this project's boards announce (INFO's default); the Python MCU adds LEARN where
``BoardConfig.on_board_learning`` is on (issue 34)."""


# --------------------------------------------------------------------------- helpers
def _pack(fmt: str, *values: Any) -> bytes:
    try:
        return struct.pack(fmt, *values)
    except struct.error as exc:
        raise FieldRangeError(f"value does not fit wire format {fmt!r}: {exc}") from None


def _unpack_exact(cls: type, fmt: str, payload: bytes) -> tuple[Any, ...]:
    size = struct.calcsize(fmt)
    if len(payload) != size:
        raise MalformedPayloadError(
            f"{cls.__name__}: payload is {len(payload)} bytes, expected {size}")
    return struct.unpack(fmt, payload)


def _text(value: str, what: str) -> bytes:
    raw = value.encode("utf-8")
    if len(raw) > MAX_TEXT:
        raise FieldRangeError(f"{what} is {len(raw)} bytes of UTF-8, at most {MAX_TEXT}")
    return bytes([len(raw)]) + raw


class _Reader:
    """Cursor over a payload that raises MalformedPayloadError on any shortfall."""

    def __init__(self, cls: type, payload: bytes):
        self.cls, self.data, self.pos = cls, bytes(payload), 0

    def take(self, fmt: str) -> tuple[Any, ...]:
        size = struct.calcsize(fmt)
        if self.pos + size > len(self.data):
            raise MalformedPayloadError(f"{self.cls.__name__}: payload truncated")
        out = struct.unpack_from(fmt, self.data, self.pos)
        self.pos += size
        return out

    def raw(self, n: int) -> bytes:
        if self.pos + n > len(self.data):
            raise MalformedPayloadError(f"{self.cls.__name__}: payload truncated")
        out = self.data[self.pos:self.pos + n]
        self.pos += n
        return out

    def text(self) -> str:
        (n,) = self.take("<B")
        if n > MAX_TEXT:
            raise MalformedPayloadError(f"{self.cls.__name__}: text field of {n} bytes")
        try:
            return self.raw(n).decode("utf-8")
        except UnicodeDecodeError:
            raise MalformedPayloadError(f"{self.cls.__name__}: text is not UTF-8") from None

    def end(self) -> None:
        if self.pos != len(self.data):
            raise MalformedPayloadError(
                f"{self.cls.__name__}: {len(self.data) - self.pos} trailing bytes")


def _bool(value: int, name: str, owner: type) -> bool:
    """A wire ``bool``: exactly 0 or 1 (anything else is malformed, docs/protocol.md)."""
    if value not in (0, 1):
        raise MalformedPayloadError(f"{owner.__name__}: {name} is {value}, a bool must be 0 or 1")
    return bool(value)


def _enum(enum_cls: type, value: int, owner: type) -> Any:
    try:
        return enum_cls(value)
    except ValueError:
        raise MalformedPayloadError(f"{owner.__name__}: invalid {enum_cls.__name__} {value}") \
            from None


# --------------------------------------------------------------------------- base classes
@dataclass(frozen=True, slots=True)
class Message:
    """Base of all messages. Subclasses set ``TYPE`` and implement encode/decode."""

    TYPE: ClassVar[int] = -1
    #: For fixed-layout messages: struct format of the payload, fields in declaration order.
    FMT: ClassVar[str | None] = None

    def encode(self) -> bytes:
        """The payload bytes of this message."""
        assert self.FMT is not None, "variable-length messages override encode()"
        return _pack(self.FMT, *(getattr(self, f.name) for f in fields(self)))

    @classmethod
    def decode(cls, payload: bytes) -> "Message":
        """Parse a payload; raises MalformedPayloadError if it does not fit this type."""
        assert cls.FMT is not None, "variable-length messages override decode()"
        values = _unpack_exact(cls, cls.FMT, payload)
        return cls(*values)


@dataclass(frozen=True, slots=True)
class Reply(Message):
    """A board -> host message."""


ReplyT = TypeVar("ReplyT", bound=Reply, covariant=True)
"""The reply type of a request: ``ReadCell`` is a ``Request[ReadCellReply]``."""


@dataclass(frozen=True, slots=True)
class Request(Message, Generic[ReplyT]):
    """A host -> board message, generic in its successful reply: a subclass names its reply
    class once, as the type argument (``class ReadCell(Request[ReadCellReply])``), which sets
    ``REPLY`` at run time and lets a client's ``request(req)`` return that type to the type
    checker."""

    REPLY: ClassVar[type[Reply]]

    def __init_subclass__(cls, **kwargs: Any) -> None:
        # two-argument super: a slots dataclass is re-created, the zero-argument form would
        # name the class before that
        super(Request, cls).__init_subclass__(**kwargs)
        for base in cls.__dict__.get("__orig_bases__", ()):
            origin, args = get_origin(base), get_args(base)
            if isinstance(origin, type) and issubclass(origin, Request) and args \
                    and isinstance(args[0], type) and issubclass(args[0], Reply):
                cls.REPLY = args[0]

    def accept(self, reply: Message) -> ReplyT | None:
        """``reply`` as this request's reply type if it is one (``REPLY``), else None."""
        if isinstance(reply, self.REPLY):
            # REPLY is the run-time value of the type argument ReplyT (__init_subclass__)
            return cast(ReplyT, reply)
        return None


@dataclass(frozen=True, slots=True)
class _BareRequest(Request[ReplyT]):
    """A request without a payload (STATUS, CLOCK, RESET)."""

    FMT: ClassVar[str] = "<"


@dataclass(frozen=True, slots=True)
class _AdcReply(Reply):
    """A reply that is one ADC code (READ_CELL, READ_COLUMN, WRITE_PULSE)."""

    FMT: ClassVar[str] = "<H"
    adc: int = 0


# --------------------------------------------------------------------------- HELLO / INFO
@dataclass(frozen=True, slots=True)
class Info(Reply, BoardConstants):
    """Board description, the reply to HELLO: the board's :class:`BoardConstants` (all their
    fields and converters; defaults: the MemriCore board) plus the link's fields.

    On the wire the derived ``v_read_v`` and ``read_code`` travel too (docs/protocol.md); a
    decoded INFO whose values disagree with its own constants is malformed.
    """

    TYPE: ClassVar[int] = 0x81
    protocol_version: int = PROTOCOL_VERSION
    firmware_version: str = ""
    board_id: str = ""
    max_payload: int = MAX_PAYLOAD
    capabilities: int = BASE_CAPABILITIES
    boot_nonce: int = 0

    _FMT_A: ClassVar[str] = "<B"
    _FMT_B: ClassVar[str] = "<BBBdBdBdB" + "d" * 8 + "HIIH"
    #: Every field on the wire, in wire order (``v_read_v`` and ``read_code`` are derived).
    WIRE_FIELDS: ClassVar[tuple[str, ...]] = (
        "protocol_version", "firmware_version", "board_id", "rows", "cols", "dac_bits",
        "dac_vref_v", "write_dac_bits", "write_dac_vref_v", "adc_bits", "adc_vref_v",
        "adc_averages", "r_load_ohm", "r_switch_ohm", "gain", "sum_gain_ohm", "v_read_v",
        "max_read_v", "max_write_v", "compliance_a", "max_payload", "capabilities",
        "boot_nonce", "read_code")

    def to_dict(self) -> dict[str, Any]:
        """Every wire field by name, in wire order (for reports and ``snan-hil info``)."""
        return {name: getattr(self, name) for name in self.WIRE_FIELDS}

    @classmethod
    def from_board(cls, board: BoardConstants, **link_fields: Any) -> "Info":
        """The INFO of a board with constants ``board`` (any BoardConstants subclass: only
        the base fields are taken) and the given link fields."""
        base = {name: getattr(board, name) for name in BoardConstants.__dataclass_fields__}
        return cls(**base, **link_fields)

    def encode(self) -> bytes:
        return (_pack(self._FMT_A, self.protocol_version)
                + _text(self.firmware_version, "firmware_version")
                + _text(self.board_id, "board_id")
                + _pack(self._FMT_B, self.rows, self.cols, self.dac_bits, self.dac_vref_v,
                        self.write_dac_bits, self.write_dac_vref_v, self.adc_bits,
                        self.adc_vref_v, self.adc_averages, self.r_load_ohm, self.r_switch_ohm,
                        self.gain, self.sum_gain_ohm, self.v_read_v, self.max_read_v,
                        self.max_write_v, self.compliance_a, self.max_payload,
                        self.capabilities, self.boot_nonce, self.read_code))

    @classmethod
    def decode(cls, payload: bytes) -> "Info":
        r = _Reader(cls, payload)
        (version,) = r.take(cls._FMT_A)
        fw, board = r.text(), r.text()
        (rows, cols, dac_bits, dac_vref_v, write_dac_bits, write_dac_vref_v, adc_bits,
         adc_vref_v, adc_averages, r_load_ohm, r_switch_ohm, gain, sum_gain_ohm, v_read_v,
         max_read_v, max_write_v, compliance_a, max_payload, capabilities, boot_nonce,
         read_code) = r.take(cls._FMT_B)
        r.end()
        try:
            info = cls(rows=rows, cols=cols, dac_bits=dac_bits, dac_vref_v=dac_vref_v,
                       write_dac_bits=write_dac_bits, write_dac_vref_v=write_dac_vref_v,
                       adc_bits=adc_bits, adc_vref_v=adc_vref_v, adc_averages=adc_averages,
                       r_load_ohm=r_load_ohm, r_switch_ohm=r_switch_ohm, gain=gain,
                       sum_gain_ohm=sum_gain_ohm, max_read_v=max_read_v, max_write_v=max_write_v,
                       compliance_a=compliance_a, protocol_version=version, firmware_version=fw,
                       board_id=board, max_payload=max_payload, capabilities=capabilities,
                       boot_nonce=boot_nonce)
            # what a host derives from the constants: computed here, so that constants a host
            # cannot work with (1e308 V, an ADC reference of 5e-324 V, ...) are a malformed INFO,
            # not an untyped error later (issue 27, item 5)
            derived = (info.read_code, info.max_write_code, info.max_cell_read_code,
                       info.max_row_read_code, info.v_read_v, info.cell_scale(),
                       info.column_scale(), info.adc_codes_per_volt)
        except (ValueError, ArithmeticError) as exc:      # OverflowError, ZeroDivisionError
            raise MalformedPayloadError(f"Info: {exc}") from None
        if not all(math.isfinite(x) and x >= 0 for x in derived):
            raise MalformedPayloadError(
                "Info: the read chain of these constants is not finite (a reference, gain or "
                "resistance out of any physical range)")
        if read_code != info.read_code or not abs(v_read_v - info.v_read_v) <= _V_READ_TOLERANCE_V:
            raise MalformedPayloadError(
                f"Info: announced read code {read_code} ({v_read_v:.4f} V) is not the largest "
                f"code at or below its max_read_v {max_read_v} V ({info.read_code})")
        if max_payload < len(payload):
            raise MalformedPayloadError(
                f"Info: max_payload {max_payload} is less than this INFO's own {len(payload)} "
                "bytes")
        return info

    def has(self, capability: Capability) -> bool:
        """Whether the board implements an optional request."""
        return bool(self.capabilities & capability)

    @property
    def chip_id(self) -> str:
        """The chip part of ``board_id`` (after a ``/``; the emulator names its chip there:
        ``EMU-4D430001/8B297CA46845``), "" for a board that reports none."""
        return self.board_id.partition("/")[2]


_V_READ_TOLERANCE_V = 1e-6
"""How far an announced nominal read voltage may differ from the one its code gives (V)."""


@dataclass(frozen=True, slots=True)
class Hello(Request[Info]):
    """Open a session: the board answers with :class:`Info` and forgets its reply cache."""

    TYPE: ClassVar[int] = 0x01
    FMT: ClassVar[str] = "<B"
    protocol_version: int = PROTOCOL_VERSION


# --------------------------------------------------------------------------- READ_CELL
@dataclass(frozen=True, slots=True)
class ReadCellReply(_AdcReply):
    """ADC code of a single-cell read."""

    TYPE: ClassVar[int] = 0x82


@dataclass(frozen=True, slots=True)
class ReadCell(Request[ReadCellReply]):
    """Read one cell: drive ``row`` with row-DAC ``dac_code``, open column ``col``."""

    TYPE: ClassVar[int] = 0x02
    FMT: ClassVar[str] = "<BBH"
    row: int = 0
    col: int = 0
    dac_code: int = 0


# --------------------------------------------------------------------------- READ_COLUMN
@dataclass(frozen=True, slots=True)
class ReadColumnReply(_AdcReply):
    """ADC code of a column multiply-accumulate."""

    TYPE: ClassVar[int] = 0x83


@dataclass(frozen=True, slots=True)
class ReadColumn(Request[ReadColumnReply]):
    """Column multiply: drive row i with ``row_codes[i]`` (len = rows), read column ``col``."""

    TYPE: ClassVar[int] = 0x03
    col: int = 0
    row_codes: tuple[int, ...] = ()

    def encode(self) -> bytes:
        n = len(self.row_codes)
        return _pack(f"<BB{n}H", self.col, n, *self.row_codes)

    @classmethod
    def decode(cls, payload: bytes) -> "ReadColumn":
        r = _Reader(cls, payload)
        col, n = r.take("<BB")
        codes = r.take(f"<{n}H")
        r.end()
        return cls(col, tuple(codes))


# --------------------------------------------------------------------------- WRITE_PULSE
@dataclass(frozen=True, slots=True)
class WritePulseReply(_AdcReply):
    """ADC code of the read that follows the pulse."""

    TYPE: ClassVar[int] = 0x84


@dataclass(frozen=True, slots=True)
class WritePulse(Request[WritePulseReply]):
    """One programming pulse on (row, col), then a read of that cell.

    ``amplitude_code`` is a write-DAC code; ``width_us`` the pulse width in us; ``read_code``
    the row-DAC code of the read after (0 = the board's nominal read voltage).
    """

    TYPE: ClassVar[int] = 0x04
    FMT: ClassVar[str] = "<BBBHIH"
    row: int = 0
    col: int = 0
    polarity: Polarity = Polarity.SET
    amplitude_code: int = 0
    width_us: int = 100
    read_code: int = 0

    @classmethod
    def decode(cls, payload: bytes) -> "WritePulse":
        row, col, pol, amp, width, read = _unpack_exact(cls, cls.FMT, payload)
        return cls(row, col, _enum(Polarity, pol, cls), amp, width, read)


# --------------------------------------------------------------------------- SPIKE_BATCH
@dataclass(frozen=True, slots=True)
class SpikeGroup:
    """One input row group: the rows a spike drives and when it spikes.

    ``rows``: (row, row-DAC code) pairs driven together for each spike.
    ``bins``: strictly increasing bin indices (relative to the batch's first bin) with a spike.
    """

    rows: tuple[tuple[int, int], ...] = ()
    bins: tuple[int, ...] = ()


@dataclass(frozen=True, slots=True)
class SpikeBatchReply(Reply):
    """Per spike (in batch order), the ADC codes of the requested columns (ascending)."""

    TYPE: ClassVar[int] = 0x85
    first_bin: int = 0
    n_columns: int = 0
    codes: tuple[tuple[int, ...], ...] = ()

    def encode(self) -> bytes:
        n = len(self.codes)
        for row in self.codes:
            if len(row) != self.n_columns:
                raise FieldRangeError(
                    f"SpikeBatchReply: a spike has {len(row)} codes, n_columns={self.n_columns}")
        flat = [c for row in self.codes for c in row]
        return _pack(f"<IHB{len(flat)}H", self.first_bin, n, self.n_columns, *flat)

    @classmethod
    def decode(cls, payload: bytes) -> "SpikeBatchReply":
        r = _Reader(cls, payload)
        first_bin, n, ncol = r.take("<IHB")
        flat = r.take(f"<{n * ncol}H")
        r.end()
        # n rows of ncol codes: zip takes ncol consecutive items of one iterator per row
        codes = tuple(zip(*[iter(flat)] * ncol)) if ncol else ((),) * n
        return cls(first_bin, ncol, codes)


@dataclass(frozen=True, slots=True)
class SpikeBatch(Request[SpikeBatchReply]):
    """Apply the spikes of one decision window (or a chunk of it) and read columns per spike.

    The window is ``n_bins`` bins of ``bin_us`` us, starting at absolute bin ``first_bin``
    (echoed in the reply so chunks can be matched). Spikes are applied in bin order; within a bin
    in group order. For each spike the board sets the group's row DACs, then reads each column in
    ``columns`` (strictly increasing) and returns the codes. ``paced``: the board waits for each
    bin's start time before applying its spikes (else as fast as possible).
    """

    TYPE: ClassVar[int] = 0x05
    groups: tuple[SpikeGroup, ...] = ()
    columns: tuple[int, ...] = ()
    n_bins: int = 1000
    bin_us: int = 1000
    first_bin: int = 0
    paced: bool = False

    def n_spikes(self) -> int:
        """Number of spikes (= entries of the reply)."""
        return sum(len(g.bins) for g in self.groups)

    def spike_order(self) -> list[tuple[int, int]]:
        """(bin, group index) of each spike, in the order the board applies them."""
        return sorted((b, gi) for gi, g in enumerate(self.groups) for b in g.bins)

    def encode(self) -> bytes:
        mask = 0
        prev = -1
        for c in self.columns:
            if not (prev < c < 32):
                raise FieldRangeError("SpikeBatch.columns must be strictly increasing, < 32")
            mask |= 1 << c
            prev = c
        if not 0 <= self.n_bins <= 0xFFFF:
            raise FieldRangeError(f"SpikeBatch.n_bins={self.n_bins} outside 0..65535")
        nbytes = (self.n_bins + 7) // 8
        out = [_pack("<IHHIBB", self.first_bin, self.n_bins, self.bin_us, mask,
                     1 if self.paced else 0, len(self.groups))]
        for g in self.groups:
            out.append(_pack("<B", len(g.rows)))
            for row, code in g.rows:
                out.append(_pack("<BH", row, code))
            bitmap = bytearray(nbytes)
            prev = -1
            for b in g.bins:
                if not (prev < b < self.n_bins):
                    raise FieldRangeError(
                        "SpikeGroup.bins must be strictly increasing and < n_bins")
                bitmap[b >> 3] |= 1 << (b & 7)
                prev = b
            out.append(bytes(bitmap))
        return b"".join(out)

    @classmethod
    def decode(cls, payload: bytes) -> "SpikeBatch":
        r = _Reader(cls, payload)
        first_bin, n_bins, bin_us, mask, flags, ngroups = r.take("<IHHIBB")
        if flags & ~1:
            raise MalformedPayloadError(f"SpikeBatch: unknown flag bits 0x{flags:02x}")
        nbytes = (n_bins + 7) // 8
        groups = []
        for _ in range(ngroups):
            (nrows,) = r.take("<B")
            flat = r.take("<" + "BH" * nrows)
            rows = tuple((flat[2 * i], flat[2 * i + 1]) for i in range(nrows))
            bitmap = r.raw(nbytes)
            if n_bins % 8 and bitmap[-1] >> (n_bins % 8):
                raise MalformedPayloadError("SpikeBatch: bitmap bits set beyond n_bins")
            bins = tuple(8 * i + bit for i, byte in enumerate(bitmap) if byte
                         for bit in _SET_BITS[byte])
            groups.append(SpikeGroup(rows, bins))
        r.end()
        columns = tuple(c for c in range(32) if mask >> c & 1)
        return cls(tuple(groups), columns, n_bins, bin_us, first_bin, bool(flags & 1))


_SET_BITS = tuple(tuple(bit for bit in range(8) if byte >> bit & 1) for byte in range(256))
"""Positions of the set bits of each byte value, LSB first (bitmap decoding)."""


def spike_batch_reply_size(n_spikes: int, n_columns: int) -> int:
    """Payload bytes of a SpikeBatchReply (to split windows under the max payload)."""
    return 7 + 2 * n_spikes * n_columns


# --------------------------------------------------------------------------- PROGRAM_CELL
@dataclass(frozen=True, slots=True)
class ProgramCellReply(Reply):
    """Outcome of a firmware write-and-verify: final ADC code, pulses per stage, success."""

    TYPE: ClassVar[int] = 0x86
    FMT: ClassVar[str] = "<HHHB"
    final_adc: int = 0
    pulses_stage1: int = 0
    pulses_stage2: int = 0
    ok: bool = False

    def encode(self) -> bytes:
        return _pack(self.FMT, self.final_adc, self.pulses_stage1, self.pulses_stage2,
                     1 if self.ok else 0)

    @classmethod
    def decode(cls, payload: bytes) -> "ProgramCellReply":
        final, s1, s2, ok = _unpack_exact(cls, cls.FMT, payload)
        return cls(final, s1, s2, _bool(ok, "ok", cls))


@dataclass(frozen=True, slots=True)
class ProgramCell(Request[ProgramCellReply]):
    """Firmware-side write-and-verify of one cell towards an ADC-code target.

    Stage 1 ramps the write amplitude from ``amp_start_code`` to ``amp_stop_code`` in steps of
    ``amp_step_code`` (write-DAC codes, ``width_us`` pulses, SET if below target, RESET if above,
    a read after each) until the read is within ``tolerance_adc`` of ``target_adc``. With
    ``fine_tune`` stage 2 applies RESET pulses until code <= target, then SET until >= target.
    At most ``max_pulses`` pulses in total. Each amplitude code given as 0 takes the old host's
    ticket ramp value (:data:`~snan_hil.protocol.board.PROGRAM_RAMP_V`, as write-DAC codes:
    :meth:`~snan_hil.protocol.board.BoardConstants.program_ramp_codes`); so the defaults below
    mean that ramp.
    """

    TYPE: ClassVar[int] = 0x06
    FMT: ClassVar[str] = "<BBHHHHHHIHB"
    row: int = 0
    col: int = 0
    target_adc: int = 0
    tolerance_adc: int = 0
    max_pulses: int = 100
    amp_start_code: int = 0
    amp_stop_code: int = 0
    amp_step_code: int = 0
    width_us: int = 100
    read_code: int = 0
    fine_tune: bool = True

    def encode(self) -> bytes:
        values = [getattr(self, f.name) for f in fields(self)]
        values[-1] = 1 if self.fine_tune else 0
        return _pack(self.FMT, *values)

    @classmethod
    def decode(cls, payload: bytes) -> "ProgramCell":
        values = list(_unpack_exact(cls, cls.FMT, payload))
        values[-1] = _bool(values[-1], "fine_tune", cls)
        return cls(*values)


# --------------------------------------------------------------------------- STATUS
@dataclass(frozen=True, slots=True)
class StatusReply(Reply):
    """Counters since boot/RESET. Link fields are filled by the device endpoint."""

    TYPE: ClassVar[int] = 0x87
    FMT: ClassVar[str] = "<" + "I" * 16
    # link (device endpoint)
    frames_in: int = 0          # valid frames received
    frames_out: int = 0         # frames sent
    crc_errors: int = 0
    framing_errors: int = 0     # COBS / length errors
    malformed: int = 0          # valid frames with a bad payload
    unknown_types: int = 0
    duplicates: int = 0         # retransmitted requests answered from the reply cache
    refusals: int = 0           # ERROR replies for refused/failed requests
    nonce_mismatches: int = 0   # requests with a stale boot nonce (not executed)
    executed: int = 0           # requests passed to the firmware handler
    # firmware
    cell_reads: int = 0
    column_reads: int = 0
    pulses_applied: int = 0     # write pulses really applied to the array
    spikes_applied: int = 0
    busy: int = 0
    saturated_reads: int = 0    # readings with an ADC conversion at full scale (clipped)

    LINK_FIELDS: ClassVar[tuple[str, ...]] = (
        "frames_in", "frames_out", "crc_errors", "framing_errors", "malformed",
        "unknown_types", "duplicates", "refusals", "nonce_mismatches", "executed")


@dataclass(frozen=True, slots=True)
class Status(_BareRequest[StatusReply]):
    """Ask for the counters."""

    TYPE: ClassVar[int] = 0x07


# --------------------------------------------------------------------------- CLOCK
@dataclass(frozen=True, slots=True)
class ClockReply(Reply):
    """Board time in us and array energy in J since boot/RESET (virtual on the emulator)."""

    TYPE: ClassVar[int] = 0x88
    FMT: ClassVar[str] = "<Qd"
    time_us: int = 0
    energy_j: float = 0.0

    @classmethod
    def decode(cls, payload: bytes) -> "ClockReply":
        """MalformedPayloadError also for an energy that is not a finite number >= 0 J."""
        time_us, energy_j = _unpack_exact(cls, cls.FMT, payload)
        if not (math.isfinite(energy_j) and energy_j >= 0):
            raise MalformedPayloadError(f"ClockReply: energy_j {energy_j!r} is not a finite "
                                        "energy >= 0 J")
        return cls(time_us, energy_j)


@dataclass(frozen=True, slots=True)
class Clock(_BareRequest[ClockReply]):
    """Ask for board time and array energy."""

    TYPE: ClassVar[int] = 0x08


# --------------------------------------------------------------------------- RESET
@dataclass(frozen=True, slots=True)
class ResetReply(Reply):
    """The board reset its clock, energy and counters and drew a new boot nonce.

    The reply's frame header already carries ``new_nonce``.
    """

    TYPE: ClassVar[int] = 0x89
    FMT: ClassVar[str] = "<II"
    old_nonce: int = 0
    new_nonce: int = 0


@dataclass(frozen=True, slots=True)
class Reset(_BareRequest[ResetReply]):
    """Soft reset (the array's conductances are kept)."""

    TYPE: ClassVar[int] = 0x09


# --------------------------------------------------------------------------- ERROR
@dataclass(frozen=True, slots=True)
class ErrorReply(Reply):
    """The board refused or failed a request; ``detail`` is an offending value or 0."""

    TYPE: ClassVar[int] = 0xFF
    code: ErrorCode = ErrorCode.INTERNAL
    request_type: int = 0
    detail: int = 0
    message: str = ""

    def encode(self) -> bytes:
        return _pack("<BBI", self.code, self.request_type, self.detail) + \
            _text(self.message, "ErrorReply.message")

    @classmethod
    def decode(cls, payload: bytes) -> "ErrorReply":
        r = _Reader(cls, payload)
        code, req, detail = r.take("<BBI")
        msg = r.text()
        r.end()
        return cls(_enum(ErrorCode, code, cls), req, detail, msg)


# --------------------------------------------------------------------------- registry
MESSAGE_TYPES: dict[int, type[Message]] = {
    cls.TYPE: cls for cls in (
        Hello, Info, ReadCell, ReadCellReply, ReadColumn, ReadColumnReply, WritePulse,
        WritePulseReply, SpikeBatch, SpikeBatchReply, ProgramCell, ProgramCellReply, Status,
        StatusReply, Clock, ClockReply, Reset, ResetReply, ErrorReply)
}
"""Type code -> message class."""

REQUEST_TYPES: dict[int, type[Request[Reply]]] = {
    code: cls for code, cls in MESSAGE_TYPES.items() if issubclass(cls, Request)}


def message_class(type_code: int) -> type[Message]:
    """The class registered for ``type_code``; UnknownTypeError if none."""
    try:
        return MESSAGE_TYPES[type_code]
    except KeyError:
        raise UnknownTypeError(f"unknown message type 0x{type_code:02x}") from None


def decode_message(type_code: int, payload: bytes) -> Message:
    """Decode a payload of the given type (UnknownTypeError / MalformedPayloadError)."""
    return message_class(type_code).decode(payload)


def _check_registry() -> None:
    for code, cls in REQUEST_TYPES.items():
        assert cls.REPLY.TYPE == code | 0x80, cls


_check_registry()


# --------------------------------------------------------------------------- DECISION_WINDOW
# One decision window on the board (issue 23, docs/protocol.md section 5, "0x0A
# DECISION_WINDOW"): the board draws the window's input spikes from the host's spike-stream
# state, drives the input neuron's rows and reads the candidates' columns per spike, and
# integrates the candidates' motor neurons (LIF, paper Eq. 1) in fixed point with the
# interneuron spike trains the host sends. Appended here (after the registry) and registered
# below.

DW_MAX_BINS = 16384
"""Longest window in bins (a motor spike travels as ``step | lane << 14``)."""
DW_MAX_ROWS = 4
"""Rows of one input neuron, driven one after another per spike."""
DW_MAX_CANDIDATES = 4
"""Candidate motor neurons of one window (a grid cell's four neighbours)."""
DW_VARINT_BYTES = 3
"""Longest interneuron spike gap (unsigned LEB128, 7 bits a byte)."""
DW_ALPHA_TABLE = 16
"""Powers alpha^1 .. alpha^16 of the decay in the parameter block (longer gaps chain them)."""
DW_FIXED_ONE = 1 << 32
"""1.0 in the Q32.32 fields of :class:`DecisionParams` (potentials, weights to potentials)."""
DW_FIELD_LIMIT = 1 << 56
"""Largest magnitude of a Q32.32 field (2^24 in model units): the board's int64 sums cannot
overflow (docs/protocol.md)."""
DW_POTENTIAL_LIMIT = 1 << 62
"""The board's potentials saturate at +-2^62 (Q32.32: +-2^30 model units)."""


class DecisionFlag(IntFlag):
    """Bits of DECISION_WINDOW's ``flags`` byte."""

    NONE = 0
    PARAMS = 1          #: a parameter block follows; the board keeps it for later windows
    MOTOR_SPIKES = 2    #: the reply carries every motor spike (step, lane)
    TRACE = 4           #: the reply carries the potentials every ``trace_stride`` steps
    PACED = 8           #: each spike waits for its bin's start (``bin_us``)
    READ_PLAN = 16      #: with PARAMS: the block is followed by its read plan byte


class DecisionLifFlag(IntFlag):
    """Bits of the parameter block's ``lif_flags``."""

    NONE = 0
    INTEGRATE = 1       #: refractory motor neurons integrate (``neuron.refractory=integrate``)


@dataclass(frozen=True, slots=True)
class DecisionParams:
    """The parameter block of DECISION_WINDOW (204 bytes): window, read and LIF constants in
    the board's fixed point. The host computes it once per session
    (:mod:`snan_hil.host.hil.board_window`); the board keeps it until HELLO, RESET or a power
    cycle.

    Q32.32 fields are int64 = round(value * 2^32) in the model's units (potentials as
    ``v - v_rest``); ``alpha_pow[k - 1]`` is the decay over k steps, exp(-k dt/tau_m), in
    Q0.64 (k = 1 .. 16). The ADC code ->
    drive conversion is the host's calibrated column chain (offset, ``G = 1/(1/G_eff - R_sw)``,
    linear weight map) times R: ``drive = k1 * x/(d - x) - k0`` with ``x = code - offset``
    (codes), evaluated as docs/protocol.md states (shifts ``num_shift``, ``den_shift``,
    ``q_shift``).

    ``conversions`` is the block's read plan (not among the 204 bytes: the request carries it
    in one more byte after the block, flag READ_PLAN, on a board with the READ_PLAN
    capability): 0 reads as SPIKE_BATCH does (one dummy and the board's ``adc_averages``
    conversions per read, the union of the candidates' columns for every row); 1 ..
    ``adc_averages`` is the lean plan: that many conversions per read, the ADC's pipeline
    without a dummy conversion, each read settling while the ADC converts the previous one,
    only each row's candidate columns (docs/protocol.md "0x0A DECISION_WINDOW", "Read plan").
    """

    n_bins: int = 1000
    bin_us: int = 1000
    row_code: int = 245
    ref_steps: int = 40
    lif_flags: int = 0
    num_shift: int = 17
    den_shift: int = 19
    q_shift: int = 4
    spike_threshold: int = 0
    alpha_pow: tuple[int, ...] = (0,) * DW_ALPHA_TABLE
    thr: int = 0
    reset: int = 0
    inh: int = 0
    offset: int = 0
    d: int = 0
    k1: int = 0
    k0: int = 0
    conversions: int = 0

    FMT: ClassVar[str] = f"<HHHHBBBBQ{DW_ALPHA_TABLE}Qqqqqqqq"
    SIZE: ClassVar[int] = 204

    def encode(self) -> bytes:
        """The 204-byte block (without the read plan byte, which :class:`DecisionWindow`
        appends)."""
        if len(self.alpha_pow) != DW_ALPHA_TABLE:
            raise FieldRangeError(f"DecisionParams.alpha_pow needs {DW_ALPHA_TABLE} values")
        values: list[Any] = []
        for f in fields(self):
            if f.name == "conversions":
                continue
            v = getattr(self, f.name)
            values += list(v) if f.name == "alpha_pow" else [v]
        return _pack(self.FMT, *values)

    @classmethod
    def decode(cls, payload: bytes) -> "DecisionParams":
        v = _unpack_exact(cls, cls.FMT, payload)
        if v[4] & ~int(DecisionLifFlag.INTEGRATE):
            raise MalformedPayloadError(f"DecisionParams: unknown lif_flags bits 0x{v[4]:02x}")
        n = DW_ALPHA_TABLE
        names = [f.name for f in fields(cls) if f.name != "conversions"]
        values = [*v[:9], tuple(v[9:9 + n]), *v[9 + n:]]
        return cls(**dict(zip(names, values)))

    @property
    def integrate(self) -> bool:
        return bool(self.lif_flags & DecisionLifFlag.INTEGRATE)

    @property
    def lean(self) -> bool:
        """The lean read plan (``conversions`` > 0)."""
        return self.conversions > 0


@dataclass(frozen=True, slots=True)
class DecisionCandidate:
    """One candidate motor neuron: its synapse cell (``row_index`` into the request's rows,
    ``col``) and its interneuron's spike steps (strictly increasing, < n_bins)."""

    col: int = 0
    row_index: int = 0
    inh: tuple[int, ...] = ()


def _varint(value: int) -> bytes:
    if not 0 <= value < 1 << (7 * DW_VARINT_BYTES):
        raise FieldRangeError(f"interneuron spike gap {value} does not fit "
                              f"{DW_VARINT_BYTES} LEB128 bytes")
    out = bytearray()
    while True:
        byte = value & 0x7F
        value >>= 7
        if value:
            out.append(byte | 0x80)
        else:
            out.append(byte)
            return bytes(out)


def _read_varint(r: "_Reader") -> int:
    value = 0
    for i in range(DW_VARINT_BYTES):
        (byte,) = r.take("<B")
        value |= (byte & 0x7F) << (7 * i)
        if not byte & 0x80:
            return value
    raise MalformedPayloadError(f"{r.cls.__name__}: a spike gap longer than "
                                f"{DW_VARINT_BYTES} bytes")


@dataclass(frozen=True, slots=True)
class DecisionWindowReply(Reply):
    """Per candidate the motor spike count; the window's input spike count (the host checks
    it against its own draw); with MOTOR_SPIKES every motor spike ``(step, lane)`` in time
    order; with TRACE the potentials (Q16.16, ``floor(u / 2^16)`` clipped to int32) at steps
    0, stride, 2 stride, ... as ``trace[point][lane]``."""

    TYPE: ClassVar[int] = 0x8A
    n_input_spikes: int = 0
    counts: tuple[int, ...] = ()
    motor_spikes: tuple[tuple[int, int], ...] | None = None
    trace: tuple[tuple[int, ...], ...] | None = None

    def encode(self) -> bytes:
        n = len(self.counts)
        if n > DW_MAX_CANDIDATES:
            raise FieldRangeError(f"DecisionWindowReply: {n} candidates, at most "
                                  f"{DW_MAX_CANDIDATES}")
        head = n | (0x08 if self.trace is not None else 0) \
            | (0x10 if self.motor_spikes is not None else 0)
        out = [_pack(f"<BH{n}H", head, self.n_input_spikes, *self.counts)]
        if self.trace is not None:
            flat = [v for point in self.trace for v in point]
            if any(len(point) != n for point in self.trace):
                raise FieldRangeError("DecisionWindowReply: a trace point without one value "
                                      "per candidate")
            out.append(_pack(f"<H{len(flat)}i", len(self.trace), *flat))
        if self.motor_spikes is not None:
            if len(self.motor_spikes) != sum(self.counts):
                raise FieldRangeError("DecisionWindowReply: motor spikes do not add up to the "
                                      "counts")
            out.append(_pack(f"<{len(self.motor_spikes)}H",
                             *(t | lane << 14 for t, lane in self.motor_spikes)))
        return b"".join(out)

    @classmethod
    def decode(cls, payload: bytes) -> "DecisionWindowReply":
        r = _Reader(cls, payload)
        (head,) = r.take("<B")
        if head & ~0x1F or (head & 0x07) > DW_MAX_CANDIDATES:
            raise MalformedPayloadError(f"DecisionWindowReply: bad header byte 0x{head:02x}")
        n = head & 0x07
        (n_in,) = r.take("<H")
        counts = r.take(f"<{n}H")
        trace = None
        if head & 0x08:
            (points,) = r.take("<H")
            flat = r.take(f"<{points * n}i")
            trace = tuple(tuple(flat[i * n:(i + 1) * n]) for i in range(points))
        spikes = None
        if head & 0x10:
            raw = r.take(f"<{sum(counts)}H")
            spikes = tuple((v & 0x3FFF, v >> 14) for v in raw)
        r.end()
        return cls(n_in, tuple(counts), spikes, trace)


@dataclass(frozen=True, slots=True)
class DecisionWindow(Request[DecisionWindowReply]):
    """Run one decision window on the board (see the section comment above).

    ``key``: the host's spike-stream state before the window (splitmix64,
    :mod:`snan_hil.host.rng`): the board draws spike t iff ``mix(key + (t+1) golden) >> 11 <
    spike_threshold``, as the host does. ``rows``: the input neuron's rows (each driven alone
    at ``params.row_code`` per spike, in this order); per spike the board reads the union of
    the candidates' columns for each row (ascending), as a SPIKE_BATCH of one group per row
    does — or, with the lean read plan (``params.conversions`` > 0), each row's own
    candidates' columns (:meth:`reads`). ``params``: the parameter block, sent with the first
    window of a session (None: the board's stored block). ``trace_stride`` 0 = no trace.
    """

    TYPE: ClassVar[int] = 0x0A
    key: int = 0
    rows: tuple[int, ...] = ()
    candidates: tuple[DecisionCandidate, ...] = ()
    params: DecisionParams | None = None
    motor_spikes: bool = False
    trace_stride: int = 0
    paced: bool = False

    @property
    def flags(self) -> int:
        f = DecisionFlag.NONE
        if self.params is not None:
            f |= DecisionFlag.PARAMS
        if self.motor_spikes:
            f |= DecisionFlag.MOTOR_SPIKES
        if self.trace_stride:
            f |= DecisionFlag.TRACE
        if self.paced:
            f |= DecisionFlag.PACED
        if self.params is not None and self.params.conversions:
            f |= DecisionFlag.READ_PLAN
        return int(f)

    def encode(self) -> bytes:
        if len(self.rows) > 7 or len(self.candidates) > 7:
            raise FieldRangeError("DecisionWindow: at most 7 rows and 7 candidates fit the "
                                  "layout byte")
        out = [_pack("<B", self.flags)]
        if self.params is not None:
            out.append(self.params.encode())
            if self.params.conversions:
                out.append(_pack("<B", self.params.conversions))
        out.append(_pack("<Q", self.key))
        if self.trace_stride:
            out.append(_pack("<H", self.trace_stride))
        out.append(_pack("<B", len(self.rows) | len(self.candidates) << 4))
        out.append(_pack(f"<{len(self.rows)}B", *self.rows))
        for c in self.candidates:
            if not (0 <= c.col < 32 and 0 <= c.row_index < 4):
                raise FieldRangeError(f"DecisionWindow: candidate column {c.col} / row index "
                                      f"{c.row_index} outside 0..31 / 0..3")
            cell = c.col | c.row_index << 5 | (0x80 if c.inh else 0)
            out.append(_pack("<B", cell))
            if c.inh:
                if len(c.inh) > 255:
                    raise FieldRangeError("DecisionWindow: more than 255 interneuron spikes")
                out.append(_pack("<B", len(c.inh)))
                prev = -1
                for t in c.inh:
                    if t <= prev:
                        raise FieldRangeError("DecisionWindow: interneuron spike steps must be "
                                              "strictly increasing and >= 0")
                    out.append(_varint(t - prev - 1))
                    prev = t
        return b"".join(out)

    @classmethod
    def decode(cls, payload: bytes) -> "DecisionWindow":
        r = _Reader(cls, payload)
        (flags,) = r.take("<B")
        if flags & ~0x1F:
            raise MalformedPayloadError(f"DecisionWindow: unknown flag bits 0x{flags:02x}")
        if flags & DecisionFlag.READ_PLAN and not flags & DecisionFlag.PARAMS:
            raise MalformedPayloadError("DecisionWindow: READ_PLAN without a parameter block")
        params = None
        if flags & DecisionFlag.PARAMS:
            params = DecisionParams.decode(r.raw(DecisionParams.SIZE))
            if flags & DecisionFlag.READ_PLAN:
                (conversions,) = r.take("<B")
                if conversions == 0:
                    raise MalformedPayloadError("DecisionWindow: a read plan of 0 conversions")
                params = replace(params, conversions=conversions)
        (key,) = r.take("<Q")
        stride = 0
        if flags & DecisionFlag.TRACE:
            (stride,) = r.take("<H")
            if stride == 0:
                raise MalformedPayloadError("DecisionWindow: TRACE with stride 0")
        (layout,) = r.take("<B")
        if layout & 0x88:
            raise MalformedPayloadError(f"DecisionWindow: layout byte 0x{layout:02x} has "
                                        "reserved bits set")
        rows = r.take(f"<{layout & 0x07}B")
        cands = []
        for _ in range(layout >> 4):
            (cell,) = r.take("<B")
            inh: tuple[int, ...] = ()
            if cell & 0x80:
                (n,) = r.take("<B")
                if n == 0:
                    raise MalformedPayloadError("DecisionWindow: an interneuron list of 0 "
                                                "spikes")
                times, t = [], -1
                for _ in range(n):
                    t += _read_varint(r) + 1
                    times.append(t)
                inh = tuple(times)
            cands.append(DecisionCandidate(cell & 0x1F, (cell >> 5) & 0x03, inh))
        r.end()
        return cls(key, tuple(rows), tuple(cands), params,
                   bool(flags & DecisionFlag.MOTOR_SPIKES), stride,
                   bool(flags & DecisionFlag.PACED))

    def union_columns(self) -> tuple[int, ...]:
        """The columns read per spike and row: the candidates' columns, ascending."""
        return tuple(sorted({c.col for c in self.candidates}))

    def reads(self) -> tuple[tuple[int, int], ...]:
        """The lean plan's reads of one spike, in order: (row index, column) for each row in
        request order, its own candidates' columns ascending (a cell two candidates share is
        read once)."""
        return tuple((ri, col) for ri in range(len(self.rows))
                     for col in sorted({c.col for c in self.candidates if c.row_index == ri}))


def decision_reply_size(n_candidates: int, *, trace_points: int = 0,
                        max_motor_spikes: int | None = None) -> int:
    """Payload bytes of a DecisionWindowReply (worst case: ``max_motor_spikes`` spikes)."""
    size = 3 + 2 * n_candidates
    if trace_points:
        size += 2 + 4 * n_candidates * trace_points
    if max_motor_spikes is not None:
        size += 2 * max_motor_spikes
    return size


def decision_conversion_fits(p: DecisionParams, adc_full: int) -> bool:
    """Whether the code -> drive arithmetic of the parameter block stays in range for every
    ADC code 0..``adc_full`` (the board refuses a block for which it does not): ``0 < d <
    2^62``, the largest denominator ``d >> den_shift`` fits 32 bits, the smallest (at the full
    scale) is >= 1 and the largest quotient < 2^32 (``x / (d - x)`` grows with the code, so
    the full-scale code is the worst case); ``num_shift <= 17`` keeps ``x << num_shift``
    below 2^63."""
    if not (0 < p.d < 1 << 62 and p.den_shift <= 62 and p.num_shift <= 17):
        return False
    if p.d >> p.den_shift >= 1 << 32:
        return False
    x_max = (adc_full << 32) - p.offset
    if x_max <= 0:
        return True
    den_min = (p.d - x_max) >> p.den_shift
    return den_min >= 1 and ((x_max << p.num_shift) >> 32) < den_min


MESSAGE_TYPES[DecisionWindow.TYPE] = DecisionWindow
MESSAGE_TYPES[DecisionWindowReply.TYPE] = DecisionWindowReply
REQUEST_TYPES[DecisionWindow.TYPE] = DecisionWindow
__all__ += ["DecisionFlag", "DecisionLifFlag", "DecisionParams", "DecisionCandidate",
            "DecisionWindow", "DecisionWindowReply", "decision_reply_size",
            "decision_conversion_fits", "DW_MAX_BINS",
            "DW_MAX_ROWS", "DW_MAX_CANDIDATES", "DW_ALPHA_TABLE", "DW_FIXED_ONE", "DW_FIELD_LIMIT",
            "DW_POTENTIAL_LIMIT"]
_check_registry()
