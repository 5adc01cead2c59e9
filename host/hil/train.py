"""Route training of the weight sets (paper: "the agent was trained 10 times for a 6x6 field to
find the path from cell 18 to cell 0 with random initial weights each time").

One weight set per seed: the initial weights are drawn from the config's distribution with
that seed, then ``cycles`` trials from ``start`` to ``goal`` run one after the other with the
weights carried over (STDP as configured in the training config; astrocytes on, as in the
paper's route learning, section 3.5). The result is written as the ``.npz`` that
:func:`snan_hil.calibration.weights_io.load_weight_set` reads.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from snan_hil.common.version import __version__
from snan_hil.files.atomicio import atomic_path
from snan_hil.calibration.weights_io import compact_to_dense, validate_weights
from snan_hil.common.errors import UserError
from snan_hil.host.agent import environment, run_trial, synapse_tables
from snan_hil.host.config import SnanConfig
from snan_hil.host.rng import trial_keys
from snan_hil.host.simulate import memory_estimate
from snan_hil.host.state import initial_weights
from snan_hil.common.progress import ProgressCallback, track

WEIGHTS_FORMAT = "snan-hil-weights/1"


@dataclass
class TrainResult:
    """K trained weight sets (dense K x N x N) and what produced them."""

    weights: np.ndarray          #: float64 [K, N, N], W[pre, post]
    initial: np.ndarray          #: float64 [K, N, N], the random initial weights
    grid: tuple[int, int]
    start: int
    goal: int
    seeds: np.ndarray            #: int64 [K], one per set
    cycles: int
    steps: np.ndarray            #: int64 [K, cycles], steps of each training trial
    success: np.ndarray          #: bool [K, cycles]
    config: SnanConfig           #: the training config
    wall_s: float
    extra: dict | None = None    #: provenance (HIL config, base seed)

    def summary(self) -> dict:
        last = self.steps[:, -1]
        return {"sets": int(self.weights.shape[0]), "cycles": self.cycles,
                "grid": list(self.grid), "start": self.start, "goal": self.goal,
                "seeds": [int(s) for s in self.seeds],
                "first_cycle_median_steps": float(np.median(self.steps[:, 0])),
                "last_cycle_median_steps": float(np.median(last)),
                "last_cycle_success_rate": float(self.success[:, -1].mean()),
                "wall_s": self.wall_s}


def set_seeds(seed: int, sets: int) -> np.ndarray:
    """The seed of each weight set: ``seed, seed + 1, ...``."""
    return np.arange(sets, dtype=np.int64) + int(seed)


def training_memory_estimate(cfg: SnanConfig, sets: int) -> int:
    """Bytes :func:`train_sets` needs for ``sets`` weight sets of ``cfg``: the trained and the
    initial dense weights (two float64 arrays of sets x N x N, N = rows x cols cells, which is
    what the weights file holds) plus one trial's working set
    (:func:`snan_hil.host.simulate.memory_estimate`). The dense N x N arrays dominate: a
    2000x2000 grid needs about 2.6e14 bytes a set."""
    n = cfg.grid.rows * cfg.grid.cols
    return 2 * int(sets) * n * n * 8 + memory_estimate(cfg, 1)


def train_sets(cfg: SnanConfig, *, sets: int, cycles: int, seed: int, start: int, goal: int,
               progress: ProgressCallback | None = None, extra: dict | None = None
               ) -> TrainResult:
    """Train ``sets`` weight sets (see module doc). ``progress`` gets the task "training"
    (one unit per training trial, i.e. sets x cycles; :mod:`snan_hil.common.progress`)."""
    if sets < 1:
        raise UserError(f"--sets must be >= 1, got {sets}")
    if cycles < 1:
        raise UserError(f"--cycles must be >= 1, got {cycles}")
    env = environment(cfg)
    env.validate_cells(start, (goal,))
    nbr, _ = synapse_tables(env, cfg)
    rows, cols = cfg.grid.rows, cfg.grid.cols
    seeds = set_seeds(seed, sets)
    n = rows * cols
    out = np.zeros((sets, n, n))
    init = np.zeros((sets, n, n))
    steps = np.zeros((sets, cycles), dtype=np.int64)
    success = np.zeros((sets, cycles), dtype=bool)
    t0 = time.perf_counter()
    bar = track(progress, "training", sets * cycles)
    # a line at once (the inputs are checked): the first trial may compile for a while
    bar.note(f"training {sets} set(s) x {cycles} cycles (on a first run the trial kernel is "
             "compiled first, ~20-40 s)")
    bar.update(0, "set 0 cycle 1 (the first trial loads the kernel; a first run compiles it)")
    for k, s in enumerate(seeds):
        _key, _task, w_seed = trial_keys(int(s), 0)
        w = initial_weights(cfg, nbr, np.random.default_rng(w_seed))
        init[k] = compact_to_dense(w, rows, cols)
        for c in range(cycles):
            r = run_trial(env, cfg, start, goal, seed=int(s), trial=c, weights=w)
            w = r.weights
            steps[k, c], success[k, c] = r.steps, r.success
            bar.advance(1, f"set {k} cycle {c + 1}: {r.steps} steps")
        out[k] = compact_to_dense(np.where(nbr >= 0, w, 0.0), rows, cols)
        validate_weights(out[k], rows, cols, what=f"trained set {k}")
    return TrainResult(weights=out, initial=init, grid=(rows, cols), start=int(start),
                       goal=int(goal), seeds=seeds, cycles=int(cycles), steps=steps,
                       success=success, config=cfg, wall_s=time.perf_counter() - t0,
                       extra=extra)


def save_weights(result: TrainResult, path: str | os.PathLike) -> Path:
    """Write the ``.npz`` atomically (temporary file in the same folder + rename).

    Keys: ``weights`` (K x N x N), ``grid`` (rows, cols), ``start``, ``goal``, ``seeds`` (K),
    ``config`` (JSON text of the training SNAN config), ``cycles``, plus ``initial``
    (K x N x N), ``train_steps`` / ``train_success`` (K x cycles), ``format`` and
    ``provenance`` (JSON text: tool version, HIL config, base seed).
    """
    path = Path(path)
    if path.suffix != ".npz":
        raise UserError(f"output {path} must end in .npz")
    path.parent.mkdir(parents=True, exist_ok=True)
    provenance = {"format": WEIGHTS_FORMAT, "snan_hil_version": __version__,
                  "summary": result.summary(), **(result.extra or {})}
    with atomic_path(path, suffix=".tmp.npz") as tmp:
        np.savez_compressed(
            tmp, weights=result.weights, grid=np.array(result.grid, dtype=np.int64),
            start=np.int64(result.start), goal=np.int64(result.goal),
            seeds=result.seeds.astype(np.int64),
            config=np.array(json.dumps(result.config.to_dict())),
            cycles=np.int64(result.cycles), initial=result.initial,
            train_steps=result.steps, train_success=result.success,
            format=np.array(WEIGHTS_FORMAT), provenance=np.array(json.dumps(provenance)))
    return path
