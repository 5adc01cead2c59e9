"""Checking a fitted device model on pulses it was not fitted on, and the read noise of data
that have no repeated reads.

**Held-out pulses** (:func:`split_trains`, :func:`score_heldout`). The pulses of each cell are
cut into *trains* — runs of one polarity, in the order they were applied (a characterisation
sweeps RESET, SET, RESET, ...) — and every ``every``-th train of a cell is held out: the model
is fitted on the rest and predicts each held-out pulse's ``Δ ln G`` from the conductance read
before it, with the cell's own fit. Whole trains are held out, not single pulses, so a held-out
pulse's neighbours are held out too (the prediction is of a sweep the fit never saw).

What is reported of the residuals ``r = Δx_observed - E[Δx]_predicted`` (ln G):

* ``median_abs_sigma`` — the median of ``|r|`` in units of the model's read noise ``σ`` (the
  relative std of one read the host sees); :attr:`HeldOut.median_abs_sigma_delta` the same in
  units of the read noise of the predicted quantity itself, ``σ_Δ = √2 σ`` (an observed
  ``Δ ln G`` is the difference of two reads);
* ``floor_sigma`` — what a perfect model would give: the median of ``|r|`` when ``r`` is only
  the noise the model itself states, ``N(0, 2 σ² + (dw_min_std E[Δx])²)`` per pulse (two reads
  and the cycle-to-cycle spread of one step), from 20 seeded draws. A model is as good as the
  data allow when ``median_abs_sigma`` is near ``floor_sigma``; on a device whose
  cycle-to-cycle spread of one step exceeds the read noise the floor itself is above 1 σ;
* ``bias_sigma`` — the mean of ``r`` in σ (a systematic over- or under-prediction);
* ``binned_sigma`` — the model's error with the noise averaged out: the residuals grouped by
  polarity and conductance (8 log-spaced bins over the data, the cells pooled: each pulse is
  predicted by its own cell's fit), the groups of >= 20 pulses; the median over groups of
  ``|mean residual|`` in σ (a systematic error of the form shows here, the noise of one
  pulse does not);
* ``z_median`` — the median of ``|r| / sd`` with ``sd`` the stated noise (0.674 for a
  normal residual of the stated size).

**Read noise of pulse data** (:func:`estimate_read_noise`): a lab's CSV and this project's
history exports carry one reading between two pulses, no repeated reads. The residual variance
of a step about its cell's local mean (a quadratic in ln G per cell and polarity, as
:func:`~.fitted._cycle_to_cycle` takes it) is ``2 σ² + c2c² E[Δx]²``: a straight line in
``E[Δx]²`` whose intercept gives ``σ`` (least squares over 12 bins of ``E²``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from snan_hil.common.polarity import Polarity
from snan_hil.crossbar_model.fitted import DeviceModel, PulseSample

__all__ = ["split_trains", "HeldOut", "score_heldout", "estimate_read_noise"]


def split_trains(samples: Sequence[PulseSample], every: int = 3
                 ) -> tuple[list[PulseSample], list[PulseSample]]:
    """``(fit, held)``: every ``every``-th train of each cell held out (module doc), the order
    of the samples kept. ``every`` >= 2."""
    if every < 2:
        raise ValueError(f"every must be >= 2, got {every}")
    train: dict[tuple[int, int], int] = {}
    last: dict[tuple[int, int], Polarity] = {}
    fit: list[PulseSample] = []
    held: list[PulseSample] = []
    for s in samples:
        key = (s.row, s.col)
        if last.get(key) != s.polarity:
            train[key] = train.get(key, -1) + 1
            last[key] = s.polarity
        (held if train[key] % every == every - 1 else fit).append(s)
    return fit, held


@dataclass(frozen=True)
class HeldOut:
    """Scores of a model on held-out pulses (module doc); ``n``: held-out pulses predicted
    (their cell has a usable fit), ``read_noise``: the σ used (relative, ln G)."""

    n: int
    read_noise: float
    median_abs_sigma: float
    floor_sigma: float
    bias_sigma: float
    binned_sigma: float
    bins: int
    z_median: float
    rms_ln: float

    @property
    def median_abs_sigma_delta(self) -> float:
        """The median ``|r|`` in units of ``σ_Δ = √2 σ``, the read noise of an observed
        ``Δ ln G`` (two reads)."""
        return self.median_abs_sigma / math.sqrt(2.0)

    def to_dict(self) -> dict[str, Any]:
        d = {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
             for k, v in asdict(self).items()}
        d["median_abs_sigma_delta"] = self.median_abs_sigma_delta
        return d


def score_heldout(model: DeviceModel, held: Sequence[PulseSample], *,
                  read_noise: float | None = None, seed: int = 0) -> HeldOut:
    """Score ``model`` on ``held`` (module doc). ``read_noise``: σ (default the model's).
    ValueError when no held-out pulse has a fitted cell or σ is not positive."""
    sigma = model.read_noise if read_noise is None else float(read_noise)
    if not (math.isfinite(sigma) and sigma > 0):
        raise ValueError(f"the read noise must be > 0 to score in its units, got {sigma}")
    obs, pred, keys = [], [], []
    for s in held:
        fit = model.cell_fit(s.row, s.col)
        if fit is None or s.g_before_s <= 0 or s.g_after_s <= 0:
            continue
        obs.append(math.log(s.g_after_s / s.g_before_s))
        pred.append(float(fit.mean_dx(s.polarity, s.g_before_s)))
        keys.append((s.row, s.col, s.polarity, math.log(s.g_before_s)))
    if not obs:
        raise ValueError("no held-out pulse belongs to a fitted cell")
    o, p = np.array(obs), np.array(pred)
    r = o - p
    c2c = model.dw_min_std if math.isfinite(model.dw_min_std) else 0.0
    sd = np.sqrt(2.0 * sigma ** 2 + (c2c * p) ** 2)
    rng = np.random.default_rng(seed)
    floor = float(np.median([np.median(np.abs(rng.standard_normal(r.size) * sd))
                             for _ in range(20)]))
    binned, n_bins = _binned(keys, o, p)
    return HeldOut(int(r.size), float(sigma), float(np.median(np.abs(r)) / sigma),
                   floor / sigma, float(r.mean() / sigma),
                   binned / sigma if n_bins else math.nan, n_bins,
                   float(np.median(np.abs(r) / sd)), float(np.sqrt(np.mean(r ** 2))))


def _binned(keys: list[tuple[int, int, Polarity, float]], o: np.ndarray, p: np.ndarray
            ) -> tuple[float, int]:
    x = np.array([k[3] for k in keys])
    edges = np.linspace(x.min(), x.max() + 1e-12, 9)
    idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, 7)
    groups: dict[tuple[Polarity, int], list[int]] = {}
    for i, k in enumerate(keys):
        groups.setdefault((k[2], int(idx[i])), []).append(i)
    errs = [abs(float(o[g].mean() - p[g].mean())) for g in groups.values() if len(g) >= 20]
    return (float(np.median(errs)) if errs else math.nan), len(errs)


def estimate_read_noise(samples: Sequence[PulseSample]) -> float:
    """σ (relative std of one read, ln G) from the steps' scatter (module doc); NaN when the
    data cannot give it (too few steps, or an intercept at or below 0)."""
    groups: dict[tuple[int, int, Polarity], list[tuple[float, float]]] = {}
    for s in samples:
        if s.g_before_s > 0 and s.g_after_s > 0:
            groups.setdefault((s.row, s.col, s.polarity), []).append(
                (math.log(s.g_before_s), math.log(s.g_after_s / s.g_before_s)))
    e2: list[float] = []
    r2: list[float] = []
    for pts in groups.values():
        if len(pts) < 12:
            continue
        x = np.array([q[0] for q in pts])
        y = np.array([q[1] for q in pts])
        mean = np.polyval(np.polyfit(x, y, 2), x)
        dof = len(pts) / (len(pts) - 3)
        e2 += list(mean ** 2)
        r2 += list((y - mean) ** 2 * dof)
    if len(e2) < 100:
        return math.nan
    a, b = np.array(e2), np.array(r2)
    edges = np.quantile(a, np.linspace(0, 1, 13))
    idx = np.clip(np.searchsorted(edges, a, side="right") - 1, 0, 11)
    xs = np.array([a[idx == k].mean() for k in range(12) if np.any(idx == k)])
    ys = np.array([b[idx == k].mean() for k in range(12) if np.any(idx == k)])
    slope, intercept = np.polyfit(xs, ys, 1)
    return math.sqrt(intercept / 2.0) if intercept > 0 else math.nan
