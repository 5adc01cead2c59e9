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
and no recording, trials run entirely inside the trial kernel
(:mod:`snan_hil.host.snan_kernel`); with any other back-end the same kernel runs window by
window (:func:`~snan_hil.host.snan_kernel.begin_window` draws the input spikes, the back-end
gives the drive, :func:`~snan_hil.host.snan_kernel.end_window` runs the network, decides,
learns and moves) and the back-end is called once per window.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Literal, Protocol, Sequence

import numpy as np

from snan_hil.common.errors import UserError
from snan_hil.host import snan_kernel as K
from snan_hil.host.config import SnanConfig
from snan_hil.host.grid import GridWorld
from snan_hil.host.kernel_params import kernel_params
from snan_hil.host.rng import trial_keys
from snan_hil.host.snan_reference import WindowResult, reference_trial
from snan_hil.host.state import initial_weights

log = logging.getLogger(__name__)

Engine = Literal["auto", "fast", "reference"]


class SynapseBackend(Protocol):
    """Input->motor synapses (see module doc)."""

    def drive(self, pre: int, dirs: Sequence[int], spikes: np.ndarray) -> np.ndarray: ...

    def apply_update(self, pre: int, dirs: Sequence[int], dw: np.ndarray) -> None: ...

    def weights(self) -> np.ndarray: ...


class MotorBackend(Protocol):
    """A board that runs the candidates' motor neurons itself (DECISION_WINDOW, issue 23):
    ``motor_window(pre, dirs, key, n_spikes, inh, want_spikes)`` runs the window of input
    neuron ``pre`` (candidates ``dirs``) whose input spikes the stream state ``key`` draws
    (``n_spikes`` of them, as the host drew), with interneuron spike steps ``inh[k]`` per
    candidate, and returns (counts int64[len(dirs)], motor spike steps per candidate: a list
    of int arrays, needed only with ``want_spikes``). Also ``apply_update`` and ``weights``
    as :class:`SynapseBackend`."""

    def motor_window(self, pre: int, dirs: Sequence[int], key: int, n_spikes: int,
                     inh: Sequence[np.ndarray], want_spikes: bool
                     ) -> tuple[np.ndarray, list[np.ndarray]]: ...

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
    windows: list[WindowResult] = field(default_factory=list)  #: per window if record=True


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
    """``auto``/``fast``: the trial kernel (every reading); ``reference``: the per-step
    Python reference (slow; the test oracle)."""
    if engine == "auto":
        return "fast"
    if engine not in ("fast", "reference"):
        raise UserError(f"unknown engine {engine!r} (auto, fast, reference)")
    return engine


def _check_env(env: GridWorld, cfg: SnanConfig) -> None:
    if (env.rows, env.cols) != (cfg.grid.rows, cfg.grid.cols):
        raise UserError(f"environment is {env.rows}x{env.cols} but the config says "
                        f"{cfg.grid.rows}x{cfg.grid.cols}")


def run_trial(env: GridWorld, cfg: SnanConfig, start: int, goals: int | Sequence[int], *,
              seed: int = 0, trial: int = 0, weights: np.ndarray | None = None,
              backend: SynapseBackend | MotorBackend | None = None, engine: Engine = "auto",
              record: bool = False) -> TrialResult:
    """Run one trial from ``start`` until every goal was visited or ``grid.max_steps``.

    ``weights`` (float[n_cells, 4]) are the initial weights (drawn from the config's
    distribution with the trial's weight seed when None; ignored if ``backend`` is given).
    ``seed``/``trial`` select the random streams (see :mod:`snan_hil.host.rng`); the same
    (seed, trial, start, goals) gives the same trial in every engine and in
    :func:`snan_hil.host.simulate.simulate`. ``record`` keeps the counts and STDP changes
    of every window (with ``engine="reference"`` also the spike rasters).
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
            return _run_trial_kernel(cfg, nbr, move, start, goals_t, w, key)
        backend = SoftwareSynapses(w, cfg.stdp.w_min, cfg.stdp.w_max,
                                   normalize=cfg.stdp.target == "normalize")
    if hasattr(backend, "motor_window"):
        return _run_trial_board(cfg, nbr, move, start, goals_t,
                                backend, key, record)  # type: ignore[arg-type]
    if eng == "reference":
        ref = reference_trial(cfg, nbr, move, start, goals_t, key, backend, record=record)
        steps = len(ref.path) - 1
        return TrialResult(path=np.array(ref.path, dtype=np.int64), success=ref.success,
                           steps=steps, weights=backend.weights(), start=start,
                           goals=goals_t, counts=ref.counts, windows=ref.windows)
    return _run_trial_backend(cfg, nbr, move, start, goals_t, backend, key, record)


def _run_trial_kernel(cfg: SnanConfig, nbr: np.ndarray, move: np.ndarray, start: int,
                      goals: tuple[int, ...], w: np.ndarray, key: int) -> TrialResult:
    """The whole trial inside the kernel (software weights)."""
    p = kernel_params(cfg)
    ts = K.new_trial_state(p, nbr.shape[0], len(goals))
    w = w.copy()
    steps, ok = K.run_trial_kernel(p, ts, nbr, move, np.int64(start),
                                   np.array(goals, dtype=np.int64), w, np.uint64(key))
    return TrialResult(path=ts.path[:steps + 1].copy(), success=bool(ok), steps=int(steps),
                       weights=w, start=start, goals=goals,
                       counts=ts.counts_hist[:steps].copy())


def _run_trial_backend(cfg: SnanConfig, nbr: np.ndarray, move: np.ndarray, start: int,
                       goals: tuple[int, ...], backend: SynapseBackend, key: int,
                       record: bool) -> TrialResult:
    """The kernel's trial, window by window, with the drive from ``backend`` (called once
    per window; its STDP updates go back to it, in order at the end with ``trial_end``)."""
    p = kernel_params(cfg)
    ts = K.new_trial_state(p, nbr.shape[0], len(goals))
    K.trial_start(p, ts, np.int64(start), np.uint64(key))
    goals_a = np.array(goals, dtype=np.int64)
    no_w = np.zeros(nbr.shape)
    steps_w = cfg.window_steps
    drive4 = np.zeros((steps_w, 4))
    spikes = ts.flags.view(np.bool_)
    windows: list[WindowResult] = []
    deferred: list[tuple[int, list[int], np.ndarray]] = []
    done = False
    while not done:
        n_lanes = int(K.begin_window(p, ts, nbr, no_w, no_w))
        pos = int(ts.iv[K.IV_POS])
        dirs = [int(d) for d in ts.dirs[:n_lanes]]
        drive = np.asarray(backend.drive(pos, dirs, spikes.copy()), dtype=np.float64)
        if drive.shape != (steps_w, n_lanes):
            raise ValueError(f"synapse back-end returned drive of shape {drive.shape}, "
                             f"expected {(steps_w, n_lanes)}")
        drive4[:, :n_lanes] = drive
        drive4[:, n_lanes:] = 0.0
        done = bool(K.end_window(p, ts, move, goals_a, no_w, drive4, True, False))
        if record:
            windows.append(WindowResult(counts=ts.counts[:n_lanes].copy(),
                                        dw=ts.dw[:n_lanes].copy()))
        if cfg.stdp.mode != "off" and n_lanes:
            upd = ts.upd[:n_lanes].copy()
            if cfg.stdp.mode == "window":
                backend.apply_update(pos, dirs, upd)
            else:
                deferred.append((pos, dirs, upd))
    for pre, dirs, upd in deferred:
        backend.apply_update(pre, dirs, upd)
    steps = int(ts.iv[K.IV_STEP])
    return TrialResult(path=ts.path[:steps + 1].copy(), success=bool(ts.iv[K.IV_SUCCESS]),
                       steps=steps, weights=backend.weights(), start=start, goals=goals,
                       counts=ts.counts_hist[:steps].copy(), windows=windows)


def _run_trial_board(cfg: SnanConfig, nbr: np.ndarray, move: np.ndarray, start: int,
                     goals: tuple[int, ...], backend: MotorBackend, key: int,
                     record: bool) -> TrialResult:
    """The kernel's trial, window by window, with the candidates' motor neurons on the board
    (:class:`MotorBackend`): the host draws the input spikes, runs the interneurons and
    astrocytes, sends the interneuron spikes; the board answers the counts (and the motor
    spike steps when STDP needs them); the host decides, learns and moves."""
    if not cfg.neuron.reset_each_window:
        raise UserError("the board runs each window's motor neurons from rest: the on-board "
                        "mode needs neuron.reset_each_window=true (use --mode batch)")
    p = kernel_params(cfg)
    ts = K.new_trial_state(p, nbr.shape[0], len(goals))
    K.trial_start(p, ts, np.int64(start), np.uint64(key))
    goals_a = np.array(goals, dtype=np.int64)
    no_w = np.zeros(nbr.shape)
    post = np.zeros((4, cfg.window_steps + 1), dtype=np.int64)
    want = cfg.stdp.mode != "off"
    windows: list[WindowResult] = []
    deferred: list[tuple[int, list[int], np.ndarray]] = []
    done = False
    while not done:
        key_w = int(ts.key[0])
        n_lanes = int(K.begin_window(p, ts, nbr, no_w, no_w))
        K.board_window_inputs(p, ts)
        pos = int(ts.iv[K.IV_POS])
        dirs = [int(d) for d in ts.dirs[:n_lanes]]
        inh = [ts.isp[k, :int(ts.lane_i[K.LI_N_ISP, k])].copy() for k in range(n_lanes)]
        counts, spikes = backend.motor_window(pos, dirs, key_w, int(ts.iv[K.IV_NS]), inh,
                                              want)
        c = np.zeros(4, dtype=np.int64)
        c[:n_lanes] = counts
        if want:
            for k in range(n_lanes):
                post[k, :len(spikes[k])] = spikes[k]
        done = bool(K.board_window_end(p, ts, move, goals_a, no_w, c, post, False))
        if record:
            windows.append(WindowResult(counts=ts.counts[:n_lanes].copy(),
                                        dw=ts.dw[:n_lanes].copy()))
        if want and n_lanes:
            upd = ts.upd[:n_lanes].copy()
            if cfg.stdp.mode == "window":
                backend.apply_update(pos, dirs, upd)
            else:
                deferred.append((pos, dirs, upd))
    for pre, dirs, upd in deferred:
        backend.apply_update(pre, dirs, upd)
    steps = int(ts.iv[K.IV_STEP])
    return TrialResult(path=ts.path[:steps + 1].copy(), success=bool(ts.iv[K.IV_SUCCESS]),
                       steps=steps, weights=backend.weights(), start=start, goals=goals,
                       counts=ts.counts_hist[:steps].copy(), windows=windows)
