"""Astrocyte calcium of every grid cell, decision by decision, for a trial that has run: a
slower traced re-run of the same trial in the plain reference (paper Fig. 3 D2).

The trial kernel does not keep per-step calcium, and needs not: the calcium of astrocyte ``i``
depends only on the input spikes of cell ``i`` (its glutamate is driven by input neuron ``i``
while the agent stands on ``i``; paper section 2.2.3 and
:mod:`snan_hil.host.snan_reference`), never on weights, motor neurons or the crossbar. Given the
trial's path and its window stream (``trial_keys(seed, trial)``; every window draws its input
spike train, then one tie-break draw, whatever the engine or back-end), the trial's calcium is
re-simulated with the reference equations: :func:`astro_window` (the readable form) steps the
glutamate and calcium of all cells at once, in the order and arithmetic of
:func:`~snan_hil.host.snan_reference.reference_window` (tested equal to it);
:func:`calcium_trace` runs the same steps compiled
(:func:`snan_hil.host.snan_kernel.astro_window_all`, tested to give the same floats), about
0.05 ms a window of the 6 x 6 task instead of 13 ms, so every launch of a comparison can carry
its calcium (the ``launches`` stream) at no cost beside the launch.

So a hardware launch (``run --animate``) and a software trial (``sim --animate``) get their
calcium the same way. Tests check that the re-run draws the trial's own spike trains (the
reference engine's recorded rasters) and that the calcium is that of the reference equations.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from snan_hil.common.errors import UserError
from snan_hil.host.config import SnanConfig
from snan_hil.host.rng import WindowStream, trial_keys
from snan_hil.host.snan_kernel import astro_window_all
from snan_hil.host.snan_reference import astro_step

__all__ = ["CalciumTrace", "calcium_trace", "astro_window"]


class CalciumTrace:
    """``ca[k, i]``: calcium of cell ``i``'s astrocyte after ``k`` decision windows (k = 0:
    before the first); ``spikes[k]``: the input spike count of window ``k``; ``path``: the
    visited cells (``path[k]`` during window ``k``); ``ca_thr``: the threshold above which
    the astrocyte lowers its interneuron's threshold."""

    def __init__(self, path: Sequence[int], ca: np.ndarray, spikes: np.ndarray,
                 ca_thr: float, grid: tuple[int, int]) -> None:
        self.path = [int(c) for c in path]
        self.ca = ca
        self.spikes = spikes
        self.ca_thr = float(ca_thr)
        self.grid = grid

    @property
    def steps(self) -> int:
        return len(self.path) - 1

    def frame(self, k: int) -> np.ndarray:
        """Calcium after window ``k`` as a rows x cols map."""
        return self.ca[k].reshape(self.grid)


def calcium_trace(cfg: SnanConfig, path: Sequence[int] | np.ndarray, *, seed: int, trial: int,
                  max_windows: int | None = None) -> CalciumTrace:
    """Re-run the astrocytes of trial ``trial`` of a run seeded ``seed`` along ``path`` (the
    trial's visited cells; ``len(path) - 1`` windows, at most ``max_windows``), compiled
    (:func:`~snan_hil.host.snan_kernel.astro_window_all`; :func:`astro_window` is its
    readable reference). UserError for a path with a cell outside the grid."""
    n = cfg.n_cells
    path = [int(c) for c in path]
    if not path or any(not 0 <= c < n for c in path):
        raise UserError(f"a path of cells 0..{n - 1} is needed to trace the calcium")
    windows = len(path) - 1 if max_windows is None else min(len(path) - 1, max_windows)
    key = trial_keys(seed, trial)[0]
    stream = WindowStream(key)
    g, c, y = np.zeros(n), np.zeros(n), np.zeros(n)
    steps_w = cfg.window_steps
    ca = np.zeros((windows + 1, n))
    spike_counts = np.zeros(windows, dtype=np.int64)
    ast = cfg.astro
    consts = (float(cfg.input.dt_ms), float(ast.alpha_n_per_ms), float(ast.k_n),
              float(ast.g_thr), float(ast.a), float(ast.tau_ca_ms))
    for k in range(windows):
        spikes = stream.spikes(steps_w, cfg.input.p)
        if ast.enabled:
            astro_window_all(*consts, path[k], spikes, g, c, y)
        stream.choice(1)                  # the window's tie-break draw
        ca[k + 1] = c
        spike_counts[k] = int(np.count_nonzero(spikes))
    return CalciumTrace(path[:windows + 1], ca, spike_counts, cfg.astro.ca_thr,
                        (cfg.grid.rows, cfg.grid.cols))


def astro_window(cfg: SnanConfig, g: np.ndarray, ca: np.ndarray, y: np.ndarray, cell: int,
                 spikes: np.ndarray) -> None:
    """One decision window of every astrocyte (in place; float64[n_cells] glutamate ``g``,
    calcium ``ca`` and its rate ``y``) with the agent on ``cell`` emitting ``spikes``
    (bool[T]): the reference's step (:func:`snan_hil.host.snan_reference.astro_step`, paper
    section 2.2.3) once per time step."""
    for t in range(len(spikes)):
        astro_step(cfg, g, ca, y, cell, 1.0 if spikes[t] else 0.0)
