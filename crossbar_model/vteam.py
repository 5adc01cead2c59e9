"""VTEAM memristor model (Kvatinsky et al. 2015) as written in the paper (section 2.3, Table tab_2).

State ``x`` is the effective tunnel-barrier thickness (m), bounded to ``[x_on, x_off]``::

    dx/dt = K_off * (v/v_off - 1)**A_off * f_off(x)    if v <= v_off < 0      (RESET, x grows)
    dx/dt = 0                                          if v_off < v < v_on
    dx/dt = K_on  * (v/v_on  - 1)**A_on  * f_on(x)     if 0 < v_on <= v       (SET, x shrinks)

    f_off(x) = exp(-exp((x - a_off) / x_c))
    f_on(x)  = exp(-exp((a_on - x) / x_con))

    R(x) = R_on * exp(lambda * (x - x_on) / (x_off - x_on)),   lambda = ln(R_off / R_on)

with ``K_on < 0 < K_off`` and ``v_off < 0 < v_on`` (the paper's sign convention, checked at
construction).

Integration is exact for a piecewise-linear voltage waveform and therefore independent of the
caller's sampling step: the voltage and state dependences are separable, so within one polarity
``F(x(t)) = F(x(t0)) + K * tau(t)`` where ``F(x) = int dx / f(x)`` (tabulated once on a fine grid)
and ``tau = int (v/v_th - 1)**A dt`` is computed in closed form on each linear segment (threshold
crossings inside a segment included). The hard bounds ``[x_on, x_off]`` are applied in F-space.

``x_on``/``x_off`` are not in the paper. Default: ``x_on = 0``, ``x_off = 3 nm`` (the customary
VTEAM device length, an effective tunnel-barrier range of a few nm). Over that range the paper's
window functions are smooth scale factors (f_on ~ 0.07, f_off ~ 0.35-0.37) rather than walls, so
the hard bounds stop the state. ``x_off = 40 nm`` (= x_c) is the named alternative
``bounds="window-40nm"`` where the windows themselves slow the state near the bounds.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from snan_hil.common.polarity import Polarity

#: Named choices for the (x_on, x_off) bounds in metres; the paper does not give them.
BOUNDS_PRESETS: dict[str, tuple[float, float]] = {
    "tunnel-3nm": (0.0, 3e-9),
    "window-40nm": (0.0, 40e-9),
}

_F_GRID_POINTS = 8193  # tabulation of F(x) = int dx/f(x); interpolation error < 1e-9 relative


@dataclass(frozen=True)
class VTEAMParams:
    """VTEAM parameters in SI units. Defaults: the paper's Table tab_2 (parylene/PPX fit).

    v_on, v_off: switching thresholds (V); r_on, r_off: memristance bounds (Ohm);
    k_on, k_off: rate constants (m/s); A_on, A_off: exponents (1);
    a_on, a_off, x_con, x_c: window parameters (m); x_on, x_off: state bounds (m, assumption).
    """

    v_on: float = 0.6
    v_off: float = -0.6
    r_on: float = 500.0
    r_off: float = 25e3
    k_on: float = -3.96e-8
    k_off: float = 1.054e-8
    A_on: float = 2.357
    A_off: float = 2.022
    a_on: float = 36.8e-9
    a_off: float = 0.12e-9
    x_c: float = 40e-9
    x_con: float = 38e-9
    x_on: float = 0.0
    x_off: float = 3e-9

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            if not math.isfinite(value):
                raise ValueError(f"VTEAM parameter {name} must be finite, got {value!r}")
        if not self.k_on < 0:
            raise ValueError(f"VTEAM sign convention: K_on must be < 0 (SET shrinks x), got {self.k_on}")
        if not self.k_off > 0:
            raise ValueError(f"VTEAM sign convention: K_off must be > 0 (RESET grows x), got {self.k_off}")
        if not self.v_on > 0:
            raise ValueError(f"VTEAM sign convention: v_on must be > 0 V, got {self.v_on}")
        if not self.v_off < 0:
            raise ValueError(f"VTEAM sign convention: v_off must be < 0 V, got {self.v_off}")
        if not 0 < self.r_on < self.r_off:
            raise ValueError(f"VTEAM needs 0 < R_on < R_off, got R_on={self.r_on}, R_off={self.r_off}")
        if not self.x_on < self.x_off:
            raise ValueError(f"VTEAM needs x_on < x_off, got x_on={self.x_on}, x_off={self.x_off}")
        if not (self.x_c > 0 and self.x_con > 0):
            raise ValueError(f"VTEAM window scales x_c, x_con must be > 0, got {self.x_c}, {self.x_con}")
        if not (self.A_on > 0 and self.A_off > 0):
            raise ValueError(f"VTEAM exponents A_on, A_off must be > 0, got {self.A_on}, {self.A_off}")

    @classmethod
    def paper(cls, bounds: str = "tunnel-3nm") -> "VTEAMParams":
        """Table tab_2 parameters with the named (x_on, x_off) choice (see ``BOUNDS_PRESETS``)."""
        if bounds not in BOUNDS_PRESETS:
            raise ValueError(f"unknown VTEAM bounds {bounds!r}; choose one of {sorted(BOUNDS_PRESETS)}")
        x_on, x_off = BOUNDS_PRESETS[bounds]
        return cls(x_on=x_on, x_off=x_off)


@dataclass
class _Antiderivative:
    """Tabulated F(x) = int_{x_on}^{x} dxi / f(xi) and its inverse (monotone)."""

    x: np.ndarray
    F: np.ndarray

    def forward(self, x: np.ndarray | float) -> np.ndarray:
        return np.interp(x, self.x, self.F)

    def inverse(self, F: np.ndarray | float) -> np.ndarray:
        # np.interp clamps outside [F(x_on), F(x_off)]: that is the hard state bound.
        return np.interp(F, self.F, self.x)


@dataclass
class VTEAM:
    """The VTEAM model with exact, step-size independent integration over voltage waveforms."""

    params: VTEAMParams = field(default_factory=VTEAMParams)

    def __post_init__(self) -> None:
        p = self.params
        self.lam = math.log(p.r_off / p.r_on)
        xs = np.linspace(p.x_on, p.x_off, _F_GRID_POINTS)
        self._F_on = _Antiderivative(xs, _cumtrapz(self._inv_f_on(xs), xs))
        self._F_off = _Antiderivative(xs, _cumtrapz(self._inv_f_off(xs), xs))

    # --- the paper's equations -------------------------------------------------------------
    def f_off(self, x: np.ndarray | float) -> np.ndarray:
        """RESET window f_off(x) = exp(-exp((x - a_off)/x_c)) (dimensionless)."""
        p = self.params
        return np.exp(-np.exp(np.minimum((np.asarray(x) - p.a_off) / p.x_c, 700.0)))

    def f_on(self, x: np.ndarray | float) -> np.ndarray:
        """SET window f_on(x) = exp(-exp((a_on - x)/x_con)) (dimensionless)."""
        p = self.params
        return np.exp(-np.exp(np.minimum((p.a_on - np.asarray(x)) / p.x_con, 700.0)))

    def _inv_f_off(self, x: np.ndarray) -> np.ndarray:
        p = self.params
        return np.exp(np.minimum(np.exp(np.minimum((x - p.a_off) / p.x_c, 700.0)), 700.0))

    def _inv_f_on(self, x: np.ndarray) -> np.ndarray:
        p = self.params
        return np.exp(np.minimum(np.exp(np.minimum((p.a_on - x) / p.x_con, 700.0)), 700.0))

    def dxdt(self, v: np.ndarray | float, x: np.ndarray | float) -> np.ndarray:
        """State velocity dx/dt (m/s) at voltage v (V) and state x (m): eq. vteam1."""
        p = self.params
        v = np.asarray(v, dtype=float)
        x = np.asarray(x, dtype=float)
        u_off = np.maximum(v / p.v_off - 1.0, 0.0)  # > 0 only for v < v_off
        u_on = np.maximum(v / p.v_on - 1.0, 0.0)  # > 0 only for v > v_on
        return (p.k_off * u_off**p.A_off * self.f_off(x) * (v <= p.v_off)
                + p.k_on * u_on**p.A_on * self.f_on(x) * (v >= p.v_on))

    def resistance(self, x: np.ndarray | float) -> np.ndarray:
        """Memristance R(x) (Ohm): eq. vteam3."""
        p = self.params
        return p.r_on * np.exp(self.lam * (np.asarray(x) - p.x_on) / (p.x_off - p.x_on))

    def conductance(self, x: np.ndarray | float) -> np.ndarray:
        """1 / R(x) (S)."""
        return 1.0 / self.resistance(x)

    # --- state <-> normalized weight ------------------------------------------------------
    def weight_from_x(self, x: np.ndarray | float) -> np.ndarray:
        """Normalized weight w = (G - G_off)/(G_on - G_off) in [0, 1] (1 at x_on, 0 at x_off)."""
        p = self.params
        g_on, g_off = 1.0 / p.r_on, 1.0 / p.r_off
        return (self.conductance(x) - g_off) / (g_on - g_off)

    def x_from_weight(self, w: np.ndarray | float) -> np.ndarray:
        """Inverse of :meth:`weight_from_x`; w is clipped to [0, 1]."""
        p = self.params
        g_on, g_off = 1.0 / p.r_on, 1.0 / p.r_off
        g = g_off + np.clip(np.asarray(w, dtype=float), 0.0, 1.0) * (g_on - g_off)
        return p.x_on + (p.x_off - p.x_on) * np.log(g_on / g) / self.lam

    def clip_x(self, x: np.ndarray | float) -> np.ndarray:
        p = self.params
        return np.clip(np.asarray(x, dtype=float), p.x_on, p.x_off)

    # --- integration ---------------------------------------------------------------------
    def segment_doses(self, t: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Exact SET and RESET 'doses' of each linear segment of a piecewise-linear waveform.

        dose_on[k]  = int max(v/v_on - 1, 0)**A_on  dt over [t[k], t[k+1]]   (s)
        dose_off[k] = int max(v/v_off - 1, 0)**A_off dt over [t[k], t[k+1]]  (s)
        """
        p = self.params
        h = np.diff(t)
        d_on = _linear_power_integral(v[:-1] / p.v_on - 1.0, v[1:] / p.v_on - 1.0, p.A_on, h)
        d_off = _linear_power_integral(v[:-1] / p.v_off - 1.0, v[1:] / p.v_off - 1.0, p.A_off, h)
        return d_on, d_off

    def advance(self, x: np.ndarray | float, dose: float, polarity: Polarity) -> np.ndarray:
        """State after a SET (VTEAM "on") or RESET ("off") dose (s) applied to state(s) x (m)."""
        if dose < 0 or not math.isfinite(dose):
            raise ValueError(f"dose must be finite and >= 0, got {dose}")
        x = self.clip_x(x)
        if dose == 0:
            return x
        if polarity == Polarity.SET:
            return self._F_on.inverse(self._F_on.forward(x) + self.params.k_on * dose)
        if polarity == Polarity.RESET:
            return self._F_off.inverse(self._F_off.forward(x) + self.params.k_off * dose)
        raise ValueError(f"polarity must be Polarity.SET or Polarity.RESET, got {polarity!r}")

    def events(self, t: np.ndarray, v: np.ndarray) -> list[tuple[Polarity, float]]:
        """The waveform reduced to its ordered polarity runs: [(polarity, total dose), ...].

        Consecutive segments of the same polarity merge exactly (the ODE is autonomous in the
        dose variable), so the final state depends only on this short list.
        """
        t, v = _check_waveform(t, v)
        d_on, d_off = self.segment_doses(t, v)
        on_first = v[:-1] >= v[1:]  # a falling segment meets v_on before v_off
        runs: list[tuple[Polarity, float]] = []
        for k in np.flatnonzero((d_on > 0) | (d_off > 0)):
            order = ((Polarity.SET, d_on[k]), (Polarity.RESET, d_off[k])) if on_first[k] \
                else ((Polarity.RESET, d_off[k]), (Polarity.SET, d_on[k]))
            for pol, dose in order:
                if dose > 0:
                    if runs and runs[-1][0] == pol:
                        runs[-1] = (pol, runs[-1][1] + float(dose))
                    else:
                        runs.append((pol, float(dose)))
        return runs

    def apply_waveform(self, x0: np.ndarray | float, t: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Final state(s) after the piecewise-linear waveform v(t) (V, s), from state(s) x0 (m).

        ``x0`` may be an array: every initial state sees the same waveform (vectorised).
        """
        x = self.clip_x(x0)
        for pol, dose in self.events(t, v):
            x = self.advance(x, dose, pol)
        return x

    def simulate(self, x0: float, t: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """State x(t) (m) and current i(t) = v / R(x) (A) at every sample of the waveform."""
        t, v = _check_waveform(t, v)
        d_on, d_off = self.segment_doses(t, v)
        on_first = v[:-1] >= v[1:]
        xs = np.empty_like(t)
        x = float(self.clip_x(x0))
        xs[0] = x
        # Segments with no dose keep x; handle active ones in order (exact per segment).
        active = np.zeros(len(t) - 1, dtype=bool)
        active[(d_on > 0) | (d_off > 0)] = True
        last = 0
        for k in np.flatnonzero(active):
            xs[last + 1:k + 1] = x
            order = ((Polarity.SET, d_on[k]), (Polarity.RESET, d_off[k])) if on_first[k] \
                else ((Polarity.RESET, d_off[k]), (Polarity.SET, d_on[k]))
            for pol, dose in order:
                if dose > 0:
                    x = float(self.advance(x, float(dose), pol))
            xs[k + 1] = x
            last = int(k) + 1
        xs[last + 1:] = x
        return xs, v / self.resistance(xs)


def _check_waveform(t: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t = np.asarray(t, dtype=float)
    v = np.asarray(v, dtype=float)
    if t.ndim != 1 or t.shape != v.shape or len(t) < 2:
        raise ValueError("waveform needs 1-D t and v of equal length >= 2")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(v))):
        raise ValueError("waveform contains NaN or infinite values")
    if np.any(np.diff(t) < 0):
        raise ValueError("waveform times must be non-decreasing")
    return t, v


def _linear_power_integral(u0: np.ndarray, u1: np.ndarray, a: float, h: np.ndarray) -> np.ndarray:
    """int_0^h max(u(s), 0)**a ds for u linear from u0 to u1 (vectorised, exact)."""
    p0 = np.maximum(u0, 0.0)
    p1 = np.maximum(u1, 0.0)
    du = u1 - u0
    scale = np.maximum(np.maximum(np.abs(u0), np.abs(u1)), 1e-300)
    flat = np.abs(du) <= 1e-7 * scale
    safe_du = np.where(flat, 1.0, du)
    exact = h * (p1 ** (a + 1) - p0 ** (a + 1)) / ((a + 1) * safe_du)
    mid = h * np.maximum(0.5 * (u0 + u1), 0.0) ** a
    out = np.where(flat, mid, exact)
    return np.maximum(out, 0.0)


def _cumtrapz(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    out = np.zeros_like(y)
    out[1:] = np.cumsum(0.5 * (y[1:] + y[:-1]) * np.diff(x))
    return out
