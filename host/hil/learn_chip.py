"""The chip arm of ``snan-hil learn``: one learning session's units on the cell bench
(docs/learning.md sections 3 and 6).

A session ``k`` is cut per cycle (:class:`ChipArm`; the units of one session run in order on
one board):

* **cycle 0**: the two-stage write-and-verify of the session's initial weights (the
  programming library function, :func:`program_on_bench`), the planner's estimates read from
  the chip, test 0;
* **cycle c >= 1**: the training trial (its STDP updates go to the planner), the plan of pulses
  -- committed to the run's checkpoint (``ctx.store``) *before* the first pulse --, the
  pulses (:class:`CyclePulses`), the refresh every ``refresh_every`` cycles, test c; the last
  cycle reads the learnt weights.

Every pulse goes through the bench: written to the run's pulse journal before it is sent and
after its reply (``(run uid, n)`` names it), counted in the unit's ledger rows
(:class:`~snan_hil.host.hil.learn_ledger.UnitLedger`) and recorded in the chip's history as it
is applied. **A cycle that runs again** (a kill, Ctrl-C, a stop) learns from ``ctx.earlier``
(the journal's pulses of its earlier attempts) which of its planned pulses ran
(:func:`replay_plan`): a pulse marked done is counted and never sent again; one marked only
sent (the kill came between the request and its reply) is *uncertain* -- counted as such,
never sent again, and its cell is read and planned anew; a lost one was not applied. Pulses an
earlier attempt sent outside the plan (re-planned cells, a refresh) are counted the same way.
The programming pulses of an attempt of cycle 0 that was cut are one ledger row of their own
(``program (interrupted)``), so the ledger holds every pulse the history holds.

**Several boards** (a session that moved from a lost board, ``learn --boards --reassign``): a
unit whose previous unit ran on another board reprograms this board's chip to the session's
intended weights after that unit first (stage ``reprogram``; committed as ``<unit>-moved``), the
planner restarting from its reads; the lost board's pulses of the unit are one ledger row on
that board (``learn (board lost)``), never sent again here; a plan committed on the lost board
is planned afresh.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from snan_hil.calibration.layout import Layout
from snan_hil.calibration.programmer import ProgramConfig
from snan_hil.calibration.programmer import program_on_bench as program_bench
from snan_hil.calibration.weights_io import compact_to_dense
from snan_hil.calibration.wv import PulseNotApplied
from snan_hil.common.errors import UserError
from snan_hil.common.polarity import Polarity
from snan_hil.crossbar_model.fitted import DeviceModel, LearningPulse
from snan_hil.host.hil.learn_arms import (LearnTask, estimated_weights, intended_weights,
                                          make_planner)
from snan_hil.host.hil.learn_ledger import Counted, UnitLedger, estimate_energy
from snan_hil.host.hil.learning import Key, PulseOrder, PulsePlanner, chip_backend
from snan_hil.host.hil.synapses import make_synapses
from snan_hil.protocol.errors import UnsupportedError
from snan_hil.records.journal import JournalPulse

__all__ = ["ChipArm", "CyclePulses", "Replay", "replay_plan", "program_on_bench",
           "read_weight", "layout_cells", "LEARN_STAGE", "PROGRAM_STAGE", "REPROGRAM_STAGE"]

log = logging.getLogger(__name__)

LEARN_STAGE = "learn"
"""Stage of a learning pulse (journal and history)."""
PROGRAM_STAGE = "program"
"""Journal stage of a session's programming pulses (the history's: write-and-verify's "1" /
"2")."""
REPROGRAM_STAGE = "reprogram"
"""Journal stage of the programming of a session that moved to this board."""


# -- the programming (the one call to switch when programming is a job of its own) --------------

@dataclass
class Programmed:
    """A programming run's summary, its pulses (events, for the ledger), the array energy by
    the board's clock (J, None without CLOCK), the host's estimate (J), the layout written."""

    summary: dict[str, Any]
    events: list[Any]
    energy_j: float | None
    estimate_j: float
    layout: Layout


class _Collector:
    """The pulses a programming run applied (an observer), for the ledger."""

    def __init__(self) -> None:
        self.events: list[Any] = []

    def on_pulses(self, events: Sequence[Any]) -> None:
        self.events.extend(events)

    def on_cell(self, event: Any) -> None:
        pass


def program_on_bench(bench: Any, task: LearnTask, k: int, weights: np.ndarray,
                     cfg: ProgramConfig, *, stage: str, skip_screen: bool) -> Programmed:
    """Write-and-verify the weights ``weights`` (float[n_cells, 4], the agent's compact form)
    of session ``k`` into the board of ``bench`` (:func:`snan_hil.calibration.programmer.
    program_on_bench`: the board's own layout and weight map; no program report, the learn
    run's files are its own), every pulse journalled and recorded by the bench (stage "1" /
    "2" of write-and-verify) and collected for the ledger row ``stage``. ``skip_screen``: the
    screen and read-chain calibration of the board's earlier sessions hold (where its layout
    exists)."""
    grid = (task.cfg.grid.rows, task.cfg.grid.cols)
    dense = compact_to_dense(np.where(task.nbr >= 0, weights, 0.0), *grid)
    if skip_screen and bench.layout_path is not None and bench.layout_path.is_file():
        cfg = dataclasses.replace(cfg, screen=False, calibrate=False)
    collected = _Collector()
    e0 = energy_now(bench.client)
    res = program_bench(bench.with_observer(collected), dense,
                        {"grid": list(grid), "session": k}, config=cfg,
                        files=dataclasses.replace(bench.session.files, report=None,
                                                  previous_report=None))
    e1 = energy_now(bench.client)
    bench.forget_layout()
    rep = res.report["summary"]
    summary = {x: rep.get(x) for x in ("ok", "failed", "pulses_total", "median_abs_rel_error",
                                       "host_pulses", "firmware_pulses")}
    return Programmed(summary, collected.events, None if e0 is None or e1 is None else e1 - e0,
                      estimate_energy(collected.events, res.layout.chain.r_switch_ohm),
                      res.layout)


# -- reads, energy, bytes ------------------------------------------------------------------------

def layout_cells(layout: Layout, nbr: np.ndarray) -> dict[Key, tuple[int, int]]:
    """Synapse ``(pre, direction)`` -> the chip cell ``(row, col)`` that holds it in
    ``layout``; ``nbr``: the agent's neighbour table, int[n_cells, 4]."""
    cells: dict[Key, tuple[int, int]] = {}
    for s in layout.synapses:
        d = np.nonzero(nbr[s.pre] == s.post)[0]
        if d.size:
            cells[(s.pre, int(d[0]))] = (s.row, s.col)
    return cells


def read_weight(client: Any, layout: Layout, row: int, col: int, reads: int = 3) -> float:
    """The weight of cell (row, col) from ``reads`` cell reads (mean conductance)."""
    chain = layout.chain
    code = chain.read_code
    g = np.mean([chain.cell_conductance(client.read_cell(row, col, code), code)
                 for _ in range(reads)])
    return float(layout.weight_map.weight(g, clip=False))


def energy_now(client: Any) -> float | None:
    """The board's array energy counter (J; CLOCK), None without one."""
    try:
        return float(client.clock().energy_j)
    except (UnsupportedError, AttributeError):
        return None


def _bytes(client: Any) -> int:
    try:
        c = client.counters_dict()
    except (AttributeError, UserError):
        return 0
    return int(c.get("bytes_in", 0)) + int(c.get("bytes_out", 0))


# -- what earlier attempts of a cycle did ----------------------------------------------------------

@dataclass
class Replay:
    """What the earlier attempts of a cycle did with its plan: ``states`` (order index, step)
    -> "done" / "lost" / "sent", and the pulses they sent outside the plan (``extra``)."""

    states: dict[tuple[int, int], str] = field(default_factory=dict)
    extra: list[JournalPulse] = field(default_factory=list)


def _slots(orders: Sequence[PulseOrder], states: dict[tuple[int, int], str]
           ) -> Iterator[tuple[int, int]]:
    """The planned pulses an attempt sends, in order, given what earlier attempts did: an
    order stops at a pulse of unknown fate (its cell is re-planned instead)."""
    for i, o in enumerate(orders):
        for n in range(o.count):
            state = states.get((i, n))
            if state in ("done", "lost"):
                continue
            if state == "sent":
                break
            yield i, n
            if states.get((i, n)) == "sent":
                break


def replay_plan(orders: Sequence[PulseOrder], earlier: Sequence[JournalPulse],
                superseded: frozenset[tuple[str, int]] = frozenset()) -> Replay:
    """Which planned pulses of ``orders`` the earlier attempts (``earlier``: their learning
    pulses on this board, in the order sent) sent and what became of them: each attempt sends
    the plan's pulses it has not seen done, lost or uncertain, in order, then its re-planned
    cells' and refresh pulses (``extra``). ``superseded``: (run, n) of pulses sent for an
    earlier plan of the cycle (extra as well). RuntimeError when the journal does not follow
    the plan (it cannot, by construction)."""
    out = Replay()
    attempts: dict[str, list[JournalPulse]] = {}
    for p in earlier:
        if (p.run, p.n) in superseded:
            out.extra.append(p)
        else:
            attempts.setdefault(p.run, []).append(p)
    for run, pulses in attempts.items():
        slots = _slots(orders, out.states)
        used = 0
        for p in pulses:
            slot = next(slots, None)
            if slot is None:
                break
            o = orders[slot[0]]
            if (p.row, p.col, p.polarity) != (o.row, o.col, o.polarity.name):
                raise RuntimeError(f"pulse {p.n} of run {run} on ({p.row},{p.col}) {p.polarity} "
                                   f"is not the committed plan's next pulse ({o.row},{o.col}) "
                                   f"{o.polarity.name}; the checkpoint and its pulse journal "
                                   "disagree")
            out.states[slot] = p.state
            used += 1
        out.extra += pulses[used:]
    return out


def _counted(p: JournalPulse) -> Counted:
    return Counted(p.row, p.col, Polarity[p.polarity])


def earlier_rows(ledger: UnitLedger, k: int, cycle: int, pulses: Sequence[JournalPulse],
                 what: str, me: int | None) -> None:
    """One ledger row per board of ``pulses`` (earlier attempts' pulses of a unit outside its
    plan: a programming cut, a lost board's): done ones counted, sent-only ones uncertain;
    stage ``<what> (interrupted)`` on this board (``me``), ``<what> (board lost)`` on
    another."""
    boards: dict[int | None, list[JournalPulse]] = {}
    for p in pulses:
        boards.setdefault(p.board, []).append(p)
    for board, mine in boards.items():
        done = [_counted(p) for p in mine if p.state == "done"]
        sent = sum(1 for p in mine if p.state == "sent")
        if done or sent:
            stage = f"{what} (interrupted)" if board == me else f"{what} (board lost)"
            ledger.add(k, cycle, stage, done, None, 0.0, uncertain=sent, board=board)


# -- a cycle's pulses ---------------------------------------------------------------------------

@dataclass
class Live:
    """A session's state on this board: the layout, synapse -> cell, the planner, the
    network's synapse back-end reading the chip."""

    board: int | None
    layout: Layout
    cells: dict[Key, tuple[int, int]]
    planner: PulsePlanner
    backend: Any


class CyclePulses:
    """One cycle's pulses on the bench (module doc): ``events`` (the pulses applied, and
    those earlier attempts applied: counted), ``uncertain`` (pulses of unknown fate)."""

    def __init__(self, bench: Any, live: Live, pulse: LearningPulse, limits: Any) -> None:
        self.bench, self.live, self.pulse, self.limits = bench, live, pulse, limits
        self.events: list[Any] = []
        self.uncertain = 0

    def apply(self, orders: Sequence[PulseOrder], replay: Replay) -> list[Any]:
        """The plan's ``orders`` less what ``replay`` says earlier attempts did; then the
        cells of uncertain pulses read and planned anew. The events."""
        replan = self._send(orders, replay.states)
        for p in replay.extra:
            if p.state == "done":
                self.events.append(_counted(p))
            elif p.state == "sent":
                self.uncertain += 1
        planner = self.live.planner
        for key in replan:                          # the truth of an uncertain cell: a read
            row, col = planner.cells[key]
            planner.observe(key, read_weight(self.bench.client, self.live.layout, row, col))
            self._send(planner.plan([key]), {})
        return self.events

    def refresh(self, keys: Sequence[Key]) -> None:
        """Every synapse read, its estimate set to what was read, and planned anew."""
        planner, layout = self.live.planner, self.live.layout
        for key in keys:
            planner.observe(key, read_weight(self.bench.client, layout, *self.live.cells[key]))
        self._send(planner.plan(), {})

    def _send(self, orders: Sequence[PulseOrder], states: dict[tuple[int, int], str]
              ) -> list[Key]:
        """Send ``orders`` but the pulses ``states`` knows; the synapses to re-plan."""
        planner, wm = self.live.planner, self.live.layout.weight_map
        replan: list[Key] = []
        for i, o in enumerate(orders):
            io = self.bench.cell(o.row, o.col, stage=LEARN_STAGE, width_us=self.pulse.width_us,
                                 limits=self.limits, chain=self.live.layout.chain)
            w_before = planner.w_est[o.key] - sum(o.steps)
            io.last_g = float(wm.conductance(max(w_before, 0.0)))
            amp = self.pulse.amplitude(o.polarity)
            try:
                for n, s in enumerate(o.steps):
                    state = states.get((i, n))
                    if state == "done":          # applied by an earlier attempt
                        self.events.append(Counted(o.row, o.col, o.polarity))
                    elif state == "lost":
                        planner.not_applied(o.key, [s])
                    elif state == "sent":        # cut between the request and its reply
                        self.uncertain += 1
                        planner.not_applied(o.key, o.steps[n:])
                        replan.append(o.key)
                        break
                    else:
                        try:
                            io.pulse(o.polarity, amp)
                        except PulseNotApplied:
                            planner.not_applied(o.key, [s])
            finally:
                self.events += io.applied
        return replan


# -- the session's units -----------------------------------------------------------------------

def _orders_of(plan: dict[str, Any]) -> list[PulseOrder]:
    return [PulseOrder((int(o[0][0]), int(o[0][1])), int(o[1]), int(o[2]), Polarity[o[3]],
                       tuple(float(x) for x in o[4])) for o in plan["orders"]]


class ChipArm:
    """The chip arm's units (module doc) for the task ``task``, planned with the fitted
    ``model``, programmed with ``program`` (its weight map is the board layout's), the
    synapses read in ``mode``."""

    def __init__(self, task: LearnTask, model: DeviceModel, program: ProgramConfig,
                 mode: str) -> None:
        self.task, self.model, self.program, self.mode = task, model, program, mode
        self._live: dict[int, Live] = {}

    def run(self, k: int, c: int, bench: Any, ctx: Any, prev: dict[str, Any] | None
            ) -> dict[str, Any]:
        """Unit (session ``k``, cycle ``c``); ``prev``: the record of cycle ``c - 1``."""
        if c == 0:
            return self._start_session(k, bench, ctx)
        if prev is None:
            raise RuntimeError(f"chip session {k} cycle {c}: cycle {c - 1} has no record")
        return self._cycle(k, c, bench, ctx, prev)

    # -- cycle 0 ------------------------------------------------------------------------------
    def _start_session(self, k: int, bench: Any, ctx: Any) -> dict[str, Any]:
        ledger = UnitLedger(ctx.board)
        earlier_rows(ledger, k, 0, list(ctx.earlier), PROGRAM_STAGE, ctx.board)
        w0 = self.task.initial(k)
        prog = program_on_bench(bench, self.task, k, w0, self.program, stage=PROGRAM_STAGE,
                                skip_screen=k > 0)
        ledger.add(k, 0, "program", prog.events, prog.energy_j, prog.estimate_j)
        live = self._open(k, bench, ctx.board)
        start = {key: float(w0[key]) for key in self.task.keys}
        live.planner.start(start, self._reads(bench, live))
        r = self.task.trial(k, 0, False, backend=live.backend)
        return {"arm": "chip", "session": k, "cycle": 0, "board": ctx.board,
                "test": [int(r.steps), bool(r.success)], "program": prog.summary,
                "planner": live.planner.state(), "mode": self.mode,
                "layout": str(live.layout.board), **ledger.to_record()}

    def test_weights(self, k: int, weights: np.ndarray, trial: int, bench: Any, ctx: Any
                     ) -> dict[str, Any]:
        """Session ``k``'s test ``trial`` (``2 c``: the test of cycle ``c``) on this board with
        ``weights`` (float[n_cells, 4], compact; e.g. what another chip learnt) written by
        write-and-verify first: the record (``program``: the programming summary; ``pulses``:
        its pulses; ``test``: steps, success). No learning pulse is sent (the planner only
        carries the chip back-end's reads). ``snan-hil transfer``."""
        ledger = UnitLedger(ctx.board)
        earlier_rows(ledger, k, 0, list(ctx.earlier), PROGRAM_STAGE, ctx.board)
        prog = program_on_bench(bench, self.task, k, weights, self.program,
                                stage=PROGRAM_STAGE, skip_screen=k > 0)
        ledger.add(k, 0, "program", prog.events, prog.energy_j, prog.estimate_j)
        live = self._open(k, bench, ctx.board)
        start = {key: float(weights[key]) for key in self.task.keys}
        live.planner.start(start, self._reads(bench, live))
        r = self.task.trial(k, trial, False, backend=live.backend)
        self._live.pop(k, None)
        return {"session": k, "trial": trial, "board": ctx.board,
                "test": [int(r.steps), bool(r.success)], "program": prog.summary,
                "mode": self.mode, **ledger.to_record()}

    def _open(self, k: int, bench: Any, board: int | None) -> Live:
        """The session's state on this board, from the board's layout (as programmed)."""
        layout = Layout.load(bench.layout_path)
        cells = layout_cells(layout, self.task.nbr)
        planner = make_planner(self.task, self.model, layout.weight_map, cells)
        reader = make_synapses(bench.client, layout, self.task.nbr, self.mode,
                               self.task.train_cfg, conversions=self.task.lc.conversions)
        live = Live(board, layout, cells, planner,
                    chip_backend(reader, planner, self.task.nbr))
        self._live[k] = live
        return live

    def _reads(self, bench: Any, live: Live) -> dict[Key, float]:
        return {key: read_weight(bench.client, live.layout, *live.cells[key])
                for key in self.task.keys}

    # -- cycles 1.. ------------------------------------------------------------------------------
    def _cycle(self, k: int, c: int, bench: Any, ctx: Any, prev: dict[str, Any]
               ) -> dict[str, Any]:
        ledger = UnitLedger(ctx.board)
        live, learning, moved = self._resume(k, c, bench, ctx, prev, ledger)
        client = bench.client
        t_cycle, bytes0 = time.perf_counter(), _bytes(client)
        plan, read_bytes, read_decisions = self._plan(k, c, bench, ctx, live, learning)
        superseded = frozenset((str(r), int(n)) for r, n in plan.get("superseded", []))
        e0 = energy_now(client)
        pulses = CyclePulses(bench, live, self.task.lc.pulse, self._limits(bench))
        pulses.apply(_orders_of(plan), replay_plan(_orders_of(plan), learning, superseded))
        stage = LEARN_STAGE
        if self.task.lc.refresh_every and c % self.task.lc.refresh_every == 0:
            pulses.refresh(self.task.keys)
            stage = "learn+refresh"
        if bench.journal is not None:
            bench.journal.sync()
        e1 = energy_now(client)
        row = ledger.add(k, c, stage, pulses.events, None if e0 is None or e1 is None
                         else e1 - e0, estimate_energy(pulses.events,
                                                       live.layout.chain.r_switch_ohm),
                         uncertain=pulses.uncertain)
        b_test = _bytes(client)
        r = self.task.trial(k, 2 * c, False, backend=live.backend)
        wire = _bytes(client) - bytes0
        read_bytes += _bytes(client) - b_test
        n = row["set"] + row["reset"]
        out = {"arm": "chip", "session": k, "cycle": c, "board": ctx.board,
               "train": plan["train"], "test": [int(r.steps), bool(r.success)], "pulses": n,
               "planner": live.planner.state(), "mode": self.mode,
               "w_intended": intended_weights(live.planner, self.task.keys),
               "w_estimate": estimated_weights(live.planner, self.task.keys),
               "max_cell_pulses": max(live.planner.spent.values(), default=0),
               "link": {"session": k, "cycle": c, "wall_s": time.perf_counter() - t_cycle,
                        "wire_bytes": wire, "pulses": n,
                        "decisions": int(plan["train"][0]) + int(r.steps), "mode": self.mode,
                        "read_bytes": read_bytes,
                        "read_decisions": read_decisions + int(r.steps)},
               **ledger.to_record()}
        if moved is not None:
            out["moved_from"] = moved
        if c == self.task.lc.cycles:                   # the session's end: its learnt weights
            out["weights"] = [read_weight(client, live.layout, *live.cells[key])
                              for key in self.task.keys]
            self._live.pop(k, None)
        return out

    def _limits(self, bench: Any) -> Any:
        """The learning pulses' limits: the write limit, write-and-verify's ceiling under
        it, the compliance margin of the programming."""
        cfg = self.program
        return bench.limits_for(ceiling_v=min(cfg.wv.v_max, bench.limits.max_write_v),
                                compliance_margin=cfg.compliance_margin)

    def _plan(self, k: int, c: int, bench: Any, ctx: Any, live: Live,
              learning: Sequence[JournalPulse]) -> tuple[dict[str, Any], int, int]:
        """The cycle's plan: the one an earlier attempt on this board committed (the planner
        back at it), else the training trial and its plan, committed before the first pulse.
        (plan, the training trial's bytes, its decisions)."""
        store, key = ctx.store, f"chip-s{k}-c{c}-plan"
        plan = store.done(key) if store is not None else None
        if plan is not None and plan.get("board") == ctx.board:
            live.planner.restore(plan["planner"])
            return plan, 0, 0
        client = bench.client
        b0 = _bytes(client)
        r = self.task.trial(k, 2 * c - 1, True, backend=live.backend)
        read_bytes = _bytes(client) - b0
        orders = live.planner.plan()
        plan = {"train": [int(r.steps), bool(r.success)], "planner": live.planner.state(),
                "orders": [[list(o.key), o.row, o.col, o.polarity.name, list(o.steps)]
                           for o in orders], "board": ctx.board,
                "superseded": [[p.run, p.n] for p in learning]}
        if store is not None:
            store.commit(key, plan)
        return plan, read_bytes, int(r.steps)

    def _resume(self, k: int, c: int, bench: Any, ctx: Any, prev: dict[str, Any],
                ledger: UnitLedger) -> tuple[Live, list[JournalPulse], int | None]:
        """The session's state on this board before cycle ``c`` (the previous unit's, or
        after a move the reprogrammed chip's), the earlier attempts' learning pulses on this
        board, and the board it moved from (None: it did not move)."""
        me = ctx.board
        mine = [p for p in ctx.earlier if p.board == me]
        learning = [p for p in mine if p.stage == LEARN_STAGE]
        prev_board = prev.get("board")
        if prev_board == me:
            earlier_rows(ledger, k, c, [p for p in ctx.earlier if p.board != me],
                         LEARN_STAGE, me)
            live = self._live.get(k)
            if live is None or live.board != me:
                live = self._open(k, bench, me)
                live.planner.restore(prev["planner"])
            return live, learning, None
        return self._moved(k, c, bench, ctx, prev, ledger), learning, prev_board

    def _moved(self, k: int, c: int, bench: Any, ctx: Any, prev: dict[str, Any],
               ledger: UnitLedger) -> Live:
        """Session ``k`` moved here from the board of ``prev`` (lost): this chip reprogrammed
        to the intended weights of ``prev`` (once: committed), the lost board's pulses of the
        unit one ledger row on it."""
        me, store = ctx.board, ctx.store
        key = f"chip-s{k}-c{c}-moved"
        done = store.done(key) if store is not None else None
        if done is not None and done.get("board") == me:
            ledger.rows += done["rows"]
            ledger.cells.update(done["cells"])
            ledger.cell_rows += [list(r) for r in done.get("cell_rows", [])]
            ledger.uncertain += int(done["uncertain"])
            live = self._open(k, bench, me)
            live.planner.restore(done["planner"])
            return live
        earlier_rows(ledger, k, c, [p for p in ctx.earlier if p.board != me], LEARN_STAGE, me)
        earlier_rows(ledger, k, c, [p for p in ctx.earlier if p.board == me
                                    and p.stage != LEARN_STAGE], REPROGRAM_STAGE, me)
        state = prev["planner"]
        intended = {(int(a), int(b)): float(w) for (a, b), w in zip(state["keys"],
                                                                   state["w_int"])}
        w_at = np.zeros(self.task.nbr.shape)
        for (i, d), w in intended.items():
            w_at[i, d] = w
        prog = program_on_bench(bench, self.task, k, w_at, self.program,
                                stage=REPROGRAM_STAGE, skip_screen=True)
        ledger.add(k, c, "reprogram", prog.events, prog.energy_j, prog.estimate_j)
        live = self._open(k, bench, me)
        live.planner.start(intended, self._reads(bench, live))
        live.planner.spent = {(int(a), int(b)): int(n)     # the session's budget goes on
                              for (a, b), n in zip(state["keys"], state.get("spent", []))
                              if n}
        log.warning("chip session %s moves from board %s to board %s at cycle %s, "
                    "reprogrammed to its intended weights", k, prev.get("board"), me, c)
        if store is not None:
            store.commit(key, {"board": me, "planner": live.planner.state(),
                               **ledger.to_record()})
            store.commit(f"chip-s{k}-owner", {"board": me, "from": prev.get("board"),
                                              "at_cycle": c})
        return live
