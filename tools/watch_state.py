"""What ``snan-hil watch`` shows, computed from a run's documents (pure, no terminal): the
live state of one run, updated document by document (:class:`RunView`), and where the
documents come from (:class:`HistorySource`: a running or finished run in the history
database, polled; :class:`ReplaySource`: a finished run's documents fed at a rate).

The view keeps, per cell, the last conductance seen (after a pulse, a cell result or a read),
the pulses applied, the last result; the conductance trace of the cell the run works on now
(after each of its pulses and reads); the progress of each task; the last pulses (the pulse
log); for hardware runs each launch's path and astrocyte calcium and the successful path
lengths per scenario (for running medians).
"""

from __future__ import annotations

import statistics
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from snan_hil.common.errors import UserError
from snan_hil.records.history import History

__all__ = ["RunView", "HistorySource", "ReplaySource", "LOG_LINES", "TRACE_POINTS"]

LOG_LINES = 200
"""Pulses the pulse log keeps."""
TRACE_POINTS = 400
"""Conductances the trace of the running cell keeps (its newest)."""


@dataclass
class LaunchView:
    scenario: str
    launch: int
    steps: int
    success: bool
    path: list[int]
    calcium: list[float]
    rows: int
    cols: int
    ca_thr: float
    set_index: int = 0


@dataclass
class RunView:
    """The state of one run after the documents fed so far (:meth:`feed`)."""

    rows: int = 32
    cols: int = 8
    start: dict[str, Any] | None = None
    stop: dict[str, Any] | None = None
    g: dict[tuple[int, int], float] = field(default_factory=dict)
    pulses: dict[tuple[int, int], int] = field(default_factory=dict)
    outcome: dict[tuple[int, int], str] = field(default_factory=dict)
    progress: dict[str, dict[str, Any]] = field(default_factory=dict)
    log: deque = field(default_factory=lambda: deque(maxlen=LOG_LINES))
    launches: list[LaunchView] = field(default_factory=list)
    steps_ok: dict[str, list[int]] = field(default_factory=dict)
    launches_per_scenario: dict[str, int] = field(default_factory=dict)
    controls: list[str] = field(default_factory=list)
    trace_cell: tuple[int, int] | None = None
    """The cell the run works on now (its last pulse or read)."""
    trace: deque = field(default_factory=lambda: deque(maxlen=TRACE_POINTS))
    """That cell's conductances in this run, in order: (G in S, what: SET / RESET / read)."""
    trace_total: int = 0
    events: int = 0
    total_pulses: int = 0
    cells_done: int = 0
    _streams: dict[str, str] = field(default_factory=dict)

    def feed(self, docs: Iterable[tuple[str, dict[str, Any]]]) -> int:
        """Take documents in order; returns how many."""
        n = 0
        for name, doc in docs:
            n += 1
            if name == "start":
                self.start = doc
            elif name == "stop":
                self.stop = doc
            elif name == "descriptor":
                self._streams[doc["uid"]] = doc.get("name", "")
            elif name == "event":
                self.events += 1
                self._event(self._streams.get(doc.get("descriptor", ""), ""), doc["data"])
        return n

    def _event(self, stream: str, d: dict[str, Any]) -> None:
        if stream == "pulses":
            cell = (int(d["row"]), int(d["col"]))
            if d.get("g_after_s") is not None:
                self.g[cell] = float(d["g_after_s"])
                self._trace(cell, float(d["g_after_s"]), str(d.get("polarity") or ""))
            self.pulses[cell] = self.pulses.get(cell, 0) + 1
            self.total_pulses += 1
            self.log.append(d)
        elif stream in ("cells", "reads"):
            cell = (int(d["row"]), int(d["col"]))
            if d.get("g_s") is not None:
                self.g[cell] = float(d["g_s"])
                if stream == "reads":
                    self._trace(cell, float(d["g_s"]), "read")
            if stream == "cells":
                self.outcome[cell] = str(d.get("outcome"))
                self.cells_done += 1
        elif stream == "progress":
            if not d.get("note"):
                self.progress[str(d["task"])] = d
        elif stream == "launches":
            L = LaunchView(str(d["scenario"]), int(d["launch"]), int(d["steps"]),
                           bool(d["success"]), [int(c) for c in d.get("path") or []],
                           [float(x) for x in d.get("calcium_final") or []],
                           int(d.get("grid_rows") or 6), int(d.get("grid_cols") or 6),
                           float(d.get("ca_thr") or 0.0), int(d.get("set_index") or 0))
            self.launches.append(L)
            self.launches_per_scenario[L.scenario] = \
                self.launches_per_scenario.get(L.scenario, 0) + 1
            if L.success:
                self.steps_ok.setdefault(L.scenario, []).append(L.steps)
        elif stream == "control":
            self.controls.append(str(d.get("action")))

    def _trace(self, cell: tuple[int, int], g: float, what: str) -> None:
        """The running cell's conductance trace: a new cell starts a new trace."""
        if cell != self.trace_cell:
            self.trace_cell = cell
            self.trace.clear()
            self.trace_total = 0
        self.trace.append((g, what))
        self.trace_total += 1

    # ------------------------------------------------------------------ summaries
    @property
    def sets(self) -> list[int]:
        """The weight sets launched so far (a comparison launches several)."""
        return sorted({L.set_index for L in self.launches})

    @property
    def kind(self) -> str:
        return str((self.start or {}).get("plan_name", "?"))

    @property
    def status(self) -> str:
        if self.stop is not None:
            return f"finished: {self.stop.get('exit_status')}" + (
                f" ({self.stop['reason']})" if self.stop.get("reason") else "")
        if self.controls and self.controls[-1] == "pause":
            return "paused"
        return "running" if self.start is not None else "waiting for the run"

    def medians(self) -> dict[str, tuple[float | None, int, int]]:
        """Scenario -> (median path length of the successful launches, successes, launches)."""
        out: dict[str, tuple[float | None, int, int]] = {}
        for scen, n in self.launches_per_scenario.items():
            ok = self.steps_ok.get(scen, [])
            out[scen] = (float(statistics.median(ok)) if ok else None, len(ok), n)
        return out

    def outcome_counts(self) -> dict[str, int]:
        counts: dict[str, int] = {}
        for o in self.outcome.values():
            counts[o] = counts.get(o, 0) + 1
        return counts


class HistorySource:
    """The documents of run ``ref`` (id or uid; None: the newest run, a running one first)
    in the history database at ``path``, polled from where the last poll ended; control
    requests are written to the same database (one connection, this process's only one)."""

    def __init__(self, path: str | Path, ref: str | None = None) -> None:
        self.path = Path(path)
        self.db = History.open(self.path, create=False)
        row = self.db.run(ref) if ref is not None else self._newest()
        if row is None:
            self.db.close()
            what = f"run {ref}" if ref is not None else "any run"
            raise UserError(f"{self.path}: no {what} to watch (see 'snan-hil history')")
        self.run = row
        self.last_id = 0

    def _newest(self) -> Any:
        runs = self.db.runs(limit=20)
        running = [r for r in runs if r.status == "running"]
        pick = running or runs
        return pick[0] if pick else None

    @property
    def controllable(self) -> bool:
        return self.run.uid is not None and self.run.status == "running"

    def poll(self) -> list[tuple[str, dict[str, Any]]]:
        rows = self.db.documents(self.run.id, self.last_id)
        if rows:
            self.last_id = rows[-1][0]
        return [(name, doc) for _i, name, doc in rows]

    def request(self, action: str) -> None:
        if self.run.uid is not None:
            self.db.request_control(self.run.uid, action, "snan-hil watch")

    def close(self) -> None:
        self.db.close()


class ReplaySource:
    """A finished run's documents, ``per_poll`` at a time (0: all at once)."""

    controllable = False

    def __init__(self, docs: list[tuple[str, dict[str, Any]]], per_poll: int = 0) -> None:
        self.docs = list(docs)
        self.per_poll = int(per_poll)
        self.at = 0

    def poll(self) -> list[tuple[str, dict[str, Any]]]:
        n = len(self.docs) - self.at if self.per_poll <= 0 else self.per_poll
        out = self.docs[self.at:self.at + n]
        self.at += len(out)
        return out

    def request(self, action: str) -> None:
        raise RuntimeError("a replay has no job to control")

    def close(self) -> None:
        pass
