"""Analog front end: turns the latched register/DAC state into crossbar currents and ADC codes.

The front end watches the SPI devices. From the row register, the column register, the row
DAC outputs and the write DAC it derives which circuit is connected (see
:mod:`snan_hil.firmware_emu.registers`):

* cell read — one bit line on the write bus (multiplexer), its word line open, column output
  through the load resistor: the ADC sees ``gain * R_load * I`` with
  ``I = V_read / (R_cell + R_on + R_sw + R_load)`` (the array's ``cell_current`` with
  ``series_ohm = R_sw + R_load``);
* single-cell multiply — the same into the summing amplifier: ``gain * sum_gain * I``;
* column multiply — all rows on the row DACs, one word line open, column at virtual ground of
  the summing amplifier: ``gain * sum_gain * sum_i V_i * G_i`` (the array's ``column_current``);
* write pulse — pulse gate on: the write-DAC amplitude across the selected cell with the chosen
  polarity for as long as the gate stays on; the array's ``apply_pulse`` is called with that
  width when the gate closes (the ADC input is disconnected meanwhile).

ADC codes: ``round(2^14 * V_adc / Vref_adc)`` plus optional input noise, clipped to 0..16383;
a clipped sample is counted as saturated. Power in the cells (memristor + select transistor,
noise free: ``V^2 * G_eff`` per driven cell, ``V * I_predicted`` during a pulse) is handed to the
virtual clock, which integrates it into the array energy.

Fast path (docs/emulator.md): :meth:`AnalogFrontEnd.sample_codes` gives the samples of one
reading at once, and :meth:`AnalogFrontEnd.spike_train_codes` those of every reading of a spike
batch; both draw the same numbers in the same order as one :meth:`AnalogFrontEnd.sample_code` at
a time.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from snan_hil.firmware_emu import registers as reg
from snan_hil.firmware_emu.clock import VirtualClock
from snan_hil.firmware_emu.config import BoardConfig
from snan_hil.firmware_emu.spi_devices import AD5328, ShiftRegister595, WriteDac
from snan_hil.common.polarity import Polarity

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Circuit:
    """What the latched state connects. ``kind``: idle, cell, cell_sum, column, pulse, conflict."""

    kind: str
    row: int = -1
    col: int = -1
    sum_path: bool = False
    set_polarity: bool = False


IDLE = Circuit("idle")


class AnalogFrontEnd:
    """Derives currents, ADC samples, pulses and array power from the device states."""

    def __init__(self, array, config: BoardConfig, clock: VirtualClock, row_dacs: list[AD5328],
                 write_dac: WriteDac, sr_row: ShiftRegister595, sr_col: ShiftRegister595,
                 adc_noise_lsb: float = 0.0, seed: int = 0):
        self.array = array
        self.config = config
        self.clock = clock
        self.row_dacs = row_dacs
        self.write_dac = write_dac
        self.sr_row = sr_row
        self.sr_col = sr_col
        self.adc_noise_lsb = float(adc_noise_lsb)
        self.seed = int(seed)
        """Seed of the ADC noise stream (the emulator derives it from its seed and boot)."""
        self._rng = np.random.default_rng(seed)
        self.circuit = IDLE
        self.samples = 0
        self.saturated_samples = 0
        self.pulses_applied = 0
        self.last_pulse_peak_a = 0.0
        self.conflicts = 0
        self._row_volts: np.ndarray | None = None
        self._stale_dacs: set[int] = set()       # row DACs whose outputs changed since row_volts()
        self._g: np.ndarray | None = None
        self._g_eff_cache: dict[float | None, np.ndarray] = {}
        self._g_eff_revision: int | None = None
        # (row volts, col) -> W, per revision
        self._column_power: dict[tuple[bytes, int], float] = {}
        self._circuits: dict[tuple[int, int], Circuit] = {}   # decode() per register pair
        self._pulse: tuple[int, int, float, bool, float] | None = None  # row, col, V, set, t0
        # hardware faults (firmware_emu/faults.py): a slow row DAC (index, tau us) and an open
        # region of cells (row0, row1, col0, col1); the settling of the slow DAC's outputs:
        # (start us, volts before, volts after)
        self.slow_dac: tuple[int, float] | None = None
        self.dead_cells: tuple[int, int, int, int] | None = None
        self._settling: tuple[float, np.ndarray, np.ndarray] | None = None
        for k, dac in enumerate(row_dacs):
            dac.on_change(functools.partial(self._row_dac_changed, k))
        for dev in (write_dac, sr_row, sr_col):
            dev.on_change(self.update)

    # -- state ------------------------------------------------------------------------------
    def invalidate_array(self) -> None:
        """Forget cached conductances (after the array was replaced or loaded)."""
        self._g = None
        self._g_eff_cache.clear()
        self._column_power.clear()
        self._g_eff_revision = None
        self.update()

    def conductance(self) -> np.ndarray:
        if self._g is None:
            self._g = np.asarray(self.array.conductance(), dtype=float)
        return self._g

    def row_volts(self) -> np.ndarray:
        """Voltages of the 32 row-DAC outputs (V). Treat as read-only: it is cached."""
        if self.slow_dac is not None:
            return self._settled_row_volts()
        volts = self._row_volts
        if volts is None:
            volts = np.array([v for dac in self.row_dacs for v in dac.outputs()])
        elif self._stale_dacs:
            volts = volts.copy()           # callers may hold the previous array
            for k in self._stale_dacs:
                dac = self.row_dacs[k]
                volts[k * dac.CHANNELS:(k + 1) * dac.CHANNELS] = dac.outputs()
        else:
            return volts
        self._stale_dacs.clear()
        self._row_volts = volts
        return volts

    def _row_dac_changed(self, k: int) -> None:
        """Row DAC ``k`` changed an output: only its 8 voltages need re-reading."""
        if self.slow_dac is not None and self.slow_dac[0] == k:
            now = self.clock.now_us
            self._settling = (now, self._slow_outputs(now),
                              np.array(self.row_dacs[k].outputs(), dtype=float))
        self._stale_dacs.add(k)
        self.update()

    def _slow_outputs(self, now_us: float) -> np.ndarray:
        """The slow DAC's 8 outputs (V) at ``now_us``: ``v_to + (v_from - v_to) *
        exp(-(t - t_change) / tau)`` since its last change (0 V before any)."""
        assert self.slow_dac is not None
        if self._settling is None:
            return np.zeros(8)
        t0, v_from, v_to = self._settling
        decay = float(np.exp(-max(0.0, now_us - t0) / self.slow_dac[1]))
        return v_to + (v_from - v_to) * decay

    def _settled_row_volts(self) -> np.ndarray:
        """Row voltages (V) with the slow DAC's outputs on their way to their codes' values
        (a faulty board, :mod:`.faults`)."""
        assert self.slow_dac is not None
        k = self.slow_dac[0]
        volts = np.array([v for dac in self.row_dacs for v in dac.outputs()], dtype=float)
        volts[k * 8:(k + 1) * 8] = self._slow_outputs(self.clock.now_us)
        return volts

    def _dead(self, row: int, col: int) -> bool:
        """Whether cell (row, col) is in the open region of a faulty board."""
        d = self.dead_cells
        return d is not None and d[0] <= row <= d[1] and d[2] <= col <= d[3]

    def _live_rows(self, volts: np.ndarray, col: int) -> np.ndarray:
        """Row voltages as the cells of column ``col`` see them: 0 V on open cells."""
        d = self.dead_cells
        if d is None or not d[2] <= col <= d[3]:
            return volts
        volts = volts.copy()
        volts[d[0]:d[1] + 1] = 0.0
        return volts

    def decode(self) -> Circuit:
        """The circuit selected by the two shift registers."""
        key = (self.sr_row.latch, self.sr_col.latch)
        circuit = self._circuits.get(key)
        if circuit is None:
            circuit = self._circuits[key] = self._decode(*key)
        return circuit

    @staticmethod
    def _decode(rowreg: int, colreg: int) -> Circuit:
        if not colreg & reg.WL_EN:
            return IDLE
        col = colreg & reg.WL_ADDR_MASK
        sum_path = bool(colreg & reg.SUM_PATH)
        set_pol = bool(colreg & reg.POL_SET)
        lo, hi = bool(rowreg & reg.MUX_LO_EN), bool(rowreg & reg.MUX_HI_EN)
        rowdac = bool(rowreg & reg.ROWDAC_EN)
        if (lo and hi) or (rowdac and (lo or hi)):
            return Circuit("conflict", col=col)
        if lo or hi:
            row = (rowreg & reg.MUX_ADDR_MASK) + (16 if hi else 0)
            if colreg & reg.PULSE_GATE:
                return Circuit("pulse", row, col, set_polarity=set_pol)
            return Circuit("cell_sum" if sum_path else "cell", row, col, sum_path)
        if rowdac:
            return Circuit("column", col=col, sum_path=sum_path)
        return IDLE

    def update(self) -> None:
        """Re-derive the circuit after any device change; open/close pulses; set the power."""
        circuit = self.decode()
        if circuit.kind == "conflict" and self.circuit.kind != "conflict":
            self.conflicts += 1
            log.warning("front end: conflicting multiplexer settings (row reg 0x%02x)",
                        self.sr_row.latch)
        self.circuit = circuit
        pulse = None
        if circuit.kind == "pulse":
            volts = self.write_dac.output_volts()
            if volts > 0.0:
                pulse = (circuit.row, circuit.col, volts, circuit.set_polarity)
        current = self._pulse[:4] if self._pulse else None
        if pulse != current:
            if self._pulse is not None:
                self._finish_pulse()
            if pulse is not None:
                self._pulse = (*pulse, self.clock.now_us)
        self.clock.set_power(self.power_w())

    def _finish_pulse(self) -> None:
        assert self._pulse is not None             # called while a pulse is open
        row, col, volts, set_pol, t0 = self._pulse
        self._pulse = None
        # the width to 1 ps: a difference of two absolute float times carries their rounding
        # (65535.999999999985 us for a 65536 us pulse late in a session), which the C
        # firmware's tick-exact times do not - the two MCUs would give the cell another dose
        # (found by the differential tester, issue 27)
        width_s = round(self.clock.now_us - t0, 6) * 1e-6
        if width_s <= 0.0 or self._dead(row, col):
            return
        polarity = Polarity.SET if set_pol else Polarity.RESET
        self.last_pulse_peak_a = float(self.array.apply_pulse(row, col, volts, polarity, width_s))
        self.pulses_applied += 1
        self._g = None
        log.debug("pulse %s r%d c%d %.3f V %.1f us peak %.3g A", polarity.name, row, col, volts,
                  width_s * 1e6, self.last_pulse_peak_a)

    # -- power ----------------------------------------------------------------------------
    def _g_eff(self, series_ohm: float | None) -> np.ndarray:
        """Noise-free conductance of cell + select transistor (+ ``series_ohm``; None = the
        array's column-read path), from the array when it offers ``effective_conductance``."""
        eff = getattr(self.array, "effective_conductance", None)
        if eff is None:
            g = self.conductance()
            return g / (1.0 + g * (series_ohm or 0.0))
        revision = getattr(self.array, "revision", None)
        if revision is None:                  # an array that does not say when it changes
            return np.asarray(eff(series_ohm), dtype=float)
        if revision != self._g_eff_revision:
            self._g_eff_cache.clear()
            self._column_power.clear()
            self._g_eff_revision = revision
        g_eff = self._g_eff_cache.get(series_ohm)
        if g_eff is None:
            g_eff = self._g_eff_cache[series_ohm] = np.asarray(eff(series_ohm), dtype=float)
        return g_eff

    def power_w(self) -> float:
        """Power dissipated in the cells (memristor + select transistor) now (W), noise free.

        Cell read: ``I^2 / G_cell`` with ``I = V * G_path`` (path through R_sw and R_load or the
        summing node); column read: ``sum_i V_i^2 * G_eff_i``; pulse: ``V * I_predicted``.
        """
        c = self.circuit
        cfg = self.config
        if c.kind in ("cell", "cell_sum"):
            volts = self.write_dac.output_volts()
            if volts <= 0.0:
                return 0.0
            series = cfg.r_switch_ohm + (0.0 if c.kind == "cell_sum" else cfg.r_load_ohm)
            g_cell = self._g_eff(0.0)[c.row, c.col]
            if g_cell <= 0.0:
                return 0.0
            current = volts * self._g_eff(series)[c.row, c.col]
            return current * current / g_cell
        if c.kind == "column":
            return self.column_power(self.row_volts(), c.col)
        if c.kind == "pulse" and self._pulse is not None:
            row, col, volts, _, _ = self._pulse
            return volts * abs(float(self.array.pulse_current(row, col, volts)))
        return 0.0

    def column_power(self, volts: np.ndarray, col: int) -> float:
        """Power (W) in the cells of column ``col`` read with row voltages ``volts`` (V):
        ``sum_i V_i^2 * G_eff_i``, noise free (cached per conductance revision)."""
        g_eff = self._g_eff(None)
        if self._g_eff_revision is None:            # no caching for this array
            return float(np.dot(volts * volts, g_eff[:, col]))
        key = (volts.tobytes(), col)                # spikes repeat the same rows and columns
        power = self._column_power.get(key)
        if power is None:
            if len(self._column_power) >= 4096:
                self._column_power.clear()
            power = self._column_power[key] = float(np.dot(volts * volts, g_eff[:, col]))
        return power

    # -- ADC input --------------------------------------------------------------------------
    def adc_volts(self) -> float:
        """Voltage at the ADC input now (V), including the array's read noise."""
        c = self.circuit
        cfg = self.config
        if c.kind in ("cell", "cell_sum") and self._dead(c.row, c.col):
            return 0.0
        if c.kind == "cell":
            volts = self.write_dac.output_volts()
            current = self.array.cell_current(c.row, c.col, volts,
                                              cfg.r_switch_ohm + cfg.r_load_ohm)
            return cfg.gain * cfg.r_load_ohm * current
        if c.kind == "cell_sum":
            volts = self.write_dac.output_volts()
            current = self.array.cell_current(c.row, c.col, volts, cfg.r_switch_ohm)
            return cfg.gain * cfg.sum_gain_ohm * current
        if c.kind == "column":
            current = self.array.column_current(self._live_rows(self.row_volts(), c.col), c.col)
            # Without the summing path the column sees the load resistor; the virtual-ground
            # model is then only approximate (the firmware never uses this combination).
            transimpedance = cfg.sum_gain_ohm if c.sum_path else cfg.r_load_ohm
            return cfg.gain * transimpedance * current
        return 0.0

    def adc_volts_samples(self, n: int) -> np.ndarray:
        """``n`` independent samples of :meth:`adc_volts` (V) of the present circuit, in one
        vectorised call: the array's ``cell_currents`` / ``column_currents`` draw the same read
        noise in the same order as ``n`` calls would (arrays without them are called n times)."""
        c = self.circuit
        cfg = self.config
        if c.kind in ("cell", "cell_sum") and self._dead(c.row, c.col):
            return np.zeros(n)
        if c.kind in ("cell", "cell_sum"):
            volts = self.write_dac.output_volts()
            series = cfg.r_switch_ohm + (cfg.r_load_ohm if c.kind == "cell" else 0.0)
            many = getattr(self.array, "cell_currents", None)
            if many is not None:
                current = many(c.row, c.col, volts, series, n)
            else:
                current = np.array([self.array.cell_current(c.row, c.col, volts, series)
                                    for _ in range(n)], dtype=float)
            return cfg.gain * (cfg.r_load_ohm if c.kind == "cell" else cfg.sum_gain_ohm) * current
        if c.kind == "column":
            row_volts = self._live_rows(self.row_volts(), c.col)
            many = getattr(self.array, "column_currents", None)
            if many is not None:
                current = many(row_volts, c.col, n)
            else:
                current = np.array([self.array.column_current(row_volts, c.col)
                                    for _ in range(n)], dtype=float)
            transimpedance = cfg.sum_gain_ohm if c.sum_path else cfg.r_load_ohm
            return cfg.gain * transimpedance * current
        return np.zeros(n)

    def sample_codes(self, n: int) -> list[int]:
        """``n`` consecutive ADC samples while nothing changes (the ADC frames of one reading):
        the same values, counters and random draws as ``n`` calls of :meth:`sample_code`."""
        cfg = self.config
        ideal = self.adc_volts_samples(n) * (1 << cfg.adc_bits) / cfg.adc_vref_v
        if self.adc_noise_lsb > 0.0:
            ideal += self._rng.normal(0.0, self.adc_noise_lsb, size=n)
        return self._clip_codes(self._round(ideal))

    def spike_train_codes(self, volts: np.ndarray, drive: np.ndarray, columns: Sequence[int],
                          n: int, sum_path: bool = True) -> np.ndarray:
        """ADC samples of a train of column readings, int64 (len(drive), len(columns), n).

        Spike ``s`` drives the rows at ``volts[drive[s]]`` (V, shape (G, rows)); then each
        column of ``columns`` is read ``n`` times in turn (column circuit, summing path as
        given). The same values, counters and random draws (read noise, then ADC noise) as
        :meth:`sample_codes` reading by reading with the rows set, spike after spike; codes
        clipped to the ADC range (saturated samples counted). Needs the array's
        ``column_currents_sequence``.
        """
        current = self.array.column_currents_sequence(volts, drive, list(columns), n)
        rounded = np.floor(self._column_lsb(current, sum_path) + 0.5)
        if not np.isfinite(rounded).all():
            raise ValueError("ADC input is not finite")
        codes = rounded.astype(np.int64)
        self.samples += codes.size
        full = self.config.adc_full_scale_code
        outside = (codes > full) | (codes < 0)
        if outside.any():
            self.saturated_samples += int(outside.sum())
            codes = np.clip(codes, 0, full)
        return codes

    def _column_lsb(self, current: np.ndarray, sum_path: bool) -> np.ndarray:
        """Column currents (A) -> ADC input in LSB with the ADC's noise drawn (one normal per
        sample, in array order), as :meth:`sample_code` computes it."""
        cfg = self.config
        transimpedance = cfg.sum_gain_ohm if sum_path else cfg.r_load_ohm
        ideal = cfg.gain * transimpedance * current * (1 << cfg.adc_bits) / cfg.adc_vref_v
        if self.adc_noise_lsb > 0.0:
            ideal += self._rng.normal(0.0, self.adc_noise_lsb, size=ideal.shape)
        return ideal

    @staticmethod
    def _round(ideal: np.ndarray) -> list:
        """Sample values in LSB (noise included) -> unclipped codes, as :meth:`sample_code`
        rounds them: ``floor(x + 0.5)``; a list (of lists for a 2-D input) of ints."""
        rounded = np.floor(ideal + 0.5)
        if not np.isfinite(rounded).all():
            raise ValueError("ADC input is not finite")
        return rounded.astype(np.int64).tolist()

    def _clip_codes(self, codes: list[int]) -> list[int]:
        """Count the samples of one reading and its saturated samples; clip to the code range."""
        cfg = self.config
        n = len(codes)
        self.samples += n
        full = cfg.adc_full_scale_code
        if codes and (max(codes) > full or min(codes) < 0):
            self.saturated_samples += sum(1 for c in codes if c > full or c < 0)
            codes = [min(max(c, 0), full) for c in codes]
        return codes

    def column_kernel(self) -> dict | None:
        """The present column circuit as a compiled kernel computes :meth:`sample_code`
        (the ISA-level MCU's native core): the array's :meth:`column_read_kernel` plus the ADC
        conversion - ``ideal = (gain * transimpedance) * current * 2^bits / vref``, plus
        ``0.0 + adc_noise_lsb * z`` (one standard normal from :attr:`adc_generator`), code
        ``floor(ideal + 0.5)`` clipped to 0..full scale. None for other circuits or arrays."""
        c = self.circuit
        get = getattr(self.array, "column_read_kernel", None)
        if c.kind != "column" or get is None or self.slow_dac is not None \
                or self.dead_cells is not None:
            return None
        read = get(self.row_volts(), c.col)
        if read is None:
            return None
        cfg = self.config
        g, v, r_mac, rel, abs_s, noisy, generator = read
        transimpedance = cfg.sum_gain_ohm if c.sum_path else cfg.r_load_ohm
        return {"g": g, "v": v, "r_mac": r_mac, "rel": rel, "abs": abs_s, "read_noisy": noisy,
                "read_generator": generator, "scale": cfg.gain * transimpedance,
                "lsb": float(1 << cfg.adc_bits), "vref": float(cfg.adc_vref_v),
                "sigma": self.adc_noise_lsb, "adc_noisy": self.adc_noise_lsb > 0.0,
                "adc_generator": self._rng, "full": cfg.adc_full_scale_code}

    def noise_checkpoint(self) -> tuple | None:
        """The random streams and sample counters now (array read noise, ADC noise, counts),
        for :meth:`noise_restore`; None if the array cannot return to a state (no
        ``rng_state``). Used by the ISA-level MCU, which draws a reading's samples ahead."""
        get = getattr(self.array, "rng_state", None)
        if get is None:
            return None
        return get(), self._rng.bit_generator.state, self.samples, self.saturated_samples

    def noise_restore(self, checkpoint: tuple) -> None:
        """Return to a :meth:`noise_checkpoint`: draws made since are undone."""
        array_state, own_state, samples, saturated = checkpoint
        self.array.set_rng_state(array_state)
        self._rng.bit_generator.state = own_state
        self.samples, self.saturated_samples = samples, saturated

    def sample_code(self) -> int:
        """One ADC sample: quantised, noisy, clipped to the code range (saturation counted)."""
        cfg = self.config
        ideal = self.adc_volts() * (1 << cfg.adc_bits) / cfg.adc_vref_v
        if self.adc_noise_lsb > 0.0:
            ideal += self._rng.normal(0.0, self.adc_noise_lsb)
        code = int(np.floor(ideal + 0.5))
        self.samples += 1
        if code > cfg.adc_full_scale_code or code < 0:
            self.saturated_samples += 1
            code = min(max(code, 0), cfg.adc_full_scale_code)
        return code
