"""Measured pulses from files: a lab's own measurements and this project's exports, read into
the samples the device model is fitted on (``snan-hil characterize --from FILE``).

Three CSV forms, told apart by their header (comma-separated, one header line, column names
case-insensitive, any column order, extra columns ignored):

* **a lab's pulse CSV** (the documented plain format, docs/learning.md §1.1): one row per
  pulse, in the order the pulses were applied::

      cell,polarity,amplitude_v,width_us,g_before_s,g_after_s[,time_s]
      3:5,SET,0.8,100,2.10e-4,2.21e-4,0.013

  ``cell`` is ``R:C`` / ``R,C`` (quoted) / ``RxC`` — or ``row`` and ``col`` columns — or any
  other text naming a device (such cells are placed in order of first appearance at row
  ``k // 8``, column ``k % 8`` of the emulated array; the model's ``meta["cell_names"]`` keeps
  the mapping); ``polarity`` is SET / RESET (also set/reset, up/down, potentiation/
  depression, +/-); SET raises the conductance; ``amplitude_v`` (V, its sign is ignored: the
  polarity says which way), ``width_us`` (us), ``g_before_s`` / ``g_after_s`` (S, the cell read
  before and after the pulse), ``time_s`` (optional, s, any origin: for retention drift);
* **this project's history export** (``snan-hil history --export pulses``: ``id, run_id, row,
  col, n, time_utc, stage, polarity, amplitude_v, width_us, g_before_s, g_after_s``): every
  pulse of the chip's life (programming, characterisation, learning), in order; a pulse
  without a reading (``learn-recovered``) counts for wear only;
* **this project's characterise CSV** (``snan-hil characterize --csv``: ``row, col, polarity,
  g_before_s, g_after_s``): the pulses of one characterisation, all at the learning pulse
  given by ``--set-v/--reset-v/--width-us``.

The model is fitted at one learning pulse (:class:`~snan_hil.crossbar_model.fitted.
LearningPulse`): the rows of that amplitude and width (tolerance 1 mV, 0.5 us) are the
samples; every other pulse of a cell still counts in its wear (``swing_before``: the
cumulative ``|Δ ln G|`` of the cell's earlier pulses in the file). A bad row is one
:class:`UserError` line naming the file, the row's line number and what to fix; nothing is
fitted from a file with a bad row.
"""

from __future__ import annotations

import csv
import datetime
import math
import re
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from snan_hil.common.errors import UserError
from snan_hil.common.polarity import Polarity
from snan_hil.crossbar_model.fitted import LearningPulse, PulseSample

__all__ = ["PulseRow", "PulseFile", "read_pulse_file", "retention_pairs", "LAB_COLUMNS",
           "ARRAY_COLS"]

LAB_COLUMNS = ("cell", "polarity", "amplitude_v", "width_us", "g_before_s", "g_after_s")
"""The columns of a lab's pulse CSV (``time_s`` optional; ``row``, ``col`` may replace
``cell``)."""
ARRAY_COLS = 8
"""Cells named by text are placed row by row in an array this wide (the MemriCore chip's)."""
AMPLITUDE_TOL_V = 1e-3
WIDTH_TOL_US = 0.5

_POLARITY_WORDS = {"set": Polarity.SET, "up": Polarity.SET, "potentiation": Polarity.SET,
                   "+": Polarity.SET, "reset": Polarity.RESET, "down": Polarity.RESET,
                   "depression": Polarity.RESET, "-": Polarity.RESET}
_CELL_PAIR = re.compile(r"^\s*(\d+)\s*[,:xX]\s*(\d+)\s*$")


@dataclass(frozen=True)
class PulseRow:
    """One pulse of a file: cell, polarity, amplitude (V), width (us), conductances read
    before and after (S; None: not read), time (s; None: unknown), the file's line number."""

    row: int
    col: int
    polarity: Polarity
    amplitude_v: float | None
    width_us: float | None
    g_before_s: float | None
    g_after_s: float | None
    time_s: float | None
    line: int


@dataclass
class PulseFile:
    """What a pulse file holds: its form (``lab``, ``history``, ``characterize``), its rows in
    order, the names of text-named cells (name -> (row, col))."""

    path: Path
    form: str
    rows: list[PulseRow]
    cell_names: dict[str, tuple[int, int]] = field(default_factory=dict)

    def pulses_by_kind(self) -> Counter[tuple[str, float | None, float | None]]:
        """How many pulses of each (polarity, amplitude V, width us) the file holds."""
        return Counter((r.polarity.name, None if r.amplitude_v is None else round(
            r.amplitude_v, 4), r.width_us) for r in self.rows)

    def most_common_pulse(self) -> LearningPulse:
        """The most frequent SET and RESET pulses of the file (amplitude, width) as a
        learning pulse; UserError when a polarity is missing or widths differ."""
        kinds = self.pulses_by_kind()
        best: dict[Polarity, tuple[float, float]] = {}
        for pol in (Polarity.SET, Polarity.RESET):
            mine = [(n, a, w) for (p, a, w), n in kinds.items()
                    if p == pol.name and a is not None and w is not None]
            if not mine:
                raise UserError(f"{self.path}: no {pol.name} pulse with an amplitude and width; "
                                "give --set-v, --reset-v and --width-us")
            _n, a, w = max(mine)
            best[pol] = (a, w)
        (sv, sw), (rv, rw) = best[Polarity.SET], best[Polarity.RESET]
        if abs(sw - rw) > WIDTH_TOL_US:
            raise UserError(f"{self.path}: the commonest SET pulses are {sw:g} us wide, the "
                            f"RESET pulses {rw:g} us; give --width-us (and --set-v, --reset-v)")
        return _pulse(sv, rv, sw, self.path)

    def samples(self, pulse: LearningPulse) -> list[PulseSample]:
        """The pulses at ``pulse`` with both readings, as fit samples in file order, each with
        its cell's cumulative swing before it (every pulse of the cell counts) and its time.
        UserError (naming the pulses the file holds) when none is at ``pulse``."""
        swing: dict[tuple[int, int], float] = {}
        out: list[PulseSample] = []
        for r in self.rows:
            key = (r.row, r.col)
            before = swing.get(key, 0.0)
            if r.g_before_s is not None and r.g_after_s is not None:
                swing[key] = before + abs(math.log(r.g_after_s / r.g_before_s))
            if r.g_before_s is None or r.g_after_s is None or not _at(r, pulse):
                continue
            out.append(PulseSample(r.row, r.col, r.polarity, r.g_before_s, r.g_after_s,
                                   swing_before=before, time_s=r.time_s))
        have = {p for p in (Polarity.SET, Polarity.RESET) if any(s.polarity == p for s in out)}
        if len(have) < 2:
            kinds = ", ".join(f"{p} {'?' if a is None else f'{a:g} V'} / "
                              f"{'?' if w is None else f'{w:g} us'}: {n}"
                              for (p, a, w), n in self.pulses_by_kind().most_common(6))
            raise UserError(f"{self.path}: no {'SET' if Polarity.SET not in have else 'RESET'} "
                            f"pulse with both readings at SET {pulse.set_v:g} V / RESET "
                            f"{pulse.reset_v:g} V, {pulse.width_us} us (the file holds {kinds});"
                            " give --set-v, --reset-v and --width-us of the pulses to fit")
        return out


def _pulse(set_v: float, reset_v: float, width_us: float, path: Path) -> LearningPulse:
    try:
        return LearningPulse(float(set_v), float(reset_v), int(round(width_us)))
    except ValueError as exc:
        raise UserError(f"{path}: {exc}") from None


def _at(r: PulseRow, pulse: LearningPulse) -> bool:
    if r.width_us is not None and abs(r.width_us - pulse.width_us) > WIDTH_TOL_US:
        return False
    if r.amplitude_v is None:
        return True
    return abs(r.amplitude_v - pulse.amplitude(r.polarity)) <= AMPLITUDE_TOL_V


# ---- reading --------------------------------------------------------------------------------
def read_pulse_file(path: str | Path) -> PulseFile:
    """Read a pulse CSV (module doc). UserError, one line, for a missing or unreadable file,
    a header of none of the three forms, or a bad row (its line number and what to fix)."""
    p = Path(path).expanduser()
    try:
        text = p.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise UserError(f"pulse file {p} does not exist") from None
    except IsADirectoryError:
        raise UserError(f"pulse file {p} is a directory; give a CSV file") from None
    except UnicodeDecodeError:
        raise UserError(f"pulse file {p} is not a text (UTF-8) CSV file") from None
    except OSError as exc:
        raise UserError(f"cannot read pulse file {p}: {exc.strerror or exc}") from None
    reader = csv.reader(text.splitlines())
    try:
        header = next(reader)
    except StopIteration:
        raise UserError(f"pulse file {p} is empty; {_FORMS}") from None
    except csv.Error as exc:
        raise UserError(f"pulse file {p} line 1: {exc}; {_FORMS}") from None
    names = [h.strip().lower() for h in header]
    form = _form(names, p)
    col = {n: i for i, n in enumerate(names)}
    out = PulseFile(p, form, [])
    try:
        for line_no, values in enumerate(reader, start=2):
            if not values or all(not v.strip() for v in values):
                continue
            if len(values) < len(names):
                raise UserError(f"{p} line {line_no}: {len(values)} fields, the header has "
                                f"{len(names)}; fill every column (an empty field where a "
                                "value is unknown)")
            out.rows.append(_row(values, col, form, out, line_no))
    except csv.Error as exc:
        raise UserError(f"{p} line {reader.line_num}: {exc}") from None
    if not out.rows:
        raise UserError(f"pulse file {p} has a header but no pulses")
    return out


_FORMS = ("give a CSV with the header " + ",".join(LAB_COLUMNS) + "[,time_s] (or row,col "
          "instead of cell), a 'snan-hil history --export pulses' file or a 'snan-hil "
          "characterize --csv' file")


def _form(names: list[str], path: Path) -> str:
    have = set(names)
    if {"run_id", "row", "col", "n", "polarity", "amplitude_v", "width_us", "g_before_s",
            "g_after_s"} <= have:
        return "history"
    cell = "cell" in have or {"row", "col"} <= have
    if cell and {"polarity", "amplitude_v", "width_us", "g_before_s", "g_after_s"} <= have:
        return "lab"
    if {"row", "col", "polarity", "g_before_s", "g_after_s"} <= have:
        return "characterize"
    missing = [c for c in LAB_COLUMNS if c not in have and not (c == "cell" and cell)]
    raise UserError(f"pulse file {path}: header lacks {', '.join(missing)}; {_FORMS}")


def _number(text: str, what: str, where: str, *, positive: bool = True,
            optional: bool = False) -> float | None:
    t = text.strip()
    if not t:
        if optional:
            return None
        raise UserError(f"{where}: {what} is empty; give a number")
    try:
        v = float(t)
    except ValueError:
        raise UserError(f"{where}: {what} {t!r} is not a number") from None
    if not math.isfinite(v):
        raise UserError(f"{where}: {what} {t!r} is not finite")
    if positive and not v > 0:
        raise UserError(f"{where}: {what} {t} must be above 0"
                        + (" (S: a conductance, not a resistance)" if what.startswith("g_")
                           else ""))
    return v


def _row(values: list[str], col: dict[str, int], form: str, out: PulseFile,
         line_no: int) -> PulseRow:
    where = f"{out.path} line {line_no}"

    def get(name: str) -> str:
        return values[col[name]] if name in col else ""

    row, c = _cell(get, col, out, where)
    word = get("polarity").strip().lower()
    if word not in _POLARITY_WORDS:
        raise UserError(f"{where}: polarity {get('polarity').strip()!r} is not SET or RESET")
    pol = _POLARITY_WORDS[word]
    amp = width = None
    if form != "characterize":
        a = _number(get("amplitude_v"), "amplitude_v", where, positive=False)
        assert a is not None
        if a == 0:
            raise UserError(f"{where}: amplitude_v is 0; a pulse needs an amplitude (V)")
        amp = abs(a)
        width = _number(get("width_us"), "width_us", where)
    readings_optional = form == "history"
    gb = _number(get("g_before_s"), "g_before_s", where, optional=readings_optional)
    ga = _number(get("g_after_s"), "g_after_s", where, optional=readings_optional)
    t = _time(get, col, form, where)
    return PulseRow(row, c, pol, amp, width, gb, ga, t, line_no)


def _cell(get: Any, col: dict[str, int], out: PulseFile, where: str) -> tuple[int, int]:
    if "row" in col and "col" in col:
        r = _number(get("row"), "row", where, positive=False)
        c = _number(get("col"), "col", where, positive=False)
        assert r is not None and c is not None
        if r != int(r) or c != int(c) or r < 0 or c < 0:
            raise UserError(f"{where}: row, col must be whole numbers >= 0, got "
                            f"{get('row').strip()}, {get('col').strip()}")
        return int(r), int(c)
    text = get("cell").strip()
    if not text:
        raise UserError(f"{where}: cell is empty; name the cell (R:C or any text)")
    m = _CELL_PAIR.match(text)
    if m:
        return int(m.group(1)), int(m.group(2))
    if text not in out.cell_names:
        k = len(out.cell_names)
        out.cell_names[text] = (k // ARRAY_COLS, k % ARRAY_COLS)
    return out.cell_names[text]


def _time(get: Any, col: dict[str, int], form: str, where: str) -> float | None:
    if form == "history" and "time_utc" in col:
        text = get("time_utc").strip()
        if not text:
            return None
        try:
            t = datetime.datetime.fromisoformat(text.replace("Z", "+00:00"))
        except ValueError:
            raise UserError(f"{where}: time_utc {text!r} is not an ISO 8601 time") from None
        if t.tzinfo is None:
            t = t.replace(tzinfo=datetime.timezone.utc)
        return t.timestamp()
    if "time_s" in col:
        return _number(get("time_s"), "time_s", where, positive=False, optional=True)
    return None


def retention_pairs(pf: PulseFile) -> list[tuple[float, float, float]]:
    """``(gap s, G after the earlier pulse S, G before the later one S)`` for consecutive
    pulses of each cell with both times and both readings (the drift fit's data,
    :func:`snan_hil.crossbar_model.aging.fit_aging`)."""
    last: dict[tuple[int, int], PulseRow] = {}
    out: list[tuple[float, float, float]] = []
    for r in pf.rows:
        key = (r.row, r.col)
        prev = last.get(key)
        if prev is not None and prev.time_s is not None and r.time_s is not None \
                and prev.g_after_s is not None and r.g_before_s is not None:
            out.append((r.time_s - prev.time_s, prev.g_after_s, r.g_before_s))
        last[key] = r
    return out
