"""Typed errors of the protocol layer.

Everything the protocol can raise derives from :class:`ProtocolError`, itself a
:class:`snan_hil.common.errors.UserError`, so an error that reaches the CLI prints one line. The
failures of the board or the link (timeouts, the port gone, a reset, busy, another protocol
version, a firmware fault) are also :class:`~snan_hil.common.errors.BoardLinkError`: exit code 3,
where the user's mistakes (a value out of range, a request the protocol lacks) exit with 2.
The hierarchy:

- :class:`FieldRangeError` — a message field does not fit its wire type (also a ``ValueError``).
- :class:`FrameError` — a received frame is broken (COBS, length, CRC); the streaming decoder
  counts these and never lets them escape from :meth:`FrameDecoder.feed`.
- :class:`MessageError` — a frame is whole but its type is unknown or its payload malformed.
- :class:`LinkError` — the conversation failed: timeout after retries, board reset under us,
  protocol version mismatch, transport cannot be opened, request not supported by the board.
- :class:`BoardError` — the board refused a request (an ERROR reply); raised by firmware
  handlers to refuse and re-raised on the host from the ERROR reply. Carries an :class:`ErrorCode`.
"""

from __future__ import annotations

from enum import IntEnum

from snan_hil.common.errors import BoardLinkError, UserError


class ErrorCode(IntEnum):
    """Codes carried by an ERROR reply (one byte on the wire)."""

    BAD_FRAME = 1       # NAK: the board received a damaged frame (CRC, COBS or length);
    #                     nothing was executed; sent with seq 0, detail = a NakReason
    BAD_CRC = 1         # the old name of BAD_FRAME (an alias)
    UNKNOWN_TYPE = 2    # the message type is not known to this board
    MALFORMED = 3       # payload length/contents do not match the message type
    OUT_OF_RANGE = 4    # row, column, code or width outside what the board has
    SAFETY_LIMIT = 5    # read above max read voltage, write above max write voltage, compliance
    BUSY = 6            # the board cannot take the request now; retry later
    BAD_VERSION = 7     # frame protocol version not supported
    NONCE_MISMATCH = 8  # the request carries the boot nonce of an earlier boot: not executed
    UNSUPPORTED = 9     # a known but optional request this board does not implement
    INTERNAL = 10       # firmware fault while executing


class NakReason(IntEnum):
    """``detail`` of a BAD_FRAME (NAK): which check the damaged frame failed."""

    CRC = 1             # COBS and length consistent, CRC-16 wrong
    COBS = 2            # a COBS group runs past the end of the frame
    LENGTH = 3          # shorter than a header + CRC, length field != bytes received, payload
    #                     above the maximum, or more bytes than the largest frame without 0x00


class ProtocolError(UserError):
    """Base of every error raised by :mod:`snan_hil.protocol`."""


class FieldRangeError(ProtocolError, ValueError):
    """A message field value does not fit its wire representation (raised when encoding)."""


# --------------------------------------------------------------------------- frames
class FrameError(ProtocolError):
    """A received frame is broken. ``kind`` names the check that failed."""

    kind = "frame"

    def __init__(self, message: str, header: tuple[int, int, int, int, int] | None = None):
        super().__init__(message)
        #: (version, flags, type, seq, nonce) when the header could be parsed, else None.
        self.header = header


class CobsError(FrameError):
    """The COBS encoding of a frame is invalid."""

    kind = "cobs"


class FrameLengthError(FrameError):
    """Frame too short, too long, or its length field disagrees with the bytes received."""

    kind = "length"


class CrcError(FrameError):
    """The CRC-16 of a frame does not match its contents."""

    kind = "crc"


# --------------------------------------------------------------------------- messages
class MessageError(ProtocolError):
    """A whole frame whose message could not be decoded."""


class UnknownTypeError(MessageError):
    """The message type code is not in the registry."""


class MalformedPayloadError(MessageError):
    """The payload does not match the layout of its message type."""


# --------------------------------------------------------------------------- link
class LinkError(ProtocolError):
    """The conversation with the board failed."""


class TransportError(LinkError, BoardLinkError):
    """The transport (serial port, socket, pty, pipe) cannot be opened, read or written."""


class LinkTimeoutError(LinkError, BoardLinkError):
    """The link gave up on a request (docs/protocol.md section 4, "Giving up"). ``kind`` says
    which failure it was (the message says it in words):

    * ``"silent"`` - not one byte came back since the session began (power, cable, wrong port);
    * ``"stalled"`` - the board had answered, then the line stayed silent longer than the
      user's ``--timeout`` for one request, or this run's stalls exceeded its budget;
    * ``"garbled"`` - bytes came back, but never a valid frame (wrong baud rate, a board
      speaking another protocol, a line that corrupts everything);
    * ``"corrupting"`` - the board answered (NAKs, other valid frames) but no intact reply
      got through within the link's time budget (a very noisy line);
    * ``"stale"`` - only replies to other requests came back (another program on the port, a
      board replaying old replies);
    * ``"echo"`` - the port sent the request back unchanged (a loopback, not a board).

    Only ``garbled`` and ``corrupting`` are :attr:`retryable`: asking again (a new request)
    can get through a damaged line; after the others it only delays the error.
    """

    KINDS = ("silent", "stalled", "garbled", "corrupting", "stale", "echo")
    #: The kinds that sending the request again (as a new request) can cure: a damaged line.
    RETRYABLE = ("garbled", "corrupting")

    def __init__(self, message: str, kind: str = "silent"):
        super().__init__(message)
        self.kind = kind if kind in self.KINDS else "silent"

    @property
    def retryable(self) -> bool:
        """Whether asking again (a new request) may get through: the line damages frames
        (``garbled``, ``corrupting``); not a silent or stalled line, an echo, stale replies."""
        return self.kind in self.RETRYABLE


class BoardBusyError(LinkError, BoardLinkError):
    """The board (or the server in front of it) answered BUSY to every try: another client is
    being served. ``detail`` is the board's ERROR detail, the message names the other client
    where the server knows it."""


class BoardResetError(LinkError, BoardLinkError):
    """The board's boot nonce changed: it was reset (or power-cycled) under the host.

    The host must re-synchronise (``client.hello()``) and re-check any state it assumed.
    """

    def __init__(self, message: str, old_nonce: int | None = None, new_nonce: int | None = None):
        super().__init__(message)
        self.old_nonce = old_nonce
        self.new_nonce = new_nonce


class VersionMismatchError(LinkError, BoardLinkError):
    """The board speaks another protocol version than this host."""


class UnsupportedError(LinkError):
    """The request is not available over this link/protocol (e.g. SPIKE_BATCH over legacy)."""


# --------------------------------------------------------------------------- board refusals
class BoardError(ProtocolError):
    """The board refused or failed a request (an ERROR reply).

    Firmware handlers raise it (or a subclass) to refuse a request; the device endpoint turns
    it into an ERROR reply, and the host client re-raises the matching subclass.
    """

    default_code = ErrorCode.INTERNAL

    def __init__(self, message: str, code: ErrorCode | int | None = None, detail: int = 0,
                 request_type: int = 0):
        super().__init__(message)
        self.code = ErrorCode(code) if code is not None else self.default_code
        self.detail = int(detail)
        self.request_type = int(request_type)


class OutOfRangeError(BoardError):
    """Row, column, code or width outside the board's range."""

    default_code = ErrorCode.OUT_OF_RANGE


class SafetyLimitError(BoardError):
    """A read or write would exceed a safety limit (voltage or compliance current)."""

    default_code = ErrorCode.SAFETY_LIMIT


class BusyError(BoardError):
    """The board is busy; the request was not executed."""

    default_code = ErrorCode.BUSY


class UnsupportedRequestError(BoardError):
    """The board does not implement this request type."""

    default_code = ErrorCode.UNSUPPORTED


class MalformedRequestError(BoardError):
    """The board could not parse the request."""

    default_code = ErrorCode.MALFORMED


class InternalBoardError(BoardError, BoardLinkError):
    """The board failed while executing the request (INTERNAL, or a code this host does not
    know): a fault of the board, not of the request."""

    default_code = ErrorCode.INTERNAL


_BY_CODE: dict[ErrorCode, type[BoardError]] = {
    ErrorCode.OUT_OF_RANGE: OutOfRangeError,
    ErrorCode.SAFETY_LIMIT: SafetyLimitError,
    ErrorCode.BUSY: BusyError,
    ErrorCode.UNSUPPORTED: UnsupportedRequestError,
    ErrorCode.UNKNOWN_TYPE: UnsupportedRequestError,
    ErrorCode.MALFORMED: MalformedRequestError,
    ErrorCode.INTERNAL: InternalBoardError,
}


def board_error(code: ErrorCode | int, message: str, detail: int = 0,
                request_type: int = 0) -> BoardError:
    """The :class:`BoardError` subclass matching ``code`` (unknown codes give the base class)."""
    try:
        code = ErrorCode(code)
    except ValueError:
        return InternalBoardError(f"board error code {int(code)}: {message}",
                                  ErrorCode.INTERNAL, detail, request_type)
    cls = _BY_CODE.get(code, BoardError)
    return cls(message, code, detail, request_type)
