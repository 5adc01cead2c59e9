"""The four-scenario comparison of the paper's Fig. 10C, and its speed/energy report (Fig. 10D).

:func:`run_compare` is cut along its seams: a :class:`CompareRequest` (what to compare) and the
board (a :class:`~snan_hil.board.session.BoardSession`, or a source of fresh sessions) go in;
per weight set of a trained ``.npz`` the launches run (:class:`_Comparison`): the software
launches (weights as numbers), then the set is programmed into the chip (two-stage
write-and-verify; cells already inside their window get no stage-1 pulse) and launched on the
crossbar, without and with astrocytes; each finished set is committed to the run's checkpoint.
The summaries and the result files come from :mod:`snan_hil.host.hil.compare_results`
(re-exported here).
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime as _dt
import json
import shutil
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from snan_hil import __version__
from snan_hil.board.identity import BoardIdentity
from snan_hil.board.files import BoardFiles
from snan_hil.board.session import BoardSession, ChipSnapshots
from snan_hil.calibration.layout import Layout
from snan_hil.calibration.observer import CellObserver
from snan_hil.calibration.programmer import ProgramConfig, program_weights
from snan_hil.calibration.weights_io import load_weight_set
from snan_hil.common.errors import UserError
from snan_hil.common.progress import ProgressCallback, track
from snan_hil.files.atomicio import atomic_write_bytes, atomic_write_text
from snan_hil.host.checkpoint import CHECKPOINT_DIR, RunFolder
from snan_hil.host.hil.compare_results import (HW_TOLERANCE, LAUNCH_COLUMNS, SPEED_COLUMNS,
                                               SPEED_COLUMNS_V1, SUMMARY_COLUMNS,
                                               SUMMARY_COLUMNS_V1,
                                               WALL_TIME_KEYS, acceptance, hw_totals, summarize,
                                               without_wall_times, write_outputs)
from snan_hil.host.hil.config import SCENARIOS, HilConfig
from snan_hil.host.hil.report import measure_spike_geometry, speed_energy_table
from snan_hil.host.hil.launch_stream import STREAM, LaunchSink, launch_event, launch_feed
from snan_hil.host.hil.runner import (LaunchResult, ScenarioResult, check_layout,
                                      require_hardware, run_scenario, scenario_parts)
from snan_hil.protocol.messages import Info

__all__ = ["RESULTS_FORMAT", "CompareRequest", "SessionSource", "UnitRunner", "run_compare",
           "run_unit", "task_of", "predicted_board_cost", "PROGRAMMING_DECISIONS",
           "check_weights_grid", "check_snapshots", "HW_TOLERANCE", "WALL_TIME_KEYS",
           "without_wall_times", "hw_totals", "summarize", "acceptance", "write_outputs",
           "LAUNCH_COLUMNS", "SUMMARY_COLUMNS_V1", "SUMMARY_COLUMNS", "SPEED_COLUMNS",
           "SPEED_COLUMNS_V1"]

RESULTS_FORMAT = "snan-hil-compare/1"


def task_of(meta: dict[str, Any], hil: HilConfig) -> tuple[int, int]:
    """(start, goal): from the weights file if it records them, else the HIL config."""
    return int(meta.get("start", hil.task.start)), int(meta.get("goal", hil.task.goal))


def check_weights_grid(meta: dict[str, Any], hil: HilConfig, path: str) -> None:
    grid = tuple(meta["grid"])
    cfg_grid = (hil.model.grid.rows, hil.model.grid.cols)
    if grid != cfg_grid:
        raise UserError(f"{path} holds {grid[0]}x{grid[1]} weights but the config is for "
                        f"{cfg_grid[0]}x{cfg_grid[1]}; pass a matching --config")


class SessionSource(Protocol):
    """Where a comparison gets a fresh session of its board for every set (on the in-process
    emulator: a fresh boot of the saved chip): a plan of the opener
    (:class:`snan_hil.lab.opener.BoardPlan`) or a session that can reopen. ``files`` and
    ``snapshots`` are known before the first one is opened."""

    @property
    def port(self) -> str: ...

    @property
    def protocol(self) -> str: ...

    @property
    def baud(self) -> int: ...

    @property
    def files(self) -> BoardFiles: ...

    @property
    def snapshots(self) -> ChipSnapshots | None: ...

    def open(self) -> BoardSession: ...


class UnitRunner(Protocol):
    """Runs the sets of a comparison elsewhere (on several boards: :mod:`snan_hil.lab.boards`),
    each as one unit (:func:`run_unit`); the comparison commits what it hands back, merges and
    summarises. ``baud`` is the boards' line rate (bit/s; the wire-time model)."""

    @property
    def baud(self) -> int: ...

    def run_units(self, request: CompareRequest, pending: list[int],
                  commit: Callable[[int, dict[str, Any]], None]) -> None:
        """Run every set of ``pending`` (indices into the weights file; ``request.sets``
        holds all the run's sets, in order, finished ones included) and call
        ``commit(index, record)`` as each one finishes, in any order; ``record`` is
        :func:`run_unit`'s, with ``"unit"`` (who ran it) added."""

    def geometry(self, request: CompareRequest) -> dict[str, Any] | None:
        """The spike measurement of the speed/energy report, on one of the boards."""

    def board_record(self) -> dict[str, Any]:
        """The results' board fields (port, protocol, mode, baud, board, session) and
        ``boards``: every board's snapshot."""


@dataclass(frozen=True)
class CompareRequest:
    """What to compare: the trained weights file (``.npz``, K sets), the HIL config, which
    sets (None: all), launches per set and scenario, the launch seed, the scenarios, how the
    hardware scenarios read the synapses (``mode``, None: the board's default,
    :mod:`.synapses`), whether each set is programmed first (``program``; False: the chip
    holds the one set already), the programming settings and where each set's programming
    report goes (``report_dir``/``program-set<K>.json``; None: not written)."""

    weights_path: str
    hil: HilConfig
    sets: tuple[int, ...] | None = None
    launches: int = 10
    seed: int = 1
    scenarios: tuple[str, ...] = SCENARIOS
    mode: str | None = None
    program: bool = True
    program_config: ProgramConfig | None = None
    report_dir: Path | None = None
    conversions: int | None = None
    """ADC conversions a read of the on-board window (None: the board's default read plan,
    :func:`~snan_hil.host.hil.board_window.read_plan`)."""

    @property
    def hw_scenarios(self) -> list[str]:
        return [s for s in self.scenarios if s.startswith("hw_")]

    @property
    def sw_scenarios(self) -> list[str]:
        return [s for s in self.scenarios if s.startswith("sw_")]


def run_compare(request: CompareRequest, board: BoardSession | SessionSource | None = None, *,
                progress: ProgressCallback | None = None,
                program_observer: CellObserver | None = None,
                checkpoint: RunFolder | None = None,
                units: UnitRunner | None = None,
                launches: LaunchSink | None = None,
                watch: Callable[[Any], Any] | None = None) -> dict[str, Any]:
    """Run the comparison ``request``; returns the results dict (:func:`write_outputs` writes
    it).

    ``board`` (needed by the hardware scenarios): a :class:`BoardSession` that cannot reopen
    is used for every set (and left open); a :class:`SessionSource` (a plan, or a session
    that reopens) gives a fresh session for each set's hardware part and for the final spike
    measurement, closed after it — so every set starts from what the board holds, nothing
    else. The layout is the board's layout file. ``program_observer`` sees every programming
    pulse and cell (:mod:`snan_hil.calibration.observer`; the chip history). ``progress``
    gets the task "launches" (one unit per launch, all sets and scenarios; sets taken from a
    checkpoint count as done) and each set's "programming".

    ``checkpoint`` (:func:`snan_hil.host.checkpoint.open_run`): each set is committed when it
    is finished (its launches, programming summary, software time) and taken from there when
    the run is resumed; with fresh sessions of a board that has chip snapshots, the chip and
    its layout are saved at every set boundary and put back before a resumed set is redone,
    so a resumed run gives the results of an uninterrupted one (wall times aside).

    ``units`` (instead of ``board``): every set not in the checkpoint runs as one unit
    elsewhere (:class:`UnitRunner`, e.g. several boards); each is committed as it comes back,
    and the results add ``units`` (set -> who ran it) to the single-board fields.

    ``launches``: ``sink(stream, data)`` gets every launch as an event of the ``launches``
    stream (:func:`~snan_hil.host.hil.launch_stream.launch_event`: scenario, set, steps,
    success, path, calcium per grid cell), as each launch ends; a set taken from the
    checkpoint (or run as a unit elsewhere) sends its launches when it is taken. ``watch``
    wraps the board client of every session (e.g. the run's control channel,
    :class:`~snan_hil.calibration.control.ControlledClient`: pause / stop between two
    requests).
    """
    return _Comparison(request, board, progress, program_observer, checkpoint, units,
                       launches, watch).run()


def run_unit(request: CompareRequest, index: int, board: SessionSource, *,
             progress: ProgressCallback | None = None,
             program_observer: CellObserver | None = None,
             warm_up: bool = True,
             watch: Callable[[Any], Any] | None = None) -> dict[str, Any]:
    """One weight set (``index`` into the weights file) of the comparison ``request`` on
    ``board``, as :func:`run_compare` runs it (software launches, then programmed and
    launched on a fresh session): the checkpoint record of the set (``results``: the
    :class:`ScenarioResult` dicts, ``programming``, ``sw_wall_s``, ``wall_s`` in s,
    ``board``: its identity, ``mode``). ``warm_up``: load the kernels first (one untimed
    software launch), as :func:`run_compare` does once a run; a process that ran a unit
    already has them; ``watch`` as :func:`run_compare` (e.g. the run's control channel). UserError
    as :func:`run_compare`."""
    one = dataclasses.replace(request, sets=(int(index),))
    comparison = _Comparison(one, board, progress, program_observer, None, watch=watch)
    if warm_up:
        comparison.warm_up(comparison.sets)
    return comparison._run_set(comparison.sets[0], "start")


@dataclass
class _Set:
    """One weight set: its index, dense weights (N x N) and the weights file's meta."""

    index: int
    weights: NDArray[np.float64]
    meta: dict[str, Any]


@dataclass
class _Tally:
    """What the finished sets add up to."""

    results: list[ScenarioResult] = field(default_factory=list)
    programming: dict[int, dict[str, Any]] = field(default_factory=dict)
    sw_wall: float = 0.0
    unit_walls: float = 0.0


class _Comparison:
    """One run of :func:`run_compare`: the sets, the board, the tally, the checkpoint."""

    def __init__(self, request: CompareRequest, board: BoardSession | SessionSource | None,
                 progress: ProgressCallback | None, observer: CellObserver | None,
                 checkpoint: RunFolder | None, units: UnitRunner | None = None,
                 launches: LaunchSink | None = None,
                 watch: Callable[[Any], Any] | None = None):
        self.t_wall = time.perf_counter()
        self.sink, self.watch = launches, watch
        self.request, self.progress, self.observer = request, progress, observer
        self.checkpoint = checkpoint
        self.units = units
        self.unit_of: dict[int, Any] = {}
        self.sets, self.meta0 = _load_sets(request)
        self.hw = bool(request.hw_scenarios)
        if self.hw and board is None and units is None:
            raise UserError("hw scenarios need a board (--port) and a layout path")
        self.board = board
        self.shared = board if isinstance(board, BoardSession) and board.reopen_with is None \
            else None
        files = board.files if board is not None else BoardFiles()
        if self.hw and files.layout is None and units is None:
            raise UserError("hw scenarios need a board (--port) and a layout path")
        self.layout_path = files.layout
        self.identity: BoardIdentity | None = None
        self.conversion_us: float | None = None
        self.hw_mode: str | None = None
        self.first_seen: BoardSession | None = None
        if isinstance(board, BoardSession):       # the board said who it is already
            self._seen(board)
        snapshots = board.snapshots if board is not None and self.shared is None and \
            checkpoint is not None else None
        self.boundary = _Boundaries(checkpoint, snapshots, self.layout_path)
        self.tally = _Tally()
        n = len(self.sets) * request.launches * len(request.scenarios)
        self.bar = track(progress, "launches", n)

    # -- the board --------------------------------------------------------------------------
    def _seen(self, session: BoardSession) -> None:
        self.first_seen = self.first_seen or session
        self.identity = session.identity
        self.conversion_us = float(session.info.conversion_us)
        if self.hw:
            self.hw_mode = require_hardware(session.client, self.request.mode,
                                            self.request.hil.launch_config(False))

    @contextlib.contextmanager
    def _board(self) -> Iterator[BoardSession]:
        """The set's session: the shared one, or a fresh one closed after the set."""
        if self.shared is not None:
            yield self._watched(self.shared)
            return
        assert self.board is not None                   # checked in __init__
        session = self.board.open()
        try:
            self._seen(session)
            yield self._watched(session)
        finally:
            session.close()

    def _watched(self, session: BoardSession) -> BoardSession:
        """``session`` with its client wrapped by :attr:`watch` (closed through the
        original)."""
        if self.watch is None:
            return session
        return dataclasses.replace(session, client=self.watch(session.client))

    # -- the launches stream ----------------------------------------------------------------
    def _feed(self, scenario: str, s: _Set) -> Callable[[LaunchResult], None] | None:
        if self.sink is None:
            return None
        req = self.request
        return launch_feed(self.sink, scenario, s.index,
                           req.hil.launch_config(scenario_parts(scenario)[1]), seed=req.seed)

    def _send_taken(self, results: list[ScenarioResult]) -> None:
        """The launches of a set taken from the checkpoint (or a unit), in order."""
        if self.sink is None:
            return
        req = self.request
        for sr in results:
            cfg = req.hil.launch_config(scenario_parts(sr.scenario)[1])
            for launch in sr.launches:
                self.sink(STREAM, launch_event(sr.scenario, sr.set_index, launch, cfg,
                                               seed=req.seed))

    # -- the run ----------------------------------------------------------------------------
    def run(self) -> dict[str, Any]:
        done = {s.index: self.checkpoint.done(f"set-{s.index}")
                if self.checkpoint is not None else None for s in self.sets}
        geometry_done = self.checkpoint.done("geometry") \
            if self.checkpoint is not None and self.hw else None
        if self.units is not None:
            return self._run_units(done, geometry_done)
        self._rewind(done, geometry_done)
        self.warm_up([s for s in self.sets if done[s.index] is None])
        previous = "start"
        for s in self.sets:
            record = done[s.index]
            if record is not None:
                self._from_checkpoint(s, record)
            else:
                self._run_set(s, previous)
            previous = f"set-{s.index}"
        return self._results(self._geometry(geometry_done))

    def warm_up(self, pending: list[_Set]) -> None:
        """Load the kernels before the software launches are timed."""
        if self.request.sw_scenarios and pending:
            req = self.request
            start, goal = task_of(self.meta0, req.hil)
            run_scenario(req.sw_scenarios[0], self.sets[0].weights, req.hil, launches=1,
                         seed=req.seed, start=start, goal=goal)

    def _run_units(self, done: dict[int, dict[str, Any] | None],
                   geometry_done: dict[str, Any] | None) -> dict[str, Any]:
        """The sets not done run as units of :attr:`units`; each is committed as it comes
        back; then every set is taken as from the checkpoint, in the request's order."""
        assert self.units is not None

        def commit(index: int, record: dict[str, Any]) -> None:
            if self.checkpoint is not None:
                self.checkpoint.commit(f"set-{index}", record)
            done[index] = record
            # its launches to the stream now (a live view sees each set as its board ends it)
            self._send_taken([ScenarioResult.from_dict(r) for r in record["results"]])
            unit = record.get("unit") or {}
            self.bar.advance(self.request.launches * len(self.request.scenarios),
                             f"set {index}: done on board {unit.get('board')}")

        pending = [s.index for s in self.sets if done[s.index] is None]
        before = {s.index for s in self.sets if done[s.index] is not None}
        if pending:
            every = dataclasses.replace(self.request, sets=tuple(s.index for s in self.sets))
            self.units.run_units(every, pending, commit)
        for s in self.sets:
            record = done[s.index]
            if record is None:
                raise RuntimeError(f"set {s.index} was not run")
            self._from_checkpoint(s, record, advance=s.index in before,
                                  send=s.index in before)
        geometry = None
        if self.hw:
            if geometry_done is not None:
                geometry = geometry_done.get("geometry")
            else:
                geometry = self.units.geometry(self.request)
                if self.checkpoint is not None:
                    self.checkpoint.commit("geometry", {"geometry": geometry})
        return self._results(geometry)

    def _rewind(self, done: dict[int, dict[str, Any] | None],
                geometry_done: dict[str, Any] | None) -> None:
        """At the start of a checkpointed run: save the start boundary; on a resume, put the
        chip and layout back as the last finished set left them."""
        if not self.hw or self.checkpoint is None:
            return
        finished = [s.index for s in self.sets if done[s.index] is not None]
        pending = len(finished) < len(self.sets)
        if not self.checkpoint.resumed or not finished and not self.boundary.saved("start"):
            self.boundary.save("start")
        elif pending or geometry_done is None:
            self.boundary.restore(f"set-{finished[-1]}" if finished else "start")

    def _from_checkpoint(self, s: _Set, record: dict[str, Any], advance: bool = True,
                         send: bool = True) -> None:
        """A set finished before: its results from the checkpoint (``send``: its launches to
        the stream, unless they were sent when it was committed)."""
        req, tally = self.request, self.tally
        taken = [ScenarioResult.from_dict(r) for r in record["results"]]
        if send:
            self._send_taken(taken)
        tally.results += taken
        if record.get("programming") is not None:
            tally.programming[s.index] = record["programming"]
        tally.sw_wall += record["sw_wall_s"]
        tally.unit_walls += record["wall_s"]
        if advance:
            self.bar.advance(req.launches * len(req.scenarios),
                             f"set {s.index}: from the checkpoint")
        board = record.get("board")
        if board is not None and self.identity is None:
            self.identity = BoardIdentity.from_record(board)
            self.conversion_us = float(board.get("conversion_us") or Info().conversion_us)
        if self.hw_mode is None and record.get("mode") is not None:
            self.hw_mode = record["mode"]
        if record.get("unit") is not None:
            self.unit_of[s.index] = record["unit"]

    def _run_set(self, s: _Set, previous: str) -> dict[str, Any]:
        """Launch one set (software, then programmed and launched on the chip) and commit
        it; returns its checkpoint record."""
        t_set = time.perf_counter()
        results = [self._launch(sc, s) for sc in self.request.sw_scenarios]
        sw_wall = time.perf_counter() - t_set
        summary = None
        if self.hw:
            summary, hw_results = self._hardware(s)
            results += hw_results
        wall = time.perf_counter() - t_set
        tally = self.tally
        tally.results += results
        tally.sw_wall += sw_wall
        tally.unit_walls += wall
        board = None if self.identity is None else {**self.identity.to_dict(),
                                                    "conversion_us": self.conversion_us}
        record = {"results": [r.to_dict() for r in results], "programming": summary,
                  "sw_wall_s": sw_wall, "wall_s": wall, "board": board if self.hw else None,
                  "mode": self.hw_mode if self.hw else None}
        if self.checkpoint is None:
            return record
        if self.hw:
            self.boundary.save(f"set-{s.index}")
        self.checkpoint.commit(f"set-{s.index}", record)
        if self.hw:
            self.boundary.drop(previous)
        return record

    def _launch(self, scenario: str, s: _Set, session: BoardSession | None = None,
                layout: Layout | None = None) -> ScenarioResult:
        req = self.request
        start, goal = task_of(self.meta0, req.hil)
        return run_scenario(scenario, s.weights, req.hil, set_index=s.index,
                            launches=req.launches, seed=req.seed, start=start, goal=goal,
                            client=session.client if session is not None else None,
                            layout=layout, mode=self.hw_mode if session is not None else None,
                            baud=session.baud if session is not None else None,
                            progress=self.bar.nested(f"set {s.index} {scenario} "),
                            on_launch=self._feed(scenario, s),
                            conversions=req.conversions)

    def _hardware(self, s: _Set) -> tuple[dict[str, Any] | None, list[ScenarioResult]]:
        """The set on the chip: programmed (or the chip's layout checked to hold it), then
        launched in the hardware scenarios."""
        req = self.request
        assert self.layout_path is not None                 # checked in __init__
        summary = None
        with self._board() as session:
            if req.program:
                self.bar.advance(0, f"programming set {s.index}")
                report = req.report_dir / f"program-set{s.index}.json" \
                    if req.report_dir is not None else None
                programmed = program_weights(
                    session.with_files(layout=self.layout_path, report=report),
                    s.weights, s.meta, config=req.program_config, progress=self.progress,
                    observer=self.observer)
                layout = programmed.layout
                summary = {**programmed.report["summary"], "all_ok": programmed.all_ok}
                self.tally.programming[s.index] = summary
            else:
                layout = Layout.load(self.layout_path)
            check_layout(layout, s.weights, tuple(s.meta["grid"]), port=session.port,
                         weights_path=req.weights_path, set_index=s.index,
                         board_options=session.options)
            results = [self._launch(sc, s, session, layout) for sc in req.hw_scenarios]
        return summary, results

    def _geometry(self, done: dict[str, Any] | None) -> dict[str, Any] | None:
        """The 15 x 8 spike measurement of the speed/energy report (hardware only)."""
        if not self.hw:
            return None
        if done is not None:
            return done.get("geometry")
        t_geo = time.perf_counter()
        with self._board() as session:
            row_code = session.info.read_code
            if self.layout_path is not None and self.layout_path.is_file():
                chain = Layout.load(self.layout_path).read_chain
                row_code = chain.read_code if chain is not None else row_code
            geometry = measure_spike_geometry(session.client, row_code=row_code,
                                              baud=session.baud)
        self.tally.unit_walls += time.perf_counter() - t_geo
        if self.checkpoint is not None:
            self.checkpoint.commit("geometry", {"geometry": geometry})
        return geometry

    def _results(self, geometry: dict[str, Any] | None) -> dict[str, Any]:
        """The results dict: summaries, speed/energy, provenance."""
        req, tally, hw = self.request, self.tally, self.hw
        start, goal = task_of(self.meta0, req.hil)
        out = summarize(tally.results, req.hil, sets=[s.index for s in self.sets],
                        launches=req.launches, seed=req.seed, start=start, goal=goal,
                        scenarios=req.scenarios)
        sw_dec = sum(r.decisions for sr in tally.results if sr.scenario.startswith("sw_")
                     for r in sr.launches)
        baud = self.board.baud if self.board is not None else \
            self.units.baud if self.units is not None else None
        hw_stats = hw_totals(tally.results, baud if hw else None)
        if hw_stats and self.conversion_us is not None:
            hw_stats["conversion_us"] = self.conversion_us
        out["speed_energy"] = speed_energy_table(
            req.hil.model.n_cells, hw=hw_stats or None, geometry=geometry,
            sw={"decisions": sw_dec, "wall_s": tally.sw_wall} if sw_dec else None)
        resumed = bool(self.checkpoint is not None and self.checkpoint.resumed)
        out.update({
            "format": RESULTS_FORMAT, "snan_hil_version": __version__,
            "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "weights": {"path": req.weights_path, "n_sets": int(self.meta0["n_sets"]),
                        "set_seeds": self.meta0.get("seeds"), "cycles": self.meta0.get("cycles"),
                        "fingerprints": {str(r.set_index): r.fingerprint
                                         for r in tally.results}},
            **self._board_record(),
            "programming": {str(k): v for k, v in tally.programming.items()},
            "config": req.hil.to_dict(),
            "wall_s": tally.unit_walls if resumed else time.perf_counter() - self.t_wall,
            "resumed": resumed,
        })
        if self.units is not None:
            out["units"] = {str(k): self.unit_of.get(k) for k in sorted(self.unit_of)}
        return out

    def _board_record(self) -> dict[str, Any]:
        """What the results record of the board: port, protocol, mode, baud, identity and
        the session's snapshot (None without hardware scenarios)."""
        if self.units is not None:
            record = self.units.board_record() if self.hw else {}
            return {**{k: None for k in ("port", "protocol", "baud", "board", "session")},
                    **record, "mode": self.hw_mode if self.hw else None}
        board = self.board if self.hw else None
        seen = self.first_seen
        return {"port": board.port if board is not None else None,
                "protocol": board.protocol if board is not None else None,
                "mode": self.hw_mode if board is not None else None,
                "baud": board.baud if board is not None else None,
                "board": self.identity.to_dict() if self.identity is not None and board
                is not None else None,
                "session": seen.snapshot() if seen is not None and board is not None
                else None}


#: A set's programming in units of one hardware decision of its launches, for
#: :func:`predicted_board_cost` (a stated assumption from a measurement: programming 120
#: synapses by write-and-verify took ~5.5 s of board time and an on-board decision ~0.06 s on
#: the emulated board over the framed protocol, bench/bench_multiboard.py, round 5; over the
#: legacy per-spike protocol a decision costs more, so programming weighs less there and
#: this errs towards counting sets evenly).
PROGRAMMING_DECISIONS = 90.0


def predicted_board_cost(request: CompareRequest) -> dict[int, float]:
    """Per set of ``request`` (all of its sets), the board time its unit will take, in
    decisions: :data:`PROGRAMMING_DECISIONS` plus the decisions of its launches in the
    software twin of every hardware scenario (``hw_astro`` -> ``sw_astro``: same weights,
    seed and trials, so nearly the same paths; the chip's read error moves a few). A pure
    function of the request (the software launches are deterministic), ~20 ms a set: what
    :func:`snan_hil.lab.boards.assign` balances the boards with, before any board runs.
    UserError as :func:`run_compare` for bad weights."""
    sets, meta0 = _load_sets(request)
    start, goal = task_of(meta0, request.hil)
    twins = sorted({"sw_" + sc[3:] for sc in request.hw_scenarios})
    cost: dict[int, float] = {}
    for s in sets:
        steps = sum(r.steps for sc in twins for r in run_scenario(
            sc, s.weights, request.hil, set_index=s.index, launches=request.launches,
            seed=request.seed, start=start, goal=goal).launches)
        cost[s.index] = (PROGRAMMING_DECISIONS if request.program else 0.0) + float(steps)
    return cost

def _load_sets(request: CompareRequest) -> tuple[list[_Set], dict[str, Any]]:
    """Every set of the request, validated before any I/O, and the file's meta."""
    path = request.weights_path
    _w0, meta0 = load_weight_set(path, 0)
    n_sets = int(meta0["n_sets"])
    indices = list(range(n_sets)) if request.sets is None else [int(k) for k in request.sets]
    sets = []
    for k in indices:
        w, meta = load_weight_set(path, k)
        check_weights_grid(meta, request.hil, path)
        sets.append(_Set(k, w, meta))
    return sets, meta0


def check_snapshots(out: Path, board: ChipSnapshots | None) -> None:
    """Check every chip and layout snapshot of the checkpoint in ``out`` (a resumed run puts
    one of them back) before the board is opened: UserError (one line naming the damaged
    file) changes nothing."""
    folder = Path(out) / CHECKPOINT_DIR
    if not folder.is_dir():
        return
    for path in sorted(folder.glob("board-*")):
        if board is not None and not path.name.startswith("."):
            board.check(path)
    for path in sorted(folder.glob("layout-*.json")):
        _check_layout_snapshot(path)


def _check_layout_snapshot(path: Path) -> None:
    """UserError (one line naming ``path``) unless it holds a valid layout."""
    from snan_hil.calibration.layout import Layout, LayoutError
    try:
        Layout.from_dict(json.loads(path.read_text(encoding="utf-8")), "snapshot")
    except (OSError, ValueError, AttributeError, LayoutError) as exc:
        reason = str(exc) if isinstance(exc, LayoutError) else f"{type(exc).__name__}: {exc}"
        raise UserError(f"--resume: the layout snapshot {path} in the checkpoint is damaged "
                        f"({reason}); the live layout was left untouched; start the run again "
                        "in a new --out") from None



class _Boundaries:
    """Snapshots of the board and the layout file at the set boundaries of a checkpointed run
    (``board-<tag>`` via :class:`~snan_hil.board.session.ChipSnapshots`,
    ``layout-<tag>.json`` a copy of the layout, ``layout-<tag>.absent`` when there was
    none)."""

    def __init__(self, checkpoint: RunFolder | None, board: ChipSnapshots | None,
                 layout_path: Path | None):
        self.checkpoint, self.board, self.layout_path = checkpoint, board, layout_path

    def _paths(self, tag: str) -> tuple[Path, Path, Path]:
        assert self.checkpoint is not None
        cp = self.checkpoint
        return cp.path(f"board-{tag}"), cp.path(f"layout-{tag}.json"), \
            cp.path(f"layout-{tag}.absent")

    def saved(self, tag: str) -> bool:
        if self.checkpoint is None:
            return False
        _b, layout, absent = self._paths(tag)
        return layout.exists() or absent.exists()

    def save(self, tag: str) -> None:
        if self.checkpoint is None:
            return
        board, layout, absent = self._paths(tag)
        if self.board is not None:
            self.board.save(board)
        if self.layout_path is not None and self.layout_path.is_file():
            atomic_write_bytes(layout, self.layout_path.read_bytes())
            absent.unlink(missing_ok=True)
        else:
            atomic_write_text(absent, "no layout at this boundary\n")
            layout.unlink(missing_ok=True)

    def restore(self, tag: str) -> None:
        if self.checkpoint is None:
            return
        board, layout, absent = self._paths(tag)
        if not (layout.exists() or absent.exists()):
            raise UserError(f"--resume: the checkpoint in {self.checkpoint.out} lacks the "
                            f"layout snapshot {layout.name}; start a new run in another --out")
        # every snapshot is checked before anything is put back: a damaged checkpoint
        # leaves the live chip and layout as they are
        if self.board is not None:
            self.board.check(board)
        if self.layout_path is not None and layout.exists():
            _check_layout_snapshot(layout)
        if self.board is not None:
            self.board.restore(board)
        if self.layout_path is not None:
            if layout.exists():
                atomic_write_bytes(self.layout_path, layout.read_bytes())
            else:
                self.layout_path.unlink(missing_ok=True)

    def drop(self, tag: str) -> None:
        if self.checkpoint is None:
            return
        for p in self._paths(tag):
            if p.is_dir():
                shutil.rmtree(p, ignore_errors=True)
            else:
                p.unlink(missing_ok=True)
