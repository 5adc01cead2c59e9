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
