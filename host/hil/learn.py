"""Route learning with the weights on a device: three arms on paired seeds (``snan-hil learn``,
docs/learning.md).

Protocol (the project's Fig. 7 protocol, :mod:`snan_hil.host.experiments.route`, on the HIL
task's grid, start and goal): per session fresh random weights; test 0 (astrocytes off, weights
fixed); then ``cycles`` times one training trial (astrocytes on, STDP ``trial_end``: the
trial's changes are applied at its end) and one test. Session ``k`` uses the random streams of
:func:`~snan_hil.host.experiments.route.session_seed` ``(seed, k)`` — its trial ``j`` (test
``c``: ``j = 2c``, training ``c``: ``j = 2c - 1``) the streams of
:func:`snan_hil.host.rng.trial_keys` ``(session_seed, j)``, its initial weights those of trial
0 — in every arm, so the arms see the same initial weights, input spikes and tie-breaks and
differ only by where the weights live:

* ``software``: the agent's weights in memory (today's learning, the trial kernel);
* ``device``: :class:`~snan_hil.host.hil.learning.DeviceModelSynapses`, the fitted model's
  quantised, noisy, asymmetric steps;
* ``chip``: the crossbar behind the board client; a session starts with the two-stage
  write-and-verify of its initial weights (:func:`~snan_hil.calibration.programmer.
  program_weights`), the network reads the synapses from the chip — by default the on-board
  decision window where the board has it (DECISION_WINDOW: the board reads the synapses, runs
  the motor neurons and answers their spike steps, the host's STDP pairs them with the input
  spikes it drew), else SPIKE_BATCH, or single-cell reads over the legacy protocol (``mode``,
  :mod:`snan_hil.host.hil.synapses`) — and every STDP update becomes WRITE_PULSEs
  (:class:`~snan_hil.host.hil.learning.PulsePlanner`), open loop unless ``refresh_every``.

The chip arm's pulses go through :class:`ChipPulser`: each pulse is written to the session's
pulse journal before it is sent and marked done when its reply is in (line-buffered, flushed:
a kill of the process loses nothing written), counted in the pulse ledger (per cycle, SET and
RESET, per cell) and handed to the history recorder. The checkpoint (:class:`~snan_hil.host.
checkpoint.RunFolder`) commits the plan of a cycle before its first pulse and the cycle when
its test is done; a resumed run takes the finished units from it, and for a cycle whose plan
was committed but not its end it sends only the pulses the journal does not mark done — a pulse
marked sent but not done (the kill came between the two) is never sent again: its cell is read
and planned anew. A pulse is never applied twice.

Several boards (``learn --boards --reassign``, docs/multiboard.md): a session whose board was
lost moves to another board (``ChipContext.board``). It goes on from its last committed cycle:
the move is committed (unit ``chip-s<k>-owner``), the lost board's journal lines of the cycle
it did not commit become a ledger row on the lost board (those pulses happened on its chip;
never sent again), the new chip is reprogrammed to the session's intended weights after that
cycle, the planner restarts from its reads, and the unfinished cycle runs again from its
training trial. Each holder of a session writes its own journal, so a line of the lost chip is
never taken as done on the new one.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from snan_hil.board.session import BoardSession
from snan_hil.calibration.board_io import BoardCellIO, BoardLimits, PulseLedger
from snan_hil.calibration.layout import Layout
from snan_hil.calibration.observer import CellObserver, Observers
from snan_hil.calibration.programmer import ProgramConfig, program_weights
from snan_hil.calibration.wv import PulseNotApplied
from snan_hil.calibration.weights_io import compact_to_dense
from snan_hil.common.errors import UserError
from snan_hil.common.polarity import Polarity
from snan_hil.common.progress import ProgressCallback, track
from snan_hil.crossbar_model.fitted import DeviceModel, LearningPulse
from snan_hil.host.agent import run_trial, synapse_tables
from snan_hil.host.grid import GridWorld
from snan_hil.host.checkpoint import RunFolder
from snan_hil.host.config import SnanConfig
from snan_hil.host.experiments.route import RouteProtocol, configs, session_seed
from snan_hil.host.hil.learning import (DeviceModelSynapses, Key, PulseOrder, PulsePlanner,
                                        chip_backend, synapse_index)
from snan_hil.host.hil.synapses import check_mode, make_synapses
from snan_hil.host.intervals import interval_fields
from snan_hil.host.rng import trial_keys
from snan_hil.host.state import initial_weights
from snan_hil.protocol.client import BoardClient
from snan_hil.protocol.errors import UnsupportedError

__all__ = ["ARMS", "LearnConfig", "ChipPulser", "PulseJournal", "run_learning", "curves",
           "PAPER_FIG7", "LEARN_STAGE", "RECOVERED_STAGE", "journal_pulses"]

log = logging.getLogger(__name__)

ARMS = ("software", "device", "chip")
#: the paper's Fig. 7 (section 3.5): size -> (median cycle 0, median cycle 20,
#: success cycle 0, success cycle 20)
PAPER_FIG7 = {3: (10.0, 4.0, 0.580, 0.978), 5: (73.0, 9.0, 0.446, 0.955),
              10: (389.0, 38.0, 0.404, 0.990)}


@dataclass(frozen=True)
class LearnConfig:
    """One learning run: sessions x cycles of each arm (see module doc)."""

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

    def __post_init__(self) -> None:
        bad = [a for a in self.arms if a not in ARMS]
        if bad or not self.arms:
            raise UserError(f"--arms: unknown {bad[0] if bad else '(none)'}; use "
                            + ", ".join(ARMS))
        if not 1 <= self.sessions <= 10_000:
            raise UserError(f"--sessions must be 1..10000, got {self.sessions}")
        if not 1 <= self.cycles <= 1000:
            raise UserError(f"--cycles must be 1..1000, got {self.cycles}")
        if self.refresh_every < 0:
            raise UserError(f"--refresh-every must be >= 0, got {self.refresh_every}")

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["arms"] = list(self.arms)
        return d


# ---- the pulse journal ------------------------------------------------------------------------
class PulseJournal:
    """Append-only JSON lines of the chip arm's pulses: ``{"c": cycle, "o": order, "n": pulse,
    "s": "sent" | "done" | "lost", "cell": [row, col], "p": "SET" | "RESET"}``; each line
    written and flushed before (sent) and after (done / lost: verifiably not applied) its
    WRITE_PULSE. ``cycle`` is the learning cycle, plus 10000 x epoch for the pulses planned
    anew inside a resumed cycle."""

    def __init__(self, path: Path, board: int | None = None) -> None:
        self.path = path
        self.board = board
        """The board whose chip the pulses go to (several boards: each line carries it as
        ``"b"``)."""
        self._fh: Any = None

    def entries(self) -> dict[tuple[int, int, int], dict[str, Any]]:
        """(cycle, order, pulse) -> its last line; a torn last line is ignored."""
        out: dict[tuple[int, int, int], dict[str, Any]] = {}
        try:
            text = self.path.read_text(encoding="utf-8")
        except FileNotFoundError:
            return out
        for line in text.splitlines():
            try:
                d = json.loads(line)
                out[(int(d["c"]), int(d["o"]), int(d["n"]))] = d
            except (ValueError, KeyError, TypeError):
                continue
        return out

    def done(self) -> list[tuple[tuple[int, int], Polarity]]:
        """The pulses marked done, in the order they were applied: [((row, col), polarity)]."""
        try:
            text = self.path.read_text(encoding="utf-8")
        except FileNotFoundError:
            return []
        out = []
        for line in text.splitlines():
            try:
                d = json.loads(line)
                if d["s"] == "done":
                    out.append(((int(d["cell"][0]), int(d["cell"][1])), Polarity[d["p"]]))
            except (ValueError, KeyError, TypeError, IndexError):
                continue
        return out

    def read(self) -> dict[tuple[int, int, int], str]:
        """(cycle, order, pulse) -> last state."""
        return {k: str(d["s"]) for k, d in self.entries().items()}

    def write(self, cycle: int, order: int, n: int, state: str, cell: tuple[int, int] = (-1, -1),
              polarity: Polarity = Polarity.SET) -> None:
        if self._fh is None:
            self._fh = open(self.path, "a", encoding="utf-8")   # noqa: SIM115 - kept open
        line = {"c": cycle, "o": order, "n": n, "s": state, "cell": list(cell),
                "p": polarity.name}
        if self.board is not None:
            line["b"] = self.board
        self._fh.write(json.dumps(line) + "\n")
        self._fh.flush()

    def sync(self) -> None:
        if self._fh is not None:
            os.fsync(self._fh.fileno())

    def close(self) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None


@dataclass
class Ledger:
    """The chip arm's pulses: per (session, cycle, stage) SET / RESET counts and energy, per
    cell counts (wear)."""

    rows: list[dict[str, Any]] = field(default_factory=list)
    per_cell: dict[str, int] = field(default_factory=dict)
    uncertain: int = 0
    """Pulses sent when a run was stopped whose fate is unknown (never resent; not in
    :attr:`total`)."""

    def add(self, session: int, cycle: int, stage: str, pulses: Sequence[Any],
            energy_j: float | None, estimate_j: float,
            board: int | None = None) -> dict[str, Any]:
        """One row; ``board`` (several boards): the board whose chip the pulses went to (the
        row gets ``board``, the cells' keys ``board-<i>:row,col``), so a session that moved
        between boards keeps each board's pulses on that board."""
        row = {"session": session, "cycle": cycle, "stage": stage,
               "set": sum(1 for p in pulses if p.polarity == Polarity.SET),
               "reset": sum(1 for p in pulses if p.polarity == Polarity.RESET),
               "energy_j": energy_j, "energy_estimate_j": estimate_j}
        if board is not None:
            row["board"] = int(board)
        self.rows.append(row)
        prefix = "" if board is None else f"board-{int(board)}:"
        for p in pulses:
            key = f"{prefix}{p.row},{p.col}"
            self.per_cell[key] = self.per_cell.get(key, 0) + 1
        return row

    @property
    def total(self) -> int:
        return sum(r["set"] + r["reset"] for r in self.rows)

    def to_dict(self) -> dict[str, Any]:
        return {"rows": self.rows, "per_cell": self.per_cell, "total": self.total,
                "uncertain": self.uncertain}

    def merge(self, d: dict[str, Any], board: int) -> None:
        """Add the ledger of one chip session run on board ``board`` (several boards): its
        rows (with ``board`` where a row names none: a row of a session that moved keeps the
        board it names), its cells' counts (keys ``board-<i>:row,col``: each chip wears on
        its own), its uncertain pulses."""
        self.rows += [{"board": board, **r} for r in d.get("rows", [])]
        for key, n in d.get("per_cell", {}).items():
            mine = key if key.startswith("board-") else f"board-{board}:{key}"
            self.per_cell[mine] = self.per_cell.get(mine, 0) + int(n)
        self.uncertain += int(d.get("uncertain", 0))

    def restore(self, d: dict[str, Any]) -> None:
        """Take the ledger of a checkpoint (the state after its unit)."""
        self.rows[:] = list(d.get("rows", []))
        self.per_cell = dict(d.get("per_cell", {}))
        self.uncertain = int(d.get("uncertain", 0))


def _energy_now(client: BoardClient) -> float | None:
    try:
        return float(client.clock().energy_j)
    except (UnsupportedError, AttributeError):
        return None


class ChipPulser:
    """Applies the chip arm's pulse orders (module doc): journal, ledger, observer."""

    def __init__(self, client: BoardClient, layout: Layout, limits: BoardLimits,
                 ledger: PulseLedger, pulse: LearningPulse, journal: PulseJournal,
                 planner: PulsePlanner, observer: CellObserver | None) -> None:
        self.client, self.layout, self.limits, self.ledger = client, layout, limits, ledger
        self.pulse, self.journal, self.planner, self.observer = pulse, journal, planner, observer
        self.uncertain = 0
        """Pulses sent when a run was stopped and not known to have run (never resent)."""
        self._entries: dict[tuple[int, int, int], dict[str, Any]] = {}

    def apply(self, orders: Sequence[PulseOrder], cycle: int,
              done: dict[tuple[int, int, int], str] | None = None) -> list[Any]:
        """Send ``orders`` (of ``cycle``); ``done``: the journal of a resumed cycle (pulses it
        marks done are not sent again and are counted as applied, lost ones as not applied; a
        pulse marked only sent ends its order: it may or may not have run, so it is counted in
        :attr:`uncertain`, never sent again, and the cell is read and planned anew). Returns
        the pulses of the orders that ran (events with row, col, polarity, ...)."""
        done = done or {}
        events: list[Any] = []
        replan: list[Key] = []
        chain = self.layout.chain
        wm = self.layout.weight_map
        for i, o in enumerate(orders):
            io = BoardCellIO(self.client, chain, o.row, o.col, self.limits, self.ledger,
                             self.pulse.width_us)
            io.stage = LEARN_STAGE
            w_before = self.planner.w_est[o.key] - sum(o.steps)
            io.last_g = float(wm.conductance(max(w_before, 0.0)))
            amp = self.pulse.amplitude(o.polarity)
            try:
                for n, s in enumerate(o.steps):
                    state = done.get((cycle, i, n))
                    if state == "done":          # applied before the run was stopped
                        events.append(_Counted(o.row, o.col, o.polarity))
                        continue
                    if state == "lost":
                        self.planner.not_applied(o.key, [s])
                        continue
                    if state == "sent":          # stopped between send and reply
                        self.uncertain += 1
                        self.planner.not_applied(o.key, o.steps[n:])
                        replan.append(o.key)
                        break
                    cell = (o.row, o.col)
                    self.journal.write(cycle, i, n, "sent", cell, o.polarity)
                    try:
                        io.pulse(o.polarity, amp)
                    except PulseNotApplied:
                        self.journal.write(cycle, i, n, "lost", cell, o.polarity)
                        self.planner.not_applied(o.key, [s])
                        continue
                    self.journal.write(cycle, i, n, "done", cell, o.polarity)
            finally:
                events += io.applied
                if self.observer is not None and io.applied:
                    self.observer.on_pulses(io.applied)
        epoch = 1
        if done and cycle < 10_000:
            # pulses planned anew inside an earlier resume of this cycle: done ones count as
            # applied, sent-only ones as uncertain (never resent)
            for (c, o_, n_), state in done.items():
                if c % 10_000 != cycle or c < 10_000:
                    continue
                epoch = max(epoch, c // 10_000 + 1)
                d = self._entries.get((c, o_, n_), {})
                cell, pol = d.get("cell", [-1, -1]), Polarity[d.get("p", "SET")]
                if state == "done":
                    events.append(_Counted(int(cell[0]), int(cell[1]), pol))
                elif state == "sent":
                    self.uncertain += 1
        for key in replan:                          # the truth of an uncertain cell: a read
            row, col = self.planner.cells[key]
            self.planner.observe(key, read_weight(self.client, self.layout, row, col))
            events += self.apply(self.planner.plan([key]), cycle + 10_000 * epoch)
        return events


def read_weight(client: BoardClient, layout: Layout, row: int, col: int,
                reads: int = 3) -> float:
    """The weight of cell (row, col) from ``reads`` cell reads (mean conductance)."""
    chain = layout.chain
    code = chain.read_code
    g = np.mean([chain.cell_conductance(client.read_cell(row, col, code), code)
                 for _ in range(reads)])
    return float(layout.weight_map.weight(g, clip=False))


def _estimate_energy(events: Sequence[Any], r_switch_ohm: float) -> float:
    """Host estimate of the pulses' array energy (J): V^2 / (1/G + R_sw) x width, G the
    conductance read before the pulse (after it where none was read)."""
    total = 0.0
    for e in events:
        g = e.g_before_s if e.g_before_s else e.g_after_s
        if g and g > 0:
            total += e.amplitude_v ** 2 / (1.0 / g + r_switch_ohm) * e.width_us * 1e-6
    return total


# ---- one session of one arm ---------------------------------------------------------------
@dataclass
class SessionResult:
    """Tests 0..cycles and trainings 1..cycles of one session of one arm."""

    test_steps: list[int] = field(default_factory=list)
    test_success: list[bool] = field(default_factory=list)
    train_steps: list[int] = field(default_factory=list)
    train_success: list[bool] = field(default_factory=list)
    pulses: list[int] = field(default_factory=list)       #: per cycle (model/chip arms)
    weights: list[float] | None = None                    #: final weights, synapse order

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


class _Task:
    """What every arm of one run shares: configs, environment, tables, task."""

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
        _k, _t, w_seed = trial_keys(self.seed(session), 0)
        return initial_weights(self.cfg, self.nbr, np.random.default_rng(w_seed))

    def trial(self, session: int, j: int, train: bool, *, weights=None, backend=None):
        return run_trial(self.env, self.train_cfg if train else self.test_cfg, self.lc.start,
                         self.lc.goal, seed=self.seed(session), trial=j, weights=weights,
                         backend=backend)


def _software_session(task: _Task, k: int, tick: Callable[[str], None]) -> SessionResult:
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


def _planner(task: _Task, model: DeviceModel, weight_map, cells: dict[Key, tuple[int, int]]
             ) -> PulsePlanner:
    d = task.cfg.stdp
    return PulsePlanner(model, weight_map, cells, d.w_min, d.w_max, per_cell=task.lc.per_cell)


def _device_session(task: _Task, k: int, model: DeviceModel, weight_map,
                    tick: Callable[[str], None]) -> SessionResult:
    out = SessionResult()
    w0 = task.initial(k)
    cells = {key: (j, -1) for j, key in enumerate(task.keys)}
    planner = _planner(task, model, weight_map, cells)
    rng = np.random.default_rng(np.random.SeedSequence([task.seed(k), 0x64657669]))  # "devi"
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
            out.train_steps.append(r.steps)
            out.train_success.append(r.success)
            tick(f"device session {k} cycle {c}")
        r = task.trial(k, 2 * c, False, backend=dev)
        out.test_steps.append(r.steps)
        out.test_success.append(r.success)
    tw = dev.true_weights()
    out.weights = [tw[key] for key in task.keys]
    return out


@dataclass
class ChipContext:
    """What the chip arm needs of the board: its session (the client, already retrying safe
    requests; the layout file, ``session.files.layout``), the weight map and programming
    settings, the recorder."""

    session: BoardSession
    program_config: ProgramConfig
    observer: CellObserver | None = None
    board: int | None = None
    """Several boards: the board's number in the run (its ledger rows and journal lines
    name it; a session whose checkpoint another board holds moves here)."""

    @property
    def layout_path(self) -> Path:
        """The board's layout file (the session's; set by the opener)."""
        path = self.session.files.layout
        if path is None:
            raise ValueError("the chip arm's session has no layout file")
        return path


def _journal_name(name: str, epoch: int, board: int | None) -> str:
    """The pulse journal of session ``name`` while board ``board`` holds it for the
    ``epoch``-th time it moved (0: the board it started on, the file of a one-board run):
    one journal per holder, so a line of a lost board's chip is never read as done on the
    chip of the board it moved to."""
    if epoch == 0:
        return f"{name}.pulses.jsonl"
    return f"{name}.move-{epoch}.board-{board}.pulses.jsonl"


def _program(task: _Task, k: int, ctx: ChipContext, w: np.ndarray, ledger_rows: Ledger, *,
             cycle: int, stage: str, skip_screen: bool) -> dict[str, Any]:
    """Write-and-verify the weights ``w`` (float[n_cells, 4]) into the chip of ``ctx``
    (:func:`~snan_hil.calibration.programmer.program_weights`, the board's own layout and
    weight map); its pulses one ledger row (``cycle``, ``stage``, the board of ``ctx``);
    the programming summary. ``skip_screen``: the screen and read-chain calibration of the
    board's earlier sessions hold (where its layout exists)."""
    client = ctx.session.client
    grid = (task.cfg.grid.rows, task.cfg.grid.cols)
    dense = compact_to_dense(np.where(task.nbr >= 0, w, 0.0), *grid)
    t0 = _energy_now(client)
    collected = _Collector()
    pcfg = ctx.program_config
    if skip_screen and ctx.layout_path.is_file():
        # the screen and the read-chain calibration of session 0 hold for the others
        pcfg = dataclasses.replace(pcfg, screen=False, calibrate=False)
    # the layout is the session's; no program report (the learn run's files are its own)
    board = ctx.session.with_files(report=None, previous_report=None)
    res = program_weights(board, dense, {"grid": list(grid), "session": k}, config=pcfg,
                          observer=Observers(ctx.observer, collected))
    t1 = _energy_now(client)
    rep = res.report["summary"]
    ledger_rows.add(k, cycle, stage, collected.events,
                    None if t0 is None or t1 is None else t1 - t0,
                    _estimate_energy(collected.events, res.layout.chain.r_switch_ohm),
                    board=ctx.board)
    return {x: rep.get(x) for x in ("ok", "failed", "pulses_total", "median_abs_rel_error",
                                    "host_pulses", "firmware_pulses")}


def _take_over(k: int, units: _SessionUnits, owner: dict[str, Any], me: int, c_last: int,
               ledger_rows: Ledger) -> dict[str, Any]:
    """Session ``k`` moves from the board of ``owner`` (lost) to board ``me`` after its
    last committed cycle ``c_last``: the pulses the lost board's journal marks done in the
    cycle it did not commit happened on its chip — one ledger row on that board (``stage``
    ``"learn (board lost)"``; its pulses marked only sent: ``uncertain``), never sent again
    here. The new holder's record (not programmed yet: the caller reprograms)."""
    old, old_epoch = int(owner["board"]), int(owner["epoch"])
    applied: list[_Counted] = []
    sent = 0
    if units.folder is not None:
        lines = PulseJournal(units.folder.path(_journal_name(units.name, old_epoch,
                                                             old))).entries()
        for (c, _o, _n), d in sorted(lines.items()):
            if c % 10_000 <= c_last:
                continue                # a committed cycle's pulses: in its ledger row
            if d.get("s") == "done":
                cell = d.get("cell", [-1, -1])
                applied.append(_Counted(int(cell[0]), int(cell[1]),
                                        Polarity[d.get("p", "SET")]))
            elif d.get("s") == "sent":
                sent += 1
    if applied or sent:
        row = ledger_rows.add(k, c_last + 1, "learn (board lost)", applied, None, 0.0,
                              board=old)
        row["uncertain"] = sent
        ledger_rows.uncertain += sent
    log.warning("chip session %s moves from board %s to board %s after cycle %s (%d pulses "
                "of the lost board's unfinished cycle kept on it, %d uncertain)", k, old, me,
                c_last, len(applied), sent)
    moves = [*owner.get("moves", []), {"from": old, "to": me, "at_cycle": c_last + 1}]
    return {"board": me, "epoch": old_epoch + 1, "moves": moves, "programmed": False,
            "base_cycle": c_last, "ledger": ledger_rows.to_dict()}


class _SessionUnits:
    """The checkpoint units of chip session ``name`` (``<name>-<suffix>``; none without a
    folder). A session that moved between boards: ``epoch`` (how often it moved) — a cycle's
    plan committed in another epoch was planned on a lost board's chip and reads as not
    there — and the move's own state (the new chip's estimates, the ledger with the
    reprogramming) read in place of the last committed cycle's (:meth:`go_on_from`)."""

    def __init__(self, folder: RunFolder | None, name: str) -> None:
        self.folder, self.name = folder, name
        self.epoch = 0
        self._instead: tuple[str, dict[str, Any]] | None = None

    def done(self, suffix: str) -> dict[str, Any] | None:
        if self.folder is None:
            return None
        data = self.folder.done(f"{self.name}-{suffix}")
        if data is None:
            return None
        if suffix.endswith("-plan") and int(data.get("epoch", 0)) != self.epoch:
            return None
        if self._instead is not None and suffix == self._instead[0]:
            return {**data, **self._instead[1]}
        return data

    def commit(self, suffix: str, data: dict[str, Any]) -> None:
        if self.folder is not None:
            self.folder.commit(f"{self.name}-{suffix}", data)

    def last_cycle(self, cycles: int) -> int:
        """The last cycle committed (-1: none, the session is programmed at most)."""
        c = -1
        while c < cycles and self.done(f"c{c + 1}") is not None:
            c += 1
        return c

    def go_on_from(self, owner: dict[str, Any]) -> None:
        """After a move (``owner``: the new holder, reprogrammed), the state to go on from is
        the move's, in place of that of the cycle it moved after."""
        if int(owner["epoch"]) > 0 and owner.get("programmed") and owner["base_cycle"] >= 0:
            self._instead = (f"c{owner['base_cycle']}",
                             {"planner": owner["planner"], "ledger": owner["ledger"]})


def _hold(task: _Task, k: int, ctx: ChipContext, units: _SessionUnits,
          prog: dict[str, Any], start: dict[Key, float], ledger_rows: Ledger
          ) -> tuple[dict[str, Any], dict[Key, float] | None]:
    """Several boards: which board holds session ``k`` (the ``owner`` unit; else the board
    that programmed it). When it is another board than this one (it was lost, the session
    moved here), the move is committed (:func:`_take_over`) and this board's chip is
    reprogrammed to the session's intended weights after its last committed cycle (the
    planner state of that cycle; the initial weights when none). Returns the holder's record
    and, when reprogrammed here, the intended weights (the caller starts the planner on the
    new chip's reads and commits the holder as programmed)."""
    me = ctx.board
    c_last = units.last_cycle(task.lc.cycles)
    owner = units.done("owner") or {"board": prog.get("board"), "epoch": 0, "moves": [],
                                    "programmed": True}
    if me is not None and owner.get("board") is not None and owner["board"] != me:
        owner = _take_over(k, units, owner, me, c_last, ledger_rows)
        units.commit("owner", owner)
    units.epoch = int(owner["epoch"])
    if owner["programmed"]:
        if units.epoch > 0 and owner.get("base_cycle") == c_last:
            units.go_on_from(owner)             # moved, reprogrammed, no cycle since
            ledger_rows.restore(owner["ledger"])
        return owner, None
    ledger_rows.restore(owner["ledger"])
    base = units.done(f"c{c_last}") if c_last >= 0 else None
    intended = dict(start) if base is None else {
        (int(key[0]), int(key[1])): float(w)
        for key, w in zip(base["planner"]["keys"], base["planner"]["w_int"])}
    w_at = np.zeros(task.nbr.shape)
    for (i, d), w in intended.items():
        w_at[i, d] = w
    owner["program"] = _program(task, k, ctx, w_at, ledger_rows, cycle=c_last + 1,
                                stage="reprogram", skip_screen=True)
    log.info("chip session %s: board %s reprogrammed to the intended weights after cycle %s "
             "(moved from board %s)", k, me, c_last, owner["moves"][-1]["from"])
    return owner, intended


def _chip_session(task: _Task, k: int, model: DeviceModel, ctx: ChipContext,
                  folder: RunFolder | None, tick: Callable[[str], None],
                  ledger_rows: Ledger, counters: dict[str, Any]) -> SessionResult:
    client = ctx.session.client                 # reads resent after a lost reply
    info = ctx.session.info
    name = f"chip-s{k}"

    units = _SessionUnits(folder, name)
    unit, commit = units.done, units.commit
    w0 = task.initial(k)
    start = {key: float(w0[key]) for key in task.keys}
    prog = unit("program")
    if prog is None:
        summary = _program(task, k, ctx, w0, ledger_rows, cycle=0, stage="program",
                           skip_screen=k > 0)
        prog = {"summary": summary, "ledger": ledger_rows.to_dict(), "board": ctx.board}
        commit("program", prog)
    else:
        ledger_rows.restore(prog["ledger"])
    owner, intended = _hold(task, k, ctx, units, prog, start, ledger_rows)
    layout = Layout.load(ctx.layout_path)
    cells = {}
    for s in layout.synapses:
        d = np.nonzero(task.nbr[s.pre] == s.post)[0]
        if d.size:
            cells[(s.pre, int(d[0]))] = (s.row, s.col)
    planner = _planner(task, model, layout.weight_map, cells)
    if intended is not None:                    # reprogrammed here: estimates from its reads
        planner.start(intended, {key: read_weight(client, layout, *cells[key])
                                 for key in task.keys})
        owner.update(programmed=True, planner=planner.state(), ledger=ledger_rows.to_dict())
        commit("owner", owner)
        units.go_on_from(owner)
    counters["moves"] = list(owner.get("moves", []))
    epoch, me = units.epoch, ctx.board
    mode = check_mode(client, task.lc.mode, task.train_cfg)
    # on_board: the board runs the motor neurons (the model's LIF block, the same in the
    # training and the test config) and answers the motor spike steps of a training trial
    reader = make_synapses(client, layout, task.nbr, mode, task.train_cfg,
                           conversions=task.lc.conversions)
    backend = chip_backend(reader, planner, task.nbr)
    counters["mode"] = mode
    limits = BoardLimits.for_board(info, ctx.program_config.wv.v_max,
                                   ctx.program_config.compliance_margin)
    pulse_ledger = PulseLedger()
    pulse_ledger.rebaseline(client)
    journal = PulseJournal(folder.path(_journal_name(name, epoch, me)) if folder is not None
                           else Path(os.devnull), board=me)
    pulser = ChipPulser(client, layout, limits, pulse_ledger, task.lc.pulse, journal, planner,
                        ctx.observer)
    out = SessionResult()
    c0 = unit("c0")
    if c0 is None:
        planner.start(start, {key: read_weight(client, layout, *cells[key]) for key in task.keys})
        r = task.trial(k, 0, False, backend=backend)
        out.test_steps.append(r.steps)
        out.test_success.append(r.success)
        commit("c0", {"result": out.to_dict(), "planner": planner.state(),
                      "ledger": ledger_rows.to_dict()})
    else:
        out = SessionResult(**c0["result"])
        planner.restore(c0["planner"])
        ledger_rows.restore(c0["ledger"])
    last = c0 or {}
    for c in range(1, task.lc.cycles + 1):
        done = unit(f"c{c}")
        if done is not None:
            out = SessionResult(**done["result"])
            planner.restore(done["planner"])
            ledger_rows.restore(done["ledger"])
            last = done
            tick(f"chip session {k} cycle {c}: from the checkpoint")
            continue
        t_cycle = time.perf_counter()
        bytes0 = _bytes(client)
        read_bytes = read_decisions = 0     # the trials run here: their requests and replies
        plan = unit(f"c{c}-plan")           # None where planned on a lost board's chip
        if plan is None:
            if last.get("planner"):
                planner.restore(last["planner"])
            r = task.trial(k, 2 * c - 1, True, backend=backend)
            read_bytes += _bytes(client) - bytes0
            read_decisions += r.steps
            orders = planner.plan()
            plan = {"train": [r.steps, r.success], "planner": planner.state(),
                    "orders": [[list(o.key), o.row, o.col, o.polarity.name, list(o.steps)]
                               for o in orders], "epoch": epoch, "board": me}
            commit(f"c{c}-plan", plan)
            journaled: dict = {}
        else:
            planner.restore(plan["planner"])
            orders = [PulseOrder((int(o[0][0]), int(o[0][1])), int(o[1]), int(o[2]),
                                 Polarity[o[3]], tuple(float(x) for x in o[4]))
                      for o in plan["orders"]]
            pulser._entries = journal.entries()
            journaled = {k: str(d["s"]) for k, d in pulser._entries.items()}
        e0 = _energy_now(client)
        events = pulser.apply(orders, c, journaled)
        stage = "learn"
        if task.lc.refresh_every and c % task.lc.refresh_every == 0:
            for key in task.keys:
                planner.observe(key, read_weight(client, layout, *cells[key]))
            events += pulser.apply(planner.plan(), c + 20_000)
            stage = "learn+refresh"
        journal.sync()
        e1 = _energy_now(client)
        row = ledger_rows.add(k, c, stage, events,
                              None if e0 is None or e1 is None else e1 - e0,
                              _estimate_energy(events, layout.chain.r_switch_ohm), board=me)
        row["uncertain"] = pulser.uncertain
        ledger_rows.uncertain += pulser.uncertain
        pulser.uncertain = 0
        out.train_steps.append(int(plan["train"][0]))
        out.train_success.append(bool(plan["train"][1]))
        out.pulses.append(row["set"] + row["reset"])
        b_test = _bytes(client)
        r = task.trial(k, 2 * c, False, backend=backend)
        out.test_steps.append(r.steps)
        out.test_success.append(r.success)
        wire = _bytes(client) - bytes0
        read_bytes += _bytes(client) - b_test
        read_decisions += r.steps
        counters.setdefault("cycles", []).append(
            {"session": k, "cycle": c, "wall_s": time.perf_counter() - t_cycle,
             "wire_bytes": wire, "pulses": row["set"] + row["reset"],
             "decisions": int(plan["train"][0]) + r.steps, "mode": mode,
             "read_bytes": read_bytes, "read_decisions": read_decisions})
        last = {"result": out.to_dict(), "planner": planner.state(),
                "ledger": ledger_rows.to_dict()}
        commit(f"c{c}", last)
        tick(f"chip session {k} cycle {c}: {row['set']} SET / {row['reset']} RESET")
    journal.close()
    out.weights = [read_weight(client, layout, *cells[key]) for key in task.keys]
    counters["layout"] = layout
    counters["cells"] = cells
    return out


def run_chip_session(cfg: SnanConfig, lc: LearnConfig, model: DeviceModel, k: int,
                     ctx: ChipContext, folder: RunFolder | None) -> dict[str, Any]:
    """Chip session ``k`` of ``lc`` alone on the board of ``ctx``, as :func:`run_learning`
    runs it (its units committed to ``folder``; a resumed one carries on): the session's
    record for several boards (``result``: :class:`SessionResult` dict, ``ledger``: its own
    :class:`Ledger` dict, ``cycles``: its link figures)."""
    ledger = Ledger()
    counters: dict[str, Any] = {}
    r = _chip_session(_Task(cfg, lc), k, model, ctx, folder, lambda _detail: None, ledger,
                      counters)
    return {"result": r.to_dict(), "ledger": ledger.to_dict(),
            "cycles": counters.get("cycles", []), "moves": counters.get("moves", [])}


ChipUnits = Callable[[SnanConfig, LearnConfig, DeviceModel, RunFolder | None],
                     Sequence[dict[str, Any]]]
"""Runs the chip sessions 0..S-1 elsewhere (several boards, :mod:`snan_hil.lab.boards`):
``(cfg, lc, model, folder)`` -> each session's :func:`run_chip_session` record, in session
order, with ``unit`` (the board that ran it)."""


LEARN_STAGE = "learn"
RECOVERED_STAGE = "learn-recovered"
"""History stage of a learning pulse recorded at ``--resume`` from the pulse journal: applied
(marked done) by a run that was killed before its recorder wrote it (:func:`journal_pulses`)."""


def journal_pulses(folder: RunFolder, sessions: int, pulse: LearningPulse) -> list[Any]:
    """Every learning pulse the chip arm's journals of ``folder`` mark done, in the order they
    were applied (session by session: one board runs them one after another), as pulse events
    of stage :data:`RECOVERED_STAGE` (conductances unknown: None)."""
    out: list[Any] = []
    for k in range(sessions):
        for (row, col), pol in PulseJournal(folder.path(f"chip-s{k}.pulses.jsonl")).done():
            out.append(_Counted(row, col, pol, pulse.amplitude(pol), pulse.width_us,
                                stage=RECOVERED_STAGE))
    return out


@dataclass(frozen=True)
class _Counted:
    """A pulse a resumed cycle's journal marks done (counted in the ledger as applied)."""

    row: int
    col: int
    polarity: Polarity
    amplitude_v: float = 0.0
    width_us: int = 0
    g_before_s: float | None = None
    g_after_s: float | None = None
    stage: str | None = None


class _Collector:
    """The pulses a programming run applied (an observer), for the ledger."""

    def __init__(self) -> None:
        self.events: list[Any] = []

    def on_pulses(self, events: Sequence[Any]) -> None:
        self.events.extend(events)

    def on_cell(self, event: Any) -> None:
        pass


def _bytes(client: BoardClient) -> int:
    try:
        c = client.counters_dict()
    except (AttributeError, UserError):
        return 0
    return int(c.get("bytes_in", 0)) + int(c.get("bytes_out", 0))


# ---- the run --------------------------------------------------------------------------------
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


def _units_arm(records: Sequence[dict[str, Any]], ledger: Ledger, counters: dict[str, Any],
               advance: Callable[[int, str], None], cycles: int) -> list[SessionResult]:
    """The chip arm's sessions as the units of several boards ran them (``records``, in
    session order): their results; their ledgers, link figures and boards added."""
    out = []
    for k, done in enumerate(records):
        out.append(SessionResult(**done["result"]))
        ledger.merge(done["ledger"], int(done["unit"]["board"]))
        counters.setdefault("cycles", []).extend(done["cycles"])
        counters.setdefault("units", {})[str(k)] = done["unit"]
        advance(cycles, f"chip session {k}: done on board {done['unit']['board']}")
    return out


def run_learning(cfg: SnanConfig, lc: LearnConfig, *, model: DeviceModel | None,
                 chip: Callable[[], ChipContext] | None = None,
                 folder: RunFolder | None = None,
                 progress: ProgressCallback | None = None,
                 chip_units: ChipUnits | None = None) -> dict[str, Any]:
    """Run the arms of ``lc`` (module doc); the results document (arms' sessions and
    curves, the chip arm's ledger and link figures). ``model``: the fitted device model (the
    device and chip arms need it); ``chip``: opens the chip arm's board context (called once;
    its session is closed by the caller); ``folder``: the checkpoint; ``chip_units``
    (instead of ``chip``): the chip sessions run as units on several boards, each on its own
    chip (the ledger's rows and cells then name the board; ``units``: session -> board)."""
    task = _Task(cfg, lc)
    if ("device" in lc.arms or "chip" in lc.arms) and model is None:
        raise UserError("the device and chip arms need a fitted device model: run "
                        "'snan-hil characterize' first (or give --model FILE)")
    per_arm_trials = lc.sessions * lc.cycles
    bar = track(progress, "learning", per_arm_trials * len(lc.arms))

    def tick(detail: str) -> None:
        bar.advance(1, detail)

    results: dict[str, list[SessionResult]] = {}
    ledger = Ledger()
    counters: dict[str, Any] = {}
    t0 = time.perf_counter()
    walls: dict[str, float] = {}
    from snan_hil.calibration.mapping import WeightMap
    for arm in lc.arms:
        ta = time.perf_counter()
        out: list[SessionResult] = []
        ctx = None
        if arm == "chip" and chip_units is not None:
            assert model is not None
            results[arm] = _units_arm(chip_units(cfg, lc, model, folder), ledger, counters,
                                      lambda n, text: bar.advance(n, text), lc.cycles)
            walls[arm] = time.perf_counter() - ta
            continue
        if arm == "chip":
            if chip is None:
                raise UserError("the chip arm needs a board (--port)")
            ctx = chip()
        wm = ctx.program_config.weight_map if ctx is not None else WeightMap()
        for k in range(lc.sessions):
            key = f"{arm}-s{k}"
            saved = folder.done(key) if folder is not None and arm != "chip" else None
            if saved is not None:
                out.append(SessionResult(**saved))
                bar.advance(lc.cycles, f"{arm} session {k}: from the checkpoint")
                continue
            if arm == "software":
                r = _software_session(task, k, tick)
            elif arm == "device":
                assert model is not None
                r = _device_session(task, k, model, wm, tick)
            else:
                assert model is not None and ctx is not None
                r = _chip_session(task, k, model, ctx, folder, tick, ledger, counters)
            out.append(r)
            if folder is not None and arm != "chip":
                folder.commit(key, r.to_dict())
        results[arm] = out
        walls[arm] = time.perf_counter() - ta
    doc: dict[str, Any] = {
        "task": {"grid": [cfg.grid.rows, cfg.grid.cols], "start": lc.start, "goal": lc.goal,
                 "step_limit": cfg.grid.max_steps},
        "config": lc.to_dict(), "model_config": cfg.to_dict(),
        "protocol": {"cycles": lc.cycles, "task": "fixed", "train_astro": True,
                     "test_astro": False, "stdp_mode": task.train_cfg.stdp.mode,
                     "target": cfg.stdp.target},
        "arms": {arm: {"sessions": [r.to_dict() for r in rs], "curves": curves(rs, lc.seed)}
                 for arm, rs in results.items()},
        "synapses": [list(k) for k in task.keys],
        "wall_s": time.perf_counter() - t0, "arm_wall_s": walls,
        "device_model": model.to_dict() if model is not None else None,
    }
    size = cfg.grid.rows if cfg.grid.rows == cfg.grid.cols else None
    if size in PAPER_FIG7:
        p = PAPER_FIG7[size]
        doc["paper"] = {"figure": "Fig. 7", "size": size,
                        "median": {"0": p[0], str(20): p[1]}, "success": {"0": p[2], "20": p[3]}}
    else:
        doc["paper"] = {"figure": "Fig. 7", "size": None,
                        "note": f"Fig. 7 has no {cfg.grid.rows}x{cfg.grid.cols} curve; its 3x3 "
                                "/ 5x5 / 10x10 values are shown beside",
                        "sizes": {str(s): v for s, v in PAPER_FIG7.items()}}
    if "chip" in results:
        doc["chip_mode"] = counters.get("mode")
        doc["ledger"] = ledger.to_dict()
        doc["link"] = counters.get("cycles", [])
        if counters.get("units") is not None:
            doc["units"] = counters["units"]
        doc["chip_layout"] = str(counters["layout"].board) if counters.get("layout") else None
        doc["_layout"] = counters.get("layout")
        doc["_cells"] = counters.get("cells")
    return doc
