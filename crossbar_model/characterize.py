"""Characterisation helpers: the mean pulse response of a chip model (for docs, bench, calibration)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from snan_hil.crossbar_model.array import CrossbarArray
from snan_hil.crossbar_model.config import ArrayConfig
from snan_hil.crossbar_model.device import POLARITIES
from snan_hil.common.polarity import Polarity
from snan_hil.crossbar_model.fitted import PulseSample, fit_device


@dataclass(frozen=True)
class StepStats:
    """Relative conductance change G_after/G_before - 1 of one pulse, over many cells."""

    polarity: Polarity
    amplitude_v: float
    width_s: float
    mean: float
    std: float
    n: int


def pulse_steps(config: ArrayConfig | None = None, amplitudes: tuple[float, ...] = (0.4, 0.5, 0.8, 1.1, 1.4),
                width_s: float = 100e-6, start_g: float | None = None, repeats: int = 4,
                seed: int = 0) -> list[StepStats]:
    """Mean and spread of the step of a single pulse from ``start_g`` (S; default: the geometric
    middle of the usable range), over every non-stuck cell of a fresh chip, ``repeats`` times.
    Includes device-to-device and cycle-to-cycle variability (no read noise: true conductance)."""
    cfg = config if config is not None else ArrayConfig.default()
    lo, hi = cfg.conductance.usable_min_s, cfg.conductance.usable_max_s
    g0 = start_g if start_g is not None else math.sqrt(lo * hi)
    arr = CrossbarArray(cfg, seed=seed)
    cells = [(r, c) for r in range(arr.rows) for c in range(arr.cols) if not arr.stuck_mask[r, c]]
    out = []
    for polarity in POLARITIES:
        for amp in amplitudes:
            rel = []
            for _ in range(repeats):
                for r, c in cells:
                    arr.set_conductance(r, c, g0)
                    before = arr.conductance()[r, c]
                    arr.apply_pulse(r, c, amp, polarity, width_s)
                    rel.append(arr.conductance()[r, c] / before - 1.0)
            out.append(StepStats(polarity, amp, width_s, float(np.mean(rel)), float(np.std(rel)), len(rel)))
    return out


# ---------------------------------------------------------------- ideal write-and-verify
# The paper's two-stage write-and-verify run straight on the array model (no board: no DAC/ADC
# quantisation, no protocol), so that the array's own write statistics can be checked (tests)
# and measured (bench/bench_crossbar.py) with one implementation. The board's real
# write-and-verify is snan_hil.calibration.


def log_uniform_targets(a: CrossbarArray, n: int, seed: int) -> list[tuple[int, int, float]]:
    """``n`` cells ``(row, col, target_s)`` in column order (cell ``k`` at ``k % rows``,
    ``k // rows``), targets (S) log-uniform in :meth:`CrossbarArray.usable_range`, drawn from
    ``numpy.random.default_rng(seed)``."""
    rng = np.random.default_rng(seed)
    lo, hi = a.usable_range()
    return [(k % a.rows, k // a.rows, math.exp(rng.uniform(math.log(lo), math.log(hi))))
            for k in range(n)]


def read_conductance(a: CrossbarArray, row: int, col: int, *, v_read: float,
                     series_ohm: float) -> float:
    """Conductance (S) of one cell from one noisy read at ``v_read`` (V) through ``series_ohm``
    (Ohm) and the cell's transistor.

    The read voltage and the series resistance are the caller's: this layer knows no board
    (a MemriCore board reads at ``protocol.board.MEMRICORE.max_read_v`` through
    ``r_load_ohm + r_switch_ohm``)."""
    i = a.cell_current(row, col, v_read, series_ohm)
    return 1.0 / (v_read / i - a.config.transistor.on_resistance_ohm - series_ohm)


def ideal_write_verify(a: CrossbarArray, row: int, col: int, target_s: float, *,
                       v_read: float, v_max: float, series_ohm: float,
                       ramp_step_v: float = 0.05, tol: float = 0.10, max_ramps: int = 6,
                       width_s: float = 100e-6) -> int:
    """Stage 1 of the paper's write-and-verify on one cell; the pulses applied.

    Amplitude ramps from ``v_read`` to ``v_max`` (V) in ``ramp_step_v`` steps, RESET while G is
    above ``target_s`` (S), SET while below, ``width_s`` pulses with a read
    (:func:`read_conductance`) after each; a ramp that overshoots starts again the other way;
    stops inside ``+-tol`` (relative) or after ``max_ramps`` ramps. ``v_read`` (V), ``v_max``
    (V) and ``series_ohm`` (Ohm) are the board's and given by the caller (for a MemriCore board
    ``MEMRICORE.max_read_v``, ``max_write_v`` and ``r_load_ohm + r_switch_ohm`` of
    ``protocol.board``, which this layer may not import).
    """
    def inside(g: float) -> bool:
        return abs(g / target_s - 1) <= tol

    pulses = 0
    for _ in range(max_ramps):
        g = read_conductance(a, row, col, v_read=v_read, series_ohm=series_ohm)
        if inside(g):
            return pulses
        polarity = Polarity.RESET if g > target_s else Polarity.SET
        amp = v_read
        while amp <= v_max + 1e-9:
            a.apply_pulse(row, col, amp, polarity, width_s)
            pulses += 1
            g = read_conductance(a, row, col, v_read=v_read, series_ohm=series_ohm)
            if inside(g):
                return pulses
            if (polarity == Polarity.RESET and g < target_s) or \
                    (polarity == Polarity.SET and g > target_s):
                break                                   # overshot: ramp the other way
            amp += ramp_step_v
    return pulses


def ideal_fine_tune(a: CrossbarArray, row: int, col: int, target_s: float, *,
                    v_read: float, series_ohm: float, amp_v: float = 0.45, limit: int = 200,
                    width_s: float = 100e-6) -> int:
    """Stage 2 of the paper's write-and-verify: ``amp_v`` RESET pulses until G <= ``target_s``,
    then SET pulses until G >= ``target_s``, at most ``limit`` in all; the pulses applied.
    ``v_read`` (V) and ``series_ohm`` (Ohm) as for :func:`ideal_write_verify`."""
    n = 0
    for polarity, wrong_side in ((Polarity.RESET, lambda g: g > target_s),
                                 (Polarity.SET, lambda g: g < target_s)):
        while wrong_side(read_conductance(a, row, col, v_read=v_read, series_ohm=series_ohm)) \
                and n < limit:
            a.apply_pulse(row, col, amp_v, polarity, width_s)
            n += 1
    return n


@dataclass(frozen=True)
class TrainResponse:
    """Conductance (S) of every non-stuck cell of a fresh chip along a train of identical
    pulses: ``g[k, i]`` after ``k`` pulses (k = 0 is the start) on cell ``cells[i]``."""

    polarity: Polarity
    amplitude_v: float
    width_s: float
    cells: tuple[tuple[int, int], ...]
    g: np.ndarray

    def steps(self) -> np.ndarray:
        """Per-pulse changes (S), shape (pulses, cells)."""
        return np.diff(self.g, axis=0)


def train_response(config: ArrayConfig | None = None, *, amplitude_v: float,
                   polarity: Polarity, pulses: int, width_s: float = 100e-6,
                   start_g: float | None = None, seed: int = 0) -> TrainResponse:
    """A train of ``pulses`` identical pulses on every non-stuck cell of a fresh chip
    (``seed``), from ``start_g`` (S; default the bottom of the usable range for SET, its top for
    RESET). True conductances (no read noise); device-to-device and cycle-to-cycle spread
    included. For docs/crossbar_model.md §2.1 and the device-model tests."""
    cfg = config if config is not None else ArrayConfig.default()
    c = cfg.conductance
    g0 = start_g if start_g is not None else (c.usable_min_s if polarity == Polarity.SET
                                              else c.usable_max_s)
    arr = CrossbarArray(cfg, seed=seed)
    cells = tuple((r, k) for r in range(arr.rows) for k in range(arr.cols)
                  if not arr.stuck_mask[r, k])
    for r, k in cells:
        arr.set_conductance(r, k, g0)
    rows = np.array([r for r, _ in cells])
    cols = np.array([k for _, k in cells])
    out = np.empty((pulses + 1, len(cells)))
    out[0] = arr.conductance()[rows, cols]
    for n in range(1, pulses + 1):
        for r, k in cells:
            arr.apply_pulse(r, k, amplitude_v, polarity, width_s)
        out[n] = arr.conductance()[rows, cols]
    return TrainResponse(polarity, float(amplitude_v), float(width_s), cells, out)


def device_truth(array: CrossbarArray, cells: list[tuple[int, int]], pulse, *,
                 g_ref_s: float, g_low_s: float, g_high_s: float, points: int = 40,
                 c2c_pulses: int = 200, seed: int = 0):
    """The emulated device's own values of the fitted model's parameters
    (:mod:`snan_hil.crossbar_model.fitted`) for ``cells`` of ``array`` at ``pulse`` (a
    ``LearningPulse``): what a perfect characterisation would give.

    Mean response: each cell's noise-free steps (its own bounds, rates and thresholds; no
    programming or read noise) on ``points`` conductances log-spaced over
    ``[g_low_s, g_high_s]``, fitted with the same model. Cycle-to-cycle: ``c2c_pulses``
    noisy pulses per polarity from ``g_ref_s`` on each cell, relative std of the step (true
    conductances, no reads). Conductances are those of the whole 1T1R cell (memristor and
    select transistor), as the board's read chain gives them. Returns
    ``(DeviceModel, dw_min_std)``; ``array`` is not changed."""
    r_t = array.config.transistor.on_resistance_ohm

    def cell_g(g_mem: float) -> float:
        return g_mem / (1.0 + g_mem * r_t)

    def mem_g(g_cell: float) -> float:
        return g_cell / (1.0 - g_cell * r_t)

    noiseless = array.config.with_overrides({
        "programming_noise.step_sigma_log": 0.0, "programming_noise.hop_sigma": 0.0,
        "read_noise.relative_sigma": 0.0, "read_noise.absolute_sigma_s": 0.0,
        "stuck.fraction": 0.0})
    twin = CrossbarArray(noiseless, seed=array.seed)
    twin.cells = array.cells
    twin._setup()
    samples = []
    width = pulse.width_us * 1e-6
    for r, c in cells:
        for g in np.geomspace(g_low_s, g_high_s, points):
            for pol in POLARITIES:
                twin.set_conductance(r, c, mem_g(float(g)))
                g0 = cell_g(float(twin.conductance()[r, c]))
                twin.apply_pulse(r, c, pulse.amplitude(pol), pol, width)
                samples.append(PulseSample(r, c, pol, g0, cell_g(float(twin.conductance()[r, c]))))
    model = fit_device(samples, pulse, g_ref_s=g_ref_s, read_noise=0.0)
    noisy = CrossbarArray(array.config.with_overrides({"stuck.fraction": 0.0}), seed=seed)
    noisy.cells = array.cells
    noisy._setup()
    rel = []
    for r, c in cells:
        for pol in POLARITIES:
            steps = []
            for _ in range(c2c_pulses):
                noisy.set_conductance(r, c, mem_g(g_ref_s))
                g0 = cell_g(float(noisy.conductance()[r, c]))
                noisy.apply_pulse(r, c, pulse.amplitude(pol), pol, width)
                steps.append(math.log(cell_g(float(noisy.conductance()[r, c])) / g0))
            s = np.array(steps)
            rel.append(float(s.std(ddof=1) / abs(s.mean())))
    return model, float(np.sqrt(np.mean(np.square(rel))))
