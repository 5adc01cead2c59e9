"""Pulse tickets: one planned pulse experiment on one cell (``snan-hil pulse``).

A ticket (the existing host's term, shared/reference/memricore-board.md) is a list of write
pulses of one polarity — a single amplitude or a ramp ``start:stop:step`` (V), each amplitude
``count`` times, all ``width_us`` wide — with a read after every pulse, and an optional stop
condition checked before the first pulse and after every read:

* ``until_g_s``: SET stops once G >= it, RESET once G <= it;
* ``window``: ``(G, p)``, stop at the first read inside ``G (1 +- p)``.

A pulse the compliance limit forbids at the cell's last conductance ends the ticket (the
existing host skipped such pulses; skipping would make the next, larger amplitude of a ramp
even more likely to be refused). The host's safety limits (largest write amplitude, read
voltage, compliance) are enforced by the cell's IO
(:class:`~snan_hil.calibration.board_io.BoardCellIO`); :func:`check_ticket` refuses a ticket
above the board's write limit before anything is sent.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Any, ClassVar

from snan_hil.calibration.observer import CellEvent, CellObserver, PulseEvent
from snan_hil.calibration.wv import CellIO, PulseNotApplied
from snan_hil.common.errors import UserError
from snan_hil.common.polarity import Polarity
from snan_hil.common.progress import ProgressCallback, track
from snan_hil.protocol.board import BoardConstants

__all__ = ["MAX_TICKET_PULSES", "MAX_WIDTH_US", "parse_amplitudes", "parse_conductance",
           "parse_window", "PulseTicket", "TicketStep", "TicketResult", "check_ticket",
           "run_ticket", "PulseTicketJob", "TicketRun", "TICKET_NAMES"]

MAX_TICKET_PULSES = 10_000
"""Most pulses one ticket may plan (the existing host's largest stock ticket has ~564)."""
MAX_WIDTH_US = 1_000_000
"""Longest pulse a ticket may ask for, us (the emulated firmware's limit,
``firmware_emu.config.BoardConfig.max_pulse_width_us``; the real board's is not public)."""


class TicketError(UserError):
    """A ticket that cannot be run as given (one line, exit code 2)."""


def parse_amplitudes(text: str) -> tuple[float, ...]:
    """``"0.8"`` -> (0.8,); ``"0.3:1.2:0.01"`` -> 0.3, 0.31, ..., 1.2 (V; the stop value is
    included when the steps land on it). TicketError for anything else, a step of 0, a step
    pointing away from the stop value (a ramp that never ends) or more than
    :data:`MAX_TICKET_PULSES` amplitudes."""
    parts = [p.strip() for p in str(text).split(":")]
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise TicketError(f"--amplitude {text!r}: give volts, V or START:STOP:STEP, e.g. 0.8 "
                          "or 0.3:1.2:0.01") from None
    if not all(math.isfinite(v) for v in values):
        raise TicketError(f"--amplitude {text!r}: amplitudes must be finite numbers of volts")
    amps: tuple[float, ...]
    if len(values) == 1:
        amps = (values[0],)
    elif len(values) == 3:
        start, stop, step = values
        if start == stop:
            amps = (start,)
        elif step == 0 or (stop - start) * step < 0:
            hint = math.copysign(abs(step) or 0.01, stop - start)
            raise TicketError(f"--amplitude {text}: a ramp from {start:g} V to {stop:g} V with "
                              f"step {step:g} V never ends; give a step with the sign of "
                              f"STOP-START, e.g. {start:g}:{stop:g}:{hint:g}")
        else:
            n = int(math.floor((stop - start) / step + 1e-9)) + 1
            if n > MAX_TICKET_PULSES:
                raise TicketError(f"--amplitude {text}: {n} amplitudes; a ticket may plan at most "
                                  f"{MAX_TICKET_PULSES} pulses, give a larger step")
            amps = tuple(round(start + i * step, 6) for i in range(n))
    else:
        raise TicketError(f"--amplitude {text!r}: give V or START:STOP:STEP (three numbers)")
    if min(amps) <= 0:
        raise TicketError(f"--amplitude {text}: amplitudes must be above 0 V (the polarity "
                          "gives the direction)")
    return amps


_UNITS = {"": 1e-6, "us": 1e-6, "µs": 1e-6, "usiemens": 1e-6, "ms": 1e-3, "s": 1.0, "ns": 1e-9}


def parse_conductance(text: str, option: str = "--until-g") -> float:
    """``"500"`` (uS), ``"500uS"``, ``"0.5mS"``, ``"5e-4S"`` -> S (> 0)."""
    m = re.fullmatch(r"\s*([-+0-9.eE]+)\s*([a-zA-Zµ]*)\s*", str(text))
    unit = m.group(2).lower() if m else ""
    if m is None or unit not in _UNITS:
        raise TicketError(f"{option} {text!r}: give a conductance such as 500 (uS), 500uS, "
                          "0.5mS or 5e-4S")
    try:
        value = float(m.group(1)) * _UNITS[unit]
    except ValueError:
        raise TicketError(f"{option} {text!r}: {m.group(1)!r} is not a number") from None
    if not (math.isfinite(value) and value > 0):
        raise TicketError(f"{option} {text!r}: the conductance must be above 0")
    return value


def parse_window(text: str) -> tuple[float, float]:
    """``"500±10%"``, ``"500uS+-10%"``, ``"0.5mS+/-5"`` -> (G in S, relative half-width)."""
    m = re.fullmatch(r"\s*(.+?)\s*(?:±|\+-|\+/-)\s*([0-9.eE+-]+)\s*%?\s*", str(text))
    if m is None:
        raise TicketError(f"--window {text!r}: give G±P, e.g. 500±10% or 500uS+-10% "
                          "(G in uS unless a unit is given, P in percent)")
    g = parse_conductance(m.group(1), "--window")
    try:
        p = float(m.group(2)) / 100.0
    except ValueError:
        raise TicketError(f"--window {text!r}: {m.group(2)!r} is not a percentage") from None
    if not 0 < p < 1:
        raise TicketError(f"--window {text!r}: the window's half-width must be between 0 and "
                          "100 %")
    return g, p


@dataclass(frozen=True)
class PulseTicket:
    """One planned experiment (V, us, S); :meth:`plan` lists its pulse amplitudes in order."""

    row: int
    col: int
    polarity: Polarity
    amplitudes_v: tuple[float, ...]
    width_us: int = 100
    count: int = 1                                  # pulses at each amplitude
    until_g_s: float | None = None
    window: tuple[float, float] | None = None       # (G in S, relative half-width)

    def plan(self) -> list[float]:
        return [a for a in self.amplitudes_v for _ in range(self.count)]

    def condition(self) -> str:
        if self.until_g_s is not None:
            op = ">=" if self.polarity == Polarity.SET else "<="
            return f"G {op} {self.until_g_s * 1e6:g} uS"
        if self.window is not None:
            return f"G in {self.window[0] * 1e6:g} uS +-{self.window[1]:.0%}"
        return "all pulses"

    def met(self, g: float) -> bool:
        if not math.isfinite(g):
            return False
        if self.until_g_s is not None:
            return g >= self.until_g_s if self.polarity == Polarity.SET else g <= self.until_g_s
        if self.window is not None:
            target, p = self.window
            return abs(g / target - 1.0) <= p
        return False

    def to_dict(self) -> dict[str, Any]:
        """The planned ticket: one ``amplitude_v``, or a ramp as ``start_v``, ``stop_v`` (the
        last amplitude planned), ``step_v`` and ``steps`` (number of amplitudes); V as asked
        (each pulse's applied, DAC-quantised voltage is in the result's steps)."""
        amps = self.amplitudes_v
        plan: dict[str, Any] = ({"amplitude_v": amps[0]} if len(amps) == 1 else
                                {"start_v": amps[0], "stop_v": amps[-1],
                                 "step_v": round(amps[1] - amps[0], 6), "steps": len(amps)})
        return {"row": self.row, "col": self.col, "polarity": self.polarity.name, **plan,
                "width_us": self.width_us, "count": self.count, "until_g_s": self.until_g_s,
                "window": list(self.window) if self.window else None,
                "condition": self.condition(), "planned_pulses": len(self.plan())}


TICKET_NAMES = {"cell": "cell", "amplitude": "amplitude_v", "width_us": "width_us",
                "count": "count", "max_write_v": "max_write_v"}
"""How :func:`check_ticket` names a ticket's fields by default (a notebook's keywords); the
command line passes its options (``--cell``, ``--amplitude``, ...)."""


def check_ticket(ticket: PulseTicket, board: BoardConstants,
                 max_write_v: float | None = None, *,
                 names: dict[str, str] | None = None) -> None:
    """TicketError (one line) unless the ticket fits the board: cell inside the array,
    amplitudes at most the host's write limit, width and counts in range. ``names``: how
    the messages call the fields (default :data:`TICKET_NAMES`).

    ``max_write_v``: the session's write limit (V; :mod:`snan_hil.protocol.safety`: the
    board's, lowered by ``--max-write-v``); None: the board's ``max_write_v``."""
    n_ = {**TICKET_NAMES, **(names or {})}
    if not (0 <= ticket.row < board.rows and 0 <= ticket.col < board.cols):
        raise TicketError(f"{n_['cell']} {ticket.row},{ticket.col} is outside the "
                          f"{board.rows}x{board.cols} array (rows 0..{board.rows - 1}, "
                          f"columns 0..{board.cols - 1})")
    top = max(ticket.amplitudes_v)
    lsb = board.write_dac_volts(1)
    if min(ticket.amplitudes_v) < lsb:
        raise TicketError(f"{n_['amplitude']}: {min(ticket.amplitudes_v):g} V is below the "
                          f"write DAC's smallest step {lsb:.4f} V; give larger amplitudes")
    limit = board.max_write_v if max_write_v is None else float(max_write_v)
    if top > limit + 1e-9:
        option = n_["max_write_v"]
        whose = (f"the board's max_write_v; {option} can only lower it"
                 if max_write_v is None else f"the board's, lowered by {option}")
        raise TicketError(f"{n_['amplitude']}: {top:g} V is above the host's write limit "
                          f"{limit:g} V ({whose}); lower the amplitude")
    if not 1 <= ticket.width_us <= MAX_WIDTH_US:
        raise TicketError(f"{n_['width_us']} {ticket.width_us}: give 1..{MAX_WIDTH_US} us")
    if ticket.count < 1:
        raise TicketError(f"{n_['count']} {ticket.count}: give at least 1 pulse per "
                          "amplitude")
    n = len(ticket.plan())
    if n > MAX_TICKET_PULSES:
        raise TicketError(f"the ticket plans {n} pulses; at most {MAX_TICKET_PULSES} (lower "
                          f"{n_['count']} or use a larger ramp step)")


@dataclass(frozen=True)
class TicketStep:
    """One pulse of a ticket and the read after it (V, S); ``amplitude_v`` is the applied
    voltage (the write DAC code's, at most the planned one)."""

    n: int
    amplitude_v: float
    g_before_s: float
    g_after_s: float


@dataclass
class TicketResult:
    """What a ticket did: the read before, every pulse, why it stopped."""

    ticket: PulseTicket
    initial_s: float
    steps: list[TicketStep] = field(default_factory=list)
    stopped: str = ""
    condition_met: bool = False

    @property
    def final_s(self) -> float:
        return self.steps[-1].g_after_s if self.steps else self.initial_s

    def to_dict(self) -> dict[str, Any]:
        return {"ticket": self.ticket.to_dict(), "initial_s": self.initial_s,
                "final_s": self.final_s, "pulses": len(self.steps), "stopped": self.stopped,
                "condition_met": self.condition_met,
                "steps": [s.__dict__ for s in self.steps]}


def run_ticket(io: CellIO, ticket: PulseTicket, *, observer: CellObserver | None = None,
               progress: ProgressCallback | None = None) -> TicketResult:
    """Run ``ticket`` on the cell behind ``io`` (read, then pulse + read until the condition,
    the plan's end or the compliance limit). ``observer`` gets every pulse (stage "ticket")
    and the result (outcome = why it stopped); ``progress`` the task "pulse ticket" (one unit
    per planned pulse)."""
    g = float(io.read())
    res = TicketResult(ticket, g)
    plan = ticket.plan()
    bar = track(progress, "pulse ticket", len(plan))
    events: list[PulseEvent] = []
    if ticket.met(g):
        res.stopped, res.condition_met = f"condition {ticket.condition()} already met", True
    else:
        res.stopped = f"all {len(plan)} planned pulses applied"
        for v in plan:
            cap = float(io.amplitude_cap(ticket.polarity, g)) if g > 0 else v
            if v > cap + 1e-9:
                res.stopped = (f"compliance: a {v:g} V pulse at G = {g * 1e6:.1f} uS would draw "
                               f"more than the current limit (at most {cap:.2f} V now)")
                break
            applied_log = getattr(io, "applied", None)
            logged = len(applied_log) if applied_log is not None else 0
            try:
                after = float(io.pulse(ticket.polarity, v))
            except PulseNotApplied:
                g = float(io.read())
                continue
            # the applied amplitude: the write DAC code's voltage (at most v) when the IO
            # logs it, else the planned one
            v_applied = (float(applied_log[-1].amplitude_v)
                         if applied_log is not None and len(applied_log) > logged else v)
            step = TicketStep(len(res.steps) + 1, v_applied, g, after)
            res.steps.append(step)
            events.append(PulseEvent(ticket.row, ticket.col, ticket.polarity, v_applied,
                                     ticket.width_us, g, after, "ticket"))
            g = after
            bar.advance(1, f"{v_applied:.3f} V -> {g * 1e6:.1f} uS")
            if ticket.met(g):
                res.stopped, res.condition_met = f"condition {ticket.condition()} met", True
                break
    if observer is not None:
        applied = getattr(io, "applied", None)
        if applied:                       # the IO's log has the DAC code's exact voltage
            events = list(applied)
        if events:
            observer.on_pulses(events)
        observer.on_cell(CellEvent(ticket.row, ticket.col, res.stopped, res.final_s,
                                   target_s=ticket.until_g_s or (ticket.window or (None,))[0],
                                   pulses=len(res.steps),
                                   detail={"initial_s": res.initial_s,
                                           "ticket": ticket.to_dict()}))
    return res


@dataclass
class TicketRun:
    """A ticket run by :class:`PulseTicketJob`: the result, where the reads' conductances came
    from (``read_chain``), and the programmed synapse the ticket changed (``stale``: its
    pre, post and the layout file, marked stale there; None when the cell held none)."""

    result: TicketResult
    read_chain: str
    stale: dict[str, Any] | None = None


class PulseTicketJob:
    """``snan-hil pulse`` as a board job (:mod:`snan_hil.calibration.job`): one unit, the
    ticket on its cell. A programmed synapse on that cell is marked stale in the board's
    layout once the ticket changed it (a run must not take it for its programmed weight)."""

    kind: ClassVar[str] = "pulse"
    restartable: ClassVar[bool] = False

    def __init__(self, ticket: PulseTicket, *, names: dict[str, str] | None = None) -> None:
        self.ticket = ticket
        self.names = names
        self._run: TicketRun | None = None

    def describe(self) -> dict[str, Any]:
        return self.ticket.to_dict()

    def plan(self, bench: Any) -> tuple[Any, ...]:
        from snan_hil.calibration.job import ONE
        check_ticket(self.ticket, bench.info, bench.limits.max_write_v, names=self.names)
        synapse = self._synapse(bench)
        if synapse is not None:
            from snan_hil.calibration.layout import check_layout_writable
            check_layout_writable(bench.layout_path)
            bench.warn(f"cell ({self.ticket.row},{self.ticket.col}) holds synapse "
                       f"{synapse.pre}->{synapse.post} of {bench.layout_path} (programmed "
                       f"weight {synapse.weight:.3f}); the ticket changes it, so the layout "
                       "marks it stale until program-weights writes it again")
        return ONE

    def _synapse(self, bench: Any) -> Any:
        layout = bench.layout
        synapse = layout.synapse_at(self.ticket.row, self.ticket.col) \
            if layout is not None else None
        return synapse if synapse is not None and synapse.weight is not None else None

    def run_unit(self, unit: Any, bench: Any, ctx: Any) -> dict[str, Any]:
        t = self.ticket
        io = bench.cell(t.row, t.col, stage="ticket", width_us=t.width_us)
        res = run_ticket(io, t, observer=bench.cell_results, progress=ctx.progress)
        stale = None
        synapse = self._synapse(bench)
        if synapse is not None and res.steps:
            synapse.stale = (f"pulse ticket {t.polarity.name} x{len(res.steps)}: "
                             f"{res.initial_s * 1e6:.1f} -> {res.final_s * 1e6:.1f} uS")
            synapse.ok = False
            bench.layout.save(bench.layout_path)
            stale = {"pre": synapse.pre, "post": synapse.post,
                     "layout": str(bench.layout_path)}
        self._run = TicketRun(res, bench.chain_source, stale)
        return res.to_dict()

    def restore(self, unit: Any, record: dict[str, Any]) -> None:
        raise NotImplementedError("a pulse ticket is not resumed")

    def result(self, records: Any, status: str) -> TicketRun:
        if self._run is None:
            raise RuntimeError("the ticket did not run")
        return self._run

    def summary(self, result: TicketRun) -> dict[str, Any]:
        return {k: v for k, v in result.result.to_dict().items() if k != "steps"}
