"""Frames: header + payload + CRC-16, COBS-encoded, terminated by a 0x00 byte.

Raw frame (before COBS), all fields little-endian::

    offset size field
    0      1    version   PROTOCOL_VERSION (1)
    1      1    flags     bit0 RETRANSMIT (host resends), bit1 FROM_CACHE (reply from cache)
    2      1    type      message type code
    3      1    reserved  0 on send, ignored on receive
    4      2    seq       sequence number (u16, wraps)
    6      2    length    payload length in bytes (<= MAX_PAYLOAD)
    8      4    nonce     boot nonce (replies: the board's; requests: the host's, 0 = any)
    12     n    payload
    12+n   2    crc       CRC-16/CCITT-FALSE over bytes 0 .. 12+n-1

On the wire: ``COBS(raw) + b"\\x00"``. A sender may put extra 0x00 bytes between frames (the
host sends one before every retransmission to flush a half-received frame); receivers ignore
empty frames. :class:`FrameDecoder` is the streaming receiver.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

from snan_hil.protocol.crc import crc16
from snan_hil.protocol.errors import CobsError, CrcError, FrameError, FrameLengthError
from snan_hil.protocol.messages import MAX_PAYLOAD, PROTOCOL_VERSION, Message, decode_message

__all__ = [
    "HEADER_FMT", "HEADER_SIZE", "CRC_SIZE", "OVERHEAD", "FLAG_RETRANSMIT", "FLAG_FROM_CACHE",
    "Frame", "cobs_encode", "cobs_decode", "pack_frame", "unpack_frame", "encode_frame",
    "decode_frame", "peek_header", "max_encoded_size", "wire_size", "DecoderCounters",
    "FrameDecoder",
]

HEADER_FMT = "<BBBBHHI"
HEADER_SIZE = struct.calcsize(HEADER_FMT)  # 12
CRC_SIZE = 2
OVERHEAD = HEADER_SIZE + CRC_SIZE          # raw bytes besides the payload
FLAG_RETRANSMIT = 0x01
FLAG_FROM_CACHE = 0x02

_header = struct.Struct(HEADER_FMT)
_crc = struct.Struct("<H")


@dataclass(frozen=True, slots=True)
class Frame:
    """One checked frame: header fields and the undecoded payload."""

    type: int
    seq: int
    payload: bytes = b""
    nonce: int = 0
    flags: int = 0
    version: int = PROTOCOL_VERSION

    @classmethod
    def of(cls, message: Message, seq: int, nonce: int = 0, flags: int = 0) -> "Frame":
        """The frame carrying ``message``."""
        return cls(message.TYPE, seq, message.encode(), nonce, flags)

    def message(self) -> Message:
        """Decode the payload (UnknownTypeError / MalformedPayloadError)."""
        return decode_message(self.type, self.payload)

    def header(self) -> tuple[int, int, int, int, int]:
        """(version, flags, type, seq, nonce)."""
        return (self.version, self.flags, self.type, self.seq, self.nonce)


# --------------------------------------------------------------------------- COBS
def cobs_encode(data: bytes) -> bytes:
    """COBS-encode ``data`` (output has no 0x00 byte; the delimiter is not appended).

    Canonical form: a final run of exactly 254 non-zero bytes ends with its 0xFF group
    (no trailing empty 0x01 group).
    """
    out = bytearray()
    blocks = bytes(data).split(b"\x00")
    last = len(blocks) - 1
    for i, block in enumerate(blocks):
        n, pos = len(block), 0
        while n - pos >= 254:
            out.append(0xFF)
            out += block[pos:pos + 254]
            pos += 254
            if i == last and pos == n:
                return bytes(out)
        out.append(n - pos + 1)
        out += block[pos:]
    return bytes(out)


def cobs_decode(encoded: bytes) -> bytes:
    """Inverse of :func:`cobs_encode`; raises CobsError on invalid input."""
    enc = bytes(encoded)
    if b"\x00" in enc:
        raise CobsError("COBS data contains a 0x00 byte")
    out = bytearray()
    i, n = 0, len(enc)
    while i < n:
        code = enc[i]
        end = i + code
        if end > n:
            raise CobsError(f"COBS group of {code - 1} bytes runs past the end ({n - i - 1} left)")
        out += enc[i + 1:end]
        i = end
        if code < 0xFF and i < n:
            out.append(0)
    return bytes(out)


def peek_header(encoded: bytes) -> tuple[int, int, int, int, int] | None:
    """(version, flags, type, seq, nonce) from the start of a COBS-encoded frame that may be
    damaged further on, or None when its first 12 raw bytes cannot be decoded. Untrusted: a
    hint that a damaged frame was a reply of this protocol (see ``LinkClient``)."""
    out = bytearray()
    i, n = 0, len(encoded)
    while i < n and len(out) < HEADER_SIZE:
        code = encoded[i]
        if code == 0:
            return None
        out += encoded[i + 1:min(i + code, n)]
        i += code
        if code < 0xFF and i < n:
            out.append(0)
    if len(out) < HEADER_SIZE:
        return None
    version, flags, type_, _res, seq, _length, nonce = _header.unpack_from(out, 0)
    return (version, flags, type_, seq, nonce)


def max_encoded_size(max_payload: int = MAX_PAYLOAD) -> int:
    """Largest COBS-encoded frame (without delimiter) for payloads up to ``max_payload``."""
    raw = OVERHEAD + max_payload
    return raw + raw // 254 + 1


def wire_size(payload_len: int) -> int:
    """Upper bound of the bytes on the wire (COBS + delimiter) for a payload of that length."""
    raw = OVERHEAD + payload_len
    return raw + raw // 254 + 2


# --------------------------------------------------------------------------- raw frames
def pack_frame(frame: Frame) -> bytes:
    """Header + payload + CRC (not COBS-encoded)."""
    if len(frame.payload) > 0xFFFF:
        raise FrameLengthError(f"payload of {len(frame.payload)} bytes does not fit a frame")
    try:
        head = _header.pack(frame.version, frame.flags, frame.type, 0, frame.seq,
                            len(frame.payload), frame.nonce)
    except struct.error as exc:
        raise FrameLengthError(f"frame header field out of range: {exc}") from None
    body = head + bytes(frame.payload)
    return body + _crc.pack(crc16(body))


def unpack_frame(raw: bytes, max_payload: int = MAX_PAYLOAD) -> Frame:
    """Check and parse a raw (COBS-decoded) frame.

    Raises FrameLengthError (too short/long, length field disagrees) or CrcError; a CrcError
    carries the parsed header when the length field was consistent.
    """
    if len(raw) < OVERHEAD:
        raise FrameLengthError(f"frame of {len(raw)} bytes is shorter than {OVERHEAD}")
    version, flags, type_, _res, seq, length, nonce = _header.unpack_from(raw, 0)
    if length != len(raw) - OVERHEAD:
        raise FrameLengthError(
            f"length field says {length} payload bytes, frame holds {len(raw) - OVERHEAD}")
    head = (version, flags, type_, seq, nonce)
    if length > max_payload:
        raise FrameLengthError(f"payload of {length} bytes exceeds the maximum {max_payload}",
                               head)
    (crc,) = _crc.unpack_from(raw, len(raw) - CRC_SIZE)
    calc = crc16(raw[:-CRC_SIZE])
    if crc != calc:
        raise CrcError(f"CRC 0x{crc:04x} != computed 0x{calc:04x}", head)
    return Frame(type_, seq, bytes(raw[HEADER_SIZE:HEADER_SIZE + length]), nonce, flags, version)


def encode_frame(frame: Frame) -> bytes:
    """The bytes to put on the wire: ``COBS(raw) + 0x00``."""
    return cobs_encode(pack_frame(frame)) + b"\x00"


def decode_frame(encoded: bytes, max_payload: int = MAX_PAYLOAD) -> Frame:
    """Decode one COBS-encoded frame (delimiter stripped or not); raises FrameError."""
    enc = bytes(encoded)
    if enc.endswith(b"\x00"):
        enc = enc[:-1]
    return unpack_frame(cobs_decode(enc), max_payload)


# --------------------------------------------------------------------------- streaming
@dataclass
class DecoderCounters:
    """What the streaming decoder has seen."""

    bytes_in: int = 0
    frames: int = 0          # good frames yielded
    crc_errors: int = 0
    cobs_errors: int = 0
    length_errors: int = 0   # too short / too long / length field mismatch / overflow
    discarded_bytes: int = 0  # bytes of broken frames

    @property
    def errors(self) -> int:
        return self.crc_errors + self.cobs_errors + self.length_errors


@dataclass
class FrameDecoder:
    """Streaming receiver: bytes in any chunking -> whole, checked frames.

    :meth:`feed` never raises; broken frames are counted in :attr:`counters` and dropped.
    :meth:`feed_events` also returns the FrameError of each broken frame (the device endpoint
    uses it to answer BAD_CRC). An over-long run without delimiter is dropped up to the next
    0x00.
    """

    max_payload: int = MAX_PAYLOAD
    counters: DecoderCounters = field(default_factory=DecoderCounters)
    _buf: bytearray = field(default_factory=bytearray, repr=False)
    _skipping: bool = field(default=False, repr=False)

    def reset(self) -> None:
        """Forget a partially received frame (counters are kept)."""
        self.counters.discarded_bytes += len(self._buf)
        self._buf.clear()
        self._skipping = False

    @property
    def pending(self) -> int:
        """Bytes buffered of an incomplete frame."""
        return len(self._buf)

    def feed(self, data: bytes) -> list[Frame]:
        """Add bytes; return the good frames completed by them, in order."""
        return [e for e in self.feed_events(data) if isinstance(e, Frame)]

    def feed_events(self, data: bytes) -> list[Frame | FrameError]:
        """Add bytes; return completed frames and the errors of broken ones, in order."""
        limit = max_encoded_size(self.max_payload)
        self.counters.bytes_in += len(data)
        buf = self._buf
        buf += data
        events: list[Frame | FrameError] = []
        start = 0
        while True:
            idx = buf.find(0, start)
            if idx < 0:
                break
            chunk = bytes(buf[start:idx])
            start = idx + 1
            if self._skipping:
                self._skipping = False
                self.counters.discarded_bytes += len(chunk)
                continue
            if not chunk:
                continue
            try:
                if len(chunk) > limit:
                    raise FrameLengthError(f"frame of {len(chunk)} encoded bytes exceeds {limit}")
                frame = unpack_frame(cobs_decode(chunk), self.max_payload)
            except FrameError as exc:
                self._count(exc)
                self.counters.discarded_bytes += len(chunk)
                if exc.header is None:
                    exc.header = peek_header(chunk)
                events.append(exc)
            else:
                self.counters.frames += 1
                events.append(frame)
        del buf[:start]
        if len(buf) > limit:
            overlong = FrameLengthError(f"more than {limit} bytes without a frame delimiter")
            self._count(overlong)
            self.counters.discarded_bytes += len(buf)
            buf.clear()
            self._skipping = True
            events.append(overlong)
        return events

    def _count(self, exc: FrameError) -> None:
        if isinstance(exc, CrcError):
            self.counters.crc_errors += 1
        elif isinstance(exc, CobsError):
            self.counters.cobs_errors += 1
        else:
            self.counters.length_errors += 1
