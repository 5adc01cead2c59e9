"""Plain, readable reference implementation of one SNAN decision window.

Every equation of the paper (sections 2.2.2-2.2.4) is stepped once per time step for every
cell, in this order within a step ``t`` (``dt`` = 1 ms by default):

1. input: the occupied cell ``c`` emits ``S[t]`` (given spike train); all other inputs are 0;
2. astrocytes (all cells): glutamate ``G += dt*(-alpha_n*G + k_n*S)``, ``J = A`` if
   ``G > G_thr`` else 0, explicit Euler for ``dCa/dt = y``,
   ``dy/dt = (J - 2*tau*y - Ca)/tau**2`` (both from the old values);
3. interneurons (all cells): threshold ``v_thr* / (1 + eta*H(Ca - Ca_thr))`` with the calcium
   of this step (``H(x) = 1`` for ``x > 0``); LIF step with input ``w_in_inter*S + I_bias``;
4. motor neurons (all cells): LIF step with ``I = drive - w_I*S_int`` where ``drive`` is the
   synaptic input from the synapse back-end (``w[c,j]*S[t]`` for software weights) for the
   candidate neighbours and 0 elsewhere, and ``S_int`` the interneuron spike of this step;
5. STDP traces for the synapses ``c -> candidates``; the change accumulates over the window.

LIF step (Eq. 1): if the neuron is refractory (``neuron.refractory = clamp``) its counter
counts down and it ignores its input; otherwise ``v = v_rest + alpha*(v - v_rest) + R*I``
and a spike happens if ``v > thr`` (then ``v = v_reset`` and ``t_ref`` steps of refractoriness).
With ``refractory = integrate`` the potential integrates during refractoriness and only the
spike is suppressed.

STDP (all-to-all, or nearest-spike with ``stdp.pairing = nearest``): a pre trace ``x`` and a
post trace ``y_post`` per candidate decay by ``exp(-dt/tau)`` each step; a post spike adds
``A+ * x`` (pre spikes up to and including this step, so ``dT = 0`` potentiates); a pre
spike adds ``-A- * y_post`` (post spikes strictly before). Traces start at 0 each window.

A trial (:func:`reference_trial`) repeats windows: the window stream draws the input spike
train, the synapse back-end turns it into the drive, the window runs, one more draw breaks
ties between the candidates with the most motor spikes, the window's STDP change goes to the
synapses (``stdp.target``), the agent moves; the trial ends when every goal was visited
(and, with ``return_to_start``, the agent is back on its start) or after ``grid.max_steps``.

This module is slow by design (pure Python loops) and is the test oracle: the trial kernel
(:mod:`snan_hil.host.snan_kernel`) is tested to reproduce it trajectory for trajectory.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from snan_hil.host.config import SnanConfig
from snan_hil.host.rng import WindowStream
from snan_hil.host.state import NetworkState


@dataclass
class WindowResult:
    """Outcome of one decision window."""

    counts: np.ndarray            #: motor spike count per candidate (int64)
    dw: np.ndarray                #: accumulated STDP change per candidate (before k)
    #: optional raster, (step, cell) pairs of this window (only when ``record=True``)
    input_spikes: list[int] = field(default_factory=list)
    motor_spikes: list[tuple[int, int]] = field(default_factory=list)
    inter_spikes: list[tuple[int, int]] = field(default_factory=list)


def lif_step(v: float, ref: int, current: float, thr: float, cfg: SnanConfig,
             alpha: float) -> tuple[float, int, bool]:
    """One time step of a LIF neuron (Eq. 1); returns (v, refractory counter, spiked)."""
    n = cfg.neuron
    if n.refractory == "clamp":
        if ref > 0:
            return v, ref - 1, False
        v = n.v_rest + alpha * (v - n.v_rest) + n.r_m * current
        if v > thr:
            return n.v_reset, cfg.ref_steps, True
        return v, ref, False
    # integrate: potential always integrates, spiking only when not refractory
    v = n.v_rest + alpha * (v - n.v_rest) + n.r_m * current
    if ref > 0:
        return v, ref - 1, False
    if v > thr:
        return n.v_reset, cfg.ref_steps, True
    return v, ref, False


def astro_step(cfg: SnanConfig, g: np.ndarray, ca: np.ndarray, y: np.ndarray, cell: int,
               s_in: float) -> None:
    """One time step of every astrocyte, in place (float64[n_cells] glutamate ``g``, calcium
    ``ca``, calcium rate ``y``), the agent on ``cell`` emitting ``s_in`` (0 or 1) — step 2 of
    the module docstring, paper section 2.2.3: ``G += dt (-alpha_n G + k_n S)``; ``J = A`` if
    ``G > G_thr`` else 0; ``Ca += dt y`` and ``y += dt (J - 2 tau y - Ca) / tau^2``, both from
    the old values. The one Python form of the calcium update (the trial kernel's numba form,
    :func:`snan_hil.host.snan_kernel.astro_step`, is tested equal to it through
    :func:`reference_window`); :mod:`snan_hil.host.calcium_trace` re-runs a trial's calcium
    with it."""
    ast = cfg.astro
    dt = cfg.input.dt_ms
    tau = ast.tau_ca_ms
    s = np.zeros_like(g)
    s[cell] = s_in
    g += dt * (-ast.alpha_n_per_ms * g + ast.k_n * s)
    j_neuro = np.where(g > ast.g_thr, ast.a, 0.0)
    ca_old = ca.copy()
    ca += dt * y
    y += dt * (j_neuro - 2.0 * tau * y - ca_old) / (tau * tau)


def reference_window(state: NetworkState, cfg: SnanConfig, cell: int, candidates: list[int],
                     spikes: np.ndarray, drive: np.ndarray, record: bool = False
                     ) -> WindowResult:
    """Simulate one decision window with the agent on ``cell``.

    ``candidates``: motor-neuron cells that receive the input (the neighbours);
    ``spikes``: bool [T] input spike train of ``cell``; ``drive``: float [T, len(candidates)]
    excitatory synaptic input per step from the synapse back-end. Mutates ``state``.
    """
    nc, a, ast, sd = cfg.neuron, cfg.input, cfg.astro, cfg.stdp
    n_cells = cfg.n_cells
    steps = cfg.window_steps
    dt = a.dt_ms
    alpha = math.exp(-dt / nc.tau_m_ms)
    dec_plus = math.exp(-dt / sd.tau_plus_ms)
    dec_minus = math.exp(-dt / sd.tau_minus_ms)
    lane_of = {c: k for k, c in enumerate(candidates)}
    n_lanes = len(candidates)

    if nc.reset_each_window:
        state.v_mot[:] = nc.v_rest
        state.v_int[:] = nc.v_rest
        state.ref_mot[:] = 0
        state.ref_int[:] = 0

    counts = np.zeros(n_lanes, dtype=np.int64)
    dw = np.zeros(n_lanes)
    x_pre = 0.0
    y_post = [0.0] * n_lanes
    res = WindowResult(counts=counts, dw=dw)
    s_int = [False] * n_cells

    for t in range(steps):
        s_in = 1.0 if spikes[t] else 0.0
        # 2. astrocytes
        if ast.enabled:
            astro_step(cfg, state.g, state.ca, state.y, cell, s_in)
        # 3. interneurons
        for i in range(n_cells):
            thr = nc.v_thr_inter
            if ast.enabled and state.ca[i] > ast.ca_thr:
                thr = nc.v_thr_inter / (1.0 + ast.eta)
            cur = (cfg.synapse.w_in_inter * s_in if i == cell else 0.0) + nc.i_bias
            v, r, sp = lif_step(state.v_int[i], int(state.ref_int[i]), cur, thr, cfg, alpha)
            state.v_int[i], state.ref_int[i], s_int[i] = v, r, sp
            if sp and record:
                res.inter_spikes.append((t, i))
        # 4. motor neurons
        post = [False] * n_lanes
        for j in range(n_cells):
            lane = lane_of.get(j, -1)
            exc = drive[t, lane] if lane >= 0 else 0.0
            cur = exc - (cfg.synapse.w_inh if s_int[j] else 0.0)
            v, r, sp = lif_step(state.v_mot[j], int(state.ref_mot[j]), cur,
                                nc.v_thr_motor, cfg, alpha)
            state.v_mot[j], state.ref_mot[j] = v, r
            if sp:
                if lane >= 0:
                    counts[lane] += 1
                    post[lane] = True
                if record:
                    res.motor_spikes.append((t, j))
        if record and s_in:
            res.input_spikes.append(t)
        # 5. STDP traces
        if sd.pairing == "nearest":
            x_pre = 1.0 if s_in else x_pre * dec_plus
        else:
            x_pre = x_pre * dec_plus + s_in
        for k in range(n_lanes):
            y_post[k] *= dec_minus
            if post[k]:
                dw[k] += sd.a_plus * x_pre
            if s_in:
                dw[k] -= sd.a_minus * y_post[k]
            if post[k]:
                y_post[k] = 1.0 if sd.pairing == "nearest" else y_post[k] + 1.0
    state.t_now += steps
    state.t_astro[:] = state.t_now
    return res


def choose(counts: Sequence[int] | np.ndarray, cfg: SnanConfig, draw) -> int:
    """Index of the winning candidate (most spikes, ties at random); -1 = stay.

    Consumes exactly one draw of the window stream whatever happens.
    """
    n = len(counts)
    if n == 0:
        draw(1)
        return -1
    mx = int(max(counts))
    tied = [k for k in range(n) if counts[k] == mx]
    idx = draw(len(tied))
    if mx == 0 and cfg.decision.no_spike == "stay":
        return -1
    return tied[idx]


def window_changes(dw: np.ndarray, chosen: int, cfg: SnanConfig,
                   target: str | None = None) -> np.ndarray:
    """The window's weight change per candidate: the chosen one ``k * dw``, the others by
    ``stdp.target`` (``all``/``normalize``: their own ``dw``; ``chosen``: 0;
    ``depress_others``: ``-|dw|``)."""
    target = target or cfg.stdp.target
    scaled = np.array(dw, dtype=np.float64)
    if chosen >= 0:
        scaled[chosen] = scaled[chosen] * cfg.stdp.k
    if target == "chosen":
        keep = np.zeros_like(scaled)
        if chosen >= 0:
            keep[chosen] = scaled[chosen]
        scaled = keep
    elif target == "depress_others":
        others = np.arange(len(scaled)) != chosen
        scaled[others] = -np.abs(scaled[others])
    return scaled


@dataclass
class ReferenceTrial:
    """Outcome of :func:`reference_trial`."""

    path: list[int]
    success: bool
    counts: np.ndarray                       #: [steps, 4] spike counts, -1 = no candidate
    windows: list[WindowResult]


def reference_trial(cfg: SnanConfig, nbr: np.ndarray, move: np.ndarray, start: int,
                    goals: Sequence[int], key: int, backend: Any, *, record: bool = False,
                    return_to_start: bool = False) -> ReferenceTrial:
    """One trial (see module doc) with the synapse back-end ``backend`` (``drive``,
    ``apply_update``; ``snan_hil.host.agent.SynapseBackend``). ``nbr[i, d]``: motor-neuron
    cell of direction d (-1: none); ``move[i, d]``: where choosing d leads (-1: stay);
    ``key``: the window stream's state. With ``stdp.mode = trial_end`` the updates are
    applied in order when the trial ends."""
    stream = WindowStream(key)
    st = NetworkState.fresh(cfg)
    steps_w = cfg.window_steps
    remaining = set(int(g) for g in goals)
    pos = int(start)
    path = [pos]
    counts_hist = np.full((cfg.grid.max_steps, 4), -1, dtype=np.int64)
    windows: list[WindowResult] = []
    deferred: list[tuple[int, list[int], np.ndarray]] = []
    success = False
    for step in range(cfg.grid.max_steps):
        dirs = [d for d in range(4) if nbr[pos, d] >= 0]
        cands = [int(nbr[pos, d]) for d in dirs]
        spikes = stream.spikes(steps_w, cfg.input.p)
        drive = np.asarray(backend.drive(pos, dirs, spikes), dtype=np.float64)
        if drive.shape != (steps_w, len(dirs)):
            raise ValueError(f"synapse back-end returned drive of shape {drive.shape}, "
                             f"expected {(steps_w, len(dirs))}")
        res = reference_window(st, cfg, pos, cands, spikes, drive, record=record)
        if record:
            windows.append(res)
        for k, d in enumerate(dirs):
            counts_hist[step, d] = res.counts[k]
        chosen = choose(res.counts, cfg, stream.choice)
        if cfg.stdp.mode != "off" and dirs:
            scaled = window_changes(res.dw, chosen, cfg)
            if cfg.stdp.mode == "window":
                backend.apply_update(pos, dirs, scaled)
            else:
                deferred.append((pos, dirs, scaled))
        if chosen >= 0:
            dest = int(move[pos, dirs[chosen]])
            if dest >= 0:
                pos = dest
        path.append(pos)
        remaining.discard(pos)
        if not remaining and (not return_to_start or pos == int(start)):
            success = True
            break
    for pre, dirs, scaled in deferred:
        backend.apply_update(pre, dirs, scaled)
    return ReferenceTrial(path, success, counts_hist[:len(path) - 1].copy(), windows)
