"""Is learning on the chip equivalent to learning in software? The statistics of issue 35
point 3 on ``snan-hil learn`` runs (docs/learning.md section 12; command ``snan-hil
equivalence``).

Each run is one chip: its ``software`` and ``chip`` arms learnt on paired seeds (session ``k``
of both arms: the same initial weights, input spikes and tie-breaks). At cycle ``c`` (20: the
paper's Fig. 7 end point) a session gives a pair (software test, chip test), each a route
length in steps and a success.

**The route, on the log scale.** A pair where both tests reach the goal gives ``d = ln(chip
steps) - ln(software steps)``. Routes are right-skewed (3 to ~100 steps on the 6x6 task, a
factor 3-7 between the quartiles) and the question is relative ("within 15 % of the median
route"): on the log scale a relative margin is one number for every route length, the
differences are far closer to normal than the steps' (a session's long route does not
dominate), and ``exp(mean d)`` is the geometric mean of the chip/software route ratios. The
**TOST** (two one-sided paired t-tests, Schuirmann 1987; ``statsmodels.stats.weightstats.
ttost_paired``) at level ``alpha`` (0.05) declares equivalence when the ``1 - 2 alpha`` (90 %)
interval of ``mean d`` lies inside ``(-ln(1 + margin), +ln(1 + margin))``: the route ratio
within ``[1/1.15, 1.15]`` for a margin of 15 %. A session in which either arm fails has no
route pair; it counts in the success rate.

**The success rate**: the chip's minus the software's, with its 90 % interval (Newcombe's
hybrid score interval for a difference of proportions, ``statsmodels.stats.proportion.
confint_proportions_2indep(method="newcomb")``; computed as for independent samples, which
is conservative for paired sessions whose outcomes agree more often than chance), beside the
exact McNemar test of the discordant pairs (``statsmodels.stats.contingency_tables.mcnemar``).

**Power** (:func:`sessions_needed`, :func:`margin_allowed`): for a true ratio of 1 the TOST has
power ``1 - beta`` when each one-sided test has power ``1 - beta / 2`` (the two rejection
regions do not overlap; Chow, Shao & Wang, *Sample Size Calculations in Clinical Research*,
3.2): ``statsmodels.stats.power.TTestPower`` (one-sample/paired t) with effect size
``ln(1 + margin) / sd(d)``, one-sided at ``alpha``. ``sd(d)`` comes from a pilot run.

**Cross-chip transfer** (:func:`transfer_summary`): the weights chip A learnt, programmed onto
chip B by write-and-verify and tested there on the same test trial (``snan-hil transfer``):
the success on B over A's own success at the same cycle; the target keeps >= 90 %.

Pooled over chips: the pairs of every run together (the runs must use different session
seeds, so that no software session counts twice: :func:`check_independent`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from snan_hil.common.errors import UserError

__all__ = ["ALPHA", "MARGIN", "POWER", "Pairs", "paired_at", "route_tost",
           "success_difference", "sessions_needed", "margin_allowed", "check_independent",
           "pool", "analyse", "transfer_summary", "TRANSFER_TARGET"]

ALPHA = 0.05
"""Level of each one-sided test of the TOST (its interval: 1 - 2 alpha = 90 %)."""
MARGIN = 0.15
"""Equivalence margin of the route: the chip's route within +-15 % (a ratio in [1/1.15, 1.15])
of software's (issue 35 point 3)."""
POWER = 0.8
"""Power the session count is planned for (a true ratio of 1)."""
TRANSFER_TARGET = 0.9
"""Weights learnt on chip A keep >= 90 % of A's success on chip B (issue 35 point 3)."""


@dataclass(frozen=True)
class Pairs:
    """One chip's paired sessions at one cycle: ``sessions`` (their numbers in the run),
    ``seed`` (the run's master seed), steps (int, a failed test's steps are the step limit)
    and successes of the software and chip arms, arrays of shape (n,)."""

    chip: str
    seed: int
    cycle: int
    sessions: np.ndarray
    software_steps: np.ndarray
    software_success: np.ndarray
    chip_steps: np.ndarray
    chip_success: np.ndarray

    @property
    def both(self) -> np.ndarray:
        """Mask of the sessions where both arms reached the goal (the route pairs)."""
        return self.software_success & self.chip_success

    @property
    def log_ratio(self) -> np.ndarray:
        """``ln(chip steps / software steps)`` of the route pairs, shape (n_both,)."""
        b = self.both
        return np.log(self.chip_steps[b].astype(float)) - np.log(
            self.software_steps[b].astype(float))


def paired_at(doc: Mapping[str, Any], cycle: int | None = None, chip: str = "chip",
              first: int | None = None) -> Pairs:
    """The pairs of a ``learn.json`` document ``doc`` at ``cycle`` (None: its last cycle),
    of its first ``first`` sessions (None: all; a pilot's count: a run's first N sessions are
    the sessions a run of N gives). UserError (one line) when the run lacks an arm, the cycle
    is out of its range, the arms hold different sessions, or it has fewer than ``first``."""
    arms = doc.get("arms") or {}
    missing = [a for a in ("software", "chip") if a not in arms]
    if missing:
        raise UserError(f"{chip}: the learn run has no {missing[0]} arm; run 'snan-hil learn' "
                        "with --arms software,chip (the equivalence pairs their sessions)")
    cycles = int(doc["config"]["cycles"])
    c = cycles if cycle is None else int(cycle)
    if not 0 <= c <= cycles:
        raise UserError(f"{chip}: cycle {c} is outside the run's 0..{cycles}; give --cycle "
                        f"0..{cycles}")
    sw, ch = arms["software"]["sessions"], arms["chip"]["sessions"]
    n = min(len(sw), len(ch))
    if n == 0 or len(sw) != len(ch):
        raise UserError(f"{chip}: the arms hold {len(sw)} software and {len(ch)} chip "
                        "sessions; finish the run first ('snan-hil learn --resume')")
    if first is not None:
        if not 1 <= first <= n:
            raise UserError(f"{chip}: --sessions {first}: the run has {n} paired sessions; "
                            f"give 1..{n}")
        sw, ch, n = sw[:first], ch[:first], first
    if any(len(s["test_steps"]) <= c for s in (*sw, *ch)):
        raise UserError(f"{chip}: a session of the run has no test at cycle {c}; finish the "
                        "run first ('snan-hil learn --resume')")
    return Pairs(chip=chip, seed=int(doc["config"]["seed"]), cycle=c,
                 sessions=np.arange(n),
                 software_steps=np.array([s["test_steps"][c] for s in sw], dtype=int),
                 software_success=np.array([s["test_success"][c] for s in sw], dtype=bool),
                 chip_steps=np.array([s["test_steps"][c] for s in ch], dtype=int),
                 chip_success=np.array([s["test_success"][c] for s in ch], dtype=bool))


def check_independent(runs: Sequence[Pairs]) -> None:
    """UserError (one line) when two runs share their master seed: their software sessions
    would be the same sessions, counted twice when the runs are pooled."""
    seen: dict[int, str] = {}
    for p in runs:
        if p.seed in seen:
            raise UserError(f"{seen[p.seed]} and {p.chip} were learnt with the same --seed "
                            f"{p.seed}: their software sessions are the same sessions; give "
                            "each chip's learn run its own --seed")
        seen[p.seed] = p.chip


def pool(runs: Sequence[Pairs], name: str = "pooled") -> Pairs:
    """The pairs of ``runs`` together (one cycle; :func:`check_independent` first)."""
    cycles = {p.cycle for p in runs}
    if len(cycles) != 1:
        raise ValueError(f"runs at different cycles {sorted(cycles)}")
    cat = np.concatenate
    return Pairs(chip=name, seed=-1, cycle=runs[0].cycle,
                 sessions=cat([p.sessions for p in runs]),
                 software_steps=cat([p.software_steps for p in runs]),
                 software_success=cat([p.software_success for p in runs]),
                 chip_steps=cat([p.chip_steps for p in runs]),
                 chip_success=cat([p.chip_success for p in runs]))


@dataclass(frozen=True)
class RouteTost:
    """The TOST of the route pairs: ``n`` pairs, mean and sd of ``ln(chip / software)``, the
    ratio ``exp(mean)`` with its ``1 - 2 alpha`` interval, the bounds (ratios), the TOST p
    (the larger one-sided p) and whether equivalence is shown at ``alpha``."""

    n: int
    mean_log: float
    sd_log: float
    ratio: float
    ratio_ci: tuple[float, float]
    bounds: tuple[float, float]
    p: float
    equivalent: bool
    alpha: float

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def route_tost(pairs: Pairs, margin: float = MARGIN, alpha: float = ALPHA) -> RouteTost:
    """The TOST of ``pairs``' routes (module doc) at ``margin`` (relative, e.g. 0.15) and
    ``alpha``. ValueError with fewer than 3 route pairs (no variance to test with)."""
    if not 0 < margin < 1 or not 0 < alpha < 0.5:
        raise ValueError(f"need 0 < margin < 1 and 0 < alpha < 0.5, got {margin}, {alpha}")
    from statsmodels.stats.weightstats import DescrStatsW, ttost_paired
    b = pairs.both
    n = int(b.sum())
    if n < 3:
        raise ValueError(f"{pairs.chip}: {n} route pair(s) at cycle {pairs.cycle}; the TOST "
                         "needs at least 3")
    x_chip = np.log(pairs.chip_steps[b].astype(float))
    x_sw = np.log(pairs.software_steps[b].astype(float))
    low, upp = -math.log1p(margin), math.log1p(margin)
    p, _lower, _upper = ttost_paired(x_chip, x_sw, low, upp)
    d = x_chip - x_sw
    lo, hi = DescrStatsW(d).tconfint_mean(alpha=2 * alpha)
    mean = float(np.mean(d))
    return RouteTost(n=n, mean_log=mean, sd_log=float(np.std(d, ddof=1)),
                     ratio=math.exp(mean), ratio_ci=(math.exp(lo), math.exp(hi)),
                     bounds=(math.exp(low), math.exp(upp)), p=float(p),
                     equivalent=bool(p < alpha), alpha=alpha)


def success_difference(pairs: Pairs, alpha: float = ALPHA) -> dict[str, Any]:
    """The chip's success rate minus software's with its ``1 - 2 alpha`` interval (Newcombe)
    and the exact McNemar test of the discordant sessions (module doc)."""
    from statsmodels.stats.contingency_tables import mcnemar
    from statsmodels.stats.proportion import confint_proportions_2indep
    n = int(pairs.sessions.size)
    c, s = int(pairs.chip_success.sum()), int(pairs.software_success.sum())
    lo, hi = confint_proportions_2indep(c, n, s, n, method="newcomb", compare="diff",
                                        alpha=2 * alpha)
    chip_only = int((pairs.chip_success & ~pairs.software_success).sum())
    sw_only = int((pairs.software_success & ~pairs.chip_success).sum())
    both = int(pairs.both.sum())
    table = [[both, chip_only], [sw_only, n - both - chip_only - sw_only]]
    return {"sessions": n, "chip": c / n, "software": s / n, "difference": (c - s) / n,
            "ci": [float(lo), float(hi)], "confidence": 1 - 2 * alpha,
            "chip_only": chip_only, "software_only": sw_only,
            "mcnemar_p": float(mcnemar(table, exact=True).pvalue),
            "method": "Newcombe hybrid score (independent-sample form); McNemar exact"}


def _effect(margin: float) -> float:
    return math.log1p(margin)


def sessions_needed(sd_log: float, margin: float = MARGIN, alpha: float = ALPHA,
                    power: float = POWER) -> int:
    """Route pairs the TOST needs for ``power`` at a true ratio of 1 (module doc), given the
    sd of the paired log differences ``sd_log`` (> 0)."""
    from statsmodels.stats.power import TTestPower
    if not sd_log > 0:
        raise ValueError(f"sd_log must be > 0, got {sd_log}")
    n = TTestPower().solve_power(effect_size=_effect(margin) / sd_log, alpha=alpha,
                                 power=1 - (1 - power) / 2, alternative="larger")
    return int(math.ceil(float(n)))


def margin_allowed(sd_log: float, n: int, alpha: float = ALPHA, power: float = POWER
                   ) -> float:
    """The smallest relative margin the TOST of ``n`` route pairs shows with ``power`` at a
    true ratio of 1, given ``sd_log``: ``exp(effect sd) - 1``."""
    from statsmodels.stats.power import TTestPower
    if n < 3 or not sd_log > 0:
        raise ValueError(f"need n >= 3 and sd_log > 0, got {n}, {sd_log}")
    es = TTestPower().solve_power(nobs=n, alpha=alpha, power=1 - (1 - power) / 2,
                                  alternative="larger")
    return math.expm1(float(es) * sd_log)


def power_block(t: RouteTost, margin: float, alpha: float, power: float,
                sessions: int) -> dict[str, Any]:
    """What the data's own variance says: the route pairs the margin needs, the margin
    their number allows, and the sessions that means at the data's share of route pairs."""
    share = t.n / sessions if sessions else 1.0
    need = sessions_needed(t.sd_log, margin, alpha, power)
    return {"sd_log": t.sd_log, "power": power, "route_pairs_needed": need,
            "sessions_needed": int(math.ceil(need / share)) if share > 0 else None,
            "route_pair_share": share,
            "margin_allowed": margin_allowed(t.sd_log, t.n, alpha, power)}


def analyse(runs: Sequence[Pairs], margin: float = MARGIN, alpha: float = ALPHA,
            power: float = POWER) -> dict[str, Any]:
    """Per chip and pooled: the route TOST, the success difference, the power block. The
    pooled row only with two runs or more (independent: :func:`check_independent`)."""
    check_independent(runs)
    rows = list(runs) + ([pool(runs)] if len(runs) > 1 else [])
    out: dict[str, Any] = {"margin": margin, "alpha": alpha, "cycle": runs[0].cycle,
                           "scale": "ln(route steps), paired", "chips": {}}
    for p in rows:
        row: dict[str, Any] = {"sessions": int(p.sessions.size), "seed": p.seed,
                               "success": success_difference(p, alpha),
                               "software_median": _median(p.software_steps,
                                                          p.software_success),
                               "chip_median": _median(p.chip_steps, p.chip_success)}
        try:
            t = route_tost(p, margin, alpha)
        except ValueError as exc:
            row.update(route=None, route_note=str(exc))
        else:
            row.update(route=t.to_dict(),
                       power=power_block(t, margin, alpha, power, int(p.sessions.size)))
        out["chips"][p.chip] = row
    return out


def _median(steps: np.ndarray, success: np.ndarray) -> float | None:
    return float(np.median(steps[success])) if success.any() else None


def transfer_summary(source_success: Sequence[bool], target_success: Sequence[bool],
                     alpha: float = ALPHA, target: float = TRANSFER_TARGET) -> dict[str, Any]:
    """Weights learnt on chip A tested on chip B (``target_success``) against A's own tests of
    the same sessions (``source_success``): the kept share ``success_B / success_A`` (the
    target: >= ``target``), the difference with its ``1 - 2 alpha`` interval (Newcombe) and
    the discordant sessions."""
    a = np.asarray(source_success, dtype=bool)
    b = np.asarray(target_success, dtype=bool)
    if a.shape != b.shape or a.size == 0:
        raise ValueError(f"need equal, non-empty session lists, got {a.size} and {b.size}")
    from statsmodels.stats.proportion import confint_proportions_2indep
    n, sa, sb = int(a.size), int(a.sum()), int(b.sum())
    lo, hi = confint_proportions_2indep(sb, n, sa, n, method="newcomb", compare="diff",
                                        alpha=2 * alpha)
    kept = sb / sa if sa else None
    return {"sessions": n, "source_success": sa / n, "target_success": sb / n,
            "kept": kept, "difference": (sb - sa) / n, "ci": [float(lo), float(hi)],
            "lost": int((a & ~b).sum()), "gained": int((b & ~a).sum()),
            "kept_target": target, "met": kept is not None and kept >= target}
