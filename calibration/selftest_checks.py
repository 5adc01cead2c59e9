"""The judgements of the board self-test (:mod:`.selftest`): pure functions of measurements.

Each function takes what the board answered (ADC codes, ratios, counters) and says whether it is
what a healthy board gives and, if not, the likely cause in one sentence. No board I/O here, so
each rule can be tested on numbers alone.

Expected ranges and their sources (docs/bench.md, "Self-test"):

* ADC bits: on a healthy TLC3541 every output bit that the readings' range exercises is set in
  some readings and clear in others; a bit set in (nearly) all readings - the 0 V reads
  included - or in (nearly) none while the range crosses it many times is stuck. The readings are
  averages of 10 conversions, so a stuck bit can leak through an average that straddles a
  boundary: the thresholds are fractions (:data:`STUCK_HIGH`, :data:`STUCK_LOW`).
* open cells: a reading at the read code within :data:`OPEN_CODES` of the 0 V reading (below
  ~0.5 uS at 0.3 V through 3 kOhm, gain 11) carries no current; a rectangle of at least
  :data:`REGION_CELLS` such cells over >= 2 rows and >= 2 columns is a dead region, a whole
  row or column a dead line.
* the column path: a column read through the summing amplifier (R_sum) where the load resistor
  (R_load) is expected reads R_load / R_sum (9.09 on MemriCore) times the cells' prediction.
"""

from __future__ import annotations

import statistics
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["STUCK_HIGH", "STUCK_LOW", "OPEN_CODES", "REGION_CELLS", "stuck_bits",
           "dead_regions", "RatioVerdict", "judge_column_ratio", "judge_row_dacs"]

STUCK_HIGH = 0.8
"""A bit set in more than this fraction of the readings (0 V reads included) is stuck at 1
(a healthy board: at most ~0.45 on the emulator; bit 6 stuck at 1: 0.89)."""
STUCK_LOW = 0.05
"""A bit the readings' range exercises, set in fewer than this fraction, is stuck at 0."""
OPEN_CODES = 8
"""A reading at the read code at most this many codes above the 0 V reading: an open cell."""
REGION_CELLS = 4
"""Open cells in one rectangle (>= 2 rows and >= 2 columns) that make a dead region."""


def stuck_bits(readings: Sequence[int], bits: int = 14) -> list[tuple[int, int, float]]:
    """Output bits of the ADC that look stuck: (bit, level 0/1, fraction of readings with the
    bit set), lowest bit first. ``readings``: ADC readings (codes) of the whole self-test, 0 V
    reads included. A bit is judged only when the readings span at least four of its periods
    (``max - min >= 2^(bit + 2)``) and there are at least 40 readings."""
    values = np.asarray([int(r) for r in readings], dtype=np.int64)
    if values.size < 40:
        return []
    span = int(values.max() - values.min())
    found = []
    for bit in range(bits):
        if span < (1 << (bit + 2)):
            break
        frac = float(np.mean((values >> bit) & 1))
        if frac > STUCK_HIGH:
            found.append((bit, 1, frac))
        elif frac < STUCK_LOW:
            found.append((bit, 0, frac))
    return found


def dead_regions(open_mask: NDArray[np.bool_]) -> list[tuple[int, int, int, int, int]]:
    """Rectangles of open cells: (row0, row1, col0, col1, open cells in it), inclusive, for each
    4-connected group of open cells with at least :data:`REGION_CELLS` cells over >= 2 rows
    and >= 2 columns, or a whole row or column. ``open_mask``: bool (rows, cols)."""
    rows, cols = open_mask.shape
    seen = np.zeros_like(open_mask, dtype=bool)
    out = []
    for r0 in range(rows):
        for c0 in range(cols):
            if not open_mask[r0, c0] or seen[r0, c0]:
                continue
            stack, group = [(r0, c0)], []
            seen[r0, c0] = True
            while stack:
                r, c = stack.pop()
                group.append((r, c))
                for rr, cc in ((r + 1, c), (r - 1, c), (r, c + 1), (r, c - 1)):
                    if 0 <= rr < rows and 0 <= cc < cols and open_mask[rr, cc] \
                            and not seen[rr, cc]:
                        seen[rr, cc] = True
                        stack.append((rr, cc))
            rs = [g[0] for g in group]
            cs = [g[1] for g in group]
            box = (min(rs), max(rs), min(cs), max(cs))
            whole_line = (box[1] - box[0] + 1 == rows) or (box[3] - box[2] + 1 == cols)
            if (len(group) >= REGION_CELLS and box[1] > box[0] and box[3] > box[2]) \
                    or whole_line:
                out.append((*box, len(group)))
    return out


@dataclass(frozen=True)
class RatioVerdict:
    """A judged ratio of measured to predicted readings: ``ok`` and, if not, ``cause``."""

    ok: bool
    cause: str = ""


def judge_column_ratio(ratio: float, lo: float, hi: float, r_load_ohm: float,
                       r_sum_ohm: float) -> RatioVerdict:
    """Column reads / the cells' prediction (``ratio``, the median over the cells tried)
    against ``lo``..``hi``; the likely cause when outside."""
    if lo <= ratio <= hi:
        return RatioVerdict(True)
    load_path = r_load_ohm / r_sum_ohm
    if abs(ratio / load_path - 1.0) < 0.2:
        return RatioVerdict(False, (
            f"column reads are {ratio:.2f} x the cells' prediction, about R_load / R_sum = "
            f"{load_path:.2f}: the column output goes through the load resistor instead of the "
            "summing amplifier - the SUM_PATH line of the column register (74HC595 bit 4) is "
            "miswired (two column-register lines swapped?)"))
    if ratio < 0.05:
        return RatioVerdict(False, "column reads carry no current while single-cell reads do: "
                            "the row DACs (ROWDAC_EN), the summing amplifier or its ADC input")
    return RatioVerdict(False, (
        f"column reads are {ratio:.2f} x the cells' prediction: the summing amplifier's "
        "resistor R_sum, the row DACs' reference, or the column register's path lines"))


def judge_row_dacs(ratios: dict[int, list[float]], tolerance: float,
                   trend_limit: float) -> tuple[RatioVerdict, dict[int, dict[str, float]]]:
    """Per row DAC ``k``: the ratios (measured / predicted) of the columns of one spike, in the
    order the board read them. A DAC whose mean ratio is more than ``tolerance`` below (or
    above) the others' median is faulty; if its ratio also grows along the spike by more than
    ``trend_limit`` (the later columns are read tens of us later), its outputs settle slowly.
    A DAC whose ratio rises along the spike by ``trend_limit`` more than the others' rise is
    faulty as well (its mean may still be close: the later columns see it settled).
    Returns the verdict and per-DAC ``{"mean": .., "first": .., "last": ..}``."""
    summary = {k: {"mean": statistics.fmean(v), "first": v[0], "last": v[-1]}
               for k, v in ratios.items() if v}
    if len(summary) < 2:
        return RatioVerdict(True), summary
    bad = []
    for k, s in summary.items():
        others = [o["mean"] for j, o in summary.items() if j != k]
        ref = statistics.median(others)
        rises = [o["last"] - o["first"] for j, o in summary.items() if j != k]
        if ref > 0 and (abs(s["mean"] / ref - 1.0) > tolerance
                        or s["last"] - s["first"] - statistics.median(rises) > trend_limit):
            bad.append((k, s, ref))
    if not bad:
        return RatioVerdict(True), summary
    k, s, ref = max(bad, key=lambda b: abs(b[1]["first"] / b[2] - 1.0))
    low = s["mean"] < ref
    rows = f"rows {8 * k}-{8 * k + 7}"
    if low and s["last"] - s["first"] > trend_limit:
        cause = (f"row DAC {k} ({rows}) reads {100 * (1 - s['mean'] / ref):.0f} % low and "
                 f"rises along the spike ({s['first']:.2f} -> {s['last']:.2f} of the "
                 "prediction from the first to the last column read): its outputs settle "
                 "slowly (slow DAC: output buffer, load capacitance, reference)")
    else:
        cause = (f"row DAC {k} ({rows}) reads {s['mean'] / ref:.2f} x the other DACs: its "
                 "reference, gain setting or outputs")
    return RatioVerdict(False, cause), summary
