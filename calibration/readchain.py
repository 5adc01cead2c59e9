"""The board's read chain, calibrated: ADC codes <-> cell conductance from fitted offsets and gain.

The formulas of both read paths — cell read (READ_CELL, and the read after every WRITE_PULSE)
and column read (READ_COLUMN, SPIKE_BATCH) — and the board's constants are those of
:class:`~snan_hil.protocol.board.BoardConstants` (docs/calibration.md,
shared/reference/memricore-board.md). :class:`ReadChain` is a BoardConstants (from the board's
Info) with the three values a calibration fits: the ADC codes at 0 V of each path
(``offset_code``, ``offset_column_code``) and the common gain factor ``c`` (``gain_factor``).

What :func:`calibrate_read_chain` identifies, and what it cannot:

* ``offset_code`` / ``offset_column_code`` — the ADC codes at 0 V (reads at DAC code 0);
* linearity — reads of the same cells at 1/3, 2/3 and 3/3 of the read voltage; the fit
  ``a - a0 = s V`` must go through zero (reported: ``linearity_error``, ``intercept_code``);
* ``gain_factor`` ``c`` — a common error of the amplifier gain, ADC reference or DAC reference
  (anything that scales both paths alike): each calibration cell is read on both paths; their
  ratio depends only on X and the two *resistors* (R_load, R_sum), which gives X and then c.
  So the board's R_load and R_sum are the references: their own error, or a gain error of one
  path only, cannot be identified without known reference resistors. Neither can the select
  transistor's resistance (hence all conductances are of the 1T1R cell).
"""

from __future__ import annotations

import functools
import logging
import statistics
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np

from snan_hil.protocol.board import BoardConstants
from snan_hil.protocol.client import BoardClient
from snan_hil.protocol.errors import BoardError, UnsupportedError
from snan_hil.protocol.messages import Capability

__all__ = ["ReadChain", "calibrate_read_chain", "pick_calibration_cells", "GAIN_FACTOR_LIMITS"]

log = logging.getLogger(__name__)

GAIN_FACTOR_LIMITS = (0.5, 2.0)
"""A fitted gain factor outside this range is rejected (nominal kept, reason recorded)."""


@dataclass(frozen=True)
class ReadChain(BoardConstants):
    """The board's constants (from its Info) plus the fitted offsets and gain factor.

    The converters (``cell_conductance``, ``column_code``, ...) are BoardConstants'; here they
    use the fitted values instead of the nominal 0 / 0 / 1. ``calibrated``/``details``: whether
    a calibration ran and what it found (JSON-able, not compared).
    """

    offset_code: float = 0.0         # ADC code at 0 V, cell path
    offset_column_code: float = 0.0  # ADC code at 0 V, column path
    gain_factor: float = 1.0         # common multiplicative error c (1 = nominal)
    calibrated: bool = False
    details: dict[str, Any] = field(default_factory=dict, compare=False)

    # ------------------------------------------------------------------ construction
    @classmethod
    def nominal(cls, board: BoardConstants) -> ReadChain:
        """The chain as the board describes itself (no calibration); ``board``: its Info."""
        return cls(**{name: getattr(board, name) for name in BoardConstants.__dataclass_fields__})

    def to_dict(self) -> dict[str, Any]:
        """JSON-able fields (and the derived ``read_code``, for readers of the file)."""
        return {**asdict(self), "read_code": self.read_code}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ReadChain:
        """Inverse of :meth:`to_dict`; unknown and derived keys are ignored."""
        known = set(cls.__dataclass_fields__)
        return cls(**{k: v for k, v in data.items() if k in known})


# ---------------------------------------------------------------------- calibration
def _mean_reads(read: Callable[[], int], n: int) -> float:
    return statistics.fmean(read() for _ in range(n))


def calibrate_read_chain(client: BoardClient, cells: Sequence[tuple[int, int]],
                         gain_cells: Sequence[tuple[int, int]] | None = None, *,
                         n_reads: int = 8) -> ReadChain:
    """Identify offsets, linearity and the common gain factor from reads (no pulses).

    ``cells``: a few healthy cells for the offset and linearity reads; ``gain_cells``: cells for
    the two-path gain fit, best the highest-conductance ones (default: ``cells``). Every read is
    at or below the nominal read voltage. Returns a calibrated :class:`ReadChain`; parts that
    cannot be identified on this board (e.g. no READ_COLUMN over the legacy protocol) keep their
    nominal values, with the reason in ``details``.
    """
    info = client.info
    if info is None:
        info = client.hello()
    chain = ReadChain.nominal(info)
    code = chain.read_code
    cells = list(cells)[:4]
    gain_cells = list(gain_cells if gain_cells is not None else cells)[:8]
    details: dict[str, Any] = {"n_reads": n_reads, "cells": [list(c) for c in cells],
                     "gain_cells": [list(c) for c in gain_cells]}
    has_column = info.has(Capability.READ_COLUMN)

    # 1. offsets: reads at 0 V
    try:
        zeros = [client.read_cell(r, c, 0) for r, c in cells for _ in range(max(2, n_reads // 2))]
        offset = statistics.fmean(zeros) if zeros else 0.0
    except (BoardError, UnsupportedError) as exc:
        offset = 0.0
        details["offset"] = f"not identified ({exc}); nominal 0"
    offset_col = 0.0
    if has_column:
        try:
            offset_col = _mean_reads(lambda: client.read_column(0, [0] * info.rows), n_reads)
        except (BoardError, UnsupportedError) as exc:
            details["offset_column"] = f"not identified ({exc}); nominal 0"
    chain = replace(chain, offset_code=offset, offset_column_code=offset_col)

    # 2. linearity: a - a0 proportional to V through zero
    fracs = (1 / 3, 2 / 3, 1.0)
    lin_err, intercepts = [], []
    for r, c in cells:
        codes = [max(1, int(round(code * f))) for f in fracs]
        volts = np.array([chain.cell_read_volts(k) for k in codes])
        means = np.array([_mean_reads(functools.partial(client.read_cell, r, c, k), n_reads)
                          for k in codes]) - offset
        if means[-1] <= 0:
            continue
        slope = float(np.dot(volts, means) / np.dot(volts, volts))
        lin_err.append(float(np.max(np.abs(means - slope * volts)) / means[-1]))
        _, intercept = np.polyfit(volts, means, 1)
        intercepts.append(float(intercept))
    details["linearity_error"] = max(lin_err) if lin_err else None
    details["intercept_code"] = statistics.fmean(intercepts) if intercepts else None

    # 3. common gain factor from the cell path / column path ratio
    factors, xs = [], []
    if has_column and gain_cells:
        s1 = chain.cell_scale(code)          # with gain_factor 1
        s2 = chain.column_scale(code)
        rs1 = chain.r_switch_ohm + chain.r_load_ohm
        rs2 = chain.r_switch_ohm
        for r, c in gain_cells:
            a1 = _mean_reads(functools.partial(client.read_cell, r, c, code), n_reads) - offset
            row_codes = [0] * info.rows
            row_codes[r] = code
            a2 = _mean_reads(functools.partial(client.read_column, c, row_codes),
                             n_reads) - offset_col
            if a1 <= 0 or a2 <= 0:
                continue
            q = (a2 / a1) * (s1 / s2)            # = (X + rs1) / (X + rs2)
            if q <= 1.0:
                continue
            x = (rs1 - q * rs2) / (q - 1.0)
            if x <= 0:
                continue
            factors.append(a1 * (x + rs1) / s1)
            xs.append(x)
    if factors:
        c_fit = statistics.median(factors)
        spread = (statistics.pstdev(factors) / c_fit) if len(factors) > 1 else None
        details["gain_factors"] = [round(f, 6) for f in factors]
        details["gain_cells_ohm"] = [round(x, 1) for x in xs]
        details["gain_factor_spread"] = spread
        lo, hi = GAIN_FACTOR_LIMITS
        if lo <= c_fit <= hi:
            chain = replace(chain, gain_factor=float(c_fit))
        else:
            details["gain"] = (f"fitted factor {c_fit:.4f} outside {lo}..{hi}; nominal kept "
                               "(check the board constants)")
    else:
        details["gain"] = ("not identified (board has no READ_COLUMN or no usable cells); "
                           "nominal gain kept")
    log.info("read chain: offset %.2f / %.2f codes, gain factor %.5f, linearity %s",
             chain.offset_code, chain.offset_column_code, chain.gain_factor,
             details.get("linearity_error"))
    return replace(chain, calibrated=True, details=details)


def pick_calibration_cells(conductances: dict[tuple[int, int], float], *, n_offset: int = 4,
                           n_gain: int = 6) -> tuple[list[tuple[int, int]], list[tuple[int, int]]]:
    """Choose cells for :func:`calibrate_read_chain` from a screen {(row, col): G (S)}.

    Offset/linearity: cells of median conductance; gain: the highest-conductance cells (the
    two-path ratio is most sensitive to X at low X). Cells must be healthy (caller filters).
    """
    ranked = sorted(conductances, key=lambda rc: conductances[rc])
    if not ranked:
        return [], []
    mid = len(ranked) // 2
    lo = max(0, mid - n_offset // 2)
    offset_cells = ranked[lo:lo + n_offset]
    gain_cells = ranked[::-1][:n_gain]
    return offset_cells, gain_cells

