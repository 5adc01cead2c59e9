"""The runnable pieces of the readings sweep (:mod:`snan_hil.host.readings`): the *units* of
the paper's work, the trial ranges they run and the sweep task that runs one.

A unit yields one or more *conditions* (the 3x3 and 10x10 open grids with and without
astrocytes, Fig. 3/4; 10x10 mazes at 20/40/60 % walls with and without, Fig. 5; route
learning on 10x10, tests at cycles 0 and 20, Fig. 7; the 6x6 hardware task's software
scenarios, Fig. 10C). Its work is measured in sweep *trials*: a navigation unit runs that many
independent trials, route learning one session per :data:`ROUTE_SESSIONS_PER_TRIAL`
trials (at least 10), the 6x6 task one base seed (10 weight sets x 10 launches) per
:data:`HIL_LAUNCHES_PER_SEED` trials (at least 1).

**Prefix-stable ranges.** A unit runs the trials ``[lo, hi)`` of the sweep's trial axis: trial
``i`` of a navigation unit, session ``s`` of route learning and base seed ``b`` of the 6x6
task depend on the task seed and their own index only, so the results of ``[0, n1)`` and
``[n1, n2)`` concatenated are the results of ``[0, n2)``. A racing sweep adds trials to its
contenders range by range and gets what a single run at the larger count gives.

This module holds what defines the results (the cache fingerprint covers it); scoring,
racing and reports live in :mod:`snan_hil.host.readings` and
:mod:`snan_hil.host.readings_stats`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from snan_hil.host.config import SnanConfig
from snan_hil.host.hil.config import HilConfig

#: sessions of route learning per sweep trial (the paper: 198 sessions on 10x10)
ROUTE_SESSIONS_PER_TRIAL = 0.2
#: 6x6 task: weight sets x launches per base seed (the paper's 10 x 10)
HIL_LAUNCHES_PER_SEED = 100
HIL_SETS = 10
HIL_LAUNCHES = 10
#: the route-learning cycles the sweep tests (its targets: cycles 0 and 20)
ROUTE_TEST_CYCLES = (0, 20)


@dataclass(frozen=True)
class Unit:
    """One runnable piece of the paper's work (see module doc).

    ``kind``: ``nav`` (independent trials; ``walls`` None = open grid), ``route`` (Fig. 7
    sessions; tests at :data:`ROUTE_TEST_CYCLES`) or ``hil`` (the 6x6 task: train 10 weight
    sets, launch each 10 times in software without and with astrocytes). ``conditions``: the
    condition ids it yields. ``cost``: relative cost per trial (progress weight)."""

    name: str
    kind: str
    preset: str
    astro: bool = False
    walls: float | None = None
    conditions: tuple[str, ...] = ()
    cost: float = 1.0
    source: str = ""


def _units() -> dict[str, Unit]:
    u: list[Unit] = []
    for grid, preset, src in (("3x3", "snan-3x3", "Fig. 3, section 3.1"),
                              ("10x10", "snan-10x10", "Fig. 4, section 3.2")):
        for on in (False, True):
            name = f"{grid}/{'astro' if on else 'no_astro'}"
            u.append(Unit(name, "nav", preset, on, None, (name,),
                          0.05 if grid == "3x3" else 1.0, src))
    for walls in (0.2, 0.4, 0.6):
        for on in (False, True):
            name = f"maze{round(walls * 100)}/{'astro' if on else 'no_astro'}"
            u.append(Unit(name, "nav", "snan-10x10", on, walls, (name,), 1.0,
                          "Fig. 5, section 3.3"))
    u.append(Unit("route10", "route", "snan-10x10", True, None,
                  ("route10/cycle0", "route10/cycle20"), 4.0, "Fig. 7, section 3.5"))
    u.append(Unit("route3", "route", "snan-3x3", True, None,
                  ("route3/cycle0", "route3/cycle20"), 0.15, "Fig. 7, section 3.5"))
    u.append(Unit("hw6x6", "hil", "hil-6x6", False, None,
                  ("hw6x6/sw_noastro", "hw6x6/sw_astro"), 0.2,
                  "Fig. 10C, section 'Hardware implementation'"))
    return {x.name: x for x in u}


UNITS: dict[str, Unit] = _units()


def route_sessions(trials: int) -> int:
    """Sessions of the route unit for ``trials`` sweep trials (>= 10; 0 for 0 trials)."""
    return 0 if trials <= 0 else max(10, round(trials * ROUTE_SESSIONS_PER_TRIAL))


def hil_base_seeds(trials: int) -> int:
    """Base seeds (10 weight sets x 10 launches each) of the 6x6 unit for ``trials`` sweep
    trials (>= 1; 0 for 0 trials)."""
    return 0 if trials <= 0 else max(1, round(trials / HIL_LAUNCHES_PER_SEED))


def trial_range(params: dict) -> tuple[int, int]:
    """``params['trials']``: ``n`` (= ``[0, n)``) or ``[lo, hi]``."""
    t = params["trials"]
    if isinstance(t, (list, tuple)):
        return int(t[0]), int(t[1])
    return 0, int(t)


def cluster_size(unit: Unit) -> int:
    """Trials of one condition that share their randomness beyond the trial itself: the 10
    launches of one trained weight set (6x6 task); 1 elsewhere (a session, a trial)."""
    return HIL_LAUNCHES if unit.kind == "hil" else 1


def run_unit(config: SnanConfig | HilConfig, params: dict, seed: int) -> dict:
    """One unit for one reading (a sweep task). params: ``unit`` (name), ``trials`` (``n``
    or ``[lo, hi]``: the range of the sweep's trial axis, module doc).
    Returns ``{"conditions": {id: {"steps": [...], "success": [...], "max_steps": n,
    "cluster": k}}, "wall_s": s}``; the task seed is shared by every reading (paired
    comparison)."""
    unit = UNITS[params["unit"]]
    lo, hi = trial_range(params)
    t0 = time.perf_counter()
    conds: dict[str, Any]
    if unit.kind == "nav":
        assert isinstance(config, SnanConfig)
        # each unit kind's simulator (numba kernels, 0.3-0.5 s of imports) when it first runs
        from snan_hil.host.experiments.trials import nav_batch
        p: dict[str, Any] = {"trials": [lo, hi], "plasticity": {"rule": "additive"}}
        if unit.walls is not None:
            p.update(walls=unit.walls, maze_rule="component", goals=1)
        r = nav_batch(config, p, seed)
        conds = {unit.conditions[0]: {"steps": [int(s) for s in r["steps"]],
                                      "success": [bool(s) for s in r["success"]],
                                      "max_steps": config.grid.max_steps, "cluster": 1}}
    elif unit.kind == "route":
        assert isinstance(config, SnanConfig)
        from snan_hil.host.experiments.route import route_batch     # as nav_batch above
        r = route_batch(config, {"sessions": [route_sessions(lo), route_sessions(hi)],
                                 "protocol": {"cycles": 20, "task": "fixed",
                                              "train_astro": True,
                                              "tests": list(ROUTE_TEST_CYCLES)},
                                 "plasticity": {}}, seed)    # rule: the config's stdp.rule
        ts = np.asarray(r["test_steps"], dtype=np.int64).reshape(-1, len(ROUTE_TEST_CYCLES))
        ok = np.asarray(r["test_success"], dtype=bool).reshape(ts.shape)
        conds = {c: {"steps": [int(v) for v in ts[:, j]],
                     "success": [bool(v) for v in ok[:, j]],
                     "max_steps": config.grid.max_steps, "cluster": 1}
                 for j, c in enumerate(unit.conditions)}
    else:
        assert isinstance(config, HilConfig)
        from snan_hil.host.hil.study import study_reading           # as nav_batch above
        base = [int(seed % 1_000_000) + i for i in range(hil_base_seeds(lo), hil_base_seeds(hi))]
        conds = {}
        if base:
            res = study_reading(config, unit.name, (), base_seeds=base, sets=HIL_SETS,
                                launches=HIL_LAUNCHES)
        for c, sc in zip(unit.conditions, ("sw_noastro", "sw_astro")):
            conds[c] = {"steps": res.steps[sc] if base else [],
                        "success": res.success[sc] if base else [],
                        "max_steps": config.model.grid.max_steps,
                        "cluster": HIL_LAUNCHES}
    return {"conditions": conds, "wall_s": time.perf_counter() - t0}


def merge_results(parts: list[dict]) -> dict:
    """The results of consecutive ranges of one unit joined into the result of their union
    (module doc: ranges are prefix-stable); ``wall_s`` is summed."""
    out: dict[str, Any] = {"conditions": {}, "wall_s": 0.0}
    for part in parts:
        out["wall_s"] += float(part.get("wall_s", 0.0))
        for c, d in part["conditions"].items():
            cur = out["conditions"].setdefault(c, {"steps": [], "success": [],
                                                   "max_steps": d.get("max_steps", 0),
                                                   "cluster": d.get("cluster", 1)})
            cur["steps"] = list(cur["steps"]) + list(d["steps"])
            cur["success"] = list(cur["success"]) + list(d["success"])
    return out
