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
window in :class:`WindowTrial` (:func:`~snan_hil.host.snan_kernel.begin_window` draws the
input spikes, the back-end gives the drive, :func:`~snan_hil.host.snan_kernel.end_window` runs
the network, decides, learns and moves) and the back-end is called once per window; a
:class:`MotorBackend` (chosen by its type) runs the window's motor neurons on a board instead.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from abc import ABC, abstractmethod
from typing import Literal, NamedTuple, Protocol, Sequence

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


class MotorBackend(ABC):
    """A board that runs the candidates' motor neurons itself (DECISION_WINDOW, issue 23):
    ``motor_window(pre, dirs, key, n_spikes, inh, want_spikes)`` runs the window of input
    neuron ``pre`` (candidates ``dirs``) whose input spikes the stream state ``key`` draws
    (``n_spikes`` of them, as the host drew), with interneuron spike steps ``inh[k]`` per
    candidate, and returns (counts int64[len(dirs)], motor spike steps per candidate: a list
    of int arrays, needed only with ``want_spikes``). Also ``apply_update`` and ``weights``
    as :class:`SynapseBackend`. :class:`WindowTrial` runs a window's motor neurons on the board
    for a back-end of this type, on the host for any other."""

    @abstractmethod
    def motor_window(self, pre: int, dirs: Sequence[int], key: int, n_spikes: int,
                     inh: Sequence[np.ndarray], want_spikes: bool
                     ) -> tuple[np.ndarray, list[np.ndarray]]: ...

    def decided(self, lane: int) -> None:
        """The host's decision on the window just answered: the lane chosen (index into the
        window's ``dirs``; -1: none). A board that learns needs it (on-board learning,
        issue 34); others ignore it."""
        return None

    @abstractmethod
    def apply_update(self, pre: int, dirs: Sequence[int], dw: np.ndarray) -> None: ...

    @abstractmethod
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
    if eng == "reference" and not isinstance(backend, MotorBackend):
        ref = reference_trial(cfg, nbr, move, start, goals_t, key, backend, record=record)
        steps = len(ref.path) - 1
        return TrialResult(path=np.array(ref.path, dtype=np.int64), success=ref.success,
                           steps=steps, weights=backend.weights(), start=start,
                           goals=goals_t, counts=ref.counts, windows=ref.windows)
    run = WindowTrial(cfg, nbr, move, start, goals_t, key, backend, record)
    while not run.done:
        run.step()
    return run.result()


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


class BoardWindow(NamedTuple):
    """What the board needs for one decision window (:meth:`MotorBackend.motor_window`'s
    arguments): input neuron ``pre``, candidate directions ``dirs``, the stream state ``key``,
    the ``n_spikes`` input spikes the host drew, the interneuron spike steps per candidate and
    whether the motor spike steps are wanted (STDP on)."""

    pre: int
    dirs: list[int]
    key: int
    n_spikes: int
    inh: list[np.ndarray]
    want_spikes: bool


class WindowTrial:
    """One trial advanced a decision window at a time: the kernel's trial (its state, input
    spikes, interneurons, astrocytes, decision rule, STDP and moves), with the input->motor
    synapses behind ``backend``. The one window-by-window driver: where a window's motor
    neurons run is chosen by the back-end's type -

    * a :class:`MotorBackend` runs them on the board: the host draws the input spikes and runs
      the interneurons and astrocytes (:meth:`open`), the board answers the counts (and the motor
      spike steps when STDP needs them), the host decides, learns and moves (:meth:`close`); the
      model must start every window at rest (``neuron.reset_each_window``);
    * any other back-end (a :class:`SynapseBackend`) gives the drive of the window's input spikes
      and the host runs the motor neurons (:meth:`step`).

    :meth:`step` runs one whole window either way; :meth:`open` / :meth:`close` let a caller
    run the board's part elsewhere meanwhile (several trials interleaved on one board). STDP
    updates go back to the back-end after each window (``stdp.mode=window``) or in order at
    the end (:meth:`result`)."""

    def __init__(self, cfg: SnanConfig, nbr: np.ndarray, move: np.ndarray, start: int,
                 goals: tuple[int, ...], key: int,
                 backend: SynapseBackend | MotorBackend, record: bool = False) -> None:
        self.on_board = isinstance(backend, MotorBackend)
        if self.on_board and not cfg.neuron.reset_each_window:
            raise UserError("the board runs each window's motor neurons from rest: the "
                            "on-board mode needs neuron.reset_each_window=true (use --mode "
                            "batch)")
        self.cfg, self.nbr, self.move, self.backend = cfg, nbr, move, backend
        self.start, self.goals, self.record = start, goals, record
        self.p = p = kernel_params(cfg)
        self.ts = ts = K.new_trial_state(p, nbr.shape[0], len(goals))
        K.trial_start(p, ts, np.int64(start), np.uint64(key))
        self.goals_a = np.array(goals, dtype=np.int64)
        self.no_w = np.zeros(nbr.shape)
        self.windows: list[WindowResult] = []
        self.deferred: list[tuple[int, list[int], np.ndarray]] = []
        self.done = False
        self._open: tuple[int, list[int]] | None = None
        if self.on_board:
            self.post = np.zeros((4, cfg.window_steps + 1), dtype=np.int64)
        else:
            self.drive4 = np.zeros((cfg.window_steps, 4))
            self.spikes = ts.flags.view(np.bool_)

    def step(self) -> None:
        """Run the next decision window (see the class doc)."""
        if self.on_board:
            window = self.open()
            counts, spikes = self.backend.motor_window(*window)  # type: ignore[union-attr]
            self.close(counts, spikes)
            return
        p, ts = self.p, self.ts
        n_lanes = int(K.begin_window(p, ts, self.nbr, self.no_w, self.no_w))
        pos = int(ts.iv[K.IV_POS])
        dirs = [int(d) for d in ts.dirs[:n_lanes]]
        drive = np.asarray(self.backend.drive(pos, dirs, self.spikes.copy()),  # type: ignore
                           dtype=np.float64)
        steps_w = self.cfg.window_steps
        if drive.shape != (steps_w, n_lanes):
            raise ValueError(f"synapse back-end returned drive of shape {drive.shape}, "
                             f"expected {(steps_w, n_lanes)}")
        self.drive4[:, :n_lanes] = drive
        self.drive4[:, n_lanes:] = 0.0
        self.done = bool(K.end_window(p, ts, self.move, self.goals_a, self.no_w, self.drive4,
                                      True, False))
        self._learned(pos, dirs, n_lanes)

    def open(self) -> BoardWindow:
        """Begin the next window whose motor neurons the board runs: the input spikes drawn,
        the interneurons and astrocytes run; what the board needs for it."""
        p, ts = self.p, self.ts
        key_w = int(ts.key[0])
        n_lanes = int(K.begin_window(p, ts, self.nbr, self.no_w, self.no_w))
        K.board_window_inputs(p, ts)
        pos = int(ts.iv[K.IV_POS])
        dirs = [int(d) for d in ts.dirs[:n_lanes]]
        inh = [ts.isp[k, :int(ts.lane_i[K.LI_N_ISP, k])].copy() for k in range(n_lanes)]
        self._open = (pos, dirs)
        return BoardWindow(pos, dirs, key_w, int(ts.iv[K.IV_NS]), inh,
                           self.cfg.stdp.mode != "off")

    def close(self, counts: np.ndarray, spikes: Sequence[np.ndarray]) -> None:
        """The board's answer to the window :meth:`open` began (counts per candidate, motor
        spike steps when wanted): decide, learn, move."""
        assert self._open is not None, "close() without open()"
        pos, dirs = self._open
        self._open = None
        n_lanes = len(dirs)
        c = np.zeros(4, dtype=np.int64)
        c[:n_lanes] = counts
        if self.cfg.stdp.mode != "off":
            for k in range(n_lanes):
                self.post[k, :len(spikes[k])] = spikes[k]
        self.done = bool(K.board_window_end(self.p, self.ts, self.move, self.goals_a, self.no_w,
                                            c, self.post, False))
        self.backend.decided(int(self.ts.iv[K.IV_CHOSEN]))  # type: ignore[union-attr]
        self._learned(pos, dirs, n_lanes)

    def _learned(self, pos: int, dirs: list[int], n_lanes: int) -> None:
        """After a window: its record and its STDP change (now, or kept for the end)."""
        ts = self.ts
        if self.record:
            self.windows.append(WindowResult(counts=ts.counts[:n_lanes].copy(),
                                             dw=ts.dw[:n_lanes].copy()))
        if self.cfg.stdp.mode != "off" and n_lanes:
            upd = ts.upd[:n_lanes].copy()
            if self.cfg.stdp.mode == "window":
                self.backend.apply_update(pos, dirs, upd)
            else:
                self.deferred.append((pos, dirs, upd))

    def result(self) -> TrialResult:
        """The finished trial (the deferred STDP updates applied, in order)."""
        for pre, dirs, upd in self.deferred:
            self.backend.apply_update(pre, dirs, upd)
        self.deferred = []
        ts = self.ts
        steps = int(ts.iv[K.IV_STEP])
        return TrialResult(path=ts.path[:steps + 1].copy(),
                           success=bool(ts.iv[K.IV_SUCCESS]), steps=steps,
                           weights=self.backend.weights(), start=self.start, goals=self.goals,
                           counts=ts.counts_hist[:steps].copy(), windows=self.windows)


def trial_setup(env: GridWorld, cfg: SnanConfig, start: int, goals: int | Sequence[int], *,
                seed: int = 0, trial: int = 0) -> tuple[np.ndarray, np.ndarray, int,
                                                        tuple[int, ...], int]:
    """(nbr, move, start, goals, key) of a trial as :func:`run_trial` sets it up: the
    environment checked, the cells validated, the trial's stream key (for a
    :class:`WindowTrial` a caller runs itself)."""
    _check_env(env, cfg)
    goals_t = ((int(goals),) if isinstance(goals, (int, np.integer))
               else tuple(int(g) for g in goals))
    start, goals_t = env.validate_cells(int(start), goals_t)
    nbr, move = synapse_tables(env, cfg)
    key, _task_seed, _w_seed = trial_keys(seed, trial)
    return nbr, move, start, goals_t, key
