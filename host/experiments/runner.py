"""Run figures: collect every figure's tasks into one sweep, execute it, analyse and write
each figure's files (see :func:`snan_hil.host.experiments.common.write_figure`)."""

from __future__ import annotations

import hashlib
import importlib
import json
import logging
import pathlib
import time
from dataclasses import dataclass
from types import ModuleType
from typing import Sequence

from snan_hil.files.atomicio import json_default
from snan_hil.common.errors import UserError
from snan_hil.host.checkpoint import RunFolder
from snan_hil.host.experiments.common import Figure, Results, RunOptions, write_figure
from snan_hil.host.experiments.executor import Executor, Task, key_text, seed_tasks
from snan_hil.common.progress import ProgressCallback, track

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


def task_unit(task: Task) -> str:
    """Checkpoint name of a task: ``task-`` + 16 hex digits of its key's SHA-256."""
    return "task-" + hashlib.sha256(key_text(task.key).encode()).hexdigest()[:16]


def _json(result: dict) -> dict:
    """A task result as a checkpoint stores it (JSON: lists for tuples, numpy scalars as
    numbers): every result goes through it, so a resumed run analyses exactly what an
    uninterrupted one does."""
    return json.loads(json.dumps(result, default=json_default, allow_nan=True))


def execute(p: Plan, executor: Executor, out_dir: str | pathlib.Path,
            progress: ProgressCallback | None = None,
            checkpoint: RunFolder | None = None) -> list[Figure]:
    """Run the sweep, then analyse and write every figure (one folder each). ``progress``
    gets the task "<figures> (<executor>)", one unit per trial (tasks restored from the
    checkpoint count as done at the start).

    ``checkpoint``: every task's result is committed as it finishes (:func:`task_unit`), and
    tasks committed before (a resumed run) are not run again."""
    t0 = time.perf_counter()
    name = f"{' '.join(p.figures)} ({executor.name})"
    bar = track(progress, name, sum(t.weight for t in p.tasks))
    results: list[dict | None] = [None] * len(p.tasks)
    if checkpoint is not None:
        for i, t in enumerate(p.tasks):
            data = checkpoint.done(task_unit(t))
            if data is not None:
                if data.get("key") != key_text(t.key):
                    raise UserError(f"checkpoint {checkpoint.unit_path(task_unit(t))} holds "
                                    f"task {data.get('key')}, not {key_text(t.key)}; delete it")
                results[i] = data["result"]
                bar.advance(t.weight, detail="from the checkpoint")
    todo = [i for i, r in enumerate(results) if r is None]

    def commit(j: int, result: dict) -> None:
        if checkpoint is not None:
            t = p.tasks[todo[j]]
            checkpoint.commit(task_unit(t), {"key": key_text(t.key), "result": _json(result)})

    fresh = executor.execute([p.tasks[i] for i in todo], bar.nested(), name, on_result=commit)
    for i, r in zip(todo, fresh):
        results[i] = r
    if checkpoint is not None:
        results = [_json(r) for r in results if r is not None]
    wall = time.perf_counter() - t0
    res = Results(p.tasks, results)  # type: ignore[arg-type]
    figures = []
    for f in p.figures:
        fig = figure_module(f).analyse(p.options, res)
        fig.data["sweep"] = {"executor": executor.name, "tasks": len(p.tasks),
                             "units": p.units, "wall_s": wall}
        write_figure(fig, out_dir)
        figures.append(fig)
    log.info("%d figures, %d tasks, %.1f s", len(figures), len(p.tasks), wall)
    return figures
