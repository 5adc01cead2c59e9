"""The board command surface: every board command defined once, shared by every client.

:class:`BoardClient` is what calibration, host and tools use of a board. Its commands
(``hello``, ``read_cell``, ``read_column``, ``write_pulse``, ``spike_batch``, ``program_cell``,
``status``, ``clock``, ``reset``) are written here, once: each checks the host's safety limits
(:mod:`snan_hil.protocol.safety`), builds its request message and hands it to
:meth:`BoardClient.request`, the one method a client implements:

* :class:`~snan_hil.protocol.link.LinkClient` sends it as a frame (framed protocol);
* :class:`~snan_hil.protocol.legacy_client.LegacyClient` translates the requests the old
  line protocol has (HELLO, READ_CELL, WRITE_PULSE) into lines and refuses the others with
  :class:`~snan_hil.protocol.errors.UnsupportedError`;
* :class:`~snan_hil.protocol.retry.RetryingClient` sends it again as a new request after the
  link gave up, when the command is declared safe to resend.

Requests are generic in their reply (``ReadCell`` is a ``Request[ReadCellReply]``), so
``request(ReadCell(...))`` is typed ``ReadCellReply`` without casts.

Every command declares, with :func:`command` beside its definition, what the link layers
need to know of it: its request type, whether it may be **resent** as a new request after the
link gave up (docs/protocol.md section 4, "What a host may resend": never for a request that
changes the chip - a lost pulse is reconciled from the board's pulse counter, never blindly
resent), the :class:`~snan_hil.protocol.messages.Capability` a board must announce for it, and
the board's execution time and reply size the link waits for (:class:`CommandSpec`, looked
up with :func:`command_of`).

**Adding a command is one change here** (plus its messages):

1. append the request and reply to :mod:`snan_hil.protocol.messages`
   (``class Foo(Request[FooReply])`` with its ``TYPE``, encode/decode, and the pair in
   ``MESSAGE_TYPES``);
2. add one method to :class:`BoardClient` decorated with
   ``@command(Foo, name="FOO", resend=..., capability=..., exec_s=..., reply_bytes=...)``
   that checks the host limits, builds ``Foo`` and returns ``self.issue(foo)`` (or a field
   of the reply; ``issue`` refuses a board without the capability, then sends).

``LinkClient`` then sends it (waiting ``exec_s`` for the board), ``RetryingClient`` resends it
or not as declared, ``LegacyClient`` refuses it as not available over the line protocol.
"""

from __future__ import annotations

import dataclasses
import logging
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Self, TypeVar

from snan_hil.protocol.errors import FieldRangeError, LinkTimeoutError, MalformedPayloadError, \
    ProtocolError, UnsupportedError
from snan_hil.protocol.messages import (MAX_PAYLOAD, Capability, Clock, ClockReply,
                                        DecisionCandidate, DecisionParams, DecisionWindow,
                                        DecisionWindowReply, Hello, Info,
                                        Polarity, ProgramCell, ProgramCellReply, ReadCell,
                                        ReadColumn, Reply, Request, Reset, ResetReply,
                                        SpikeBatch, SpikeGroup, Status, StatusReply, WritePulse,
                                        spike_batch_reply_size)
from snan_hil.protocol.learn_messages import (LEARN_NO_LANE, LearnApply, LearnApplyReply,
                                              LearnSetup, LearnSetupReply, LearnState,
                                              LearnStateReply, LearnWindow, LearnWindowReply)
from snan_hil.protocol.safety import HostLimits
from snan_hil.protocol.transport import Transport

__all__ = ["BoardClient", "ClientBase", "CommandSpec", "SpikeBatchResult", "command",
           "command_of", "COMMANDS"]

log = logging.getLogger(__name__)

ReplyT = TypeVar("ReplyT", bound=Reply)
F = TypeVar("F", bound=Callable[..., Any])

DEFAULT_REPLY_BYTES = 64
"""Reply payload the link budgets wire time for when a command does not say (bytes)."""


def _no_exec(_req: Any) -> float:
    return 0.0


def _default_reply(_req: Any) -> int:
    return DEFAULT_REPLY_BYTES


@dataclass(frozen=True)
class CommandSpec:
    """What the link layers know of one board command (declared with :func:`command`).

    ``resend``: whether the request may be sent again as a *new* request after the link gave
    up on it (it changes nothing on the chip); ``capability``: the INFO capability a board
    must announce (None: every board); ``exec_s(req)``: the board's execution time (s, an
    estimate the link adds to its wait); ``reply_bytes(req)``: the expected reply payload.
    """

    request: type[Request[Reply]]
    name: str
    method: str
    resend: bool
    capability: Capability | None = None
    exec_s: Callable[[Any], float] = _no_exec
    reply_bytes: Callable[[Any], int] = _default_reply


COMMANDS: dict[type[Request[Reply]], CommandSpec] = {}
"""Request class -> its command (filled by :func:`command`)."""


def command_of(req: Request[Reply]) -> CommandSpec | None:
    """The command ``req`` belongs to (None for a request no command sends)."""
    return COMMANDS.get(type(req))


def command(request: type[Request[Reply]], *, name: str, resend: bool,
            capability: Capability | None = None,
            exec_s: Callable[[Any], float] = _no_exec,
            reply_bytes: Callable[[Any], int] = _default_reply) -> Callable[[F], F]:
    """Declare a :class:`BoardClient` method as the command sending ``request`` (see
    :class:`CommandSpec`); the method sends it with :meth:`BoardClient.issue`."""

    def register(method: F) -> F:
        if request in COMMANDS:
            raise ValueError(f"{request.__name__} already has a command")
        COMMANDS[request] = CommandSpec(request, name, method.__name__, resend, capability,
                                        exec_s, reply_bytes)
        return method

    return register


@dataclass(frozen=True, slots=True)
class SpikeBatchResult:
    """Readings of one decision window.

    ``spikes[k] = (bin, group)`` of the k-th applied spike (absolute bin index, group index);
    ``codes[k][j]`` the ADC code of column ``columns[j]`` read for that spike.
    """

    spikes: tuple[tuple[int, int], ...]
    columns: tuple[int, ...]
    codes: tuple[tuple[int, ...], ...]
    round_trips: int = 1


def _spike_exec_s(req: SpikeBatch) -> float:
    return req.n_spikes() * 0.002 + (req.n_bins * req.bin_us * 1e-6 if req.paced else 0.0)


def _spike_reply_bytes(req: SpikeBatch) -> int:
    return spike_batch_reply_size(req.n_spikes(), len(req.columns))


def _window_exec_s(req: DecisionWindow) -> float:
    # an estimate: the window's spike draws and read per row and its bins (paced: real time);
    # without a parameter block in the request the board's held one, taken as the defaults
    p = req.params or DecisionParams()
    spikes = p.n_bins * p.spike_threshold / float(1 << 53)
    return spikes * len(req.rows) * 0.002 + p.n_bins * 20e-6 + (
        p.n_bins * p.bin_us * 1e-6 if req.paced else 0.0)


def _window_reply_bytes(req: DecisionWindow) -> int:
    p = req.params or DecisionParams()
    return 64 + (2 * 4 * p.n_bins // (p.ref_steps + 1) if req.motor_spikes else 0) + (
        4 * 4 * p.n_bins // req.trace_stride if req.trace_stride else 0)


class BoardClient(ABC):
    """Typed access to a board: the command surface (module docstring).

    Codes are raw DAC/ADC codes; ``info`` (the board's INFO, a
    :class:`~snan_hil.protocol.board.BoardConstants`; None before HELLO) converts them.
    Subclasses implement :meth:`request`, :meth:`counters_dict` and :meth:`close` and provide
    ``transport`` and ``info``.
    """

    #: How often spike_batch may halve a window chunk whose reply keeps getting lost.
    MAX_SPIKE_SPLITS = 32

    transport: Transport
    info: Info | None
    host_max_write_v: float | None = None
    window_params: DecisionParams | None = None
    """The DECISION_WINDOW parameter block the board holds, as far as this client knows
    (None: none; a HELLO or RESET makes the board forget it). Kept by :meth:`decision_window`
    so the block travels only when the board lacks it or it changes."""
    """The host's write limit (V) set by the user (``--max-write-v``); None: the board's
    ``max_write_v``. Host policy (protocol.safety), on both protocols."""

    # ------------------------------------------------------------------ what a client does
    @abstractmethod
    def request(self, req: Request[ReplyT]) -> ReplyT:
        """Send ``req`` as it is (no host-side check) and return its reply; raises the
        :mod:`~snan_hil.protocol.errors` of a refusal or a failed link."""

    @abstractmethod
    def counters_dict(self) -> dict[str, int]:
        """Host-side link counters by name."""

    @abstractmethod
    def close(self) -> None:
        """Close the transport."""

    # ------------------------------------------------------------------ plumbing
    @property
    def name(self) -> str:
        """The transport's name (the port), for messages."""
        return self.transport.name

    @property
    def constants(self) -> Info:
        """The board's INFO, or the defaults assumed before HELLO."""
        return self.info or Info()

    @property
    def limits(self) -> HostLimits:
        """Host-side safety limits from the board's INFO (its defaults before HELLO) and the
        configured write limit (``host_max_write_v``)."""
        return HostLimits.from_board(self.info or Info(), self.host_max_write_v)

    @property
    def payload_limit(self) -> int:
        """Largest request or reply payload on this link (bytes): the board's ``max_payload``
        (protocol maximum before HELLO)."""
        return self.info.max_payload if self.info is not None else MAX_PAYLOAD

    def unsupported(self, what: str) -> UnsupportedError:
        """The error for a command this board does not implement."""
        return UnsupportedError(f"board on {self.name} does not implement {what}")

    def issue(self, req: Request[ReplyT]) -> ReplyT:
        """``req`` as its command sends it (after the command's host-side checks): refused
        with UnsupportedError when the board's INFO lacks the command's capability, else
        :meth:`request`."""
        self._check_capability(req)
        return self.request(req)

    def _check_capability(self, req: Request[Reply]) -> None:
        spec = command_of(req)
        if spec is not None and spec.capability is not None and self.info is not None \
                and not self.info.has(spec.capability):
            raise self.unsupported(spec.name)

    # ------------------------------------------------------------------ two outstanding
    @property
    def pipelined(self) -> bool:
        """Whether a second request may be outstanding (:meth:`submit`); a client over a link
        that cannot (the legacy line protocol) is always stop-and-wait."""
        return False

    @pipelined.setter
    def pipelined(self, on: bool) -> None:
        if on:
            raise ValueError(f"the client on {self.name} sends one request at a time")

    def pipelinable(self, req: Request[Reply]) -> bool:
        """Whether ``req`` may be sent while another request is outstanding."""
        return False

    def submit(self, req: Request[ReplyT]) -> Any:
        """Send ``req`` and return a ticket for :meth:`collect` (here: the request runs at
        once; :class:`~snan_hil.protocol.link.LinkClient` keeps two outstanding)."""
        return _Done(self.request(req))

    def collect(self, ticket: Any) -> Any:
        """The reply of a :meth:`submit` ticket."""
        assert isinstance(ticket, _Done)
        return ticket.reply

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ the commands
    @command(Hello, name="HELLO", resend=True, reply_bytes=lambda _req: 256)
    def hello(self) -> Info:
        """Open the session: the board's INFO (constants, capabilities, boot nonce). The
        client keeps it as ``info``."""
        return self.issue(Hello())

    @command(ReadCell, name="READ_CELL", resend=True)
    def read_cell(self, row: int, col: int, dac_code: int | None = None) -> int:
        """ADC code of one cell read at write-DAC ``dac_code`` (default: INFO's
        ``read_code``; 0 = a 0 V offset read). HostSafetyError above the read limit."""
        code = self.constants.read_code if dac_code is None else int(dac_code)
        self.limits.check_reads((code,), f"READ_CELL ({row}, {col})")
        return self.issue(ReadCell(row, col, code)).adc

    @command(ReadColumn, name="READ_COLUMN", resend=True, capability=Capability.READ_COLUMN)
    def read_column(self, col: int, row_codes: Sequence[int]) -> int:
        """ADC code of a column multiply with row-DAC codes ``row_codes`` (one per row)."""
        self.limits.check_reads(row_codes, f"READ_COLUMN {col}", dac="row")
        return self.issue(ReadColumn(col, tuple(int(c) for c in row_codes))).adc

    @command(WritePulse, name="WRITE_PULSE", resend=False,
             exec_s=lambda req: req.width_us * 1e-6 + 0.002)
    def write_pulse(self, row: int, col: int, polarity: Polarity, amplitude_code: int,
                    width_us: int, read_code: int = 0) -> int:
        """Apply one pulse (write-DAC ``amplitude_code``, ``width_us`` µs) and return the ADC
        code of the read after it (at write-DAC ``read_code``; 0 = the board's read code).
        Never resent as a new request: a lost pulse is reconciled from STATUS by the caller."""
        limits = self.limits
        limits.check_write(amplitude_code, f"WRITE_PULSE ({row}, {col})")
        limits.check_reads((read_code,), f"WRITE_PULSE ({row}, {col})")
        req = WritePulse(row, col, Polarity(polarity), int(amplitude_code), int(width_us),
                         int(read_code))
        return self.issue(req).adc

    @command(SpikeBatch, name="SPIKE_BATCH", resend=True, capability=Capability.SPIKE_BATCH,
             exec_s=_spike_exec_s, reply_bytes=_spike_reply_bytes)
    def spike_batch(self, groups: Sequence[SpikeGroup], columns: Sequence[int],
                    n_bins: int = 1000, bin_us: int = 1000,
                    paced: bool = False) -> SpikeBatchResult:
        """Apply a decision window of spikes; per spike, read ``columns``.

        The window is split into as few SPIKE_BATCH requests as the max payload allows
        (``round_trips`` in the result); a chunk whose reply keeps getting lost is retried as
        two halves (reads only: applying spikes again is harmless). ``groups[g].bins`` are bin
        indices in ``0..n_bins-1``.
        """
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
        max_spikes = (self.payload_limit - spike_batch_reply_size(0, 0)) // max(1, per_spike)
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
                reply = self.issue(req)
            except LinkTimeoutError as exc:
                busy_bins = sorted({b for b, _ in order if lo <= b < hi})
                if not exc.retryable or len(busy_bins) < 2 or splits >= self.MAX_SPIKE_SPLITS:
                    raise
                splits += 1
                mid = busy_bins[len(busy_bins) // 2]
                log.info("%s: SPIKE_BATCH bins %d..%d lost; retrying as two halves",
                         self.name, lo, hi - 1)
                todo += [(mid, hi), (lo, mid)]
                continue
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

    @command(ProgramCell, name="PROGRAM_CELL", resend=False, capability=Capability.PROGRAM_CELL,
             exec_s=lambda req: req.max_pulses * (req.width_us * 1e-6 + 0.003))
    def program_cell(self, row: int, col: int, target_adc: int, tolerance_adc: int, *,
                     max_pulses: int = 100, amp_start_code: int = 0, amp_stop_code: int = 0,
                     amp_step_code: int = 0, width_us: int = 100, read_code: int = 0,
                     fine_tune: bool = True) -> ProgramCellReply:
        """Firmware write-and-verify of one cell (see :class:`ProgramCell`).

        Amplitude codes left at 0 mean the old host's ramp: 0.3 -> 1.2 V in 0.01 V steps.
        Never resent as a new request (it pulses).
        """
        limits = self.limits
        for code in (amp_start_code, amp_stop_code):
            limits.check_write(code, f"PROGRAM_CELL ({row}, {col})")
        limits.check_reads((read_code,), f"PROGRAM_CELL ({row}, {col})")
        return self.issue(ProgramCell(row, col, target_adc, tolerance_adc, max_pulses,
                                        amp_start_code, amp_stop_code, amp_step_code, width_us,
                                        read_code, fine_tune))

    @command(DecisionWindow, name="DECISION_WINDOW", resend=True,
             capability=Capability.DECISION_WINDOW, exec_s=_window_exec_s,
             reply_bytes=_window_reply_bytes)
    def decision_window(self, key: int, rows: Sequence[int],
                        candidates: Sequence[DecisionCandidate], params: DecisionParams, *,
                        motor_spikes: bool = False, trace_stride: int = 0,
                        paced: bool = False) -> DecisionWindowReply:
        """Run one decision window on the board (see :class:`DecisionWindow`): the parameter
        block travels only when the board does not hold it yet (first window of a session,
        after HELLO or RESET, or when it changes). Resent as a new request after a lost reply:
        a window changes nothing on the chip. MalformedPayloadError unless the reply has one
        count per candidate and the sections asked for."""
        req = self.window_request(key, rows, candidates, params, motor_spikes=motor_spikes,
                                  trace_stride=trace_stride, paced=paced)
        return self.window_reply(req, params, self.issue(req))

    def window_request(self, key: int, rows: Sequence[int],
                       candidates: Sequence[DecisionCandidate], params: DecisionParams, *,
                       motor_spikes: bool = False, trace_stride: int = 0,
                       paced: bool = False) -> DecisionWindow:
        """The DECISION_WINDOW of :meth:`decision_window`, after its host-side checks (to
        :meth:`submit` it while another window runs; :meth:`window_reply` checks the reply)."""
        self.limits.check_reads((params.row_code,), "DECISION_WINDOW", dac="row")
        req = DecisionWindow(int(key), tuple(int(r) for r in rows), tuple(candidates),
                             None if params == self.window_params else params,
                             bool(motor_spikes), int(trace_stride), bool(paced))
        self._check_capability(req)
        return req

    def window_reply(self, req: DecisionWindow, params: DecisionParams,
                     reply: DecisionWindowReply) -> DecisionWindowReply:
        """``reply`` to ``req`` checked (see :meth:`decision_window`); the board now holds
        ``params``."""
        if (len(reply.counts) != len(req.candidates)
                or (reply.motor_spikes is None) == req.motor_spikes
                or (reply.trace is None) == bool(req.trace_stride)):
            raise MalformedPayloadError(
                f"board on {self.name} answered DECISION_WINDOW with {len(reply.counts)} "
                f"counts for {len(req.candidates)} candidates (or without the sections asked)")
        self.window_params = params
        return reply

    # -- on-board learning (issue 34 stage 1; docs/protocol.md "On-board learning") ------
    @command(LearnSetup, name="LEARN_SETUP", resend=True, capability=Capability.LEARN)
    def learn_setup(self, block: LearnSetup) -> LearnSetupReply:
        """Give the board its learning block and the session's synapses (replaces its learning
        state). The learning pulse's amplitudes are checked against the host's write limit
        first. Resent after a lost reply: the same block gives the same state."""
        for code in (block.set_code, block.reset_code):
            self.limits.check_write(code, "LEARN_SETUP's learning pulse")
        return self.issue(block)

    @command(LearnWindow, name="LEARN_WINDOW", resend=True, capability=Capability.LEARN,
             exec_s=lambda req: _window_exec_s(req.window_req),
             reply_bytes=lambda req: _window_reply_bytes(req.window_req))
    def learn_window(self, trial: int, window: int, decided: int, key: int,
                     rows: Sequence[int], candidates: Sequence[DecisionCandidate],
                     params: DecisionParams) -> LearnWindowReply:
        """A decision window of training trial ``trial`` (its index ``window``) whose STDP the
        board computes; ``decided``: the lane the host chose in the window before
        (:data:`LEARN_NO_LANE`: none). Resent after a lost reply: the board keys a window by
        (trial, window), so a repeated one applies no decision twice."""
        inner = self.window_request(key, rows, candidates, params)
        req = LearnWindow(int(trial), int(window), int(decided), inner)
        self._check_capability(req)
        reply = self.issue(req)
        self.window_reply(inner, params, reply)
        return reply

    @command(LearnApply, name="LEARN_APPLY", resend=False, capability=Capability.LEARN,
             exec_s=lambda req: 0.5)
    def learn_apply(self, trial: int, window: int, decided: int = LEARN_NO_LANE
                    ) -> LearnApplyReply:
        """End training trial ``trial`` (its last window ``window`` and the decision on it):
        the board plans and applies the trial's pulses. Never resent as a new request (it
        pulses); a repeat of an applied trial is answered ``already``."""
        return self.issue(LearnApply(int(trial), int(window), int(decided)))

    @command(LearnState, name="LEARN_STATE", resend=True, capability=Capability.LEARN)
    def learn_state(self, first: int = 0, count: int = 255) -> LearnStateReply:
        """The board's learning state and ledger of synapses ``first ..``."""
        return self.issue(LearnState(int(first), int(count)))

    @command(Status, name="STATUS", resend=True)
    def status(self) -> StatusReply:
        """The board's counters (STATUS)."""
        return self.issue(Status())

    @command(Clock, name="CLOCK", resend=True, capability=Capability.CLOCK)
    def clock(self) -> ClockReply:
        """Board time (µs) and array energy (J) since boot/RESET."""
        return self.issue(Clock())

    @command(Reset, name="RESET", resend=False, capability=Capability.RESET)
    def reset(self) -> ResetReply:
        """Soft-reset the board (clock, energy, counters; a new boot nonce, which the client
        learns from the reply). Never resent as a new request."""
        return self.issue(Reset())


@dataclass(frozen=True)
class _Done:
    """The ticket of a request a stop-and-wait client ran at once."""

    reply: Any


class ClientBase(BoardClient):
    """What a client over one transport holds: ``transport``, ``info``, a counters
    dataclass, ``counters_dict()`` and ``close()``."""

    counters: Any   # a dataclass of ints

    def __init__(self, transport: Transport) -> None:
        self.transport = transport
        self.info = None

    def counters_dict(self) -> dict[str, int]:
        """Host-side link counters as a dict."""
        return dataclasses.asdict(self.counters)

    def close(self) -> None:
        """Close the transport."""
        self.transport.close()


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
