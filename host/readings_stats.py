"""Intervals of a reading's distance to the paper and paired comparisons of readings
(:mod:`snan_hil.host.readings`; docs/model.md "Readings sweep").

**Bootstrap over trials.** A distance is a function of every condition's success rate and
median successful path (:func:`snan_hil.host.readings.distance`). Its sampling error comes from
the trials, so its interval is a percentile bootstrap: every resample draws each unit's trials
with replacement (:func:`resample_counts`: a multinomial count per trial), recomputes every
condition's rate and median and the distance, ``B`` = :data:`N_RESAMPLES` times.

* **Clusters.** Trials that share randomness beyond their own are resampled together: the 10
  launches of one trained 6x6 weight set (launches of one set are correlated) form one
  cluster; the conditions of one unit (route learning's cycle 0 and cycle 20 tests of one
  session, the 6x6 task's launches without and with astrocytes) share the resample.
* **Paired.** Every reading sees the same trials (task seeds depend on the condition only), so
  the same resample is applied to every reading: the difference ``D_r - D_s`` of two
  readings is bootstrapped pair-wise (:func:`paired_interval`), which removes the noise the
  two share (e.g. a condition both run identically).
* **Median of a resample** without materialising it: the successful trials sorted by path
  length, their resample counts accumulated; the median is the mean of the order statistics
  at ranks ``(K-1)//2`` and ``K//2`` (``np.median``'s definition, ``K`` successes in the
  resample); a resample without a success counts its median at the step limit (as
  :func:`~snan_hil.host.readings.target_distance` does).

Resamples are seeded by (sweep seed, unit name, trial count), so a report is reproducible and
every reading of one sweep shares them.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

#: bootstrap resamples of a distance
N_RESAMPLES = 1000
CONFIDENCE = 0.95
SUCCESS_SCALE = 0.07
MEDIAN_SCALE = math.log(1.25)
METHOD = (f"percentile bootstrap over trials ({N_RESAMPLES} resamples, 95 %; the 10 launches "
          "of a 6x6 weight set resampled together; the same resamples for every reading)")


def unit_rng(seed: int, unit: str, trials: int) -> np.random.Generator:
    """The resample stream of ``unit`` at ``trials`` trials in a sweep seeded ``seed``."""
    d = hashlib.sha256(f"{unit}/{int(trials)}".encode()).digest()
    words = [int.from_bytes(d[i:i + 4], "little") for i in range(0, 16, 4)]
    return np.random.default_rng(np.random.SeedSequence([int(seed) & (2**64 - 1), *words]))


def resample_counts(n_trials: int, cluster: int, rng: np.random.Generator,
                    n_resamples: int = N_RESAMPLES) -> np.ndarray:
    """Counts (int32, shape (B, n_trials)) of each trial in ``B`` resamples that draw the
    ``n_trials / cluster`` clusters (consecutive trials) with replacement. ``n_trials`` must be
    a multiple of ``cluster``."""
    if n_trials == 0:
        return np.zeros((n_resamples, 0), dtype=np.int32)
    if n_trials % cluster:
        raise ValueError(f"{n_trials} trials are not whole clusters of {cluster}")
    k = n_trials // cluster
    idx = rng.integers(0, k, size=(n_resamples, k))
    flat = (idx + (np.arange(n_resamples) * k)[:, None]).ravel()
    counts = np.bincount(flat, minlength=n_resamples * k).reshape(n_resamples, k)
    return np.repeat(counts.astype(np.int32), cluster, axis=1)


def resampled_stats(steps: np.ndarray, ok: np.ndarray, counts: np.ndarray, max_steps: int
                    ) -> tuple[np.ndarray, np.ndarray]:
    """(success rate, median of the successful paths) of every resample, shape (B,) each;
    ``counts`` (B, n) from :func:`resample_counts`. A resample without a success gets the
    median ``max_steps`` (at least 1)."""
    steps = np.asarray(steps, dtype=np.float64)
    ok = np.asarray(ok, dtype=bool)
    b = counts.shape[0]
    n = counts.sum(axis=1)
    good = np.nonzero(ok)[0]
    if good.size == 0:
        return np.zeros(b), np.full(b, float(max(max_steps, 1)))
    order = good[np.argsort(steps[good], kind="stable")]
    vals = steps[order]
    cum = np.cumsum(counts[:, order], axis=1)
    k = cum[:, -1]
    rate = k / np.maximum(n, 1)
    lo = (k - 1) // 2
    hi = k // 2
    p_lo = np.minimum((cum <= lo[:, None]).sum(axis=1), vals.size - 1)
    p_hi = np.minimum((cum <= hi[:, None]).sum(axis=1), vals.size - 1)
    med = 0.5 * (vals[p_lo] + vals[p_hi])
    med = np.where(k > 0, med, float(max(max_steps, 1)))
    return rate, med


def target_distances(quantity: str, paper: float | Sequence[float], values: np.ndarray
                     ) -> np.ndarray:
    """The distance of one target (module doc of :mod:`snan_hil.host.readings`) for an array
    of values (success rates as fractions, or medians)."""
    lo, hi = (paper, paper) if isinstance(paper, (int, float)) else (paper[0], paper[1])
    lo, hi = float(lo), float(hi)
    v = np.asarray(values, dtype=np.float64)
    if quantity == "success_rate":
        return np.where(v < lo, lo - v, np.where(v > hi, v - hi, 0.0)) / SUCCESS_SCALE
    ref = np.where(v < lo, lo, hi)
    inside = (v >= lo) & (v <= hi)
    return np.where(inside, 0.0, np.abs(np.log(v / ref))) / MEDIAN_SCALE


def bootstrap_distances(targets: Sequence[Any], data: Mapping[str, Mapping[str, Any]],
                        counts: Mapping[str, np.ndarray]) -> np.ndarray:
    """The distance of one reading in every resample, shape (B,). ``data``: condition ->
    ``{"steps", "success", "max_steps"}``; ``counts``: condition -> resample counts."""
    total: np.ndarray | None = None
    cache: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for t in targets:
        if t.condition not in cache:
            d = data[t.condition]
            cache[t.condition] = resampled_stats(np.asarray(d["steps"]),
                                                 np.asarray(d["success"], dtype=bool),
                                                 counts[t.condition], int(d.get("max_steps", 1)))
        rate, med = cache[t.condition]
        part = target_distances(t.quantity, t.paper,
                                rate if t.quantity == "success_rate" else med)
        total = part if total is None else total + part
    assert total is not None
    return total


def percentile_interval(values: np.ndarray, confidence: float = CONFIDENCE) -> list[float]:
    """[low, high] percentile interval of bootstrap values."""
    a = 1.0 - confidence
    lo, hi = np.percentile(values, [50 * a, 100 * (1 - a / 2)])
    return [float(lo), float(hi)]


def paired_interval(d_r: np.ndarray, d_s: np.ndarray, confidence: float = CONFIDENCE
                    ) -> list[float]:
    """Interval of ``D_r - D_s`` from the same resamples (paired bootstrap)."""
    return percentile_interval(np.asarray(d_r) - np.asarray(d_s), confidence)


def tie_ranks(intervals: Sequence[Sequence[float]]) -> list[int]:
    """Rank of each reading that counts only the readings *clearly* better: 1 + the number of
    readings whose whole interval lies below this one's (intervals that overlap tie)."""
    lows = [float(i[0]) for i in intervals]
    highs = np.sort(np.array([float(i[1]) for i in intervals]))
    return [1 + int(np.searchsorted(highs, lo, side="left")) for lo in lows]
