"""Host side of the legacy line protocol: :class:`LegacyClient`, a better host for boards running
the existing firmware, with the board command surface of
:class:`~snan_hil.protocol.client.BoardClient`.

It speaks the requests the line protocol has - HELLO (the connect probe, then mode 100),
READ_CELL (mode 9) and WRITE_PULSE (mode 7) - and refuses the others with
:class:`~snan_hil.protocol.errors.UnsupportedError`. The old protocol has no checksum and no
duplicate detection: a resent mode-7 line applies the pulse again. The client therefore never
resends a write: when a write's reply is lost (or arrives with another id) it reads the cell
(mode 9, safe to repeat) and returns that reading as the "read after", counting the write as
uncertain (the pulse was applied once or not at all, never twice).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator
from typing import TypeVar

from snan_hil.protocol.client import ClientBase, command_of
from snan_hil.protocol.errors import (FieldRangeError, LinkTimeoutError, MalformedPayloadError,
                                      ProtocolError, UnsupportedError, board_error)
from snan_hil.protocol.legacy_codec import (CONNECT_PROBE, ID_MODULUS, MAX_LINE, LegacyCounters,
                                            LegacyInfoRequest, LegacyPulse, LegacyRead,
                                            LegacyReply, format_request, next_id, parse_info,
                                            parse_reply, reported_info_fields)
from snan_hil.protocol.messages import (Hello, Info, Polarity, ReadCell, ReadCellReply, Reply,
                                        Request, WritePulse, WritePulseReply)
from snan_hil.protocol.transport import Transport

__all__ = ["PROBE_TRIES", "LegacyClient", "LegacyTimeoutError", "LegacyInfoError"]

log = logging.getLogger(__name__)

PROBE_TRIES = 20
"""Connect probes (``7,0,0,0,0,0,0,0``) the old host sends before it gives up."""

ReplyT = TypeVar("ReplyT", bound=Reply)


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
        super().__init__(transport)
        self.timeout, self.retries = float(timeout), int(retries)
        self.refusals = bool(refusals)
        self._id = (first_id - 1) % ID_MODULUS
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

    # ------------------------------------------------------------------ requests
    def request(self, req: Request[ReplyT]) -> ReplyT:
        """``req`` over the line protocol: HELLO, READ_CELL and WRITE_PULSE (see their
        methods below); any other request raises UnsupportedError."""
        reply = self._answer(req)
        accepted = req.accept(reply)
        if accepted is None:     # pragma: no cover - _answer builds the request's reply type
            raise ProtocolError(f"legacy client built {reply!r} for {req!r}")
        return accepted

    def _answer(self, req: Request[Reply]) -> Reply:
        if isinstance(req, Hello):
            return self._hello()
        if isinstance(req, ReadCell):
            return ReadCellReply(self._read_cell(req.row, req.col, req.dac_code))
        if isinstance(req, WritePulse):
            return WritePulseReply(self._write_pulse(req))
        spec = command_of(req)
        raise self.unsupported(spec.name if spec else type(req).__name__)

    def unsupported(self, what: str) -> UnsupportedError:
        return UnsupportedError(f"{what} is not available over the legacy line protocol "
                                f"(board on {self.name}); use --protocol framed")

    def _hello(self) -> Info:
        """Connect probe, then mode 100 (sent up to ``1 + retries`` times); an Info
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

    @property
    def constants(self) -> Info:
        """The board's Info, or the client's ``defaults`` before HELLO."""
        return self.info or self.defaults

    @property
    def post_pulse_read_code(self) -> int:
        """Write-DAC code of the board's own read after a mode-7 pulse (its fixed read
        voltage, ``legacy_read_code``: 246 on MemriCore); what ``write_pulse(...,
        read_code=0)`` returns a reading at."""
        return self.constants.legacy_read_code

    def _read_cell(self, row: int, col: int, vol: int) -> int:
        """Mode 9; resent (new id) up to ``retries`` times; any of this call's ids is accepted."""
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

    def _write_pulse(self, req: WritePulse) -> int:
        """Mode 7 once, then the ADC code of the cell read after it.

        ``read_code`` 0: the board's own read after the pulse (at ``post_pulse_read_code``);
        another code: one more read (mode 9) at that code, since the old firmware cannot
        read after a pulse at a chosen voltage. The reply is awaited for ``timeout`` plus the
        pulse width. If it is lost, or comes with another id, the pulse is NOT resent: the cell
        is read (mode 9) instead and the write counted as uncertain.
        """
        row, col, amplitude_code, width_us = req.row, req.col, req.amplitude_code, req.width_us
        if amplitude_code <= 0:
            raise FieldRangeError("amplitude_code must be > 0 (0 means read-only in mode 7)")
        if int(width_us) < 0:
            raise FieldRangeError(f"pulse width {width_us} us must be >= 0")
        t_ms, t_us = divmod(int(width_us), 1000)
        sign = int(Polarity(req.polarity))
        # every field checked (FieldRangeError) before an id is used or anything is sent
        format_request(LegacyPulse(int(amplitude_code), t_ms, t_us, sign, 0, col, row))
        self.counters.requests += 1
        self._flush()
        id_ = self._new_id()
        self._send(format_request(LegacyPulse(int(amplitude_code), t_ms, t_us, sign, id_, col,
                                              row)))
        wait = self.timeout + int(width_us) * 1e-6
        heard = _Heard()
        reply = self._await_reply({id_}, time.monotonic() + wait, heard)
        read_code = req.read_code or self.post_pulse_read_code
        if reply is None:
            self.counters.timeouts += 1
            self.counters.uncertain_writes += 1
            log.warning("%s: no reply with id %d to the write pulse on (%d, %d)%s; not resending "
                        "it, reading the cell instead", self.name, id_, row, col,
                        f" ({heard.text()})" if heard.text() else "")
            return self._read_cell(row, col, req.read_code or self.constants.read_code)
        if req.read_code and req.read_code != self.post_pulse_read_code:
            return self._read_cell(row, col, read_code)
        return reply.adc
