"""Launches of the 6x6 task in the four scenarios (paper Fig. 10C): software / memristor
crossbar, without / with astrocytes.

All scenarios run the same agent (:func:`snan_hil.host.agent.run_trial`) with the weights fixed
(``stdp.mode=off``). Launch ``l`` of weight set ``k`` uses the random streams of
``(seed, k * TRIAL_STRIDE + l)`` in every scenario, so the four scenarios see the same input
spike trains and tie-break draws: software and hardware differ only by the analog reads,
astro and no-astro only by the astrocytes.

Hardware launches read the layout of the chip (``Layout``) and refuse weights the chip does not
hold: the fingerprint of the weight set must equal that of the weights the layout records as
programmed.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import hashlib
import statistics
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from snan_hil.calibration.layout import Layout, LayoutError
from snan_hil.calibration.weights_io import dense_to_compact, grid_synapses, weights_to_vector
from snan_hil.common.errors import UserError
from snan_hil.host.agent import (TrialResult, WindowTrial, environment, run_trial,
                                 synapse_tables, trial_setup)
from snan_hil.host.config import SnanConfig
from snan_hil.host.hil.config import SCENARIOS, HilConfig
from snan_hil.host.hil.board_window import OnBoardMotorNeurons
from snan_hil.host.hil.group_window import GroupMotorNeurons
from snan_hil.host.hil.interleave import run_interleaved
from snan_hil.host.hil.synapses import check_mode, make_synapses
from snan_hil.host.intervals import interval_fields
from snan_hil.common.progress import ProgressCallback, track
from snan_hil.protocol.client import BoardClient
from snan_hil.protocol.errors import UnsupportedError
from snan_hil.protocol.messages import Capability
from snan_hil.protocol.transport import wire_seconds

TRIAL_STRIDE = 1000          #: launches per set are < TRIAL_STRIDE
FINGERPRINT_DIGITS = 6       #: weights are compared rounded to 1e-6


def weights_fingerprint(w: np.ndarray, grid: tuple[int, int]) -> str:
    """Short hash of the synapse weights of a dense N x N matrix (grid synapse order, rounded
    to 1e-6)."""
    vec = weights_to_vector(np.asarray(w, dtype=float), grid_synapses(*grid))
    return _hash(vec)


def _hash(vec: np.ndarray) -> str:
    q = np.round(np.asarray(vec, dtype=float), FINGERPRINT_DIGITS) + 0.0   # no -0.0
    return hashlib.sha256(q.astype("<f8").tobytes()).hexdigest()[:16]


def layout_fingerprint(layout: Layout) -> str | None:
    """Fingerprint of the weights the layout records as programmed (None if any synapse has
    never been programmed, or is not marked programmed: ``ok`` None, e.g. a programming run
    that was stopped before it reached that synapse)."""
    by_pair = {(s.pre, s.post): (None if s.ok is None else s.weight) for s in layout.synapses}
    vec = [by_pair.get(p) for p in layout.pairs()]
    if any(v is None for v in vec):
        return None
    return _hash(np.array(vec, dtype=float))


def check_layout(layout: Layout, w: np.ndarray, grid: tuple[int, int], *, port: str,
                 weights_path: str = "weights", set_index: int = 0,
                 board_options: str | None = None) -> str:
    """Raise :class:`LayoutError` (one line) unless the chip holds weight set ``w``; returns
    the fingerprint. ``board_options``: the command-line options that reach this board, for
    the "program it first" hint (default ``--port PORT``; give ``--protocol legacy`` and the
    like too, or the hint fails on that board)."""
    fix = (f"program it first: snan-hil program-weights {weights_path} --weight-set {set_index} "
           f"{board_options or f'--port {port}'}")
    if tuple(layout.grid) != tuple(grid):
        raise LayoutError(f"the chip at {port} holds a {layout.grid[0]}x{layout.grid[1]} layout, "
                          f"the weights are {grid[0]}x{grid[1]}; {fix}")
    want = weights_fingerprint(w, grid) if layout.pres is None else \
        _hash(weights_to_vector(np.asarray(w, dtype=float), layout.pairs()))
    have = layout_fingerprint(layout)
    if have is None:
        done = sum(1 for s in layout.synapses if s.ok is not None and s.weight is not None)
        raise LayoutError(f"the layout of {port} is not completely programmed ({done} of "
                          f"{layout.n_synapses} synapses programmed: an earlier programming "
                          f"was stopped?); {fix}")
    if have != want:
        raise LayoutError(f"the chip at {port} holds other weights (fingerprint {have}) than set "
                          f"{set_index} of {weights_path} ({want}); {fix}")
    return want


def require_hardware(client: BoardClient, mode: str | None = None,
                     cfg: SnanConfig | None = None) -> str:
    """The hardware mode to run on ``client`` (``None``: the board's default, see
    :mod:`snan_hil.host.hil.synapses`); UserError if the board cannot run ``mode``."""
    return check_mode(client, mode, cfg)


@dataclass
class LaunchResult:
    """One launch: path, success and (hardware) the board's cost of it."""

    launch: int
    trial: int
    steps: int
    success: bool
    path: list[int]
    decisions: int
    wall_s: float
    spikes: int = 0
    requests: int = 0
    virtual_us: float | None = None       #: board clock over the launch (incl. UART)
    wire_us: float | None = None          #: UART time of the launch's bytes at the baud
    energy_j: float | None = None         #: array energy over the launch

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "LaunchResult":
        return cls(**d)


@dataclass
class ScenarioResult:
    """Launches of one weight set in one scenario."""

    scenario: str
    set_index: int
    seed: int
    launches: list[LaunchResult]
    fingerprint: str
    mode: str | None = None
    read_stats: dict = field(default_factory=dict)

    @property
    def path_lengths(self) -> list[int]:
        return [r.steps for r in self.launches]

    @property
    def success_rate(self) -> float:
        return sum(r.success for r in self.launches) / len(self.launches) if self.launches else 0.0

    @property
    def median_steps(self) -> float | None:
        """Median path length of the successful launches (None if none succeeded)."""
        ok = [r.steps for r in self.launches if r.success]
        return float(statistics.median(ok)) if ok else None

    def to_dict(self) -> dict[str, Any]:
        """Everything, JSON-able (a checkpoint of a run); :meth:`from_dict` reads it back."""
        return {"scenario": self.scenario, "set_index": self.set_index, "seed": self.seed,
                "launches": [r.to_dict() for r in self.launches],
                "fingerprint": self.fingerprint, "mode": self.mode,
                "read_stats": self.read_stats}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "ScenarioResult":
        return cls(d["scenario"], int(d["set_index"]), int(d["seed"]),
                   [LaunchResult.from_dict(r) for r in d["launches"]], d["fingerprint"],
                   d.get("mode"), dict(d.get("read_stats") or {}))

    def summary(self) -> dict[str, Any]:
        return {"scenario": self.scenario, "set": self.set_index, "seed": self.seed,
                "launches": len(self.launches), "path_lengths": self.path_lengths,
                "success": [r.success for r in self.launches],
                "median_steps": self.median_steps, "success_rate": self.success_rate,
                **interval_fields(self.path_lengths, [r.success for r in self.launches],
                                  seed=self.seed),
                "fingerprint": self.fingerprint, "mode": self.mode,
                "read_stats": self.read_stats}


def scenario_parts(scenario: str) -> tuple[bool, bool]:
    """(hardware, astro) of a scenario name."""
    if scenario not in SCENARIOS:
        raise UserError(f"unknown scenario {scenario!r}; use one of {', '.join(SCENARIOS)}")
    return scenario.startswith("hw_"), scenario.endswith("_astro")


def check_launches(launches: int) -> None:
    """UserError (one line) unless ``1 <= launches < TRIAL_STRIDE``: a set's launches take the
    trial numbers ``set_index * TRIAL_STRIDE + launch`` (commands check it before any work)."""
    if not 1 <= launches < TRIAL_STRIDE:
        raise UserError(f"--launches must be in 1..{TRIAL_STRIDE - 1}, got {launches}")


def run_scenario(scenario: str, w: np.ndarray, hil: HilConfig, *, set_index: int = 0,
                 launches: int = 10, seed: int = 0, start: int | None = None,
                 goal: int | None = None, client: BoardClient | None = None,
                 layout: Layout | None = None,
                 mode: str | None = None, baud: int | None = None,
                 progress: ProgressCallback | None = None,
                 on_launch: Callable[[LaunchResult], None] | None = None,
                 conversions: int | None = None,
                 interleave: bool | None = None,
                 group: Sequence[tuple[BoardClient, Layout]] | None = None) -> ScenarioResult:
    """Run ``launches`` launches of weight set ``w`` (dense N x N) in ``scenario``.
    ``progress`` gets a task named after the scenario (one unit per launch); ``on_launch``
    each launch's result as soon as it is done (a live view's feed).

    Hardware scenarios need ``client`` (connected; a session's client retries lost reads, this
    function never wraps it) and the chip's ``layout``; the layout must
    hold ``w`` (:func:`check_layout` is the caller's job, the fingerprint is recorded here).
    ``mode``: how the synapses are read (``on_board``, ``batch``, ``per_spike``,
    ``per_window``; None: the board's default). ``baud`` (line rate) converts the bytes of
    each launch to UART time. ``conversions``: ADC conversions a read of the on-board window
    (None: the board's default read plan, :func:`~snan_hil.host.hil.board_window.read_plan`).
    ``interleave``: run the on-board launches two at a time, the next window's request on the
    line while the board works (:mod:`~snan_hil.host.hil.interleave`; None: where the board
    has the PIPELINE capability and the windows read with the lean plan, whose noise is keyed
    by the window). The decisions are those of the launches one after another; each launch's
    board time, UART time and energy are then the scenario's shared by its decisions.

    ``group``: the network over a group of chips instead of one (``client``/``layout``
    unused): (client, layout) per chip, each layout a share of the grid
    (:mod:`snan_hil.host.hil.group_window`; on-board windows only, each on the chip of its
    input neuron). A launch's board time and energy are then the sum over the chips (the
    chips run one window at a time: an upper bound of a real group's), its UART time that of
    every chip's bytes at ``baud`` (each chip on its own line: also an upper bound).
    """
    hw, astro = scenario_parts(scenario)
    check_launches(launches)
    cfg = hil.launch_config(astro)
    env = environment(cfg)
    grid = (cfg.grid.rows, cfg.grid.cols)
    if w.shape != (env.n_cells, env.n_cells):
        raise UserError(f"weights are {w.shape[0]}x{w.shape[1]}, the {grid[0]}x{grid[1]} task "
                        f"needs {env.n_cells}x{env.n_cells}")
    start = hil.task.start if start is None else int(start)
    goal = hil.task.goal if goal is None else int(goal)
    env.validate_cells(start, (goal,))
    nbr, _ = synapse_tables(env, cfg)
    compact = dense_to_compact(w, *grid)
    backend: Any = None
    board: BoardClient | None = None
    boards: list[BoardClient] = []
    hw_mode: str | None = None
    if hw and group is not None:
        for c, _lay in group:
            check_mode(c, "on_board", cfg)
        hw_mode = "on_board"
        backend = GroupMotorNeurons(group, nbr, cfg, conversions=conversions)
        boards = backend.clients
        board = boards[0]
    elif hw:
        if client is None or layout is None:
            raise UserError(f"scenario {scenario} needs a board (--port) and its layout")
        hw_mode = check_mode(client, mode, cfg)
        board = client      # the session's: reads already resent after a lost reply
        backend = make_synapses(board, layout, nbr, hw_mode, cfg, conversions=conversions)
        boards = [board]
    results: list[LaunchResult] = []
    bar = track(progress, scenario, launches)
    windows = isinstance(backend, (OnBoardMotorNeurons, GroupMotorNeurons))
    if windows and all(_interleaving(b, interleave, backend) for b in boards):
        results = _interleaved(backend, boards, env, cfg, start, goal, seed, set_index,
                               launches, baud, on_launch, bar)
    for launch in range(launches if not results else 0):
        trial = set_index * TRIAL_STRIDE + launch
        t0 = time.perf_counter()
        if backend is None:
            r = run_trial(env, cfg, start, goal, seed=seed, trial=trial, weights=compact)
            res = LaunchResult(launch, trial, r.steps, r.success, [int(c) for c in r.path],
                               r.steps, time.perf_counter() - t0)
        else:
            before = _boards_snapshot(boards)
            spikes0, req0 = backend.stats.spikes, backend.stats.requests
            r = run_trial(env, cfg, start, goal, seed=seed, trial=trial, backend=backend)
            after = _boards_snapshot(boards)
            res = LaunchResult(launch, trial, r.steps, r.success, [int(c) for c in r.path],
                               r.steps, time.perf_counter() - t0,
                               spikes=backend.stats.spikes - spikes0,
                               requests=backend.stats.requests - req0)
            t0_us, e0_j, _ = before
            t1_us, e1_j, _ = after
            if t0_us is not None and t1_us is not None and e0_j is not None \
                    and e1_j is not None:
                res.virtual_us = float(t1_us - t0_us)
                res.energy_j = float(e1_j - e0_j)
            if baud:
                res.wire_us = wire_seconds(after[2] - before[2], baud) * 1e6
        results.append(res)
        if on_launch is not None:
            on_launch(res)
        bar.advance(1, f"launch {res.launch}: {res.steps} steps")
    fp = weights_fingerprint(w, grid)
    stats = backend.stats.to_dict() if backend is not None else {}
    if results and windows and all(_interleaving(b, interleave, backend) for b in boards):
        stats["interleaved"] = True             # the UART overlapped the board's work
    if isinstance(backend, GroupMotorNeurons):
        stats["chips"] = len(backend.chips)
        stats["decisions_per_chip"] = list(backend.decisions_per_chip)
    return ScenarioResult(scenario, set_index, seed, results, fp,
                          mode=hw_mode if hw else None, read_stats=stats)


def _interleaving(client: BoardClient | None, interleave: bool | None,
                  backend: OnBoardMotorNeurons | GroupMotorNeurons) -> bool:
    """Whether the on-board launches run interleaved (see :func:`run_scenario`): the board
    takes a request while it works (PIPELINE) and its windows read with the lean plan (their
    noise keyed by the window: a window reads alike whatever ran before it; the standard reads
    draw from the chip's running noise, as the batch mode, so interleaving would change them)."""
    info = getattr(client, "info", None)
    has = bool(info is not None and info.has(Capability.PIPELINE))
    if interleave and not has:
        raise UserError(f"the board on {getattr(client, 'name', '?')} cannot take a request "
                        "while it runs one (no PIPELINE capability: older firmware); run the "
                        "launches one after another")
    if interleave and not backend.conversions:
        raise UserError("interleaved launches need the lean read plan (conversions > 0): the "
                        "standard reads would take other noise than one after another")
    return has and bool(backend.conversions) if interleave is None else bool(interleave)


def _interleaved(backend: OnBoardMotorNeurons | GroupMotorNeurons, boards: list[BoardClient],
                 env, cfg: SnanConfig,
                 start: int, goal: int, seed: int, set_index: int, launches: int,
                 baud: int | None, on_launch: Callable[[LaunchResult], None] | None,
                 bar) -> list[LaunchResult]:
    """The launches of a scenario two at a time on the board (:func:`run_interleaved`), in
    launch order; the board clock, UART bytes and energy over all of them shared by decisions.
    Each launch goes to ``on_launch`` as it ends, in launch order (its shares of time, energy
    and wire are filled in once the last one has ended)."""
    done: dict[int, LaunchResult] = {}
    sent: list[int] = []                   # launches handed to on_launch
    before = _boards_snapshot(boards)

    def trials():
        for launch in range(launches):
            trial = set_index * TRIAL_STRIDE + launch
            nbr, move, s0, goals, key = trial_setup(env, cfg, start, goal, seed=seed,
                                                    trial=trial)
            yield launch, WindowTrial(cfg, nbr, move, s0, goals, key, backend)

    def finished(launch: int, r: TrialResult, wall_s: float) -> None:
        done[launch] = LaunchResult(launch, set_index * TRIAL_STRIDE + launch, r.steps,
                                    r.success, [int(c) for c in r.path], r.steps, wall_s)
        bar.advance(1, f"launch {launch}: {r.steps} steps")
        while on_launch is not None and len(sent) in done:    # handed on in launch order
            on_launch(done[len(sent)])                         # as they end (the board's time
            sent.append(len(sent))                             # shares come after the last)

    spikes0, req0 = backend.stats.spikes, backend.stats.requests
    for board in boards:
        board.pipelined = True
    try:
        run_interleaved(backend, trials(), finished)
    finally:
        for board in boards:
            board.pipelined = False
    after = _boards_snapshot(boards)
    results = [done[k] for k in range(launches)]
    decisions = sum(r.decisions for r in results) or 1
    for r in results:
        share = r.decisions / decisions
        r.spikes = round((backend.stats.spikes - spikes0) * share)
        r.requests = r.decisions
        if before[0] is not None and after[0] is not None and before[1] is not None \
                and after[1] is not None:
            r.virtual_us = (after[0] - before[0]) * share
            r.energy_j = (after[1] - before[1]) * share
        if baud:
            r.wire_us = wire_seconds(after[2] - before[2], baud) * 1e6 * share
    assert backend.stats.requests - req0 == decisions
    return results


def _boards_snapshot(clients: list[BoardClient]) -> tuple[int | None, float | None, int]:
    """:func:`_board_snapshot` summed over ``clients`` (one board, or the chips of a group):
    time and energy None when any board has no CLOCK."""
    shots = [_board_snapshot(c) for c in clients]
    t = None if any(s[0] is None for s in shots) else sum(int(s[0] or 0) for s in shots)
    e = None if any(s[1] is None for s in shots) else sum(float(s[1] or 0.0) for s in shots)
    return t, e, sum(s[2] for s in shots)


def _board_snapshot(client: BoardClient) -> tuple[int | None, float | None, int]:
    """(board time us, array energy J, host link bytes in + out); time and energy are None
    without CLOCK (legacy protocol), the bytes are always counted.

    The CLOCK round trip itself is inside the next snapshot's interval; its bytes are counted
    in the link bytes, so the UART share is subtracted correctly."""
    counters = client.counters_dict() if hasattr(client, "counters_dict") else {}
    try:
        c = client.clock()
    except (UnsupportedError, AttributeError):
        return None, None, _link_bytes(counters)
    counters = client.counters_dict() if hasattr(client, "counters_dict") else {}
    return int(c.time_us), float(c.energy_j), _link_bytes(counters)


def _link_bytes(counters: dict[str, int]) -> int:
    return int(counters.get("bytes_in", 0)) + int(counters.get("bytes_out", 0))
