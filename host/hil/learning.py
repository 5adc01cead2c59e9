"""STDP as pulses: the synapse back-ends of learning with the weights on a device
(``snan-hil learn``, docs/learning.md).

The rest of the network (input, interneurons, astrocytes, decision) runs on the host as in
every trial (:func:`snan_hil.host.agent.run_trial`); the back-end gives the motor neurons'
synaptic drive (or, on the board's decision window, the motor neurons' spikes) and takes the
STDP updates.

**Update rule** (:class:`PulsePlanner`). Per synapse the host keeps the *intended* weight
``w_int`` — what the software rule would hold: every update ``dw`` (the window's STDP change,
``k`` times for the chosen move) gives ``w_int = clip(w_int + dw, w_min, w_max)``, exactly as
:class:`~snan_hil.host.agent.SoftwareSynapses` does — and its *estimate* ``w_est`` of the
weight on the device. After a trial (``stdp.mode = trial_end``: the changes of a trial are
applied at its end) the difference ``w_int - w_est`` becomes whole pulses of the learning
pulse, each predicted by the fitted device model (:class:`~snan_hil.crossbar_model.fitted.
DeviceModel`, the cell's own fit where it has one): SET while the difference is at least half
a predicted SET step above 0, RESET while at least half a RESET step below; ``w_est`` moves by
each predicted step. What is left (less than half a step) is the synapse's *remainder*: it is
not lost, the next update adds to it (the Tiki-Taka idea of aihwkit's transfer compounds: a
digital buffer per weight, whole pulses sent). The weights stay inside the mapping window:
``w_int`` is clipped to ``[w_min, w_max]`` and no pulse is planned that the model predicts to
end beyond it by more than half a step. Pulses are open loop; an optional refresh re-reads
the synapses every N cycles and sets ``w_est`` to what was read (the next plan corrects the
difference).

**Budget** (:class:`PulseBudget`, issue 36): a learning session may spend at most
``session_pulses`` learning pulses, a synapse's cell at most ``cell_pulses`` of them, one plan
at most ``plan_pulses`` per synapse; and a pulse is only sent while the pending change is at
least ``threshold_steps`` predicted steps (0.5: the rounding above; 1: *thresholded* — a
whole step's worth must have accumulated). What a budget holds back is not lost: it stays in
the remainder (*buffered transfer*, as above) and goes out in a later plan when the budget
allows — or never, when the rule takes it back first. When a plan wants more pulses than the
session has left, they are granted one at a time to the synapse with the largest pending
change left, in units of its next step (the largest error first). Every budget is off
(None) by default: today's rule.

* :class:`DeviceModelSynapses` — the *device-model arm*: the weights live in simulated devices
  drawn from the fitted model (each synapse its own device: the model's device-to-device
  spreads), every pulse a noisy step of it (cycle-to-cycle spread), reads with the measured
  read noise: quantised, noisy, asymmetric steps without a board.
* :class:`ChipSynapses` / :class:`ChipMotorNeurons` — the *chip arm*: drive read from the
  crossbar by a fixed-layout back-end (:mod:`snan_hil.host.hil.synapses`; ``batch``,
  ``per_spike``, ``per_window``), or, in the ``on_board`` mode, the motor neurons run on the
  board too and each window answers the motor spike steps STDP needs (DECISION_WINDOW);
  updates applied as WRITE_PULSEs through a :class:`PulseSink` (the learn run's, which
  journals every pulse, keeps the ledger and never sends a pulse twice).
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any, Protocol

import numpy as np

from snan_hil.calibration.mapping import WeightMap
from snan_hil.common.polarity import Polarity
from snan_hil.crossbar_model.fitted import CellFit, DeviceModel
from snan_hil.host.agent import MotorBackend

__all__ = ["PulseBudget", "PulseOrder", "PulsePlanner", "PulseSink", "DeviceModelSynapses",
           "ChipSynapses", "ChipMotorNeurons", "chip_backend", "synapse_index"]

Key = tuple[int, int]            #: a synapse: (pre, direction) in the agent's compact tables


def synapse_index(nbr: np.ndarray) -> list[Key]:
    """Every synapse of the neighbour table ``nbr`` (int [n_cells, 4], -1 = none), in
    (pre, direction) order."""
    return [(int(i), int(d)) for i in range(nbr.shape[0]) for d in range(nbr.shape[1])
            if nbr[i, d] >= 0]


@dataclass(frozen=True)
class PulseOrder:
    """``count`` pulses of ``polarity`` for synapse ``key`` in cell (row, col); ``step`` the
    predicted weight change of each (signed), in order."""

    key: Key
    row: int
    col: int
    polarity: Polarity
    steps: tuple[float, ...]

    @property
    def count(self) -> int:
        return len(self.steps)


@dataclass(frozen=True)
class PulseBudget:
    """Limits of the learning pulses (module doc): per session, per synapse cell and session,
    per synapse and plan (None: no limit), and the pending change (in predicted steps) below
    which no pulse is sent (0.5: round to the nearest step)."""

    session_pulses: int | None = None
    cell_pulses: int | None = None
    plan_pulses: int | None = None
    threshold_steps: float = 0.5
    plan_share: float = 1.0
    """The most of the session's remaining pulses one plan may take (pacing: 0.25 leaves
    three quarters of what is left to the later cycles)."""
    recent_first: bool = True
    """When the session's budget cannot grant every wanted pulse: first to the synapses the
    latest trial updated (the rule's newest error), then to the older remainders."""

    def __post_init__(self) -> None:
        for name in ("session_pulses", "cell_pulses", "plan_pulses"):
            v = getattr(self, name)
            if v is not None and (int(v) != v or v < 1):
                raise ValueError(f"{name} must be a whole number >= 1 (or None: no limit), "
                                 f"got {v}")
        if not (math.isfinite(self.threshold_steps) and 0.5 <= self.threshold_steps <= 10):
            raise ValueError(f"threshold_steps must be 0.5..10 predicted steps, got "
                             f"{self.threshold_steps}")
        if not 0 < self.plan_share <= 1:
            raise ValueError(f"plan_share must be in (0, 1], got {self.plan_share}")

    @property
    def limited(self) -> bool:
        return (self.session_pulses is not None or self.cell_pulses is not None
                or self.plan_pulses is not None or self.threshold_steps != 0.5)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class PulsePlanner:
    """Intended weights, device estimates, remainders -> pulses (see module doc).

    ``cells``: synapse -> (row, col) of its device (the layout's cell; any unique pair for a
    simulated device); ``model``: the fitted device model (its ``cells`` fits used where
    ``per_cell``); ``weight_map``: weight <-> cell conductance (S). ``max_pulses``: most pulses
    one plan may give a synapse (a bound on a runaway; the remainder keeps the rest);
    ``budget``: the session's limits (:class:`PulseBudget`), counted from :meth:`start` in
    ``spent`` (pulses planned per synapse, less those not applied)."""

    model: DeviceModel
    weight_map: WeightMap
    cells: dict[Key, tuple[int, int]]
    w_min: float
    w_max: float
    per_cell: bool = True
    max_pulses: int = 200
    budget: PulseBudget = field(default_factory=PulseBudget)
    w_int: dict[Key, float] = field(default_factory=dict)
    w_est: dict[Key, float] = field(default_factory=dict)
    spent: dict[Key, int] = field(default_factory=dict)
    _fits: dict[Key, CellFit] = field(default_factory=dict, repr=False)
    _fresh: set[Key] = field(default_factory=set, repr=False)
    """Synapses updated since the last plan (the latest trial's)."""

    def __post_init__(self) -> None:
        chip = self.model.chip_cell()
        for key, (row, col) in self.cells.items():
            own = self.model.cell_fit(row, col) if self.per_cell else None
            self._fits[key] = own if own is not None else chip

    def start(self, weights: dict[Key, float], estimates: dict[Key, float] | None = None
              ) -> None:
        """Begin a session: intended weights ``weights``, device estimates ``estimates``
        (default the same: the device was programmed to them)."""
        self.w_int = {k: float(v) for k, v in weights.items()}
        self.w_est = dict(self.w_int if estimates is None else
                          {k: float(v) for k, v in estimates.items()})
        self.spent = {}
        self._fresh = set()

    @property
    def session_spent(self) -> int:
        """Learning pulses planned this session (less those not applied)."""
        return sum(self.spent.values())

    def remainder(self, key: Key) -> float:
        """Weight change not yet sent to the device (weight units)."""
        return self.w_int[key] - self.w_est[key]

    def update(self, key: Key, dw: float) -> None:
        """One STDP update of synapse ``key`` (weight units), clipped like the software rule."""
        self.w_int[key] = min(max(self.w_int[key] + float(dw), self.w_min), self.w_max)
        if dw != 0.0:
            self._fresh.add(key)

    def step(self, key: Key, polarity: Polarity, w: float) -> float:
        """Predicted signed weight change of one pulse at weight ``w``."""
        g = self.weight_map.conductance(w)
        dg = g * math.expm1(float(self._fits[key].mean_dx(polarity, g)))
        return dg / self.weight_map.span_s

    def _steps(self, key: Key) -> tuple[Polarity, list[float]]:
        """The predicted steps that bring ``key`` within ``threshold_steps`` of its intended
        weight, in order, within the window and the per-plan and per-cell limits."""
        b = self.budget
        pending = self.w_int[key] - self.w_est[key]
        pol = Polarity.SET if pending > 0 else Polarity.RESET
        if pending == 0.0:
            return pol, []
        sign = 1.0 if pending > 0 else -1.0
        limit = self.max_pulses
        if b.plan_pulses is not None:
            limit = min(limit, b.plan_pulses)
        if b.cell_pulses is not None:
            limit = min(limit, b.cell_pulses - self.spent.get(key, 0))
        w = self.w_est[key]
        steps: list[float] = []
        while len(steps) < limit:
            s = self.step(key, pol, w)
            if sign * s <= 1e-9 or sign * (self.w_int[key] - w) < b.threshold_steps * abs(s):
                break
            if not self.w_min - 0.5 * abs(s) <= w + s <= self.w_max + 0.5 * abs(s):
                break
            steps.append(s)
            w += s
        return pol, steps

    def _grant(self, wanted: dict[Key, tuple[Polarity, list[float]]]) -> dict[Key, int]:
        """How many of each synapse's wanted pulses the session's budget grants: all when
        they fit, else one at a time — to the synapses the latest trial updated first
        (``recent_first``), among them to the largest pending change left, in units of the
        synapse's next step."""
        total = sum(len(v[1]) for v in wanted.values())
        b = self.budget
        left = (total if b.session_pulses is None
                else max(b.session_pulses - self.session_spent, 0))
        if b.session_pulses is not None and b.plan_share < 1:
            left = min(left, math.ceil(b.plan_share * left))
        if total <= left:
            return {k: len(v[1]) for k, v in wanted.items()}
        granted = {k: 0 for k in wanted}

        def rank(k: Key, n: int) -> tuple[int, float]:
            steps = wanted[k][1]
            remaining = abs(self.w_int[k] - self.w_est[k] - sum(steps[:n]))
            stale = 0 if (b.recent_first and k in self._fresh) else 1
            return stale, -remaining / abs(steps[n])

        heap = [(rank(k, 0), k) for k in wanted]
        heapq.heapify(heap)
        while left > 0 and heap:
            _, k = heapq.heappop(heap)
            n = granted[k] = granted[k] + 1
            left -= 1
            if n < len(wanted[k][1]):
                heapq.heappush(heap, (rank(k, n), k))
        return granted

    def plan(self, keys: Iterable[Key] | None = None) -> list[PulseOrder]:
        """The pulses that bring each synapse's estimate to within ``threshold_steps`` of
        its intended weight, within the budget; the estimates move by the predicted steps
        (module doc)."""
        wanted: dict[Key, tuple[Polarity, list[float]]] = {}
        for key in (self.w_int if keys is None else keys):
            pol, steps = self._steps(key)
            if steps:
                wanted[key] = (pol, steps)
        granted = self._grant(wanted)
        self._fresh = set()
        orders = []
        for key, (pol, steps) in wanted.items():
            mine = steps[:granted[key]]
            if not mine:
                continue
            self.w_est[key] += sum(mine)
            self.spent[key] = self.spent.get(key, 0) + len(mine)
            row, col = self.cells[key]
            orders.append(PulseOrder(key, row, col, pol, tuple(mine)))
        return orders

    def not_applied(self, key: Key, steps: Sequence[float]) -> None:
        """Pulses of a plan that were not applied: the estimate moves back by their steps,
        and they are not counted against the budget."""
        self.w_est[key] -= float(sum(steps))
        if key in self.spent:
            left = self.spent[key] - len(steps)
            if left > 0:
                self.spent[key] = left
            else:
                del self.spent[key]

    def observe(self, key: Key, weight: float) -> None:
        """A read of the device (refresh): the estimate becomes it."""
        self.w_est[key] = float(weight)

    def state(self) -> dict[str, list]:
        """JSON-able intended weights and estimates (a checkpoint)."""
        keys = sorted(self.w_int)
        return {"keys": [list(k) for k in keys], "w_int": [self.w_int[k] for k in keys],
                "w_est": [self.w_est[k] for k in keys],
                "spent": [self.spent.get(k, 0) for k in keys]}

    def restore(self, state: dict[str, list]) -> None:
        keys = [tuple(int(v) for v in k) for k in state["keys"]]
        self.w_int = {k: float(v) for k, v in zip(keys, state["w_int"])}  # type: ignore[misc]
        self.w_est = {k: float(v) for k, v in zip(keys, state["w_est"])}  # type: ignore[misc]
        self.spent = {k: int(v) for k, v in zip(keys, state.get("spent", [0] * len(keys)))  # type: ignore[misc]
                      if v}


class _CollectingBackend:
    """``SynapseBackend`` plumbing shared by the two learning back-ends: STDP updates go to
    the planner (applied as pulses when the learn run says, after the trial)."""

    planner: PulsePlanner
    nbr: np.ndarray

    def apply_update(self, pre: int, dirs: Sequence[int], dw: np.ndarray) -> None:
        for d, delta in zip(dirs, dw):
            if delta != 0.0:
                self.planner.update((int(pre), int(d)), float(delta))

    def weights(self) -> np.ndarray:
        """The intended weights, float[n_cells, 4]."""
        out = np.zeros(self.nbr.shape)
        for (i, d), w in self.planner.w_int.items():
            out[i, d] = w
        return out


class DeviceModelSynapses(_CollectingBackend):
    """The device-model arm (module doc): one simulated device per synapse.

    Device of synapse s: the model's chip curve with its rates scaled by
    ``exp(dw_min_dtod xi_a +- up_down_dtod xi_b)`` (SET +, RESET -) and its bounds moved by
    ``g_max_dtod xi_c``, ``g_min_dtod xi_d`` in ln G (xi standard normals drawn from ``rng`` at
    construction); one pulse changes ln G by its mean step times ``1 + dw_min_std xi``
    (never reversed); a read of a synapse sees ``G (1 + read_noise xi)``, a fresh draw per
    input spike (the batch read of the chip arm). Programming to a weight puts the device
    within ``program_sigma`` (relative, normal) of its target: the write-and-verify error."""

    def __init__(self, model: DeviceModel, weight_map: WeightMap, nbr: np.ndarray,
                 planner: PulsePlanner, rng: np.random.Generator, *,
                 program_sigma: float = 0.01) -> None:
        self.model, self.weight_map, self.nbr = model, weight_map, np.asarray(nbr)
        self.planner, self.rng, self.program_sigma = planner, rng, float(program_sigma)
        self.keys = synapse_index(self.nbr)
        chip = model.chip_cell()
        n = len(self.keys)
        z = rng.standard_normal((4, n))
        self.devices: dict[Key, CellFit] = {}
        for j, key in enumerate(self.keys):
            common, bias = model.dw_min_dtod * z[0, j], model.up_down_dtod * z[1, j]
            self.devices[key] = CellFit(
                -1, -1, chip.x_ref, chip.up_rate * math.exp(common + bias), chip.up_slope,
                chip.x_max + model.g_max_dtod * z[2, j],
                chip.down_rate * math.exp(common - bias), chip.down_slope,
                chip.x_min + model.g_min_dtod * z[3, j])
        self.g: dict[Key, float] = {}
        self.pulses = {Polarity.SET: 0, Polarity.RESET: 0}

    def program(self, weights: dict[Key, float]) -> None:
        """Put every device at its weight (within the programming error)."""
        for key, w in weights.items():
            g = self.weight_map.conductance(w)
            self.g[key] = g * (1.0 + self.program_sigma * float(self.rng.standard_normal()))

    def read_weight(self, key: Key) -> float:
        """One noisy read of a synapse, as a weight (not clipped)."""
        g = self.g[key] * (1.0 + self.model.read_noise * float(self.rng.standard_normal()))
        return float(self.weight_map.weight(g, clip=False))

    def true_weights(self) -> dict[Key, float]:
        return {k: float(self.weight_map.weight(g, clip=False)) for k, g in self.g.items()}

    def drive(self, pre: int, dirs: Sequence[int], spikes: np.ndarray) -> np.ndarray:
        spikes = np.asarray(spikes, dtype=bool)
        out = np.zeros((spikes.shape[0], len(dirs)))
        bins = np.flatnonzero(spikes)
        if bins.size:
            for k, d in enumerate(dirs):
                g = self.g[(int(pre), int(d))]
                noisy = g * (1.0 + self.model.read_noise * self.rng.standard_normal(bins.size))
                out[bins, k] = (noisy - self.weight_map.g_min_s) / self.weight_map.span_s
        return out

    def apply(self, orders: Sequence[PulseOrder]) -> None:
        """Apply planned pulses to the simulated devices."""
        for o in orders:
            dev = self.devices[o.key]
            g = self.g[o.key]
            for _ in range(o.count):
                mean = float(dev.mean_dx(o.polarity, g))
                g *= math.exp(mean * max(1.0 + self.model.dw_min_std
                                         * float(self.rng.standard_normal()), 0.0))
                self.pulses[o.polarity] += 1
            self.g[o.key] = g


class PulseSink(Protocol):
    """Where the chip arm's pulses go (the learn run's journaled, ledgered executor)."""

    def apply(self, orders: Sequence[PulseOrder]) -> None: ...


class ChipSynapses(_CollectingBackend):
    """The chip arm (module doc) in the modes that read the synapses' drive (``batch``,
    ``per_spike``, ``per_window``): ``reader`` (a fixed-layout back-end of
    :mod:`snan_hil.host.hil.synapses`) gives the drive, the host integrates the motor
    neurons; updates are planned by ``planner`` and applied by the learn run through its
    :class:`PulseSink`."""

    def __init__(self, reader, planner: PulsePlanner, nbr: np.ndarray) -> None:
        self.reader, self.planner, self.nbr = reader, planner, np.asarray(nbr)

    def drive(self, pre: int, dirs: Sequence[int], spikes: np.ndarray) -> np.ndarray:
        return self.reader.drive(pre, dirs, spikes)


class ChipMotorNeurons(_CollectingBackend, MotorBackend):
    """The chip arm in the ``on_board`` mode (issue 23): ``reader`` (an
    :class:`~snan_hil.host.hil.board_window.OnBoardMotorNeurons`) runs each decision window on
    the board, one DECISION_WINDOW round trip, and — in a training trial (``want_spikes``,
    STDP on) — answers the motor spike steps beside the counts. The host's STDP pairs them
    with the input spike steps it drew itself (:func:`snan_hil.host.agent.run_trial`'s board
    path); the updates go to ``planner`` as in :class:`ChipSynapses`: the pulses are planned
    and applied the same way whichever mode read the synapses."""

    def __init__(self, reader, planner: PulsePlanner, nbr: np.ndarray) -> None:
        self.reader, self.planner, self.nbr = reader, planner, np.asarray(nbr)

    def motor_window(self, pre: int, dirs: Sequence[int], key: int, n_spikes: int,
                     inh: Sequence[np.ndarray], want_spikes: bool
                     ) -> tuple[np.ndarray, list[np.ndarray]]:
        """(counts int64[len(dirs)], motor spike steps per candidate) of one window
        (``agent.MotorBackend``)."""
        return self.reader.motor_window(pre, dirs, key, n_spikes, inh, want_spikes)


def chip_backend(reader, planner: PulsePlanner, nbr: np.ndarray
                 ) -> ChipSynapses | ChipMotorNeurons:
    """The chip arm's back-end for ``reader``: :class:`ChipMotorNeurons` for the on-board
    window (a reader that is a :class:`~snan_hil.host.agent.MotorBackend`), else
    :class:`ChipSynapses`."""
    if isinstance(reader, MotorBackend):
        return ChipMotorNeurons(reader, planner, nbr)
    return ChipSynapses(reader, planner, nbr)
