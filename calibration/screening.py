"""Cell screening: classify crossbar cells as good, stuck high, stuck low, noisy or unresponsive
with a bounded number of pulses (``snan-hil cells test``).

Per cell (against a :class:`~snan_hil.calibration.wv.CellIO`, in practice a
:class:`~snan_hil.calibration.board_io.BoardCellIO`, which enforces the host's read, write and
compliance limits):

1. **reads**: ``reads`` reads at the read voltage; ``G0`` = their median, the read noise their
   relative standard deviation;
2. **probe away from the nearer bound**: SET (G up) if ``G0`` is below the geometric middle of
   ``[g_low_s, g_high_s]``, else RESET; amplitudes ``v_start, v_start + v_step, ...`` up to
   ``v_max`` (and the compliance cap), one read after each pulse, until G has moved by
   ``response`` (relative) — at most ``max_probe_pulses`` pulses;
3. **probe back**: the other polarity, the same ramp, from where step 2 left the cell;
4. **classify** (first match): no ``response`` in either direction → ``stuck_high`` if
   ``G0 >= g_high_s``, ``stuck_low`` if ``G0 <= g_low_s``, else ``unresponsive``; the other
   direction moving less than ``reverse_response`` → ``unresponsive`` (the detail names the
   direction that worked); read noise above ``noise_limit`` → ``noisy``; else ``good``. The
   smaller threshold for the second direction is for cells near a bound of their range (a
   healthy cell at its G_min answers RESET with a few percent only: soft-bound switching);
5. **restore** (``restore``): a good or noisy cell is written back to ``G0`` with the two-stage
   write-and-verify (:func:`~snan_hil.calibration.wv.write_and_verify`, window
   ``restore_tolerance``, at most ``max_restore_pulses`` pulses), so screening a programmed chip
   leaves its weights where they were (within the window).

**The user's criteria** (:class:`UserCriteria`, ``cells test --rmin-below / --rmax-above /
--ratio-above``, the existing host's batch test and a lab's ON/OFF threshold): on top of the
fixed class, a responsive (good or noisy) cell's **switching window** is measured with full
ramps before its restore -- SET pulses from ``ramp_start_v`` up by ``ramp_step_v`` to
``set_v``, then held at ``set_v``, each followed by a read, until the cell settles (the last
``settle_pulses`` pulses moved G by less than ``settle`` in all) or ``max_ramp_pulses``:
``R_min``; then the same with RESET pulses up to ``reset_v``: ``R_max`` (R = 1/G of the read
chain, transistor included). Its **verdict** is ``good`` when its class is good and it meets
every criterion given (``R_min < rmin_below``, ``R_max > rmax_above``, ``R_max/R_min >
ratio_above``: the ON/OFF ratio of the window), else ``bad`` with the reasons. A ramp that
did not settle within ``max_ramp_pulses`` gives a window at least that wide (said in the
reasons); a pulse the compliance limit forbids is lowered to the limit. (One SET/RESET pair
at 1.2 V moves a YSZ cell by 5-30 %: its R_max/R_min is the step of one pulse pair, 1.05-1.6,
not the window, ~50 on the emulated chip; a threshold of 2 marked every healthy cell bad.)
The cell is then written back to its G0 with a larger budget (:data:`WINDOW_RESTORE_PULSES`):
after the window it sits at its G_min.

At most ``2 * max_probe_pulses + max_restore_pulses`` pulses per cell (with criteria:
``+ 2 * max_ramp_pulses``, and the restore's budget at least
:data:`WINDOW_RESTORE_PULSES`).
The limits' sources:
``g_low_s`` / ``g_high_s`` are the programming screen's (15 uS: below the device's G_min of
25 uS; 1.4 mS: a cell the 2 mA compliance cannot drive at 1.4 V); ``response`` 10 % is the
paper's programming window; ``reverse_response`` 3 % is three times the emulated chip's 1 %
read noise (an assumption); ``noise_limit`` 5 % is five times the emulated chip's 1 % read noise
(an assumption: a cell that noisy cannot be verified to the 2 % fine tolerance).
"""

from __future__ import annotations

import logging
import math
import os
import sqlite3
import statistics
from collections.abc import Callable, Sequence
from pathlib import Path
from dataclasses import asdict, dataclass, field
from typing import Annotated, Any, ClassVar

from annotated_types import Ge, Gt, Interval

from snan_hil.calibration.board_io import BoardCellIO
from snan_hil.calibration.observer import CellEvent, CellObserver, PulseEvent
from snan_hil.calibration.wv import CellIO, PulseNotApplied, WVConfig, write_and_verify
from snan_hil.common.polarity import Polarity
from snan_hil.common.progress import ProgressCallback, track
from snan_hil.config import loader as configio
from snan_hil.protocol.board import MEMRICORE
from snan_hil.records.history import History, HistoryError

__all__ = ["CLASSES", "BAD_CLASSES", "ScreenConfig", "UserCriteria", "CellClass", "screen_cell",
           "WINDOW_RESTORE_PULSES", "screen_cells", "bad_cells_from_history",
           "good_cells_from_history", "summarize", "mark_layout", "ScreenJob", "ScreenRun"]

log = logging.getLogger(__name__)

CLASSES = ("good", "stuck_high", "stuck_low", "noisy", "unresponsive")
BAD_CLASSES = ("stuck_high", "stuck_low", "noisy", "unresponsive")
SET, RESET = Polarity.SET, Polarity.RESET


@dataclass(frozen=True)
class ScreenConfig:
    """Settings of the cell test (S, V, us, counts); module docstring for the steps. Each
    field's bounds beside it, checked on construction (ConfigError naming the field), the
    checks across fields after them (``ValueError``)."""

    reads: Annotated[int, Ge(2)] = 5          # reads per cell (the read noise needs two)
    noise_limit: Annotated[float, Interval(gt=0, lt=1)] = 0.05   # relative read noise: noisy
    g_low_s: Annotated[float, Gt(0)] = 15e-6   # below: stuck low / open, S
    g_high_s: Annotated[float, Gt(0)] = 1.4e-3   # above: stuck high / shorted, S
    response: Annotated[float, Interval(gt=0, lt=1)] = 0.10   # |dG/G| a probe ramp must reach
    reverse_response: Annotated[float, Gt(0)] = 0.03   # ... in the second direction
    v_start: Annotated[float, Gt(0)] = 0.5     # first probe amplitude, V
    v_step: Annotated[float, Gt(0)] = 0.1      # probe ramp step, V
    v_max: Annotated[float, Gt(0)] = MEMRICORE.max_write_v   # largest probe amplitude, V
    width_us: Annotated[int, Ge(1)] = 100      # probe pulse width, us
    max_probe_pulses: Annotated[int, Ge(1)] = 8   # pulses per probe ramp, SET and RESET
    restore: bool = True
    restore_tolerance: Annotated[float, Interval(gt=0, lt=1)] = 0.10   # relative
    max_restore_pulses: Annotated[int, Ge(2)] = 20   # pulses to write a cell back

    def __post_init__(self) -> None:
        configio.check_bounds(self)
        if not self.g_low_s < self.g_high_s:
            raise ValueError("need g_low_s < g_high_s")
        if not self.reverse_response <= self.response:
            raise ValueError("need 0 < reverse_response <= response")
        if not MEMRICORE.max_read_v < self.v_start <= self.v_max:
            raise ValueError(f"v_max {self.v_max:g} V: give at least the first probe "
                             f"amplitude v_start {self.v_start:g} V (and v_start above the "
                             f"read limit {MEMRICORE.max_read_v} V)")

    @property
    def max_pulses(self) -> int:
        """Most pulses one cell can receive."""
        return 2 * self.max_probe_pulses + (self.max_restore_pulses if self.restore else 0)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


WINDOW_RESTORE_PULSES = 60
"""Pulses the restore may use after a window measurement (the cell is at its G_min then; 60:
twice what a YSZ cell of the emulated chip takes from G_min back to mid-range at 1.2 V)."""


@dataclass(frozen=True)
class UserCriteria:
    """The user's pass criteria of a cell test (Ohm; None: not tested) and the full SET and
    RESET ramps that measure the switching window, R_min and R_max (V, us, counts; module
    docstring)."""

    rmin_below_ohm: float | None = None
    rmax_above_ohm: float | None = None
    ratio_above: float | None = None
    set_v: float = 1.2                  # top of the SET ramp, V
    reset_v: float = 1.2                # top of the RESET ramp, V
    width_us: int = 100
    ramp_start_v: float = 0.5           # first pulse of each ramp, V (the probes' v_start)
    ramp_step_v: float = 0.1            # ramp step up to the top, V
    max_ramp_pulses: int = 80           # pulses per ramp at most
    settle: float = 0.02                # relative change of G over settle_pulses: settled
    settle_pulses: int = 5

    def __post_init__(self) -> None:
        for name in ("rmin_below_ohm", "rmax_above_ohm", "ratio_above"):
            v = getattr(self, name)
            if v is not None and not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive number, got {v}")
        if self.ratio_above is not None and self.ratio_above <= 1:
            raise ValueError(f"ratio_above must be above 1 (R_max/R_min), got "
                             f"{self.ratio_above}")
        if not (MEMRICORE.max_read_v < self.set_v and MEMRICORE.max_read_v < self.reset_v):
            raise ValueError(f"set_v and reset_v must be above the read limit "
                             f"{MEMRICORE.max_read_v} V")
        if not (self.ramp_step_v > 0 and self.max_ramp_pulses >= self.settle_pulses >= 1
                and 0 < self.settle < 1):
            raise ValueError("need ramp_step_v > 0, 0 < settle < 1 and "
                             "max_ramp_pulses >= settle_pulses >= 1")

    @property
    def active(self) -> bool:
        return any(v is not None for v in (self.rmin_below_ohm, self.rmax_above_ohm,
                                           self.ratio_above))

    def judge(self, cls: str, r_min: float | None, r_max: float | None) -> list[str]:
        """Why a cell fails (empty: it passes)."""
        why = [] if cls == "good" else [f"class {cls}"]
        if r_min is None or r_max is None:
            return why + ["no window measured (not responsive)"] if cls == "good" else why
        ratio = r_max / r_min if r_min > 0 else math.inf
        if self.rmin_below_ohm is not None and not r_min < self.rmin_below_ohm:
            why.append(f"R_min {r_min:.0f} Ohm >= {self.rmin_below_ohm:g}")
        if self.rmax_above_ohm is not None and not r_max > self.rmax_above_ohm:
            why.append(f"R_max {r_max:.0f} Ohm <= {self.rmax_above_ohm:g}")
        if self.ratio_above is not None and not ratio > self.ratio_above:
            why.append(f"R_max/R_min {ratio:.2f} <= {self.ratio_above:g}")
        return why

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class CellClass:
    """Result of one cell's test (conductances in S)."""

    row: int
    col: int
    cls: str
    g0_s: float
    noise_rel: float
    moves: dict[str, float] = field(default_factory=dict)   # polarity name -> relative change
    pulses: int = 0
    probe_pulses: int = 0
    final_s: float | None = None
    restored: bool | None = None
    note: str = ""
    r_min_ohm: float | None = None
    r_max_ohm: float | None = None
    verdict: str | None = None            # user criteria: "good" / "bad" (None: none given)
    reasons: list[str] = field(default_factory=list)
    window_pulses: int = 0                # pulses of the SET and RESET ramps of the window

    @property
    def ratio(self) -> float | None:
        if self.r_min_ohm is None or self.r_max_ohm is None or self.r_min_ohm <= 0:
            return None
        return self.r_max_ohm / self.r_min_ohm

    @property
    def good(self) -> bool:
        return self.cls == "good"

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["class"] = d.pop("cls")
        d["ratio"] = self.ratio
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                for k, v in d.items()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> CellClass:
        """The inverse of :meth:`to_dict` (a non-finite float comes back as NaN)."""
        fields = {k: v for k, v in d.items() if k not in ("class", "ratio")}
        for key in ("g0_s", "noise_rel"):
            if fields.get(key) is None:
                fields[key] = math.nan
        return cls(cls=d["class"], **fields)


def _ramp(cfg: ScreenConfig) -> list[float]:
    out: list[float] = []
    v = cfg.v_start
    while v <= cfg.v_max + 1e-9 and len(out) < cfg.max_probe_pulses:
        out.append(round(v, 6))
        v += cfg.v_step
    return out


def _probe(io: CellIO, polarity: Polarity, g_start: float,
           cfg: ScreenConfig) -> tuple[float, int, float, str]:
    """Ramp one polarity until G moved by ``response``: (relative move in the pulse's
    direction, pulses, G after, note)."""
    g = g_start
    pulses = 0
    note = ""
    best = 0.0
    for v in _ramp(cfg):
        cap = float(io.amplitude_cap(polarity, g)) if g > 0 else cfg.v_max
        if v > cap + 1e-9:
            if pulses == 0:
                note = f"{polarity.name} probe: compliance allows at most {cap:.2f} V"
            break
        try:
            g = float(io.pulse(polarity, v))
        except PulseNotApplied:
            g = float(io.read())
            continue
        pulses += 1
        if g_start > 0 and math.isfinite(g):
            ratio = g / g_start if polarity == SET else g_start / max(g, 1e-12)
            best = max(best, ratio - 1.0)
        if best >= cfg.response:
            break
    return best, pulses, g, note


def _ramp_until_settled(io: CellIO, pol: Polarity, top_v: float, crit: UserCriteria,
                        g: float) -> tuple[float, int, list[str]]:
    """Pulses of ``pol`` from ``ramp_start_v`` up to ``top_v`` then held there, a read after
    each, until the last ``settle_pulses`` moved G by less than ``settle`` or
    ``max_ramp_pulses``: (G after, pulses, notes)."""
    history = [g]
    notes: list[str] = []
    lowered = False
    v = min(crit.ramp_start_v, top_v)
    for _ in range(crit.max_ramp_pulses):
        cap = float(io.amplitude_cap(pol, g)) if g > 0 else v
        amp = min(v, cap)
        if amp < v - 1e-9 and not lowered:
            lowered = True
            notes.append(f"{pol.name} ramp lowered to {amp:.2f} V (compliance)")
        try:
            g = float(io.pulse(pol, amp))
        except PulseNotApplied:
            g = float(io.read())
        history.append(g)
        v = min(top_v, v + crit.ramp_step_v)
        if v >= top_v - 1e-9 and len(history) > crit.settle_pulses:
            before = history[-1 - crit.settle_pulses]
            if before > 0 and abs(g / before - 1.0) < crit.settle:
                return g, len(history) - 1, notes
    notes.append(f"{pol.name} ramp not settled in {crit.max_ramp_pulses} pulses (the window "
                 "is at least this wide)")
    return g, len(history) - 1, notes


def _window(io: CellIO, crit: UserCriteria, res: CellClass) -> None:
    """The switching window of the user's criteria: R_min after a full SET ramp, R_max after
    a full RESET ramp (module docstring)."""
    if isinstance(io, BoardCellIO):
        io.stage = "window"
        io.width_us = crit.width_us
    g = res.final_s if res.final_s is not None else float(io.read())
    g_on, n_set, notes_set = _ramp_until_settled(io, SET, crit.set_v, crit, g)
    g_off, n_reset, notes_reset = _ramp_until_settled(io, RESET, crit.reset_v, crit, g_on)
    res.pulses += n_set + n_reset
    res.window_pulses = n_set + n_reset
    res.reasons += notes_set + notes_reset
    res.r_min_ohm = 1.0 / g_on if g_on > 0 else math.inf
    res.r_max_ohm = 1.0 / g_off if g_off > 0 else math.inf
    res.final_s = g_off


def screen_cell(io: CellIO, cfg: ScreenConfig, row: int, col: int,
                criteria: UserCriteria | None = None) -> CellClass:
    """Classify one cell (module docstring); ``io`` is that cell; ``criteria``: the user's
    (the switching window, measured with full ramps, and a verdict)."""
    reads = [float(io.read()) for _ in range(cfg.reads)]
    finite = [g for g in reads if math.isfinite(g)]
    g0 = statistics.median(finite) if finite else math.nan
    mean = statistics.fmean(finite) if finite else math.nan
    noise = (statistics.stdev(finite) / mean) if len(finite) > 1 and mean > 0 else math.inf
    res = CellClass(row, col, "good", g0, noise)
    if not math.isfinite(g0) or g0 <= 0:
        res.cls, res.note = "stuck_low", "no valid read (open cell)"
        return res
    first = SET if g0 < math.sqrt(cfg.g_low_s * cfg.g_high_s) else RESET
    second = RESET if first == SET else SET
    m1, p1, g1, n1 = _probe(io, first, g0, cfg)
    m2, p2, g2, n2 = _probe(io, second, g1, cfg)
    res.moves = {first.name: m1, second.name: m2}
    res.probe_pulses = res.pulses = p1 + p2
    res.final_s = g2
    notes = [n for n in (n1, n2) if n]
    strong = max(m1, m2) >= cfg.response
    weak = min(m1, m2) >= cfg.reverse_response
    if not strong:
        if g0 >= cfg.g_high_s:
            res.cls = "stuck_high"
        elif g0 <= cfg.g_low_s:
            res.cls = "stuck_low"
        else:
            res.cls = "unresponsive"
        notes.append(f"no {cfg.response:.0%} change to SET or RESET pulses up to "
                     f"{cfg.v_max:.2f} V")
    elif not weak:
        res.cls = "unresponsive"
        moved = first if m1 >= m2 else second
        notes.append(f"responds to {moved.name} only")
    elif noise > cfg.noise_limit:
        res.cls = "noisy"
        notes.append(f"read noise {100 * noise:.3g}% > {100 * cfg.noise_limit:.3g}%")
    if criteria is not None and criteria.active:
        if res.cls in ("good", "noisy"):
            _window(io, criteria, res)
        notes_window = list(res.reasons)
        res.reasons = criteria.judge(res.cls, res.r_min_ohm, res.r_max_ohm) + notes_window
        res.verdict = "good" if not criteria.judge(res.cls, res.r_min_ohm, res.r_max_ohm) \
            else "bad"
    if cfg.restore and res.cls in ("good", "noisy"):
        if isinstance(io, BoardCellIO):           # label the pulses that follow
            io.stage = "restore"
            io.width_us = cfg.width_us
        _restore(io, cfg, res, budget=WINDOW_RESTORE_PULSES if res.window_pulses else 0)
    res.note = "; ".join(notes)
    return res


def _restore(io: CellIO, cfg: ScreenConfig, res: CellClass, budget: int = 0) -> None:
    """Write the cell back to G0 with at most ``max(cfg.max_restore_pulses, budget)``
    pulses."""
    total = max(cfg.max_restore_pulses, budget)
    half = max(1, total // 2)
    wv = WVConfig(tolerance=cfg.restore_tolerance,
                  fine_tolerance=min(0.02, cfg.restore_tolerance / 2),
                  v_max=cfg.v_max, fine_v_max=min(1.0, cfg.v_max), v_floor=min(0.35, cfg.v_max),
                  width_us=cfg.width_us, max_pulses_stage1=total - half,
                  max_pulses_stage2=half, max_rounds=1)
    out = write_and_verify(io, res.g0_s, wv)
    res.pulses += out.pulses
    res.final_s = out.final_s
    res.restored = out.ok


def screen_cells(make_io: Callable[[int, int], Any], cells: Sequence[tuple[int, int]],
                 cfg: ScreenConfig, *, observer: CellObserver | None = None,
                 progress: ProgressCallback | None = None,
                 criteria: UserCriteria | None = None) -> list[CellClass]:
    """Test ``cells`` one by one; ``make_io(row, col)`` gives the cell's IO (a
    :class:`~snan_hil.calibration.board_io.BoardCellIO`: its log of applied pulses goes to
    ``observer``, stage "probe" or "restore"). ``progress`` gets the task "testing cells"."""
    out: list[CellClass] = []
    bar = track(progress, "testing cells", len(cells))
    counts: dict[str, int] = {}
    for row, col in cells:
        io = make_io(row, col)
        if isinstance(io, BoardCellIO):
            io.stage = "probe"
        try:
            res = screen_cell(io, cfg, row, col, criteria)
        except BaseException:           # interrupted or stopped: the pulses applied so far
            if observer is not None and getattr(io, "applied", None):
                observer.on_pulses(list(io.applied))
            raise
        out.append(res)
        counts[res.cls] = counts.get(res.cls, 0) + 1
        if observer is not None:
            events: list[PulseEvent] = list(getattr(io, "applied", []))
            if events:
                observer.on_pulses(events)
            observer.on_cell(CellEvent(row, col, res.cls, res.final_s if res.final_s is not None
                                       else res.g0_s, target_s=res.g0_s if res.restored
                                       is not None else None, pulses=res.pulses,
                                       detail=res.to_dict()))
        bar.advance(1, f"cell ({row},{col}) {res.cls}; " +
                    ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))
    return out


def summarize(results: Sequence[CellClass]) -> dict[str, Any]:
    """Counts per class and pulses (and, with user criteria, per verdict)."""
    counts = {c: sum(1 for r in results if r.cls == c) for c in CLASSES}
    pulses = [r.pulses for r in results]
    judged = [r for r in results if r.verdict is not None]
    verdicts = ({"criteria_good": sum(1 for r in judged if r.verdict == "good"),
                 "criteria_bad": sum(1 for r in judged if r.verdict == "bad"),
                 "criteria_good_pct": 100.0 * sum(1 for r in judged if r.verdict == "good")
                 / len(judged)} if judged else {})
    return {"cells": len(results), **counts, **verdicts,
            "pulses_total": sum(pulses), "max_pulses_per_cell": max(pulses, default=0),
            "restored": sum(1 for r in results if r.restored),
            "restore_failed": sum(1 for r in results if r.restored is False)}


def good_cells_from_history(path: str | os.PathLike[str] | None) -> set[tuple[int, int]]:
    """Cells whose last class in a ``screen`` run of the history database at ``path`` is
    good (nothing when there is no database or it cannot be read)."""
    if path is None or not os.path.isfile(path):
        return set()
    try:
        with History.open(path, create=False) as db:
            latest = db.latest_cell_results("screen")
    except (sqlite3.Error, OSError, HistoryError):
        return set()
    return {cell for cell, (cls, _t, _run) in latest.items() if cls == "good"}


def bad_cells_from_history(path: str | os.PathLike[str] | None,
                           warn: Callable[[str], object] | None = None
                           ) -> dict[tuple[int, int], str]:
    """Cells whose last class in a ``screen`` run of the history database at ``path`` is not
    good: {(row, col): reason}. Nothing when there is no database; a database that cannot be
    read gives one ``warn`` line and nothing."""
    if path is None or not os.path.isfile(path):
        return {}
    try:
        with History.open(path, create=False) as db:
            latest = db.latest_cell_results("screen")
    except (sqlite3.Error, OSError, HistoryError) as exc:
        if warn is not None:
            warn(f"history database {path}: {exc}; cell-test classes not used for spare "
                 "selection")
        return {}
    return {cell: f"cell test (run {run}, {t[:19]}): {cls}"
            for cell, (cls, t, run) in latest.items() if cls in BAD_CLASSES}


def mark_layout(layout: Any, path: Any, results: Sequence[CellClass]
                ) -> tuple[list[list[int]], list[list[int]]]:
    """Bring the board's ``layout`` (saved to ``path`` if changed; None: no layout) up to the
    classes just found: bad cells marked, and the cell-test marks of cells now found good
    removed (the last class counts); returns (newly marked, cleared) cells."""
    from snan_hil.calibration.layout import CELL_TEST_MARK
    if layout is None:
        return [], []
    new, cleared = [], []
    changed = False
    for r in results:
        cell = (r.row, r.col)
        have = layout.bad_cells.get(cell)
        if r.cls in BAD_CLASSES:
            if have is None or (have.startswith(CELL_TEST_MARK)
                                and have != f"{CELL_TEST_MARK}: {r.cls}"):
                layout.mark_bad(r.row, r.col, f"{CELL_TEST_MARK}: {r.cls}")
                changed = True
                if have is None:
                    new.append([r.row, r.col])
        elif r.good and have is not None and have.startswith(CELL_TEST_MARK):
            del layout.bad_cells[cell]
            cleared.append([r.row, r.col])
    if changed or cleared:
        layout.save(path)
    return new, cleared


@dataclass
class ScreenRun:
    """A cell test as :class:`ScreenJob` ran it: every cell's class (in test order), the
    summary, the layout's cells newly marked bad and cleared (None: the board has no layout),
    and where the reads' conductances came from."""

    results: list[CellClass]
    summary: dict[str, Any]
    marked: list[list[int]]
    cleared: list[list[int]]
    layout_path: Any
    read_chain: str


class ScreenJob:
    """``snan-hil cells test`` as a board job (:mod:`snan_hil.calibration.job`): one unit,
    the cells in order; the board's layout (if it has one) marks the bad cells. ``names``:
    how the front door calls the config's fields in messages (the CLI's options; default
    the field names, as a notebook's keywords)."""

    kind: ClassVar[str] = "screen"
    restartable: ClassVar[bool] = False

    def __init__(self, cells: Sequence[tuple[int, int]] | None, cfg: ScreenConfig,
                 criteria: UserCriteria | None = None, *,
                 names: dict[str, str] | None = None) -> None:
        self.cells = None if cells is None else [(int(r), int(c)) for r, c in cells]
        """The cells in test order; None: every cell of the board, row by row."""
        self.cfg, self.criteria = cfg, criteria
        self.names = names or {}
        self._run: ScreenRun | None = None

    def describe(self) -> dict[str, Any]:
        return self.cfg.to_dict() | ({"criteria": self.criteria.to_dict()}
                                     if self.criteria else {})

    def plan(self, bench: Any) -> tuple[Any, ...]:
        from snan_hil.calibration.job import ONE, check_cells
        from snan_hil.calibration.layout import check_layout_writable
        if self.cells is None:
            self.cells = [(r, c) for r in range(bench.info.rows) for c in range(bench.info.cols)]
        check_cells(self.cells, bench.info, self.names.get("cells", "cells"))
        bench.check_amplitude(self.cfg.v_max, self.names.get("v_max", "v_max"))
        if bench.layout is not None:
            check_layout_writable(bench.layout_path)
        return ONE

    def run_unit(self, unit: Any, bench: Any, ctx: Any) -> dict[str, Any]:
        cfg = self.cfg
        assert self.cells is not None                      # plan() decided them
        results = screen_cells(
            lambda row, col: bench.cell(row, col, width_us=cfg.width_us, ceiling_v=cfg.v_max),
            self.cells, cfg, observer=bench.cell_results, progress=ctx.progress,
            criteria=self.criteria)
        layout = bench.layout
        marked, cleared = mark_layout(layout, bench.layout_path, results)
        return {"cells": [r.to_dict() for r in results], "marked": marked,
                "cleared": cleared, "read_chain": bench.chain_source,
                "layout": str(bench.layout_path) if layout is not None else None}

    def restore(self, unit: Any, record: dict[str, Any]) -> None:
        pass                                    # the record is all the result needs

    def result(self, records: Any, status: str) -> ScreenRun:
        record = records.get("all")
        if record is None:
            raise RuntimeError("the cell test did not run")
        results = [CellClass.from_dict(d) for d in record["cells"]]
        return ScreenRun(results, summarize(results), record["marked"], record["cleared"],
                         None if record["layout"] is None else Path(record["layout"]),
                         record["read_chain"])

    def summary(self, result: ScreenRun) -> dict[str, Any]:
        return result.summary
