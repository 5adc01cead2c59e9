"""Run figures: collect every figure's tasks into one sweep, execute it, analyse and write
each figure's files (see :func:`snan_hil.host.experiments.common.write_figure`)."""

from __future__ import annotations

import importlib
import logging
import pathlib
import time
from dataclasses import dataclass
from types import ModuleType
from typing import Sequence

from snan_hil.errors import UserError
from snan_hil.host.experiments.common import Figure, Results, RunOptions, write_figure
from snan_hil.host.experiments.executor import Executor, Task, seed_tasks
from snan_hil.progress import ProgressCallback

log = logging.getLogger(__name__)

FIGURES = ("fig3", "fig4", "fig5", "fig6", "fig7")


def figure_module(name: str) -> ModuleType:
    if name not in FIGURES:
        raise UserError(f"unknown figure {name!r}; choose one of {', '.join(FIGURES)} or all")
    return importlib.import_module(f"snan_hil.host.experiments.{name}")


def resolve(names: Sequence[str]) -> list[str]:
    """``all`` -> every figure; keeps order, drops duplicates."""
    out: list[str] = []
    for n in names:
        for m in (FIGURES if n == "all" else (n,)):
            figure_module(m)
            if m not in out:
                out.append(m)
    return out


@dataclass
class Plan:
    """The sweep of one run: figures and their seeded tasks."""

    figures: list[str]
    tasks: list[Task]
    options: RunOptions

    @property
    def units(self) -> int:
        return sum(t.weight for t in self.tasks)


def plan(names: Sequence[str], opts: RunOptions) -> Plan:
    figs = resolve(names)
    tasks: list[Task] = []
    for f in figs:
        tasks += figure_module(f).tasks(opts)
    return Plan(figs, seed_tasks(tasks, opts.seed), opts)


def execute(p: Plan, executor: Executor, out_dir: str | pathlib.Path,
            progress: ProgressCallback | None = None) -> list[Figure]:
    """Run the sweep, then analyse and write every figure (one folder each). ``progress``
    gets the task "<figures> (<executor>)", one unit per trial."""
    t0 = time.perf_counter()
    results = executor.execute(p.tasks, progress, f"{' '.join(p.figures)} ({executor.name})")
    wall = time.perf_counter() - t0
    res = Results(p.tasks, results)
    figures = []
    for f in p.figures:
        fig = figure_module(f).analyse(p.options, res)
        fig.data["sweep"] = {"executor": executor.name, "tasks": len(p.tasks),
                             "units": p.units, "wall_s": wall}
        write_figure(fig, out_dir)
        figures.append(fig)
    log.info("%d figures, %d tasks, %.1f s", len(figures), len(p.tasks), wall)
    return figures
