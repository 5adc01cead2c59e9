"""Program a weight matrix into the crossbar: screen, calibrate, place, write-and-verify, report.

:func:`program_weights` is the whole ``program-weights`` job on an open
:class:`~snan_hil.protocol.client.BoardClient` (HELLO done):

1. take the pulse counter baseline (STATUS) and the board clock (CLOCK);
2. load the layout at ``layout_path`` if it fits this grid and board (bad cells are kept), else
   place the synapses afresh;
3. screen: read every cell once; cells reading outside ``[screen_g_min_s, screen_g_max_s]``
   (stuck low / stuck high) are marked bad;
4. calibrate the read chain from reads of healthy cells (no pulses);
5. move synapses off bad cells, un-mark every synapse (``ok`` None: not verified on the chip),
   save the layout (before the first pulse);
6. per synapse: two-stage write-and-verify (:mod:`snan_hil.calibration.wv`) to its target
   conductance; a cell that fails is marked bad and the synapse moved to a spare (if enabled,
   at most ``max_attempts`` cells per synapse); the layout as it stands after a finished
   synapse is saved at most every ``checkpoint_s`` seconds, and always at the end and when the
   run stops on an error or interrupt, so an interrupted run leaves a consistent layout and a
   rerun resumes (cells already in place get few or no pulses);
7. compare the board's pulse counter with the pulses the host applied; build the report.

A board reset during programming (the link reports a new boot nonce) is survived: HELLO, a new
counter baseline, the cell is re-read and continued (at most ``max_resyncs`` times per run).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import statistics
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from snan_hil import __version__
from snan_hil.files.atomicio import atomic_write_json
from snan_hil.calibration.board_io import BoardCellIO, BoardLimits, PulseLedger
from snan_hil.calibration.layout import CELL_TEST_MARK, USER_LIST_MARK, Layout, LayoutError
from snan_hil.calibration.mapping import WeightMap
from snan_hil.calibration.observer import CellEvent, CellObserver, PulseEvent
from snan_hil.calibration.readchain import ReadChain, calibrate_read_chain, pick_calibration_cells
from snan_hil.calibration.wv import CellOutcome, ResponseModel, WVConfig, write_and_verify
from snan_hil.common.errors import UserError
from snan_hil.common.progress import ProgressCallback, track
from snan_hil.protocol.board import BoardConstants
from snan_hil.protocol.client import BoardClient
from snan_hil.protocol.errors import BoardResetError, UnsupportedError
from snan_hil.protocol.retry import RetryingClient

__all__ = ["ProgramConfig", "ProgramResult", "program_weights", "screen_cells",
           "REPORT_FORMAT", "failed_report", "write_failed_report", "write_report",
           "previous_report_path", "ConductanceRangeError", "programmable_range",
           "check_targets"]

log = logging.getLogger(__name__)

REPORT_FORMAT = "snan-hil-program-report/1"


@dataclass(frozen=True)
class ProgramConfig:
    """Settings of one programming run (conductances in S, voltages in V)."""

    wv: WVConfig = field(default_factory=WVConfig)
    weight_map: WeightMap = field(default_factory=WeightMap)
    spares: bool = True               # move failing synapses to spare cells
    max_attempts: int = 3             # cells tried per synapse (1 + relocations)
    screen: bool = True
    screen_g_min_s: float = 15e-6     # below: stuck low / open
    screen_g_max_s: float = 1.4e-3    # above: stuck high / shorted (compliance at 1.4 V)
    calibrate: bool = True
    calib_reads: int = 8
    verify_reads: int = 3             # reads averaged for the final conductance
    compliance_margin: float = 0.95
    max_resyncs: int = 3
    fresh_layout: bool = False        # ignore an existing layout file
    checkpoint_s: float = 1.0
    """Least wall time between two saves of the layout during programming (0: after every
    synapse). Each save is a full atomic rewrite (JSON, fsync, rename: ~10 ms, more on a busy
    disk); the layout is always saved before the first pulse, at the end, and when the run
    stops on an error or interrupt, so only a hard kill loses up to this much progress (a rerun
    re-verifies those cells)."""

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["wv"] = self.wv.to_dict()
        d["weight_map"] = self.weight_map.to_dict()
        return d


@dataclass
class ProgramResult:
    """What :func:`program_weights` returns: the report (dict, JSON-ready) and the layout."""

    report: dict
    layout: Layout

    @property
    def all_ok(self) -> bool:
        s = self.report["summary"]
        return bool(self.report.get("complete")) and s["failed"] == 0 and s["ok"] == s["cells"]


def _f(x: float | None, digits: int = 9) -> float | None:
    if x is None or not math.isfinite(x):
        return None
    return float(f"{x:.{digits}g}")


def screen_cells(client: BoardClient, chain: ReadChain, rows: int,
                 cols: int) -> dict[tuple[int, int], float]:
    """One read of every cell: {(row, col): G (S)}."""
    code = chain.read_code
    return {(r, c): float(chain.cell_conductance(client.read_cell(r, c, code), code))
            for r in range(rows) for c in range(cols)}


def _clock_us(client: BoardClient) -> int | None:
    try:
        return int(client.clock().time_us)
    except (UnsupportedError, AttributeError):
        return None


def _initial_layout(layout_path: Path | None, grid: tuple[int, int], info, cfg: ProgramConfig,
                    port: str) -> Layout:
    array = (info.rows, info.cols)
    old: Layout | None = None
    if layout_path is not None and layout_path.is_file() and not cfg.fresh_layout:
        try:
            old = Layout.load(layout_path)
        except LayoutError as exc:
            log.warning("ignoring unusable layout %s: %s", layout_path, exc)
    bad: dict = {}
    if old is not None:
        unknown = ("", "legacy")          # the legacy protocol has no board identity
        same_board = old.array == array and (old.board.get("board_id") in (None, *unknown)
                                             or info.board_id in unknown
                                             or old.board.get("board_id") == info.board_id)
        if same_board:
            bad = dict(old.bad_cells)
            if old.grid == tuple(grid):
                old.weight_map = cfg.weight_map
                return old
        else:
            log.warning("layout %s belongs to board %s; placing afresh", layout_path,
                        old.board.get("board_id"))
    layout = Layout.place(grid, array, bad, cfg.weight_map)
    layout.board = {"board_id": info.board_id, "firmware_version": info.firmware_version,
                    "port": port}
    return layout


class ConductanceRangeError(UserError):
    """Target conductances outside what the board can program and verify."""


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


def program_weights(client: BoardClient, weights: np.ndarray, meta: dict | None = None, *,
                    layout_path: str | os.PathLike[str] | None,
                    config: ProgramConfig | None = None,
                    port: str = "", report_path: str | os.PathLike[str] | None = None,
                    progress: ProgressCallback | None = None,
                    observer: CellObserver | None = None,
                    known_bad: dict[tuple[int, int], str] | None = None,
                    known_good: set[tuple[int, int]] | None = None) -> ProgramResult:
    """Program ``weights`` (dense N x N, validated) into the board behind ``client``.

    ``meta`` comes from :func:`~snan_hil.calibration.weights_io.load_weight_set` (needs
    ``grid``). ``progress`` gets the task "programming" (:mod:`snan_hil.common.progress`): one unit
    per synapse, the detail naming the cell and the ok / failed counts; a note for each
    synapse moved to a spare. The report is written atomically to ``report_path`` (if given)
    — also when the run is interrupted (``complete: false``). Raises on link failures it
    cannot survive.

    ``observer`` (:mod:`snan_hil.calibration.observer`) gets the screen's reads as cell results
    (outcome "read" or the reason a cell was marked bad), every applied pulse (stage "1" / "2")
    and every programmed cell's result ("ok" / "failed"). ``known_bad``: cells known to be bad
    from elsewhere (a cell test, :mod:`snan_hil.calibration.screening`), {(row, col): reason};
    they are marked bad before placement, so synapses go to spares instead. ``known_good``:
    cells whose last cell test found them good; a layout mark from an earlier cell test
    (reason starting "cell test") on one of them is dropped (the last class counts).
    """
    cfg = config or ProgramConfig()
    meta = dict(meta or {})
    if not isinstance(client, RetryingClient):
        client = RetryingClient(client)
    grid = tuple(meta.get("grid") or _square_grid(weights.shape[0]))
    wall0 = time.monotonic()
    layout_path = Path(layout_path) if layout_path is not None else None
    try:
        # a failure here (HELLO, the first STATUS or CLOCK, the layout) must not leave an
        # earlier run's complete report beside the new layout: an incomplete one replaces it
        info = client.info or client.hello()
        check_targets(info, cfg, f"board {info.board_id or port}")       # before any pulse
        ledger = PulseLedger()
        ledger.rebaseline(client)
        # board time (us) at start / resync, and the resets survived
        clock: dict[str, Any] = {"start": _clock_us(client), "resets": 0}
        layout = _initial_layout(layout_path, grid, info, cfg, port)
        checkpoints = _LayoutCheckpoints(layout, layout_path, cfg.checkpoint_s)
    except ConductanceRangeError:
        raise               # refused before anything changed: an earlier report stays valid
    except BaseException as exc:
        if report_path is not None:
            write_failed_report(report_path, exc, port=port, meta=meta, config=cfg,
                                wall_s=time.monotonic() - wall0)
        raise
    model = ResponseModel(cfg.wv)
    entries: list[dict | None] = [None] * layout.n_synapses
    state: dict[str, Any] = {"complete": False, "error": None}
    limits = BoardLimits.for_board(info, cfg.wv.v_max, cfg.compliance_margin)
    chain = layout.read_chain if layout.read_chain is not None else ReadChain.nominal(info)

    def report() -> dict:
        now = _clock_us_safe(client)
        virtual = None
        if clock["start"] is not None and now is not None:
            virtual = (now - clock["start"]) * 1e-6
        try:
            state["link"] = client.counters_dict()
        except (AttributeError, UserError):
            pass
        state["board_resets"] = clock["resets"]
        return _build_report(entries, layout, cfg, meta, ledger, model, state, port, info,
                             virtual, time.monotonic() - wall0, fw_delta=state.get("fw_delta"))

    try:
        # -- screen and calibrate (reads only) ---------------------------------------------
        screened: dict[tuple[int, int], float] = {}
        for cell in sorted(known_good or ()):
            if layout.bad_cells.get(cell, "").startswith(CELL_TEST_MARK):
                del layout.bad_cells[cell]
        for cell in [c for c, why in layout.bad_cells.items() if why.startswith(USER_LIST_MARK)]:
            del layout.bad_cells[cell]        # an earlier run's --cells-only / --cells-avoid
        for (r, c), why in sorted((known_bad or {}).items()):
            if 0 <= r < info.rows and 0 <= c < info.cols and (r, c) not in layout.bad_cells:
                layout.mark_bad(r, c, why)
        if cfg.screen:
            screened = screen_cells(client, chain, info.rows, info.cols)
            for cell, g in screened.items():
                seen = "read"
                if g < cfg.screen_g_min_s or g > cfg.screen_g_max_s:
                    why = "stuck low/open" if g < cfg.screen_g_min_s else "stuck high/shorted"
                    layout.mark_bad(*cell, f"screen: reads {g * 1e6:.1f} uS ({why})")
                    seen = why
                if observer is not None:
                    observer.on_cell(CellEvent(cell[0], cell[1], seen, g,
                                               detail={"step": "screen"}))
        if cfg.calibrate:
            healthy = {c: g for c, g in screened.items() if c not in layout.bad_cells}
            if not healthy:
                healthy = {(s.row, s.col): 1e-4 for s in layout.synapses[:8]}
            offset_cells, gain_cells = pick_calibration_cells(healthy)
            chain = calibrate_read_chain(client, offset_cells, gain_cells,
                                         n_reads=cfg.calib_reads)
        layout.read_chain = chain
        layout.relocate_bad()
        if info.board_id not in ("", "legacy") or not layout.board.get("board_id"):
            layout.board["board_id"] = info.board_id
        layout.board.update({"firmware_version": info.firmware_version, "port": port})
        # before the first pulse, no synapse is marked ok any more: a pulse may change any
        # of them, and one is marked ok again only once its write-and-verify has finished
        # (so a synapse the saved layout marks ok is always on the chip, whatever stops
        # the run; docs/durability.md)
        for syn in layout.synapses:
            syn.ok = None
        if layout_path is not None:
            checkpoints.save()                          # before the first pulse
        state["screen"] = {"cells": len(screened),
                           "bad": sorted([list(c) for c in layout.bad_cells])}

        # -- program ---------------------------------------------------------------------------
        targets = [float(weights[s.pre, s.post]) for s in layout.synapses]
        bar = track(progress, "programming", layout.n_synapses)
        counts = {"ok": 0, "failed": 0}
        for i, syn in enumerate(layout.synapses):
            w = targets[i]
            target = cfg.weight_map.conductance(w)
            attempts: list[dict] = []
            outcome: CellOutcome | None = None
            while True:
                bar.advance(0, f"cell ({syn.row:2d},{syn.col}) {syn.pre:>3}->{syn.post:<3} "
                               f"ok {counts['ok']} failed {counts['failed']}")
                io = BoardCellIO(client, chain, syn.row, syn.col, limits, ledger,
                                 cfg.wv.width_us)
                try:
                    outcome = write_and_verify(io, target, cfg.wv, model,
                                               verify_reads=cfg.verify_reads)
                    _observe(observer, io, outcome, w)
                except KeyboardInterrupt:      # Ctrl-C or a stop: the pulses applied so far
                    _observe(observer, io, None, w)
                    raise
                except BoardResetError as exc:
                    _observe(observer, io, None, w)
                    if ledger.resyncs >= cfg.max_resyncs:
                        raise
                    log.warning("board reset during programming (%s); resynchronising", exc)
                    client.hello()
                    ledger.resyncs += 1
                    ledger.rebaseline(client)
                    # the board's clock restarted: virtual time counts from here on
                    clock["start"], clock["resets"] = _clock_us(client), clock["resets"] + 1
                    continue
                if outcome.ok:
                    break
                attempts.append({"row": syn.row, "col": syn.col, "pulses": outcome.pulses,
                                 "final_s": _f(outcome.final_s), "reason": outcome.reason})
                if not cfg.spares or len(attempts) >= cfg.max_attempts:
                    break
                layout.mark_bad(syn.row, syn.col, f"programming: {outcome.reason}")
                old = (syn.row, syn.col)
                try:
                    layout.relocate(i)
                except LayoutError as exc:
                    log.warning("%s", exc)
                    break
                bar.note(f"cell {old} failed ({outcome.reason}); synapse {syn.pre}->{syn.post} "
                         f"moved to spare ({syn.row}, {syn.col})")
            assert outcome is not None
            syn.weight, syn.target_s = w, target
            syn.final_s, syn.ok = outcome.final_s, outcome.ok
            syn.stale = None
            entries[i] = _cell_entry(syn, w, outcome, attempts)
            checkpoints.synapse_done()
            counts["ok" if outcome.ok else "failed"] += 1
            bar.advance(1, f"ok {counts['ok']} failed {counts['failed']}")
        checkpoints.flush()
        state["fw_delta"] = ledger.firmware_delta(client)
        state["complete"] = True
    except KeyboardInterrupt:
        state["error"] = "interrupted"
        raise
    except Exception as exc:
        state["error"] = f"{type(exc).__name__}: {exc}"
        raise
    finally:
        if not state["complete"]:
            try:                      # the layout as of the last finished synapse
                checkpoints.flush()
            except OSError as exc:
                log.error("cannot save layout %s: %s", layout_path, exc)
        rep = report()
        state["report"] = rep
        if report_path is not None:
            try:
                write_report(report_path, rep)
            except OSError as exc:
                if state["error"] is not None:      # another error is on its way out
                    log.error("cannot write report %s: %s", report_path, exc)
                else:                               # the result was not written: not success
                    raise UserError(f"programming done (layout {layout_path}), but the report "
                                    f"{report_path} could not be written: "
                                    f"{exc.strerror or exc}") from None
    return ProgramResult(state["report"], layout)


def failed_report(error: BaseException | str, *, port: str = "", meta: dict | None = None,
                  config: ProgramConfig | None = None, wall_s: float | None = None) -> dict:
    """The report of a run that failed before programming started (no board state known):
    ``complete: false``, the error, no cells. Same format marker and top-level keys as a
    full report, so readers need no special case."""
    meta = meta or {}
    err = error if isinstance(error, str) else (
        "interrupted" if isinstance(error, KeyboardInterrupt)
        else f"{type(error).__name__}: {error}")
    return {
        "format": REPORT_FORMAT, "complete": False, "error": err, "port": port, "board": None,
        "weights": {k: meta.get(k) for k in ("path", "format", "set_index", "n_sets", "grid",
                                             "seed", "start", "goal") if k in meta},
        "config": (config or ProgramConfig()).to_dict(), "read_chain": None, "screen": None,
        "response_model": None, "ledger": None, "link": None, "board_resets": 0,
        "bad_cells": [],
        "summary": {"cells": None, "ok": 0, "failed": 0, "median_abs_rel_error": None,
                    "median_pulses": None, "virtual_s": None, "wall_s": _f(wall_s, 6),
                    "programmed": 0, "host_pulses": 0, "firmware_pulses": None,
                    "pulses_match": None},
        "cells": [],
    }


def previous_report_path(report_path: str | os.PathLike[str]) -> Path:
    """Where :func:`write_report` keeps the last complete report when a failed run replaces it:
    ``<name>.prev.json`` beside ``<name>.json`` (``chip.program-report.json`` ->
    ``chip.program-report.prev.json``)."""
    p = Path(report_path)
    stem = p.name[:-len(".json")] if p.name.endswith(".json") else p.name
    return p.with_name(f"{stem}.prev.json")


def _is_report(path: Path, *, complete: bool | None = None) -> bool:
    """Whether ``path`` holds a programming report (and, given, one with that ``complete``)."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return False
    return (isinstance(data, dict) and data.get("format") == REPORT_FORMAT
            and (complete is None or bool(data.get("complete")) == complete))


def write_report(report_path: str | os.PathLike[str], report: dict) -> None:
    """Write ``report`` to ``report_path`` atomically. The path always holds the last run's
    report (so no earlier ``complete: true`` report stays beside a layout a failed run has
    changed), and a failed run never loses the last good one: when ``report`` is incomplete
    and ``report_path`` holds a complete report, that one is first moved to
    :func:`previous_report_path` (replacing an older report there; a file there that is not a
    programming report is left alone and the complete report is then overwritten, logged).
    Raises OSError."""
    p = Path(report_path)
    if not report.get("complete") and _is_report(p, complete=True):
        prev = previous_report_path(p)
        if not prev.exists() or _is_report(prev):
            os.replace(p, prev)
            log.info("kept the last complete report as %s", prev)
        else:
            log.error("%s is not a programming report: the complete report %s is replaced "
                      "by this run's incomplete one", prev, p)
    atomic_write_json(p, report, indent=1, allow_nan=False)


def write_failed_report(report_path: str | os.PathLike[str], error: BaseException | str,
                        **kwargs: Any) -> None:
    """Write :func:`failed_report` to ``report_path`` with :func:`write_report` (an earlier
    complete report is kept as ``<name>.prev.json``); an unwritable path is logged, never
    raised over the original error."""
    try:
        write_report(report_path, failed_report(error, **kwargs))
    except OSError as exc:
        log.error("cannot write report %s: %s", report_path, exc)


def _observe(observer: CellObserver | None, io: BoardCellIO, outcome: CellOutcome | None,
             weight: float) -> None:
    """Hand one write-and-verify attempt to the observer: its pulses (stage from the
    outcome's trace, which lists the same executed pulses in order) and, when it finished,
    the cell's result."""
    if observer is None:
        return
    events: list[PulseEvent] = list(io.applied)
    if outcome is not None and len(outcome.trace) == len(events):
        events = [dataclasses.replace(e, stage=str(rec.stage))
                  for e, rec in zip(events, outcome.trace)]
    if events:
        observer.on_pulses(events)
    if outcome is None:
        return
    observer.on_cell(CellEvent(
        io.row, io.col, "ok" if outcome.ok else "failed", _f(outcome.final_s),
        target_s=outcome.target_s, pulses=outcome.pulses,
        detail={"weight": weight, "initial_s": _f(outcome.initial_s),
                "stage1_s": _f(outcome.stage1_s), "rel_error": _f(outcome.rel_error, 6),
                "reason": outcome.reason, "rounds": outcome.rounds}))


def _clock_us_safe(client: BoardClient) -> int | None:
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
        self._pending: dict | None = None
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

    def _write(self, snapshot: dict) -> None:
        if self.path is not None:
            Layout.write_snapshot(self.path, snapshot)
            self._saved_at = time.monotonic()
        self._pending = None


def _square_grid(n: int) -> tuple[int, int]:
    side = math.isqrt(n)
    if side * side != n:
        raise UserError(f"{n} neurons is not a square grid; pass meta['grid']")
    return side, side


def _cell_entry(syn, weight: float, o: CellOutcome, attempts: list[dict]) -> dict:
    failed_pulses = sum(a["pulses"] for a in attempts[:len(attempts) - (0 if o.ok else 1)]) \
        if attempts else 0
    return {
        "row": syn.row, "col": syn.col, "weight": weight, "target_s": _f(o.target_s),
        "final_s": _f(o.final_s), "rel_error": _f(o.rel_error, 6),
        "pulses_stage1": o.pulses_stage1, "pulses_stage2": o.pulses_stage2, "ok": o.ok,
        "pre": syn.pre, "post": syn.post, "initial_s": _f(o.initial_s),
        "stage1_s": _f(o.stage1_s), "stage1_ok": o.stage1_ok,
        "stage1_rel_error": _f(o.stage1_s / o.target_s - 1.0, 6),
        "pulses_total": o.pulses + failed_pulses, "rounds": o.rounds,
        "not_applied": o.not_applied, "reason": o.reason,
        "moved_from": [list(m) for m in syn.moved_from], "failed_attempts": attempts
        if o.ok else attempts[:-1],
    }


def _build_report(entries, layout: Layout, cfg: ProgramConfig, meta: dict, ledger: PulseLedger,
                  model: ResponseModel, state: dict, port: str, info, virtual_s, wall_s,
                  fw_delta: int | None) -> dict:
    done = [e for e in entries if e is not None]
    ok = [e for e in done if e["ok"]]
    errs = [abs(e["rel_error"]) for e in done if e["rel_error"] is not None]
    pulses = [e["pulses_total"] for e in done]
    host_pulses = ledger.host_pulses
    summary = {
        "cells": layout.n_synapses,
        "ok": len(ok),
        "failed": len(done) - len(ok),
        "median_abs_rel_error": _f(statistics.median(errs), 6) if errs else None,
        "median_pulses": statistics.median(pulses) if pulses else None,
        "virtual_s": _f(virtual_s, 6),
        "wall_s": _f(wall_s, 6),
        # extras
        "programmed": len(done),
        "stage1_ok": sum(1 for e in done if e["stage1_ok"]),
        "max_abs_rel_error": _f(max(errs), 6) if errs else None,
        "mean_pulses": _f(statistics.fmean(pulses), 6) if pulses else None,
        "max_pulses": max(pulses) if pulses else None,
        "pulses_total": ledger.confirmed,
        "relocated": sum(1 for s in layout.synapses if s.moved_from),
        "bad_cells": len(layout.bad_cells),
        "host_pulses": host_pulses,
        "firmware_pulses": fw_delta,
        "pulses_match": None if fw_delta is None else fw_delta == host_pulses,
    }
    return {
        "format": REPORT_FORMAT,
        "version": __version__,
        "complete": bool(state.get("complete")),
        "error": state.get("error"),
        "port": port,
        "board": {"board_id": info.board_id, "firmware_version": info.firmware_version},
        "weights": {k: meta.get(k) for k in ("path", "format", "set_index", "n_sets", "grid",
                                             "seed", "start", "goal") if k in meta},
        "config": cfg.to_dict(),
        "read_chain": layout.read_chain.to_dict() if layout.read_chain else None,
        "screen": state.get("screen"),
        "response_model": model.state(),
        "ledger": ledger.to_dict(),
        "link": state.get("link"),
        "board_resets": state.get("board_resets", 0),
        "bad_cells": [{"row": r, "col": c, "reason": why}
                      for (r, c), why in sorted(layout.bad_cells.items())],
        "summary": summary,
        "cells": done,
    }
