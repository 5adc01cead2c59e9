"""The four-scenario comparison of the paper's Fig. 10C, and its speed/energy report (Fig. 10D).

The comparison is a board job (:class:`CompareJob`, :mod:`snan_hil.calibration.job`) run by the
job runner (:func:`snan_hil.lab.runner.run_job`): a :class:`CompareRequest` (what to compare)
goes in; its units are the weight sets of a trained ``.npz`` (:class:`SetUnit`, one group a
set) and the spike measurement of the speed/energy report (:class:`GeometryUnit`). Per set the
software launches run (weights as numbers), then the set is programmed into the chip
(two-stage write-and-verify; cells already inside their window get no stage-1 pulse) and
launched on the crossbar, without and with astrocytes. The job is ``restartable``: each unit
runs on a fresh session of the board, and a set cut short is run again from the chip the
runner saved before it, so a resumed run gives the results of an uninterrupted one (wall
times aside). Each unit's record is the set's checkpoint record; the results come from the
records alone (:meth:`CompareJob.result`). A comparison of software scenarios only needs no
board (:func:`run_software`). The summaries and the result files come from
:mod:`snan_hil.host.hil.compare_results` (re-exported here).
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime as _dt
import json
import os
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from snan_hil.common.version import __version__
from snan_hil.board.identity import BoardIdentity
from snan_hil.board.session import BoardSession, ChipSnapshots
from snan_hil.calibration.bench import CellBench
from snan_hil.calibration.chip_group import GroupBench, GroupPlan, merge_programming
from snan_hil.calibration.job import UnitContext
from snan_hil.calibration.layout import Layout, LayoutError
from snan_hil.calibration.programmer import (ProgramConfig, ProgramResult, check_program,
                                             program_on_bench)
from snan_hil.calibration.weights_io import load_weight_set
from snan_hil.common.errors import UserError
from snan_hil.common.progress import ProgressCallback, ProgressTracker, track
from snan_hil.files.atomicio import atomic_write_text
from snan_hil.host.checkpoint import CHECKPOINT_DIR, RunFolder
from snan_hil.host.hil.compare_results import (HW_TOLERANCE, LAUNCH_COLUMNS, SPEED_COLUMNS,
                                               SPEED_COLUMNS_V1, SUMMARY_COLUMNS,
                                               SUMMARY_COLUMNS_V1,
                                               WALL_TIME_KEYS, acceptance, hw_totals, summarize,
                                               without_wall_times, write_outputs)
from snan_hil.host.hil.config import SCENARIOS, HilConfig
from snan_hil.host.hil.launch_stream import STREAM, LaunchSink, launch_event, launch_feed
from snan_hil.host.hil.report import measure_spike_geometry, speed_energy_table
from snan_hil.host.hil.runner import (ScenarioResult, check_layout, require_hardware,
                                      run_scenario, scenario_parts)
from snan_hil.protocol.messages import Info

__all__ = ["RESULTS_FORMAT", "CompareRequest", "CompareJob", "SetUnit", "GeometryUnit",
           "run_software", "compare_summary", "boards_fields", "task_of",
           "predicted_board_cost", "PROGRAMMING_DECISIONS",
           "check_weights_grid", "check_snapshots", "adopt_old_snapshots", "HW_TOLERANCE",
           "WALL_TIME_KEYS", "without_wall_times", "hw_totals", "summarize", "acceptance",
           "write_outputs", "LAUNCH_COLUMNS", "SUMMARY_COLUMNS_V1", "SUMMARY_COLUMNS",
           "SPEED_COLUMNS", "SPEED_COLUMNS_V1"]

RESULTS_FORMAT = "snan-hil-compare/1"

NEEDS_BOARD = "hw scenarios need a board (--port) and a layout path"


def task_of(meta: dict[str, Any], hil: HilConfig) -> tuple[int, int]:
    """(start, goal): from the weights file if it records them, else the HIL config."""
    return int(meta.get("start", hil.task.start)), int(meta.get("goal", hil.task.goal))


def check_weights_grid(meta: dict[str, Any], hil: HilConfig, path: str) -> None:
    grid = tuple(meta["grid"])
    cfg_grid = (hil.model.grid.rows, hil.model.grid.cols)
    if grid != cfg_grid:
        raise UserError(f"{path} holds {grid[0]}x{grid[1]} weights but the config is for "
                        f"{cfg_grid[0]}x{cfg_grid[1]}; pass a matching --config")


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


@dataclass(frozen=True)
class SetUnit:
    """One weight set of a comparison (``index`` into the weights file): its software
    launches, then (hardware scenarios) programmed and launched on the chip. Its own group:
    the sets of a run over several boards may run on any board."""

    index: int

    @property
    def key(self) -> str:
        return f"set-{self.index}"

    @property
    def group(self) -> str | None:
        return self.key


@dataclass(frozen=True)
class GeometryUnit:
    """The 15 x 8 spike measurement of the speed/energy report (hardware scenarios; after
    the sets; its own group: over several boards, after the sets of the board it lands
    on)."""

    key: str = "geometry"
    group: str | None = "geometry"


@dataclass
class _Set:
    """One weight set: its index, dense weights (N x N) and the weights file's meta."""

    index: int
    weights: NDArray[np.float64]
    meta: dict[str, Any]


def compare_summary(results: dict[str, Any]) -> dict[str, Any]:
    """The RunStop's ``summary`` of a comparison: per scenario the median path length of the
    successful launches, its 95 % interval, the success rate and the launches; the
    programming per set."""
    return {"scenarios": {s: {k: v.get(k) for k in ("median_steps", "median_steps_ci",
                                                   "success_rate", "launches")}
                          for s, v in results["scenarios"].items()},
            "programming": results.get("programming") or None}


class CompareJob:
    """The comparison as a board job (see the module docstring): ``request`` (the weights
    file is read and checked here, before any I/O: UserError). Units: a :class:`SetUnit`
    per set in the request's order, then (hardware scenarios) the :class:`GeometryUnit`.

    A set's record (its checkpoint record): ``results`` (the :class:`ScenarioResult`
    dicts), ``programming`` (the programming summary with ``all_ok``, None without
    programming), ``sw_wall_s`` and ``wall_s`` (s), ``mode`` and, with hardware scenarios,
    the board it ran on: ``board`` (identity and ``conversion_us``), ``port``, ``protocol``,
    ``baud``, ``session`` (its snapshot). The geometry's: ``geometry``, ``wall_s``. The
    ``launches`` stream gets every launch as it ends (``ctx.emit``); the launches of sets
    taken from the checkpoint go out when the first unit runs."""

    kind: ClassVar[str] = "hil"
    restartable: ClassVar[bool] = True

    def __init__(self, request: CompareRequest, *,
                 names: Mapping[str, str] | None = None) -> None:
        self.request = request
        self.names = dict(names or {})
        self.sets, self.meta0 = _load_sets(request)
        self.by_index = {s.index: s for s in self.sets}
        self.hw = bool(request.hw_scenarios)
        self.hw_mode: str | None = None
        self._seen: dict[str, Any] = {}           # the run's session (plan): board fields
        self._t0: float | None = None
        self._resumed = False
        self._taken: list[tuple[int, dict[str, Any]]] = []   # restored, not yet streamed
        self._bar: ProgressTracker | None = None
        self._warm = False
        self.group: GroupPlan | None = None
        """The network over a chip group (planned on a :class:`GroupBench`), else None."""

    # -- the job protocol -------------------------------------------------------------------
    def describe(self) -> dict[str, Any]:
        req = self.request
        return {"weights": req.weights_path,
                "sets": None if req.sets is None else list(req.sets),
                "launches": req.launches, "scenarios": list(req.scenarios),
                "mode": self.hw_mode or req.mode, "program": req.program,
                "conversions": req.conversions}

    def mode_on(self, client: Any) -> str | None:
        """The hardware mode this comparison runs on the board of ``client`` (the request's,
        else the board's default; UserError when the board cannot), None without hardware
        scenarios. Decided once: :meth:`plan` checks it again."""
        if self.hw and self.hw_mode is None:
            self.hw_mode = self._mode_of(client)
        return self.hw_mode

    def plan(self, bench: CellBench | GroupBench | None) -> list[SetUnit | GeometryUnit]:
        """The units; with hardware scenarios the board's mode checked (UserError) and its
        layout path known. ``bench`` None: no board (software scenarios only); a
        :class:`GroupBench`: the network over a chip group (:meth:`_plan_group`)."""
        self._t0 = time.perf_counter()
        units: list[SetUnit | GeometryUnit] = [SetUnit(s.index) for s in self.sets]
        if not self.hw:
            return units
        if isinstance(bench, GroupBench):
            return [*units, *self._plan_group(bench)]
        if bench is None or bench.layout_path is None:
            raise UserError(NEEDS_BOARD)
        self.hw_mode = self._mode_of(bench.client)          # (again: a resumed job)
        if self.request.program:        # the targets and the layout file: before any set
            check_program(bench.session, bench.layout_path,
                          self.request.program_config or ProgramConfig())
        self._seen = _board_fields(bench.session)
        return [*units, GeometryUnit()]

    def run_unit(self, unit: SetUnit | GeometryUnit, bench: CellBench | GroupBench | None,
                 ctx: UnitContext) -> dict[str, Any]:
        self._start(ctx)
        if isinstance(bench, GroupBench):
            if isinstance(unit, GeometryUnit):      # the spike measurement on the first chip
                bench = bench.benches[0]
            else:
                return self._group_set_record(self.by_index[unit.index], bench, ctx)
        if isinstance(unit, GeometryUnit):
            if bench is None:
                raise UserError(NEEDS_BOARD)
            t = time.perf_counter()
            geometry = _measure_geometry(bench.session, bench.client)
            return {"geometry": geometry, "wall_s": time.perf_counter() - t}
        board = None if bench is None else contextlib.nullcontext(
            dataclasses.replace(bench.session, client=bench.client))
        return self.set_record(self.by_index[unit.index], board, bench=bench,
                               progress=ctx.progress, emit=ctx.emit)

    def restore(self, unit: SetUnit | GeometryUnit, record: dict[str, Any]) -> None:
        self._resumed = True
        if isinstance(unit, SetUnit):
            self._taken.append((unit.index, record))

    def result(self, records: Mapping[str, dict[str, Any]], status: str) -> dict[str, Any]:
        """The results dict (:func:`write_outputs` writes it) from the units' records: every
        set's (``status`` "complete"), or those that finished ("interrupted")."""
        req = self.request
        taken = [(s, records[f"set-{s.index}"]) for s in self.sets if f"set-{s.index}" in records]
        if status == "complete" and len(taken) < len(self.sets):
            missing = [s.index for s in self.sets if f"set-{s.index}" not in records]
            raise RuntimeError(f"set {missing[0]} was not run")
        results = [ScenarioResult.from_dict(r) for _s, rec in taken for r in rec["results"]]
        walls = sum(rec["wall_s"] for _s, rec in taken)
        sw_wall = sum(rec["sw_wall_s"] for _s, rec in taken)
        geo = records.get("geometry") if self.hw else None
        geometry = geo.get("geometry") if geo is not None else None
        walls += float(geo.get("wall_s") or 0.0) if geo is not None else 0.0
        board = self._board_of([rec for _s, rec in taken])
        start, goal = task_of(self.meta0, req.hil)
        out = summarize(results, req.hil, sets=[s.index for s, _rec in taken],
                        launches=req.launches, seed=req.seed, start=start, goal=goal,
                        scenarios=req.scenarios)
        sw_dec = sum(r.decisions for sr in results if sr.scenario.startswith("sw_")
                     for r in sr.launches)
        hw_stats = hw_totals(results, board["baud"] if self.hw else None)
        if hw_stats and board["conversion_us"] is not None:
            hw_stats["conversion_us"] = board["conversion_us"]
        out["speed_energy"] = speed_energy_table(
            req.hil.model.n_cells, hw=hw_stats or None, geometry=geometry,
            sw={"decisions": sw_dec, "wall_s": sw_wall} if sw_dec else None)
        resumed = self._resumed or self._t0 is None
        group = next((rec.get("group") for _s, rec in taken if rec.get("group")), None)
        if self.group is not None or group is not None:
            out["group"] = {"plan": self.group.to_dict() if self.group is not None else None,
                            "chips": group or self._seen.get("group")}
        out.update({
            "format": RESULTS_FORMAT, "snan_hil_version": __version__,
            "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "weights": {"path": req.weights_path, "n_sets": int(self.meta0["n_sets"]),
                        "set_seeds": self.meta0.get("seeds"), "cycles": self.meta0.get("cycles"),
                        "fingerprints": {str(r.set_index): r.fingerprint for r in results}},
            **{k: board[k] for k in ("port", "protocol", "mode", "baud", "board", "session")},
            "programming": {str(s.index): rec["programming"] for s, rec in taken
                            if rec.get("programming") is not None},
            "config": req.hil.to_dict(),
            "wall_s": walls if resumed or self._t0 is None
            else time.perf_counter() - self._t0,
            "resumed": self._resumed,
        })
        return out

    def summary(self, result: dict[str, Any]) -> dict[str, Any]:
        return compare_summary(result)

    # -- over several boards (lab.fanout) ---------------------------------------------------
    def start_here(self, resumed: bool) -> None:
        """The run's clock started on the host (several boards: the sets run elsewhere; the
        results' ``wall_s`` is the host's, ``resumed`` says whether the run was)."""
        self._t0 = time.perf_counter()
        self._resumed = resumed

    def unit_order(self) -> list[str]:
        """The units' keys in the run's order (the records :meth:`result` takes)."""
        return [SetUnit(s.index).key for s in self.sets] + \
            ([GeometryUnit().key] if self.hw else [])

    def groups(self) -> list[str]:
        """The groups: a set each, then the spike measurement (hardware scenarios)."""
        return self.unit_order()

    def group_cost(self) -> dict[str, float]:
        """Each group's predicted board time in decisions (:func:`predicted_board_cost`; the
        spike measurement ~0)."""
        cost = predicted_board_cost(self.request)
        return {**{SetUnit(k).key: c for k, c in cost.items()}, GeometryUnit().key: 0.0}

    def checkpoint_events(self, store: Any) -> list[tuple[str, dict[str, Any]]]:
        """The launches of the sets ``store`` (the run's checkpoint) holds, as the
        ``launches`` stream's events: a resumed run over several boards sends them first, so
        its stream holds the whole run as a one-board run's does."""
        events: list[tuple[str, dict[str, Any]]] = []
        for s in self.sets:
            saved = store.done(SetUnit(s.index).key) if store is not None else None
            if saved is not None:
                self.send_taken(saved, lambda stream, data: events.append((stream, data)))
        return events

    def group_name(self, group: str) -> str:
        return "the spike measurement" if group == GeometryUnit().key \
            else group.replace("-", " ")

    # -- a set ------------------------------------------------------------------------------
    def set_record(self, s: _Set, board: contextlib.AbstractContextManager[BoardSession] | None,
                   *, bench: CellBench | None = None,
                   progress: ProgressCallback | None = None,
                   emit: LaunchSink | None = None) -> dict[str, Any]:
        """Launch set ``s``: software, then (hardware scenarios) programmed and launched on
        the session ``board`` gives (entered after the software launches); its record (see
        the class docstring). ``bench``: the unit's cell bench (the job runner's: the set is
        programmed on it, its pulses journalled and recorded as applied; needed with
        programming)."""
        t_set = time.perf_counter()
        results = [self._launch(sc, s, None, None, emit) for sc in self.request.sw_scenarios]
        sw_wall = time.perf_counter() - t_set
        summary = None
        fields: dict[str, Any] = {}
        if self.hw:
            if board is None:
                raise UserError(NEEDS_BOARD)
            with board as session:
                fields = _board_fields(session)
                summary, hw_results = self._hardware(s, session, bench, progress,
                                                     emit)
            results += hw_results
        record = {"results": [r.to_dict() for r in results], "programming": summary,
                  "sw_wall_s": sw_wall, "wall_s": time.perf_counter() - t_set,
                  "board": None, "mode": self.hw_mode if self.hw else None}
        if self.hw:
            record.update(board={**fields["board"], "conversion_us": fields["conversion_us"]},
                          port=fields["port"], protocol=fields["protocol"],
                          baud=fields["baud"], session=fields["session"])
        return record

    def _hardware(self, s: _Set, session: BoardSession, bench: CellBench | None,
                  progress: ProgressCallback | None,
                  emit: LaunchSink | None
                  ) -> tuple[dict[str, Any] | None, list[ScenarioResult]]:
        """The set on the chip: programmed (or the chip's layout checked to hold it), then
        launched in the hardware scenarios."""
        req = self.request
        layout_path = session.files.layout
        if layout_path is None:
            raise UserError(NEEDS_BOARD)
        if self.hw_mode is None:
            self.hw_mode = self._mode_of(session.client)
        summary = None
        if req.program:
            self.bar.advance(0, f"programming set {s.index}")
            programmed = self._program(s, bench, progress)
            layout = programmed.layout
            summary = {**programmed.report["summary"], "all_ok": programmed.all_ok}
        else:
            layout = Layout.load(layout_path)
        check_layout(layout, s.weights, tuple(s.meta["grid"]), port=session.port,
                     weights_path=req.weights_path, set_index=s.index,
                     board_options=session.options)
        return summary, [self._launch(sc, s, session, layout, emit) for sc in req.hw_scenarios]

    def _program(self, s: _Set, bench: CellBench | None,
                 progress: ProgressCallback | None) -> ProgramResult:
        """Program set ``s`` (two-stage write-and-verify), its report into the request's
        ``report_dir``, on the unit's ``bench`` (every pulse journalled and recorded as
        applied)."""
        req = self.request
        report = req.report_dir / f"program-set{s.index}.json" \
            if req.report_dir is not None else None
        if bench is None:
            raise UserError(NEEDS_BOARD)
        return program_on_bench(bench, s.weights, s.meta, config=req.program_config,
                                progress=progress,
                                files=dataclasses.replace(bench.session.files, report=report))

    # -- a chip group ------------------------------------------------------------------------
    def _plan_group(self, bench: GroupBench) -> list[GeometryUnit]:
        """The checks of a chip group (each chip's mode, layout path and programming
        targets; UserError before anything is sent), its plan (which input neurons each chip
        holds, :mod:`snan_hil.calibration.chip_group`)."""
        req = self.request
        if not req.program:
            raise UserError("a chip group is programmed by the comparison (each chip its "
                            "share of every set): leave --no-program out")
        if req.mode not in (None, "on_board"):
            raise UserError(f"a chip group runs the on-board decision windows (each on the "
                            f"chip of its input neuron); --mode {req.mode.replace('_', '-')} "
                            "is not supported over a group: leave --mode out")
        self.group = bench.plan(tuple(self.meta0["grid"]))
        for b in bench.benches:
            require_hardware(b.client, "on_board", req.hil.launch_config(False))
            if b.layout_path is None:
                raise UserError(NEEDS_BOARD)
            check_program(b.session, b.layout_path, req.program_config or ProgramConfig())
        self.hw_mode = "on_board"
        chips = [_board_fields(b.session) for b in bench.benches]
        self._seen = {**chips[0], "group": [_chip_entry(c) for c in chips]}
        return [GeometryUnit()]

    def _group_set_record(self, s: _Set, bench: GroupBench, ctx: UnitContext
                          ) -> dict[str, Any]:
        """Set ``s`` over the chip group: software launches, then each chip programmed with
        its share (write-and-verify on its bench: pulses journalled and recorded in its
        history), then the hardware launches with every window on the chip of its input
        neuron. The record of :meth:`set_record`, the board fields of the first chip, the
        programming merged (:func:`merge_programming`) and ``group`` (every chip's fields)."""
        req = self.request
        assert self.group is not None
        t_set = time.perf_counter()
        results = [self._launch(sc, s, None, None, ctx.emit) for sc in req.sw_scenarios]
        sw_wall = time.perf_counter() - t_set
        per_chip: list[dict[str, Any]] = []
        chips: list[tuple[Any, Layout]] = []
        for k, b in enumerate(bench.benches):
            self.bar.advance(0, f"programming set {s.index} on chip {k}")
            report = req.report_dir / f"program-set{s.index}-chip{k}.json" \
                if req.report_dir is not None else None
            programmed = program_on_bench(
                b, s.weights, {**s.meta, "pres": list(self.group.shares[k])},
                config=req.program_config, progress=ctx.progress,
                files=dataclasses.replace(b.session.files, report=report))
            per_chip.append({**programmed.report["summary"], "all_ok": programmed.all_ok})
            check_layout(programmed.layout, s.weights, tuple(s.meta["grid"]),
                         port=b.session.port, weights_path=req.weights_path,
                         set_index=s.index, board_options=b.session.options)
            chips.append((b.client, programmed.layout))
        first = bench.benches[0].session
        results += [self._launch(sc, s, first, None, ctx.emit, group=chips)
                    for sc in req.hw_scenarios]
        fields = [_board_fields(b.session) for b in bench.benches]
        return {"results": [r.to_dict() for r in results],
                "programming": merge_programming(per_chip),
                "sw_wall_s": sw_wall, "wall_s": time.perf_counter() - t_set,
                "mode": self.hw_mode,
                "board": {**fields[0]["board"], "conversion_us": fields[0]["conversion_us"]},
                "port": fields[0]["port"], "protocol": fields[0]["protocol"],
                "baud": fields[0]["baud"], "session": fields[0]["session"],
                "group": [_chip_entry(f) for f in fields]}

    def _launch(self, scenario: str, s: _Set, session: BoardSession | None,
                layout: Layout | None, emit: LaunchSink | None,
                group: list[tuple[Any, Layout]] | None = None) -> ScenarioResult:
        req = self.request
        start, goal = task_of(self.meta0, req.hil)
        feed = None if emit is None else launch_feed(
            emit, scenario, s.index, req.hil.launch_config(scenario_parts(scenario)[1]),
            seed=req.seed)
        return run_scenario(scenario, s.weights, req.hil, set_index=s.index,
                            launches=req.launches, seed=req.seed, start=start, goal=goal,
                            client=session.client if session is not None else None,
                            layout=layout, mode=self.hw_mode if session is not None else None,
                            baud=session.baud if session is not None else None,
                            progress=self.bar.nested(f"set {s.index} {scenario} "),
                            on_launch=feed, conversions=req.conversions, group=group)

    # -- the run's progress and stream ------------------------------------------------------
    @property
    def bar(self) -> ProgressTracker:
        """The ``launches`` task (one unit per launch, all sets and scenarios)."""
        if self._bar is None:
            self._bar = track(None, "launches", self._n_launches)
        return self._bar

    @property
    def _n_launches(self) -> int:
        return len(self.sets) * self.request.launches * len(self.request.scenarios)

    def _start(self, ctx: UnitContext) -> None:
        """Before the run's first unit here: the progress task (sets taken from the
        checkpoint count as done), their launches sent to the stream, the kernels warmed
        up."""
        if self._bar is None:
            self._bar = track(ctx.progress, "launches", self._n_launches)
        self._resumed = self._resumed or bool(getattr(ctx.store, "resumed", False))
        per_set = self.request.launches * len(self.request.scenarios)
        for index, record in self._taken:
            self.send_taken(record, ctx.emit)
            self._bar.advance(per_set, f"set {index}: from the checkpoint")
        self._taken = []
        if not self._warm:
            self.warm_up()

    def send_taken(self, record: dict[str, Any], emit: LaunchSink | None) -> None:
        """The launches of a set's ``record`` (taken from the checkpoint or run elsewhere)
        to the ``launches`` stream, in order."""
        if emit is None:
            return
        req = self.request
        for d in record["results"]:
            sr = ScenarioResult.from_dict(d)
            cfg = req.hil.launch_config(scenario_parts(sr.scenario)[1])
            for launch in sr.launches:
                emit(STREAM, launch_event(sr.scenario, sr.set_index, launch, cfg,
                                          seed=req.seed))

    def warm_up(self) -> None:
        """Load the kernels before the software launches are timed (one untimed launch)."""
        self._warm = True
        req = self.request
        if req.sw_scenarios:
            start, goal = task_of(self.meta0, req.hil)
            run_scenario(req.sw_scenarios[0], self.sets[0].weights, req.hil, launches=1,
                         seed=req.seed, start=start, goal=goal)

    # -- the board --------------------------------------------------------------------------
    def _mode_of(self, client: Any) -> str:
        return require_hardware(client, self.request.mode, self.request.hil.launch_config(False))

    def _board_of(self, records: list[dict[str, Any]]) -> dict[str, Any]:
        """The results' board fields from the records (the first hardware one), else the
        run's session as planned: port, protocol, mode, baud, board (identity), session
        (snapshot), conversion_us; None without hardware scenarios."""
        keys = ("port", "protocol", "mode", "baud", "board", "session", "conversion_us")
        if not self.hw:
            return dict.fromkeys(keys)
        found = next((r for r in records if r.get("board") is not None), None)
        seen = self._seen
        if found is None:
            return {**dict.fromkeys(keys), **seen, "mode": self.hw_mode}
        board = found["board"]
        return {"port": found.get("port", seen.get("port")),
                "protocol": found.get("protocol", seen.get("protocol")),
                "mode": found.get("mode") or self.hw_mode,
                "baud": found.get("baud", seen.get("baud")),
                "board": BoardIdentity.from_record(board).to_dict(),
                "session": found.get("session", seen.get("session")),
                "conversion_us": float(board.get("conversion_us") or Info().conversion_us)}


def _board_fields(session: BoardSession) -> dict[str, Any]:
    """What the results record of the board a set ran on."""
    return {"port": session.port, "protocol": session.protocol, "baud": session.baud,
            "board": session.identity.to_dict(),
            "conversion_us": float(session.info.conversion_us),
            "session": session.snapshot()}


def _chip_entry(fields: dict[str, Any]) -> dict[str, Any]:
    """A chip of a group as the results record it: port, board id, protocol, baud."""
    return {"port": fields["port"], "board_id": fields["board"].get("board_id"),
            "protocol": fields["protocol"], "baud": fields["baud"]}


def _measure_geometry(session: BoardSession, client: Any) -> dict[str, Any] | None:
    """The 15 x 8 spike measurement of the speed/energy report on ``session``'s board (its
    reads at the layout's read code, else the INFO's), through ``client``."""
    row_code = session.info.read_code
    path = session.files.layout
    if path is not None and path.is_file():
        chain = Layout.load(path).read_chain
        row_code = chain.read_code if chain is not None else row_code
    return measure_spike_geometry(client, row_code=row_code, baud=session.baud)


def run_software(job: CompareJob, *, checkpoint: RunFolder | None = None,
                 progress: ProgressCallback | None = None,
                 emit: Callable[[str, dict[str, Any]], None] | None = None) -> dict[str, Any]:
    """A comparison of software scenarios only (no board: not a board job): the sets in
    order, each taken from ``checkpoint`` when it holds it, else run and committed; the
    results (:meth:`CompareJob.result`). UserError when ``job`` has hardware scenarios."""
    if job.hw:
        raise UserError(NEEDS_BOARD)
    ctx = UnitContext(progress=progress, store=checkpoint,
                      emit=emit if emit is not None else (lambda _s, _d: None))
    records: dict[str, dict[str, Any]] = {}
    for unit in job.plan(None):
        saved = checkpoint.done(unit.key) if checkpoint is not None else None
        if saved is not None:
            job.restore(unit, saved)
        else:
            saved = job.run_unit(unit, None, ctx)
            if checkpoint is not None:
                checkpoint.commit(unit.key, saved)
        records[unit.key] = saved
    if job._taken:                              # every set was taken: stream them all
        job._start(ctx)
    return job.result(records, "complete")


# -- several boards (lab.fanout): the results' board fields ----------------------------------

def boards_fields(job: CompareJob, results: dict[str, Any], units: Mapping[str, Any],
                  boards: list[dict[str, Any]]) -> dict[str, Any]:
    """The results of a comparison over several boards (``results``: :meth:`CompareJob.result`
    of every set's record) with board 0's fields as a one-board run records them (port,
    protocol, baud, board, session), ``boards`` (every board's description, ``lost`` when it
    was) and ``units`` (set -> the board, port, board id and worker that ran it; ``units``:
    :attr:`snan_hil.lab.fanout.BoardsRun.units`, by group)."""
    out = dict(results)
    keys = ("port", "protocol", "baud", "board", "session")
    if job.hw and boards:
        first = boards[0]
        out.update({"port": first["port"], "protocol": first["protocol"],
                    "baud": first["baud"], "board": first["identity"],
                    "session": first["session"], "boards": boards})
    else:
        out.update(dict.fromkeys(keys))
        out["mode"] = None
    out["units"] = {str(s.index): units.get(SetUnit(s.index).key)
                    for s in sorted(job.sets, key=lambda s: s.index)}
    return out


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


def adopt_old_snapshots(out: Path, unit_keys: list[str]) -> bool:
    """A checkpoint in ``out`` written before the comparison ran on the job runner keeps the
    emulated chip and its layout as they were after the last finished set (``board-<tag>``,
    ``layout-<tag>.json`` or ``layout-<tag>.absent``; ``<tag>`` the set's key, ``start``
    before the first): moved to where the runner puts back the chip of the first unfinished
    unit of ``unit_keys`` (``boundaries/before-<key>/``), so such a run resumes to the
    results of an uninterrupted one as it did. Whether anything was moved."""
    folder = Path(out) / CHECKPOINT_DIR
    if not folder.is_dir() or (folder / "boundaries").exists():
        return False
    done = [k for k in unit_keys if (folder / f"unit-{k}.json").is_file()]
    pending = [k for k in unit_keys if k not in done]
    finished = [k for k in done if k.startswith("set-")]
    tag = finished[-1] if finished else "start"
    chip, layout = folder / f"board-{tag}", folder / f"layout-{tag}.json"
    if not pending or not chip.exists() or not (layout.exists()
                                                or (folder / f"layout-{tag}.absent").exists()):
        return False
    dest = folder / "boundaries" / f"before-{pending[0]}"
    dest.mkdir(parents=True)
    os.replace(chip, dest / "chip")
    if layout.exists():
        os.replace(layout, dest / "layout.json")
    atomic_write_text(dest / "saved", f"chip and layout after {tag} (an earlier snan-hil)\n")
    return True


def check_snapshots(out: Path, board: ChipSnapshots | None) -> None:
    """Check every chip and layout snapshot the checkpoint in ``out`` holds (a resumed run
    puts one of them back: the job runner's boundaries, ``boundaries/**``, and those of a run
    over several boards, ``boards/**``) before the board is opened: UserError (one line
    naming the damaged file) changes nothing."""
    folder = Path(out) / CHECKPOINT_DIR
    if not folder.is_dir():
        return
    for mark in sorted(folder.glob("**/saved")):
        key = mark.parent.name.removeprefix("before-")
        if (folder / f"unit-{key}.json").is_file():
            continue                        # its unit finished: never put back
        chip, layout = mark.with_name("chip"), mark.with_name("layout.json")
        if board is not None:
            board.check(chip)
        if layout.exists():
            _check_layout_snapshot(layout)


def _check_layout_snapshot(path: Path) -> None:
    """UserError (one line naming ``path``) unless it holds a valid layout."""
    try:
        Layout.from_dict(json.loads(path.read_text(encoding="utf-8")), "snapshot")
    except (OSError, ValueError, AttributeError, LayoutError) as exc:
        reason = str(exc) if isinstance(exc, LayoutError) else f"{type(exc).__name__}: {exc}"
        raise UserError(f"--resume: the layout snapshot {path} in the checkpoint is damaged "
                        f"({reason}); the live layout was left untouched; start the run again "
                        "in a new --out") from None
