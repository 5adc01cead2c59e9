"""95 % intervals (host/intervals.py): Wilson against hand-computed values and coverage on
simulated binomials, the fast median bootstrap against scipy's resampling bootstrap, its
coverage and determinism by seed, and the paper-inside / distance checks."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from snan_hil.host import intervals as I

Z = 1.959963984540054


def _wilson_by_hand(k: int, n: int) -> tuple[float, float]:
    p = k / n
    centre = (p + Z * Z / (2 * n)) / (1 + Z * Z / n)
    half = Z / (1 + Z * Z / n) * math.sqrt(p * (1 - p) / n + Z * Z / (4 * n * n))
    return centre - half, centre + half


@pytest.mark.parametrize("k,n,want", [(0, 10, (0.0, 0.27753)), (10, 10, (0.72247, 1.0)),
                                      (5, 10, (0.23659, 0.76341))])
def test_wilson_known_values(k, n, want):
    assert I.wilson(k, n) == pytest.approx(want, abs=5e-5)


@pytest.mark.parametrize("k,n", [(78, 100), (231, 500), (1, 500), (499, 500), (3, 7)])
def test_wilson_matches_the_score_formula(k, n):
    assert I.wilson(k, n) == pytest.approx(_wilson_by_hand(k, n), abs=1e-9)


@pytest.mark.parametrize("bad", [(3, 0), (-1, 5), (6, 5)])
def test_wilson_rejects_impossible_counts(bad):
    with pytest.raises(ValueError):
        I.wilson(*bad)


@pytest.mark.parametrize("p,n", [(0.3, 50), (0.631, 500), (0.95, 100)])
def test_wilson_covers_the_true_rate_about_95_percent_of_the_time(p, n):
    rng = np.random.default_rng(7)
    ks = rng.binomial(n, p, 2000)
    cover = np.mean([lo <= p <= hi for lo, hi in (I.wilson(int(k), n) for k in ks)])
    assert 0.925 <= cover <= 0.975, cover      # 2000 draws: SE of the coverage ~0.005


@pytest.mark.parametrize("n", [7, 8, 41, 60])
def test_fast_median_bootstrap_has_the_resampling_distribution(n):
    """Same bootstrap distribution (CDF at every data value) as resampling with scipy."""
    x = np.round(np.random.default_rng(n).lognormal(3, 1, n))
    fast = I.bootstrap_medians(x, np.random.default_rng(1), 40_000)
    ref = stats.bootstrap((x,), np.median, n_resamples=40_000, method="percentile",
                          rng=np.random.default_rng(2)).bootstrap_distribution
    grid = np.union1d(np.unique(fast), np.unique(ref))
    cdf = lambda d: np.searchsorted(np.sort(d), grid, side="right") / d.size  # noqa: E731
    assert np.max(np.abs(cdf(fast) - cdf(ref))) < 0.02    # 40 000 draws each: KS noise ~0.01
    assert I.median_interval(x, seed=3, n_resamples=40_000) == pytest.approx(
        I.median_interval_reference(x, seed=3, n_resamples=40_000),
        abs=np.ptp(x) / 10)


def test_median_interval_covers_the_true_median():
    rng = np.random.default_rng(11)
    true = math.exp(3.0)              # median of lognormal(3, 1)
    hits = [lo <= true <= hi for lo, hi in
            (I.median_interval(rng.lognormal(3, 1, 101), seed=s) for s in range(400))]
    assert 0.90 <= np.mean(hits) <= 0.99      # 400 samples: SE of the coverage ~0.011


def test_median_interval_is_deterministic_by_seed():
    x = np.random.default_rng(5).integers(1, 400, 300)
    a, b = I.median_interval(x, seed=9), I.median_interval(x, seed=9)
    assert a == b
    others = {I.median_interval(x, seed=s) for s in range(10, 20)}
    assert len(others) > 1                 # the seed does drive the resampling
    lo, hi = a
    assert lo <= float(np.median(x)) <= hi


def test_median_interval_degenerate_cases():
    assert I.median_interval([]) is None
    assert I.median_interval([7]) == (7.0, 7.0)
    assert I.median_interval([4, 4, 4]) == (4.0, 4.0)


def test_interval_fields_of_a_condition():
    steps = np.array([5, 9, 100, 7, 100, 6])
    ok = steps < 100
    f = I.interval_fields(steps, ok, seed=1)
    assert f["success_rate_ci"] == pytest.approx(list(I.wilson(4, 6)))
    lo, hi = f["median_steps_ci"]
    assert 5 <= lo <= 6.5 <= hi <= 9
    assert f["ci_method"] == I.METHOD
    none = I.interval_fields([100, 100], [False, False])
    assert none["median_steps_ci"] is None and none["success_rate_ci"][0] == 0.0
    assert I.interval_fields([], [])["success_rate_ci"] is None


def test_paper_inside_and_distance():
    assert I.paper_inside(0.631, [0.6, 0.7]) is True
    assert I.paper_inside(362, [177, 198]) is False
    assert I.paper_distance(362, [177, 198]) == 164
    assert I.paper_distance(55, [79, 81]) == -24
    assert I.paper_distance(0.65, [0.6, 0.7]) == 0
    assert I.paper_inside((0.97, 1.0), [0.95, 0.975]) is True          # a range overlaps
    assert I.paper_distance((0.05, 0.166), [0.2, 0.3]) == pytest.approx(-0.034)
    assert I.paper_inside(None, [1, 2]) is None and I.paper_distance(3, None) is None
    assert I.paper_check(10, [6, 8]) == {"paper_inside": False, "paper_distance": 2.0}


def test_flat_intervals_and_text():
    row = {"a": 1, "success_rate_ci": [0.1, 0.2], "median_steps_ci": None,
           "ci_method": I.METHOD}
    flat = I.flat_intervals(row)
    assert list(flat) == ["a", "success_rate_ci_low", "success_rate_ci_high",
                          "median_steps_ci_low", "median_steps_ci_high", "ci_method"]
    assert flat["success_rate_ci_high"] == 0.2 and flat["median_steps_ci_low"] is None
    assert "Wilson" in flat["ci_method"] and "bootstrap" in flat["ci_method"]
    assert I.format_interval([0.7416, 0.8141], percent=True) == "[74.2, 81.4] %"
    assert I.format_interval([6.0, 7.5]) == "[6, 7.5]"
    assert I.format_interval(None) == "–" and I.inside_text(False) == "no"


def _paired_arms(rng, n, ratio, shared=0.5):
    """Two arms of ``n`` paired sessions: log-normal path lengths with a shared part per
    session (the pairing) and arm ``a``'s true median ``ratio`` times arm ``b``'s; about 10 %
    of each arm's sessions fail."""
    z = rng.standard_normal(n)
    a = np.exp(2.4 + math.log(ratio) + shared * z + (1 - shared) * rng.standard_normal(n))
    b = np.exp(2.4 + shared * z + (1 - shared) * rng.standard_normal(n))
    return a, rng.random(n) > 0.1, b, rng.random(n) > 0.1


def test_median_ratio_interval_agrees_with_scipys_paired_bootstrap():
    a, oa, b, ob = _paired_arms(np.random.default_rng(4), 80, 1.2)
    point, (lo, hi) = I.median_ratio_interval(a, oa, b, ob, seed=1, n_resamples=20_000)
    ref = I.median_ratio_interval_reference(a, oa, b, ob, seed=2, n_resamples=20_000)
    assert point == pytest.approx(np.median(a[oa]) / np.median(b[ob]))
    assert (lo, hi) == pytest.approx(ref, rel=0.03)
    assert lo < point < hi


def test_median_ratio_interval_covers_the_true_ratio():
    rng = np.random.default_rng(21)
    hits = []
    for s in range(200):
        a, oa, b, ob = _paired_arms(rng, 60, 1.3)
        _, (lo, hi) = I.median_ratio_interval(a, oa, b, ob, seed=s, n_resamples=2000)
        hits.append(lo <= 1.3 <= hi)
    assert 0.88 <= np.mean(hits) <= 0.995     # 200 samples: SE of the coverage ~0.015


def test_median_ratio_interval_keeps_the_pairing():
    """Strongly paired arms give a narrower interval than the same values unpaired."""
    a, oa, b, ob = _paired_arms(np.random.default_rng(8), 60, 1.0, shared=0.95)
    _, (lo, hi) = I.median_ratio_interval(a, oa, b, ob, seed=0)
    perm = np.random.default_rng(9).permutation(b.size)
    _, (ulo, uhi) = I.median_ratio_interval(a, oa, b[perm], ob[perm], seed=0)
    assert hi - lo < 0.6 * (uhi - ulo)


def test_median_ratio_interval_degenerate_and_bad_cases():
    assert I.median_ratio_interval([5, 6], [False, False], [5, 6], [True, True]) is None
    point, (lo, hi) = I.median_ratio_interval([4, 4, 4], [True] * 3, [4, 4, 4], [True] * 3)
    assert point == lo == hi == 1.0
    with pytest.raises(ValueError, match="one value per session"):
        I.median_ratio_interval([1, 2], [True, True], [1, 2, 3], [True] * 3)
