"""Board side of the legacy line protocol: :class:`LegacyDevice` handles lines as the
existing firmware does, around a request handler (the emulator's dispatcher, or a test board).

What the existing firmware does with each line (fields, clamps, silence) is read in
:mod:`snan_hil.protocol.legacy_codec` and docs/protocol.md section 9.1.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

from snan_hil.protocol.errors import BoardError, ErrorCode, MalformedPayloadError, ProtocolError
from snan_hil.protocol.legacy_codec import (MAX_LINE, LegacyCounters, LegacyInfoRequest,
                                            LegacyPulse, format_info, format_reply,
                                            parse_request)
from snan_hil.protocol.messages import (Hello, Info, Polarity, ReadCell, ReadCellReply, Reply,
                                        Request, WritePulse, WritePulseReply)

__all__ = ["LegacyDevice"]

log = logging.getLogger(__name__)


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

    def __init__(self, handler: Callable[[Request[Reply]], Reply], name: str = "legacy device", *,
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
        msg: Request[Reply]
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
