"""The control channel of a running job: pause, resume and stop requests, polled between pulses.

``snan-hil watch`` (or anyone with the file) writes a request into the run's history database
(``controls`` table, :meth:`snan_hil.records.history.History.request_control`); the job polls
it through :class:`RunControl` before each board request that may change a cell
(:class:`snan_hil.calibration.control.ControlledClient` calls :meth:`RunControl.check`).
Polling happens between pulses, never inside one: a pulse already sent is answered, its read
recorded, and only then does the next check see the request. So a stop never leaves a pulse
half-recorded: :class:`StopRequested` is raised *before* the next pulse is sent, the job's
usual interrupt clean-up runs (a programming run saves its layout and its report with
``complete: false``), and the recorder closes the run as ``interrupted`` (RunStop
``exit_status: abort``, reason "stop requested").

Why the database and not a signal: a signal can arrive between a request and its reply (the
pulse is applied but the job never reads its conductance); a file or a table is only seen where
the job looks. Why the database and not a separate control file: the watcher already has it
open (WAL mode: its write never waits on the job's), a request is tied to the run's uid, and
the history keeps who asked for what and when.

A base module: it imports no layer.
"""

from __future__ import annotations

import logging
import os
import sqlite3
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from snan_hil.records.history import History
from snan_hil.records.interrupts import RecordingStopped, StopRequested

__all__ = ["StopRequested", "RecordingStopped", "RunControl", "POLL_INTERVAL_S"]

log = logging.getLogger(__name__)

POLL_INTERVAL_S = 0.1
"""Least time between two looks at the control table (s); while paused, the period of the
look for resume / stop."""


class RunControl:
    """Polls the control requests of run ``run_uid`` in the history database at ``path``.

    :meth:`check` returns at once while nothing is asked; blocks while the run is paused
    (looking every ``poll_s`` for resume or stop); raises :class:`StopRequested` on stop.
    ``on_action(action)`` is told of every request acted on (the job's document stream
    records it). A database that cannot be read disables the channel with one ``warn`` line
    (the run goes on).

    ``db``: what to poll through, anything with ``controls(run_uid, after_id)``: an open
    :class:`~snan_hil.records.history.History`, or the run's
    :class:`~snan_hil.records.history.Recorder` (its own connection) -- in the job's own
    process always the recorder's: a second ``History.open`` there reads the file's header
    with ``open()``/``close()``, and closing any descriptor of an SQLite file drops every POSIX
    lock the process holds on it (SQLite's documented pitfall), so another process could
    checkpoint the WAL under the running job."""

    def __init__(self, path: str | os.PathLike[str] | None, run_uid: str, *,
                 db: Any = None,
                 poll_s: float = POLL_INTERVAL_S,
                 on_action: Callable[[str], object] | None = None,
                 warn: Callable[[str], object] | None = None,
                 sleep: Callable[[float], None] = time.sleep,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.path = None if path is None else Path(path)
        self.run_uid = run_uid
        self.poll_s = float(poll_s)
        self.on_action = on_action
        self.warn = warn or (lambda line: log.warning("%s", line))
        self.sleep, self.clock = sleep, clock
        self.last_id = 0
        self.last_poll = -float("inf")
        self.paused = False
        self.disabled = self.path is None
        self.checks = 0
        self._stopped = False
        self._db: Any = db
        self._own = db is None
        if db is not None:
            self.disabled = False

    def _requests(self) -> list[tuple[int, str]]:
        if self.disabled:
            return []
        try:
            if self._db is None:
                self._db = History.open(self.path, create=False)   # type: ignore[arg-type]
                self._own = True
            found: list[tuple[int, str]] = self._db.controls(self.run_uid, self.last_id)
        except sqlite3.OperationalError as exc:
            if "locked" in str(exc).lower() or "busy" in str(exc).lower():
                return []                         # another connection's lock: next poll
            self.disabled = True
            self.warn(f"control channel in {self.path} unreadable ({exc}); pause and stop from "
                      "'snan-hil watch' do not reach this run (Ctrl-C still does)")
            return []
        except (sqlite3.Error, OSError, Exception) as exc:   # never stops the run
            self.disabled = True
            self.warn(f"control channel in {self.path} unreadable ({exc}); pause and stop from "
                      "'snan-hil watch' do not reach this run (Ctrl-C still does)")
            return []
        if found:
            self.last_id = found[-1][0]
        return found

    def _act(self, requests: list[tuple[int, str]]) -> None:
        for _id, action in requests:
            if action == "stop":
                self._tell("stop")
                raise StopRequested("stop requested (snan-hil watch)")
            if action == "pause" and not self.paused:
                self.paused = True
                self._tell("pause")
            elif action == "resume" and self.paused:
                self.paused = False
                self._tell("resume")

    def _tell(self, action: str) -> None:
        if self.on_action is not None:
            try:
                self.on_action(action)
            except Exception:
                log.warning("control action hook failed", exc_info=True)

    def check(self, force: bool = False) -> None:
        """Between two board requests: act on new control requests (module docstring); at
        most every ``poll_s`` unless ``force`` (the job runner between two units)."""
        self.checks += 1
        now = self.clock()
        if now - self.last_poll < self.poll_s and not self.paused and not force:
            return
        self.last_poll = now
        self._act(self._requests())
        while self.paused:
            self.sleep(self.poll_s)
            self._act(self._requests())

    def stop_requested(self) -> bool:
        """Act on new control requests without waiting (``on_action`` is told of each, a
        pause only noted): True once a stop has been asked. What a job polls that does not
        send the board requests itself (several boards: each board's worker checks its own
        :class:`RunControl` of the same run before each request, so a pause holds them
        and a stop ends them; the job's process records the actions)."""
        if self._stopped:
            return True
        try:
            self._act(self._requests())
        except StopRequested:
            self._stopped = True
        return self._stopped

    def close(self) -> None:
        if self._db is not None and self._own:
            try:
                self._db.close()
            except sqlite3.Error:
                pass
            self._db = None
