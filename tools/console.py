"""Shared terminal output for the CLI: one rich console, and the one renderer of progress
events (:mod:`snan_hil.progress`)."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator

from rich.console import Console
from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TaskID, TextColumn,
                           TimeElapsedColumn, TimeRemainingColumn)

from snan_hil.progress import ProgressCallback, ProgressEvent

__all__ = ["console", "err_console", "progress_display", "PlainProgress", "PLAIN_INTERVAL_S"]

console = Console()
err_console = Console(stderr=True)

PLAIN_INTERVAL_S = 5.0
"""Seconds between two progress lines when stderr is not a terminal."""


def _describe(event: ProgressEvent) -> str:
    return f"{event.task} {event.detail}" if event.detail else event.task


class _BarProgress:
    """Progress events as rich bars (one per task) on stderr."""

    def __init__(self, bar: Progress) -> None:
        self.bar = bar
        self.tasks: dict[str, TaskID] = {}

    def __call__(self, event: ProgressEvent) -> None:
        if event.note:
            self.bar.console.print(event.note, markup=False, highlight=False, soft_wrap=True)
            return
        task = self.tasks.get(event.task)
        if task is None:
            self.tasks[event.task] = self.bar.add_task(_describe(event), total=event.total,
                                                       completed=event.done)
        else:
            self.bar.update(task, completed=event.done, total=event.total,
                            description=_describe(event))


class PlainProgress:
    """Progress events as plain lines for a log or a pipe: a task's first event, then at most
    one line every ``interval_s`` seconds, and the line that completes a task; notes always.

    ``write`` takes one line (no newline)."""

    def __init__(self, write, interval_s: float = PLAIN_INTERVAL_S,
                 clock=time.monotonic) -> None:
        self.write = write
        self.interval_s = float(interval_s)
        self.clock = clock
        self.t0 = clock()
        self.last = -float("inf")
        self.started: dict[str, float] = {}
        self.finished: set[str] = set()

    def __call__(self, event: ProgressEvent) -> None:
        now = self.clock()
        if event.note:
            self.write(event.note)
            return
        first = event.task not in self.started or (event.done == 0
                                                   and event.task in self.finished)
        if first:
            self.started[event.task] = now
            self.finished.discard(event.task)
        complete = event.total is not None and event.done >= event.total
        if complete and event.task in self.finished:
            return
        if not (first or complete or now - self.last >= self.interval_s):
            return
        self.last = now
        if complete:
            self.finished.add(event.task)
        count = (f"{event.done}/{event.total} ({100 * event.done / event.total:.0f} %)"
                 if event.total else f"{event.done}")
        detail = f" {event.detail}" if event.detail else ""
        self.write(f"{event.task}: {count}{detail}, {now - self.started[event.task]:.0f} s")


@contextlib.contextmanager
def progress_display(*, transient: bool = False, enabled: bool = True,
                     interval_s: float = PLAIN_INTERVAL_S) -> Iterator[ProgressCallback]:
    """The CLI's progress callback, on stderr (so ``--json`` output on stdout stays clean):
    rich bars when stderr is a terminal, else :class:`PlainProgress` lines; ``enabled``
    False: a callback that shows nothing."""
    if not enabled:
        yield lambda event: None
        return
    if err_console.is_terminal:
        with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                      TimeElapsedColumn(), TimeRemainingColumn(), console=err_console,
                      transient=transient) as bar:
            yield _BarProgress(bar)
        return
    yield PlainProgress(lambda line: err_console.print(line, markup=False, highlight=False,
                                                       soft_wrap=True), interval_s)
