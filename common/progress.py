"""Progress of long jobs: one event type, one callback protocol; the CLI alone renders it.

Library code (calibration, host, ...) never prints. A long job takes an optional
``progress`` argument, a :class:`ProgressCallback`, and reports through a
:class:`ProgressTracker`::

    def program(..., progress: ProgressCallback | None = None):
        bar = track(progress, "programming", total=len(cells))
        for cell in cells:
            ...
            bar.advance(detail=f"cell {cell}")
        bar.note("synapse 3->4 moved to a spare")    # a line of its own

The CLI passes a callback that draws a progress bar on a terminal and prints a plain line
every few seconds otherwise (:func:`snan_hil.tools.console.progress_display`). Tests pass
``events.append``. A base module like :mod:`snan_hil.common.errors`: every layer may import it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

__all__ = ["ProgressEvent", "ProgressCallback", "ProgressTracker", "track"]


@dataclass(frozen=True)
class ProgressEvent:
    """Where one task of a job stands.

    ``task`` names the task (one bar per name; a task may start over with ``done`` 0, e.g.
    "programming" once per weight set); ``done`` counts the units finished so far (absolute,
    not an increment); ``total`` the units in all (None: unknown); ``detail`` says what is
    happening now; ``note`` is a one-off message worth a line of its own (empty: none).
    """

    task: str
    done: int
    total: int | None = None
    detail: str = ""
    note: str = ""


class ProgressCallback(Protocol):
    """What a long job calls with each :class:`ProgressEvent` (must return quickly; an
    exception it raises, e.g. KeyboardInterrupt, propagates out of the job)."""

    def __call__(self, event: ProgressEvent, /) -> None: ...


class ProgressTracker:
    """Counts the units of one task and reports them to a callback (None: reports nothing)."""

    def __init__(self, progress: ProgressCallback | None, task: str,
                 total: int | None = None) -> None:
        self.progress = progress
        self.task = task
        self.total = total
        self.done = 0

    def _emit(self, detail: str = "", note: str = "") -> None:
        if self.progress is not None:
            self.progress(ProgressEvent(self.task, self.done, self.total, detail, note))

    def update(self, done: int, detail: str = "") -> None:
        """Set the units done to ``done`` and report."""
        self.done = int(done)
        self._emit(detail)

    def advance(self, n: int = 1, detail: str = "") -> None:
        """``n`` more units done (0: only a new ``detail``); report."""
        self.update(self.done + n, detail)

    def note(self, text: str) -> None:
        """Report a one-off message (the count is unchanged)."""
        self._emit(note=text)

    def nested(self, label: str = "") -> ProgressCallback:
        """A callback for a sub-job whose units are units of this task: each of its events
        sets this task to (units done when the sub-job started) + its ``done``, its detail
        prefixed with ``label``; its notes are passed on."""
        base = self.done

        def forward(event: ProgressEvent) -> None:
            if event.note:
                self.note(event.note)
            else:
                self.update(base + event.done, f"{label}{event.detail}")
        return forward


def track(progress: ProgressCallback | None, task: str, total: int | None = None,
          detail: str = "") -> ProgressTracker:
    """A :class:`ProgressTracker` for ``task`` that has reported its start (``done`` 0)."""
    tracker = ProgressTracker(progress, task, total)
    tracker.update(0, detail)
    return tracker
