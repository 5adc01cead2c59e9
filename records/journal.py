"""The pulse journal of a run: every write pulse written down before it is sent and after its
reply, so a run killed at any moment leaves a true account of what its board did.

One JSON object a line, appended and flushed (not fsynced: a process kill loses nothing
written; a power cut may lose the last lines, which the board's pulse counter then decides):

* ``{"r": RUN, "n": N, "s": "sent", "u": UNIT, "c": [ROW, COL], "p": "SET", "v": VOLTS,
  "w": WIDTH_US, "st": STAGE, "b": BOARD}`` -- written *before* WRITE_PULSE goes out;
* ``{"r": RUN, "n": N, "s": "done", "g0": G_BEFORE_S, "g1": G_AFTER_S}`` -- its reply came
  (or the board's pulse counter said it ran);
* ``{"r": RUN, "n": N, "s": "lost"}`` -- the board's pulse counter says it never ran;
* ``{"r": RUN, "s": "base", "fw": COUNT, "boot": NONCE}`` -- the board's pulse counter when
  the run started (None over the legacy protocol) and its boot nonce (the counter of one boot
  only compares with the same boot's).

``RUN`` is the run's uid (one per start or resume of a job: a history run), ``N`` counts the
run's pulses from 0, so ``(RUN, N)`` names a pulse uniquely by construction; ``UNIT`` is the
key of the job's unit the pulse belongs to (its attempts are the runs that ran it). The job
runner (:mod:`snan_hil.lab.runner`) writes the journal through the cell bench and reads it
back to reconcile a killed run's pulses with the chip's history and to tell a resumed unit
which of its pulses already ran (docs/durability.md).

A line cut by a kill (or followed by garbage: a power cut's zeros) is named, never skipped
without a word: :func:`settle_torn` decides what happened to the pulse it leaves open -- from
the board's pulse counter where the board still has it (the same boot), else from the order the
lines are written in (a "sent" line goes before the request: a pulse whose "sent" line is cut
never went out) -- and says what it did in one line.

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

__all__ = ["PulseJournal", "JournalPulse", "JournalRead", "read_journal", "settle_torn"]

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
    boots: dict[str, int | None] = field(default_factory=dict)
    """The board's boot nonce at the start of each run (None: not recorded)."""
    path: Path | None = None
    after: dict[int, tuple[str, int | None] | None] = field(default_factory=dict)
    """Torn line -> (run, pulse number) of the last whole line before it (pulse number None:
    that line was the run's start); None when no whole line comes before it."""
    fragments: dict[int, str] = field(default_factory=dict)
    """Torn line -> its text (the start of a line a kill cut, or garbage)."""
    settled: set[int] = field(default_factory=set)
    """Torn lines already decided (:func:`settle_torn`)."""

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
    out = JournalRead(path=Path(path))
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except FileNotFoundError:
        return out
    by_key: dict[tuple[str, int], JournalPulse] = {}
    last: tuple[str, int | None] | None = None
    for no, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        try:
            d = json.loads(line)
            run, state = str(d["r"]), str(d["s"])
            if state == "base":
                fw, boot = d.get("fw"), d.get("boot")
                out.baselines[run] = None if fw is None else int(fw)
                out.boots[run] = None if boot is None else int(boot)
                last = (run, None)
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
            last = key
        except (ValueError, KeyError, TypeError, IndexError):
            out.torn.append(no)
            out.after[no] = last
            out.fragments[no] = line[:200]
    return out


def settle_torn(read: JournalRead, *, boot: int | None = None,
                counter: int | None = None) -> list[str]:
    """Decide the pulse each cut line of ``read`` leaves open (module doc) and say what was
    done, one line each (a cut line and the garbage right after it: one line). ``boot``,
    ``counter``: the board's boot nonce and pulse counter now (None: unknown), for the last
    run of the journal (a run after it gives its own start's). The pulses' states in
    ``read`` are updated ("done": it ran, counted and never sent again; "lost": it did not
    run; left "sent": uncertain, never sent again). A line is decided once."""
    told: list[str] = []
    groups: list[list[int]] = []
    for no in read.torn:
        if no in read.settled:
            continue
        if groups and no == groups[-1][-1] + 1:
            groups[-1].append(no)
        else:
            groups.append([no])
    for group in groups:
        read.settled.update(group)
        what = _settle_one(read, group[0], boot, counter)
        lines = f"line {group[0]}" if len(group) == 1 else f"lines {group[0]}-{group[-1]}"
        told.append(f"pulse journal {read.path}: {lines} cut or unreadable (a kill while "
                    f"writing it); {what}")
    return told


def _settle_one(read: JournalRead, no: int, boot: int | None, counter: int | None) -> str:
    """What happened to the pulse the cut line ``no`` leaves open (see settle_torn)."""
    before = read.after.get(no)
    if before is None:
        return "no pulse line before it: nothing to count"
    run, n = before
    pulse = next((p for p in read.of_run(run) if p.n == n), None) if n is not None else None
    executed = _executed(read, run, boot, counter)
    if pulse is None or pulse.state != "sent":
        # the pulse before it is accounted for: the cut line is the next pulse's "sent" line,
        # written before its request -- that pulse never went out
        agree = "" if executed is None else \
            " (the board's pulse counter agrees)" if executed == _done(read, run) else \
            f" (the board's pulse counter says {executed} pulses ran in that run, the journal " \
            f"{_done(read, run)}: check the board)"
        return f"it was the \"sent\" line of a pulse, written before its request: that pulse " \
               f"never went out, nothing to count or send again{agree}"
    where = f"pulse {pulse.n} of run {run} on cell {pulse.row},{pulse.col}"
    fragment = read.fragments.get(no, "")
    if executed is not None:
        ran = executed - _done(read, run)
        if ran in (0, 1):
            pulse.state = "done" if ran else "lost"
            return (f"it was the reply line of {where}; the board's pulse counter (same boot) "
                    + ("says it ran: counted as applied, never sent again" if ran else
                       "says it did not run: not applied"))
    for state, said in (("done", "ran: counted as applied, never sent again"),
                        ("lost", "did not run: not applied")):
        if f'"s":"{state}"' in fragment.replace(" ", ""):
            pulse.state = state
            return f"it was the \"{state}\" line of {where}, written after the reply: it {said}"
    why = "the board's pulse counter cannot tell (another boot, or none)" if executed is None \
        else f"the board's pulse counter says {executed} ran against {_done(read, run)} done"
    return (f"it was the reply line of {where}, cut before its state, and {why}: counted "
            "uncertain, never sent again")


def _done(read: JournalRead, run: str) -> int:
    return sum(1 for p in read.of_run(run) if p.state == "done")


def _executed(read: JournalRead, run: str, boot: int | None, counter: int | None
              ) -> int | None:
    """Pulses the board executed during ``run`` by its pulse counter: from the run's start to
    the next run's start (or ``counter`` now, for the journal's last run), when both are of
    the same boot; None when that cannot be told."""
    runs = read.runs()
    if run not in read.baselines or read.baselines[run] is None:
        return None
    start, start_boot = read.baselines[run], read.boots.get(run)
    later = runs[runs.index(run) + 1:]
    nxt = next((r for r in later if r in read.baselines), None)
    end, end_boot = (read.baselines[nxt], read.boots.get(nxt)) if nxt is not None \
        else (counter, boot)
    if start is None or end is None or start_boot is None or start_boot != end_boot:
        return None
    return end - start


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
            cut = _ends_mid_line(self.path)
            self._fh = open(self.path, "a", encoding="utf-8")   # noqa: SIM115 - kept open
            if cut:                   # a killed run's last line: ours starts on a line of its own
                self._fh.write("\n")
        self._fh.write(json.dumps(line, separators=(",", ":")) + "\n")
        self._fh.flush()

    def baseline(self, pulses_applied: int | None, boot: int | None = None) -> None:
        """The board's pulse counter as the run starts (None: the board has none) and its
        boot nonce (None: not known)."""
        line: dict[str, Any] = {"r": self.run, "s": "base", "fw": pulses_applied}
        if boot is not None:
            line["boot"] = int(boot)
        self._write(line)

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


def _ends_mid_line(path: Path) -> bool:
    """Whether the file at ``path`` exists and its last byte is not a newline."""
    try:
        with open(path, "rb") as fh:
            fh.seek(0, os.SEEK_END)
            if fh.tell() == 0:
                return False
            fh.seek(-1, os.SEEK_END)
            return fh.read(1) != b"\n"
    except FileNotFoundError:
        return False
