"""What the calibration jobs tell an observer about the cells they touch: the recording hook.

Programming (:func:`~snan_hil.calibration.programmer.program_weights`), cell screening
(:mod:`~snan_hil.calibration.screening`) and pulse tickets (:mod:`~snan_hil.calibration.tickets`)
report every applied pulse (:class:`PulseEvent`) and every cell's result (:class:`CellEvent`)
to an optional :class:`CellObserver`. The chip history database
(:class:`snan_hil.records.history.Recorder`) is one; the CLI's trace figure of ``program-weights
--trace`` another (:class:`TraceCollector`). Write-and-verify itself knows nothing of them:
:class:`~snan_hil.calibration.board_io.BoardCellIO` keeps a log of the pulses it applied and
the job hands that log over when the cell is done.

Observers must not raise: a database problem is theirs to report (the Recorder warns once and
goes on), never a reason to stop programming.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

from snan_hil.common.polarity import Polarity

__all__ = ["PulseEvent", "CellEvent", "CellObserver", "Observers", "TraceCollector"]


@dataclass(frozen=True)
class PulseEvent:
    """One applied write pulse on cell (row, col): amplitude in V (the DAC code's voltage),
    width in us, conductance read before (None: not read yet) and after (S); ``stage`` "1" /
    "2" (write-and-verify), "probe" / "restore" (screening), "ticket" (pulse tickets)."""

    row: int
    col: int
    polarity: Polarity
    amplitude_v: float
    width_us: int
    g_before_s: float | None
    g_after_s: float
    stage: str | None = None


@dataclass(frozen=True)
class CellEvent:
    """A cell's result in a job: ``outcome`` (programming: "ok" / "failed"; screening: the
    class; tickets: why it stopped), conductance now and target (S), pulses applied to it in
    this job, anything else in ``detail`` (JSON-able)."""

    row: int
    col: int
    outcome: str
    g_s: float | None
    target_s: float | None = None
    pulses: int | None = None
    detail: dict[str, Any] = field(default_factory=dict)


class CellObserver(Protocol):
    """Receives the pulses and results of a calibration job (must not raise)."""

    def on_pulses(self, events: Sequence[PulseEvent]) -> None: ...

    def on_cell(self, event: CellEvent) -> None: ...


class Observers:
    """Several observers as one (each gets every event, in order)."""

    def __init__(self, *observers: CellObserver | None) -> None:
        self.observers = [o for o in observers if o is not None]

    def on_pulses(self, events: Sequence[PulseEvent]) -> None:
        for o in self.observers:
            o.on_pulses(events)

    def on_cell(self, event: CellEvent) -> None:
        for o in self.observers:
            o.on_cell(event)


@dataclass
class CellTrace:
    """Write-and-verify of one cell as the trace figure needs it (conductances in S)."""

    row: int
    col: int
    initial_s: float | None
    pulses: list[PulseEvent] = field(default_factory=list)
    target_s: float | None = None
    outcome: str = ""
    weight: float | None = None


class TraceCollector:
    """Keeps every cell's pulses and result of a programming run (for ``program-weights
    --trace``): ``traces[(row, col)]`` in the order the cells finished."""

    def __init__(self) -> None:
        self.traces: dict[tuple[int, int], CellTrace] = {}
        self._pending: dict[tuple[int, int], list[PulseEvent]] = {}

    def on_pulses(self, events: Sequence[PulseEvent]) -> None:
        for e in events:
            self._pending.setdefault((e.row, e.col), []).append(e)

    def on_cell(self, event: CellEvent) -> None:
        key = (event.row, event.col)
        pulses = self._pending.pop(key, [])
        initial = event.detail.get("initial_s")
        if initial is None and pulses:
            initial = pulses[0].g_before_s
        self.traces[key] = CellTrace(event.row, event.col, initial, pulses, event.target_s,
                                     event.outcome, event.detail.get("weight"))
