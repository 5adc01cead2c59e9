"""Numba trial loop of the experiments: the agent's trial loop plus what the paper's later
sections need.

It reuses the agent's event-driven window engine (:func:`snan_hil.host.snan_kernel.
fast_window_core` and its pieces, so the neuron and astrocyte dynamics are the agent's own)
and adds, each as a named option whose default keeps the agent's behaviour:

* **return to start** (Fig. 6C/D): after every goal was visited the trial goes on until the
  agent is back on its start cell;
* **where the window's STDP change goes** (``target``, the route-learning question of
  Fig. 7): ``all`` = every candidate synapse gets its own change, the chosen move's change
  times ``k`` (the agent's reading); ``chosen`` = only the chosen move's synapse changes
  (by ``k`` times its change); ``depress_others`` = chosen ``k*dw``, the other candidates
  ``-|dw|``; ``normalize`` = as ``all``, then the cell's outgoing weights are scaled back
  to their sum before the update (heterosynaptic normalisation);
* **memristive plasticity** (``plasticity = vteam``): the window's change of a synapse is the
  sum over spike pairs of a VTEAM device lookup ``dw(w, dt)`` instead of the additive rule.

With the defaults (no return, ``all``, additive) a trial equals
:func:`snan_hil.host.snan_kernel.run_trial_kernel` step for step (tested), so the
experiments and ``snan-hil sim`` agree. Only the ``fast`` engine is supported
(``neuron.reset_each_window = true``, the agent's default reading).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from snan_hil.host import snan_kernel as K

# ---- int options (xi) ---------------------------------------------------------------------
X_RETURN, X_TARGET, X_PLAST, X_NEAREST_V = range(4)
N_XI = 4
TARGETS = K.TARGET_CODES     # the agent's own stdp.target codes (snan_kernel)
PLAST_ADDITIVE, PLAST_VTEAM = 0, 1
# ---- float options (xp) -------------------------------------------------------------------
XP_LATENCY, XP_DT0, XP_DTSTEP, XP_DT = range(4)
N_XP = 4

_I_STEPS = K.I_STEPS
_I_STDP = K.I_STDP
_I_ASTRO = K.I_ASTRO
_I_STAY = K.I_STAY
_I_MAXSTEPS = K.I_MAXSTEPS
_I_SPIKETHR = K.I_SPIKETHR
_I_REST_HI = K.I_KF_REST_HI
_F_K = K.F_K
_F_WMIN = K.F_WMIN
_F_WMAX = K.F_WMAX
_STDP_OFF = K.STDP_OFF
_STDP_TRIAL_END = K.STDP_TRIAL_END
_NEVER = K.NEVER


@njit(cache=True)
def lut_value(lut, w, dt_ms, dt0, dtstep):
    """Bilinear lookup of ``lut[w_index, dt_index]`` (w on 0..1 in equal steps, dt from
    ``dt0`` in ``dtstep`` ms); 0 outside the dt range. Same as ``StdpLookup.delta_w``."""
    n_w = lut.shape[0]
    n_dt = lut.shape[1]
    wc = min(max(w, 0.0), 1.0)
    wi = wc * (n_w - 1)
    i0 = int(np.floor(wi))
    if i0 > n_w - 2:
        i0 = n_w - 2
    fw = wi - i0
    dj = (dt_ms - dt0) / dtstep
    if dj < 0.0 or dj > n_dt - 1:
        return 0.0
    j0 = int(np.floor(dj))
    if j0 > n_dt - 2:
        j0 = n_dt - 2
    fd = dj - j0
    return ((1 - fw) * (1 - fd) * lut[i0, j0] + fw * (1 - fd) * lut[i0 + 1, j0]
            + (1 - fw) * fd * lut[i0, j0 + 1] + fw * fd * lut[i0 + 1, j0 + 1])


@njit(cache=True)
def vteam_lane(sp, ns, post, n_post, w0, lut, xp, nearest):
    """Window change of one synapse from its pre (``sp[:ns]``) and post (``post[:n_post]``)
    spike steps under the VTEAM lookup. A pair's delay is ``(t_post - t_pre)*dt + latency``
    ms (a motor spike caused by an input spike of the same step comes ``latency`` after
    it). All pairs within the lookup's range (``nearest``: each post spike with the latest
    pre spike at or before it, each pre spike with the latest post spike before it)."""
    dt = xp[XP_DT]
    lat = xp[XP_LATENCY]
    dt0 = xp[XP_DT0]
    dts = xp[XP_DTSTEP]
    span = -dt0 + lat
    dwk = 0.0
    if nearest:
        a = 0
        for b in range(n_post):
            tp = post[b]
            while a + 1 < ns and sp[a + 1] <= tp:
                a += 1
            if a < ns and sp[a] <= tp:
                dwk += lut_value(lut, w0, (tp - sp[a]) * dt + lat, dt0, dts)
        b = 0
        for a in range(ns):
            tq = sp[a]
            while b + 1 < n_post and post[b + 1] < tq:
                b += 1
            if b < n_post and post[b] < tq:
                dwk += lut_value(lut, w0, (post[b] - tq) * dt + lat, dt0, dts)
        return dwk
    lo = 0
    for b in range(n_post):
        tp = post[b]
        while lo < ns and (tp - sp[lo]) * dt > span:
            lo += 1
        a = lo
        while a < ns and (sp[a] - tp) * dt <= span:
            dwk += lut_value(lut, w0, (tp - sp[a]) * dt + lat, dt0, dts)
            a += 1
    return dwk


@njit(cache=True)
def vteam_window_core(fp, ip, tab, cell, cands, n_lanes, sp, ns, wl, wdev, t_now, g, ca, y,
                      t_cell, counts, dw, scratch_i, h_on, h_off, lut, xp, nearest):
    """:func:`snan_kernel.fast_window_core` with the VTEAM change per synapse (device state
    ``wdev[lane]``) instead of the additive rule; dynamics identical."""
    steps = ip[_I_STEPS]
    astro = ip[_I_ASTRO] != 0
    if astro:
        K.advance_idle(cell, t_now - t_cell[cell], fp, ip, tab, g, ca, y)
        for k in range(n_lanes):
            K.advance_idle(cands[k], t_now - t_cell[cands[k]], fp, ip, tab, g, ca, y)
    isp = scratch_i[0]
    post = scratch_i[1]
    drive = np.zeros((1, 4))
    for k in range(n_lanes):
        n_int = 0
        if astro:
            n_int = K.candidate_astro(cands[k], k, fp, ip, tab, g, ca, y, h_on, h_off)
        n_isp = 0
        if n_int > 0 or ip[_I_REST_HI] < _NEVER:
            n_isp = K.interneuron_spikes(k, n_int, h_on, h_off, fp, ip, isp)
        n_post = K.motor_lane(k, sp, ns, isp, n_isp, wl[k], drive, False, fp, ip, tab, post)
        counts[k] = n_post
        if ip[_I_STDP] != _STDP_OFF:
            dw[k] = vteam_lane(sp, ns, post, n_post, wdev[k], lut, xp, nearest)
        else:
            dw[k] = 0.0
    if astro:
        K.current_cell_astro(cell, sp, ns, fp, ip, tab, g, ca, y)
    t_cell[cell] = t_now + steps
    for k in range(n_lanes):
        t_cell[cands[k]] = t_now + steps


@njit(cache=True)
def trial_kernel(fp, ip, tab, xi, xp, lut, nbr, move, start, goals, w, key, path):
    """One trial from a fresh network state (see module doc). ``w`` (float64 [N, 4]) holds
    the initial weights and receives the learned ones (unless STDP is off). ``path`` gets
    the visited cells. Returns (steps, success)."""
    n_cells = nbr.shape[0]
    steps_w = ip[_I_STEPS]
    max_steps = ip[_I_MAXSTEPS]
    g = np.zeros(n_cells)
    ca = np.zeros(n_cells)
    y = np.zeros(n_cells)
    t_cell = np.zeros(n_cells, dtype=np.int64)
    spikes = np.zeros(steps_w, dtype=np.bool_)
    sp = np.zeros(steps_w, dtype=np.int64)
    drive = np.zeros((1, 4))
    cands = np.zeros(4, dtype=np.int64)
    dirs = np.zeros(4, dtype=np.int64)
    counts = np.zeros(4, dtype=np.int64)
    dw = np.zeros(4)
    wl = np.zeros(4)
    wdev = np.zeros(4)
    tied = np.zeros(4, dtype=np.int64)
    scratch = np.empty((2, steps_w + 1), dtype=np.int64)
    h_on = np.empty((4, 64), dtype=np.int64)
    h_off = np.empty((4, 64), dtype=np.int64)
    n_goals = goals.shape[0]
    reached = np.zeros(n_goals, dtype=np.bool_)
    n_reached = 0
    ret = xi[X_RETURN] != 0
    target = xi[X_TARGET]
    vteam = xi[X_PLAST] == PLAST_VTEAM
    nearest = xi[X_NEAREST_V] != 0
    pos = start
    path[0] = start
    t_now = 0
    stdp = ip[_I_STDP]
    kf = fp[_F_K]
    wmin = fp[_F_WMIN]
    wmax = fp[_F_WMAX]
    w_run = w.copy() if stdp == _STDP_TRIAL_END else w
    for step in range(max_steps):
        n_lanes = 0
        for d in range(4):
            nb = nbr[pos, d]
            if nb >= 0:
                cands[n_lanes] = nb
                dirs[n_lanes] = d
                wl[n_lanes] = w_run[pos, d]
                wdev[n_lanes] = w[pos, d]
                n_lanes += 1
        key, ns = K.draw_spikes(key, steps_w, ip[_I_SPIKETHR], spikes, sp)
        if vteam:
            vteam_window_core(fp, ip, tab, pos, cands, n_lanes, sp, ns, wl, wdev, t_now, g,
                              ca, y, t_cell, counts, dw, scratch, h_on, h_off, lut, xp,
                              nearest)
        else:
            K.fast_window_core(fp, ip, tab, pos, cands, n_lanes, sp, ns, wl, drive, False,
                               t_now, g, ca, y, t_cell, counts, dw, scratch, h_on, h_off)
        t_now += steps_w
        key, z = K.splitmix_next(key)
        chosen = K.choose_lane(counts, n_lanes, z, ip[_I_STAY] != 0, tied)
        if stdp != _STDP_OFF:
            K.apply_window_stdp(w, pos, dirs, n_lanes, dw, chosen, target, kf, wmin, wmax)
        if chosen >= 0:
            dest = move[pos, dirs[chosen]]
            if dest >= 0:
                pos = dest
        path[step + 1] = pos
        for gi in range(n_goals):
            if not reached[gi] and goals[gi] == pos:
                reached[gi] = True
                n_reached += 1
        if n_reached == n_goals and (not ret or pos == start):
            return step + 1, True
    return max_steps, False
