"""The SNAN agent: one trial in a grid environment, with a pluggable synapse back-end.

:func:`run_trial` is the reusable entry point (experiments, route learning, hardware runs):
give it an environment (grid with walls), start and goal cell(s), a config, optionally the
initial weights (to carry learning across trials) and a seed; it returns the path, success,
the number of steps and the final weights.

Synapse back-end seam
---------------------
The only part of the network a hardware crossbar replaces is the input->motor synaptic
drive. A back-end implements :class:`SynapseBackend`:

* ``drive(pre, dirs, spikes) -> float[T, len(dirs)]``: excitatory synaptic input, per time
  step, of the motor neurons reached from input neuron ``pre`` through directions ``dirs``,
  given that input neuron's spike train ``spikes`` (bool[T]) of the window;
* ``apply_update(pre, dirs, dw)``: add the window's STDP change (already multiplied by
  ``k`` for the chosen move) to those synapses (software: add and clip; hardware: program);
* ``weights()``: the current weights as float[n_cells, 4] (for results and plots).

:class:`SoftwareSynapses` is the default (``drive = w * S``). With the software back-end
and no recording, trials run entirely inside the numba loop; with any other back-end the
window loop runs in Python and calls the back-end once per window, and the neuron and
astrocyte dynamics still run in the chosen engine.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Literal, Protocol, Sequence

import numpy as np

from snan_hil.errors import UserError
from snan_hil.host import snan_kernel as K
from snan_hil.host.config import SnanConfig
from snan_hil.host.grid import GridWorld
from snan_hil.host.rng import WindowStream, trial_keys
from snan_hil.host.snan_reference import WindowResult, reference_window
from snan_hil.host.state import NetworkState, initial_weights

log = logging.getLogger(__name__)

Engine = Literal["auto", "fast", "full", "reference"]


class SynapseBackend(Protocol):
    """Input->motor synapses (see module doc)."""

    def drive(self, pre: int, dirs: Sequence[int], spikes: np.ndarray) -> np.ndarray: ...

    def apply_update(self, pre: int, dirs: Sequence[int], dw: np.ndarray) -> None: ...

    def weights(self) -> np.ndarray: ...


class SoftwareSynapses:
    """Weights in memory: ``drive[t, k] = w[pre, dirs[k]] * S[t]``; STDP adds and clips.

    ``normalize`` (``stdp.target = normalize``): after an update the synapses ``dirs`` of
    ``pre`` are scaled back to their sum before it (same arithmetic as the numba kernel's
    :func:`snan_hil.host.snan_kernel.apply_window_stdp`).
    """

    def __init__(self, w: np.ndarray, w_min: float, w_max: float,
                 normalize: bool = False) -> None:
        self.w = np.array(w, dtype=np.float64)
        self.w_min, self.w_max = w_min, w_max
        self.normalize = normalize

    def drive(self, pre: int, dirs: Sequence[int], spikes: np.ndarray) -> np.ndarray:
        wk = self.w[pre, list(dirs)]
        return np.where(spikes[:, None], wk[None, :], 0.0)

    def _clip(self, v: float) -> float:
        return min(max(v, self.w_min), self.w_max)

    def apply_update(self, pre: int, dirs: Sequence[int], dw: np.ndarray) -> None:
        before = 0.0
        if self.normalize:
            for d in dirs:
                before += self.w[pre, d]
        for d, delta in zip(dirs, dw):
            self.w[pre, d] = self._clip(self.w[pre, d] + delta)
        if self.normalize and len(dirs) > 0:
            after = 0.0
            for d in dirs:
                after += self.w[pre, d]
            if after > 0.0:
                for d in dirs:
                    self.w[pre, d] = self._clip(self.w[pre, d] * before / after)

    def weights(self) -> np.ndarray:
        return self.w.copy()


@dataclass
class TrialResult:
    """Outcome of one trial. ``steps`` = moves made (== len(path) - 1)."""

    path: np.ndarray                 #: visited cells, path[0] = start
    success: bool
    steps: int
    weights: np.ndarray              #: final input->motor weights [n_cells, 4]
    start: int
    goals: tuple[int, ...]
    counts: np.ndarray | None = None  #: spike counts per step and direction (-1: none)
    windows: list[WindowResult] = field(default_factory=list)  #: rasters if record=True


def synapse_tables(env: GridWorld, cfg: SnanConfig) -> tuple[np.ndarray, np.ndarray]:
    """(nbr, move) int64 [n_cells, 4]: motor-neuron cell per synapse direction, and the cell
    the agent lands in when choosing that direction (-1 = stays, a bumping wall)."""
    if cfg.grid.walls == "bump":
        nbr = env.neighbour_table(through_walls=True)
        move = env.neighbour_table(through_walls=False)
    else:
        nbr = env.neighbour_table()
        move = nbr.copy()
    return nbr, move


def environment(cfg: SnanConfig) -> GridWorld:
    """The open grid of ``cfg.grid``."""
    return GridWorld(cfg.grid.rows, cfg.grid.cols)


def resolve_engine(cfg: SnanConfig, engine: Engine) -> Engine:
    if engine == "auto":
        return "fast" if K.fast_supported(cfg) else "full"
    if engine == "fast" and not K.fast_supported(cfg):
        raise UserError("engine 'fast' needs neuron.reset_each_window=true; use 'full'")
    if engine not in ("fast", "full", "reference"):
        raise UserError(f"unknown engine {engine!r} (auto, fast, full, reference)")
    return engine


def _check_env(env: GridWorld, cfg: SnanConfig) -> None:
    if (env.rows, env.cols) != (cfg.grid.rows, cfg.grid.cols):
        raise UserError(f"environment is {env.rows}x{env.cols} but the config says "
                        f"{cfg.grid.rows}x{cfg.grid.cols}")


def run_trial(env: GridWorld, cfg: SnanConfig, start: int, goals: int | Sequence[int], *,
              seed: int = 0, trial: int = 0, weights: np.ndarray | None = None,
              backend: SynapseBackend | None = None, engine: Engine = "auto",
              record: bool = False) -> TrialResult:
    """Run one trial from ``start`` until every goal was visited or ``grid.max_steps``.

    ``weights`` (float[n_cells, 4]) are the initial weights (drawn from the config's
    distribution with the trial's weight seed when None; ignored if ``backend`` is given).
    ``seed``/``trial`` select the random streams (see :mod:`snan_hil.host.rng`); the same
    (seed, trial, start, goals) gives the same trial in every engine and in
    :func:`snan_hil.host.simulate.simulate`. ``record`` keeps spike rasters per window
    (forces the Python window loop).
    """
    _check_env(env, cfg)
    goals_t = ((int(goals),) if isinstance(goals, (int, np.integer))
               else tuple(int(g) for g in goals))
    start, goals_t = env.validate_cells(int(start), goals_t)
    eng = resolve_engine(cfg, engine)
    nbr, move = synapse_tables(env, cfg)
    key, _task_seed, w_seed = trial_keys(seed, trial)
    if backend is None:
        if weights is None:
            w = initial_weights(cfg, nbr, np.random.default_rng(w_seed))
        else:
            w = np.array(weights, dtype=np.float64)
            if w.shape != nbr.shape:
                raise UserError(f"weights must have shape {nbr.shape}, got {w.shape}")
            w = np.where(nbr >= 0, w, 0.0)
        if eng != "reference" and not record:
            return _run_trial_numba(cfg, eng, nbr, move, start, goals_t, w, key)
        backend = SoftwareSynapses(w, cfg.stdp.w_min, cfg.stdp.w_max,
                                   normalize=cfg.stdp.target == "normalize")
    return _run_trial_python(cfg, eng, nbr, move, start, goals_t, backend, key, record)


def _run_trial_numba(cfg: SnanConfig, eng: Engine, nbr: np.ndarray, move: np.ndarray,
                     start: int, goals: tuple[int, ...], w: np.ndarray, key: int
                     ) -> TrialResult:
    fp, ip, tab = K.pack_params(cfg, K.ENGINE_FAST if eng == "fast" else K.ENGINE_FULL)
    st = NetworkState.fresh(cfg)
    path = np.full(cfg.grid.max_steps + 1, -1, dtype=np.int64)
    counts = np.full((cfg.grid.max_steps, 4), -1, dtype=np.int64)
    w = w.copy()
    steps, ok, _ = K.run_trial_kernel(fp, ip, tab, nbr, move, np.int64(start),
                                      np.array(goals, dtype=np.int64), w, np.uint64(key),
                                      path, counts, st.v_mot, st.ref_mot, st.v_int,
                                      st.ref_int, st.g, st.ca, st.y, st.t_astro)
    return TrialResult(path=path[:steps + 1].copy(), success=bool(ok), steps=int(steps),
                       weights=w, start=start, goals=goals, counts=counts[:steps].copy())


def _run_trial_python(cfg: SnanConfig, eng: Engine, nbr: np.ndarray, move: np.ndarray,
                      start: int, goals: tuple[int, ...], backend: SynapseBackend, key: int,
                      record: bool) -> TrialResult:
    """Window loop in Python: any back-end, any engine, optional rasters."""
    fp, ip, tab = K.pack_params(cfg, K.ENGINE_FAST if eng == "fast" else K.ENGINE_FULL)
    stream = WindowStream(key)
    st = NetworkState.fresh(cfg)
    steps_w = cfg.window_steps
    remaining = set(goals)
    pos = start
    path = [start]
    counts_hist = np.full((cfg.grid.max_steps, 4), -1, dtype=np.int64)
    windows: list[WindowResult] = []
    cands_buf = np.zeros(4, dtype=np.int64)
    counts = np.zeros(4, dtype=np.int64)
    dw = np.zeros(4)
    success = False
    deferred: list[tuple[int, list[int], np.ndarray]] = []
    for step in range(cfg.grid.max_steps):
        dirs = [d for d in range(4) if nbr[pos, d] >= 0]
        cands = [int(nbr[pos, d]) for d in dirs]
        spikes = stream.spikes(steps_w, cfg.input.p)
        drive = np.asarray(backend.drive(pos, dirs, spikes), dtype=np.float64)
        if drive.shape != (steps_w, len(dirs)):
            raise ValueError(f"synapse back-end returned drive of shape {drive.shape}, "
                             f"expected {(steps_w, len(dirs))}")
        if eng == "reference":
            res = reference_window(st, cfg, pos, cands, spikes, drive, record=record)
            c_k, dw_k = res.counts, res.dw
        else:
            cands_buf[:len(cands)] = cands
            drive4 = np.zeros((steps_w, 4))
            drive4[:, :len(dirs)] = drive
            fn = K.full_window
            if eng == "fast" and not np.any(drive[~spikes]):
                fn = K.fast_window  # event-driven: drive only at input spikes
            fn(fp, ip, tab, np.int64(pos), cands_buf, np.int64(len(cands)), spikes, drive4,
               np.int64(st.t_now), st.v_mot, st.ref_mot, st.v_int, st.ref_int, st.g, st.ca,
               st.y, st.t_astro, counts, dw)
            st.t_now += steps_w
            c_k, dw_k = counts[:len(cands)].copy(), dw[:len(cands)].copy()
            res = WindowResult(counts=c_k, dw=dw_k)
        if record:
            windows.append(res)
        choice_draw = stream.choice  # one draw per window, always
        for k, d in enumerate(dirs):
            counts_hist[step, d] = c_k[k]
        chosen = _choose(c_k, cfg, choice_draw)
        if cfg.stdp.mode != "off" and dirs:
            scaled = np.array(dw_k, dtype=np.float64)
            if chosen >= 0:
                scaled[chosen] = scaled[chosen] * cfg.stdp.k
            if cfg.stdp.target == "chosen":
                keep = np.zeros_like(scaled)
                if chosen >= 0:
                    keep[chosen] = scaled[chosen]
                scaled = keep
            elif cfg.stdp.target == "depress_others":
                others = np.arange(len(scaled)) != chosen
                scaled[others] = -np.abs(scaled[others])
            if cfg.stdp.mode == "window":
                backend.apply_update(pos, dirs, scaled)
            else:  # trial_end: replayed in order when the trial ends
                deferred.append((pos, dirs, scaled))
        if chosen >= 0:
            dest = int(move[pos, dirs[chosen]])
            if dest >= 0:
                pos = dest
        path.append(pos)
        remaining.discard(pos)
        if not remaining:
            success = True
            break
    for pre, dirs, scaled in deferred:
        backend.apply_update(pre, dirs, scaled)
    steps = len(path) - 1
    return TrialResult(path=np.array(path, dtype=np.int64), success=success, steps=steps,
                       weights=backend.weights(), start=start, goals=goals,
                       counts=counts_hist[:steps].copy(), windows=windows)


def _choose(counts: np.ndarray, cfg: SnanConfig, draw) -> int:
    """Index of the winning candidate (most spikes, ties at random); -1 = stay.

    Consumes exactly one draw of the window stream whatever happens (kernel does the same).
    """
    n = len(counts)
    if n == 0:
        draw(1)
        return -1
    mx = int(max(counts))
    tied = [k for k in range(n) if counts[k] == mx]
    idx = draw(len(tied))
    if mx == 0 and cfg.decision.no_spike == "stay":
        return -1
    return tied[idx]
