"""Trials of the experiments: one trial and the sweep tasks (pure functions ``(config,
params, seed) -> small dict`` run by the executors); the plasticity options are
:mod:`snan_hil.host.plasticity`.

Random streams (all derived from the task seed, never from execution order):
trial ``i`` of a task seeded ``s`` uses :func:`snan_hil.host.rng.trial_keys` ``(s, i)`` for
its input spikes / tie-breaks, its start and goal (open grid, one goal: exactly as
:func:`snan_hil.host.simulate.simulate`), and its initial weights; a maze and the task
placed on it come from ``SeedSequence([s, i, MAZE_WORD])``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from snan_hil.common.errors import UserError
from snan_hil.host import snan_kernel as K
from snan_hil.host.agent import synapse_tables
from snan_hil.host.config import SnanConfig
from snan_hil.host.experiments.mazes import MAZE_RULES, maze_task
from snan_hil.host.grid import GridWorld
from snan_hil.host.kernel_params import KernelParams, kernel_params
from snan_hil.host.plasticity import Plasticity, vteam_rule
from snan_hil.host.rng import MASK64, trial_keys
from snan_hil.host.state import initial_weights

MAZE_WORD = 0x6D617A65  # "maze"


@dataclass
class Prepared:
    """Kernel parameters of one configuration + plasticity (+ return to start) and the trial
    arrays the kernel reuses between trials."""

    cfg: SnanConfig
    params: KernelParams
    vteam_gain: tuple[float, float] | None  #: (potentiation, depression) gain vs the device
    _states: dict = field(default_factory=dict, repr=False)

    def state(self, n_cells: int, n_goals: int) -> K.TrialState:
        ts = self._states.get((n_cells, n_goals))
        if ts is None:
            ts = self._states[(n_cells, n_goals)] = K.new_trial_state(self.params, n_cells,
                                                                       n_goals)
        return ts


def prepare(cfg: SnanConfig, plasticity: Plasticity = Plasticity(),
            return_to_start: bool = False, learn: bool = True) -> Prepared:
    """The trial kernel's parameters for ``cfg`` with the experiment's options.

    ``learn=False``: the caller discards the learned weights. With ``stdp.mode=trial_end``
    the trial runs on its initial weights anyway, so the kernel then skips the STDP
    arithmetic (same paths; ``nav_batch`` uses this)."""
    if not learn and cfg.stdp.mode == "trial_end":
        cfg = cfg.replace(**{"stdp.mode": "off"})
    vteam = None
    gain = None
    rule = plasticity.rule if plasticity.rule is not None else cfg.stdp.rule
    if rule == "vteam":
        vteam, gain = vteam_rule(cfg, plasticity)
    elif cfg.stdp.rule != "additive":
        cfg = cfg.replace(**{"stdp.rule": "additive"})
    params = kernel_params(cfg, return_to_start=return_to_start, target=plasticity.target,
                           vteam=vteam)
    return Prepared(cfg, params, gain)


def run_one(prep: Prepared, nbr: np.ndarray, move: np.ndarray, start: int,
            goals: tuple[int, ...], w: np.ndarray, key: int
            ) -> tuple[int, bool, np.ndarray, np.ndarray]:
    """One trial; returns (steps, success, path, learned weights)."""
    ts = prep.state(nbr.shape[0], len(goals))
    w = np.array(w, dtype=np.float64)
    steps, ok = K.run_trial_kernel(prep.params, ts, nbr, move, np.int64(start),
                                   np.array(goals, dtype=np.int64), w, np.uint64(key))
    return int(steps), bool(ok), ts.path[:steps + 1].copy(), w


def maze_rng(seed: int, trial: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([int(seed) & MASK64, int(trial),
                                                         MAZE_WORD]))


def open_task(env: GridWorld, n_goals: int, task_seed: int) -> tuple[int, tuple[int, ...]]:
    """Start and goals on an open grid (one goal: the draw of ``simulate``)."""
    rng = np.random.default_rng(task_seed)
    if n_goals == 1:
        s, g = env.sample_start_goal(rng)
        return s, (g,)
    cells = rng.choice(env.n_cells, size=1 + n_goals, replace=False)
    return int(cells[0]), tuple(int(c) for c in cells[1:])


def nav_batch(cfg: SnanConfig, params: dict, seed: int) -> dict:
    """Trials ``params['trials'] = [lo, hi)`` of one condition (a sweep task).

    params: ``walls`` (wall fraction; absent/None = open grid), ``maze_rule``, ``goals``
    (number of goals, any order), ``return_to_start``, ``plasticity`` (dict of
    :class:`Plasticity`), ``keep`` (trial indices whose path, start, goals and walls are
    returned). Returns per-trial ``steps`` and ``success`` lists and ``examples``.
    """
    lo, hi = (int(v) for v in params["trials"])
    walls = params.get("walls")
    rule = params.get("maze_rule", "component")
    if rule not in MAZE_RULES:
        raise UserError(f"unknown maze rule {rule!r} ({', '.join(MAZE_RULES)})")
    n_goals = int(params.get("goals", 1))
    ret = bool(params.get("return_to_start", False))
    keep = {int(k) for k in params.get("keep", ())}
    prep = prepare(cfg, Plasticity(**params.get("plasticity", {})), ret, learn=False)
    rows, cols = cfg.grid.rows, cfg.grid.cols
    open_env = GridWorld(rows, cols)
    open_tables = synapse_tables(open_env, cfg)
    n = hi - lo
    n_cells = rows * cols
    starts = np.zeros(n, dtype=np.int64)
    goal_arr = np.zeros((n, n_goals), dtype=np.int64)
    w0 = np.zeros((n, n_cells, 4))
    keys = np.zeros(n, dtype=np.uint64)
    nbrs = np.zeros((n if walls is not None else 1, n_cells, 4), dtype=np.int64)
    moves = np.zeros_like(nbrs)
    if walls is None:
        nbrs[0], moves[0] = open_tables
    envs = []
    for j, i in enumerate(range(lo, hi)):
        key, task_seed, w_seed = trial_keys(seed, i)
        if walls is None:
            env = open_env
            nbr = open_tables[0]
            start, goals = open_task(env, n_goals, task_seed)
        else:
            env, start, goals = maze_task(rows, cols, float(walls), n_goals,
                                          maze_rng(seed, i), rule)
            nbr, moves[j] = synapse_tables(env, cfg)
            nbrs[j] = nbr
        envs.append(env)
        w0[j] = initial_weights(cfg, nbr, np.random.default_rng(w_seed))
        starts[j], goal_arr[j], keys[j] = start, goals, np.uint64(key)
    paths = np.full((n, cfg.grid.max_steps + 1), -1, dtype=np.int64)
    steps = np.zeros(n, dtype=np.int64)
    success = np.zeros(n, dtype=np.bool_)
    K.run_batch_kernel(prep.params, nbrs, moves, starts, goal_arr,
                       np.full(n, n_goals, dtype=np.int64), w0, keys, paths, steps, success,
                       np.zeros_like(w0))
    examples = []
    for j, i in enumerate(range(lo, hi)):
        if i in keep:
            ok = bool(success[j])
            examples.append({"trial": i, "start": int(starts[j]),
                             "goals": [int(g) for g in goal_arr[j]],
                             "walls": sorted(sorted(x) for x in envs[j].walls),
                             "path": paths[j, :steps[j] + 1].tolist(), "success": ok})
    return {"trials": [lo, hi], "steps": [int(v) for v in steps],
            "success": [bool(v) for v in success], "examples": examples}
