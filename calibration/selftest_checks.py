"""The judgements of the board self-test (:mod:`.selftest`): pure functions of measurements.

Each function takes what the board answered (ADC codes, ratios, counters) and says whether it is
what a healthy board gives and, if not, the likely cause in one sentence. No board I/O here, so
each rule can be tested on numbers alone.

Expected ranges and their sources (docs/bench.md, "Self-test"):

* ADC bits: on a healthy TLC3541 every output bit that the readings' range exercises is set in
  some readings and clear in others; a bit set in (nearly) all readings - the 0 V reads
  included - or in (nearly) none of the readings above it is stuck. The readings are averages
  of 10 conversions, so only quiet readings (0 V, a fine low-voltage sweep) are judged, and a
  stuck bit can leak through an average that straddles a boundary: the thresholds are
  fractions (:data:`STUCK_HIGH`, :data:`STUCK_LOW`). Bits 0-2 stuck at 0 hide in the average
  of 10 (a sum of even codes divided by 10 need not be even); they are not judged reliably.
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
"""A bit set in more than this fraction of the quiet readings (0 V reads included) is stuck at
1 (a healthy board: ~0.1 on the emulator, the 0 V reads being ~0; bit 2 stuck at 1: 0.85)."""
STUCK_LOW = 0.6
"""A bit set in fewer than this part of the share its readings' span would give (~0.5) is stuck
at 0 (healthy: 0.45-0.55 of readings on the emulator; bit 5 stuck at 0: 0.13-0.21, bit 3:
0.27 - an average of 10 that straddles a boundary of the bit leaks through)."""
OPEN_CODES = 8
"""A reading at the read code at most this many codes above the 0 V reading: an open cell."""
REGION_CELLS = 4
"""Open cells in one rectangle (>= 2 rows and >= 2 columns) that make a dead region."""


def stuck_bits(quiet: Sequence[int], bits: int = 14) -> list[tuple[int, int, float]]:
    """Output bits of the ADC that look stuck: (bit, level 0/1, fraction of readings with the
    bit set), lowest bit first.

    ``quiet``: readings whose noise is well below one code step of the bits judged - the 0 V
    reads and a fine voltage sweep of cells from 0 V (the board averages 10 conversions, so
    the read noise of a cell at the full read voltage, ~10 codes, would blur every low bit).
    Stuck at 1: the bit is set in more than :data:`STUCK_HIGH` of all of them (the 0 V reads
    included, which a healthy ADC gives as ~0). Stuck at 0: among the readings of at least
    ``2^(bit+1)`` (at least 8, spanning at least two periods of the bit), the bit is set in
    fewer than :data:`STUCK_LOW` x the fraction of that span where it would be set.
    Fewer than 40 readings: nothing is judged."""
    values = np.asarray([int(r) for r in quiet], dtype=np.int64)
    if values.size < 40:
        return []
    found = []
    for bit in range(bits):
        frac = float(np.mean((values >> bit) & 1))
        if frac > STUCK_HIGH:
            found.append((bit, 1, frac))
            continue
        above = values[values >= (2 << bit)]
        if above.size < 8:
            continue
        lo, hi = int(above.min()), int(above.max())
        if hi - lo < (4 << bit):
            continue
        span = np.arange(lo, hi + 1, dtype=np.int64)
        expected = float(np.mean((span >> bit) & 1))
        frac_above = float(np.mean((above >> bit) & 1))
        if expected >= 0.3 and frac_above < STUCK_LOW * expected:
            found.append((bit, 0, frac_above))
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
    order the board read them. A DAC is **slow** when its first column (read right after the
    DAC update) is more than ``tolerance`` below the other DACs' first columns and more than
    ``trend_limit`` below its own later columns (which see it settled); it is **off** when its
    mean ratio is more than ``tolerance`` away from the others' median (a reference, gain or
    output fault). A common error of every DAC (the amplifier gain) is neither.
    Returns the verdict and per-DAC ``{"mean": .., "first": .., "rest": .., "last": ..}``."""
    summary = {k: {"mean": statistics.fmean(v), "first": v[0],
                   "rest": statistics.fmean(v[1:]) if len(v) > 1 else v[0], "last": v[-1]}
               for k, v in ratios.items() if v}
    if len(summary) < 2:
        return RatioVerdict(True), summary
    slow, off = [], []
    for k, s in summary.items():
        ref_mean = statistics.median(o["mean"] for j, o in summary.items() if j != k)
        ref_first = statistics.median(o["first"] for j, o in summary.items() if j != k)
        if ref_first > 0 and s["first"] / ref_first < 1.0 - tolerance \
                and s["rest"] - s["first"] > trend_limit:
            slow.append((s["first"] / ref_first, k, s))
        elif ref_mean > 0 and abs(s["mean"] / ref_mean - 1.0) > tolerance:
            off.append((abs(s["mean"] / ref_mean - 1.0), k, s, ref_mean))
    if slow:
        _, k, s = min(slow, key=lambda x: x[0])
        return RatioVerdict(False, (
            f"row DAC {k} (rows {8 * k}-{8 * k + 7}) reads {s['first']:.2f} of the prediction "
            f"in the first column of a spike and {s['rest']:.2f} in the later ones (the other "
            "DACs: the same in every column): its outputs settle slowly (slow DAC: output "
            "buffer, load capacitance, reference)")), summary
    if off:
        _, k, s, ref = max(off, key=lambda x: x[0])
        return RatioVerdict(False, (
            f"row DAC {k} (rows {8 * k}-{8 * k + 7}) reads {s['mean'] / ref:.2f} x the other "
            "DACs: its reference, gain setting or outputs")), summary
    return RatioVerdict(True), summary
