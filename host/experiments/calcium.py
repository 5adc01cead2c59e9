"""Duration of the astrocytic modulation in decision steps, and the (tau_Ca, A) family that
sweeps it (paper Fig. 4C2 and 6C/D: "duration of astrocytic modulation", 1 to >100 steps).

**Definition.** The duration of a parameter set is measured from the model itself: one
astrocyte receives the input of one visit (one decision window ``T_stim`` of the input
neuron firing at its mean rate: a spike at step ``t`` iff ``floor((t+1) p) > floor(t p)``,
i.e. exactly ``p * T_stim / dt`` evenly spread spikes), then nothing. The agent's own Euler
step (:func:`snan_hil.host.snan_kernel.astro_step`, in
:func:`~snan_hil.host.snan_kernel.calcium_event_kernel`) is iterated until the calcium has
risen above ``Ca_thr`` and fallen back below it. The *duration* is the time the calcium
stays above ``Ca_thr`` (the interneuron threshold is lowered), in decision windows:
``(t_off - t_on) * dt / T_stim``. The *onset* ``t_on * dt / T_stim`` is reported too (a
slow rise lets the agent step back before the memory acts).

**Family.** The sweeps move along one parameter ``s`` (seconds):
``tau_Ca = max(s, 1 s)`` and ``A = r * s``, where ``r = A / tau_Ca`` of the base
configuration (the 10x10 preset: 22 / 22 = 1 per second); every other parameter is fixed.
For ``s >= 1 s`` this scales ``tau_Ca`` and ``A`` together (the duration grows with
``tau_Ca``, tested); below 1 s ``tau_Ca`` stays at 1 s and only ``A`` shrinks towards
``Ca_thr``, because with a faster calcium the response follows the glutamate drive, which
stays above ``G_thr`` for ~5.5 s after any visit, so durations under ~4 decisions exist only
with ``A`` close to ``Ca_thr`` (the calcium then crosses its threshold late, see ``onset``).
The duration grows monotonically and continuously with ``s`` (tested);
:func:`level_for_duration` inverts it by bisection. The 10x10 preset (tau 22 s, A 22) is
``s = 22`` and gives ~108 decisions, the paper's "100 steps".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from snan_hil.common.errors import UserError
from snan_hil.host import snan_kernel as K
from snan_hil.host.config import SnanConfig
from snan_hil.host.kernel_params import kernel_params


@dataclass(frozen=True)
class CalciumEvent:
    """Calcium response to one visit, in decision windows (``T_stim``)."""

    duration: float   #: time above Ca_thr
    onset: float      #: first step above Ca_thr, from the start of the visit
    end: float        #: last step above Ca_thr + 1, from the start of the visit
    peak: float       #: largest calcium value


def calcium_event(cfg: SnanConfig, max_windows: int = 100_000) -> CalciumEvent:
    """The calcium response of ``cfg`` to one visit (see module doc)."""
    a, i = cfg.astro, cfg.input
    key = (a.a, a.tau_ca_ms, a.alpha_n_per_ms, a.k_n, a.g_thr, a.ca_thr, i.p, i.t_stim_ms,
           i.dt_ms, int(max_windows))
    ev = _CACHE.get(key)
    if ev is None:
        params = kernel_params(cfg.replace(**{"astro.enabled": True}))
        win = cfg.window_steps
        t_on, t_off, peak = K.calcium_event_kernel(params, win, float(i.p),
                                                   int(max_windows) * win)
        if t_on < 0:
            ev = CalciumEvent(0.0, math.inf, math.inf, float(peak))
        else:
            ev = CalciumEvent((t_off - t_on) / win, t_on / win, t_off / win, float(peak))
        if len(_CACHE) < 100_000:
            _CACHE[key] = ev
    return ev


_CACHE: dict[tuple, CalciumEvent] = {}


def duration_steps(cfg: SnanConfig) -> float:
    """Duration of the astrocytic modulation of ``cfg`` in decisions (0: never active)."""
    return calcium_event(cfg).duration


def family_config(base: SnanConfig, level_s: float) -> SnanConfig:
    """``base`` with ``tau_Ca = max(level_s, 1) s`` and ``A = level_s * A_base / tau_base``."""
    if not (math.isfinite(level_s) and level_s > 0):
        raise UserError(f"the calcium level must be a positive number of seconds, got {level_s}")
    ratio = base.astro.a / (base.astro.tau_ca_ms / 1000.0)
    return base.replace(**{"astro.tau_ca_s": float(max(level_s, 1.0)),
                           "astro.a": float(level_s * ratio)})


def level_for_duration(base: SnanConfig, target: float, hi: float = 500.0,
                       rtol: float = 1e-4) -> float:
    """Family level ``s`` (seconds) whose duration is ``target`` decisions (bisection)."""
    if not target > 0:
        raise UserError(f"a calcium duration must be > 0 decisions, got {target}")
    ratio = base.astro.a / (base.astro.tau_ca_ms / 1000.0)
    lo = base.astro.ca_thr / ratio  # A == Ca_thr: never above threshold
    if duration_steps(family_config(base, hi)) < target:
        raise UserError(f"calcium duration {target} decisions needs a level above {hi} s")
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if duration_steps(family_config(base, mid)) < target:
            lo = mid
        else:
            hi = mid
        if hi - lo < rtol * hi:
            break
    return hi
