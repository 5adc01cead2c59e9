"""The trial kernel's parameters built from a configuration.

:class:`~snan_hil.host.snan_kernel.KernelParams` is one typed, read-only structure (a
``typing.NamedTuple``; the kernels read its fields by name, ``p.v_thr_motor``).
:func:`kernel_params` is the only place that reads a
:class:`~snan_hil.host.config.SnanConfig` for the kernel: when a config field is renamed,
this function is the one to adapt.

Besides the config's values it holds derived constants (decay factors per step, the lowered
interneuron threshold) and tables the event-driven engine looks up instead of recomputing:

* ``pow_*``: powers ``base**k`` for ``k = 0 .. steps + 1`` by repeated multiplication (the
  kernel uses ``base**k`` beyond);
* ``v_bias_rest`` / ``v_bias_reset``: an interneuron's potential after ``k`` steps of bias
  input alone from ``v_rest`` / ``v_reset``, by the reference's own per-step formula (so a
  neuron following them is bit-identical to the per-step reference), computed until the
  trajectory stops changing (at most :data:`MAX_BIAS_TABLE` steps);
* ``kf_*``: the first step ``k >= 1`` at which those trajectories exceed the normal /
  lowered interneuron threshold (:data:`NEVER` if they never do).

Tables are shared between parameter sets with the same inputs (cached): never write to them.

Units: as in the config (times in ms, potentials in the paper's dimensionless units); table
indices and ``steps``/``ref_steps`` in time steps of ``dt_ms``.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from snan_hil.host.config import SnanConfig
from snan_hil.host.plasticity import VteamRule, vteam_rule
from snan_hil.host.rng import spike_threshold
# the codes live in the kernel module (numba freezes globals into its cache)
from snan_hil.host.snan_kernel import NEVER, STDP_MODES, TARGET_CODES, KernelParams

MAX_BIAS_TABLE = 1 << 16        #: longest bias-only trajectory table (steps)


@functools.lru_cache(maxsize=256)
def _powers(base: float, n: int) -> np.ndarray:
    out = np.empty(n)
    v = 1.0
    for k in range(n):
        out[k] = v
        v = v * base
    return out


@functools.lru_cache(maxsize=256)
def _bias_table(v0: float, v_rest: float, alpha: float, r_m: float, i_bias: float,
                min_len: int) -> np.ndarray:
    """Bias-only trajectory from ``v0`` by the reference's step (see module doc)."""
    cur = 0.0 + i_bias
    vals = [v0]
    v = v0
    while len(vals) < MAX_BIAS_TABLE:
        v = v_rest + alpha * (v - v_rest) + r_m * cur
        if len(vals) >= min_len and (v == vals[-1] or (len(vals) >= 2 and v == vals[-2])):
            break
        vals.append(v)
    return np.array(vals)


def _first_above(table: np.ndarray, thr: float) -> int:
    above = np.nonzero(table[1:] > thr)[0]
    return int(above[0]) + 1 if above.size else NEVER


def kernel_params(cfg: SnanConfig, *, return_to_start: bool = False,
                  target: str | None = None, vteam: VteamRule | None = None) -> KernelParams:
    """The kernel parameters of ``cfg`` (the one function that reads the config).

    ``return_to_start`` (Fig. 6C/D), ``target`` (overrides ``stdp.target``) and ``vteam`` (the
    memristive plasticity rule) are the experiments' trial options; their defaults keep the
    agent's behaviour. With ``stdp.rule = vteam`` and no ``vteam`` given, the rule is built from
    the config's ``vteam`` section (:func:`snan_hil.host.plasticity.vteam_rule`).
    """
    if vteam is None and cfg.stdp.rule == "vteam":
        vteam = vteam_rule(cfg)[0]
    n, s, inp, d, ast = cfg.neuron, cfg.synapse, cfg.input, cfg.stdp, cfg.astro
    steps = cfg.window_steps
    dt = inp.dt_ms
    alpha = math.exp(-dt / n.tau_m_ms)
    tau = ast.tau_ca_ms
    q = 1.0 - ast.alpha_n_per_ms * dt
    lam = 1.0 - dt / tau
    dec_plus = math.exp(-dt / d.tau_plus_ms)
    dec_minus = math.exp(-dt / d.tau_minus_ms)
    thr_low = n.v_thr_inter / (1.0 + ast.eta)
    rest = _bias_table(n.v_rest, n.v_rest, alpha, n.r_m, n.i_bias, steps + 2)
    reset = _bias_table(n.v_reset, n.v_rest, alpha, n.r_m, n.i_bias, steps + 2)
    vt = vteam if vteam is not None else VteamRule(np.zeros((2, 2)), 0.0, 1.0)
    return KernelParams(
        steps=int(steps), dt_ms=float(dt), max_steps=int(cfg.grid.max_steps),
        spike_threshold=int(spike_threshold(inp.p)),
        no_spike_stay=cfg.decision.no_spike == "stay", return_to_start=bool(return_to_start),
        alpha=alpha, v_rest=float(n.v_rest), v_reset=float(n.v_reset),
        v_thr_motor=float(n.v_thr_motor), v_thr_inter=float(n.v_thr_inter),
        v_thr_inter_low=thr_low, r_m=float(n.r_m), i_bias=float(n.i_bias),
        u_inf_bias=n.r_m * n.i_bias / (1.0 - alpha), log_alpha=math.log(alpha),
        ref_steps=int(cfg.ref_steps), integrate=n.refractory == "integrate",
        reset_each_window=bool(n.reset_each_window),
        w_in_inter=float(s.w_in_inter), w_inh=float(s.w_inh),
        astro=bool(ast.enabled), alpha_n=float(ast.alpha_n_per_ms), k_n=float(ast.k_n),
        g_thr=float(ast.g_thr), a_ca=float(ast.a), tau_ca_ms=float(tau),
        ca_thr=float(ast.ca_thr), q=q, lam=lam, log_q=math.log(q),
        log_lam=math.log(lam) if lam > 0.0 else 0.0,
        stdp_mode=STDP_MODES[d.mode], target=TARGET_CODES[target or d.target],
        nearest=d.pairing == "nearest", a_plus=float(d.a_plus), a_minus=float(d.a_minus),
        dec_plus=dec_plus, dec_minus=dec_minus, w_min=float(d.w_min), w_max=float(d.w_max),
        k=float(d.k), vteam=vteam is not None,
        vteam_lut=np.ascontiguousarray(vt.lut, dtype=np.float64),
        vteam_dt0_ms=float(vt.dt0_ms), vteam_dtstep_ms=float(vt.dtstep_ms),
        vteam_latency_ms=float(vt.latency_ms),
        pow_q=_powers(q, steps + 2), pow_lam=_powers(lam, steps + 2),
        pow_alpha=_powers(alpha, steps + 2), pow_dec_plus=_powers(dec_plus, steps + 2),
        pow_dec_minus=_powers(dec_minus, steps + 2),
        v_bias_rest=rest, v_bias_reset=reset,
        kf_rest_hi=_first_above(rest, n.v_thr_inter), kf_rest_lo=_first_above(rest, thr_low),
        kf_reset_hi=_first_above(reset, n.v_thr_inter),
        kf_reset_lo=_first_above(reset, thr_low),
    )
