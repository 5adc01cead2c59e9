"""Program a weight matrix into the crossbar: plan, execute, record.

:class:`ProgramJob` is the ``program-weights`` job as the job runner runs it
(:mod:`snan_hil.calibration.job`: its checks in ``plan``, the programming as its one unit);
:func:`program_on_bench` is the programming itself on a
:class:`~snan_hil.calibration.bench.CellBench` (the session's client as the run controls it,
the run's pulse ledger, every pulse journalled and recorded as it is applied), for the jobs
that program as a part of their work (a comparison's sets, a learning session);
:func:`program_weights` runs it on a bare :class:`~snan_hil.board.session.BoardSession` (a
bench made for the call: no journal, ``observer`` the only recorder). The layout and report
files are the session's (or ``files``):

*plan* (:func:`check_program`, :func:`_start`, :func:`_prepare_cells`; reads only, no pulse):

1. the target conductances checked against the board;
2. the layout at the session's layout file loaded if it fits this grid and board (bad cells are
   kept; a layout of another board or chip, or of a newer format, is refused, never
   overwritten), else the synapses placed afresh; the pulse counter baseline (STATUS) and the
   board clock (CLOCK) taken;
3. screen: every cell read once; cells reading outside ``[screen_g_min_s, screen_g_max_s]``
   (stuck low / stuck high) are marked bad, as are cells a cell test found bad;
4. the read chain calibrated from reads of healthy cells;
5. synapses moved off bad cells, every synapse un-marked (``ok`` None: not verified on the
   chip), the layout saved (before the first pulse);

*execute* (:func:`_program_synapses`): per synapse two-stage write-and-verify
(:mod:`snan_hil.calibration.wv`) to its target conductance; a cell that fails is marked bad and
the synapse moved to a spare (if enabled, at most ``max_attempts`` cells per synapse). A board
reset during programming (the link reports a new boot nonce) is survived by the resync policy
(:class:`_Resync`: HELLO, a new counter baseline, the cell re-read and continued, at most
``max_resyncs`` times per run);

*record* (:func:`_record`): the layout as it stands after a finished synapse is saved at most
every ``checkpoint_s`` seconds, and always at the end and when the run stops on an error or
interrupt, so an interrupted run leaves a consistent layout and a rerun resumes (cells already
in place get few or no pulses); the board's pulse counter is compared with the pulses the host
applied and the report (:mod:`snan_hil.calibration.program_report`) written.
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from snan_hil.board.files import BoardFiles
from snan_hil.board.identity import BoardIdentity
from snan_hil.board.session import BoardSession
from snan_hil.calibration.bench import CellBench
from snan_hil.calibration.board_io import BoardCellIO, CellLimits
from snan_hil.calibration.job import ONE, SingleUnit, UnitContext, check_cells
from snan_hil.calibration.layout import (CELL_TEST_MARK, LAYOUT_FORMAT, USER_LIST_MARK, Layout,
                                         LayoutError, Synapse)
from snan_hil.calibration.observer import CellEvent, CellObserver
from snan_hil.calibration.program_config import ProgramConfig
from snan_hil.calibration.program_report import (REPORT_FORMAT, build_report, cell_entry,
                                                 failed_report, finite, previous_report_path,
                                                 write_failed_report, write_report)
from snan_hil.calibration.readchain import ReadChain, calibrate_read_chain, pick_calibration_cells
from snan_hil.calibration.wv import CellOutcome, ResponseModel, write_and_verify
from snan_hil.common.errors import BoardLinkError, UserError
from snan_hil.common.progress import ProgressCallback, ProgressTracker, track
from snan_hil.protocol.board import BoardConstants
from snan_hil.protocol.client import BoardClient
from snan_hil.protocol.errors import BoardResetError, UnsupportedError

__all__ = ["ProgramConfig", "ProgramResult", "CellTests", "CellChoice", "ProgramJob",
           "ProgramRun", "program_on_bench", "program_weights", "check_program", "screen_cells",
           "REPORT_FORMAT", "failed_report", "write_failed_report", "write_report",
           "previous_report_path", "ConductanceRangeError", "LayoutRefused",
           "programmable_range", "check_targets", "check_layout_file"]

log = logging.getLogger(__name__)

Cell = tuple[int, int]


@dataclass(frozen=True)
class CellTests:
    """What cell tests (``snan-hil cells test``, :mod:`snan_hil.calibration.screening`) found:
    ``bad`` cells {(row, col): reason}, marked bad before placement so synapses go to spares
    instead; ``good`` cells, whose layout marks from an earlier cell test (reason starting
    "cell test") are dropped (the last class counts)."""

    bad: dict[Cell, str] = field(default_factory=dict)
    good: frozenset[Cell] = frozenset()


@dataclass
class ProgramResult:
    """What :func:`program_weights` returns: the report (JSON-ready) and the layout."""

    report: dict[str, Any]
    layout: Layout

    @property
    def all_ok(self) -> bool:
        s = self.report["summary"]
        return bool(self.report.get("complete")) and s["failed"] == 0 and s["ok"] == s["cells"]


class ConductanceRangeError(UserError):
    """Target conductances outside what the board can program and verify."""


class LayoutRefused(LayoutError):
    """The layout file belongs to another board or chip, or is of a newer format: it is left
    as it is (programming never overwrites it)."""


def screen_cells(client: BoardClient, chain: ReadChain, rows: int,
                 cols: int) -> dict[Cell, float]:
    """One read of every cell: {(row, col): G (S)}."""
    code = chain.read_code
    return {(r, c): float(chain.cell_conductance(client.read_cell(r, c, code), code))
            for r in range(rows) for c in range(cols)}


def programmable_range(info: BoardConstants, cfg: ProgramConfig) -> tuple[float, float]:
    """(lowest, highest) target conductance (S) of a cell on the board with constants
    ``info``: above the screen's stuck-low/open threshold, and below both its stuck-high
    threshold and the conductance that draws the board's compliance current at its largest
    write amplitude (``compliance_a / max_write_v``: 2 mA / 1.4 V = 1.43 mS on MemriCore; a
    cell above it could not take a full RESET pulse, and the screen would class it shorted)."""
    hi = min(cfg.screen_g_max_s, info.compliance_a / info.max_write_v)
    return cfg.screen_g_min_s, hi


def check_targets(info: BoardConstants, cfg: ProgramConfig, board: str = "the board") -> None:
    """ConductanceRangeError (one line) unless the weight map's G_min..G_max lies inside
    :func:`programmable_range`; called before any pulse."""
    lo, hi = programmable_range(info, cfg)
    wm = cfg.weight_map
    if lo <= wm.g_min_s and wm.g_max_s <= hi:
        return
    raise ConductanceRangeError(
        f"target conductances {wm.g_min_s * 1e6:g}..{wm.g_max_s * 1e6:g} uS are outside what "
        f"{board} can program and verify, {lo * 1e6:g}..{hi * 1e6:.4g} uS (below: a cell "
        f"reads as open/stuck low; above: as shorted, {info.compliance_a * 1e3:g} mA "
        f"compliance at {info.max_write_v:g} V); choose --g-min-us and --g-max-us inside it")


# -- the run's state --------------------------------------------------------------------------
@dataclass
class _Run:
    """One programming run: what the plan fixed, what execution changes, what is recorded."""

    bench: CellBench
    files: BoardFiles
    cfg: ProgramConfig
    meta: dict[str, Any]
    wall0: float
    layout: Layout
    checkpoints: _LayoutCheckpoints
    clock_start_us: int | None
    model: ResponseModel
    limits: CellLimits
    chain: ReadChain
    entries: list[dict[str, Any] | None]
    board_resets: int = 0
    state: dict[str, Any] = field(default_factory=lambda: {"complete": False, "error": None})

    @property
    def session(self) -> BoardSession:
        return self.bench.session

    @property
    def client(self) -> BoardClient:
        """The session's client as the run controls it (the bench's)."""
        return self.bench.client

    def report(self) -> dict[str, Any]:
        """The report as the run stands now (board time from the board's clock)."""
        now = _clock_us_safe(self.client)
        virtual = None
        if self.clock_start_us is not None and now is not None:
            virtual = (now - self.clock_start_us) * 1e-6
        try:
            self.state["link"] = self.client.counters_dict()
        except (AttributeError, UserError):
            pass
        self.state["board_resets"] = self.board_resets
        return build_report(self.session, self.entries, self.layout, self.cfg, self.meta,
                            self.bench.ledger, self.model, self.state, virtual_s=virtual,
                            wall_s=time.monotonic() - self.wall0)


def program_on_bench(bench: CellBench, weights: NDArray[np.float64],
                     meta: dict[str, Any] | None = None, *,
                     config: ProgramConfig | None = None,
                     progress: ProgressCallback | None = None,
                     cell_tests: CellTests | None = None, files: BoardFiles | None = None,
                     on_report: Callable[[dict[str, Any]], object] | None = None
                     ) -> ProgramResult:
    """Program ``weights`` (dense N x N, validated, in [0, 1]) into the board of ``bench``
    (see the module docstring); the layout goes to ``files.layout`` and the report
    (atomically, also when the run is interrupted: ``complete: false``) to ``files.report``
    when they are set (``files``: default the session's, ``bench.session.files``).

    ``meta`` comes from :func:`~snan_hil.calibration.weights_io.load_weight_set` (needs ``grid``;
    ``pres``, when set: only those input neurons' synapses, the board's share of a chip group,
    :mod:`snan_hil.calibration.chip_group`). ``progress`` gets the task "programming"
    (:mod:`snan_hil.common.progress`): one unit per synapse, the detail naming the cell and the ok /
    failed counts; a note for each synapse moved to a spare. Every pulse is recorded by the bench as
    it is applied (stage "1" / "2"); the bench's observers get the screen's reads as cell results
    (outcome "read" or the reason a cell was marked bad) and every programmed cell's result ("ok" /
    "failed"). ``cell_tests``: what cell tests found (:class:`CellTests`). ``on_report``: told the
    report as it is written (also for a run that fails or is interrupted). The report's ledger is
    the bench's, baselined on the board's pulse counter at the start (again here when the bench
    applied pulses before).

    The write amplitude ``config.wv.v_max`` is capped at the bench's one write limit, as
    before the job runner (a job checks its own ``v_max`` against the limit in its plan:
    :class:`ProgramJob`); the client refuses any pulse above it again. Raises
    ConductanceRangeError / :class:`LayoutRefused` before anything changes (an earlier report
    stays valid), and the link failures it cannot survive (the report then says so).
    """
    cfg = config or ProgramConfig()
    run = _start(bench, weights, dict(meta or {}), cfg,
                 files if files is not None else bench.session.files)
    try:
        _prepare_cells(run, cell_tests or CellTests())
        _program_synapses(run, weights, progress)
        run.checkpoints.flush()
        run.state["fw_delta"] = bench.ledger.firmware_delta(run.client)
        run.state["complete"] = True
    except KeyboardInterrupt:
        run.state["error"] = "interrupted"
        raise
    except Exception as exc:
        run.state["error"] = f"{type(exc).__name__}: {exc}"
        raise
    finally:
        _record(run, on_report)
        if run.files.layout == bench.layout_path:
            bench.forget_layout()                 # rewritten: load it again when asked for
    return ProgramResult(run.state["report"], run.layout)


def program_weights(session: BoardSession, weights: NDArray[np.float64],
                    meta: dict[str, Any] | None = None, *,
                    config: ProgramConfig | None = None,
                    progress: ProgressCallback | None = None,
                    observer: CellObserver | None = None,
                    cell_tests: CellTests | None = None) -> ProgramResult:
    """:func:`program_on_bench` on a bench made for this call from ``session`` (its client,
    a pulse ledger baselined on the board's counter; no pulse journal): for the callers that
    hold a session and not a bench (a comparison's set, a learning session, tests).
    ``observer`` gets every pulse as it is applied and every cell's result. A failure to take
    the pulse-counter baseline (STATUS) writes the failed report, as any failure after the
    checks does."""
    cfg = config or ProgramConfig()
    wall0 = time.monotonic()
    check_program(session, session.files.layout, cfg)
    try:
        bench = CellBench(session, observer=observer)
    except BaseException as exc:
        if session.files.report is not None:
            write_failed_report(session.files.report, exc, port=session.port, meta=meta,
                                config=cfg, wall_s=time.monotonic() - wall0)
        raise
    return program_on_bench(bench, weights, meta, config=cfg, progress=progress,
                            cell_tests=cell_tests)


# -- plan ---------------------------------------------------------------------------------------
def check_program(session: BoardSession, layout_path: Path | None, cfg: ProgramConfig) -> None:
    """Every check of a programming run before anything is sent: the weight map's targets
    against what the board can program (:class:`ConductanceRangeError`) and the layout file
    at ``layout_path`` (:class:`LayoutRefused` for another board's or chip's, or a newer
    format); one line each."""
    info = session.info
    check_targets(info, cfg, f"board {info.board_id or session.port}")
    _previous_layout(layout_path, session, True)


def _start(bench: CellBench, weights: NDArray[np.float64], meta: dict[str, Any],
           cfg: ProgramConfig, files: BoardFiles) -> _Run:
    """The checks before anything changes, the pulse and clock baselines, the initial layout.
    A failure after the checks (STATUS, CLOCK) must not leave an earlier run's complete
    report beside the new layout: an incomplete one replaces it."""
    wall0 = time.monotonic()
    session, info = bench.session, bench.info
    check_targets(info, cfg, f"board {info.board_id or session.port}")    # before any pulse
    grid = tuple(meta.get("grid") or _square_grid(weights.shape[0]))
    layout_path = files.layout
    previous = _previous_layout(layout_path, session, cfg.fresh_layout)
    # the write-and-verify ceiling, at most the session's one limit (a job checks its own
    # v_max against the limit in its plan; a caller's default above a lowered limit is capped)
    limits = bench.limits_for(ceiling_v=min(cfg.wv.v_max, bench.limits.max_write_v),
                              compliance_margin=cfg.compliance_margin)
    try:
        if bench.ledger.host_pulses:              # the bench applied pulses before this run
            bench.ledger.rebaseline(bench.client)
        clock_start = _clock_us(bench.client)
        share = meta.get("pres")              # a chip of a group: its input neurons
        layout = _initial_layout(previous, layout_path, (grid[0], grid[1]), session, cfg,
                                 None if share is None else tuple(sorted(map(int, share))))
    except BaseException as exc:
        if files.report is not None:
            write_failed_report(files.report, exc, port=session.port, meta=meta,
                                config=cfg, wall_s=time.monotonic() - wall0)
        raise
    chain = layout.read_chain if layout.read_chain is not None else ReadChain.nominal(info)
    return _Run(bench, files, cfg, meta, wall0, layout,
                _LayoutCheckpoints(layout, layout_path, cfg.checkpoint_s), clock_start,
                ResponseModel(cfg.wv), limits, chain, [None] * layout.n_synapses)


def _newer_format(fmt: object) -> bool:
    """Whether ``fmt`` is a later version of the layout format than this snan-hil writes."""
    family, _, version = LAYOUT_FORMAT.rpartition("/")
    have_family, _, have = str(fmt).rpartition("/")
    return have_family == family and have.isdigit() and int(have) > int(version)


def check_layout_file(path: Path | None, session: BoardSession) -> None:
    """:class:`LayoutRefused` (one line) when programming the board of ``session`` would refuse
    the layout at ``path`` (another board's or chip's, a newer format): a command that
    programs later checks it before it opens its output folder or does long work."""
    _previous_layout(path, session, True)


def _previous_layout(path: Path | None, session: BoardSession, fresh: bool) -> Layout | None:
    """The layout at ``path`` to start from (None: none, unusable, or ``fresh``).
    :class:`LayoutRefused` (one line, the file left as it is) for a layout of another board
    or chip or of a newer format, whatever ``fresh`` says (issue 27, item 8)."""
    if path is None or not path.is_file():
        return None
    try:
        raw = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        raw = None
    if isinstance(raw, dict):
        if _newer_format(raw.get("format")):
            raise LayoutRefused(
                f"layout {path} is of format {raw.get('format')}, newer than this snan-hil "
                f"reads ({LAYOUT_FORMAT}); it is left as it is: use the snan-hil version "
                "that wrote it, or give another --layout")
        recorded = BoardIdentity.from_record(raw.get("board") if isinstance(
            raw.get("board"), dict) else None)
        if not session.identity.owns(recorded):
            raise LayoutRefused(
                f"layout {path} was made on board {recorded.board_id}, but {session.port} is "
                f"board {session.identity.board_id}"
                f"{session.identity.other_chip_note(recorded)}; programming never overwrites "
                "another board's layout: leave --layout out for this board's own, give "
                "another file, or move that one away")
    if fresh:
        return None
    try:
        return Layout.load(path)
    except LayoutError as exc:
        log.warning("ignoring unusable layout %s: %s", path, exc)
        return None


def _initial_layout(old: Layout | None, path: Path | None, grid: tuple[int, int],
                    session: BoardSession, cfg: ProgramConfig,
                    pres: tuple[int, ...] | None = None) -> Layout:
    """The previous layout if it fits the grid and the share ``pres`` (a chip of a group;
    None: the whole network) — its bad cells kept when it fits the array — else the synapses
    placed afresh."""
    info = session.info
    array = (info.rows, info.cols)
    bad: dict[Cell, str] = {}
    if old is not None:
        if old.array == array:
            bad = dict(old.bad_cells)
            if old.grid == tuple(grid) and old.pres == pres:
                old.weight_map = cfg.weight_map
                return old
        else:
            log.warning("layout %s is for a %dx%d array, the board's is %dx%d; placing "
                        "afresh", path, *old.array, *array)
    layout = Layout.place(grid, array, bad, cfg.weight_map, pres=pres)
    layout.board = session.identity.to_dict(port=session.port)
    return layout


def _prepare_cells(run: _Run, tests: CellTests) -> None:
    """Screen, calibrate and place (reads only): marks bad cells, calibrates the read chain,
    moves synapses off bad cells, un-marks every synapse and saves the layout before the
    first pulse."""
    layout, info, cfg = run.layout, run.session.info, run.cfg
    for cell in sorted(tests.good):
        if layout.bad_cells.get(cell, "").startswith(CELL_TEST_MARK):
            del layout.bad_cells[cell]
    for cell in [c for c, why in layout.bad_cells.items() if why.startswith(USER_LIST_MARK)]:
        del layout.bad_cells[cell]        # an earlier run's --cells-only / --cells-avoid
    for (r, c), why in sorted(tests.bad.items()):
        if 0 <= r < info.rows and 0 <= c < info.cols and (r, c) not in layout.bad_cells:
            layout.mark_bad(r, c, why)
    screened = _screen(run) if cfg.screen else {}
    if cfg.calibrate:
        healthy = {c: g for c, g in screened.items() if c not in layout.bad_cells}
        if not healthy:
            healthy = {(s.row, s.col): 1e-4 for s in layout.synapses[:8]}
        offset_cells, gain_cells = pick_calibration_cells(healthy)
        run.chain = calibrate_read_chain(run.client, offset_cells, gain_cells,
                                         n_reads=cfg.calib_reads)
    layout.read_chain = run.chain
    layout.relocate_bad()
    identity = run.session.identity
    if identity.known or not layout.board.get("board_id"):
        layout.board["board_id"] = identity.board_id
    layout.board.update({"firmware_version": identity.firmware_version,
                         "port": run.session.port})
    # before the first pulse, no synapse is marked ok any more: a pulse may change any of
    # them, and one is marked ok again only once its write-and-verify has finished (so a
    # synapse the saved layout marks ok is always on the chip, whatever stops the run;
    # docs/durability.md)
    for syn in layout.synapses:
        syn.ok = None
    if run.checkpoints.path is not None:
        run.checkpoints.save()                          # before the first pulse
    run.state["screen"] = {"cells": len(screened),
                           "bad": sorted([list(c) for c in layout.bad_cells])}


def _screen(run: _Run) -> dict[Cell, float]:
    """One read of every cell; cells outside the screen's window are marked bad."""
    cfg, layout, info = run.cfg, run.layout, run.session.info
    screened = screen_cells(run.client, run.chain, info.rows, info.cols)
    for cell, g in screened.items():
        seen = "read"
        if g < cfg.screen_g_min_s or g > cfg.screen_g_max_s:
            why = "stuck low/open" if g < cfg.screen_g_min_s else "stuck high/shorted"
            layout.mark_bad(*cell, f"screen: reads {g * 1e6:.1f} uS ({why})")
            seen = why
        run.bench.report(CellEvent(cell[0], cell[1], seen, g, detail={"step": "screen"}))
    return screened


# -- execute ------------------------------------------------------------------------------------
class _Resync:
    """The board-reset policy: a write-and-verify interrupted by a board reset (a new boot
    nonce) is survived — HELLO, a new pulse-counter baseline, the board's clock taken again,
    the cell re-read and continued — at most ``max_resyncs`` times per run, then the reset
    is raised."""

    def __init__(self, run: _Run):
        self.run = run

    def write_and_verify(self, syn: Synapse, target_s: float, weight: float, note: str,
                         bar: ProgressTracker) -> CellOutcome:
        """Two-stage write-and-verify of ``syn``'s cell to ``target_s`` (S); its pulses are
        recorded by the bench as they are applied (stage "1" / "2"), its result reported
        when it finished."""
        run = self.run
        while True:
            bar.advance(0, note)
            io = run.bench.cell(syn.row, syn.col, width_us=run.cfg.wv.width_us,
                                limits=run.limits, chain=run.chain)
            try:
                outcome = write_and_verify(io, target_s, run.cfg.wv, run.model,
                                           verify_reads=run.cfg.verify_reads,
                                           on_stage=_stage_of(io))
            except BoardResetError as exc:
                self._recover(exc)
                continue
            _report_cell(run.bench, io, outcome, weight)
            return outcome

    def _recover(self, exc: BoardResetError) -> None:
        run = self.run
        ledger = run.bench.ledger
        if ledger.resyncs >= run.cfg.max_resyncs:
            raise exc
        log.warning("board reset during programming (%s); resynchronising", exc)
        run.client.hello()
        ledger.resyncs += 1
        ledger.rebaseline(run.client)
        # the board's clock restarted: virtual time counts from here on
        run.clock_start_us = _clock_us(run.client)
        run.board_resets += 1


def _program_synapses(run: _Run, weights: NDArray[np.float64],
                      progress: ProgressCallback | None) -> None:
    """Write-and-verify every synapse of the layout (moving failing ones to spares)."""
    layout = run.layout
    targets = [float(weights[s.pre, s.post]) for s in layout.synapses]
    bar = track(progress, "programming", layout.n_synapses)
    counts = {"ok": 0, "failed": 0}
    resync = _Resync(run)
    for i, syn in enumerate(layout.synapses):
        outcome, attempts = _program_synapse(run, i, targets[i], resync, bar, counts)
        syn.weight, syn.target_s = targets[i], run.cfg.weight_map.conductance(targets[i])
        syn.final_s, syn.ok = outcome.final_s, outcome.ok
        syn.stale = None
        run.entries[i] = cell_entry(syn, targets[i], outcome, attempts)
        run.checkpoints.synapse_done()
        counts["ok" if outcome.ok else "failed"] += 1
        bar.advance(1, f"ok {counts['ok']} failed {counts['failed']}")


def _program_synapse(run: _Run, index: int, weight: float, resync: _Resync,
                     bar: ProgressTracker, counts: dict[str, int]
                     ) -> tuple[CellOutcome, list[dict[str, Any]]]:
    """Program synapse ``index`` to ``weight``; a failed cell is marked bad and the synapse
    moved to a spare while spares and attempts last. Returns the last outcome and the failed
    attempts."""
    cfg, layout = run.cfg, run.layout
    syn = layout.synapses[index]
    target = cfg.weight_map.conductance(weight)
    attempts: list[dict[str, Any]] = []
    while True:
        note = (f"cell ({syn.row:2d},{syn.col}) {syn.pre:>3}->{syn.post:<3} "
                f"ok {counts['ok']} failed {counts['failed']}")
        outcome = resync.write_and_verify(syn, target, weight, note, bar)
        if outcome.ok:
            return outcome, attempts
        attempts.append({"row": syn.row, "col": syn.col, "pulses": outcome.pulses,
                         "final_s": finite(outcome.final_s), "reason": outcome.reason})
        if not cfg.spares or len(attempts) >= cfg.max_attempts:
            return outcome, attempts
        layout.mark_bad(syn.row, syn.col, f"programming: {outcome.reason}")
        old = (syn.row, syn.col)
        try:
            layout.relocate(index)
        except LayoutError as exc:
            log.warning("%s", exc)
            return outcome, attempts
        bar.note(f"cell {old} failed ({outcome.reason}); synapse {syn.pre}->{syn.post} "
                 f"moved to spare ({syn.row}, {syn.col})")


def _stage_of(io: BoardCellIO) -> Callable[[int], None]:
    """Labels the pulses ``io`` applies with their write-and-verify stage ("1" / "2")."""
    def label(stage: int) -> None:
        io.stage = str(stage)
    return label


def _report_cell(bench: CellBench, io: BoardCellIO, outcome: CellOutcome,
                 weight: float) -> None:
    """A finished write-and-verify's result to the bench's observers (its pulses were
    recorded as they were applied)."""
    bench.report(CellEvent(
        io.row, io.col, "ok" if outcome.ok else "failed", finite(outcome.final_s),
        target_s=outcome.target_s, pulses=outcome.pulses,
        detail={"weight": weight, "initial_s": finite(outcome.initial_s),
                "stage1_s": finite(outcome.stage1_s), "rel_error": finite(outcome.rel_error, 6),
                "reason": outcome.reason, "rounds": outcome.rounds}))


# -- record -------------------------------------------------------------------------------------
def _record(run: _Run, on_report: Callable[[dict[str, Any]], object] | None = None) -> None:
    """The layout as of the last finished synapse (when the run did not complete) and the
    report, written (and handed to ``on_report``). A report that cannot be written after a
    complete run is an error (the result was not recorded); after a failed one it is logged
    under the failure."""
    if not run.state["complete"]:
        try:                      # the layout as of the last finished synapse
            run.checkpoints.flush()
        except OSError as exc:
            log.error("cannot save layout %s: %s", run.checkpoints.path, exc)
    report = run.report()
    run.state["report"] = report
    if on_report is not None:
        on_report(report)
    path = run.files.report
    if path is None:
        return
    try:
        write_report(path, report)
    except OSError as exc:
        if run.state["error"] is not None:      # another error is on its way out
            log.error("cannot write report %s: %s", path, exc)
        else:                                   # the result was not written: not success
            raise UserError(f"programming done (layout {run.checkpoints.path}), but the report "
                            f"{path} could not be written: {exc.strerror or exc}") from None


def _clock_us(client: BoardClient) -> int | None:
    try:
        return int(client.clock().time_us)
    except (UnsupportedError, AttributeError):
        return None


def _clock_us_safe(client: BoardClient) -> int | None:
    """The board clock for a report, or None where it cannot be asked: a board reset or a
    link failure, or a request still on the line (a run stopped by Ctrl-C inside a round
    trip: asking now would be a second request on a stop-and-wait link)."""
    if getattr(client, "outstanding", 0):
        return None
    try:
        return _clock_us(client)
    except (BoardResetError, UserError):
        return None


class _LayoutCheckpoints:
    """Saves the layout as it stood after the last finished synapse: at most every
    ``interval_s`` s of wall time (the states in between are kept in memory), and on
    :meth:`flush`. ``path`` None: never saved."""

    def __init__(self, layout: Layout, path: Path | None, interval_s: float):
        self.layout, self.path, self.interval_s = layout, path, float(interval_s)
        self._pending: dict[str, Any] | None = None
        self._saved_at = -math.inf

    def save(self) -> None:
        """Save the layout as it stands now."""
        self._write(self.layout.snapshot())

    def synapse_done(self) -> None:
        """A synapse is finished: save if the interval has passed, else keep its state."""
        if self.path is None:
            return
        if time.monotonic() - self._saved_at >= self.interval_s:
            self.save()
        else:
            self._pending = self.layout.snapshot()

    def flush(self) -> None:
        """Write the last kept state, if it was not written yet."""
        if self._pending is not None:
            self._write(self._pending)

    def _write(self, snapshot: dict[str, Any]) -> None:
        if self.path is not None:
            Layout.write_snapshot(self.path, snapshot)
            self._saved_at = time.monotonic()
        self._pending = None


def _square_grid(n: int) -> tuple[int, int]:
    side = math.isqrt(n)
    if side * side != n:
        raise UserError(f"{n} neurons is not a square grid; pass meta['grid']")
    return side, side


# -- the job ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CellChoice:
    """The user's choice of cells for one run: synapses ``only`` on these cells (the others
    count as bad for this run), or never on the cells of ``avoid``; ``source`` is how the
    front door names the list in the layout's reasons (the CLI: ``--cells-only good.csv``; a
    notebook: ``cells_only``)."""

    only: frozenset[Cell] | None = None
    avoid: frozenset[Cell] = frozenset()
    source: str = ""

    def bad(self, rows: int, cols: int) -> dict[Cell, str]:
        """The cells this choice rules out on a ``rows`` x ``cols`` array, with the reason
        (starting with the layout's ``USER_LIST_MARK``)."""
        if self.only is not None:
            return {(r, c): f"{USER_LIST_MARK}: not in {self.source}"
                    for r in range(rows) for c in range(cols) if (r, c) not in self.only}
        return {cell: f"{USER_LIST_MARK}: in {self.source}" for cell in sorted(self.avoid)}

    def to_dict(self) -> dict[str, Any]:
        return {"only": None if self.only is None else sorted(map(list, self.only)),
                "avoid": sorted(map(list, self.avoid)), "source": self.source}


@dataclass
class ProgramRun:
    """A programming run as :class:`ProgramJob` ran it: the report (None when the run was cut
    before the board answered), where the layout and report were written, and the run's
    status ("complete", "interrupted")."""

    report: dict[str, Any] | None
    layout_path: Path | None
    report_path: Path | None
    status: str = "complete"

    @property
    def all_ok(self) -> bool:
        """Complete, and every synapse inside its window."""
        if self.report is None:
            return False
        s = self.report["summary"]
        return bool(self.report.get("complete")) and s["failed"] == 0 and s["ok"] == s["cells"]


def _recording_failed(bench: CellBench) -> bool:
    """Whether the run's recorder (an observer of the bench: ``failed`` set) gave up on its
    history database, and said so in its one warning line."""
    observer = bench.observer
    return any(getattr(o, "failed", None) is not None
               for o in getattr(observer, "observers", [observer]))


class ProgramJob:
    """``snan-hil program-weights`` as a board job (:mod:`snan_hil.calibration.job`): one
    unit, :func:`program_on_bench` with the cell classes of the board's cell tests (its
    history database, ``cell_tests``) and the user's ``cells`` choice. ``names``: how the
    front door spells the config's fields in messages (``v_max``, ``cells``)."""

    kind: ClassVar[str] = "program"
    restartable: ClassVar[bool] = False

    def __init__(self, weights: NDArray[np.float64], meta: Mapping[str, Any] | None = None,
                 config: ProgramConfig | None = None, *, cells: CellChoice | None = None,
                 cell_tests: bool = True, names: Mapping[str, str] | None = None) -> None:
        self.weights = weights
        self.meta = dict(meta or {})
        self.cfg = config or ProgramConfig()
        self.cells = cells or CellChoice()
        self.use_cell_tests = cell_tests
        self.names = dict(names or {})
        self.planned = False
        """Whether the runner got as far as the job's checks (the board opened, the bench
        made): a failure before it leaves no report of the job's own
        (:meth:`failed_before_start`)."""
        self._tests = CellTests()
        self._problems: list[str] = []
        self._report: dict[str, Any] | None = None
        self._files: BoardFiles | None = None

    def describe(self) -> dict[str, Any]:
        return self.cfg.to_dict()

    def plan(self, bench: CellBench) -> Sequence[SingleUnit]:
        self.planned = True
        bench.check_amplitude(self.cfg.wv.v_max, self.names.get("v_max", "v_max"))
        check_program(bench.session, bench.layout_path, self.cfg)
        info = bench.info
        for cells in (self.cells.only, self.cells.avoid):
            if cells:
                check_cells(sorted(cells), info, self.names.get("cells", "cells"))
        self._tests = self._cell_tests(bench)
        self._files = bench.session.files
        return ONE

    def _cell_tests(self, bench: CellBench) -> CellTests:
        """What the board's cell tests found (its history database) and the user's choice;
        a database that cannot be read is one warning line when the run starts (none when
        the run's recorder named the file already: :meth:`run_unit`)."""
        from snan_hil.calibration.screening import (bad_cells_from_history,
                                                    good_cells_from_history)
        history = bench.session.files.history
        bad = bad_cells_from_history(history, warn=self._problems.append) \
            if self.use_cell_tests else {}
        bad.update(self.cells.bad(bench.info.rows, bench.info.cols))
        good = frozenset(good_cells_from_history(history)) if self.use_cell_tests \
            else frozenset()
        return CellTests(bad, good)

    def run_unit(self, unit: SingleUnit, bench: CellBench, ctx: UnitContext) -> dict[str, Any]:
        def keep(report: dict[str, Any]) -> None:
            self._report = report
        if not _recording_failed(bench):
            for line in self._problems:
                bench.warn(line)
        result = program_on_bench(bench, self.weights, self.meta, config=self.cfg,
                                  progress=ctx.progress, cell_tests=self._tests,
                                  on_report=keep)
        return {"report": result.report}

    def restore(self, unit: SingleUnit, record: dict[str, Any]) -> None:
        raise NotImplementedError("a programming run is not resumed (a rerun starts from the "
                                  "layout it left)")

    def result(self, records: Mapping[str, dict[str, Any]], status: str) -> ProgramRun:
        record = records.get(ONE[0].key)
        report = record["report"] if record is not None else self._report
        files = self._files or BoardFiles()
        return ProgramRun(report, files.layout, files.report, status)

    def summary(self, result: ProgramRun) -> dict[str, Any] | None:
        return None if result.report is None else result.report["summary"]

    def failed_before_start(self, report: Path | None, error: BaseException, *,
                            port: str = "") -> None:
        """After ``error`` ended the run: the failed report at ``report`` when the run ended
        before the job's checks (the board could not be opened, its pulse counter not read),
        as a failure after them leaves the run's own report; an earlier complete report is
        kept as ``<name>.prev.json``. A user mistake found when the board opened (a
        ``--max-write-v`` above its declared limit, another board's files) writes nothing:
        it is not a failed programming run, and the last report stays as it was."""
        if isinstance(error, UserError) and not isinstance(error, BoardLinkError):
            return
        if not self.planned and report is not None:
            write_failed_report(report, error, port=port, meta=self.meta, config=self.cfg)
