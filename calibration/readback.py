"""Read programmed synapses back: conductances, the weight matrix, and retention statistics.

Two read paths (:mod:`snan_hil.calibration.readchain`):

* ``"cell"`` — READ_CELL of each cell (the path programming verified with);
* ``"column"`` — SPIKE_BATCH with one spike per used row (only that row driven, at the read
  voltage) and a read of every used column, exactly what the agent's hardware runs see; the
  column codes are converted with :meth:`ReadChain.column_cell_conductance`. Many read cycles
  travel in one request, which makes 10,000-cycle retention runs practical.
"""

from __future__ import annotations

import copy
import math
import statistics
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from snan_hil.calibration.bench import CellBench
from snan_hil.calibration.job import ONE, SingleUnit, UnitContext
from snan_hil.calibration.layout import Layout, load_session_layout
from snan_hil.calibration.observer import CellEvent
from snan_hil.calibration.readchain import ReadChain
from snan_hil.common.errors import UserError
from snan_hil.common.progress import ProgressCallback, track
from snan_hil.protocol.client import BoardClient
from snan_hil.protocol.messages import Capability, SpikeGroup

Floats = NDArray[np.float64]
"""A float64 array (shape and unit in each docstring)."""

__all__ = ["READ_PATHS", "read_conductances", "read_weight_matrix", "RetentionCell",
           "retention_run", "retention_stats", "weight_errors", "read_series",
           "summarize_retention", "board_layout", "RetentionConfig", "RetentionRun",
           "RetentionJob", "ReadWeightsConfig", "WeightsRead", "ReadWeightsJob"]

READ_PATHS = ("cell", "column")


def _chain(layout: Layout, client: BoardClient) -> ReadChain:
    if layout.read_chain is not None:
        return layout.read_chain
    return ReadChain.nominal(client.info or client.hello())


def check_read_path(client: BoardClient, path: str) -> str:
    """``path`` if ``client``'s board can read that way (UserError, one line, else)."""
    if path not in READ_PATHS:
        raise UserError(f"unknown read path {path!r}; use one of {', '.join(READ_PATHS)}")
    if path == "column" and client.info is not None and \
            not client.info.has(Capability.SPIKE_BATCH):
        raise UserError("this board has no SPIKE_BATCH (e.g. legacy protocol); use --path cell")
    return path


def read_series(client: BoardClient, layout: Layout, n_reads: int, path: str = "cell", *,
                chunk_cycles: int = 64,
                progress: ProgressCallback | None = None) -> Floats:
    """``n_reads`` read cycles of every synapse: float[n_reads, n_synapses] of G (S).

    A cycle reads each synapse once (column path: one spike per used row). ``progress`` gets
    the task "read cycles" (one unit per cycle, :mod:`snan_hil.common.progress`)."""
    if n_reads < 1:
        raise UserError(f"number of reads must be >= 1, got {n_reads}")
    path = check_read_path(client, path)
    chain = _chain(layout, client)
    code = chain.read_code
    syn = layout.synapses
    out = np.empty((n_reads, len(syn)))
    bar = track(progress, "read cycles", n_reads, f"{len(syn)} cells, {path} path")
    if path == "cell":
        for k in range(n_reads):
            for j, s in enumerate(syn):
                out[k, j] = chain.cell_conductance(client.read_cell(s.row, s.col, code), code)
            bar.update(k + 1)
        return out
    rows = sorted({s.row for s in syn})
    cols = sorted({s.col for s in syn})
    col_index = {c: i for i, c in enumerate(cols)}
    row_index = {r: i for i, r in enumerate(rows)}
    n_rows = len(rows)
    done = 0
    while done < n_reads:
        m = min(chunk_cycles, n_reads - done)
        groups = [SpikeGroup(((r, code),), tuple(k * n_rows + i for k in range(m)))
                  for i, r in enumerate(rows)]
        res = client.spike_batch(groups, cols, n_bins=m * n_rows, bin_us=1000, paced=False)
        codes = np.asarray(res.codes, dtype=float)           # [m * n_rows, n_cols]
        g = chain.column_cell_conductance(codes, code)
        g = np.asarray(g).reshape(m, n_rows, len(cols))
        for j, s in enumerate(syn):
            out[done:done + m, j] = g[:, row_index[s.row], col_index[s.col]]
        done += m
        bar.update(done)
    return out


def read_conductances(client: BoardClient, layout: Layout, n_reads: int = 4,
                      path: str = "cell") -> Floats:
    """Mean conductance (S) of each synapse's cell over ``n_reads`` reads (layout order)."""
    return read_series(client, layout, n_reads, path).mean(axis=0)


def read_weight_matrix(client: BoardClient, layout: Layout, n_reads: int = 4,
                       path: str = "cell") -> tuple[Floats, Floats]:
    """Read the synapses back: (dense N x N weight matrix, conductances in layout order)."""
    g = read_conductances(client, layout, n_reads, path)
    n = layout.n_neurons
    w = np.zeros((n, n))
    weights = layout.weight_map.weight(g, clip=False)
    for s, value in zip(layout.synapses, np.atleast_1d(weights)):
        w[s.pre, s.post] = value
    return w, g


def weight_errors(read: Floats, reference: Floats, layout: Layout) -> dict[str, Any]:
    """Error statistics of read weights against reference weights over the layout's synapses."""
    d = np.array([read[s.pre, s.post] - reference[s.pre, s.post] for s in layout.synapses])
    ad = np.abs(d)
    return {"synapses": int(d.size), "mean_abs": float(ad.mean()), "median_abs":
            float(np.median(ad)), "max_abs": float(ad.max()), "rms": float(np.sqrt((d * d).mean())),
            "bias": float(d.mean()), "worst": _worst(ad, layout)}


def _worst(ad: Floats, layout: Layout) -> dict[str, Any]:
    k = int(np.argmax(ad))
    s = layout.synapses[k]
    return {"pre": s.pre, "post": s.post, "row": s.row, "col": s.col, "abs_error": float(ad[k])}


@dataclass(frozen=True)
class RetentionCell:
    """Retention of one cell over a read series (relative values are fractions of the mean)."""

    pre: int
    post: int
    row: int
    col: int
    mean_s: float
    noise_rel: float        # std of single reads / mean
    first_s: float          # mean of the first tenth of the reads
    last_s: float           # mean of the last tenth
    drift_rel: float        # last / first - 1
    drift_z: float          # drift in units of its own standard error
    slope_rel: float        # fitted linear change over the whole series, relative
    stable: bool            # |drift| within the read noise (see retention_run)

    def to_dict(self) -> dict[str, Any]:
        return {k: (float(v) if isinstance(v, float) else v) for k, v in self.__dict__.items()}


def retention_run(client: BoardClient, layout: Layout, n_reads: int, path: str = "column", *,
                  z_limit: float = 4.0,
                  progress: ProgressCallback | None = None) -> list[RetentionCell]:
    """Read every synapse ``n_reads`` times and measure drift per cell
    (:func:`retention_stats`)."""
    series = read_series(client, layout, n_reads, path, progress=progress)
    return retention_stats(series, layout, z_limit=z_limit)


def retention_stats(series: Floats, layout: Layout, *,
                    z_limit: float = 4.0) -> list[RetentionCell]:
    """Drift per cell of a read series float[n_reads, n_synapses] (S).

    ``drift = mean(last tenth) / mean(first tenth) - 1``. A cell is *stable* when that change is
    within the read noise: ``|drift| <= noise`` (one single-read sigma, relative) or not
    significant (``|drift_z| <= z_limit``, z = drift / its standard error)."""
    series = np.asarray(series, dtype=float)
    n = series.shape[0]
    block = max(1, n // 10)
    t = np.arange(n, dtype=float)
    out = []
    for j, s in enumerate(layout.synapses):
        x = series[:, j]
        mean = float(x.mean())
        sd = float(x.std(ddof=1)) if n > 1 else 0.0
        first, last = float(x[:block].mean()), float(x[-block:].mean())
        drift = last / first - 1.0 if first > 0 else math.nan
        se = sd * math.sqrt(2.0 / block) / first if first > 0 and n > 1 else math.nan
        z = drift / se if se and se > 0 else 0.0
        slope = float(np.polyfit(t, x, 1)[0]) * (n - 1) / mean if n > 2 and mean > 0 else 0.0
        noise = sd / mean if mean > 0 else math.nan
        stable = bool(abs(drift) <= noise or abs(z) <= z_limit) if math.isfinite(drift) else False
        out.append(RetentionCell(s.pre, s.post, s.row, s.col, mean, noise, first, last, drift,
                                 z, slope, stable))
    return out


def summarize_retention(cells: list[RetentionCell]) -> dict[str, Any]:
    """Counts and extremes of a retention run."""
    drifts = [abs(c.drift_rel) for c in cells if math.isfinite(c.drift_rel)]
    return {"cells": len(cells), "stable": sum(c.stable for c in cells),
            "max_abs_drift_rel": max(drifts) if drifts else None,
            "median_abs_drift_rel": statistics.median(drifts) if drifts else None,
            "median_noise_rel": statistics.median(c.noise_rel for c in cells) if cells else None}


# -- the jobs ---------------------------------------------------------------------------------
def board_layout(bench: CellBench) -> Layout:
    """The board's layout (checked to be this board's and chip's); LayoutError, one line,
    when it has none (``program-weights`` first)."""
    path = bench.layout_path
    layout = bench.layout if path is not None and path.is_file() else None
    return layout if layout is not None else load_session_layout(bench.session)


def _board_clock_us(client: BoardClient) -> int | None:
    try:
        return int(client.clock().time_us)
    except UserError:   # CLOCK is optional (legacy boards: UnsupportedError)
        return None


@dataclass(frozen=True)
class RetentionConfig:
    """A retention run: ``reads`` read cycles of every synapse (at least 2) along ``path``
    ("column" or "cell"), only the first ``cells`` synapses of the layout (None: all), a
    drift within ``z_limit`` standard errors counted stable (:func:`retention_stats`)."""

    reads: int = 10000
    path: str = "column"
    z_limit: float = 4.0
    cells: int | None = None

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class RetentionRun:
    """A retention run as :class:`RetentionJob` ran it: per synapse its statistics
    (``cells``, layout order), the summary (counts, extremes, reads, path, board time
    ``virtual_s``), the read series float[reads, cells] (S) and the layout (the synapses
    read)."""

    cells: list[RetentionCell]
    summary: dict[str, Any]
    series: Floats
    layout: Layout


class RetentionJob:
    """``snan-hil retention`` as a board job (:mod:`snan_hil.calibration.job`): one unit,
    the read series of the layout's synapses and their drift, each cell's verdict a cell
    result ("stable" / "unstable"). ``memory_check(need_bytes, what, advice)``: the front
    door's check that the host holds the series (UserError); ``names``: how it spells the
    config's fields in messages."""

    kind: ClassVar[str] = "retention"
    restartable: ClassVar[bool] = False

    def __init__(self, config: RetentionConfig, *, names: Mapping[str, str] | None = None,
                 memory_check: Callable[[int, str, str], None] | None = None) -> None:
        self.cfg = config
        self.names = dict(names or {})
        self.memory_check = memory_check
        self._layout: Layout | None = None
        self._run: RetentionRun | None = None

    def describe(self) -> dict[str, Any]:
        return self.cfg.to_dict()

    def plan(self, bench: CellBench) -> Sequence[SingleUnit]:
        cfg = self.cfg
        name = self.names.get
        if cfg.reads < 2:
            raise UserError(f"{name('reads', 'reads')} must be >= 2, got {cfg.reads}")
        if cfg.cells is not None and cfg.cells < 1:
            raise UserError(f"{name('cells', 'cells')} must be >= 1, got {cfg.cells}")
        if not math.isfinite(cfg.z_limit) or cfg.z_limit <= 0:
            raise UserError(f"{name('z_limit', 'z_limit')} must be a positive number of "
                            f"standard errors, got {cfg.z_limit:g}")
        layout = copy.copy(board_layout(bench))
        check_read_path(bench.client, cfg.path)
        if cfg.cells is not None:
            layout.synapses = layout.synapses[:cfg.cells]
        if self.memory_check is not None:        # the series: float64[reads, cells]
            n = len(layout.synapses)
            self.memory_check(8 * cfg.reads * max(1, n), f"{cfg.reads} reads of {n} cells",
                              f"give fewer {name('reads', 'reads')} (or "
                              f"{name('cells', 'cells')})")
        self._layout = layout
        return ONE

    def run_unit(self, unit: SingleUnit, bench: CellBench, ctx: UnitContext) -> dict[str, Any]:
        cfg, layout = self.cfg, self._layout
        assert layout is not None                               # plan() loaded it
        t0 = _board_clock_us(bench.client)
        series = read_series(bench.client, layout, cfg.reads, cfg.path, progress=ctx.progress)
        cells = retention_stats(series, layout, z_limit=cfg.z_limit)
        t1 = _board_clock_us(bench.client)
        summary = summarize_retention(cells)
        summary.update(reads=cfg.reads, path=cfg.path,
                       virtual_s=None if t0 is None or t1 is None else (t1 - t0) * 1e-6)
        for c, s in zip(cells, layout.synapses):
            bench.report(CellEvent(c.row, c.col, "stable" if c.stable else "unstable",
                                   c.mean_s, target_s=s.target_s, detail=c.to_dict()))
        self._run = RetentionRun(cells, summary, series, layout)
        return {"summary": summary, "cells": [c.to_dict() for c in cells]}

    def restore(self, unit: SingleUnit, record: dict[str, Any]) -> None:
        raise NotImplementedError("a retention run is not resumed")

    def result(self, records: Mapping[str, dict[str, Any]], status: str
               ) -> RetentionRun | None:
        """The run (None when it was stopped before the series was read whole)."""
        return self._run if ONE[0].key in records else None

    def summary(self, result: RetentionRun | None) -> dict[str, Any] | None:
        return None if result is None else result.summary


@dataclass(frozen=True)
class ReadWeightsConfig:
    """Read the layout's synapses back: ``reads`` reads averaged per cell along ``path``
    ("cell" or "column")."""

    reads: int = 4
    path: str = "cell"

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class WeightsRead:
    """The synapses read back (:class:`ReadWeightsJob`): the weight matrix N x N, the
    conductances (S, layout order), the layout, the reference weights (N x N; None: none)
    and where they came from, the synapses a pulse changed after programming (``stale``:
    pre, post, row, col, why)."""

    weights: Floats
    conductances_s: Floats
    layout: Layout
    reference: Floats | None
    source: str | None
    stale: list[dict[str, Any]]


class ReadWeightsJob:
    """``snan-hil read-weights`` as a board job (:mod:`snan_hil.calibration.job`): one unit,
    the layout's synapses read back into a weight matrix. ``reference``: (weights N x N,
    their meta with ``grid``, what to call them) to compare with; None: the weights the
    layout was last programmed with, when it records them all."""

    kind: ClassVar[str] = "read"
    restartable: ClassVar[bool] = False

    def __init__(self, config: ReadWeightsConfig | None = None, *,
                 reference: tuple[Floats, Mapping[str, Any], str] | None = None) -> None:
        self.cfg = config or ReadWeightsConfig()
        self.reference = reference
        self._layout: Layout | None = None
        self._ref: tuple[Floats | None, str | None] = (None, None)
        self._read: WeightsRead | None = None

    def describe(self) -> dict[str, Any]:
        return {**self.cfg.to_dict(),
                "reference": None if self.reference is None else self.reference[2]}

    def plan(self, bench: CellBench) -> Sequence[SingleUnit]:
        if self.cfg.reads < 1:
            raise UserError(f"reads must be >= 1, got {self.cfg.reads}")
        layout = board_layout(bench)
        if self.reference is not None:
            weights, meta, source = self.reference
            if tuple(meta["grid"]) != tuple(layout.grid):
                raise UserError(f"{source} is for a {meta['grid'][0]}x{meta['grid'][1]} "
                                f"grid, the layout for {layout.grid[0]}x{layout.grid[1]}")
            self._ref = (weights, source)
        elif all(s.weight is not None for s in layout.synapses):
            n = layout.n_neurons
            reference = np.zeros((n, n))
            for s in layout.synapses:
                reference[s.pre, s.post] = s.weight
            self._ref = (reference, "layout (last programmed weights)")
        check_read_path(bench.client, self.cfg.path)
        self._layout = layout
        return ONE

    def run_unit(self, unit: SingleUnit, bench: CellBench, ctx: UnitContext) -> dict[str, Any]:
        layout = self._layout
        assert layout is not None                               # plan() loaded it
        w, g = read_weight_matrix(bench.client, layout, self.cfg.reads, self.cfg.path)
        stale = [{"pre": s.pre, "post": s.post, "row": s.row, "col": s.col, "why": s.stale}
                 for s in layout.stale_synapses()]
        self._read = WeightsRead(w, g, layout, *self._ref, stale)
        return {"g_min_s": float(g.min()), "g_max_s": float(g.max()),
                "synapses": layout.n_synapses}

    def restore(self, unit: SingleUnit, record: dict[str, Any]) -> None:
        raise NotImplementedError("a read-back is not resumed")

    def result(self, records: Mapping[str, dict[str, Any]], status: str
               ) -> WeightsRead | None:
        return self._read if ONE[0].key in records else None

    def summary(self, result: WeightsRead | None) -> dict[str, Any] | None:
        if result is None:
            return None
        g = result.conductances_s
        return {"synapses": result.layout.n_synapses, "g_min_s": float(g.min()),
                "g_max_s": float(g.max())}
