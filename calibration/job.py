"""What a board job is, as the job runner (:mod:`snan_hil.lab.runner`) runs it.

A job is a small typed class (the PyMeasure ``Procedure`` / bluesky plan idea): it declares its
configuration as a dataclass (``config``), and is cut along three seams the runner calls:

* :meth:`BoardJob.plan` -- the job's units, computed from its config and the board (the cell
  bench: INFO, layout, limits) *before* anything changes on the chip: every check of the
  user's input against the board belongs here (UserError, one line, nothing sent);
* :meth:`BoardJob.run_unit` -- one unit on the bench; returns the unit's record (JSON-able),
  which the runner commits to the run's checkpoint when the run has one (``--resume`` takes it
  from there instead of running the unit again: :meth:`BoardJob.restore`);
* :meth:`BoardJob.result` -- the job's result from every unit's record (``status``
  "complete", or "interrupted" when a stop or Ctrl-C ended the run: then the records of the
  units that finished).

Units are small frozen dataclasses with a ``key`` (unique in the job; the checkpoint's and the
pulse journal's name for the unit) and a ``group`` (the units of one group run in order on one
board: a learning session's cycles; ``None``: every unit is its own group).

A job never imports the runner, never opens a board, never builds limits, a ledger, a recorder
or a control channel: the runner gives it the :class:`~snan_hil.calibration.bench.CellBench`
and the :class:`UnitContext`. The same job runs from the command line and from a notebook.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Generic, Protocol, TypeVar

from snan_hil.calibration.bench import CellBench
from snan_hil.common.progress import ProgressCallback
from snan_hil.records.journal import JournalPulse

__all__ = ["Unit", "UnitContext", "UnitStore", "BoardJob", "SingleUnit", "ONE", "check_cells"]


class Unit(Protocol):
    """A unit of a job: ``key`` (unique in the job), ``group`` (units of a group run in order on
    one board; None: the unit alone)."""

    @property
    def key(self) -> str: ...

    @property
    def group(self) -> str | None: ...


@dataclass(frozen=True)
class SingleUnit:
    """The one unit of a job that is not cut (a pulse ticket, a map, a programming run)."""

    key: str = "all"
    group: str | None = None


ONE = (SingleUnit(),)
"""The units of a job that runs as one piece."""


class UnitStore(Protocol):
    """The run's checkpoint as a unit sees it (:class:`snan_hil.host.checkpoint.RunFolder`):
    a unit may commit named parts of itself before its end (a learning cycle commits its pulse
    plan before its first pulse) and keep files (chip snapshots)."""

    def done(self, unit: str) -> dict[str, Any] | None: ...

    def commit(self, unit: str, data: Mapping[str, Any]) -> None: ...

    def path(self, name: str) -> Path: ...


def check_cells(cells: Sequence[tuple[int, int]], board: Any, name: str = "cells") -> None:
    """UserError (one line naming ``name``) unless every cell is inside the board's array
    (``board``: its INFO: ``rows``, ``cols``) and none is named twice."""
    from snan_hil.common.errors import UserError
    if not cells:
        raise UserError(f"{name}: no cell given")
    seen: set[tuple[int, int]] = set()
    for row, col in cells:
        if not (0 <= row < board.rows and 0 <= col < board.cols):
            raise UserError(f"{name}: cell {row},{col} is outside the {board.rows}x{board.cols} "
                            f"array (rows 0..{board.rows - 1}, columns 0..{board.cols - 1})")
        if (row, col) in seen:
            raise UserError(f"{name}: cell {row},{col} is named twice; give each cell once")
        seen.add((row, col))


UnitT = TypeVar("UnitT", bound=Unit)
ResultT = TypeVar("ResultT")


@dataclass
class UnitContext:
    """What a unit gets besides the bench: ``progress`` (the run's progress callback: the
    terminal's bar and the run's documents), ``emit(stream, data)`` (an event of one of the
    run's document streams, written at once: a live view sees it), ``store`` (the run's
    checkpoint, None without one), ``board`` (the board's number in a run over several boards,
    None on one board), ``earlier`` (the pulses the run's journal holds of earlier attempts of
    this unit: a resumed unit knows which of its pulses ran, which may have, which did not),
    ``attempt`` (0 the first time the unit runs)."""

    progress: ProgressCallback | None = None
    emit: Callable[[str, dict[str, Any]], None] = field(default=lambda _s, _d: None)
    store: UnitStore | None = None
    board: int | None = None
    earlier: Sequence[JournalPulse] = ()
    attempt: int = 0


class BoardJob(Protocol, Generic[UnitT, ResultT]):
    """See the module docstring. ``kind``: the history run kind (records.history.KINDS);
    ``restartable``: a unit that did not finish is run again from a snapshot of the emulated
    chip taken before it (the runner saves and puts it back; a real chip cannot be put back,
    so there the unit starts again from what the chip holds). Each unit of a restartable job
    runs on its own session of the board (a fresh connection: on the in-process emulator a
    fresh boot of the saved chip), given by the runner once the job is planned on the run's
    session, which it then closes: a chip can be saved and put back only while no
    connection holds it (when the runner was given an open session, e.g. a notebook's, the
    units run on that one)."""

    kind: ClassVar[str]
    restartable: ClassVar[bool]

    def describe(self) -> dict[str, Any]:
        """The job's configuration as recorded with the run (JSON-able)."""

    def plan(self, bench: CellBench) -> Sequence[UnitT]:
        """The units, after every check against the board (UserError: nothing sent)."""

    def run_unit(self, unit: UnitT, bench: CellBench, ctx: UnitContext) -> dict[str, Any]:
        """Run ``unit``; its record (JSON-able)."""

    def restore(self, unit: UnitT, record: dict[str, Any]) -> None:
        """Take the committed record of ``unit`` (a resumed run)."""

    def result(self, records: Mapping[str, dict[str, Any]], status: str) -> ResultT:
        """The result from the units' records (in unit order)."""

    def summary(self, result: ResultT) -> dict[str, Any] | None:
        """What the history's run row and RunStop carry of the result."""
