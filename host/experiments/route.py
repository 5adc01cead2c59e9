"""Route learning (paper section 3.5, Fig. 7): sessions of training cycles without weight
reset, each followed by a test without astrocytes.

One *session*: fresh random weights; test 0 (before any learning); then ``cycles`` times a
training trial (astrocytes as in ``train_astro``, plasticity on, the weights carried on)
followed by a test trial with the weights after that cycle, astrocytes off and plasticity
off (a test does not change the weights). ``task = fixed``: start and goal are drawn once
per session and kept for every training and test trial ("the route"); ``random``: every
trial draws its own start and goal.

Random streams of session ``k`` of a task seeded ``s``: a session seed from
``SeedSequence([s, k])``; its trial ``j`` (test c: ``j = 2c``, training cycle c:
``j = 2c - 1``) uses :func:`snan_hil.host.rng.trial_keys` ``(session_seed, j)``; the
session's start/goal and initial weights come from trial 0's streams.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from snan_hil.host.agent import synapse_tables
from snan_hil.host.config import SnanConfig
from snan_hil.host.experiments.trials import open_task, prepare, run_one
from snan_hil.host.plasticity import Plasticity
from snan_hil.host.grid import GridWorld
from snan_hil.host.rng import MASK64, trial_keys
from snan_hil.host.state import initial_weights


@dataclass(frozen=True)
class RouteProtocol:
    """Knobs of the route-learning protocol (the readings compared in docs/experiments.md)."""

    cycles: int = 20
    task: str = "fixed"            #: fixed | random start/goal across the cycles
    train_astro: bool = True       #: astrocytes during training
    test_astro: bool = False       #: astrocytes during the tests (paper: off)
    #: the cycles after which a test runs (None: every cycle 0..cycles). A test never changes
    #: the weights and has its own stream (trial ``2c``), so leaving tests out changes no other
    #: result (the readings sweep tests cycles 0 and 20 only)
    tests: tuple[int, ...] | None = None


def session_seed(seed: int, session: int) -> int:
    ss = np.random.SeedSequence([int(seed) & MASK64, int(session)])
    return int(ss.generate_state(1, dtype=np.uint64)[0] >> np.uint64(1))


def configs(cfg: SnanConfig, proto: RouteProtocol) -> tuple[SnanConfig, SnanConfig]:
    """(training config, test config) derived from ``cfg``."""
    train = cfg.replace(**{"astro.enabled": proto.train_astro})
    if train.stdp.mode == "off":
        train = train.replace(**{"stdp.mode": "trial_end"})
    test = cfg.replace(**{"astro.enabled": proto.test_astro, "stdp.mode": "off"})
    return train, test


def run_session(cfg: SnanConfig, proto: RouteProtocol, plasticity: Plasticity, seed: int,
                session: int, keep_weights: bool = False) -> dict:
    """One session; returns test/train steps and success per cycle (test: one per cycle of
    ``proto.tests``, by default cycles + 1)."""
    train_cfg, test_cfg = configs(cfg, proto)
    p_train = prepare(train_cfg, plasticity)
    p_test = prepare(test_cfg, plasticity)
    env = GridWorld(cfg.grid.rows, cfg.grid.cols)
    nbr, move = synapse_tables(env, cfg)
    sseed = session_seed(seed, session)
    _k0, task0, w_seed = trial_keys(sseed, 0)
    start, goals = open_task(env, 1, task0)
    w = initial_weights(cfg, nbr, np.random.default_rng(w_seed))
    test_steps, test_ok, train_steps, train_ok, sat = [], [], [], [], []
    weights = [w.copy()] if keep_weights else []
    valid = nbr >= 0
    tested = set(range(proto.cycles + 1)) if proto.tests is None else set(proto.tests)
    for c in range(proto.cycles + 1):
        if c > 0:
            key, task_seed, _ = trial_keys(sseed, 2 * c - 1)
            if proto.task == "random":
                start, goals = open_task(env, 1, task_seed)
            st, ok, _path, w = run_one(p_train, nbr, move, start, goals, w, key)
            train_steps.append(st)
            train_ok.append(ok)
            sat.append(float(np.mean(w[valid] >= cfg.stdp.w_max - 1e-9)))
            if keep_weights:
                weights.append(w.copy())
        if c not in tested:
            continue
        key, task_seed, _ = trial_keys(sseed, 2 * c)
        t_start, t_goals = start, goals
        if proto.task == "random":
            t_start, t_goals = open_task(env, 1, task_seed)
        st, ok, _path, _w = run_one(p_test, nbr, move, t_start, t_goals, w, key)
        test_steps.append(st)
        test_ok.append(ok)
    out = {"test_steps": test_steps, "test_success": test_ok, "train_steps": train_steps,
           "train_success": train_ok, "saturated": sat, "start": start, "goal": goals[0]}
    if keep_weights:
        out["weights"] = np.array(weights)
    return out


def route_batch(cfg: SnanConfig, params: dict, seed: int) -> dict:
    """Sessions ``params['sessions'] = [lo, hi)`` (a sweep task). params: ``protocol``
    (dict of :class:`RouteProtocol`), ``plasticity`` (dict of :class:`Plasticity`)."""
    lo, hi = (int(v) for v in params["sessions"])
    pp = dict(params.get("protocol", {}))
    if pp.get("tests") is not None:
        pp["tests"] = tuple(int(c) for c in pp["tests"])
    proto = RouteProtocol(**pp)
    plast = Plasticity(**params.get("plasticity", {}))
    keys = ("test_steps", "test_success", "train_steps", "train_success", "saturated")
    out: dict = {k: [] for k in keys}
    out["sessions"] = [lo, hi]
    for s in range(lo, hi):
        r = run_session(cfg, proto, plast, seed, s)
        for k in keys:
            out[k].append(r[k])
    return out
