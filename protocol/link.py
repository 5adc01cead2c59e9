"""Host side of the framed protocol: a reliable request/response client.

One request is outstanding at a time (stop-and-wait). Per request:

- a new sequence number; the input buffer is flushed first (stale bytes from earlier requests);
- the frame is sent (a HELLO preceded by one 0x00, which ends any half frame an earlier
  session left in the board's receive buffer); when no valid reply arrives within the
  retransmission timeout it is resent with the SAME sequence number (flag RETRANSMIT,
  preceded by one 0x00 to flush a half frame on the board) - the board answers a resent
  request it already executed from its reply cache, so nothing runs twice;
- a NAK or a damaged frame from the board triggers an immediate resend; BUSY a resend after a
  back-off (for up to ``busy_wait_s`` when the host waits for a busy board);
- replies with another seq (late or duplicated) are discarded and counted;
- the boot nonce learned at HELLO is sent in every request header and checked in every reply:
  a different nonce (or a NONCE_MISMATCH error) raises :class:`BoardResetError`; the client keeps
  the old nonce, so every later request fails the same way until the caller calls ``hello()``;
- other ERROR replies raise the matching :class:`BoardError` subclass.

**When to resend** (the retransmission timeout, RTO) and **when to give up** are separate
(docs/protocol.md section 4). A try waits twice the wire time of request and expected reply at
the transport's baud + the board's execution time (declared by the command) + the RTO, which
follows the measured round trip (RFC 6298) within [``min_rto_s``, ``max_rto_s``] and doubles
after each silent try. The link gives up on a request only when:

- the line stayed silent (not one byte) for ``timeout`` s - ``connect_timeout`` s while the
  board has not answered anything yet in this session - or, counting every silence longer than
  the RTO ceiling as a stall, when this run's stalls would exceed ``stall_budget_s``
  (``LinkTimeoutError`` kind ``silent`` when nothing ever came back, else ``stalled``);
- bytes came in ``retries`` + 1 tries but never a frame (``garbled``);
- the port sent our own request back (``echo``: a loopback, not a board);
- ``retries`` + 1 tries in a row brought only replies to other requests (``stale``);
- the board answers (NAKs, damaged replies) but nothing intact gets through in ``give_up_s``
  (``corrupting``).

On a ``synchronous`` transport (an in-process board that answers inside ``write``) the wall
clock plays no part: the reply is buffered when ``write`` returns and is read however long that
took (an empty read means it was lost, only with fault injection, and counts as a silent try:
``retries`` + 1 of them in a row give up), so host load never causes a resend - and extra
frames on the board's virtual clock.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import time
from dataclasses import dataclass
from typing import Annotated, Any, Generic, TypeVar

from annotated_types import Interval

from snan_hil.protocol.client import DEFAULT_REPLY_BYTES, ClientBase, command_of
from snan_hil.protocol.errors import (BoardBusyError, BoardResetError, ErrorCode,
                                      FieldRangeError, LinkTimeoutError, MessageError,
                                      VersionMismatchError, board_error)
from snan_hil.protocol.frames import (FLAG_RETRANSMIT, Frame, FrameDecoder, encode_frame,
                                      wire_size)
from snan_hil.protocol.messages import (MAX_PAYLOAD, PIPELINE_BYTES, PIPELINE_REPLY_MAX,
                                        PROTOCOL_VERSION, Capability, ErrorReply, Hello, Info,
                                        Reply, Request, ResetReply)
from snan_hil.protocol.transport import Transport, wire_seconds

ReplyT = TypeVar("ReplyT", bound=Reply)

__all__ = ["LinkCounters", "LinkClient", "Ticket", "RttEstimator", "StallLog", "DEFAULT_TIMEOUT_S",
           "DEFAULT_CONNECT_TIMEOUT_S", "DEFAULT_STALL_BUDGET_S", "DEFAULT_RETRIES",
           "DEFAULT_GIVE_UP_S", "DEFAULT_MIN_RTO_S", "DEFAULT_MAX_RTO_S", "LinkTimes",
           "MAX_TIMEOUT_S", "MAX_STALL_BUDGET_S", "MAX_WAIT_S"]

log = logging.getLogger(__name__)

DEFAULT_TIMEOUT_S = 10.0
"""Longest the line may stay silent during one request before the link gives up on it (s);
the user's ``--timeout``. A stall of a serial adapter or a loaded PC is shorter."""
DEFAULT_CONNECT_TIMEOUT_S = 2.0
"""Longest silence before the board has answered anything in this session (s): a board that
is there answers HELLO within milliseconds (unless ``--timeout`` asks for longer)."""
DEFAULT_STALL_BUDGET_S = 60.0
"""Total length of the stalls (silences longer than the RTO ceiling) a run survives (s)."""
DEFAULT_RETRIES = 3
"""Resends of a request that gets only bytes that never form a frame, or only stale replies,
before the link gives up (and BUSY answers, without a wait)."""
DEFAULT_GIVE_UP_S = 30.0
"""How long a request is resent while the board answers but nothing intact gets through (s)."""
DEFAULT_MIN_RTO_S = 0.02
"""Shortest adaptive wait per try beyond wire and execution time (s)."""
DEFAULT_MAX_RTO_S = 0.5
"""Longest wait per try beyond wire and execution time (s): the RTO before the first measured
round trip and its ceiling (never above ``timeout``). A silence longer than it is a stall."""
BUSY_POLL_MAX_S = 0.5
"""Longest back-off between two requests to a busy board while the host waits for it (s)."""
MAX_TIMEOUT_S = 3600.0
"""Upper bound of ``--timeout`` (s): a line silent for an hour is gone, not stalled (an
assumption: the longest stall seen of a USB-serial adapter or a loaded PC is seconds); a larger
value would make a run hang for ever on a dead board (``1e308`` s was accepted)."""
MAX_STALL_BUDGET_S = 86400.0
"""Upper bound of ``--stall-budget`` (s): a day of stalls in one run."""
MAX_WAIT_S = 86400.0
"""Upper bound of ``--wait`` (s): a day of waiting for a board another host holds."""


@dataclass(frozen=True)
class LinkTimes:
    """The link's time options a user sets, in s, each with its bounds beside it (checked for
    the command line's ``--timeout``, ``--stall-budget`` and ``--wait`` by
    :meth:`snan_hil.lab.ports.BoardAddress.check`; the defaults are the link's).

    ``timeout_s``: the longest silence of one request (:data:`DEFAULT_TIMEOUT_S`);
    ``stall_budget_s``: the total of a run's stalls (:data:`DEFAULT_STALL_BUDGET_S`);
    ``wait_s``: how long to wait for a board another host holds (0: stop at once)."""

    timeout_s: Annotated[float, Interval(gt=0, le=MAX_TIMEOUT_S)] = DEFAULT_TIMEOUT_S
    stall_budget_s: Annotated[float, Interval(gt=0, le=MAX_STALL_BUDGET_S)] = \
        DEFAULT_STALL_BUDGET_S
    wait_s: Annotated[float, Interval(ge=0, le=MAX_WAIT_S)] = 0.0


@dataclass
class StallLog:
    """The stalls of a run: silences of the line longer than the RTO ceiling, s."""

    count: int = 0
    total_s: float = 0.0
    longest_s: float = 0.0

    def add(self, silence_s: float) -> None:
        """One stall of ``silence_s`` seconds."""
        self.count += 1
        self.total_s += silence_s
        self.longest_s = max(self.longest_s, silence_s)


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

    started: float = 0.0        # first transmission (monotonic s)
    served_from: float = 0.0    # since when the board serves it (after any BUSY wait)
    quiet_from: float = 0.0     # from then on the board could have answered: silence counts
    heard_at: float = 0.0       # last byte received during this request
    sent: int = 0               # transmissions (first + retries)
    silent_streak: int = 0      # tries in a row that ended without a byte
    stale_streak: int = 0       # tries in a row that brought only replies to other requests
    noisy_tries: int = 0        # tries that brought bytes but not one frame
    bytes_total: int = 0
    bytes_this_try: int = 0
    stale_this_try: int = 0
    other_this_try: int = 0     # NAKs, damaged frames, frames with our seq
    stale_total: int = 0
    alive: bool = False         # a valid frame (a NAK, a stale reply) came back
    naks: int = 0               # the board reported a damaged frame
    damaged: int = 0            # frames from the board that arrived damaged
    busy: int = 0
    busy_text: str = ""
    busy_since: float | None = None
    last_wait: float = 0.0

    def silence_start(self) -> float:
        """Since when the line has been silent for this request (monotonic s)."""
        return max(self.quiet_from, self.heard_at)


@dataclass
class Ticket(Generic[ReplyT]):
    """A request sent by :meth:`LinkClient.submit` and not yet collected."""

    seq: int
    req: Request[ReplyT]
    first: bytes                # the frame's first transmission
    again: bytes                # its retransmission (flag RETRANSMIT, a leading 0x00)
    predicted: float            # wire and execution time (s)
    tries: int
    rto_s: float | None
    att: _Attempts = dataclasses.field(default_factory=_Attempts)
    t_sent: float = 0.0         # the last transmission (monotonic s)
    wait: float = 0.0           # how long that try waits


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
    """Reliable framed-protocol client over any :class:`Transport` (module docstring).

    ``timeout`` (s): the longest the line may stay silent during one request (the user's
    ``--timeout``); ``connect_timeout`` (s): the same before the board has answered anything in
    this session (default: ``timeout``, at most :data:`DEFAULT_CONNECT_TIMEOUT_S`);
    ``stall_budget_s``: the total of the stalls a run survives; ``busy_wait_s``: how long a
    request waits for a board that answers BUSY (0: give up after ``retries`` + 1 BUSY
    answers); ``retries``: resends of a request that only gets garbage or stale replies;
    ``give_up_s``: how long a request is resent while the board answers but nothing intact
    gets through; ``min_rto_s`` / ``max_rto_s``: the range of the retransmission timeout;
    ``first_seq``: first sequence number (default: random, so a new session never collides
    with the board's reply cache of an earlier one); ``max_payload``: our receive/send limit
    (the board's Info may lower it).
    """

    def __init__(self, transport: Transport, *, timeout: float = DEFAULT_TIMEOUT_S,
                 connect_timeout: float | None = None,
                 stall_budget_s: float = DEFAULT_STALL_BUDGET_S, busy_wait_s: float = 0.0,
                 retries: int = DEFAULT_RETRIES, first_seq: int | None = None,
                 max_payload: int = MAX_PAYLOAD, busy_backoff_s: float = 0.005,
                 give_up_s: float = DEFAULT_GIVE_UP_S, min_rto_s: float = DEFAULT_MIN_RTO_S,
                 max_rto_s: float = DEFAULT_MAX_RTO_S):
        super().__init__(transport)
        self.timeout = float(timeout)
        self.connect_timeout = float(min(self.timeout, DEFAULT_CONNECT_TIMEOUT_S)
                                     if connect_timeout is None else connect_timeout)
        self.stall_budget_s = float(stall_budget_s)
        self.busy_wait_s = float(busy_wait_s)
        self.retries = int(retries)
        self.give_up_s = float(give_up_s)
        self.min_rto_s = float(min_rto_s)
        self.max_rto_s = float(max_rto_s)
        self.rtt = RttEstimator()
        self.max_payload = int(max_payload)
        self.busy_backoff_s = busy_backoff_s
        self.boot_nonce: int | None = None
        self.counters = LinkCounters()
        #: requests the board answered (a reply or an ERROR) in this session
        self.answered = 0
        #: the stalls of this session (silences longer than the RTO ceiling)
        self.stalls = StallLog()
        self._decoder = FrameDecoder(self.max_payload)
        #: requests sent and not yet collected, by sequence number
        self._outstanding: dict[int, Ticket[Any]] = {}
        #: frames that answered an outstanding request while another one was awaited
        self._early: dict[int, Frame] = {}
        self._pipelined = False
        if first_seq is None:
            first_seq = int.from_bytes(os.urandom(2), "little")
        self._seq = first_seq & 0xFFFF

    # ------------------------------------------------------------------ generic request
    @property
    def pipelined(self) -> bool:
        """Two requests may be outstanding (:meth:`submit`): the host's next request goes on
        the line while the board runs the last one. Set it on a board with the PIPELINE
        capability; the transport is told (an in-process board then lets bytes arrive while
        it works). Off (the default): stop-and-wait."""
        return self._pipelined

    @pipelined.setter
    def pipelined(self, on: bool) -> None:
        if on and (self.info is None or not self.info.has(Capability.PIPELINE)):
            raise ValueError(f"the board on {self.name} has no PIPELINE capability")
        if not on and self._outstanding:
            raise RuntimeError("collect the outstanding requests first")
        self._pipelined = bool(on)
        self.transport.pipeline(self._pipelined)

    @property
    def outstanding(self) -> int:
        """Requests submitted and not yet collected (0, 1 or, pipelined, 2)."""
        return len(self._outstanding)

    def next_seq(self) -> int:
        """Sequence number the next request will use."""
        return self._seq

    @property
    def rto_ceiling_s(self) -> float:
        """The longest retransmission timeout: ``max_rto_s``, never above ``timeout``; a
        silence longer than it is a stall."""
        return min(self.max_rto_s, self.timeout)

    def request(self, req: Request[ReplyT], *, rto_s: float | None = None,
                retries: int | None = None) -> ReplyT:
        """Send ``req`` and return its reply (type ``req.REPLY``); see the module docstring.
        The client learns from the replies it gets: INFO (``info``, the boot nonce; another
        protocol version is a :class:`VersionMismatchError`) and RESET (the new nonce).

        ``rto_s``: a fixed wait per try instead of the adaptive one; ``retries``: instead of
        :attr:`retries`.
        """
        return self.collect(self.submit(req, rto_s=rto_s, retries=retries))

    def submit(self, req: Request[ReplyT], *, rto_s: float | None = None,
               retries: int | None = None) -> "Ticket[ReplyT]":
        """Send ``req`` now and return its ticket; :meth:`collect` waits for the reply. With
        :attr:`pipelined` on, a second request may be submitted before the first is collected
        (docs/protocol.md section 4, "Two requests outstanding"): the two replies are told
        apart by their sequence numbers and either request is resent with its own; otherwise
        (and for a request that is no :meth:`pipelinable` one) every earlier ticket is
        collected first."""
        if self._outstanding and not (self.pipelined and self._fits(req)):
            raise RuntimeError("a second request outstanding needs pipelined=True and a "
                               "request that fits the board's pipeline (pipelinable)")
        seq = self._seq
        self._seq = (self._seq + 1) & 0xFFFF
        self.counters.requests += 1
        payload = req.encode()
        limit = self.payload_limit
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
        tries = 1 + (self.retries if retries is None else int(retries))
        if not self._outstanding:
            self._flush()
        ticket: Ticket[ReplyT] = Ticket(seq, req, first, again, self._predicted(req, len(first)),
                                        tries, rto_s)
        att = ticket.att
        att.started = att.served_from = time.monotonic()
        att.quiet_from = att.started + ticket.predicted
        self._send_try(ticket)
        self._outstanding[seq] = ticket
        return ticket

    def collect(self, ticket: "Ticket[ReplyT]") -> ReplyT:
        """The reply to a submitted request: read (and resend its request) until it comes;
        replies to the other outstanding request are kept for their own :meth:`collect`."""
        try:
            return self._collect(ticket)
        finally:
            self._outstanding.pop(ticket.seq, None)
            self._early.pop(ticket.seq, None)

    def pipelinable(self, req: Request[Reply]) -> bool:
        """Whether ``req`` may be the second request outstanding: the board has the PIPELINE
        capability, the request's frame fits its receive ring (``PIPELINE_BYTES``) and its reply
        is one the board caches for every request (at most ``PIPELINE_REPLY_MAX`` bytes)."""
        return self.info is not None and self.info.has(Capability.PIPELINE) and self._fits(req)

    def _fits(self, req: Request[Reply]) -> bool:
        spec = command_of(req)
        reply = spec.reply_bytes(req) if spec else DEFAULT_REPLY_BYTES
        return (wire_size(len(req.encode())) <= PIPELINE_BYTES - 2
                and reply <= PIPELINE_REPLY_MAX)

    def _send_try(self, t: "Ticket[Any]") -> None:
        att = t.att
        if att.sent:
            self.counters.retries += 1
        t.wait = t.predicted + (float(t.rto_s) if t.rto_s is not None
                                else self._rto(att.silent_streak))
        t.t_sent = time.monotonic()
        self._write(t.again if att.sent else t.first)
        att.sent += 1
        att.last_wait = t.wait

    def _collect(self, t: "Ticket[ReplyT]") -> ReplyT:
        att, seq, req = t.att, t.seq, t.req
        while True:
            early = self._early.pop(seq, None)
            if early is not None:
                outcome: ReplyT | _Retry | None = self._check(early, seq, req, att)
            else:
                deadline = min(t.t_sent + t.wait, self._silence_deadline(att))
                outcome = self._await(seq, req, deadline, att)
            if outcome is None:
                self.counters.timeouts += 1
                self._decoder.reset()  # a half-received reply is garbage by now
                att.silent_streak = att.silent_streak + 1 if not att.bytes_this_try else 0
                only_stale = att.stale_this_try and not att.other_this_try
                att.stale_streak = att.stale_streak + 1 if only_stale else 0
                if att.bytes_this_try and not (att.stale_this_try or att.other_this_try):
                    att.noisy_tries += 1        # bytes, but not one frame of them
            elif isinstance(outcome, _Retry):
                att.silent_streak = att.stale_streak = 0
                if not att.alive:
                    att.noisy_tries += 1        # only damaged frames, none from a board
                if outcome.backoff:
                    self._wait_busy(att, t.tries)
            else:
                # Karn: time only exchanges sent once; an in-process board's round trip is
                # its emulation time, not a line's, and says nothing about when to resend
                if att.sent == 1 and not self.transport.synchronous:
                    self.rtt.add(time.monotonic() - t.t_sent - t.predicted)
                self.answered += 1
                self._learn(outcome)
                return outcome
            self._give_up_if_spent(req, att, t.tries)
            self._send_try(t)

    def _silence_deadline(self, att: _Attempts) -> float:
        """When the silence of this request ends it: its limit (``timeout``, or
        ``connect_timeout`` before the first answer), or earlier when it would take this run's
        stalls beyond ``stall_budget_s``."""
        if self.transport.synchronous:
            return float("inf")                   # no wall clock: tries count (module doc)
        limit = self.timeout if self.answered else self.connect_timeout
        budget_left = self.stall_budget_s - self.stalls.total_s
        return att.silence_start() + min(limit, max(self.rto_ceiling_s, budget_left))

    def _wait_busy(self, att: _Attempts, tries: int) -> None:
        """After a BUSY answer: back off and let the request be resent, or give up - after
        ``tries`` BUSY answers, or, when the host waits (``busy_wait_s``), once it has waited
        that long (one warning line says who holds the board)."""
        now = time.monotonic()
        holder = att.busy_text or "no reason given"
        if att.busy_since is None:
            att.busy_since = now
            if self.busy_wait_s > 0:
                log.warning("board on %s is busy (%s); waiting up to %g s for it (--wait)",
                            self.name, holder, self.busy_wait_s)
        waited = now - att.busy_since
        if (self.busy_wait_s <= 0 and att.busy >= tries) or \
                (self.busy_wait_s > 0 and waited >= self.busy_wait_s):
            self.counters.board_errors += 1
            waited_text = (f" and stayed busy for the {self.busy_wait_s:g} s this host waited "
                           "(--wait)" if self.busy_wait_s > 0 else "")
            raise BoardBusyError(
                f"board on {self.name} is busy ({holder}){waited_text}; wait until the other "
                "program has finished, or stop it (--wait SECONDS waits for the board)")
        pause = min(self.busy_backoff_s * (2 ** (att.busy - 1)), BUSY_POLL_MAX_S)
        if self.busy_wait_s > 0:
            pause = min(pause, max(0.0, self.busy_wait_s - waited))
        time.sleep(pause)
        # the clocks of a request start again once the board serves it
        att.heard_at = att.served_from = time.monotonic()

    def _learn(self, reply: Reply) -> None:
        """What the client keeps from a reply: the board's INFO, a RESET's new nonce."""
        if isinstance(reply, Info):
            if reply.protocol_version != PROTOCOL_VERSION:
                raise VersionMismatchError(
                    f"board on {self.name} speaks protocol version {reply.protocol_version}, "
                    f"this host speaks {PROTOCOL_VERSION}; update the board firmware or snan-hil")
            self.info = reply
            self.window_params = None       # a new session: the board holds no window block
        elif isinstance(reply, ResetReply):
            self.window_params = None       # RESET: the board forgot its window parameters
            if self.info is not None:
                self.info = dataclasses.replace(self.info, boot_nonce=reply.new_nonce)

    def _give_up_if_spent(self, req: Request[Reply], att: _Attempts, tries: int) -> None:
        name = type(req).__name__
        now = time.monotonic()
        if self.transport.synchronous:
            silent = att.silent_streak >= tries
            silence = 0.0
        else:
            silence = now - att.silence_start()
            silent = now >= self._silence_deadline(att) and not att.bytes_this_try
        if silent:
            self._give_up_silent(name, att, silence)
        if att.stale_streak >= tries:
            raise LinkTimeoutError(
                f"the board on {self.name} answers, but only with replies to other requests: "
                f"{att.stale_total} replies with another sequence number in {att.sent} tries of "
                f"{name} ({now - att.started:.1f} s), none to this one; another program is "
                "talking to the board on this port, or the board replays old replies: stop the "
                "other program or reset the board, then run the command again", "stale")
        if att.sent < tries:
            return
        if not att.alive:
            if att.noisy_tries >= tries:
                raise LinkTimeoutError(
                    f"{att.bytes_total} bytes came from the board on {self.name} in {att.sent} "
                    f"tries of {name} but none formed a valid frame: wrong --baud "
                    f"({self.transport.baud or 'no line'}), a board speaking the legacy protocol "
                    "(try --protocol legacy), or a line that corrupts everything", "garbled")
            return
        elapsed = now - att.served_from
        if elapsed >= self.give_up_s:
            raise LinkTimeoutError(
                f"the link to the board on {self.name} is too damaged: no intact reply to {name} "
                f"in {elapsed:.1f} s ({att.sent} tries; the board reported {att.naks} of our "
                f"frames damaged, {att.damaged} of its frames arrived damaged); check cable, "
                "ground and --baud", "corrupting")

    def _give_up_silent(self, name: str, att: _Attempts, silence: float) -> None:
        """The line stayed silent too long: one line that says what happened."""
        if silence >= self.rto_ceiling_s:
            self.stalls.add(silence)
        if not self.answered and not self.counters.bytes_in:
            waited = (f"in {silence:.1f} s" if not self.transport.synchronous else "")
            raise LinkTimeoutError(
                f"no answer from the board on {self.name} to {name}: no byte at all came back "
                f"in {att.sent} tries {waited}{self._baud_text()}; check power, cable, the port "
                "and --baud, or try --protocol legacy for old firmware", "silent")
        resume = ("then run the command again: what it finished is kept (program-weights "
                  "continues from its layout; compare, demo and experiment with --resume)")
        if self.transport.synchronous:
            raise LinkTimeoutError(
                f"the board on {self.name} went silent after {self.answered} answered requests: "
                f"{att.sent} tries of {name} in a row got no byte back; check the board, "
                f"{resume}", "stalled")
        limit = self.timeout if self.answered else self.connect_timeout
        if silence < limit - 1e-3:
            raise LinkTimeoutError(
                f"the line to the board on {self.name} went silent again after {self.answered} "
                f"answered requests: {silence:.1f} s without a byte waiting for {name}, "
                f"{self.stalls.total_s:.1f} s of stalls in {self.stalls.count} stalls in this "
                f"run, beyond its --stall-budget of {self.stall_budget_s:g} s; the line or the "
                f"board keeps stalling (a serial adapter, a loaded PC): check them, {resume}",
                "stalled")
        raise LinkTimeoutError(
            f"the line to the board on {self.name} went silent after {self.answered} answered "
            f"requests: no byte for {silence:.1f} s waiting for {name} (--timeout "
            f"{limit:g} s per request{self._baud_text()}); check cable, adapter and the "
            f"board's power (a longer --timeout rides out longer stalls), {resume}", "stalled")

    def _baud_text(self) -> str:
        return f" at {self.transport.baud} baud" if self.transport.baud else ""

    @property
    def payload_limit(self) -> int:
        """Largest payload on this link: ours (``max_payload``), lowered by the board's INFO."""
        if self.info is not None:
            return min(self.max_payload, self.info.max_payload)
        return self.max_payload

    def _rto(self, silent_streak: int) -> float:
        """The wait beyond wire and execution time: from the measured round trips (at least
        :attr:`min_rto_s`, at most :attr:`rto_ceiling_s`), doubled after each silent try."""
        ceiling = self.rto_ceiling_s
        base = self.rtt.rto(min(self.min_rto_s, ceiling), ceiling)
        return min(ceiling, base * (2 ** min(silent_streak, 30)))

    def _predicted(self, req: Request[Reply], req_wire: int) -> float:
        """Wire time of request and reply (twice: a margin for the line) and the board's
        execution time its command declares (:class:`~snan_hil.protocol.client.CommandSpec`),
        s."""
        spec = command_of(req)
        reply_payload = spec.reply_bytes(req) if spec else DEFAULT_REPLY_BYTES
        exec_s = spec.exec_s(req) if spec else 0.0
        wire = wire_seconds(req_wire + wire_size(reply_payload), self.transport.baud)
        return 2 * wire + exec_s

    def _flush(self) -> None:
        self.transport.reset_input_buffer()
        self._decoder.reset()

    def _write(self, data: bytes) -> None:
        self.transport.write(data)
        self.counters.frames_sent += 1
        self.counters.bytes_out += len(data)

    def _await(self, seq: int, req: Request[ReplyT], deadline: float,
               att: _Attempts) -> ReplyT | _Retry | None:
        att.bytes_this_try = att.stale_this_try = att.other_this_try = 0
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
            self._heard(att)
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
                        att.other_this_try += 1
                        if _our_damaged_reply(event.header, seq):
                            att.alive = True
                        retry = retry or _Retry(backoff=False)
                        continue
                    att.alive = True
                    outcome = self._check(event, seq, req, att)
                    if outcome is None:
                        continue
                    if not isinstance(outcome, _Retry):
                        return outcome      # a reply wins over a NAK in the same bytes
                    if retry is None or outcome.backoff:
                        retry = outcome
            finally:
                dc = self._decoder.counters
                self.counters.crc_errors = dc.crc_errors
                self.counters.framing_errors = dc.cobs_errors + dc.length_errors
            if retry is not None:
                return retry

    def _heard(self, att: _Attempts) -> None:
        """Bytes came: a silence longer than the RTO ceiling before them was a stall."""
        now = time.monotonic()
        if not self.transport.synchronous:
            silence = now - att.silence_start()
            if silence >= self.rto_ceiling_s:
                self.stalls.add(silence)
                log.info("%s: the line was silent for %.2f s (stall %d of this run, %.1f s in "
                         "all)", self.name, silence, self.stalls.count, self.stalls.total_s)
        att.heard_at = now

    def _check(self, frame: Frame, seq: int, req: Request[ReplyT],
               att: _Attempts) -> ReplyT | _Retry | None:
        if frame.type == ErrorReply.TYPE and _is_nak(frame):
            # NAK: the board received a damaged frame (ours); its seq means nothing
            self.counters.bad_crc_reported += 1
            att.naks += 1
            att.other_this_try += 1
            return _Retry(backoff=False)
        if frame.type < 0x80:
            # a board never sends a request: our own frame came back
            self.counters.unexpected_replies += 1
            if frame.type == req.TYPE and frame.seq == seq:
                raise LinkTimeoutError(
                    f"the port {self.name} sends back what this host sends (our "
                    f"{type(req).__name__} came back unchanged): it is a loopback (loop://, a "
                    "serial adapter with TX wired to RX, a terminal echoing), not a board; "
                    "check --port", "echo")
            return None
        if frame.seq != seq and frame.seq in self._outstanding:
            self._early[frame.seq] = frame         # the other outstanding request's reply
            att.other_this_try += 1
            return None
        if frame.seq != seq:
            self.counters.stale_replies += 1
            att.stale_this_try += 1
            att.stale_total += 1
            return None
        att.other_this_try += 1
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
            return self._refused(frame, msg, req, att)
        reply = req.accept(msg)
        if reply is None:
            self.counters.unexpected_replies += 1
            return None
        self._track_nonce(frame, req, reply)
        return reply

    def _refused(self, frame: Frame, msg: ErrorReply, req: Request[ReplyT],
                 att: _Attempts) -> _Retry:
        """An error reply to ``req``: BUSY is retried (with backoff); anything else raises
        (VersionMismatchError, BoardResetError, or the code's BoardError)."""
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
        self.answered += 1
        name = type(req).__name__
        raise board_error(msg.code, f"board on {self.name} refused {name}: {msg.message}",
                          msg.detail, msg.request_type)

    def _track_nonce(self, frame: Frame, req: Request[ReplyT], reply: ReplyT) -> None:
        """Follow the board's boot nonce through an accepted reply: HELLO and RESET set it,
        any other reply must carry it unchanged."""
        if isinstance(req, Hello):
            if self.boot_nonce is not None and frame.nonce != self.boot_nonce:
                self.counters.resets_detected += 1
                log.info("%s: board boot nonce changed 0x%08x -> 0x%08x", self.name,
                         self.boot_nonce, frame.nonce)
            self.boot_nonce = frame.nonce
        elif isinstance(reply, ResetReply):
            if self.boot_nonce is not None and reply.old_nonce != self.boot_nonce:
                self._reset_detected(reply.old_nonce, "was reset before this RESET")
            self.boot_nonce = frame.nonce
        else:
            self._check_nonce(frame, req)

    def _check_nonce(self, frame: Frame, req: Request[Reply]) -> None:
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
