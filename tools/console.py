"""Shared terminal output for the CLI: one rich console, and the one renderer of progress
events (:mod:`snan_hil.common.progress`)."""

from __future__ import annotations

import contextlib
import os
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

from rich.console import Console
from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TaskID, TextColumn,
                           TimeElapsedColumn, TimeRemainingColumn)

from snan_hil.common.progress import ProgressCallback, ProgressEvent

__all__ = ["console", "err_console", "progress_display", "progress_sink", "PlainProgress",
           "PLAIN_INTERVAL_S", "INTERVAL_ENV", "warn", "warn_stale_synapses"]

#: width of the consoles when they do not write to a terminal (a pipe, a log): wide enough
#: that tables keep one line per row (rich would fall back to 80 columns); $COLUMNS wins
PLAIN_WIDTH = 250


def _console(stderr: bool = False) -> Console:
    c = Console(stderr=stderr)
    if not c.is_terminal and not os.environ.get("COLUMNS"):
        c = Console(stderr=stderr, width=PLAIN_WIDTH)
    return c


console = _console()
err_console = _console(stderr=True)

PLAIN_INTERVAL_S = 5.0
"""Seconds between two progress lines when stderr is not a terminal."""
INTERVAL_ENV = "SNAN_HIL_PROGRESS_INTERVAL_S"
"""Environment variable that sets those seconds (e.g. 60 for a quiet log, 0 for every event)."""


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
    """Progress events as plain lines for a log or a pipe: a line when a task has run for
    ``interval_s`` seconds, then at most one every ``interval_s`` seconds, and the line that
    completes a task that showed one (short tasks stay silent); notes always.

    Lines are due by the clock, not only when an event arrives: :meth:`tick` (called every
    fraction of the interval by :func:`progress_display`'s timer thread) writes the latest
    state of a running task whose line is due, so a long step — the kernels compiling before
    the first trial, one slow task of a sweep — still shows a line every ``interval_s``.

    ``write`` takes one line (no newline)."""

    def __init__(self, write: Callable[[str], object], interval_s: float = PLAIN_INTERVAL_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.write = write
        self.interval_s = float(interval_s)
        self.clock = clock
        self.last = -float("inf")
        self.started: dict[str, float] = {}
        self.shown: set[str] = set()           # tasks that printed a line and are not done
        self.completed: set[str] = set()
        self.latest: dict[str, ProgressEvent] = {}   # running tasks: their last event
        self._lock = threading.Lock()

    def __call__(self, event: ProgressEvent) -> None:
        with self._lock:
            self._event(event)

    def _event(self, event: ProgressEvent) -> None:
        now = self.clock()
        if event.note:
            self.write(event.note)
            return
        complete = event.total is not None and event.done >= event.total
        if event.task not in self.started or (event.task in self.completed and not complete):
            self.started[event.task] = now             # a new task, or one starting over
            self.completed.discard(event.task)
        if complete:
            self.latest.pop(event.task, None)
            if event.task in self.shown:
                self._line(event, now)
                self.shown.discard(event.task)
            self.completed.add(event.task)
            return
        self.latest[event.task] = event
        if now - max(self.last, self.started[event.task]) >= self.interval_s:
            self._line(event, now)
            self.shown.add(event.task)

    def tick(self) -> None:
        """Write the latest state of one running task whose line is due (no event needed)."""
        with self._lock:
            now = self.clock()
            for task, event in self.latest.items():
                if now - max(self.last, self.started[task]) >= self.interval_s:
                    self._line(event, now)
                    self.shown.add(task)
                    return

    def _line(self, event: ProgressEvent, now: float) -> None:
        self.last = now
        count = (f"{event.done}/{event.total} ({100 * event.done / event.total:.0f} %)"
                 if event.total else f"{event.done}")
        detail = f" {event.detail}" if event.detail else ""
        self.write(f"{event.task}: {count}{detail}, {now - self.started[event.task]:.0f} s")


def _interval_from_env() -> float:
    text = os.environ.get(INTERVAL_ENV, "")
    try:
        value = float(text)
    except ValueError:
        return PLAIN_INTERVAL_S
    return value if value >= 0 else PLAIN_INTERVAL_S


_sinks: list[ProgressCallback] = []
"""Where every progress event also goes (the current software run's document stream,
:func:`snan_hil.tools.commands._run.software_run`)."""


@contextlib.contextmanager
def progress_sink(sink: ProgressCallback) -> Iterator[None]:
    """While inside: every :func:`progress_display` callback also calls ``sink``."""
    _sinks.append(sink)
    try:
        yield
    finally:
        _sinks.remove(sink)


@contextlib.contextmanager
def progress_display(*, transient: bool = False, enabled: bool = True,
                     interval_s: float | None = None) -> Iterator[ProgressCallback]:
    """:func:`_progress_display`, teeing each event to the :func:`progress_sink` sinks."""
    with _progress_display(transient=transient, enabled=enabled,
                           interval_s=interval_s) as show:
        if not _sinks:
            yield show
            return
        sinks = list(_sinks)

        def both(event: ProgressEvent) -> None:
            show(event)
            for sink in sinks:
                sink(event)
        yield both


@contextlib.contextmanager
def _progress_display(*, transient: bool = False, enabled: bool = True,
                      interval_s: float | None = None) -> Iterator[ProgressCallback]:
    """The CLI's progress callback, on stderr (so ``--json`` output on stdout stays clean):
    rich bars when stderr is a terminal, else :class:`PlainProgress` lines every
    ``interval_s`` seconds (default: ``$SNAN_HIL_PROGRESS_INTERVAL_S``, else 5); ``enabled``
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
    plain = PlainProgress(lambda line: err_console.print(line, markup=False, highlight=False,
                                                        soft_wrap=True),
                          _interval_from_env() if interval_s is None else interval_s)
    if plain.interval_s <= 0:                   # a line for every event: no timer needed
        yield plain
        return
    stop = threading.Event()

    def timer() -> None:
        while not stop.wait(min(max(plain.interval_s / 4, 0.05), 1.0)):
            plain.tick()

    thread = threading.Thread(target=timer, name="progress-lines", daemon=True)
    thread.start()
    try:
        yield plain
    finally:
        stop.set()
        thread.join()


def note(line: str) -> None:
    """One plain line on stderr (what the job is doing, not a problem; no markup)."""
    err_console.print(line, markup=False, highlight=False, soft_wrap=True)


def warn(line: str) -> None:
    """One ``warning: ...`` line on stderr (the CLI's warnings; no markup)."""
    err_console.print(f"warning: {line}", markup=False, highlight=False, soft_wrap=True)


def warn_stale_synapses(layout: Any, path: object) -> list[dict]:
    """Warn (one line) when ``layout`` holds synapses a pulse ticket changed after programming
    (:meth:`snan_hil.calibration.layout.Layout.stale_synapses`): their targets no longer
    describe the cells. Returns them as ``{"pre", "post", "row", "col", "why"}`` dicts."""
    stale = [{"pre": s.pre, "post": s.post, "row": s.row, "col": s.col, "why": s.stale}
             for s in layout.stale_synapses()]
    if stale:
        names = ", ".join(f"{d['pre']}->{d['post']} in ({d['row']},{d['col']})"
                          for d in stale[:5]) + (", ..." if len(stale) > 5 else "")
        warn(f"{len(stale)} synapse(s) of {path} were changed by a pulse ticket after "
             f"programming and no longer hold their weight: {names}; their errors below "
             "compare against a stale target (re-run program-weights)")
    return stale
