"""Memristive STDP windows from the VTEAM model (the paper's Fig. 2B/D procedure) and a lookup.

Procedure: both neurons emit the same bi-triangular spike ``s(t)``; the pre-synaptic spike starts
at 0, the post-synaptic one at ``dt`` (ms). The memristor sees their difference::

    v(t) = orientation * (s(t - dt) - s(t))        (V; orientation +1: post minus pre)

No single spike reaches a threshold (``max|s| < min(v_on, -v_off)``, checked); only the overlap
of the positive lobe of one spike with the negative lobe of the other does. With the default
orientation and a spike whose positive lobe comes first, post-after-pre (dt > 0) overlaps the
post's positive lobe with the pre's negative lobe: v > v_on, SET, conductance up (potentiation);
dt < 0 gives v < v_off, RESET (depression); the change decays as |dt| grows along the lobe.

The weight is the normalized conductance w = (G - G_off)/(G_on - G_off) of the VTEAM device, and
the curves are computed for initial states on a grid with a step of 1 % of the conductance range
(as the paper did). :class:`StdpLookup` precomputes dw(w, dt) on such a grid for cheap use in the
SNAN (``--plasticity vteam``).
"""

from __future__ import annotations

import functools
import json
import math
from dataclasses import asdict, dataclass, field

import numpy as np

from snan_hil.files.atomicio import atomic_path
from snan_hil.crossbar_model.vteam import VTEAM, VTEAMParams


@dataclass(frozen=True)
class BiTriangularSpike:
    """A spike made of a positive triangle then a negative triangle (V, ms).

    Breakpoints (t in ms, v in V): (0, 0), (t_pos/2, +a_pos), (t_pos, 0),
    (t_pos + t_neg_peak, -a_neg), (t_pos + t_neg, 0).

    Defaults are an assumption (the paper shows its spike only in a figure insert): a short
    sharp positive lobe (1 ms) and a long negative lobe (a triangle whose peak comes 0.5 ms after
    the lobe starts and which returns to 0 over 30 ms), both 0.1 V below the 0.6 V thresholds, so
    the window has the usual STDP shape (largest change at small |dt|, decaying to zero by
    about |dt| = 20 ms).
    """

    a_pos: float = 0.5
    t_pos: float = 1.0
    a_neg: float = 0.5
    t_neg_peak: float = 0.5
    t_neg: float = 30.0

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"spike parameter {name} must be finite and >= 0, got {value!r}")
        if self.t_pos <= 0 or self.t_neg <= 0 or not 0 < self.t_neg_peak < self.t_neg:
            raise ValueError("spike needs t_pos > 0 and 0 < t_neg_peak < t_neg")

    @property
    def duration_ms(self) -> float:
        return self.t_pos + self.t_neg

    def breakpoints(self) -> tuple[np.ndarray, np.ndarray]:
        """(t_ms, v) of the piecewise-linear spike, including the start and end at 0 V."""
        t = np.array([0.0, self.t_pos / 2, self.t_pos, self.t_pos + self.t_neg_peak, self.t_pos + self.t_neg])
        v = np.array([0.0, self.a_pos, 0.0, -self.a_neg, 0.0])
        return t, v

    def __call__(self, t_ms: np.ndarray | float) -> np.ndarray:
        tb, vb = self.breakpoints()
        return np.interp(t_ms, tb, vb, left=0.0, right=0.0)


def pair_waveform(spike: BiTriangularSpike, dt_ms: float, orientation: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """The exact piecewise-linear memristor voltage of one pre/post pair: (t in s, v in V)."""
    if orientation not in (1, -1):
        raise ValueError(f"orientation must be +1 or -1, got {orientation}")
    tb, _ = spike.breakpoints()
    t = np.unique(np.concatenate([tb, tb + dt_ms]))
    v = orientation * (spike(t - dt_ms) - spike(t))
    return t * 1e-3, v


def _check_subthreshold(spike: BiTriangularSpike, params: VTEAMParams) -> None:
    limit = min(params.v_on, -params.v_off)
    if max(spike.a_pos, spike.a_neg) >= limit:
        raise ValueError(
            f"each spike must stay below the switching thresholds (|v| < {limit} V); "
            f"got a_pos={spike.a_pos} V, a_neg={spike.a_neg} V")


MAPPINGS = ("conductance", "state")
"""Weight <-> device state readings: ``conductance`` w = (G - G_off)/(G_on - G_off);
``state`` w = (x_off - x)/(x_off - x_on) (the barrier state, linear in ln G)."""


def _weight_maps(model: VTEAM, mapping: str):
    """(x_of_w, w_of_x) of a mapping (:data:`MAPPINGS`)."""
    if mapping == "conductance":
        return model.x_from_weight, model.weight_from_x
    if mapping == "state":
        p = model.params
        span = p.x_off - p.x_on

        def x_of_w(w):
            return p.x_off - np.clip(np.asarray(w, dtype=float), 0.0, 1.0) * span

        def w_of_x(x):
            return (p.x_off - np.asarray(x, dtype=float)) / span
        return x_of_w, w_of_x
    raise ValueError(f"unknown weight mapping {mapping!r} ({', '.join(MAPPINGS)})")


def stdp_window(w0: float | np.ndarray, dt_ms: np.ndarray, spike: BiTriangularSpike | None = None,
                params: VTEAMParams | None = None, orientation: int = 1,
                mapping: str = "conductance") -> np.ndarray:
    """Weight change dw for each pair delay dt_ms (ms) from initial normalized weight(s) w0.

    Returns an array of shape ``(len(w0), len(dt_ms))`` (or ``(len(dt_ms),)`` for scalar w0) of
    weight changes; ``mapping`` (:data:`MAPPINGS`) says what the weight is: the normalized
    conductance (fraction of G_on - G_off; multiply by that for siemens) or the normalized
    barrier state.
    """
    spike = spike or BiTriangularSpike()
    model = _model(params or VTEAMParams())
    _check_subthreshold(spike, model.params)
    scalar = np.ndim(w0) == 0
    w0 = np.atleast_1d(np.asarray(w0, dtype=float))
    if np.any(~np.isfinite(w0)):
        raise ValueError("initial weights must be finite")
    dts = np.atleast_1d(np.asarray(dt_ms, dtype=float))
    x_of_w, w_of_x = _weight_maps(model, mapping)
    x0 = x_of_w(w0)
    w_start = w_of_x(x0)
    out = np.empty((len(w0), len(dts)))
    for j, dt in enumerate(dts):
        t, v = pair_waveform(spike, float(dt), orientation)
        out[:, j] = w_of_x(model.apply_waveform(x0, t, v)) - w_start
    return out[0] if scalar else out


@functools.lru_cache(maxsize=8)
def _model(params: VTEAMParams) -> VTEAM:
    return VTEAM(params)


@dataclass
class StdpLookup:
    """dw(w, dt) precomputed on a grid; bilinear interpolation; dw = 0 outside the dt range.

    ``w_grid`` (normalized weight, 0..1), ``dt_grid_ms`` (ms), ``table[i, j]`` = dw at
    (w_grid[i], dt_grid_ms[j]). ``gain`` records any scaling applied (1 = pure device physics).
    """

    w_grid: np.ndarray
    dt_grid_ms: np.ndarray
    table: np.ndarray
    gain: float = 1.0
    meta: dict = field(default_factory=dict)

    @classmethod
    def build(cls, spike: BiTriangularSpike | None = None, params: VTEAMParams | None = None,
              w_step: float = 0.01, dt_max_ms: float | None = None, dt_step_ms: float = 0.25,
              orientation: int = 1, mapping: str = "conductance") -> "StdpLookup":
        """Compute the table: w from 0 to 1 in ``w_step`` (paper: 1 %), dt in +-dt_max_ms;
        ``mapping``: what w is (:data:`MAPPINGS`)."""
        spike = spike or BiTriangularSpike()
        params = params or VTEAMParams()
        if dt_max_ms is None:
            dt_max_ms = spike.duration_ms
        n_w = int(round(1.0 / w_step)) + 1
        w_grid = np.linspace(0.0, 1.0, n_w)
        n_dt = int(round(dt_max_ms / dt_step_ms))
        dt_grid = np.arange(-n_dt, n_dt + 1) * dt_step_ms
        table = stdp_window(w_grid, dt_grid, spike, params, orientation, mapping)
        meta = {"spike": asdict(spike), "vteam": asdict(params), "orientation": orientation,
                "mapping": mapping}
        return cls(w_grid, dt_grid, table, 1.0, meta)

    def scaled(self, gain: float) -> "StdpLookup":
        """A copy with every dw multiplied by ``gain`` (a documented, recorded scaling)."""
        if not (math.isfinite(gain) and gain > 0):
            raise ValueError(f"gain must be finite and > 0, got {gain}")
        return StdpLookup(self.w_grid, self.dt_grid_ms, self.table * gain, self.gain * gain, dict(self.meta))

    def normalized_to(self, peak: float, w_ref: float = 0.5) -> "StdpLookup":
        """A copy scaled so that the largest potentiation at weight ``w_ref`` equals ``peak``."""
        row = self.delta_w(np.full_like(self.dt_grid_ms, w_ref), self.dt_grid_ms)
        top = float(np.max(row))
        if top <= 0:
            raise ValueError("the window has no potentiation to normalize")
        return self.scaled(peak / top)

    def delta_w(self, w: np.ndarray | float, dt_ms: np.ndarray | float) -> np.ndarray:
        """dw for current normalized weight(s) w and pair delay(s) dt_ms (ms), broadcast."""
        w, dt = np.broadcast_arrays(np.asarray(w, dtype=float), np.asarray(dt_ms, dtype=float))
        wi = np.clip(w, 0.0, 1.0) * (len(self.w_grid) - 1)
        i0 = np.clip(np.floor(wi).astype(np.intp), 0, len(self.w_grid) - 2)
        fw = wi - i0
        step = self.dt_grid_ms[1] - self.dt_grid_ms[0]
        dj = (dt - self.dt_grid_ms[0]) / step
        inside = (dj >= 0) & (dj <= len(self.dt_grid_ms) - 1)
        dj = np.clip(dj, 0, len(self.dt_grid_ms) - 1)
        j0 = np.clip(np.floor(dj).astype(np.intp), 0, len(self.dt_grid_ms) - 2)
        fd = dj - j0
        t = self.table
        val = ((1 - fw) * (1 - fd) * t[i0, j0] + fw * (1 - fd) * t[i0 + 1, j0]
               + (1 - fw) * fd * t[i0, j0 + 1] + fw * fd * t[i0 + 1, j0 + 1])
        return np.where(inside, val, 0.0)

    def apply(self, w: np.ndarray | float, dt_ms: np.ndarray | float) -> np.ndarray:
        """New weight(s) w + dw(w, dt), clipped to [0, 1]."""
        return np.clip(np.asarray(w, dtype=float) + self.delta_w(w, dt_ms), 0.0, 1.0)

    def save(self, path: str) -> None:
        with atomic_path(path, suffix=".tmp.npz") as tmp:
            np.savez(tmp, w_grid=self.w_grid, dt_grid_ms=self.dt_grid_ms, table=self.table,
                     gain=np.array(self.gain), meta=np.array(json.dumps(self.meta)))

    @classmethod
    def load(cls, path: str) -> "StdpLookup":
        with np.load(path, allow_pickle=False) as d:
            return cls(d["w_grid"], d["dt_grid_ms"], d["table"], float(d["gain"]), json.loads(str(d["meta"])))


@functools.lru_cache(maxsize=1)
def default_stdp_lookup() -> StdpLookup:
    """The lookup for the default spike and the paper's parameters (built once, ~0.1 s)."""
    return StdpLookup.build()
