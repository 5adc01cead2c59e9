"""Software-only study of the HIL training readings (docs/hil.md, "Training readings").

For one training reading (``train_set`` overrides on top of the HIL config) and several base
seeds: train ``sets`` weight sets per base seed exactly as ``snan-hil train`` does, launch
each set ``launches`` times without and with astrocytes in software, and pool the path
lengths. The crossbar is not involved (it follows the software launch by launch, see
``snan-hil compare``), so a reading can be judged over many training seeds in seconds.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from snan_hil.config.loader import parse_assignments
from snan_hil.host.config import RENAMED, SnanConfig
from snan_hil.host.hil.config import HilConfig, paper_median
from snan_hil.host.intervals import METHOD, interval_fields, median_interval, paper_check
from snan_hil.host.hil.runner import run_scenario
from snan_hil.host.hil.train import train_sets
from snan_hil.common.progress import ProgressCallback, track
from snan_hil.host.readings_stats import percentile_interval, resample_counts, resampled_stats


@dataclass
class ReadingResult:
    """Pooled launches of one training reading (all base seeds)."""

    name: str
    train_overrides: tuple[str, ...]
    base_seeds: tuple[int, ...]
    steps: dict[str, list[int]] = field(default_factory=dict)      #: scenario -> lengths
    success: dict[str, list[bool]] = field(default_factory=dict)
    per_seed_median_all: dict[str, list[float]] = field(default_factory=dict)
    frac_at_wmax: float = 0.0       #: trained weights at exactly w_max (exact-tie risk)

    def summary(self, seed: int | None = None) -> dict:
        """Per scenario: launches, median of the successful launches and success rate with
        their 95 % intervals (``median_steps_ci`` bootstrap seeded by ``seed``, default the
        first base seed; ``success_rate_ci`` Wilson; ``ci_method``), the median of all
        launches with its interval, and the paper's median (14 / 7 steps) with
        ``paper_inside`` / ``paper_distance`` (steps)."""
        seed = (self.base_seeds[0] if self.base_seeds else 0) if seed is None else seed
        out: dict = {"name": self.name, "train_overrides": list(self.train_overrides),
                     "base_seeds": list(self.base_seeds),
                     "frac_at_wmax": self.frac_at_wmax}
        for sc, lengths in self.steps.items():
            ok = [s for s, good in zip(lengths, self.success[sc]) if good]
            out[sc] = {"launches": len(lengths),
                       "median_steps": float(np.median(ok)) if ok else None,
                       "success_rate": len(ok) / len(lengths) if lengths else 0.0,
                       "median_steps_all": float(np.median(lengths)) if lengths else None,
                       **interval_fields(lengths, self.success[sc], seed=seed),
                       "median_steps_all_ci": _ci(median_interval(lengths, seed=seed)),
                       "per_seed_median_all": self.per_seed_median_all[sc],
                       "paper_median_steps": paper_median(sc)}
            out[sc].update(paper_check(paper_median(sc), out[sc]["median_steps_ci"]))
            out[sc]["ci_method"] = METHOD
        return out


def _ci(interval: tuple[float, float] | None) -> list[float] | None:
    return list(interval) if interval else None


def study_reading(hil: HilConfig, name: str, train_overrides: Sequence[str], *,
                  base_seeds: Sequence[int], sets: int = 10, launches: int = 10,
                  progress: ProgressCallback | None = None) -> ReadingResult:
    """Train and launch (software, both astro settings) for every base seed; see module doc.
    ``progress`` gets the task "base seeds" (one unit per base seed).

    Launch streams are those of ``snan-hil compare --seed S`` with ``S`` the base seed, so
    base seed 1 reproduces the software columns of the default comparison."""
    extra = parse_assignments(SnanConfig, train_overrides, option="train override",
                              renamed=RENAMED)
    cfg = HilConfig(model=hil.model, task=hil.task,
                    train_overrides={**hil.train_overrides, **extra},
                    source=hil.source, base=hil.base, overrides=hil.overrides)
    tcfg = cfg.train_config()
    res = ReadingResult(name, tuple(train_overrides), tuple(int(s) for s in base_seeds))
    scenarios = ("sw_noastro", "sw_astro")
    for sc in scenarios:
        res.steps[sc], res.success[sc], res.per_seed_median_all[sc] = [], [], []
    at_max = []
    bar = track(progress, "base seeds", len(res.base_seeds), name)
    for bs in res.base_seeds:
        trained = train_sets(tcfg, sets=sets, cycles=cfg.task.cycles, seed=bs,
                             start=cfg.task.start, goal=cfg.task.goal)
        seed_steps: dict[str, list[int]] = {sc: [] for sc in scenarios}
        for k in range(sets):
            w = trained.weights[k]
            at_max.append(float(np.mean(w[w > 0] >= tcfg.stdp.w_max)))
            for sc in scenarios:
                r = run_scenario(sc, w, cfg, set_index=k, launches=launches, seed=bs)
                for L in r.launches:
                    res.steps[sc].append(int(L.steps))
                    res.success[sc].append(bool(L.success))
                    seed_steps[sc].append(int(L.steps))
        for sc in scenarios:
            res.per_seed_median_all[sc].append(float(np.median(seed_steps[sc])))
        bar.advance(1, f"{name}: base seed {bs}")
    res.frac_at_wmax = float(np.mean(at_max)) if at_max else 0.0
    return res


#: resamples of the weight-set bootstrap
SET_RESAMPLES = 2000


def set_bootstrap(res: ReadingResult, launches: int, seed: int = 0,
                  n_resamples: int = SET_RESAMPLES) -> dict:
    """Intervals that resample whole weight sets (the ``launches`` launches of one trained set
    share its weights, so they are not independent): per scenario the median of the
    successful launches and the median of all launches (a failed launch counts its path at
    the step limit) with 95 % percentile-bootstrap intervals over sets, and per metric the
    ratio astrocytes / no astrocytes with its paired interval (the same sets are launched
    both ways, so each resample draws the same sets for both). ``halves``: the paper's ratio
    (7 / 14 = 0.5) lies inside that interval.

    Returns ``{"sets", "launches", "method", scenario: {...}, "ratio": {metric: {...}}}``."""
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x5E75]))
    n = len(res.steps["sw_noastro"])
    counts = resample_counts(n, launches, rng, n_resamples)
    out: dict = {"sets": n // launches, "launches": launches,
                 "method": f"percentile bootstrap over weight sets ({n_resamples} resamples, "
                           "95 %; a set's launches resampled together; paired across the "
                           "scenarios)"}
    meds: dict[tuple[str, str], np.ndarray] = {}
    for sc in ("sw_noastro", "sw_astro"):
        steps = np.asarray(res.steps[sc], dtype=np.float64)
        ok = np.asarray(res.success[sc], dtype=bool)
        limit = int(steps.max()) if steps.size else 1
        _r, med_ok = resampled_stats(steps, ok, counts, limit)
        _r, med_all = resampled_stats(steps, np.ones_like(ok), counts, limit)
        meds[(sc, "successful")], meds[(sc, "all")] = med_ok, med_all
        out[sc] = {"median_steps": float(np.median(steps[ok])) if ok.any() else None,
                   "median_steps_ci": percentile_interval(med_ok),
                   "median_steps_all": float(np.median(steps)) if steps.size else None,
                   "median_steps_all_ci": percentile_interval(med_all),
                   "success_rate": float(ok.mean()) if ok.size else 0.0}
    out["ratio"] = {}
    for metric in ("successful", "all"):
        key = "median_steps" if metric == "successful" else "median_steps_all"
        a, b = out["sw_astro"][key], out["sw_noastro"][key]
        ratio = meds[("sw_astro", metric)] / meds[("sw_noastro", metric)]
        ci = percentile_interval(ratio)
        out["ratio"][metric] = {"ratio": None if not a or not b else a / b, "ratio_ci": ci,
                                "halves": ci[0] <= 0.5 <= ci[1]}
    return out
