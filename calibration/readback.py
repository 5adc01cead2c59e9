"""Read programmed synapses back: conductances, the weight matrix, and retention statistics.

Two read paths (:mod:`snan_hil.calibration.readchain`):

* ``"cell"`` — READ_CELL of each cell (the path programming verified with);
* ``"column"`` — SPIKE_BATCH with one spike per used row (only that row driven, at the read
  voltage) and a read of every used column, exactly what the agent's hardware runs see; the
  column codes are converted with :meth:`ReadChain.column_cell_conductance`. Many read cycles
  travel in one request, which makes 10,000-cycle retention runs practical.
"""

from __future__ import annotations

from typing import Any

import math
import statistics
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from snan_hil.calibration.layout import Layout
from snan_hil.calibration.readchain import ReadChain
from snan_hil.common.errors import UserError
from snan_hil.common.progress import ProgressCallback, track
from snan_hil.protocol.client import BoardClient
from snan_hil.protocol.messages import Capability, SpikeGroup

Floats = NDArray[np.float64]
"""A float64 array (shape and unit in each docstring)."""

__all__ = ["READ_PATHS", "read_conductances", "read_weight_matrix", "RetentionCell",
           "retention_run", "retention_stats", "weight_errors", "read_series",
           "summarize_retention"]

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
