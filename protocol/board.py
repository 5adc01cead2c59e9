"""The board's constants, defined once: :class:`BoardConstants` and its converters.

Everything the host, the emulator and the calibration need to know about a MemriCore-class
board is here: array size, the two DACs and the ADC, the read chain's resistors and gain, and
the safety limits. The INFO message carries it (:class:`~snan_hil.protocol.messages.Info` is a
BoardConstants plus link fields); the emulator's ``BoardConfig`` extends it with emulator-only
fields (timing, longest pulse, ...); the calibration's ``ReadChain`` extends it with the fitted
offsets and gain factor only. No other module states a board constant or limit as a literal.

Sources (shared/reference/memricore-board.md): 12-bit row DACs and write DAC and a 14-bit ADC,
all at a 5 V reference; a 3000 Ohm load resistor, 10 Ohm of switches, an amplifier gain of 11
and a 330 Ohm column-sum transimpedance; reads at or below 0.3 V, writes at or below 1.4 V;
a 2 mA software current limit; ten ADC conversions averaged per reading.

Converters (V, codes, Ohm, S, A):

* DAC code <-> V: ``V = code * Vref / (2^bits - 1)`` (the host's formula); ``*_code`` rounds to
  the nearest code, ``*_floor_code`` gives the largest code whose voltage does not exceed a
  limit (0.3 V at 12 bit / 5 V is code 245 = 0.2991 V, not 246 = 0.3004 V).
* cell read (READ_CELL and the read after a WRITE_PULSE; the read voltage comes from the write
  DAC, the cell in series with the switches and the load resistor, the amplifier across the
  load)::

      a = a0 + c * gain * R_load * 2^adc_bits / Vref_adc * V / (X + R_sw + R_load)

* column read (READ_COLUMN, SPIKE_BATCH; row voltages from the row DACs, the column at the
  summing amplifier's virtual ground)::

      a = a0_col + c * gain * R_sum * 2^adc_bits / Vref_adc * sum_i V_i / (X_i + R_sw)

  ``X = 1/G`` is the resistance of the whole 1T1R cell. ``a0``, ``a0_col`` (ADC codes at 0 V)
  and the common gain factor ``c`` are 0, 0 and 1 here (nominal); a calibrated ``ReadChain``
  overrides them with fitted values.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any, overload

import numpy as np
import numpy.typing as npt

__all__ = ["BoardConstants", "MEMRICORE", "PROGRAM_RAMP_V", "RESET_CLAMP_V", "DAC_SETTLE_US",
           "ADC_RATE_SPS", "ADC_DUMMY_CONVERSIONS", "SPI_HZ", "MCU_HZ", "WINDOW_CONVERSIONS",
           "floor_code",
           "FloatArray", "Values"]

FloatArray = npt.NDArray[np.float64]
"""An array of float64 values (what the converters return for array input, of its shape)."""

Values = npt.NDArray[Any] | Sequence[float]
"""Array input of the converters: codes or conductances of any numeric dtype, any shape."""

PROGRAM_RAMP_V = (0.3, 1.2, 0.01)
"""The old host's programming ticket ramp (start, stop, step) in V; what PROGRAM_CELL uses for
amplitude codes given as 0 (write-DAC codes 246, 983, 8 on MemriCore)."""

RESET_CLAMP_V = 3.0
"""Largest positive (RESET) pulse of the board's existing firmware (V): it clamps a RESET
amplitude to 3.0 V, write-DAC code 2457 at a 5 V reference (board reference; the public
Raspberry-Pi driver of the board clamps RESET codes above 2457 the same way). SET pulses are
not clamped below the write DAC's full scale. Board behaviour of the old firmware, not a
safety limit of this project (those are ``max_read_v`` / ``max_write_v``)."""

DAC_SETTLE_US = 6.0
"""Settling time of the board's DACs after an update (us; board reference, AD5328)."""
ADC_RATE_SPS = 200e3
"""Conversion rate of the board's ADC (samples/s; board reference, TLC3541): 5 us a
conversion."""
ADC_DUMMY_CONVERSIONS = 1
"""Conversions the board discards before averaging ``adc_averages`` (board reference: the
driver takes one dummy conversion, then averages 10)."""

SPI_HZ = 15e6
"""SPI clock between the MCU and the board's chips (Hz; board reference: 15 MHz): a 16-bit DAC
word or ADC frame takes ~1.07 us on the bus."""
MCU_HZ = 32_000_000
"""Core clock of the board's MCU (Hz; MIK32 reference: up to 32 MHz, RV32IMC, no FPU)."""

WINDOW_CONVERSIONS = 2
"""ADC conversions per read of the on-board decision window's lean read plan
(DECISION_WINDOW on a board with the READ_PLAN capability; docs/protocol.md "Read plan"): the
read-noise budget of the 6x6 hardware task, the fewest conversions whose decisions stay >= 99 %
identical to the standard ten-average reads on the same chips and seeds
(``bench/bench_window.py``, part 2; docs/hil.md "Read-noise budget"). A board without the
capability reads with its ``adc_averages`` (ten, after one dummy conversion)."""

_MAX_LINES = 32
"""Most rows or columns a board may have (SPIKE_BATCH addresses columns in a 32-bit mask)."""

_MAX_BITS = 16
"""Widest DAC or ADC (codes travel as 16-bit fields)."""

_MIN_X_OHM = 1.0
"""Smallest cell resistance a reading is converted to (Ohm): a reading at or beyond a short."""


def floor_code(volts: float, to_code: Callable[[float], int],
               to_volts: Callable[[int], float]) -> int:
    """Largest DAC code whose voltage does not exceed ``volts`` (V), never below 0."""
    code = max(0, to_code(volts))
    while code > 0 and to_volts(code) > volts:
        code -= 1
    return code


def _scalar_or_array(x: FloatArray) -> float | FloatArray:
    return float(x) if x.ndim == 0 else x


@dataclass(frozen=True)
class BoardConstants:
    """Electrical constants and safety limits of a board (counts, bits, V, Ohm, A).

    Defaults are the MemriCore board's (module docstring). Derived values are properties:
    full-scale codes, the largest read and write codes (``max_read_code``, ``max_write_code``),
    the nominal read (``read_code``, ``v_read_v``); the last four are computed once per
    instance (every request checks them).
    """

    rows: int = 32
    """Bit lines (rows) of the crossbar."""
    cols: int = 8
    """Word lines (columns) of the crossbar."""
    dac_bits: int = 12
    """Resolution of the row DACs (AD5328 class), which drive the rows of a column read."""
    dac_vref_v: float = 5.0
    """Reference voltage of the row DACs (V)."""
    write_dac_bits: int = 12
    """Resolution of the write DAC, which drives programming pulses and cell reads."""
    write_dac_vref_v: float = 5.0
    """Reference voltage of the write DAC (V)."""
    adc_bits: int = 14
    """Resolution of the ADC (TLC3541 class)."""
    adc_vref_v: float = 5.0
    """Reference voltage of the ADC (V)."""
    adc_averages: int = 10
    """ADC conversions averaged per reading (after one dummy conversion)."""
    r_load_ohm: float = 3000.0
    """Load resistor of the cell-read path (Ohm)."""
    r_switch_ohm: float = 10.0
    """Resistance of the multiplexer switches in series with a cell (Ohm)."""
    gain: float = 11.0
    """Amplifier gain in front of the ADC (V/V)."""
    sum_gain_ohm: float = 330.0
    """Transimpedance of the column-sum amplifier (Ohm)."""
    max_read_v: float = 0.3
    """Largest read voltage (V): reads above could change a cell; refused on both sides."""
    max_write_v: float = 1.4
    """Largest write-pulse amplitude (V), either polarity; refused above."""
    compliance_a: float = 2e-3
    """Largest predicted cell current of a write pulse (A); refused above (host's soft_cc)."""

    def __post_init__(self) -> None:
        """ValueError naming the first constant outside its physical range."""
        checks = (
            ("rows", 1 <= self.rows <= _MAX_LINES), ("cols", 1 <= self.cols <= _MAX_LINES),
            ("dac_bits", 1 <= self.dac_bits <= _MAX_BITS),
            ("write_dac_bits", 1 <= self.write_dac_bits <= _MAX_BITS),
            ("adc_bits", 1 <= self.adc_bits <= _MAX_BITS),
            ("dac_vref_v", 0 < self.dac_vref_v < math.inf),
            ("write_dac_vref_v", 0 < self.write_dac_vref_v < math.inf),
            ("adc_vref_v", 0 < self.adc_vref_v < math.inf),
            ("adc_averages", self.adc_averages >= 1),
            ("r_load_ohm", 0 <= self.r_load_ohm < math.inf),
            ("r_switch_ohm", 0 <= self.r_switch_ohm < math.inf),
            ("gain", 0 < self.gain < math.inf),
            ("sum_gain_ohm", 0 < self.sum_gain_ohm < math.inf),
            ("max_read_v", 0 <= self.max_read_v < math.inf),
            ("max_write_v", 0 <= self.max_write_v < math.inf),
            ("compliance_a", 0 < self.compliance_a < math.inf),
        )
        for name, ok in checks:
            if not ok:
                raise ValueError(f"board constant {name}={getattr(self, name)!r} is outside its "
                                 "physical range")

    # ------------------------------------------------------------------ converters: DACs
    @property
    def dac_full_scale_code(self) -> int:
        """Largest row-DAC code."""
        return (1 << self.dac_bits) - 1

    @property
    def write_dac_full_scale_code(self) -> int:
        """Largest write-DAC code."""
        return (1 << self.write_dac_bits) - 1

    @property
    def adc_full_scale_code(self) -> int:
        """Largest ADC code (a reading at it is saturated)."""
        return (1 << self.adc_bits) - 1

    def dac_volts(self, code: int) -> float:
        """Row-DAC code -> V."""
        return code * self.dac_vref_v / (2 ** self.dac_bits - 1)

    def dac_code(self, volts: float) -> int:
        """V -> nearest row-DAC code (not clamped)."""
        return int(round(volts * (2 ** self.dac_bits - 1) / self.dac_vref_v))

    def write_dac_volts(self, code: int) -> float:
        """Write-DAC code -> V."""
        return code * self.write_dac_vref_v / (2 ** self.write_dac_bits - 1)

    def write_dac_code(self, volts: float) -> int:
        """V -> nearest write-DAC code (not clamped)."""
        return int(round(volts * (2 ** self.write_dac_bits - 1) / self.write_dac_vref_v))

    def dac_floor_code(self, volts: float) -> int:
        """Largest row-DAC code whose voltage does not exceed ``volts`` (V), at most full
        scale (also for limits far above it, e.g. 1e308 V)."""
        full = self.dac_full_scale_code
        if volts >= self.dac_volts(full):
            return full
        return min(floor_code(volts, self.dac_code, self.dac_volts), full)

    def write_dac_floor_code(self, volts: float) -> int:
        """Largest write-DAC code whose voltage does not exceed ``volts`` (V), at most full
        scale (also for limits far above it)."""
        full = self.write_dac_full_scale_code
        if volts >= self.write_dac_volts(full):
            return full
        return min(floor_code(volts, self.write_dac_code, self.write_dac_volts), full)

    def adc_volts(self, code: int) -> float:
        """ADC code -> V at the ADC input (``code * Vref / 2^bits``)."""
        return code * self.adc_vref_v / (2 ** self.adc_bits)

    # ------------------------------------------------------------------ limits
    @cached_property
    def max_cell_read_code(self) -> int:
        """Largest write-DAC code of a single-cell read (READ_CELL ``dac_code``, the
        ``read_code`` of WRITE_PULSE and PROGRAM_CELL): at or below ``max_read_v`` on the write
        DAC, which drives the cell-read path. 245 = 0.2991 V on MemriCore."""
        return self.write_dac_floor_code(self.max_read_v)

    @cached_property
    def max_row_read_code(self) -> int:
        """Largest row-DAC code of a driven row (READ_COLUMN, SPIKE_BATCH): at or below
        ``max_read_v`` on the row DACs. 245 = 0.2991 V on MemriCore."""
        return self.dac_floor_code(self.max_read_v)

    @cached_property
    def max_read_code(self) -> int:
        """Largest DAC code at or below ``max_read_v`` on *both* DACs: a code safe for either
        kind of read (the nominal ``read_code``). 245 = 0.2991 V on MemriCore."""
        return min(self.max_cell_read_code, self.max_row_read_code)

    @cached_property
    def max_write_code(self) -> int:
        """Largest write-DAC amplitude code: at or below ``max_write_v`` (1146 = 1.3993 V)."""
        return self.write_dac_floor_code(self.max_write_v)

    @cached_property
    def read_code(self) -> int:
        """DAC code of the nominal read (what "read_code 0" and the legacy reads use): the
        largest code at or below the read limit. (The old host's "0.3 V" read, code 246 =
        0.3004 V, is above the limit.)"""
        return self.max_read_code

    @cached_property
    def v_read_v(self) -> float:
        """Nominal cell-read voltage (V) = the write-DAC voltage of ``read_code`` (a single-cell
        read is driven by the write DAC; on a board whose DACs are alike it is also the row
        voltage of ``read_code``)."""
        return self.write_dac_volts(self.read_code)

    @cached_property
    def legacy_read_code(self) -> int:
        """Write-DAC code of the existing firmware's fixed read (the read after a mode-7 pulse,
        and the clamp of mode-9 reads): the *nearest* code to ``max_read_v``, as the old host
        and firmware round it (246 = 0.3004 V on MemriCore, 0.4 mV above the read limit; the
        public driver writes 246). Board behaviour of the legacy firmware; this project's own
        reads use ``read_code``."""
        return min(self.write_dac_code(self.max_read_v), self.write_dac_full_scale_code)

    @cached_property
    def reset_clamp_code(self) -> int:
        """Write-DAC code the existing firmware clamps RESET pulses to: nearest code of
        :data:`RESET_CLAMP_V` (2457 on MemriCore)."""
        return min(self.write_dac_code(RESET_CLAMP_V), self.write_dac_full_scale_code)

    @property
    def conversion_us(self) -> float:
        """Documented analog time of one cell reading (us): the DAC settling time plus the
        dummy and the ``adc_averages`` conversions at the ADC's rate (61 us on MemriCore:
        6 us + 11 x 5 us). SPI and MCU time come on top on a real board."""
        return DAC_SETTLE_US + (ADC_DUMMY_CONVERSIONS + self.adc_averages) / ADC_RATE_SPS * 1e6

    def program_ramp_codes(self) -> tuple[int, int, int]:
        """Write-DAC codes (start, stop, step) of :data:`PROGRAM_RAMP_V`."""
        start, stop, step = PROGRAM_RAMP_V
        return self.write_dac_code(start), self.write_dac_code(stop), self.write_dac_code(step)

    @property
    def board(self) -> BoardConstants:
        """Just the board constants (of an Info, a BoardConfig or a ReadChain)."""
        return BoardConstants(**{name: getattr(self, name)
                                 for name in BoardConstants.__dataclass_fields__})

    # ------------------------------------------------------------------ read chain
    @property
    def offset_code(self) -> float:
        """ADC code of a cell read at 0 V: 0 nominal (a calibrated ReadChain fits it)."""
        return 0.0

    @property
    def offset_column_code(self) -> float:
        """ADC code of a column read at 0 V: 0 nominal (a calibrated ReadChain fits it)."""
        return 0.0

    @property
    def gain_factor(self) -> float:
        """Common multiplicative error of both read paths: 1 nominal (ReadChain fits it)."""
        return 1.0

    def cell_read_volts(self, code: int | None = None) -> float:
        """Read voltage (V) of a cell read at write-DAC ``code`` (default: nominal)."""
        return self.write_dac_volts(self.read_code if code is None else code)

    def row_volts(self, code: int | None = None) -> float:
        """Row voltage (V) of a column read at row-DAC ``code`` (default: nominal)."""
        return self.dac_volts(self.read_code if code is None else code)

    @property
    def adc_codes_per_volt(self) -> float:
        """ADC codes per V at the ADC input (``2^bits / Vref``)."""
        return 2 ** self.adc_bits / self.adc_vref_v

    def cell_scale(self, read_code: int | None = None) -> float:
        """``c * gain * R_load * 2^bits / Vref * V`` (code * Ohm) of the cell path."""
        return (self.gain_factor * self.gain * self.r_load_ohm * self.adc_codes_per_volt
                * self.cell_read_volts(read_code))

    @overload
    def cell_resistance(self, adc: float, read_code: int | None = None) -> float: ...
    @overload
    def cell_resistance(self, adc: Values, read_code: int | None = None) -> FloatArray: ...

    def cell_resistance(self, adc: float | Values,
                        read_code: int | None = None) -> float | FloatArray:
        """Cell resistance X (Ohm, memristor + transistor) from cell-read ADC code(s);
        a float for a scalar, else an array of the input's shape.

        ``X = scale / (a - a0) - R_sw - R_load`` (the host's formula); codes at or below the
        offset give ``inf`` (open cell); X is at least 1 Ohm."""
        a = np.asarray(adc, dtype=float) - self.offset_code
        with np.errstate(divide="ignore"):
            x = np.where(a > 0, self.cell_scale(read_code) / np.where(a > 0, a, 1.0)
                         - self.r_switch_ohm - self.r_load_ohm, np.inf)
        return _scalar_or_array(np.maximum(x, _MIN_X_OHM))

    @overload
    def cell_conductance(self, adc: float, read_code: int | None = None) -> float: ...
    @overload
    def cell_conductance(self, adc: Values, read_code: int | None = None) -> FloatArray: ...

    def cell_conductance(self, adc: float | Values,
                         read_code: int | None = None) -> float | FloatArray:
        """Cell conductance G = 1/X (S) from cell-read ADC code(s); 0 for an open cell."""
        x = np.asarray(self.cell_resistance(adc, read_code), dtype=float)
        return _scalar_or_array(1.0 / x)

    @overload
    def cell_current_a(self, adc: float) -> float: ...
    @overload
    def cell_current_a(self, adc: Values) -> FloatArray: ...

    def cell_current_a(self, adc: float | Values) -> float | FloatArray:
        """The cell's current (A) during a cell read, from its ADC code(s): the ADC sees
        ``gain * R_load * I`` (the load resistor in series with the cell; the host's read
        chain), so ``I = (a - a0) / (c * gain * R_load * 2^bits / Vref)``; the same current
        :meth:`cell_resistance` divides the read voltage by. The board measures current only
        so, at a read voltage (at most ``max_read_v``), never during a write pulse."""
        a = np.asarray(adc, dtype=float) - self.offset_code
        return _scalar_or_array(a / (self.gain_factor * self.gain * self.r_load_ohm
                                     * self.adc_codes_per_volt))

    @overload
    def cell_code(self, conductance_s: float, read_code: int | None = None) -> float: ...
    @overload
    def cell_code(self, conductance_s: Values, read_code: int | None = None) -> FloatArray: ...

    def cell_code(self, conductance_s: float | Values,
                  read_code: int | None = None) -> float | FloatArray:
        """Expected cell-read ADC code (float, not quantised or clipped) of conductance G (S)."""
        g = np.asarray(conductance_s, dtype=float)
        a = self.offset_code + self.cell_scale(read_code) * g / (
            1.0 + g * (self.r_switch_ohm + self.r_load_ohm))
        return _scalar_or_array(a)

    def column_scale(self, row_code: int | None = None) -> float:
        """``c * gain * R_sum * 2^bits / Vref * V`` (code * Ohm) of the column path."""
        return (self.gain_factor * self.gain * self.sum_gain_ohm * self.adc_codes_per_volt
                * self.row_volts(row_code))

    @overload
    def column_current_a(self, adc: float) -> float: ...
    @overload
    def column_current_a(self, adc: Values) -> FloatArray: ...

    def column_current_a(self, adc: float | Values) -> float | FloatArray:
        """Column current (A) from column-read ADC code(s):
        ``I = (a - a0_col) / (c * gain * R_sum * 2^bits / Vref)``."""
        a = np.asarray(adc, dtype=float) - self.offset_column_code
        return _scalar_or_array(a / (self.gain_factor * self.gain * self.sum_gain_ohm
                                     * self.adc_codes_per_volt))

    @overload
    def column_effective_conductance(self, adc: float, row_code: int | None = None) -> float: ...
    @overload
    def column_effective_conductance(self, adc: Values,
                                     row_code: int | None = None) -> FloatArray: ...

    def column_effective_conductance(self, adc: float | Values,
                                     row_code: int | None = None) -> float | FloatArray:
        """Sum over driven rows of ``1 / (X_i + R_sw)`` (S), all rows at ``row_code``."""
        a = np.asarray(adc, dtype=float) - self.offset_column_code
        return _scalar_or_array(a / self.column_scale(row_code))

    @overload
    def column_cell_conductance(self, adc: float, row_code: int | None = None) -> float: ...
    @overload
    def column_cell_conductance(self, adc: Values, row_code: int | None = None) -> FloatArray: ...

    def column_cell_conductance(self, adc: float | Values,
                                row_code: int | None = None) -> float | FloatArray:
        """Cell conductance G = 1/X (S) from a column read with ONE driven row (a spike)."""
        geff = np.asarray(self.column_effective_conductance(adc, row_code), dtype=float)
        with np.errstate(divide="ignore"):
            x = np.where(geff > 0, 1.0 / np.where(geff > 0, geff, 1.0) - self.r_switch_ohm,
                         np.inf)
        return _scalar_or_array(1.0 / np.maximum(x, _MIN_X_OHM))

    @overload
    def column_code(self, conductance_s: float, row_code: int | None = None) -> float: ...
    @overload
    def column_code(self, conductance_s: Values, row_code: int | None = None) -> FloatArray: ...

    def column_code(self, conductance_s: float | Values,
                    row_code: int | None = None) -> float | FloatArray:
        """Expected column-read ADC code of one driven cell of conductance G (S)."""
        g = np.asarray(conductance_s, dtype=float)
        a = self.offset_column_code + self.column_scale(row_code) * g / (
            1.0 + g * self.r_switch_ohm)
        return _scalar_or_array(a)


MEMRICORE = BoardConstants()
"""The MemriCore board's constants (the defaults)."""
