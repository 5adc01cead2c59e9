"""95 % intervals of the numbers the project reports: success rates and median path lengths.

* success rate: the **Wilson score** interval (``scipy.stats.binomtest(...).proportion_ci(
  method="wilson")``; Wilson, J. Am. Stat. Assoc. 22 (1927) 209), good at rates near 0 and 1
  where the normal approximation fails;
* median: the **percentile bootstrap** (``scipy.stats.bootstrap``, ``method="percentile"``,
  10 000 resamples by default) of the median of the successful trials, seeded so that a
  report is reproducible (the seed is the run's seed unless given).

``interval_fields`` gives the fields every report carries beside a rate or a median
(``success_rate_ci``, ``median_steps_ci``, ``ci_method``), and :func:`paper_inside` says
whether the paper's value lies inside an interval.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy import stats as _stats

#: confidence level of every interval the project reports
CONFIDENCE = 0.95
#: bootstrap resamples of a median interval
N_RESAMPLES = 10_000
#: how the intervals are computed (recorded in every result)
METHOD = {"success_rate": "Wilson score, 95 %",
          "median_steps": f"percentile bootstrap of the median, {N_RESAMPLES} resamples, 95 %"}


def wilson(successes: int, n: int, confidence: float = CONFIDENCE) -> tuple[float, float]:
    """Wilson score interval of a success rate ``successes / n`` (both counts).

    Raises ValueError when ``n < 1`` or ``successes`` is outside ``0..n``."""
    if n < 1 or not 0 <= successes <= n:
        raise ValueError(f"need 0 <= successes <= n and n >= 1, got {successes}/{n}")
    ci = _stats.binomtest(int(successes), int(n)).proportion_ci(confidence_level=confidence,
                                                                 method="wilson")
    return float(ci.low), float(ci.high)


def median_interval(values: Sequence[float] | np.ndarray, seed: int = 0,
                    confidence: float = CONFIDENCE, n_resamples: int = N_RESAMPLES
                    ) -> tuple[float, float] | None:
    """Percentile-bootstrap interval of the median of ``values`` (shape (n,)); None when
    there are no values. One value: the degenerate interval (v, v)."""
    x = np.asarray(values, dtype=np.float64).ravel()
    if x.size == 0:
        return None
    if x.size == 1 or np.all(x == x[0]):
        return float(x[0]), float(x[0])
    res = _stats.bootstrap((x,), np.median, confidence_level=confidence,
                           n_resamples=n_resamples, method="percentile", vectorized=True,
                           rng=np.random.default_rng(seed))
    return float(res.confidence_interval.low), float(res.confidence_interval.high)


def interval_fields(steps: Sequence[int] | np.ndarray, success: Sequence[bool] | np.ndarray,
                    seed: int = 0) -> dict[str, Any]:
    """``success_rate_ci`` (Wilson) and ``median_steps_ci`` (bootstrap over the successful
    trials' path lengths; None when none succeeded) and ``ci_method`` of one condition."""
    s = np.asarray(steps)
    ok = np.asarray(success, dtype=bool)
    rate = wilson(int(ok.sum()), int(ok.size)) if ok.size else None
    med = median_interval(s[ok], seed=seed)
    return {"success_rate_ci": list(rate) if rate else None,
            "median_steps_ci": list(med) if med else None,
            "ci_method": METHOD}


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
