"""The board's read chain: ADC codes <-> cell conductance, and its calibration from reads.

Two read paths (docs/calibration.md, shared/reference/memricore-board.md):

* **cell read** (READ_CELL, and the read after every WRITE_PULSE): the cell in series with the
  switches and the load resistor, the amplifier across the load::

      a = a0 + c * gain * R_load * 2^bits / Vref_adc * V / (X + R_sw + R_load)

* **column read** (READ_COLUMN, SPIKE_BATCH): the column at the summing amplifier's virtual
  ground; for the cells of the driven rows::

      a = a0_col + c * gain * R_sum * 2^bits / Vref_adc * sum_i V_i / (X_i + R_sw)

``X = 1/G`` is the resistance of the whole 1T1R cell (memristor + select transistor; the two are
always in series and cannot be told apart by any read). ``V`` comes from the DAC code
(write DAC for cell reads, row DAC for column reads). The board constants come from its Info.

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

import logging
import statistics
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from snan_hil.protocol.errors import BoardError, UnsupportedError
from snan_hil.protocol.messages import Capability, Info
from snan_hil.protocol.safety import HostLimits

__all__ = ["ReadChain", "calibrate_read_chain", "pick_calibration_cells", "read_code_for",
           "max_read_code", "GAIN_FACTOR_LIMITS"]

log = logging.getLogger(__name__)

GAIN_FACTOR_LIMITS = (0.5, 2.0)
"""A fitted gain factor outside this range is rejected (nominal kept, reason recorded)."""

_MIN_X_OHM = 1.0


@dataclass(frozen=True)
class ReadChain:
    """Board constants (from Info) plus the identified offsets and gain factor."""

    adc_bits: int = 14
    adc_vref_v: float = 5.0
    dac_bits: int = 12
    dac_vref_v: float = 5.0
    write_dac_bits: int = 12
    write_dac_vref_v: float = 5.0
    gain: float = 11.0
    r_load_ohm: float = 3000.0
    r_switch_ohm: float = 10.0
    sum_gain_ohm: float = 330.0
    read_code: int = 245             # DAC code of the nominal read voltage (<= 0.3 V)
    offset_code: float = 0.0         # ADC code at 0 V, cell path
    offset_column_code: float = 0.0  # ADC code at 0 V, column path
    gain_factor: float = 1.0         # common multiplicative error c (1 = nominal)
    calibrated: bool = False
    details: dict = field(default_factory=dict, compare=False)

    # ------------------------------------------------------------------ construction
    @classmethod
    def nominal(cls, info: Info) -> "ReadChain":
        """The chain as the board describes itself (no calibration)."""
        return cls(adc_bits=info.adc_bits, adc_vref_v=info.adc_vref_v, dac_bits=info.dac_bits,
                   dac_vref_v=info.dac_vref_v, write_dac_bits=info.write_dac_bits,
                   write_dac_vref_v=info.write_dac_vref_v, gain=info.gain,
                   r_load_ohm=info.r_load_ohm, r_switch_ohm=info.r_switch_ohm,
                   sum_gain_ohm=info.sum_gain_ohm, read_code=read_code_for(info))

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> "ReadChain":
        known = {f for f in cls.__dataclass_fields__}
        return cls(**{k: v for k, v in data.items() if k in known})

    # ------------------------------------------------------------------ voltages
    def cell_read_volts(self, code: int | None = None) -> float:
        """Read voltage (V) of a cell read at write-DAC ``code`` (default: nominal)."""
        code = self.read_code if code is None else code
        return code * self.write_dac_vref_v / (2 ** self.write_dac_bits - 1)

    def row_volts(self, code: int | None = None) -> float:
        """Row voltage (V) of a column read at row-DAC ``code`` (default: nominal)."""
        code = self.read_code if code is None else code
        return code * self.dac_vref_v / (2 ** self.dac_bits - 1)

    @property
    def _codes_per_volt(self) -> float:
        return 2 ** self.adc_bits / self.adc_vref_v

    # ------------------------------------------------------------------ cell path
    def cell_scale(self, read_code: int | None = None) -> float:
        """``c * gain * R_load * 2^bits / Vref * V`` (code * Ohm) of the cell path."""
        return (self.gain_factor * self.gain * self.r_load_ohm * self._codes_per_volt
                * self.cell_read_volts(read_code))

    def cell_resistance(self, adc, read_code: int | None = None):
        """Cell resistance X (Ohm, memristor + transistor) from a cell-read ADC code.

        Codes at or below the offset give ``inf`` (open cell)."""
        a = np.asarray(adc, dtype=float) - self.offset_code
        with np.errstate(divide="ignore"):
            x = np.where(a > 0, self.cell_scale(read_code) / np.where(a > 0, a, 1.0)
                         - self.r_switch_ohm - self.r_load_ohm, np.inf)
        x = np.maximum(x, _MIN_X_OHM)
        return float(x) if x.ndim == 0 else x

    def cell_conductance(self, adc, read_code: int | None = None):
        """Cell conductance G = 1/X (S) from a cell-read ADC code."""
        x = np.asarray(self.cell_resistance(adc, read_code), dtype=float)
        g = 1.0 / x
        return float(g) if g.ndim == 0 else g

    def cell_code(self, conductance_s, read_code: int | None = None):
        """Expected cell-read ADC code (float) of a cell of conductance G (S)."""
        g = np.asarray(conductance_s, dtype=float)
        a = self.offset_code + self.cell_scale(read_code) * g / (
            1.0 + g * (self.r_switch_ohm + self.r_load_ohm))
        return float(a) if a.ndim == 0 else a

    # ------------------------------------------------------------------ column path
    def column_scale(self, row_code: int | None = None) -> float:
        """``c * gain * R_sum * 2^bits / Vref * V`` (code * Ohm) of the column path."""
        return (self.gain_factor * self.gain * self.sum_gain_ohm * self._codes_per_volt
                * self.row_volts(row_code))

    def column_current_a(self, adc):
        """Column current (A) from a column-read ADC code."""
        a = np.asarray(adc, dtype=float) - self.offset_column_code
        i = a / (self.gain_factor * self.gain * self.sum_gain_ohm * self._codes_per_volt)
        return float(i) if i.ndim == 0 else i

    def column_effective_conductance(self, adc, row_code: int | None = None):
        """Sum over driven rows of ``1 / (X_i + R_sw)`` (S), all rows at ``row_code``."""
        a = np.asarray(adc, dtype=float) - self.offset_column_code
        g = a / self.column_scale(row_code)
        return float(g) if g.ndim == 0 else g

    def column_cell_conductance(self, adc, row_code: int | None = None):
        """Cell conductance G = 1/X (S) from a column read with ONE driven row (a spike)."""
        geff = np.asarray(self.column_effective_conductance(adc, row_code), dtype=float)
        with np.errstate(divide="ignore"):
            x = np.where(geff > 0, 1.0 / np.where(geff > 0, geff, 1.0) - self.r_switch_ohm,
                         np.inf)
        x = np.maximum(x, _MIN_X_OHM)
        g = 1.0 / x
        return float(g) if g.ndim == 0 else g

    def column_code(self, conductance_s, row_code: int | None = None):
        """Expected column-read ADC code of one driven cell of conductance G (S)."""
        g = np.asarray(conductance_s, dtype=float)
        a = self.offset_column_code + self.column_scale(row_code) * g / (
            1.0 + g * self.r_switch_ohm)
        return float(a) if a.ndim == 0 else a


def read_code_for(info: Info) -> int:
    """DAC code of the board's nominal read voltage, never above its read limit.

    The board reference calls code 246 (0.3004 V) its 0.3 V read; this host never exceeds
    ``max_read_v``, so it uses the largest code at or below it (245 = 0.2991 V).
    """
    nominal = info.dac_code(min(info.v_read_v, info.max_read_v))
    return min(nominal, max_read_code(info))


def max_read_code(info: Info) -> int:
    """Largest DAC code this host sends for a read: never above ``max_read_v`` (V).

    0.3 V is not a whole code at 12 bits / 5 V: 245 (0.2991 V) is used, not 246 (0.3004 V).
    The same limit the protocol clients enforce (:class:`~snan_hil.protocol.safety.HostLimits`).
    """
    return HostLimits.from_info(info).max_read_code


# ---------------------------------------------------------------------- calibration
def _mean_reads(read, n: int) -> float:
    return statistics.fmean(read() for _ in range(n))


def calibrate_read_chain(client, cells: Sequence[tuple[int, int]],
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
    details: dict = {"n_reads": n_reads, "cells": [list(c) for c in cells],
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
        means = np.array([_mean_reads(lambda k=k: client.read_cell(r, c, k), n_reads)
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
            a1 = _mean_reads(lambda: client.read_cell(r, c, code), n_reads) - offset
            row_codes = [0] * info.rows
            row_codes[r] = code
            a2 = _mean_reads(lambda: client.read_column(c, row_codes), n_reads) - offset_col
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

