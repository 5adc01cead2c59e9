"""Host side of the framed protocol: a reliable request/response client.

One request is outstanding at a time (stop-and-wait). Per request:

- a new sequence number; the input buffer is flushed first (stale bytes from earlier requests);
- the frame is sent (a HELLO preceded by one 0x00, which ends any half frame an earlier
  session left in the board's receive buffer); if no valid reply arrives within the
  request's time budget it is resent with the SAME sequence number (flag RETRANSMIT,
  preceded by one 0x00 to flush a half frame on the board), at most ``retries`` times, then
  :class:`LinkTimeoutError`;
- a board ERROR BAD_CRC for this seq triggers an immediate resend; BUSY a resend after a short
  backoff; both use up the retry budget;
- replies with another seq (late or duplicated) are discarded and counted;
- the boot nonce learned at HELLO is sent in every request header and checked in every reply:
  a different nonce (or a NONCE_MISMATCH error) raises :class:`BoardResetError`; the client keeps
  the old nonce, so every later request fails the same way until the caller calls ``hello()``;
- other ERROR replies raise the matching :class:`BoardError` subclass.

The per-request time budget is ``timeout`` + twice the wire time of request and expected reply
at the transport's baud + an estimate of the board's execution time (pulse widths, spikes).
"""

from __future__ import annotations

import dataclasses
import logging
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass

from snan_hil.protocol.client import ClientBase, SpikeBatchResult
from snan_hil.protocol.errors import (BoardResetError, ErrorCode, FieldRangeError,
                                      LinkTimeoutError, MalformedPayloadError, MessageError,
                                      ProtocolError, UnsupportedError, VersionMismatchError,
                                      board_error)
from snan_hil.protocol.frames import (FLAG_RETRANSMIT, Frame, FrameDecoder, encode_frame,
                                      wire_size)
from snan_hil.protocol.messages import (MAX_PAYLOAD, PROTOCOL_VERSION, Capability, Clock,
                                        ClockReply, ErrorReply, Hello, Info, Polarity,
                                        ProgramCell, ProgramCellReply, ReadCell, ReadColumn,
                                        Reply, Request, Reset, ResetReply, SpikeBatch,
                                        SpikeBatchReply, SpikeGroup, Status, StatusReply,
                                        WritePulse, spike_batch_reply_size)
from snan_hil.protocol.transport import Transport, wire_seconds

__all__ = ["LinkCounters", "LinkClient", "DEFAULT_TIMEOUT_S", "DEFAULT_RETRIES"]

log = logging.getLogger(__name__)

DEFAULT_TIMEOUT_S = 0.5
DEFAULT_RETRIES = 3
_NAMES = {cls.TYPE: cls.__name__ for cls in (Hello, ReadCell, ReadColumn, WritePulse,
                                              SpikeBatch, ProgramCell, Status, Clock, Reset)}


@dataclass
class LinkCounters:
    """Host-side link counters."""

    requests: int = 0           # requests issued (each with a new seq)
    frames_sent: int = 0
    retries: int = 0            # retransmissions with the same seq
    timeouts: int = 0           # attempts that got no valid reply in time
    crc_errors: int = 0         # reply frames dropped for a bad CRC
    framing_errors: int = 0     # reply frames dropped for COBS/length errors
    bad_crc_reported: int = 0   # the board reported our frame as corrupted
    busy: int = 0               # BUSY replies
    stale_replies: int = 0      # replies for another seq (late/duplicate), discarded
    unexpected_replies: int = 0  # right seq but wrong type or undecodable payload
    board_errors: int = 0       # ERROR replies raised to the caller
    resets_detected: int = 0    # boot nonce changes seen
    bytes_out: int = 0
    bytes_in: int = 0


class _Retry:
    def __init__(self, backoff: bool):
        self.backoff = backoff


class LinkClient(ClientBase):
    """Reliable framed-protocol client over any :class:`Transport`.

    ``timeout`` (s): base reply timeout per attempt; ``retries``: resends after the first try;
    ``first_seq``: first sequence number (default: random, so a new session never collides with
    the board's reply cache of an earlier one); ``max_payload``: our receive/send limit (the
    board's Info may lower it).
    """

    #: How often spike_batch may halve a window chunk whose reply keeps getting lost.
    MAX_SPIKE_SPLITS = 32

    def __init__(self, transport: Transport, *, timeout: float = DEFAULT_TIMEOUT_S,
                 retries: int = DEFAULT_RETRIES, first_seq: int | None = None,
                 max_payload: int = MAX_PAYLOAD, busy_backoff_s: float = 0.005):
        self.transport = transport
        self.timeout = float(timeout)
        self.retries = int(retries)
        self.max_payload = int(max_payload)
        self.busy_backoff_s = busy_backoff_s
        self.info: Info | None = None
        self.boot_nonce: int | None = None
        self.counters = LinkCounters()
        self._decoder = FrameDecoder(self.max_payload)
        if first_seq is None:
            first_seq = int.from_bytes(os.urandom(2), "little")
        self._seq = first_seq & 0xFFFF

    # ------------------------------------------------------------------ generic request
    def next_seq(self) -> int:
        """Sequence number the next request will use."""
        return self._seq

    def request(self, req: Request, *, timeout: float | None = None,
                retries: int | None = None) -> Reply:
        """Send ``req`` and return its reply (type ``req.REPLY``); see the module docstring."""
        seq = self._seq
        self._seq = (self._seq + 1) & 0xFFFF
        self.counters.requests += 1
        payload = req.encode()
        limit = self._limit()
        if len(payload) > limit:
            raise FieldRangeError(f"{type(req).__name__} payload of {len(payload)} bytes exceeds "
                                  f"the max payload {limit}")
        nonce = 0 if isinstance(req, Hello) or self.boot_nonce is None else self.boot_nonce
        frame = Frame(req.TYPE, seq, payload, nonce)
        first = encode_frame(frame)
        if isinstance(req, Hello):
            # A new session: end any half frame the board still holds from an earlier one.
            first = b"\x00" + first
        again = b"\x00" + encode_frame(dataclasses.replace(frame, flags=FLAG_RETRANSMIT))
        budget = self._budget(req, len(first)) if timeout is None else float(timeout)
        tries = 1 + (self.retries if retries is None else int(retries))
        self._flush()
        last: str = "no reply"
        busy_rounds = 0
        for attempt in range(tries):
            if attempt:
                self.counters.retries += 1
            self._write(again if attempt else first)
            outcome = self._await(seq, req, time.monotonic() + budget)
            if isinstance(outcome, Reply):
                return outcome
            if outcome is None:
                self.counters.timeouts += 1
                self._decoder.reset()  # a half-received reply is garbage by now
                last = "no reply"
            elif outcome.backoff:
                last = "board busy"
                time.sleep(self.busy_backoff_s * (2 ** busy_rounds))
                busy_rounds += 1
            else:
                last = "board received corrupted frames"
        raise LinkTimeoutError(
            f"{last} from board on {self.name} to {_NAMES.get(req.TYPE, type(req).__name__)} "
            f"after {tries} tries ({budget:.2f} s each{self._baud_text()}); check cable, power "
            "and --baud, or use --protocol legacy for old firmware")

    def _baud_text(self) -> str:
        return f" at {self.transport.baud} baud" if self.transport.baud else ""

    def _limit(self) -> int:
        if self.info is not None:
            return min(self.max_payload, self.info.max_payload)
        return self.max_payload

    def _budget(self, req: Request, req_wire: int) -> float:
        reply_payload = 64
        exec_s = 0.0
        if isinstance(req, SpikeBatch):
            n = req.n_spikes()
            reply_payload = spike_batch_reply_size(n, len(req.columns))
            exec_s = n * 0.002 + (req.n_bins * req.bin_us * 1e-6 if req.paced else 0.0)
        elif isinstance(req, WritePulse):
            exec_s = req.width_us * 1e-6 + 0.002
        elif isinstance(req, ProgramCell):
            exec_s = req.max_pulses * (req.width_us * 1e-6 + 0.003)
        elif isinstance(req, Hello):
            reply_payload = 256
        wire = wire_seconds(req_wire + wire_size(reply_payload), self.transport.baud)
        return self.timeout + 2 * wire + exec_s

    def _flush(self) -> None:
        self.transport.reset_input_buffer()
        self._decoder.reset()

    def _write(self, data: bytes) -> None:
        self.transport.write(data)
        self.counters.frames_sent += 1
        self.counters.bytes_out += len(data)

    def _await(self, seq: int, req: Request, deadline: float) -> Reply | _Retry | None:
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return None
            data = self.transport.read(65536, remaining)
            if not data:
                if self.transport.synchronous:
                    return None
                continue
            self.counters.bytes_in += len(data)
            frames = self._decoder.feed(data)
            dc = self._decoder.counters
            self.counters.crc_errors = dc.crc_errors
            self.counters.framing_errors = dc.cobs_errors + dc.length_errors
            for frame in frames:
                outcome = self._check(frame, seq, req)
                if outcome is not None:
                    return outcome

    def _check(self, frame: Frame, seq: int, req: Request) -> Reply | _Retry | None:
        if frame.seq != seq:
            self.counters.stale_replies += 1
            return None
        if frame.version != PROTOCOL_VERSION:
            raise VersionMismatchError(
                f"board on {self.name} speaks protocol version {frame.version}, this host "
                f"speaks {PROTOCOL_VERSION}; update the board firmware or snan-hil")
        try:
            msg = frame.message()
        except MessageError as exc:
            self.counters.unexpected_replies += 1
            log.debug("%s: undecodable reply: %s", self.name, exc)
            return None
        if isinstance(msg, ErrorReply):
            if msg.code == ErrorCode.BAD_CRC:
                self.counters.bad_crc_reported += 1
                return _Retry(backoff=False)
            if msg.code == ErrorCode.BUSY:
                self.counters.busy += 1
                return _Retry(backoff=True)
            if msg.code == ErrorCode.BAD_VERSION:
                raise VersionMismatchError(
                    f"board on {self.name} speaks protocol version {msg.detail}, this host "
                    f"speaks {PROTOCOL_VERSION}; update the board firmware or snan-hil")
            if msg.code == ErrorCode.NONCE_MISMATCH:
                self._reset_detected(frame.nonce, "refused a request from before its reset")
            self._check_nonce(frame, req)
            self.counters.board_errors += 1
            name = _NAMES.get(req.TYPE, type(req).__name__)
            raise board_error(msg.code, f"board on {self.name} refused {name}: {msg.message}",
                              msg.detail, msg.request_type)
        if not isinstance(msg, req.REPLY):
            self.counters.unexpected_replies += 1
            return None
        if isinstance(req, Hello):
            if self.boot_nonce is not None and frame.nonce != self.boot_nonce:
                self.counters.resets_detected += 1
                log.info("%s: board boot nonce changed 0x%08x -> 0x%08x", self.name,
                         self.boot_nonce, frame.nonce)
            self.boot_nonce = frame.nonce
        elif isinstance(msg, ResetReply):
            if self.boot_nonce is not None and msg.old_nonce != self.boot_nonce:
                self._reset_detected(msg.old_nonce, "was reset before this RESET")
            self.boot_nonce = frame.nonce
        else:
            self._check_nonce(frame, req)
        return msg

    def _check_nonce(self, frame: Frame, req: Request) -> None:
        if self.boot_nonce is None:
            self.boot_nonce = frame.nonce
        elif frame.nonce != self.boot_nonce and not isinstance(req, Hello):
            self._reset_detected(frame.nonce, "answered with a new boot nonce")

    def _reset_detected(self, new: int, what: str) -> None:
        self.counters.resets_detected += 1
        old = self.boot_nonce
        raise BoardResetError(
            f"board on {self.name} {what} (boot nonce 0x{old or 0:08x} -> 0x{new:08x}): it was "
            "reset; call hello() to resynchronise and re-check its state", old, new)

    # ------------------------------------------------------------------ typed methods
    def hello(self) -> Info:
        """Open the session: learn the board's Info and boot nonce; checks the version."""
        info = self.request(Hello())
        assert isinstance(info, Info)
        if info.protocol_version != PROTOCOL_VERSION:
            raise VersionMismatchError(
                f"board on {self.name} speaks protocol version {info.protocol_version}, this "
                f"host speaks {PROTOCOL_VERSION}; update the board firmware or snan-hil")
        self.info = info
        return info

    def _read_code(self) -> int:
        return (self.info or Info()).read_code

    def read_cell(self, row: int, col: int, dac_code: int | None = None) -> int:
        """ADC code of one cell read at row-DAC ``dac_code`` (default: INFO's ``read_code``)."""
        code = self._read_code() if dac_code is None else dac_code
        self.limits.check_reads((code,), f"READ_CELL ({row}, {col})")
        return self.request(ReadCell(row, col, code)).adc  # type: ignore[attr-defined]

    def read_column(self, col: int, row_codes: Sequence[int]) -> int:
        """ADC code of a column multiply with row-DAC codes ``row_codes`` (one per row)."""
        self._need(Capability.READ_COLUMN, "READ_COLUMN")
        self.limits.check_reads(row_codes, f"READ_COLUMN {col}", dac="row")
        return self.request(ReadColumn(col, tuple(row_codes))).adc  # type: ignore[attr-defined]

    def write_pulse(self, row: int, col: int, polarity: Polarity, amplitude_code: int,
                    width_us: int, read_code: int = 0) -> int:
        """Apply one pulse (write-DAC code, us) and return the ADC code of the read after."""
        limits = self.limits
        limits.check_write(amplitude_code, f"WRITE_PULSE ({row}, {col})")
        limits.check_reads((read_code,), f"WRITE_PULSE ({row}, {col})")
        req = WritePulse(row, col, Polarity(polarity), amplitude_code, width_us, read_code)
        return self.request(req).adc  # type: ignore[attr-defined]

    def spike_batch(self, groups: Sequence[SpikeGroup], columns: Sequence[int],
                    n_bins: int = 1000, bin_us: int = 1000,
                    paced: bool = False) -> SpikeBatchResult:
        """Apply a decision window of spikes; per spike, read ``columns``.

        The window is split into as few SPIKE_BATCH requests as the max payload allows
        (``round_trips`` in the result). ``groups[g].bins`` are bin indices in ``0..n_bins-1``.
        """
        self._need(Capability.SPIKE_BATCH, "SPIKE_BATCH")
        groups = tuple(SpikeGroup(tuple((int(r), int(c)) for r, c in g.rows),
                                  tuple(int(b) for b in g.bins)) for g in groups)
        columns = tuple(int(c) for c in columns)
        _check_spike_window(groups, n_bins, bin_us, paced)
        self.limits.check_reads((c for g in groups for _r, c in g.rows), "SPIKE_BATCH",
                                dac="row")
        order = sorted((b, gi) for gi, g in enumerate(groups) for b in g.bins)
        if any(b < 0 or b >= n_bins for b, _ in order):
            raise FieldRangeError(f"spike bins must lie in 0..{n_bins - 1}")
        per_spike = 2 * len(columns)
        max_spikes = (self._limit() - spike_batch_reply_size(0, 0)) // max(1, per_spike)
        todo = _chunk_bins(order, n_bins, max_spikes)[::-1]
        spikes: list[tuple[int, int]] = []
        codes: list[tuple[int, ...]] = []
        round_trips, splits = 0, 0
        while todo:
            lo, hi = todo.pop()
            sub = tuple(SpikeGroup(g.rows, tuple(b - lo for b in g.bins if lo <= b < hi))
                        for g in groups)
            req = SpikeBatch(sub, columns, hi - lo, bin_us, lo, paced)
            round_trips += 1
            try:
                reply = self.request(req)
            except LinkTimeoutError:
                # A long reply that never gets through a noisy line: retry the chunk as two
                # halves (reads are non-destructive, so re-applying spikes is harmless).
                busy_bins = sorted({b for b, _ in order if lo <= b < hi})
                if len(busy_bins) < 2 or splits >= self.MAX_SPIKE_SPLITS:
                    raise
                splits += 1
                mid = busy_bins[len(busy_bins) // 2]
                log.info("%s: SPIKE_BATCH bins %d..%d lost; retrying as two halves",
                         self.name, lo, hi - 1)
                todo += [(mid, hi), (lo, mid)]
                continue
            assert isinstance(reply, SpikeBatchReply)
            expect = [(b + lo, gi) for b, gi in req.spike_order()]
            if (reply.first_bin != lo or len(reply.codes) != len(expect)
                    or reply.n_columns != len(columns)):
                raise MalformedPayloadError(
                    f"board on {self.name} answered SPIKE_BATCH for bins {lo}..{hi - 1} with "
                    f"{len(reply.codes)} spikes x {reply.n_columns} columns from bin "
                    f"{reply.first_bin}; expected {len(expect)} x {len(columns)} from {lo}")
            spikes.extend(expect)
            codes.extend(reply.codes)
        return SpikeBatchResult(tuple(spikes), columns, tuple(codes), round_trips)

    def program_cell(self, row: int, col: int, target_adc: int, tolerance_adc: int, *,
                     max_pulses: int = 100, amp_start_code: int = 0, amp_stop_code: int = 0,
                     amp_step_code: int = 0, width_us: int = 100, read_code: int = 0,
                     fine_tune: bool = True) -> ProgramCellReply:
        """Firmware write-and-verify of one cell (see :class:`ProgramCell`).

        Amplitude codes left at 0 mean the old host's ramp: 0.3 -> 1.2 V in 0.01 V steps.
        """
        limits = self.limits
        for code in (amp_start_code, amp_stop_code):
            limits.check_write(code, f"PROGRAM_CELL ({row}, {col})")
        limits.check_reads((read_code,), f"PROGRAM_CELL ({row}, {col})")
        self._need(Capability.PROGRAM_CELL, "PROGRAM_CELL")
        req = ProgramCell(row, col, target_adc, tolerance_adc, max_pulses, amp_start_code,
                          amp_stop_code, amp_step_code, width_us, read_code, fine_tune)
        reply = self.request(req)
        assert isinstance(reply, ProgramCellReply)
        return reply

    def status(self) -> StatusReply:
        """The board's counters."""
        reply = self.request(Status())
        assert isinstance(reply, StatusReply)
        return reply

    def clock(self) -> ClockReply:
        """Board time (us) and array energy (J) since boot/RESET."""
        self._need(Capability.CLOCK, "CLOCK")
        reply = self.request(Clock())
        assert isinstance(reply, ClockReply)
        return reply

    def reset(self) -> ResetReply:
        """Soft-reset the board (clock, energy, counters; new boot nonce, learned here)."""
        self._need(Capability.RESET, "RESET")
        reply = self.request(Reset())
        assert isinstance(reply, ResetReply)
        if self.info is not None:
            self.info = dataclasses.replace(self.info, boot_nonce=reply.new_nonce)
        return reply

    def _need(self, cap: Capability, what: str) -> None:
        if self.info is not None and not self.info.has(cap):
            raise UnsupportedError(f"board on {self.name} does not implement {what}")


def _chunk_bins(order: list[tuple[int, int]], n_bins: int,
                max_spikes: int) -> list[tuple[int, int]]:
    """Split bins 0..n_bins into consecutive ranges holding at most ``max_spikes`` spikes."""
    per_bin: dict[int, int] = {}
    for b, _ in order:
        per_bin[b] = per_bin.get(b, 0) + 1
    if per_bin and max(per_bin.values()) > max_spikes:
        raise ProtocolError(f"one bin holds more than {max_spikes} spikes; too many groups for "
                            "the max payload")
    chunks, lo, count = [], 0, 0
    for b in sorted(per_bin):
        if count + per_bin[b] > max_spikes:
            chunks.append((lo, b))
            lo, count = b, 0
        count += per_bin[b]
    chunks.append((lo, n_bins))
    return chunks


def _check_spike_window(groups: Sequence[SpikeGroup], n_bins: int, bin_us: int,
                        paced: bool) -> None:
    """The SPIKE_BATCH edge cases the board refuses (docs/protocol.md), refused here first."""
    if n_bins < 1:
        raise FieldRangeError(f"SPIKE_BATCH needs at least one bin, got n_bins={n_bins}")
    if paced and bin_us < 1:
        raise FieldRangeError("a paced SPIKE_BATCH needs bin_us >= 1")
    for gi, g in enumerate(groups):
        rows = [r for r, _c in g.rows]
        if not rows:
            raise FieldRangeError(f"SPIKE_BATCH group {gi} drives no row")
        if len(set(rows)) != len(rows):
            raise FieldRangeError(f"SPIKE_BATCH group {gi} names a row twice: {rows}")
