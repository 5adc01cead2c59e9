"""A chip's life of learning sessions (issue 36 point 5): many sessions of the route task on
one emulated chip, each programmed and learnt within the pulse budget, the chip wearing as it
goes; per-cell cumulative pulses, the wear the host predicts from them and the remaining
endurance (``bench/bench_lifetime.py``).

The synapses live on a :class:`~snan_hil.crossbar_model.array.CrossbarArray` driven directly
(:class:`ArraySynapses`; no board, no protocol: the bench drives the library, as the lead's
issue allows), its physics untouched — the twin of a fitted model
(:mod:`snan_hil.crossbar_model.device_twin`) with its wear term on. What the host does is what
the chip arm of ``snan-hil learn`` does, at the array's level:

* each session programs its initial weights with the board's two-stage write-and-verify
  (:func:`snan_hil.calibration.wv.write_and_verify`, adaptive ramp) on the array's cells,
  every read the host's (the array's read noise, averaged over the board's ``read_draws``
  conversions);
* every training trial's STDP updates become learning pulses through the same
  :class:`~snan_hil.host.hil.learning.PulsePlanner` and :class:`PulseBudget`;
* **refresh policy**: every ``refresh_every`` cycles the synapses are read (3 reads each) and
  the planner's estimates set to what was read, the correction planned at once (closed loop:
  what wear changed in the steps is read back instead of accumulating); every session starts
  from a fresh write-and-verify.

**Wear the host predicts** (:class:`WearLedger`): per cell the ``|Δ ln G|`` of every pulse as
the host knows it — the planned step of a learning pulse (the model's prediction), the change
between the host's reads before and after a write-and-verify pulse — summed and counted in the
model's cycles (``sum / (2 W)``, :class:`~snan_hil.crossbar_model.fitted.AgingTerm`); the
remaining endurance is the aging term's endurance minus that, and the sessions it leaves at
the run's mean rate. The emulated chip's own wear (:attr:`CrossbarArray.wear`, device cycles,
and its per-cell endurance) is the truth the prediction is compared with.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from snan_hil.calibration.mapping import WeightMap
from snan_hil.calibration.wv import ResponseModel, WVConfig, write_and_verify
from snan_hil.common.polarity import Polarity
from snan_hil.crossbar_model.array import CrossbarArray
from snan_hil.crossbar_model.fitted import DeviceModel, LearningPulse
from snan_hil.host.agent import run_trial, synapse_tables
from snan_hil.host.config import SnanConfig
from snan_hil.host.experiments.route import RouteProtocol, configs, session_seed
from snan_hil.host.grid import GridWorld
from snan_hil.host.hil.learning import (Key, PulseBudget, PulseOrder, PulsePlanner,
                                        _CollectingBackend, synapse_index)
from snan_hil.host.rng import trial_keys
from snan_hil.host.state import initial_weights

__all__ = ["LifetimeConfig", "ArraySynapses", "WearLedger", "run_lifetime"]

READ_V = 0.3            #: the board's read voltage (V; protocol.board MEMRICORE.max_read_v)
READ_SERIES_OHM = 3010.0   #: load + switches of the board's cell-read chain (Ohm)
WRITE_V_MAX = 1.4       #: the host's write limit (V), write-and-verify's ramp top


@dataclass(frozen=True)
class LifetimeConfig:
    """One chip's life: ``sessions`` x (program, ``cycles`` learning cycles); the route task
    of ``start`` -> ``goal``; ``budget`` the learning pulses' limits; ``refresh_every`` the
    closed-loop re-read (cycles, 0: open loop); ``read_draws`` the conversions a read
    averages (the board's ADC averages); ``pulse`` the learning pulse."""

    start: int
    goal: int
    sessions: int = 1000
    cycles: int = 20
    seed: int = 1
    budget: PulseBudget = field(default_factory=PulseBudget)
    refresh_every: int = 5
    read_draws: int = 10
    pulse: LearningPulse = field(default_factory=LearningPulse)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["budget"] = self.budget.to_dict()
        return d


class ArraySynapses(_CollectingBackend):
    """Synapses in cells of ``array`` (``cells``: synapse -> (row, col)); weights are cell
    conductances (memristor + select transistor, S) through ``weight_map``. A read is the
    mean of ``read_draws`` noisy reads of the array's read chain; each input spike of a trial
    reads its synapses afresh (the chip arm's batch read)."""

    def __init__(self, array: CrossbarArray, cells: dict[Key, tuple[int, int]],
                 weight_map: WeightMap, nbr: np.ndarray, planner: PulsePlanner,
                 pulse: LearningPulse, read_draws: int = 10,
                 wear: "WearLedger | None" = None) -> None:
        self.array, self.cells, self.weight_map = array, cells, weight_map
        self.nbr, self.planner, self.pulse = np.asarray(nbr), planner, pulse
        self.read_draws = int(read_draws)
        self.wear = wear
        self.wv = WVConfig()
        self.pulses = {Polarity.SET: 0, Polarity.RESET: 0}

    def _cell_g(self, row: int, col: int, n: int) -> np.ndarray:
        """``n`` host reads (each the mean of ``read_draws`` draws) of a cell, S."""
        i = self.array.cell_currents(row, col, READ_V, READ_SERIES_OHM, n * self.read_draws)
        i = i.reshape(n, self.read_draws).mean(axis=1)
        return 1.0 / np.maximum(READ_V / np.maximum(i, 1e-15) - READ_SERIES_OHM, 1e-3)

    def read_weight(self, key: Key, reads: int = 3) -> float:
        g = float(self._cell_g(*self.cells[key], reads).mean())
        return float(self.weight_map.weight(g, clip=False))

    def drive(self, pre: int, dirs: Sequence[int], spikes: np.ndarray) -> np.ndarray:
        spikes = np.asarray(spikes, dtype=bool)
        out = np.zeros((spikes.shape[0], len(dirs)))
        bins = np.flatnonzero(spikes)
        if bins.size:
            for k, d in enumerate(dirs):
                g = self._cell_g(*self.cells[(int(pre), int(d))], bins.size)
                out[bins, k] = (g - self.weight_map.g_min_s) / self.weight_map.span_s
        return out

    def apply(self, orders: Sequence[PulseOrder]) -> None:
        width = self.pulse.width_us * 1e-6
        for o in orders:
            amp = self.pulse.amplitude(o.polarity)
            w = self.planner.w_est[o.key] - sum(o.steps)
            for s in o.steps:
                self.array.apply_pulse(o.row, o.col, amp, o.polarity, width)
                self.pulses[o.polarity] += 1
                if self.wear is not None:
                    g0 = float(self.weight_map.conductance(w))
                    g1 = float(self.weight_map.conductance(w + s))
                    self.wear.add(o.row, o.col, abs(math.log(max(g1, 1e-9) / max(g0, 1e-9))),
                                  learning=True)
                w += s

    def program(self, weights: dict[Key, float]) -> int:
        """Two-stage write-and-verify (:func:`snan_hil.calibration.wv.write_and_verify`, the
        board's own, one response model for the session) of every synapse to its weight;
        the pulses applied. The host's reads around each pulse feed the wear ledger."""
        total = 0
        model = ResponseModel(self.wv)
        for key, wv in weights.items():
            row, col = self.cells[key]
            io = _ArrayCellIO(self, row, col)
            out = write_and_verify(io, float(self.weight_map.conductance(wv)), self.wv, model)
            total += out.pulses_stage1 + out.pulses_stage2
        return total


class _ArrayCellIO:
    """One cell of :class:`ArraySynapses` as write-and-verify sees it (calibration's
    ``CellIO``): host reads (cell conductance, S), pulses of ``wv.width_us``; every pulse
    and the change of ln G between the reads around it go to the wear ledger."""

    def __init__(self, syn: ArraySynapses, row: int, col: int) -> None:
        self.syn, self.row, self.col = syn, row, col
        self.last: float | None = None

    def read(self) -> float:
        self.last = float(self.syn._cell_g(self.row, self.col, 1)[0])
        return self.last

    def pulse(self, polarity: Polarity, amplitude_v: float) -> float:
        before = self.last if self.last is not None else self.read()
        self.syn.array.apply_pulse(self.row, self.col, amplitude_v, polarity,
                                   self.syn.wv.width_us * 1e-6)
        after = self.read()
        if self.syn.wear is not None:
            self.syn.wear.count(self.row, self.col, learning=False)
            self.syn.wear.add(self.row, self.col, abs(math.log(after / before)),
                              learning=False)
        return after

    def amplitude_cap(self, polarity: Polarity, conductance_s: float) -> float:
        return self.syn.wv.v_max


@dataclass
class WearLedger:
    """Per cell (row, col): pulses (learning, programming) and the host's ``|Δ ln G|`` sum."""

    learning: dict[tuple[int, int], int] = field(default_factory=dict)
    programming: dict[tuple[int, int], int] = field(default_factory=dict)
    swing: dict[tuple[int, int], float] = field(default_factory=dict)

    def count(self, row: int, col: int, *, learning: bool) -> None:
        book = self.learning if learning else self.programming
        book[(row, col)] = book.get((row, col), 0) + 1

    def add(self, row: int, col: int, dlng: float, *, learning: bool) -> None:
        self.swing[(row, col)] = self.swing.get((row, col), 0.0) + float(dlng)
        if learning:
            self.count(row, col, learning=True)

    def cycles(self, model: DeviceModel) -> dict[tuple[int, int], float]:
        """Predicted wear per cell in the model's cycles (``sum |Δ ln G| / (2 W)``)."""
        w = math.log(model.g_max_s / model.g_min_s)
        return {k: v / (2.0 * w) for k, v in self.swing.items()}


class _Task:
    def __init__(self, cfg: SnanConfig, lc: LifetimeConfig) -> None:
        self.lc, self.cfg = lc, cfg
        self.train_cfg, self.test_cfg = configs(cfg, RouteProtocol(cycles=lc.cycles))
        self.env = GridWorld(cfg.grid.rows, cfg.grid.cols)
        self.env.validate_cells(lc.start, (lc.goal,))
        self.nbr, _ = synapse_tables(self.env, cfg)
        self.keys = synapse_index(self.nbr)

    def initial(self, session: int) -> np.ndarray:
        _k, _t, w_seed = trial_keys(session_seed(self.lc.seed, session), 0)
        return initial_weights(self.cfg, self.nbr, np.random.default_rng(w_seed))

    def trial(self, session: int, j: int, train: bool, backend: Any) -> Any:
        return run_trial(self.env, self.train_cfg if train else self.test_cfg, self.lc.start,
                         self.lc.goal, seed=session_seed(self.lc.seed, session), trial=j,
                         backend=backend)


def _cells_for(array: CrossbarArray, keys: Sequence[Key]) -> dict[Key, tuple[int, int]]:
    """The synapses in the array's working cells, column by column from (0, 0) (a layout
    without spares: stuck cells skipped)."""
    free = [(r, c) for c in range(array.cols) for r in range(array.rows)
            if not array.stuck_mask[r, c]]
    if len(free) < len(keys):
        raise ValueError(f"{len(keys)} synapses, {len(free)} working cells")
    return dict(zip(keys, free))


def run_lifetime(cfg: SnanConfig, lc: LifetimeConfig, model: DeviceModel,
                 array: CrossbarArray, *, weight_map: WeightMap | None = None,
                 progress: Callable[[int, dict[str, Any]], None] | None = None
                 ) -> dict[str, Any]:
    """``lc.sessions`` sessions on ``array`` (module doc), planned with ``model``; the
    record: per session the test result of every cycle and the pulses, per cell the pulses
    and predicted cycles, the chip's true wear. ``progress(k, session_record)`` after each
    session."""
    task = _Task(cfg, lc)
    wm = weight_map or WeightMap()
    cells = _cells_for(array, task.keys)
    wear = WearLedger()
    d = cfg.stdp
    sessions: list[dict[str, Any]] = []
    t0 = time.perf_counter()
    for k in range(lc.sessions):
        planner = PulsePlanner(model, wm, cells, d.w_min, d.w_max, budget=lc.budget)
        syn = ArraySynapses(array, cells, wm, task.nbr, planner, lc.pulse, lc.read_draws, wear)
        w0 = task.initial(k)
        start = {key: float(w0[key]) for key in task.keys}
        prog = syn.program(start)
        planner.start(start, {key: syn.read_weight(key) for key in task.keys})
        tests = [bool(task.trial(k, 0, False, syn).success)]
        steps = []
        pulses = []
        for c in range(1, lc.cycles + 1):
            task.trial(k, 2 * c - 1, True, syn)
            before = sum(syn.pulses.values())
            syn.apply(planner.plan())
            if lc.refresh_every and c % lc.refresh_every == 0:
                for key in task.keys:
                    planner.observe(key, syn.read_weight(key))
                syn.apply(planner.plan())
            pulses.append(sum(syn.pulses.values()) - before)
            r = task.trial(k, 2 * c, False, syn)
            tests.append(bool(r.success))
            steps.append(int(r.steps))
        rec = {"session": k, "tests": tests, "last_steps": steps[-1], "pulses": pulses,
               "learning_pulses": int(sum(pulses)), "programming_pulses": int(prog),
               "max_cell_pulses": max(planner.spent.values(), default=0)}
        sessions.append(rec)
        if progress is not None:
            progress(k, rec)
    predicted = wear.cycles(model)
    keys_cells = sorted(set(cells.values()))
    aging = model.aging
    endurance = aging.endurance_cycles if aging is not None else math.inf
    return {
        "config": lc.to_dict(), "wall_s": time.perf_counter() - t0,
        "sessions": sessions,
        "cells": [{"row": r, "col": c,
                   "learning_pulses": wear.learning.get((r, c), 0),
                   "programming_pulses": wear.programming.get((r, c), 0),
                   "predicted_cycles": predicted.get((r, c), 0.0),
                   "true_wear_cycles": float(array.wear[r, c]),
                   "true_endurance_cycles": float(array.endurance[r, c]),
                   "worn": bool(array.worn[r, c])} for r, c in keys_cells],
        "model_endurance_cycles": endurance,
        "aging": None if aging is None else aging.to_dict(),
    }
