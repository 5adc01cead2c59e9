"""What the three arms of ``snan-hil learn`` share (the configuration, the task, a session's
result, the curves) and the two arms that need no board: ``software`` and ``device``
(docs/learning.md section 3; the chip arm: :mod:`snan_hil.host.hil.learn_chip`).

Session ``k`` of every arm uses the random streams of
:func:`~snan_hil.host.experiments.route.session_seed` ``(seed, k)`` -- its trial ``j`` (test
``c``: ``j = 2c``, training ``c``: ``j = 2c - 1``) the streams of
:func:`snan_hil.host.rng.trial_keys` ``(session_seed, j)``, its initial weights those of trial
0 -- so the arms see the same initial weights, input spikes and tie-breaks and differ only by
where the weights live.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from snan_hil.calibration.mapping import WeightMap
from snan_hil.common.errors import UserError
from snan_hil.crossbar_model.fitted import DeviceModel, LearningPulse
from snan_hil.host.agent import run_trial, synapse_tables
from snan_hil.host.config import SnanConfig
from snan_hil.host.experiments.route import RouteProtocol, configs, session_seed
from snan_hil.host.grid import GridWorld
from snan_hil.host.hil.learning import (DeviceModelSynapses, Key, PulseBudget, PulsePlanner,
                                        synapse_index)
from snan_hil.host.intervals import interval_fields
from snan_hil.host.rng import trial_keys
from snan_hil.host.state import initial_weights

__all__ = ["ARMS", "PAPER_FIG7", "LearnConfig", "SessionResult", "LearnTask",
           "software_session", "device_session", "curves", "make_planner", "intended_weights",
           "estimated_weights"]

ARMS = ("software", "device", "chip")
#: the paper's Fig. 7 (section 3.5): size -> (median cycle 0, median cycle 20,
#: success cycle 0, success cycle 20)
PAPER_FIG7 = {3: (10.0, 4.0, 0.580, 0.978), 5: (73.0, 9.0, 0.446, 0.955),
              10: (389.0, 38.0, 0.404, 0.990)}

MAX_DEVICE_SEED = 2**63 - 1   #: as the CLI's --seed (tools/cli.py MAX_SEED): an SQLite INTEGER


@dataclass(frozen=True)
class LearnConfig:
    """One learning run: ``sessions`` x ``cycles`` of each arm of ``arms`` on the route
    ``start`` -> ``goal`` (cells of the model's grid), sessions seeded from ``seed``;
    ``refresh_every``: the chip arm re-reads its synapses every N cycles (0: open loop);
    ``per_cell``: plan with each cell's own fit where it was measured; ``mode``: how the chip
    arm reads the synapses (None: the board's default, :func:`snan_hil.host.hil.synapses.
    check_mode`); ``conversions``: ADC conversions a read of the on-board window (None: the
    board's read plan, :func:`snan_hil.host.hil.board_window.read_plan`); ``pulse``: the
    learning pulse (the device model must be of it); ``budget``: the learning pulses' limits
    per session, cell and plan (:class:`~snan_hil.host.hil.learning.PulseBudget`, device and
    chip arms); ``device_seed``: the device-model arm's draw of its devices and their noise.
    :meth:`check` names what is wrong."""

    start: int
    goal: int
    sessions: int = 10
    cycles: int = 20
    seed: int = 1
    arms: tuple[str, ...] = ARMS
    refresh_every: int = 0            #: chip arm: re-read every N cycles (0: open loop)
    per_cell: bool = True             #: plan with each cell's own fit where measured
    mode: str | None = None           #: how the chip arm reads the synapses (None: default)
    conversions: int | None = None    #: on-board window: ADC conversions a read (None: board's)
    pulse: LearningPulse = field(default_factory=LearningPulse)
    budget: PulseBudget = field(default_factory=PulseBudget)   #: learning pulses' limits
    device_seed: int = 0
    """The device-model arm's draw of its devices and their noise (0: the default stream;
    another value: another chip of the same model, with its own noise, over the same
    sessions -- the spread between two such runs is what the arm's prediction of a chip
    can be expected to miss by, whatever the model)."""

    def check(self, names: Mapping[str, str] | None = None) -> None:
        """UserError (one line; a field is named as ``names`` spells it: the CLI's options,
        a notebook's keywords) for a value no run can take."""
        name = (names or {}).get
        bad = [a for a in self.arms if a not in ARMS]
        if bad or not self.arms:
            raise UserError(f"{name('arms', 'arms')}: unknown {bad[0] if bad else '(none)'}; "
                            "use " + ", ".join(ARMS))
        if len(set(self.arms)) != len(self.arms):
            raise UserError(f"{name('arms', 'arms')} {','.join(self.arms)}: names an arm twice; "
                            "give each arm once")
        for what, value, low, high in (("sessions", self.sessions, 1, 10_000),
                                       ("cycles", self.cycles, 1, 1000)):
            if not low <= value <= high:
                raise UserError(f"{name(what, what)} must be {low}..{high}, got {value}")
        if self.device_seed < 0:
            raise UserError(f"{name('device_seed', 'device_seed')} must be >= 0, got "
                            f"{self.device_seed}")
        if self.device_seed > MAX_DEVICE_SEED:      # recorded with the run, as --seed is
            raise UserError(f"{name('device_seed', 'device_seed')} {self.device_seed}: at most "
                            f"{MAX_DEVICE_SEED} (2**63 - 1, what the run's record can hold); "
                            "give a smaller seed")
        if self.device_seed and "device" not in self.arms:
            raise UserError(f"{name('device_seed', 'device_seed')} draws the device-model "
                            f"arm's devices, and {name('arms', 'arms')} "
                            f"{','.join(self.arms)} has no device arm: add device, or leave "
                            f"{name('device_seed', 'device_seed')} out")
        if self.refresh_every < 0:
            raise UserError(f"{name('refresh_every', 'refresh_every')} must be >= 0, got "
                            f"{self.refresh_every}")

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["arms"] = list(self.arms)
        d["budget"] = self.budget.to_dict()
        return d


@dataclass
class SessionResult:
    """Tests 0..cycles and trainings 1..cycles of one session of one arm."""

    test_steps: list[int] = field(default_factory=list)
    test_success: list[bool] = field(default_factory=list)
    train_steps: list[int] = field(default_factory=list)
    train_success: list[bool] = field(default_factory=list)
    pulses: list[int] = field(default_factory=list)       #: per cycle (model/chip arms)
    weights: list[float] | None = None                    #: final weights, synapse order
    w_intended: list[list[float]] = field(default_factory=list)
    """Model and chip arms, per cycle 1..C: the planner's intended weights after the cycle's
    plan (synapse order)."""
    w_estimate: list[list[float]] = field(default_factory=list)
    """Per cycle 1..C: the planner's estimates of the device's weights after the plan."""
    max_cell_pulses: int = 0
    """The most learning pulses one synapse's cell took in the session (the planner's
    count, :attr:`PulsePlanner.spent`)."""

    def keep_weights(self, planner: PulsePlanner, keys: Sequence[Key]) -> None:
        """Record the planner's intended and estimated weights of this cycle."""
        self.w_intended.append(intended_weights(planner, keys))
        self.w_estimate.append(estimated_weights(planner, keys))
        self.max_cell_pulses = max(planner.spent.values(), default=0)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


class LearnTask:
    """What every arm of one run shares: configs (training: astrocytes on, STDP at the
    trial's end; test: astrocytes off), the environment, the synapse tables."""

    def __init__(self, cfg: SnanConfig, lc: LearnConfig) -> None:
        self.lc = lc
        self.proto = RouteProtocol(cycles=lc.cycles, task="fixed", train_astro=True)
        self.train_cfg, self.test_cfg = configs(cfg, self.proto)
        self.cfg = cfg
        self.env = GridWorld(cfg.grid.rows, cfg.grid.cols)
        self.env.validate_cells(lc.start, (lc.goal,))
        self.nbr, _ = synapse_tables(self.env, cfg)
        self.keys = synapse_index(self.nbr)

    def seed(self, session: int) -> int:
        return session_seed(self.lc.seed, session)

    def initial(self, session: int) -> np.ndarray:
        """Session ``session``'s initial weights, float[n_cells, 4]."""
        _k, _t, w_seed = trial_keys(self.seed(session), 0)
        return initial_weights(self.cfg, self.nbr, np.random.default_rng(w_seed))

    def trial(self, session: int, j: int, train: bool, *, weights: Any = None,
              backend: Any = None) -> Any:
        """Trial ``j`` of session ``session`` (:func:`snan_hil.host.agent.run_trial`)."""
        return run_trial(self.env, self.train_cfg if train else self.test_cfg, self.lc.start,
                         self.lc.goal, seed=self.seed(session), trial=j, weights=weights,
                         backend=backend)


def make_planner(task: LearnTask, model: DeviceModel, weight_map: WeightMap,
                 cells: dict[Key, tuple[int, int]]) -> PulsePlanner:
    """The pulse planner of one session (the model's STDP window bounds, the run's budget)."""
    d = task.cfg.stdp
    return PulsePlanner(model, weight_map, cells, d.w_min, d.w_max, per_cell=task.lc.per_cell,
                        budget=task.lc.budget)


def intended_weights(planner: PulsePlanner, keys: Sequence[Key]) -> list[float]:
    """The planner's intended weights of ``keys`` (rounded to 1e-6: the dataset's)."""
    return [round(planner.w_int[k], 6) for k in keys]


def estimated_weights(planner: PulsePlanner, keys: Sequence[Key]) -> list[float]:
    """The planner's estimates of the device's weights of ``keys`` (rounded to 1e-6)."""
    return [round(planner.w_est[k], 6) for k in keys]


def software_session(task: LearnTask, k: int, tick: Callable[[str], None]) -> SessionResult:
    """Session ``k`` of the software arm: the weights in memory, the trial kernel."""
    out = SessionResult()
    w = task.initial(k)
    for c in range(task.lc.cycles + 1):
        if c:
            r = task.trial(k, 2 * c - 1, True, weights=w)
            w = r.weights
            out.train_steps.append(r.steps)
            out.train_success.append(r.success)
            tick(f"software session {k} cycle {c}")
        r = task.trial(k, 2 * c, False, weights=w)
        out.test_steps.append(r.steps)
        out.test_success.append(r.success)
    out.weights = [float(w[key]) for key in task.keys]
    return out


def device_session(task: LearnTask, k: int, model: DeviceModel, weight_map: WeightMap,
                   tick: Callable[[str], None]) -> SessionResult:
    """Session ``k`` of the device-model arm (:class:`~snan_hil.host.hil.learning.
    DeviceModelSynapses`: one simulated device per synapse, drawn from the fitted model)."""
    out = SessionResult()
    w0 = task.initial(k)
    cells = {key: (j, -1) for j, key in enumerate(task.keys)}
    planner = make_planner(task, model, weight_map, cells)
    tag = [0x64657669] + ([task.lc.device_seed] if task.lc.device_seed else [])   # "devi"
    rng = np.random.default_rng(np.random.SeedSequence([task.seed(k), *tag]))
    dev = DeviceModelSynapses(model, weight_map, task.nbr, planner, rng)
    start = {key: float(w0[key]) for key in task.keys}
    dev.program(start)
    planner.start(start, dev.true_weights())
    for c in range(task.lc.cycles + 1):
        if c:
            r = task.trial(k, 2 * c - 1, True, backend=dev)
            before = sum(dev.pulses.values())
            dev.apply(planner.plan())
            out.pulses.append(sum(dev.pulses.values()) - before)
            out.keep_weights(planner, task.keys)
            out.train_steps.append(r.steps)
            out.train_success.append(r.success)
            tick(f"device session {k} cycle {c}")
        r = task.trial(k, 2 * c, False, backend=dev)
        out.test_steps.append(r.steps)
        out.test_success.append(r.success)
    tw = dev.true_weights()
    out.weights = [tw[key] for key in task.keys]
    return out


def curves(results: Sequence[SessionResult], seed: int = 0) -> dict[str, Any]:
    """Per cycle of the tests: median of the successful tests and success rate with their
    95 % intervals (:func:`snan_hil.host.intervals.interval_fields`)."""
    if not results:
        return {}
    ts = np.array([r.test_steps for r in results])
    ok = np.array([r.test_success for r in results], dtype=bool)
    out: dict[str, Any] = {"median": [], "median_ci": [], "success": [], "success_ci": [],
                           "sessions": int(ts.shape[0])}
    for c in range(ts.shape[1]):
        f = interval_fields(ts[:, c], ok[:, c], seed=seed)
        out["median"].append(float(np.median(ts[ok[:, c], c])) if ok[:, c].any() else None)
        out["success"].append(float(ok[:, c].mean()))
        out["median_ci"].append(f["median_steps_ci"])
        out["success_ci"].append(f["success_rate_ci"])
    if results[0].pulses:
        out["pulses_per_cycle"] = [float(v) for v in
                                   np.mean([r.pulses for r in results], axis=0)]
    return out
