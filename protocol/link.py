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
On a ``synchronous`` transport (an in-process board that answers inside ``write``) the budget
is not applied: the reply is buffered when ``write`` returns and is read however long that took
in wall time (an empty read means it was lost, only with fault injection), so host load never
causes a resend - and extra frames on the board's virtual clock.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass

from snan_hil.protocol.client import ClientBase, SpikeBatchResult
from snan_hil.protocol.errors import (BoardBusyError, BoardResetError, ErrorCode,
                                      FieldRangeError,
                                      LinkTimeoutError, MalformedPayloadError, MessageError,
                                      ProtocolError, UnsupportedError, VersionMismatchError,
                                      board_error)
from snan_hil.protocol.frames import (FLAG_RETRANSMIT, Frame, FrameDecoder, encode_frame,
                                      wire_size)
from snan_hil.protocol.messages import (MAX_PAYLOAD, PROTOCOL_VERSION, Capability, Clock,
                                        ClockReply, DecisionCandidate, DecisionParams,
                                        DecisionWindow, DecisionWindowReply, ErrorReply,
                                        Hello, Info, Polarity,
                                        ProgramCell, ProgramCellReply, ReadCell, ReadColumn,
                                        Reply, Request, Reset, ResetReply, SpikeBatch,
                                        SpikeBatchReply, SpikeGroup, Status, StatusReply,
                                        WritePulse, spike_batch_reply_size)
from snan_hil.protocol.transport import Transport, wire_seconds

__all__ = ["LinkCounters", "LinkClient", "RttEstimator", "DEFAULT_TIMEOUT_S", "DEFAULT_RETRIES",
           "DEFAULT_GIVE_UP_S", "DEFAULT_MIN_RTO_S"]

log = logging.getLogger(__name__)

DEFAULT_TIMEOUT_S = 0.5
"""Longest wait per try beyond wire and execution time (s); also the wait before the link has
measured a round trip."""
DEFAULT_RETRIES = 3
"""Resends of a request that gets no byte, or only bytes that never form a frame."""
DEFAULT_GIVE_UP_S = 30.0
"""How long a request is resent while the board answers but nothing intact gets through (s)."""
DEFAULT_MIN_RTO_S = 0.02
"""Shortest adaptive wait per try beyond wire and execution time (s)."""
_NAMES = {cls.TYPE: cls.__name__ for cls in (Hello, ReadCell, ReadColumn, WritePulse,
                                              SpikeBatch, ProgramCell, Status, Clock, Reset,
                                              DecisionWindow)}


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


@dataclass
class _Attempts:
    """What one request has seen so far (decides when and how the link gives up)."""

    sent: int = 0               # transmissions (first + retries)
    silent_streak: int = 0      # tries in a row that ended without a byte
    bytes_total: int = 0
    bytes_this_try: int = 0
    alive: bool = False         # a valid frame (a NAK, a stale reply) came back
    naks: int = 0               # the board reported a damaged frame
    damaged: int = 0            # frames from the board that arrived damaged
    busy: int = 0
    busy_text: str = ""
    last_wait: float = 0.0


def _is_nak(frame: Frame) -> bool:
    """An ERROR BAD_FRAME: the board's answer to a damaged frame (any seq)."""
    return len(frame.payload) >= 1 and frame.payload[0] == ErrorCode.BAD_FRAME


def _our_damaged_reply(header: tuple[int, int, int, int, int] | None, seq: int) -> bool:
    """Whether a damaged frame's (untrusted) header says it was the board's reply to ``seq``
    or a NAK: evidence that the board is there and speaks this protocol, so a noisy line is
    not mistaken for a wrong baud rate."""
    if header is None:
        return False
    version, _flags, type_, hseq, _nonce = header
    return version == PROTOCOL_VERSION and (
        (hseq == seq and type_ >= 0x80) or (type_ == ErrorReply.TYPE and hseq == 0))


@dataclass
class RttEstimator:
    """Smoothed round-trip overhead (RFC 6298: SRTT, RTTVAR, RTO = SRTT + 4 RTTVAR) of the
    measured round trip minus the predicted wire and execution time, s."""

    srtt: float | None = None
    rttvar: float = 0.0
    samples: int = 0

    def add(self, sample_s: float) -> None:
        """One measured overhead (negative values count as 0)."""
        x = max(0.0, float(sample_s))
        if self.srtt is None:
            self.srtt, self.rttvar = x, x / 2
        else:
            self.rttvar = 0.75 * self.rttvar + 0.25 * abs(self.srtt - x)
            self.srtt = 0.875 * self.srtt + 0.125 * x
        self.samples += 1

    def rto(self, floor_s: float, ceiling_s: float) -> float:
        """The retransmission timeout: ``ceiling_s`` before any sample, else SRTT + 4 RTTVAR
        within [floor_s, ceiling_s]."""
        if self.srtt is None:
            return ceiling_s
        return min(ceiling_s, max(floor_s, self.srtt + 4 * self.rttvar))


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
                 max_payload: int = MAX_PAYLOAD, busy_backoff_s: float = 0.005,
                 give_up_s: float = DEFAULT_GIVE_UP_S, min_rto_s: float = DEFAULT_MIN_RTO_S):
        self.transport = transport
        self.timeout = float(timeout)
        self.retries = int(retries)
        self.give_up_s = float(give_up_s)
        self.min_rto_s = float(min_rto_s)
        self.rtt = RttEstimator()
        self.max_payload = int(max_payload)
        self.busy_backoff_s = busy_backoff_s
        self.info: Info | None = None
        self.boot_nonce: int | None = None
        self.counters = LinkCounters()
        self._decoder = FrameDecoder(self.max_payload)
        self._dw_params: DecisionParams | None = None   # the block the board holds
        if first_seq is None:
            first_seq = int.from_bytes(os.urandom(2), "little")
        self._seq = first_seq & 0xFFFF

    # ------------------------------------------------------------------ generic request
    def next_seq(self) -> int:
        """Sequence number the next request will use."""
        return self._seq

    def request(self, req: Request, *, timeout: float | None = None,
                retries: int | None = None) -> Reply:
        """Send ``req`` and return its reply (type ``req.REPLY``); see the module docstring.

        ``timeout``: a fixed wait per try instead of the adaptive one; ``retries``: instead of
        :attr:`retries` (silent or garbled tries before giving up).
        """
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
        predicted = self._predicted(req, len(first))
        tries = 1 + (self.retries if retries is None else int(retries))
        self._flush()
        att = _Attempts()
        t0 = time.monotonic()
        while True:
            if att.sent:
                self.counters.retries += 1
            wait = predicted + (float(timeout) if timeout is not None
                                else self._rto(att.silent_streak))
            t_sent = time.monotonic()
            self._write(again if att.sent else first)
            att.sent += 1
            att.last_wait = wait
            outcome = self._await(seq, req, t_sent + wait, att)
            if isinstance(outcome, Reply):
                # Karn: time only exchanges sent once; an in-process board's round trip is
                # its emulation time, not a line's, and says nothing about when to resend
                if att.sent == 1 and not self.transport.synchronous:
                    self.rtt.add(time.monotonic() - t_sent - predicted)
                return outcome
            if outcome is None:
                self.counters.timeouts += 1
                self._decoder.reset()  # a half-received reply is garbage by now
                att.silent_streak = att.silent_streak + 1 if not att.bytes_this_try else 0
            else:
                att.silent_streak = 0
                if outcome.backoff:
                    if att.busy > (self.retries if retries is None else int(retries)):
                        self.counters.board_errors += 1
                        raise BoardBusyError(
                            f"board on {self.name} is busy ({att.busy_text or 'no reason given'}"
                            f"); wait until the other program has finished, or stop it")
                    time.sleep(self.busy_backoff_s * (2 ** (att.busy - 1)))
            self._give_up_if_spent(req, att, tries, time.monotonic() - t0)

    def _give_up_if_spent(self, req: Request, att: "_Attempts", tries: int,
                          elapsed: float) -> None:
        name = _NAMES.get(req.TYPE, type(req).__name__)
        if att.silent_streak >= tries:
            if att.bytes_total == 0:
                raise LinkTimeoutError(
                    f"no answer from the board on {self.name} to {name}: no byte at all came "
                    f"back in {att.sent} tries ({att.last_wait:.2f} s each{self._baud_text()}); "
                    "check power, cable, the port and --baud, or try --protocol legacy for old "
                    "firmware", "silent")
            raise LinkTimeoutError(
                f"the board on {self.name} stopped answering {name}: {att.silent_streak} tries "
                f"in a row without a byte ({att.last_wait:.2f} s each{self._baud_text()}); check "
                "power and cable", "silent")
        if att.sent < tries:
            return
        if not att.alive:
            if att.bytes_total and (att.sent >= tries):
                raise LinkTimeoutError(
                    f"{att.bytes_total} bytes came from the board on {self.name} in {att.sent} "
                    f"tries of {name} but none formed a valid frame: wrong --baud "
                    f"({self.transport.baud or 'no line'}), a board speaking the legacy protocol "
                    "(try --protocol legacy), or a line that corrupts everything", "garbled")
            return
        if elapsed >= self.give_up_s:
            raise LinkTimeoutError(
                f"the link to the board on {self.name} is too damaged: no intact reply to {name} "
                f"in {elapsed:.1f} s ({att.sent} tries; the board reported {att.naks} of our "
                f"frames damaged, {att.damaged} of its frames arrived damaged); check cable, "
                "ground and --baud", "corrupting")

    def _baud_text(self) -> str:
        return f" at {self.transport.baud} baud" if self.transport.baud else ""

    def _limit(self) -> int:
        if self.info is not None:
            return min(self.max_payload, self.info.max_payload)
        return self.max_payload

    def _rto(self, silent_streak: int) -> float:
        """The wait beyond wire and execution time: from the measured round trips (at least
        :attr:`min_rto_s`, at most :attr:`timeout`), doubled after each silent try."""
        base = self.rtt.rto(self.min_rto_s, self.timeout)
        return min(self.timeout, base * (2 ** silent_streak))

    def _predicted(self, req: Request, req_wire: int) -> float:
        """Wire time of request and reply (twice: a margin for the line) and an estimate of
        the board's execution time, s."""
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
        elif isinstance(req, DecisionWindow):
            p = req.params or self._dw_params or DecisionParams()
            spikes = p.n_bins * p.spike_threshold / float(1 << 53)
            reply_payload = 64 + (2 * 4 * p.n_bins // (p.ref_steps + 1) if req.motor_spikes
                                  else 0) + (4 * 4 * p.n_bins // req.trace_stride
                                             if req.trace_stride else 0)
            exec_s = spikes * len(req.rows) * 0.002 + p.n_bins * 20e-6 + (
                p.n_bins * p.bin_us * 1e-6 if req.paced else 0.0)
        wire = wire_seconds(req_wire + wire_size(reply_payload), self.transport.baud)
        return 2 * wire + exec_s

    def _flush(self) -> None:
        self.transport.reset_input_buffer()
        self._decoder.reset()

    def _write(self, data: bytes) -> None:
        self.transport.write(data)
        self.counters.frames_sent += 1
        self.counters.bytes_out += len(data)

    def _await(self, seq: int, req: Request, deadline: float,
               att: "_Attempts") -> Reply | _Retry | None:
        att.bytes_this_try = 0
        synchronous = self.transport.synchronous
        while True:
            remaining = deadline - time.monotonic()
            # An in-process board answered inside write(): its reply is buffered whatever the
            # wall clock says (a loaded host may take longer than the wait to emulate it), so
            # it is read, never timed out and resent; only an empty read means it was lost.
            if remaining <= 0 and not synchronous:
                return None
            data = self.transport.read(65536, max(0.0, remaining))
            if not data:
                if synchronous:
                    return None
                continue
            self.counters.bytes_in += len(data)
            att.bytes_total += len(data)
            att.bytes_this_try += len(data)
            retry: _Retry | None = None
            try:
                for event in self._decoder.feed_events(data):
                    if not isinstance(event, Frame):
                        # a damaged frame from the board: most likely our reply; ask again
                        # at once (a retransmission is answered from the reply cache)
                        att.damaged += 1
                        if _our_damaged_reply(event.header, seq):
                            att.alive = True
                        retry = retry or _Retry(backoff=False)
                        continue
                    att.alive = True
                    outcome = self._check(event, seq, req, att)
                    if isinstance(outcome, Reply):
                        return outcome      # a reply wins over a NAK in the same bytes
                    if outcome is not None and (retry is None or outcome.backoff):
                        retry = outcome
            finally:
                dc = self._decoder.counters
                self.counters.crc_errors = dc.crc_errors
                self.counters.framing_errors = dc.cobs_errors + dc.length_errors
            if retry is not None:
                return retry

    def _check(self, frame: Frame, seq: int, req: Request,
               att: "_Attempts") -> Reply | _Retry | None:
        if frame.type == ErrorReply.TYPE and _is_nak(frame):
            # NAK: the board received a damaged frame (ours); its seq means nothing
            self.counters.bad_crc_reported += 1
            att.naks += 1
            return _Retry(backoff=False)
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
            if msg.code == ErrorCode.BUSY:
                self.counters.busy += 1
                att.busy += 1
                att.busy_text = msg.message
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
        self._dw_params = None          # HELLO: the board forgot its window parameters
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
                                  tuple(map(int, g.bins))) for g in groups)
        columns = tuple(int(c) for c in columns)
        _check_spike_window(groups, n_bins, bin_us, paced)
        self.limits.check_reads((c for g in groups for _r, c in g.rows), "SPIKE_BATCH",
                                dac="row")
        order = sorted((b, gi) for gi, g in enumerate(groups) for b in g.bins)
        if order and (order[0][0] < 0 or order[-1][0] >= n_bins):
            raise FieldRangeError(f"spike bins must lie in 0..{n_bins - 1}")
        per_spike = 2 * len(columns)
        max_spikes = (self._limit() - spike_batch_reply_size(0, 0)) // max(1, per_spike)
        todo = _chunk_bins(order, n_bins, max_spikes)[::-1]
        spikes: list[tuple[int, int]] = []
        codes: list[tuple[int, ...]] = []
        round_trips, splits = 0, 0
        while todo:
            lo, hi = todo.pop()
            whole = lo == 0 and hi == n_bins            # the usual case: one request
            sub = groups if whole else tuple(
                SpikeGroup(g.rows, tuple(b - lo for b in g.bins if lo <= b < hi)) for g in groups)
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
            expect = order if whole else [(b + lo, gi) for b, gi in req.spike_order()]
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
        self._dw_params = None          # RESET: the board forgot its window parameters
        return reply

    def decision_window(self, key: int, rows: Sequence[int],
                        candidates: Sequence[DecisionCandidate], params: DecisionParams, *,
                        motor_spikes: bool = False, trace_stride: int = 0,
                        paced: bool = False) -> DecisionWindowReply:
        """Run one decision window on the board (see :class:`DecisionWindow`): the
        parameter block travels only when the board does not hold it yet (first window of a
        session, after HELLO or RESET, or when it changes). Checks that the reply has one
        count per candidate and the motor spikes when asked."""
        self._need(Capability.DECISION_WINDOW, "DECISION_WINDOW")
        self.limits.check_reads((params.row_code,), "DECISION_WINDOW", dac="row")
        req = DecisionWindow(int(key), tuple(int(r) for r in rows), tuple(candidates),
                             None if params == self._dw_params else params,
                             bool(motor_spikes), int(trace_stride), bool(paced))
        reply = self.request(req)
        assert isinstance(reply, DecisionWindowReply)
        if (len(reply.counts) != len(req.candidates)
                or (reply.motor_spikes is None) == req.motor_spikes
                or (reply.trace is None) == bool(req.trace_stride)):
            raise MalformedPayloadError(
                f"board on {self.name} answered DECISION_WINDOW with {len(reply.counts)} "
                f"counts for {len(req.candidates)} candidates (or without the sections asked)")
        self._dw_params = params
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
