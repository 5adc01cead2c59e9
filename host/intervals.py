"""95 % intervals of the numbers the project reports: success rates and median path lengths.

* success rate: the **Wilson score** interval (``scipy.stats.binomtest(...).proportion_ci(
  method="wilson")``; Wilson, J. Am. Stat. Assoc. 22 (1927) 209), good at rates near 0 and 1
  where the normal approximation fails;
* median: the **percentile bootstrap** of the median of the successful trials (Efron 1979),
  10 000 resamples by default, seeded so that a report is reproducible (the seed is the run's
  seed unless given). A resample's median is an order statistic of the sorted data at
  resampled ranks, so it is drawn directly from the order statistics of uniform ranks (Beta
  distributions; exactly the distribution of resampling the values with replacement) in
  O(resamples) time instead of O(resamples x n); :func:`median_interval_reference` is the
  plain ``scipy.stats.bootstrap`` version, and tests/agent/test_intervals.py checks they agree.

``interval_fields`` gives the fields every report carries beside a rate or a median
(``success_rate_ci``, ``median_steps_ci``, ``ci_method``), :func:`paper_inside` says
whether the paper's value lies inside an interval and :func:`paper_distance` how far outside.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

#: confidence level of every interval the project reports
CONFIDENCE = 0.95
#: bootstrap resamples of a median interval
N_RESAMPLES = 10_000
#: how the intervals are computed (recorded in every result)
METHOD = {"success_rate": "Wilson score, 95 %",
          "median_steps": f"percentile bootstrap of the median, {N_RESAMPLES} resamples, 95 %"}
#: :data:`METHOD` as one line (CSV cells, report footnotes)
METHOD_TEXT = "; ".join(f"{k}: {v}" for k, v in METHOD.items())


def wilson(successes: int, n: int, confidence: float = CONFIDENCE) -> tuple[float, float]:
    """Wilson score interval (low, high), both in 0..1, of a success rate ``successes / n``.

    Raises ValueError when ``n < 1`` or ``successes`` is outside ``0..n``."""
    if n < 1 or not 0 <= successes <= n:
        raise ValueError(f"need 0 <= successes <= n and n >= 1, got {successes}/{n}")
    from scipy import stats as _stats     # ~1 s to import: not at every CLI start
    ci = _stats.binomtest(int(successes), int(n)).proportion_ci(confidence_level=confidence,
                                                                 method="wilson")
    return float(ci.low), float(ci.high)


def bootstrap_medians(values: Sequence[float] | np.ndarray, rng: np.random.Generator,
                      n_resamples: int = N_RESAMPLES) -> np.ndarray:
    """``n_resamples`` medians (``np.median``'s definition) of resamples with replacement of
    ``values`` (shape (n,), n >= 1); shape (n_resamples,).

    A resample's k-th smallest value is ``sorted(values)[floor(n U_(k))]`` with ``U_(k)`` the
    k-th order statistic of n uniforms, ``U_(k) ~ Beta(k, n - k + 1)``; the next one is
    ``U_(k) + (1 - U_(k)) Beta(1, n - k)`` (the smallest of the n - k uniforms above it)."""
    xs = np.sort(np.asarray(values, dtype=np.float64).ravel())
    n = xs.size
    if n < 1:
        raise ValueError("bootstrap_medians needs at least one value")

    def at(u: np.ndarray) -> np.ndarray:
        return xs[np.minimum((u * n).astype(np.int64), n - 1)]
    if n % 2:
        k = (n + 1) // 2
        return at(rng.beta(k, n - k + 1, n_resamples))
    k = n // 2
    u1 = rng.beta(k, n - k + 1, n_resamples)
    u2 = u1 + (1.0 - u1) * rng.beta(1, n - k, n_resamples)
    return 0.5 * (at(u1) + at(u2))


def median_interval(values: Sequence[float] | np.ndarray, seed: int = 0,
                    confidence: float = CONFIDENCE, n_resamples: int = N_RESAMPLES
                    ) -> tuple[float, float] | None:
    """Percentile-bootstrap interval (low, high) of the median of ``values`` (shape (n,),
    same unit as the values); None when there are no values. One value (or all equal): the
    degenerate interval (v, v). Deterministic for a given ``seed``."""
    x = np.asarray(values, dtype=np.float64).ravel()
    if x.size == 0:
        return None
    if x.size == 1 or np.all(x == x[0]):
        return float(x[0]), float(x[0])
    meds = bootstrap_medians(x, np.random.default_rng(seed), n_resamples)
    alpha = 1.0 - confidence
    lo, hi = np.percentile(meds, [50 * alpha, 100 * (1 - alpha / 2)])
    return float(lo), float(hi)


def median_interval_reference(values: Sequence[float] | np.ndarray, seed: int = 0,
                              confidence: float = CONFIDENCE, n_resamples: int = N_RESAMPLES
                              ) -> tuple[float, float] | None:
    """The same interval with ``scipy.stats.bootstrap`` (resampling the values themselves;
    about 1 s for 500 values): the readable reference of :func:`median_interval`."""
    x = np.asarray(values, dtype=np.float64).ravel()
    if x.size == 0:
        return None
    if x.size == 1 or np.all(x == x[0]):
        return float(x[0]), float(x[0])
    from scipy import stats as _stats     # ~1 s to import: not at every CLI start
    res = _stats.bootstrap((x,), np.median, confidence_level=confidence,
                           n_resamples=n_resamples, method="percentile", vectorized=True,
                           rng=np.random.default_rng(seed))
    return float(res.confidence_interval.low), float(res.confidence_interval.high)


def _ratio_of_medians(a: np.ndarray, b: np.ndarray, axis: int = -1) -> np.ndarray:
    """``nanmedian(a) / nanmedian(b)`` along ``axis`` (NaN: a failed session, left out)."""
    with np.errstate(invalid="ignore", divide="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)     # an all-NaN resample: NaN
        return np.nanmedian(a, axis=axis) / np.nanmedian(b, axis=axis)


def _paired_values(steps_a, ok_a, steps_b, ok_b) -> tuple[np.ndarray, np.ndarray]:
    a = np.where(np.asarray(ok_a, dtype=bool), np.asarray(steps_a, dtype=np.float64), np.nan)
    b = np.where(np.asarray(ok_b, dtype=bool), np.asarray(steps_b, dtype=np.float64), np.nan)
    if a.shape != b.shape or a.ndim != 1:
        raise ValueError(f"the two arms need one value per session each, got shapes {a.shape} "
                         f"and {b.shape}")
    return a, b


def median_ratio_interval(steps_a: Sequence[float] | np.ndarray,
                          ok_a: Sequence[bool] | np.ndarray,
                          steps_b: Sequence[float] | np.ndarray,
                          ok_b: Sequence[bool] | np.ndarray, seed: int = 0,
                          confidence: float = CONFIDENCE, n_resamples: int = N_RESAMPLES
                          ) -> tuple[float, tuple[float, float]] | None:
    """The ratio of two arms' median path lengths over paired sessions and its
    percentile-bootstrap interval: ``(median(a) / median(b), (low, high))``, each median over
    the sessions that succeeded in that arm. ``steps_*``, ``ok_*``: shape (sessions,), session
    ``k`` of ``a`` paired with session ``k`` of ``b`` (the same seeds); a resample draws whole
    sessions with replacement, both arms' together (the pairing kept: Efron & Tibshirani 1993,
    ch. 6). None when an arm has no success. Deterministic for a given ``seed``; resamples in
    which an arm has no success are left out. ValueError when the shapes differ.
    :func:`median_ratio_interval_reference` is the ``scipy.stats.bootstrap`` version."""
    a, b = _paired_values(steps_a, ok_a, steps_b, ok_b)
    if np.all(np.isnan(a)) or np.all(np.isnan(b)):
        return None
    point = float(_ratio_of_medians(a, b))
    idx = np.random.default_rng(seed).integers(0, a.size, (n_resamples, a.size))
    r = _ratio_of_medians(a[idx], b[idx], axis=1)
    r = r[np.isfinite(r)]
    alpha = 1.0 - confidence
    lo, hi = np.percentile(r, [50 * alpha, 100 * (1 - alpha / 2)])
    return point, (float(lo), float(hi))


def median_ratio_interval_reference(steps_a: Sequence[float] | np.ndarray,
                                    ok_a: Sequence[bool] | np.ndarray,
                                    steps_b: Sequence[float] | np.ndarray,
                                    ok_b: Sequence[bool] | np.ndarray, seed: int = 0,
                                    confidence: float = CONFIDENCE,
                                    n_resamples: int = N_RESAMPLES) -> tuple[float, float]:
    """The interval of :func:`median_ratio_interval` with ``scipy.stats.bootstrap``
    (``paired=True``): the readable reference (tests/agent/test_intervals.py)."""
    a, b = _paired_values(steps_a, ok_a, steps_b, ok_b)
    from scipy import stats as _stats     # ~1 s to import: not at every CLI start
    res = _stats.bootstrap((a, b), _ratio_of_medians, paired=True, vectorized=True,
                           confidence_level=confidence, n_resamples=n_resamples,
                           method="percentile", rng=np.random.default_rng(seed))
    return float(res.confidence_interval.low), float(res.confidence_interval.high)


def rate_interval(successes: int, n: int) -> list[float] | None:
    """:func:`wilson` as a list, None when ``n == 0``."""
    return list(wilson(int(successes), int(n))) if n else None


def interval_fields(steps: Sequence[int] | np.ndarray, success: Sequence[bool] | np.ndarray,
                    seed: int = 0) -> dict[str, Any]:
    """``success_rate_ci`` (Wilson, [low, high] in 0..1; None without trials) and
    ``median_steps_ci`` (bootstrap over the successful trials' path lengths, [low, high] in
    steps; None when none succeeded) and ``ci_method`` (:data:`METHOD`) of one condition;
    ``steps`` and ``success`` have shape (trials,)."""
    s = np.asarray(steps)
    ok = np.asarray(success, dtype=bool)
    rate = wilson(int(ok.sum()), int(ok.size)) if ok.size else None
    med = median_interval(s[ok], seed=seed)
    return {"success_rate_ci": list(rate) if rate else None,
            "median_steps_ci": list(med) if med else None,
            "ci_method": dict(METHOD)}


def paper_inside(paper: float | Sequence[float] | None,
                 interval: Sequence[float] | None) -> bool | None:
    """Whether the paper's value (a number, or a [low, high] range the paper states) lies
    inside (overlaps) ``interval``; None when either is missing."""
    if paper is None or interval is None:
        return None
    lo, hi = float(interval[0]), float(interval[1])
    if isinstance(paper, (int, float)):
        return lo <= float(paper) <= hi
    p_lo, p_hi = float(paper[0]), float(paper[1])
    return p_lo <= hi and lo <= p_hi


def paper_distance(paper: float | Sequence[float] | None,
                   interval: Sequence[float] | None) -> float | None:
    """How far the paper's value lies outside ``interval`` (same unit): 0 inside, positive
    above the interval, negative below; for a paper range, the gap between the two ranges.
    None when either is missing."""
    if paper is None or interval is None:
        return None
    lo, hi = float(interval[0]), float(interval[1])
    if isinstance(paper, (int, float)):
        p_lo = p_hi = float(paper)
    else:
        p_lo, p_hi = float(paper[0]), float(paper[1])
    if p_lo > hi:
        return p_lo - hi
    if p_hi < lo:
        return p_hi - lo
    return 0.0


def paper_check(paper: float | Sequence[float] | None,
                interval: Sequence[float] | None) -> dict[str, Any]:
    """``{"paper_inside", "paper_distance"}`` of :func:`paper_inside` / :func:`paper_distance`."""
    return {"paper_inside": paper_inside(paper, interval),
            "paper_distance": paper_distance(paper, interval)}


def format_interval(interval: Sequence[float] | None, percent: bool = False,
                    digits: int = 1) -> str:
    """``[low, high]`` for a report: rates (0..1) as percent with ``percent``, medians with
    no decimals when whole; "–" for no interval."""
    if interval is None:
        return "–"
    if percent:
        return f"[{100 * interval[0]:.{digits}f}, {100 * interval[1]:.{digits}f}] %"

    def num(v: float) -> str:
        return f"{v:.0f}" if float(v).is_integer() else f"{v:.{digits}f}"
    return f"[{num(interval[0])}, {num(interval[1])}]"


def inside_text(inside: bool | None) -> str:
    """A report cell for :func:`paper_inside`: "yes", "no" or "–"."""
    return "–" if inside is None else ("yes" if inside else "no")


def flat_intervals(row: Mapping[str, Any]) -> dict[str, Any]:
    """A row for a CSV file: every ``<name>_ci`` [low, high] becomes ``<name>_ci_low`` and
    ``<name>_ci_high`` (empty when None) and ``ci_method`` (a dict) :data:`METHOD_TEXT`-style
    text; other fields unchanged, in order."""
    out: dict[str, Any] = {}
    for k, v in row.items():
        if k.endswith("_ci") and (v is None or isinstance(v, (list, tuple))):
            out[f"{k}_low"] = None if v is None else v[0]
            out[f"{k}_high"] = None if v is None else v[1]
        elif k == "ci_method" and isinstance(v, Mapping):
            out[k] = "; ".join(f"{q}: {m}" for q, m in v.items())
        else:
            out[k] = v
    return out
