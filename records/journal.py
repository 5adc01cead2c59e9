"""The pulse journal of a run: every write pulse written down before it is sent and after its
reply, so a run killed at any moment leaves a true account of what its board did.

One JSON object a line, appended and flushed (not fsynced: a process kill loses nothing
written; a power cut may lose the last lines, which the board's pulse counter then decides):

* ``{"r": RUN, "n": N, "s": "sent", "u": UNIT, "c": [ROW, COL], "p": "SET", "v": VOLTS,
  "w": WIDTH_US, "st": STAGE, "b": BOARD}`` -- written *before* WRITE_PULSE goes out;
* ``{"r": RUN, "n": N, "s": "done", "g0": G_BEFORE_S, "g1": G_AFTER_S}`` -- its reply came
  (or the board's pulse counter said it ran);
* ``{"r": RUN, "n": N, "s": "lost"}`` -- the board's pulse counter says it never ran;
* ``{"r": RUN, "s": "base", "fw": COUNT}`` -- the board's pulse counter when the run started
  (None over the legacy protocol).

``RUN`` is the run's uid (one per start or resume of a job: a history run), ``N`` counts the
run's pulses from 0, so ``(RUN, N)`` names a pulse uniquely by construction; ``UNIT`` is the
key of the job's unit the pulse belongs to (its attempts are the runs that ran it). The job
runner (:mod:`snan_hil.lab.runner`) writes the journal through the cell bench and reads it
back to reconcile a killed run's pulses with the chip's history and to tell a resumed unit
which of its pulses already ran (docs/durability.md).

A base module: it imports no layer.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

__all__ = ["PulseJournal", "JournalPulse", "JournalRead", "read_journal"]

log = logging.getLogger(__name__)


@dataclass
class JournalPulse:
    """One pulse of a journal: run uid, its number in the run, state ("sent": it may or may
    not have run; "done"; "lost": it did not run), unit key, cell, polarity name, amplitude
    (V), width (us), stage, board, conductances before and after (S, when done)."""

    run: str
    n: int
    state: str
    unit: str | None = None
    row: int = -1
    col: int = -1
    polarity: str = "SET"
    amplitude_v: float = 0.0
    width_us: int = 0
    stage: str | None = None
    board: int | None = None
    g_before_s: float | None = None
    g_after_s: float | None = None


@dataclass
class JournalRead:
    """A journal as read back: its pulses in the order they were sent, the board's pulse
    counter at the start of each run (None: unknown), and the lines that could not be read
    (1-based line numbers: a line cut by a kill, or garbage)."""

    pulses: list[JournalPulse] = field(default_factory=list)
    baselines: dict[str, int | None] = field(default_factory=dict)
    torn: list[int] = field(default_factory=list)

    def runs(self) -> list[str]:
        """The runs that wrote this journal, in the order they started."""
        seen: dict[str, None] = dict.fromkeys(self.baselines)
        for p in self.pulses:
            seen.setdefault(p.run, None)
        return list(seen)

    def of_run(self, run: str) -> list[JournalPulse]:
        return [p for p in self.pulses if p.run == run]

    def of_unit(self, unit: str) -> list[JournalPulse]:
        return [p for p in self.pulses if p.unit == unit]


def read_journal(path: Path) -> JournalRead:
    """Read the journal at ``path`` (an empty account when it does not exist)."""
    out = JournalRead()
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except FileNotFoundError:
        return out
    by_key: dict[tuple[str, int], JournalPulse] = {}
    for no, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        try:
            d = json.loads(line)
            run, state = str(d["r"]), str(d["s"])
            if state == "base":
                fw = d.get("fw")
                out.baselines[run] = None if fw is None else int(fw)
                continue
            key = (run, int(d["n"]))
            if state == "sent":
                cell = d["c"]
                p = JournalPulse(run, key[1], "sent", d.get("u"), int(cell[0]), int(cell[1]),
                                 str(d["p"]), float(d["v"]), int(d["w"]), d.get("st"),
                                 d.get("b"))
                by_key[key] = p
                out.pulses.append(p)
            elif state in ("done", "lost") and key in by_key:
                p = by_key[key]
                p.state = state
                if state == "done":
                    p.g_before_s = _num(d.get("g0"))
                    p.g_after_s = _num(d.get("g1"))
            else:
                raise ValueError(f"unknown state {state!r}")
        except (ValueError, KeyError, TypeError, IndexError):
            out.torn.append(no)
    return out


def _num(x: Any) -> float | None:
    return None if x is None else float(x)


class PulseJournal:
    """Appends the pulses of run ``run`` to the journal at ``path`` (see the module doc);
    ``board``: the board's number in a run over several boards (each line names it)."""

    def __init__(self, path: Path, run: str, *, board: int | None = None) -> None:
        self.path = Path(path)
        self.run = str(run)
        self.board = board
        self._n = 0
        self._fh: TextIO | None = None
        self.unit: str | None = None
        """The unit the next pulses belong to (set by the runner before each unit)."""

    def _write(self, line: dict[str, Any]) -> None:
        if self._fh is None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._fh = open(self.path, "a", encoding="utf-8")   # noqa: SIM115 - kept open
        self._fh.write(json.dumps(line, separators=(",", ":")) + "\n")
        self._fh.flush()

    def baseline(self, pulses_applied: int | None) -> None:
        """The board's pulse counter as the run starts (None: the board has none)."""
        self._write({"r": self.run, "s": "base", "fw": pulses_applied})

    def sent(self, row: int, col: int, polarity: str, amplitude_v: float, width_us: int,
             stage: str | None) -> int:
        """A pulse is about to be sent: its number in the run."""
        n = self._n
        self._n += 1
        line: dict[str, Any] = {"r": self.run, "n": n, "s": "sent", "u": self.unit,
                                "c": [int(row), int(col)], "p": polarity,
                                "v": round(float(amplitude_v), 6), "w": int(width_us),
                                "st": stage}
        if self.board is not None:
            line["b"] = self.board
        self._write(line)
        return n

    def done(self, n: int, g_before_s: float | None, g_after_s: float | None) -> None:
        self._write({"r": self.run, "n": int(n), "s": "done", "g0": g_before_s,
                     "g1": g_after_s})

    def lost(self, n: int) -> None:
        self._write({"r": self.run, "n": int(n), "s": "lost"})

    def sync(self) -> None:
        """Make what is written durable (fsync)."""
        if self._fh is not None:
            os.fsync(self._fh.fileno())

    def close(self) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None

    def __iter__(self) -> Iterator[JournalPulse]:
        return iter(read_journal(self.path).pulses)
