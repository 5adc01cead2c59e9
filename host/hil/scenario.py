"""One scenario of the hardware experiment as a board job: ``launches`` launches of the agent
on the HIL task with one weight set, its synapses read from the crossbar (``hw_*``) or taken
as numbers (``sw_*``), with or without astrocytes (``*_astro``).

:class:`ScenarioJob` is what ``snan-hil run`` and a notebook's ``board.run_scenario(...)`` run
through the job runner (:func:`snan_hil.lab.runner.run_job`) for a hardware scenario: one
unit; its ``plan`` checks that the board's layout holds the weight set before any launch; each
launch goes to the run's ``launches`` stream as it ends
(:mod:`snan_hil.host.hil.launch_stream`). A software scenario needs no board
(:meth:`ScenarioJob.run_without_board`).
"""

from __future__ import annotations

import shlex
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

from snan_hil.calibration.bench import CellBench
from snan_hil.calibration.chip_group import GroupBench
from snan_hil.calibration.job import ONE, SingleUnit, UnitContext
from snan_hil.calibration.layout import Layout, LayoutError
from snan_hil.calibration.weights_io import load_weight_set
from snan_hil.common.errors import UserError
from snan_hil.common.progress import ProgressCallback
from snan_hil.host.hil.compare import check_weights_grid, task_of
from snan_hil.host.hil.config import HilConfig
from snan_hil.host.hil.launch_stream import launch_feed
from snan_hil.host.hil.runner import ScenarioResult, check_layout, run_scenario, scenario_parts

__all__ = ["ScenarioConfig", "ScenarioJob"]


@dataclass(frozen=True)
class ScenarioConfig:
    """What to launch: ``scenario`` (``sw_noastro``, ``sw_astro``, ``hw_noastro``,
    ``hw_astro``), the trained weights file (``.npz`` / ``.npy``) and its set
    ``set_index``, ``launches`` (launch l of set K uses trial K*1000+l of the ``seed``),
    the hardware ``mode`` (how the synapses are read; None: the board's default),
    ``conversions``: ADC conversions a read of the on-board window (None: the board's default
    read plan, :func:`~snan_hil.host.hil.board_window.read_plan`)."""

    scenario: str
    weights: str
    set_index: int = 0
    launches: int = 10
    seed: int = 1
    mode: str | None = None
    conversions: int | None = None


class ScenarioJob:
    """See the module docstring. ``hil``: the launch model (checked against the weights
    file's grid here, before any I/O: UserError); ``program_hint``: how the front door says
    to program the set first when the board's layout does not hold it (the CLI's
    ``program-weights`` command line, a notebook's ``board.program_weights(...)``); ``names``:
    how it spells the config's fields (unused: every check of the input is the front
    door's)."""

    kind: ClassVar[str] = "hil"
    restartable: ClassVar[bool] = False

    def __init__(self, cfg: ScenarioConfig, hil: HilConfig, *, program_hint: str | None = None,
                 names: Mapping[str, str] | None = None) -> None:
        self.cfg, self.hil = cfg, hil
        self.hw, self.astro = scenario_parts(cfg.scenario)
        self.weights, self.meta = load_weight_set(cfg.weights, cfg.set_index)
        check_weights_grid(self.meta, hil, cfg.weights)
        self.start, self.goal = task_of(self.meta, hil)
        self.program_hint = program_hint or (
            f"program it first: snan-hil program-weights {shlex.quote(cfg.weights)} --weight-set "
            f"{cfg.set_index}")
        self.names = dict(names or {})
        self.layout: Layout | None = None
        self.group: list[Layout] | None = None
        """Each chip's layout when the scenario runs over a chip group (:meth:`plan` on a
        :class:`GroupBench`)."""

    def describe(self) -> dict[str, Any]:
        return {"scenario": self.cfg.scenario, "weights": str(self.cfg.weights),
                "set_index": self.cfg.set_index, "launches": self.cfg.launches,
                "mode": self.cfg.mode, "conversions": self.cfg.conversions}

    def plan(self, bench: CellBench | GroupBench) -> Sequence[SingleUnit]:
        """One unit; a hardware scenario's board must hold the weight set in its layout
        (:class:`~snan_hil.calibration.layout.LayoutError`, one line naming how to program
        it); over a chip group every chip its share of the set, as the group's plan places
        it (:mod:`snan_hil.calibration.chip_group`)."""
        if isinstance(bench, GroupBench):
            self._plan_group(bench)
        elif self.hw:
            layout = bench.layout
            if layout is None:
                raise LayoutError(f"no layout for board {bench.session.identity.board_id} on "
                                  f"{bench.session.port} ({bench.layout_path}); "
                                  f"{self.program_hint}")
            check_layout(layout, self.weights, tuple(self.meta["grid"]),
                         port=bench.session.port, weights_path=shlex.quote(self.cfg.weights),
                         set_index=self.cfg.set_index, board_options=bench.session.options)
            self.layout = layout
        return ONE

    def _plan_group(self, bench: GroupBench) -> None:
        if not self.hw:
            raise UserError(f"scenario {self.cfg.scenario} runs in software; a chip group "
                            "runs the hardware scenarios (hw_noastro, hw_astro)")
        if self.cfg.mode not in (None, "on_board"):
            raise UserError("a chip group runs the on-board decision windows; leave --mode out")
        plan = bench.plan(tuple(self.meta["grid"]))
        layouts = []
        for k, b in enumerate(bench.benches):
            layout = b.layout
            if layout is None or layout.pres != plan.shares[k]:
                have = "no layout" if layout is None else (
                    "the whole network" if layout.pres is None else
                    f"input neurons {min(layout.pres)}-{max(layout.pres)}")
                raise LayoutError(
                    f"chip {k} of the group ({b.session.port}) holds {have}, the group's plan "
                    f"puts input neurons {min(plan.shares[k])}-{max(plan.shares[k])} there; "
                    f"{self.program_hint}")
            try:
                check_layout(layout, self.weights, tuple(self.meta["grid"]),
                             port=b.session.port, weights_path=shlex.quote(self.cfg.weights),
                             set_index=self.cfg.set_index)
            except LayoutError as exc:       # the group's own hint, not program-weights'
                reason = str(exc).split("; program it first")[0]
                raise LayoutError(f"{reason}; {self.program_hint}") from None
            layouts.append(layout)
        self.group = layouts

    def run_unit(self, unit: SingleUnit, bench: CellBench | GroupBench | None,
                 ctx: UnitContext) -> dict[str, Any]:
        """The launches (``bench`` None: a software scenario); the record is the
        :class:`ScenarioResult` as a dict."""
        if self.hw and bench is None:
            raise UserError(f"scenario {self.cfg.scenario} needs a board (--port) and its "
                            "layout")
        cfg = self.cfg
        feed = launch_feed(ctx.emit, cfg.scenario, cfg.set_index,
                           self.hil.launch_config(self.astro), seed=cfg.seed)
        if isinstance(bench, GroupBench):
            assert self.group is not None                    # planned on the group
            return run_scenario(
                cfg.scenario, self.weights, self.hil, set_index=cfg.set_index,
                launches=cfg.launches, seed=cfg.seed, start=self.start, goal=self.goal,
                group=[(b.client, lay) for b, lay in zip(bench.benches, self.group)],
                baud=bench.benches[0].session.baud, progress=ctx.progress, on_launch=feed,
                conversions=cfg.conversions).to_dict()
        res = run_scenario(cfg.scenario, self.weights, self.hil, set_index=cfg.set_index,
                           launches=cfg.launches, seed=cfg.seed, start=self.start,
                           goal=self.goal,
                           client=bench.client if bench is not None and self.hw else None,
                           layout=self.layout, mode=cfg.mode,
                           baud=bench.session.baud if bench is not None and self.hw else None,
                           progress=ctx.progress, on_launch=feed,
                           conversions=cfg.conversions)
        return res.to_dict()

    def restore(self, unit: SingleUnit, record: dict[str, Any]) -> None:
        pass                                    # the record is the whole result

    def result(self, records: Mapping[str, dict[str, Any]], status: str) -> ScenarioResult:
        record = records.get(ONE[0].key)
        if record is None:
            raise RuntimeError("the launches did not run")
        return ScenarioResult.from_dict(record)

    def summary(self, result: ScenarioResult) -> dict[str, Any]:
        return {"median_steps": result.median_steps, "success_rate": result.success_rate}

    def run_without_board(self, progress: ProgressCallback | None = None) -> ScenarioResult:
        """A software scenario's launches (no board, nothing recorded)."""
        if self.hw:
            raise UserError(f"scenario {self.cfg.scenario} needs a board (--port) and its "
                            "layout")
        record = self.run_unit(ONE[0], None, UnitContext(progress=progress))
        return self.result({ONE[0].key: record}, "complete")
