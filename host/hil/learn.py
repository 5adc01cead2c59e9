"""Route learning with the weights on a device: three arms on paired seeds (``snan-hil learn``,
docs/learning.md), as a board job (:mod:`snan_hil.calibration.job`).

Protocol (the project's Fig. 7 protocol, :mod:`snan_hil.host.experiments.route`, on the HIL
task's grid, start and goal): per session fresh random weights; test 0 (astrocytes off, weights
fixed); then ``cycles`` times one training trial (astrocytes on, STDP ``trial_end``: the
trial's changes are applied at its end) and one test. The arms (paired seeds:
:mod:`snan_hil.host.hil.learn_arms`) differ only by where the weights live:

* ``software``: the agent's weights in memory (today's learning, the trial kernel);
* ``device``: :class:`~snan_hil.host.hil.learning.DeviceModelSynapses`, the fitted model's
  quantised, noisy, asymmetric steps;
* ``chip``: the crossbar behind the board (:mod:`snan_hil.host.hil.learn_chip`): a session
  starts with the two-stage write-and-verify of its initial weights, the network reads the
  synapses from the chip (``mode``, :mod:`snan_hil.host.hil.synapses`) and every STDP update
  becomes WRITE_PULSEs (:class:`~snan_hil.host.hil.learning.PulsePlanner`), open loop unless
  ``refresh_every``.

:class:`LearnJob` cuts the run into units (:class:`LearnUnit`): one per session of the software
and device arms (no board I/O), and per (session, cycle) of the chip arm (the session is the
unit's group: its cycles run in order on one board; cycle 0 is the programming and test 0).
The job runner (:func:`snan_hil.lab.runner.run_job`) runs them on one board, records every
pulse, journals it, commits each unit (``--resume``) and reconciles a killed run's pulses with
the chip's history; :meth:`LearnJob.result` puts the results document together from the
units' records alone (``learn.json``: the arms' sessions and curves, the chip arm's ledger and
link figures).

Several boards (``learn --boards/--dask``) go through :func:`snan_hil.lab.fanout.run_on_boards`:
the units without a board (:meth:`LearnJob.host_units`) run on the host, each chip session (a
group) on a board's worker by the same unit loop as on one board; :func:`board_units` says
which board ran each session and where a session moved.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

from snan_hil.calibration.bench import CellBench
from snan_hil.calibration.job import UnitContext
from snan_hil.calibration.layout import Layout
from snan_hil.calibration.mapping import WeightMap
from snan_hil.calibration.programmer import ProgramConfig, check_layout_file
from snan_hil.common.errors import UserError
from snan_hil.common.progress import ProgressCallback, ProgressTracker, track
from snan_hil.crossbar_model.fitted import DeviceModel
from snan_hil.host.checkpoint import RunFolder
from snan_hil.host.config import SnanConfig
from snan_hil.host.hil.learn_arms import (ARMS, PAPER_FIG7, LearnConfig, LearnTask,
                                          SessionResult, curves, device_session,
                                          software_session)
from snan_hil.host.hil.learn_chip import LEARN_STAGE, ChipArm
from snan_hil.host.hil.learn_ledger import Ledger
from snan_hil.host.hil.board_window import read_plan
from snan_hil.host.hil.synapses import check_mode
from snan_hil.records.journal import JournalPulse

__all__ = ["ARMS", "PAPER_FIG7", "LearnConfig", "LearnTask", "LearnUnit", "LearnJob",
           "SessionResult", "run_learning", "run_here", "board_units", "curves", "LEARN_STAGE"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class LearnUnit:
    """A unit of a learning run: session ``session`` of arm ``arm``; the chip arm's cycle
    ``cycle`` (0: the session's programming and test 0; c: training c, its pulses, test c),
    None for the arms that run a whole session as one unit. ``group``: the chip session (its
    cycles run in order on one board); ``on_board``: whether the unit uses a board."""

    arm: str
    session: int
    cycle: int | None = None

    @property
    def key(self) -> str:
        if self.arm == "chip":
            return f"chip-s{self.session}-c{self.cycle}"
        return f"{self.arm}-s{self.session}"

    @property
    def group(self) -> str | None:
        return f"chip-s{self.session}" if self.arm == "chip" else None

    @property
    def on_board(self) -> bool:
        return self.arm == "chip"


class LearnJob:
    """``snan-hil learn`` as a board job (module doc). ``cfg``: the SNAN model config;
    ``lc``: the run; ``model``: the fitted device model (the device and chip arms need it);
    ``program``: the chip arm's programming settings (default: the defaults with the weight
    map of the board's layout); ``names``: how the front door spells the config's fields in
    messages (the CLI's options; default the field names, as a notebook's keywords)."""

    kind: ClassVar[str] = "learn"
    restartable: ClassVar[bool] = False

    def __init__(self, cfg: SnanConfig, lc: LearnConfig, model: DeviceModel | None = None, *,
                 program: ProgramConfig | None = None,
                 names: Mapping[str, str] | None = None) -> None:
        self.names = dict(names or {})
        lc.check(self.names)
        self.cfg, self.lc, self.model, self.program = cfg, lc, model, program
        self.task = LearnTask(cfg, lc)
        self.mode: str | None = None
        """The chip arm's mode, decided on the board (:meth:`plan`)."""
        self._chip: ChipArm | None = None
        self._prev: dict[int, dict[str, Any]] = {}      # session -> its last chip record
        self._bar: ProgressTracker | None = None
        self._restored = 0

    @property
    def chip_arm(self) -> ChipArm | None:
        """The chip arm's units on the board :meth:`plan` checked (None before)."""
        return self._chip

    def _name(self, field: str) -> str:
        return self.names.get(field, field)

    # -- the job's seams ---------------------------------------------------------------------
    def describe(self) -> dict[str, Any]:
        return {"learn": self.lc.to_dict()}

    def units(self) -> list[LearnUnit]:
        """Every unit, arm by arm, session by session (a chip session cycle by cycle)."""
        out: list[LearnUnit] = []
        for arm in self.lc.arms:
            for k in range(self.lc.sessions):
                if arm == "chip":
                    out += [LearnUnit(arm, k, c) for c in range(self.lc.cycles + 1)]
                else:
                    out.append(LearnUnit(arm, k))
        return out

    def groups(self) -> list[str]:
        """The groups of units that need a board: the chip arm's sessions, in order (several
        boards place them; the units without a board, ``on_board`` False, run where the run
        is: :meth:`host_units`)."""
        return [f"chip-s{k}" for k in range(self.lc.sessions)] if "chip" in self.lc.arms \
            else []

    def group_name(self, group: str) -> str:
        return f"chip session {group.removeprefix('chip-s')}"

    def host_units(self) -> list[LearnUnit]:
        """The units that need no board (the software and device arms): over several boards
        they run on the host, not on a board's worker."""
        return [u for u in self.units() if not u.on_board]

    def unit_order(self) -> list[str]:
        return [u.key for u in self.units()]

    def check_model(self) -> None:
        """UserError (one line) when an arm needs the device model and none was given."""
        if ("device" in self.lc.arms or "chip" in self.lc.arms) and self.model is None:
            raise UserError("the device and chip arms need a fitted device model: run "
                            "'snan-hil characterize' first (or give a model file)")

    def plan(self, bench: CellBench) -> list[LearnUnit]:
        """The units, after the checks against the board (the chip arm: its synapses in the
        crossbar, the learning pulse under the write limit, the board's layout usable, the
        mode the board can run)."""
        self.check_model()
        if "chip" in self.lc.arms:
            self._check_board(bench)
        return self.units()

    def _check_board(self, bench: CellBench) -> None:
        info, n = bench.info, len(self.task.keys)
        room = (info.rows - 1) * info.cols            # the block and one row of spares
        if n > room:
            grid = self.cfg.grid
            side = max((s for s in range(2, 64) if 4 * s * (s - 1) <= room), default=1)
            raise UserError(f"a {grid.rows}x{grid.cols} field has {n} synapses; the "
                            f"{info.rows}x{info.cols} crossbar holds at most {room} with a row "
                            f"of spares: run the chip arm on {side}x{side} or smaller "
                            f"({self._name('arms')} software,device for larger)")
        pulse = self.lc.pulse
        bench.check_amplitude(pulse.set_v, self._name("set_v"))
        bench.check_amplitude(pulse.reset_v, self._name("reset_v"))
        check_layout_file(bench.layout_path, bench.session)
        self.mode = check_mode(bench.client, self.lc.mode, self.task.train_cfg)
        if self.mode == "on_board":         # the read plan the board can run: before a pulse
            read_plan(bench.client, self.lc.conversions)
        program = self.program
        if program is None:
            path = bench.layout_path
            program = ProgramConfig(weight_map=Layout.load(path).weight_map
                                    if path is not None and path.is_file() else WeightMap())
        assert self.model is not None
        self._chip = ChipArm(self.task, self.model, program, self.mode)

    def run_unit(self, unit: LearnUnit, bench: CellBench | None, ctx: UnitContext
                 ) -> dict[str, Any]:
        t0 = time.perf_counter()
        tick = self._ticker(ctx.progress)
        k = unit.session
        if unit.arm == "software":
            record: dict[str, Any] = {"result": software_session(self.task, k, tick).to_dict()}
        elif unit.arm == "device":
            assert self.model is not None
            record = {"result": device_session(self.task, k, self.model, WeightMap(),
                                               tick).to_dict()}
        else:
            if self._chip is None or bench is None:
                raise UserError("the chip arm needs a board (--port)")
            assert unit.cycle is not None
            record = self._chip.run(k, unit.cycle, bench, ctx, self._previous(unit, ctx))
            self._prev[k] = record
            if unit.cycle:
                tick(f"chip session {k} cycle {unit.cycle}: {_polarities(record)}")
        record.update(arm=unit.arm, session=k, wall_s=time.perf_counter() - t0)
        return record

    def _previous(self, unit: LearnUnit, ctx: UnitContext) -> dict[str, Any] | None:
        """The record of the chip unit before ``unit`` (None before cycle 0)."""
        if not unit.cycle:
            return None
        prev = self._prev.get(unit.session)
        if prev is not None and prev.get("cycle") == unit.cycle - 1:
            return prev
        key = LearnUnit("chip", unit.session, unit.cycle - 1).key
        return ctx.store.done(key) if ctx.store is not None else None

    def restore(self, unit: LearnUnit, record: dict[str, Any]) -> None:
        if unit.arm == "chip":
            self._prev[unit.session] = record
            self._restored += 1 if unit.cycle else 0
        else:
            self._restored += self.lc.cycles

    def _ticker(self, progress: ProgressCallback | None) -> Callable[[str], None]:
        if self._bar is None:
            self._bar = track(progress, "learning",
                              self.lc.sessions * self.lc.cycles * len(self.lc.arms))
        bar = self._bar
        if self._restored:
            bar.advance(self._restored, "from the checkpoint")
            self._restored = 0
        return lambda detail: bar.advance(1, detail)

    def result(self, records: Mapping[str, dict[str, Any]], status: str) -> dict[str, Any]:
        """The results document from the units' records (module doc); for ``status``
        "interrupted" the sessions that finished (a chip session: its cycles so far; the
        curves of the finished sessions)."""
        arms: dict[str, list[SessionResult]] = {}
        walls: dict[str, float] = {}
        chip: list[dict[str, Any]] = []
        for arm in self.lc.arms:
            got = [(u, records[u.key]) for u in self.units() if u.arm == arm
                   and u.key in records]
            walls[arm] = sum(float(r.get("wall_s", 0.0)) for _u, r in got)
            if arm == "chip":
                chip = [r for _u, r in got]
                arms[arm] = _chip_sessions(chip)
            else:
                arms[arm] = [SessionResult(**r["result"]) for _u, r in got]
        if status == "complete" and any(len(rs) != self.lc.sessions for rs in arms.values()):
            raise RuntimeError("a learning run completed with sessions missing")
        doc = self._document(arms, walls)
        if "chip" in arms:
            doc.update(_chip_fields(chip))
        return doc

    def _document(self, arms: dict[str, list[SessionResult]], walls: dict[str, float]
                  ) -> dict[str, Any]:
        cfg, lc = self.cfg, self.lc
        whole = {arm: [s for s in rs if len(s.test_steps) == lc.cycles + 1]
                 for arm, rs in arms.items()}
        doc: dict[str, Any] = {
            "task": {"grid": [cfg.grid.rows, cfg.grid.cols], "start": lc.start,
                     "goal": lc.goal, "step_limit": cfg.grid.max_steps},
            "config": lc.to_dict(), "model_config": cfg.to_dict(),
            "protocol": {"cycles": lc.cycles, "task": "fixed", "train_astro": True,
                         "test_astro": False, "stdp_mode": self.task.train_cfg.stdp.mode,
                         "target": cfg.stdp.target},
            "arms": {arm: {"sessions": [r.to_dict() for r in rs],
                           "curves": curves(whole[arm], lc.seed)}
                     for arm, rs in arms.items()},
            "synapses": [list(k) for k in self.task.keys],
            "wall_s": sum(walls.values()), "arm_wall_s": walls,
            "device_model": self.model.to_dict() if self.model is not None else None,
            "paper": _paper(cfg)}
        return doc

    def summary(self, result: dict[str, Any]) -> dict[str, Any]:
        return {"pulses": (result.get("ledger") or {}).get("total")}


def _polarities(record: dict[str, Any]) -> str:
    row = next((r for r in record["rows"] if r["stage"].startswith(LEARN_STAGE)
                and "board lost" not in r["stage"]), {"set": 0, "reset": 0})
    return f"{row['set']} SET / {row['reset']} RESET"


def _chip_sessions(records: Sequence[dict[str, Any]]) -> list[SessionResult]:
    """The chip arm's sessions from its units' records (in unit order)."""
    out: dict[int, SessionResult] = {}
    for rec in records:
        s = out.setdefault(int(rec["session"]), SessionResult())
        if rec["cycle"]:
            s.train_steps.append(int(rec["train"][0]))
            s.train_success.append(bool(rec["train"][1]))
            s.pulses.append(int(rec["pulses"]))
        s.test_steps.append(int(rec["test"][0]))
        s.test_success.append(bool(rec["test"][1]))
        if rec.get("weights") is not None:
            s.weights = [float(w) for w in rec["weights"]]
        if rec.get("w_intended") is not None:
            s.w_intended.append([float(w) for w in rec["w_intended"]])
            s.w_estimate.append([float(w) for w in rec["w_estimate"]])
            s.max_cell_pulses = int(rec.get("max_cell_pulses", 0))
    return [out[k] for k in sorted(out)]


def _chip_fields(records: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The chip arm's part of the results document: its mode, ledger, link figures, the
    board layout it learnt on (one board)."""
    firsts = [r for r in records if r["cycle"] == 0]
    one_board = all(r.get("board") is None for r in records)
    return {"chip_mode": firsts[-1]["mode"] if firsts else None,
            "ledger": Ledger.of(records).to_dict(),
            "link": [r["link"] for r in records if r.get("link") is not None],
            "chip_layout": firsts[-1].get("layout") if firsts and one_board else None}


def _paper(cfg: SnanConfig) -> dict[str, Any]:
    """Fig. 7's values of this grid's size, or of every size it has."""
    size = cfg.grid.rows if cfg.grid.rows == cfg.grid.cols else None
    if size in PAPER_FIG7:
        p = PAPER_FIG7[size]
        return {"figure": "Fig. 7", "size": size, "median": {"0": p[0], str(20): p[1]},
                "success": {"0": p[2], "20": p[3]}}
    return {"figure": "Fig. 7", "size": None,
            "note": f"Fig. 7 has no {cfg.grid.rows}x{cfg.grid.cols} curve; its 3x3 / 5x5 / "
                    "10x10 values are shown beside",
            "sizes": {str(s): v for s, v in PAPER_FIG7.items()}}


# -- units run here (no runner): the arms without a board ------------------------------------

def run_here(job: LearnJob, units: Sequence[LearnUnit], bench: CellBench | None,
             folder: RunFolder | None, *, board: int | None = None,
             earlier: Callable[[str], Sequence[JournalPulse]] | None = None,
             progress: ProgressCallback | None = None) -> dict[str, dict[str, Any]]:
    """Run ``units`` of ``job`` in order on ``bench`` (None: units without board I/O), each
    committed to ``folder`` (a committed one restored); the records by unit key. The unit
    loop of :func:`snan_hil.lab.runner.run_units` for a run without a board (the software and
    device arms alone: :func:`run_learning`)."""
    records: dict[str, dict[str, Any]] = {}
    for unit in units:
        saved = folder.done(unit.key) if folder is not None else None
        if saved is not None:
            job.restore(unit, saved)
            records[unit.key] = saved
            continue
        if bench is not None and bench.journal is not None:
            bench.journal.unit = unit.key
        ctx = UnitContext(progress=progress, store=folder, board=board,
                          earlier=earlier(unit.key) if earlier is not None else ())
        record = job.run_unit(unit, bench, ctx)
        if folder is not None:
            folder.commit(unit.key, record)
        records[unit.key] = record
    return records


def run_learning(cfg: SnanConfig, lc: LearnConfig, *, model: DeviceModel | None,
                 folder: RunFolder | None = None, progress: ProgressCallback | None = None,
                 names: Mapping[str, str] | None = None) -> dict[str, Any]:
    """The arms of ``lc`` that need no board (``software``, ``device``: :func:`run_here`);
    the results document (:meth:`LearnJob.result`). The chip arm needs a board: one board:
    :class:`LearnJob` through the runner; several: :func:`snan_hil.lab.fanout.run_on_boards`."""
    job = LearnJob(cfg, lc, model, names=names)
    job.check_model()
    if "chip" in lc.arms:
        raise UserError("the chip arm needs a board (--port)")
    records = run_here(job, job.units(), None, folder, progress=progress)
    return job.result(records, "complete")


def board_units(groups: Mapping[str, dict[str, Any]], records: Mapping[str, dict[str, Any]]
                ) -> dict[str, dict[str, Any]]:
    """Session -> who ran it (a run over several boards: ``groups``, the chip session's group
    -> its board, port, board id, worker), with ``moved_from``, ``moved_at_cycle`` and
    ``moves`` for a session that moved from a lost board (its cycles' ``records``)."""
    out: dict[str, dict[str, Any]] = {}
    for group, unit in groups.items():
        k = int(group.removeprefix("chip-s"))
        mine = [r for key, r in records.items() if key.startswith(f"chip-s{k}-c")]
        moves = [{"from": r["moved_from"], "to": r["board"], "at_cycle": r["cycle"]}
                 for r in sorted(mine, key=lambda r: int(r["cycle"]))
                 if r.get("moved_from") is not None]
        row = dict(unit)
        if moves:
            row.update(moved_from=moves[-1]["from"], moved_at_cycle=moves[-1]["at_cycle"],
                       moves=moves)
        out[str(k)] = row
    return dict(sorted(out.items(), key=lambda kv: int(kv[0])))
