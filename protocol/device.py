"""Board side of the framed protocol: framing, checks, dedupe, counters around a handler.

The firmware (or the emulator, or a test) supplies ``handler(request) -> reply``; it may raise
:class:`~snan_hil.protocol.errors.BoardError` (or a subclass) to refuse, which becomes an ERROR
reply. :class:`DeviceEndpoint` is sans-IO (``feed(bytes) -> bytes``); :meth:`serve` and
:class:`DeviceServer` run it on a transport.

Per received frame, in this order:

1. broken frame (CRC, COBS or length error, an over-long run without delimiter) -> counted and
   answered with a NAK: ERROR BAD_FRAME with seq 0, request type 0 and ``detail`` = the
   :class:`~snan_hil.protocol.errors.NakReason`; nothing of a damaged frame is trusted (the
   host resends its outstanding request at once);
2. version != PROTOCOL_VERSION -> ERROR BAD_VERSION (``detail`` = our version);
3. seq found in the reply cache with the same type, nonce and payload -> the cached reply is
   sent again (flag FROM_CACHE) and the request is NOT executed (counter ``duplicates``);
4. not a request type (or one the handler's ``serves(type)`` declines: an optional
   request the board does not implement) -> ERROR UNKNOWN_TYPE;
5. nonce != 0 and != the current boot nonce (HELLO exempt) -> ERROR NONCE_MISMATCH, not executed;
6. payload does not decode -> ERROR MALFORMED;
7. SPIKE_BATCH whose reply would exceed the max payload -> ERROR OUT_OF_RANGE, not executed;
8. HELLO clears the reply cache (a new session); then the handler runs; its reply (or ERROR) is
   cached under seq (except BUSY) and sent.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import threading
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass

from snan_hil.protocol.errors import (BoardError, CobsError, CrcError, ErrorCode, FrameError,
                                      MessageError, NakReason, ProtocolError, TransportError)
from snan_hil.protocol.frames import (FLAG_FROM_CACHE, Frame, FrameDecoder, encode_frame)
from snan_hil.protocol.messages import (MAX_PAYLOAD, MAX_TEXT, PROTOCOL_VERSION, REQUEST_TYPES,
                                        ErrorReply, Hello, Info, Reply, Request, ResetReply,
                                        SpikeBatch, StatusReply, spike_batch_reply_size)
from snan_hil.protocol.transport import Transport

__all__ = ["Handler", "DeviceCounters", "DeviceEndpoint", "DeviceServer", "NAK_TEXT",
           "nak_reason", "nak_reply"]

log = logging.getLogger(__name__)

NAK_TEXT = {NakReason.CRC: "damaged frame: CRC mismatch",
            NakReason.COBS: "damaged frame: bad COBS encoding",
            NakReason.LENGTH: "damaged frame: wrong length"}
"""The message text of each NAK (the reference texts; the text is for humans only)."""

def nak_reason(error: FrameError) -> NakReason:
    """The NAK ``detail`` of a damaged frame: CRC, COBS, or length (everything else)."""
    if isinstance(error, CrcError):
        return NakReason.CRC
    return NakReason.COBS if isinstance(error, CobsError) else NakReason.LENGTH


def nak_reply(error: FrameError) -> ErrorReply:
    """The NAK's message: ERROR BAD_FRAME, request type 0, ``detail`` the reason (sent with
    seq 0 and flags 0: nothing of a damaged frame is trusted)."""
    reason = nak_reason(error)
    return ErrorReply(ErrorCode.BAD_FRAME, 0, reason, NAK_TEXT[reason])


Handler = Callable[[Request[Reply]], Reply]
"""Firmware entry point: request -> reply of type ``request.REPLY`` (or raise BoardError)."""


@dataclass
class DeviceCounters:
    """Link counters of the board side (reported in STATUS)."""

    bytes_in: int = 0
    bytes_out: int = 0
    frames_in: int = 0          # good frames received
    frames_out: int = 0
    crc_errors: int = 0
    framing_errors: int = 0     # COBS / length errors
    malformed: int = 0
    unknown_types: int = 0
    duplicates: int = 0         # answered from the reply cache, not executed
    refusals: int = 0           # ERROR replies (handler refusals and protocol errors)
    nonce_mismatches: int = 0
    version_errors: int = 0
    executed: int = 0           # handler calls


class DeviceEndpoint:
    """Sans-IO board endpoint wrapping a firmware ``handler``.

    ``boot_nonce``: an int (kept here; a RESET reply's ``new_nonce`` replaces it), a callable
    returning the firmware's current nonce (called for every reply; the emulator should pass
    one, seeded), or None for a random one. Nonces must be non-zero (0 in a request means "any
    board"). ``cache_size``: replies
    remembered for dedupe (the host has one request outstanding, so a few suffice).
    """

    def __init__(self, handler: Handler, *, boot_nonce: int | Callable[[], int] | None = None,
                 cache_size: int = 16, max_payload: int = MAX_PAYLOAD, name: str = "device"):
        self.handler = handler
        self.name = name
        self.max_payload = max_payload
        self.cache_size = max(1, cache_size)
        if boot_nonce is None:  # a real board draws a fresh non-zero nonce at every boot
            boot_nonce = int.from_bytes(os.urandom(4), "little") or 1
        self._nonce = boot_nonce
        self.counters = DeviceCounters()
        self._decoder = FrameDecoder(max_payload)
        self._cache: OrderedDict[int, tuple[tuple[int, int, bytes], Frame]] = OrderedDict()
        self._lock = threading.Lock()

    # ------------------------------------------------------------------ state
    @property
    def boot_nonce(self) -> int:
        """The nonce put in reply headers."""
        return int(self._nonce() if callable(self._nonce) else self._nonce)

    @boot_nonce.setter
    def boot_nonce(self, value: int) -> None:
        self._nonce = value

    def reset_counters(self) -> None:
        """Zero the link counters (RESET does this)."""
        self.counters = DeviceCounters()

    def clear_cache(self) -> None:
        """Forget cached replies (HELLO does this)."""
        self._cache.clear()

    # ------------------------------------------------------------------ sans-IO core
    def feed(self, data: bytes) -> bytes:
        """Process received bytes; return the bytes to send back (possibly empty)."""
        with self._lock:
            self.counters.bytes_in += len(data)
            out = []
            for event in self._decoder.feed_events(data):
                reply = self._on_event(event)
                if reply is not None:
                    wire = encode_frame(reply)
                    self.counters.frames_out += 1
                    self.counters.bytes_out += len(wire)
                    out.append(wire)
            return b"".join(out)

    def _on_event(self, event: Frame | FrameError) -> Frame | None:
        if isinstance(event, FrameError):
            return self.nak(event)
        return self.handle_frame(event)

    def nak(self, error: FrameError) -> Frame:
        """The NAK for a damaged frame: ERROR BAD_FRAME, seq 0, request type 0, ``detail`` the
        NakReason (nothing of the damaged header is trusted); counted as a CRC or framing
        error and as a refusal."""
        reason = nak_reason(error)
        if reason == NakReason.CRC:
            self.counters.crc_errors += 1
        else:
            self.counters.framing_errors += 1
        return self._error(0, ErrorCode.BAD_FRAME, 0, reason, NAK_TEXT[reason])

    def handle_frame(self, frame: Frame) -> Frame | None:
        """Answer one checked frame (see the module docstring for the order of checks)."""
        self.counters.frames_in += 1
        if frame.version != PROTOCOL_VERSION:
            self.counters.version_errors += 1
            return self._error(frame.seq, ErrorCode.BAD_VERSION, frame.type, PROTOCOL_VERSION,
                               f"protocol version {frame.version} not supported, "
                               f"board speaks {PROTOCOL_VERSION}")
        key = (frame.type, frame.nonce, frame.payload)
        cached = self._cache.get(frame.seq)
        if cached is not None and cached[0] == key:
            self.counters.duplicates += 1
            return dataclasses.replace(cached[1], flags=cached[1].flags | FLAG_FROM_CACHE)
        cls = REQUEST_TYPES.get(frame.type)
        serves = getattr(self.handler, "serves", None)   # a board serving fewer types
        if cls is None or (serves is not None and not serves(frame.type)):
            self.counters.unknown_types += 1
            return self._error(frame.seq, ErrorCode.UNKNOWN_TYPE, frame.type, frame.type,
                               f"unknown request type 0x{frame.type:02x}")
        nonce = self.boot_nonce
        if frame.nonce not in (0, nonce) and cls is not Hello:
            self.counters.nonce_mismatches += 1
            return self._error(frame.seq, ErrorCode.NONCE_MISMATCH, frame.type, frame.nonce,
                               "request from before the last reset; not executed")
        try:
            request = cls.decode(frame.payload)
            assert isinstance(request, Request)      # REQUEST_TYPES holds request classes
        except MessageError as exc:
            self.counters.malformed += 1
            return self._error(frame.seq, ErrorCode.MALFORMED, frame.type, len(frame.payload),
                               str(exc))
        if isinstance(request, SpikeBatch):
            size = spike_batch_reply_size(request.n_spikes(), len(request.columns))
            if size > self.max_payload:
                return self._error(
                    frame.seq, ErrorCode.OUT_OF_RANGE, frame.type, size,
                    f"reply of {size} bytes would exceed max payload {self.max_payload}; "
                    "split the window")
        if isinstance(request, Hello):
            self.clear_cache()
        reply_frame = self._execute(frame, request)
        if not (reply_frame.type == ErrorReply.TYPE
                and ErrorReply.decode(reply_frame.payload).code == ErrorCode.BUSY):
            self._cache[frame.seq] = (key, reply_frame)
            self._cache.move_to_end(frame.seq)
            while len(self._cache) > self.cache_size:
                self._cache.popitem(last=False)
        return reply_frame

    def _execute(self, frame: Frame, request: Request[Reply]) -> Frame:
        self.counters.executed += 1
        try:
            reply = self.handler(request)
            if not isinstance(reply, (request.REPLY, ErrorReply)):
                raise TypeError(f"handler returned {type(reply).__name__} for "
                                f"{type(request).__name__}")
        except BoardError as exc:
            return self._error(frame.seq, exc.code, frame.type, exc.detail, str(exc))
        except ProtocolError as exc:
            return self._error(frame.seq, ErrorCode.INTERNAL, frame.type, 0, str(exc))
        except Exception as exc:  # noqa: BLE001 - a firmware bug must not kill the link
            log.exception("%s: handler failed on %s", self.name, type(request).__name__)
            return self._error(frame.seq, ErrorCode.INTERNAL, frame.type, 0,
                               f"{type(exc).__name__}: {exc}")
        if isinstance(reply, ErrorReply):
            self.counters.refusals += 1
        if isinstance(reply, ResetReply) and not callable(self._nonce):
            self._nonce = reply.new_nonce
        nonce = self.boot_nonce
        if isinstance(reply, StatusReply):
            reply = dataclasses.replace(
                reply, **{f: getattr(self.counters, f) for f in StatusReply.LINK_FIELDS})
        elif isinstance(reply, Info):
            reply = dataclasses.replace(reply, boot_nonce=nonce,
                                        max_payload=min(reply.max_payload, self.max_payload))
        try:
            out = Frame.of(reply, frame.seq, nonce)
        except ProtocolError as exc:
            return self._error(frame.seq, ErrorCode.INTERNAL, frame.type, 0,
                               f"reply does not encode: {exc}")
        if len(out.payload) > self.max_payload:
            return self._error(frame.seq, ErrorCode.INTERNAL, frame.type, len(out.payload),
                               "reply exceeds the max payload")
        if isinstance(reply, ResetReply):
            self.reset_counters()
        return out

    def _error(self, seq: int, code: ErrorCode, request_type: int, detail: int,
               message: str) -> Frame:
        self.counters.refusals += 1
        raw = message.encode("utf-8")[:MAX_TEXT].decode("utf-8", "ignore")
        err = ErrorReply(ErrorCode(code), request_type & 0xFF, int(detail) & 0xFFFFFFFF, raw)
        return Frame.of(err, seq & 0xFFFF, self.boot_nonce)

    # ------------------------------------------------------------------ I/O loop
    def serve(self, transport: Transport, stop: threading.Event | None = None,
              poll_s: float = 0.05) -> None:
        """Answer requests arriving on ``transport`` until ``stop`` is set or it fails."""
        while stop is None or not stop.is_set():
            try:
                data = transport.read(65536, poll_s)
                if data:
                    out = self.feed(data)
                    if out:
                        transport.write(out)
            except TransportError as exc:
                if stop is None or not stop.is_set():
                    log.info("%s: transport ended: %s", self.name, exc)
                return


class DeviceServer:
    """Runs :meth:`DeviceEndpoint.serve` in a daemon thread; ``stop()`` ends and joins it."""

    def __init__(self, endpoint: DeviceEndpoint, transport: Transport, poll_s: float = 0.02):
        self.endpoint, self.transport = endpoint, transport
        self._stop = threading.Event()
        self._thread = threading.Thread(target=endpoint.serve, args=(transport, self._stop, poll_s),
                                        name=f"{endpoint.name} server", daemon=True)
        self._thread.start()

    def stop(self, close_transport: bool = True) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        if close_transport:
            self.transport.close()

    def __enter__(self) -> "DeviceServer":
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
