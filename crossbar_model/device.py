"""Yttria-stabilized-zirconia (YSZ) 1T1R cell physics: conductance state and pulse response.

State: ``s`` in [0, 1] per cell, log-linear in conductance (the same exponential form as the
VTEAM memristance)::

    G(s) = g_min * (g_max / g_min) ** s                                   (S)

A pulse of amplitude V (V, applied to the bit line) and width t (s) puts
``V_mem = V * R_mem / (R_mem + R_T + R_series)`` across the memristor (R_T: select transistor,
current limited to I_sat). Above the cell's threshold v_th (>= 0.3 V) the switching rate is::

    nu(V_mem) = rate * ((|V_mem| - v_th) / 1 V) ** exponent                (1/s)

and the state moves with soft bounds (closed form for a constant rate over a sub-step dt)::

    SET   (negative pulse on the board, G up):    s <- 1 - (1 - s) * exp(-nu dt)
    RESET (positive pulse on the board, G down):  s <- s * exp(-nu dt)

SET and RESET have their own rate and exponent (asymmetry). The soft bound is integrated exactly
and the divider's change of V_mem with R_mem by 4th-order Runge-Kutta (:func:`pulse_response`),
so the response depends on width * rate, not on how a pulse is sliced in time. Below threshold
nothing changes.

Device-to-device variability is drawn once per cell (:func:`sample_cells`); the cycle-to-cycle
programming error, read noise and drift live in :mod:`snan_hil.crossbar_model.noise`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from snan_hil.crossbar_model.config import ArrayConfig
from snan_hil.common.polarity import Polarity

POLARITIES = (Polarity.SET, Polarity.RESET)

_MAX_SUBSTEPS = 4096


@dataclass
class CellParams:
    """Per-cell device parameters (arrays of shape (rows, cols)): the device-to-device spread."""

    g_min: np.ndarray  # S
    g_max: np.ndarray  # S
    rate_set: np.ndarray  # 1/s
    rate_reset: np.ndarray  # 1/s
    vth_set: np.ndarray  # V
    vth_reset: np.ndarray  # V

    def arrays(self) -> dict[str, np.ndarray]:
        return {k: getattr(self, k) for k in ("g_min", "g_max", "rate_set", "rate_reset", "vth_set", "vth_reset")}


def sample_cells(config: ArrayConfig, rng: np.random.Generator) -> CellParams:
    """Draw every cell's parameters around the config's nominal values (log-normal spreads)."""
    shape = (config.rows, config.cols)
    var = config.variability
    g = config.conductance
    sw = config.switching

    def lognormal(nominal: float, sigma: float) -> np.ndarray:
        return nominal * np.exp(sigma * rng.standard_normal(shape))

    g_min = lognormal(g.g_min_s, var.g_min_sigma_log)
    g_max = lognormal(g.g_max_s, var.g_max_sigma_log)
    # Keep every cell's bounds outside the usable range (the range is what calibration targets).
    g_min = np.minimum(g_min, 0.9 * g.usable_min_s)
    g_max = np.maximum(g_max, 1.1 * g.usable_max_s)
    rate_set = lognormal(sw.set_rate_per_s, var.rate_sigma_log)
    rate_reset = lognormal(sw.reset_rate_per_s, var.rate_sigma_log)
    vth_set = sw.v_threshold_v + np.abs(var.threshold_sigma_v * rng.standard_normal(shape))
    vth_reset = sw.v_threshold_v + np.abs(var.threshold_sigma_v * rng.standard_normal(shape))
    return CellParams(g_min, g_max, rate_set, rate_reset, vth_set, vth_reset)


def conductance_of_state(s: np.ndarray | float, g_min: np.ndarray | float, g_max: np.ndarray | float) -> np.ndarray:
    """G(s) = g_min * (g_max/g_min)**s (S)."""
    return np.asarray(g_min) * np.exp(np.log(np.asarray(g_max) / np.asarray(g_min)) * np.asarray(s))


def state_of_conductance(g: np.ndarray | float, g_min: np.ndarray | float, g_max: np.ndarray | float) -> np.ndarray:
    """Inverse of :func:`conductance_of_state`, clipped to [0, 1]."""
    g = np.maximum(np.asarray(g, dtype=float), 1e-15)
    return np.clip(np.log(g / np.asarray(g_min)) / np.log(np.asarray(g_max) / np.asarray(g_min)), 0.0, 1.0)


def series_current(amplitude_v: float, g: float, series_ohm: float, i_sat: float) -> float:
    """Current (A) through a memristor of conductance g (S) in series with series_ohm (Ohm),
    limited by the transistor saturation current i_sat (A)."""
    if g <= 0:
        return 0.0
    i = amplitude_v / (1.0 / g + series_ohm)
    return float(min(i, i_sat))


@dataclass
class PulseResult:
    """Outcome of one pulse on one cell."""

    s_after: float
    peak_current_a: float
    dose: float  # integral of nu dt actually applied (dose factor included), dimensionless


def pulse_response(s: float, amplitude_v: float, polarity: Polarity, width_s: float, g_min: float, g_max: float,
                   rate: float, vth: float, exponent: float, series_ohm: float, i_sat: float,
                   max_substep_dose: float, dose_factor: float = 1.0) -> PulseResult:
    """Deterministic response of one cell to one rectangular pulse (no noise except dose_factor).

    ``dose_factor`` multiplies the switching rate for this pulse (the cycle-to-cycle factor).

    Integration: for a rectangular pulse the state obeys the autonomous ODE
    ``ds/dt = nu(V_mem(s)) (1 - s)`` (SET) or ``-nu(V_mem(s)) s`` (RESET). In the variable
    ``u = -ln(1 - s)`` (SET) or ``u = -ln s`` (RESET) the soft bound is exact and
    ``du/dt = nu(V_mem(s(u)))``: only the slow change of the divider's V_mem as R_mem moves is
    left to the integrator, which is the classical 4th-order Runge-Kutta with sub-steps of at
    most ``max_substep_dose`` of the pulse's nominal dose (``nu`` at the full amplitude).
    The result is a function of the width, not of how a pulse is cut: one pulse and the same
    pulse in pieces agree to < 1e-6 in G on the default device (tests/crossbar/test_crossbar_device.py;
    the previous first-order scheme was 1-2.5 % off for a 10 ms RESET at 0.5 V on a
    low-resistance cell). ``dose`` of the result is the integral of nu dt (= the change of u).
    """
    g0 = float(conductance_of_state(s, g_min, g_max))
    peak = series_current(amplitude_v, g0, series_ohm, i_sat)
    if amplitude_v <= vth or width_s <= 0:
        return PulseResult(s, peak, 0.0)
    k_rate = rate * dose_factor
    nominal = k_rate * ((amplitude_v - vth) ** exponent) * width_s
    n = int(min(_MAX_SUBSTEPS, max(1, math.ceil(nominal / max_substep_dose))))
    dt = width_s / n
    log_ratio = math.log(g_max / g_min)
    is_set = polarity == Polarity.SET
    # u-space: s = 1 - exp(-u) (SET), s = exp(-u) (RESET)
    s = min(max(s, 0.0), 1.0)
    if is_set:
        u = math.inf if s >= 1.0 else -math.log1p(-s)
    else:
        u = math.inf if s <= 0.0 else -math.log(s)

    r_series, expo = series_ohm, exponent
    exp, expm1 = math.exp, math.expm1

    def nu(u_: float) -> float:
        """Switching rate (1/s) at u: the divider (and current limit) at that state."""
        g = g_min * exp(log_ratio * (-expm1(-u_) if is_set else exp(-u_)))
        i = amplitude_v / (1.0 / g + r_series)
        v_mem = (i if i < i_sat else i_sat) / g
        return k_rate * (v_mem - vth) ** expo if v_mem > vth else 0.0

    u0 = u
    if math.isfinite(u):
        for _ in range(n):
            k1 = nu(u)
            if k1 == 0.0:
                # below threshold: V_mem only moves away from it as the state changes
                # (RESET raises R_mem and V_mem; SET lowers both), so nothing ever starts
                break
            k2 = nu(u + 0.5 * dt * k1)
            k3 = nu(u + 0.5 * dt * k2)
            k4 = nu(u + dt * k3)
            u += dt * (k1 + 2.0 * k2 + 2.0 * k3 + k4) / 6.0
        s = -math.expm1(-u) if is_set else math.exp(-u)
    total = (u - u0) if math.isfinite(u) else 0.0
    # the peak current: a SET draws it at the end (lowest R), a RESET at the start
    g_end = g_min * math.exp(log_ratio * s)
    peak = max(peak, series_current(amplitude_v, g_end, series_ohm, i_sat))
    return PulseResult(min(max(s, 0.0), 1.0), peak, total)
