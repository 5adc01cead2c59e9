"""Batches of independent SNAN trials (fresh network and weights every trial) and their
summary statistics, as in the paper's sections 3.1-3.2."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from snan_hil.common.errors import UserError
from snan_hil.host import snan_kernel as K
from snan_hil.host.agent import Engine, environment, resolve_engine, run_trial, synapse_tables
from snan_hil.host.config import SnanConfig, load_config
from snan_hil.host.grid import GridWorld
from snan_hil.host.intervals import interval_fields, paper_check
from snan_hil.host.kernel_params import kernel_params
from snan_hil.host.rng import trial_keys
from snan_hil.host.state import initial_weights
from snan_hil.common.progress import ProgressCallback, ProgressTracker, track


@dataclass
class SimResult:
    """Per-trial outcomes of a batch; ``steps[i]`` = moves made in trial i (== max_steps
    for a failed trial), ``paths[i, :steps[i]+1]`` the visited cells."""

    config: SnanConfig
    seed: int
    engine: str
    starts: np.ndarray
    goals: np.ndarray
    steps: np.ndarray
    success: np.ndarray
    paths: np.ndarray
    wall_s: float

    @property
    def trials(self) -> int:
        return int(self.steps.shape[0])

    @property
    def decisions(self) -> int:
        return int(self.steps.sum())

    def path(self, i: int) -> np.ndarray:
        return self.paths[i, :self.steps[i] + 1]

    def summary(self) -> dict[str, Any]:
        """Success rate (0..1) and statistics of the successful path lengths (steps), with
        their 95 % intervals (``success_rate_ci`` Wilson, ``median_steps_ci`` bootstrap seeded
        by the batch's seed, ``ci_method``; :mod:`snan_hil.host.intervals`)."""
        ok = self.steps[self.success]
        stats: dict[str, Any] = {
            "trials": self.trials,
            "successes": int(self.success.sum()),
            "success_rate": float(self.success.mean()) if self.trials else 0.0,
            "median_steps": float(np.median(ok)) if ok.size else None,
            **interval_fields(self.steps, self.success, seed=self.seed),
            "mean_steps": float(ok.mean()) if ok.size else None,
            "p10_steps": float(np.percentile(ok, 10)) if ok.size else None,
            "p25_steps": float(np.percentile(ok, 25)) if ok.size else None,
            "p75_steps": float(np.percentile(ok, 75)) if ok.size else None,
            "p90_steps": float(np.percentile(ok, 90)) if ok.size else None,
            "min_steps": int(ok.min()) if ok.size else None,
            "max_steps_taken": int(ok.max()) if ok.size else None,
            "step_limit": self.config.grid.max_steps,
            "grid": f"{self.config.grid.rows}x{self.config.grid.cols}",
            "astro": self.config.astro.enabled,
            "decisions": self.decisions,
            "decisions_per_s": self.decisions / self.wall_s if self.wall_s > 0 else None,
            "seed": self.seed,
            "engine": self.engine,
            "wall_s": self.wall_s,
        }
        return stats


def trials_task(cfg: SnanConfig) -> str:
    """Progress task name of a batch: grid size and astrocytes, e.g. "10x10 astro trials"."""
    return f"{cfg.grid.rows}x{cfg.grid.cols} {'astro' if cfg.astro.enabled else 'no astro'} trials"


#: Bytes a batch holds per grid cell whatever its trial count: the neighbour and move tables
#: (2 x int64[4]), the open-grid neighbour table that host/grid.py keeps per grid size and the
#: grid's own cached copy (2 x int64[4]), one trial's fresh weights with the temporaries of
#: drawing them (3 x float64[4]) and the kernel's eight per-cell state arrays (8 x 8 B).
MEMORY_PER_CELL = 2 * 32 + 2 * 32 + 3 * 32 + 8 * 8
#: Bytes per grid cell and trial: the initial and final weights (2 x float64[4]).
MEMORY_PER_CELL_TRIAL = 2 * 32
#: Bytes per trial besides the weights: start, goal, key, steps, success (33 B) and the path
#: (int64 per step, ``max_steps + 1``).
MEMORY_PER_TRIAL = 33


def memory_estimate(cfg: SnanConfig, trials: int) -> int:
    """Bytes :func:`simulate` needs for ``trials`` trials of ``cfg`` (the data above; the
    interpreter, numba and the compiled kernels not counted). Checked against the measured
    peak in tests/agent/test_simulate_memory.py; the 10000x10000 grid of issue 13 needs ~35 GB."""
    n = cfg.grid.rows * cfg.grid.cols
    per_trial = MEMORY_PER_TRIAL + 8 * (cfg.grid.max_steps + 1) + MEMORY_PER_CELL_TRIAL * n
    return MEMORY_PER_CELL * n + trials * per_trial


def trial_setup(cfg: SnanConfig, env: GridWorld, nbr: np.ndarray, seed: int, trial: int
                ) -> tuple[int, int, np.ndarray, int]:
    """(start, goal, initial weights, window-stream key) of trial ``trial``."""
    key, task_seed, w_seed = trial_keys(seed, trial)
    start, goal = env.sample_start_goal(np.random.default_rng(task_seed))
    w = initial_weights(cfg, nbr, np.random.default_rng(w_seed))
    return start, goal, w, key


def kernel_cached(kernel: Any = None) -> bool:
    """Whether numba ``kernel`` (default: the batch trial kernel
    :func:`~snan_hil.host.snan_kernel.run_batch_kernel`) runs without compiling first: it is
    compiled in this process, or numba's on-disk cache holds a version compiled from the
    kernel module's current source. False on a first run after an install or an edit of
    ``host/snan_kernel.py`` (then the first call compiles it, about a minute), and when the
    cache cannot be inspected (numba's cache index is an internal API; its index file is then
    the fallback)."""
    kernel = K.run_batch_kernel if kernel is None else kernel
    if getattr(kernel, "signatures", None):
        return True
    cache_file: Any = getattr(getattr(kernel, "_cache", None), "_cache_file", None)
    try:
        return bool(cache_file._load_index())
    except Exception:  # noqa: BLE001 - another numba version: fall back to the index file
        path: Any = getattr(cache_file, "_index_path", None)
        return isinstance(path, str) and os.path.isfile(path)


def simulate(cfg: SnanConfig, trials: int, seed: int = 0, *, engine: Engine = "auto",
             env: GridWorld | None = None, chunk: int = 25,
             progress: ProgressCallback | None = None) -> SimResult:
    """Run ``trials`` independent trials: random start != goal, weights drawn fresh.

    ``progress`` gets the task :func:`trials_task` (one unit per trial, reported after every
    chunk; :mod:`snan_hil.common.progress`). Trial i uses the streams of (seed, i), so a trial can
    be
    replayed alone with :func:`snan_hil.host.agent.run_trial` (same start/goal, weights and
    spikes).

    ``wall_s`` (and ``decisions_per_s``) time the batch kernel's calls alone: the kernel is
    compiled or loaded from numba's cache by an empty batch first (:func:`kernel_cached`
    tells whether that compiles).
    """
    if trials < 1:
        raise UserError(f"number of trials must be >= 1, got {trials}")
    eng = resolve_engine(cfg, engine)
    bar = track(progress, trials_task(cfg), trials)
    if eng == "reference":
        return _simulate_reference(cfg, trials, seed, env, bar)
    env = env or environment(cfg)
    nbr, move = synapse_tables(env, cfg)
    n = env.n_cells
    starts = np.zeros(trials, dtype=np.int64)
    goals = np.zeros((trials, 1), dtype=np.int64)
    w0 = np.zeros((trials, n, 4))
    keys = np.zeros(trials, dtype=np.uint64)
    for i in range(trials):
        s, g, w, key = trial_setup(cfg, env, nbr, seed, i)
        starts[i], goals[i, 0], w0[i], keys[i] = s, g, w, np.uint64(key)
    p = kernel_params(cfg)
    max_steps = cfg.grid.max_steps
    paths = np.full((trials, max_steps + 1), -1, dtype=np.int64)
    steps = np.zeros(trials, dtype=np.int64)
    success = np.zeros(trials, dtype=np.bool_)
    w_out = np.zeros_like(w0)
    n_goals = np.ones(trials, dtype=np.int64)
    # compile (first run) or load the kernel with an empty batch of the same types, so the
    # timing below is the kernel's alone
    K.run_batch_kernel(p, nbr[None], move[None], starts[:0], goals[:0], n_goals[:0], w0[:0],
                       keys[:0], paths[:0], steps[:0], success[:0], w_out[:0])
    t0 = time.perf_counter()
    for lo in range(0, trials, chunk):
        hi = min(trials, lo + chunk)
        K.run_batch_kernel(p, nbr[None], move[None], starts[lo:hi], goals[lo:hi],
                           n_goals[lo:hi], w0[lo:hi], keys[lo:hi], paths[lo:hi],
                           steps[lo:hi], success[lo:hi], w_out[lo:hi])
        bar.update(hi)
    wall = time.perf_counter() - t0
    return SimResult(config=cfg, seed=seed, engine=eng, starts=starts, goals=goals[:, 0],
                     steps=steps, success=success, paths=paths, wall_s=wall)


def _simulate_reference(cfg: SnanConfig, trials: int, seed: int, env: GridWorld | None,
                        bar: ProgressTracker) -> SimResult:
    env = env or environment(cfg)
    nbr, _ = synapse_tables(env, cfg)
    max_steps = cfg.grid.max_steps
    starts = np.zeros(trials, dtype=np.int64)
    goals = np.zeros(trials, dtype=np.int64)
    paths = np.full((trials, max_steps + 1), -1, dtype=np.int64)
    steps = np.zeros(trials, dtype=np.int64)
    success = np.zeros(trials, dtype=np.bool_)
    t0 = time.perf_counter()
    for i in range(trials):
        s, g, w, _key = trial_setup(cfg, env, nbr, seed, i)
        r = run_trial(env, cfg, s, g, seed=seed, trial=i, weights=w, engine="reference")
        starts[i], goals[i], steps[i], success[i] = s, g, r.steps, r.success
        paths[i, :r.steps + 1] = r.path
        bar.advance()
    return SimResult(config=cfg, seed=seed, engine="reference", starts=starts, goals=goals,
                     steps=steps, success=success, paths=paths,
                     wall_s=time.perf_counter() - t0)


#: The paper's results (500 trials, weights reset every trial): (success rate, median).
PAPER_RESULTS: dict[tuple[str, bool], tuple[float, float]] = {
    ("snan-3x3", False): (0.631, 10.0),
    ("snan-3x3", True): (1.000, 4.0),
    ("snan-10x10", False): (0.462, 362.0),
    ("snan-10x10", True): (1.000, 55.0),
}


_PAPER_GRIDS = {(3, 3): "snan-3x3", (10, 10): "snan-10x10"}


def paper_result(cfg: SnanConfig) -> tuple[float, float] | None:
    """The paper's (success rate, median path) for this config's grid and astrocyte setting
    (sections 3.1-3.2: 3x3 and 10x10), None for other grids."""
    preset = _PAPER_GRIDS.get((cfg.grid.rows, cfg.grid.cols))
    if preset is None:
        return None
    return PAPER_RESULTS[(preset, bool(cfg.astro.enabled))]


def paper_fields(paper: tuple[float, float] | None, summary: dict[str, Any]) -> dict[str, Any]:
    """The paper's success rate and median next to a :meth:`SimResult.summary`: whether each
    lies inside our 95 % interval and how far outside (rate in 0..1, median in steps)."""
    if paper is None:
        return {"paper_success_rate": None, "paper_median_steps": None}
    succ = paper_check(paper[0], summary.get("success_rate_ci"))
    med = paper_check(paper[1], summary.get("median_steps_ci"))
    return {"paper_success_rate": paper[0], "paper_median_steps": paper[1],
            "paper_success_inside": succ["paper_inside"],
            "paper_success_distance": succ["paper_distance"],
            "paper_median_inside": med["paper_inside"],
            "paper_median_distance": med["paper_distance"]}


@dataclass
class ComparisonRow:
    """One line of the software comparison against the paper."""

    preset: str
    astro: bool
    summary: dict[str, Any]
    paper_success: float
    paper_median: float

    @property
    def success_ok(self) -> bool:
        """Within the project's tolerance of +-7 percentage points."""
        return abs(self.summary["success_rate"] - self.paper_success) <= 0.07

    @property
    def median_ok(self) -> bool:
        """Within the project's tolerance of +-25 %."""
        med = self.summary["median_steps"]
        return med is not None and abs(med - self.paper_median) <= 0.25 * self.paper_median

    @property
    def paper(self) -> dict[str, Any]:
        """:func:`paper_fields` of this row: the paper's values inside our 95 % intervals?
        (None for a row without intervals, e.g. a checkpoint of an older version)."""
        return paper_fields((self.paper_success, self.paper_median), self.summary)


def snan_comparison(trials: int = 500, seed: int = 1,
                    presets: tuple[str, ...] = ("snan-3x3", "snan-10x10"),
                    overrides: tuple[str, ...] = (),
                    progress: ProgressCallback | None = None,
                    done: Callable[[str, bool], ComparisonRow | None] | None = None,
                    on_row: Callable[[ComparisonRow], None] | None = None
                    ) -> list[ComparisonRow]:
    """Run every preset with and without astrocytes; ``progress`` gets one task per batch
    (:func:`trials_task`). ``done(preset, astro)`` may return a row finished earlier (a
    checkpoint), which is then not run again; ``on_row(row)`` is called for every row run
    here."""
    rows = []
    for preset in presets:
        for astro in (False, True):
            earlier = done(preset, astro) if done else None
            if earlier is not None:
                rows.append(earlier)
                continue
            cfg = load_config(preset=preset, overrides=[*overrides,
                                                        f"astro.enabled={str(astro).lower()}"])
            res = simulate(cfg, trials, seed, progress=progress)
            paper = PAPER_RESULTS.get((preset, astro), (float("nan"), float("nan")))
            rows.append(ComparisonRow(preset, astro, res.summary(), *paper))
            if on_row is not None:
                on_row(rows[-1])
    return rows
