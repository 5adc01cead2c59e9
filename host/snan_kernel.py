"""Fast numba kernels for the SNAN agent.

Two window engines share one trial loop and one state layout (:class:`NetworkState`):

* ``full`` (:func:`full_window`): the reference equations stepped every time step for the
  *relevant* cells (the occupied cell and its candidate neighbours). An idle cell is not
  touched while idle; when it becomes relevant again it is first caught up step by step
  with the idle equations (no input), so results are bit-for-bit the reference's. Supports
  every option, also membrane potentials carried over between windows.
* ``fast`` (:func:`fast_window`): event-driven, for ``neuron.reset_each_window = true``
  (the default reading). Astrocytes are advanced in closed form between changes of their
  glutamate drive J (the Euler recurrence of the calcium model has the double eigenvalue
  ``1 - dt/tau``, so ``M^n = lam^n I + n lam^(n-1) (M - lam I)``); motor neurons are updated
  only at input / inhibitory spike events (exact decay ``alpha^n`` in between); candidate
  interneurons follow a precomputed bias-only trajectory table; STDP traces are updated at
  events. These are the same recurrences, so only floating-point rounding differs (~1e-12
  relative): spike counts and trajectories equal the reference's except in threshold ties
  of that size (tested on many windows).

All parameters are packed into ``fp`` (float64), ``ip`` (int64) and ``tab`` (float64 tables)
by :func:`pack_params`, so the kernels compile once (``cache=True``) for any configuration.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from snan_hil.host.config import SnanConfig
from snan_hil.host.rng import spike_threshold

# ---- float parameter indices --------------------------------------------------------------
F_ALPHA, F_VREST, F_VTHR_M, F_VTHR_I, F_VRESET, F_RM, F_IBIAS, F_WININ, F_WINH, F_DT = range(10)
F_ALPHAN, F_KN, F_GTHR, F_A, F_TAU, F_CATHR, F_ETA, F_APLUS, F_AMINUS, F_DECP = range(10, 20)
F_DECM, F_WMIN, F_WMAX, F_K, F_VTHR_I_LOW, F_Q, F_LAM = range(20, 27)
N_FP = 27
# ---- int parameter indices ----------------------------------------------------------------
I_STEPS, I_REF, I_INTEGRATE, I_RESET, I_ASTRO, I_STDP, I_NEAREST, I_STAY, I_MAXSTEPS = range(9)
I_SPIKETHR, I_BUMP, I_ENGINE, I_KF_REST_LO, I_KF_REST_HI, I_KF_RESET_LO = range(9, 15)
I_KF_RESET_HI = 15
I_TARGET = 16
N_IP = 17
# ---- table rows (each of length steps + 2) --------------------------------------------------
T_QPOW, T_LAMPOW, T_APOW, T_DECP, T_DECM, T_VREST, T_VRESET = range(7)
N_TAB = 7

ENGINE_FULL = 0
ENGINE_FAST = 1
STDP_OFF, STDP_WINDOW, STDP_TRIAL_END = 0, 1, 2
#: ``stdp.target``: which candidate synapses a window's STDP change goes to (docs/model.md)
TARGET_ALL, TARGET_CHOSEN, TARGET_DEPRESS, TARGET_NORMALIZE = 0, 1, 2, 3
TARGET_CODES = {"all": TARGET_ALL, "chosen": TARGET_CHOSEN,
                "depress_others": TARGET_DEPRESS, "normalize": TARGET_NORMALIZE}
NEVER = 1 << 40  # "no such step"

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MUL1 = np.uint64(0xBF58476D1CE4E5B9)
_MUL2 = np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _S11, _S53 = (np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11),
                                np.uint64(53))


def pack_params(cfg: SnanConfig, engine: int = ENGINE_FULL
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pack a config into (fp float64[N_FP], ip int64[N_IP], tab float64[N_TAB, T+2])."""
    n, s, a, d, ast = cfg.neuron, cfg.synapse, cfg.input, cfg.stdp, cfg.astro
    fp = np.zeros(N_FP)
    alpha = math.exp(-a.dt_ms / n.tau_m_ms)
    fp[F_ALPHA] = alpha
    fp[F_VREST], fp[F_VTHR_M], fp[F_VTHR_I] = n.v_rest, n.v_thr_motor, n.v_thr_inter
    fp[F_VRESET], fp[F_RM], fp[F_IBIAS] = n.v_reset, n.r_m, n.i_bias
    fp[F_WININ], fp[F_WINH], fp[F_DT] = s.w_in_inter, s.w_inh, a.dt_ms
    fp[F_ALPHAN], fp[F_KN], fp[F_GTHR], fp[F_A] = ast.alpha_n_per_ms, ast.k_n, ast.g_thr, ast.a
    fp[F_TAU], fp[F_CATHR], fp[F_ETA] = ast.tau_ca_ms, ast.ca_thr, ast.eta
    fp[F_APLUS], fp[F_AMINUS] = d.a_plus, d.a_minus
    fp[F_DECP] = math.exp(-a.dt_ms / d.tau_plus_ms)
    fp[F_DECM] = math.exp(-a.dt_ms / d.tau_minus_ms)
    fp[F_WMIN], fp[F_WMAX], fp[F_K] = d.w_min, d.w_max, d.k
    thr_low = n.v_thr_inter / (1.0 + ast.eta)
    fp[F_VTHR_I_LOW] = thr_low
    fp[F_Q] = 1.0 - ast.alpha_n_per_ms * a.dt_ms
    fp[F_LAM] = 1.0 - a.dt_ms / ast.tau_ca_ms
    ip = np.zeros(N_IP, dtype=np.int64)
    steps = cfg.window_steps
    ip[I_STEPS], ip[I_REF] = steps, cfg.ref_steps
    ip[I_INTEGRATE] = int(n.refractory == "integrate")
    ip[I_RESET] = int(n.reset_each_window)
    ip[I_ASTRO] = int(ast.enabled)
    ip[I_STDP] = {"off": STDP_OFF, "window": STDP_WINDOW, "trial_end": STDP_TRIAL_END}[d.mode]
    ip[I_NEAREST] = int(d.pairing == "nearest")
    ip[I_TARGET] = TARGET_CODES[d.target]
    ip[I_STAY] = int(cfg.decision.no_spike == "stay")
    ip[I_MAXSTEPS] = cfg.grid.max_steps
    ip[I_SPIKETHR] = spike_threshold(a.p)
    ip[I_BUMP] = int(cfg.grid.walls == "bump")
    ip[I_ENGINE] = engine
    # tables: powers by repeated multiplication, bias-only interneuron trajectories by the
    # reference's own per-step formula (so they are bit-identical to it)
    tab = np.zeros((N_TAB, steps + 2))
    for row, base in ((T_QPOW, fp[F_Q]), (T_LAMPOW, fp[F_LAM]), (T_APOW, alpha),
                      (T_DECP, fp[F_DECP]), (T_DECM, fp[F_DECM])):
        v = 1.0
        for k in range(steps + 2):
            tab[row, k] = v
            v = v * base
    cur = 0.0 + n.i_bias
    for row, v0 in ((T_VREST, n.v_rest), (T_VRESET, n.v_reset)):
        v = v0
        for k in range(steps + 2):
            tab[row, k] = v
            v = n.v_rest + alpha * (v - n.v_rest) + n.r_m * cur
    for row, i_lo, i_hi in ((T_VREST, I_KF_REST_LO, I_KF_REST_HI),
                            (T_VRESET, I_KF_RESET_LO, I_KF_RESET_HI)):
        for idx, thr in ((i_lo, thr_low), (i_hi, n.v_thr_inter)):
            above = np.nonzero(tab[row, 1:] > thr)[0]
            ip[idx] = int(above[0]) + 1 if above.size else NEVER
    return fp, ip, tab


def fast_supported(cfg: SnanConfig) -> bool:
    """The event-driven engine covers the default reading (potentials reset per window)
    and needs a non-decreasing bias-only interneuron trajectory (i_bias >= 0)."""
    return cfg.neuron.reset_each_window and cfg.neuron.i_bias >= 0


# ---- random stream (same integer arithmetic as snan_hil.host.rng) ------------------------
@njit(cache=True, inline="always")
def splitmix_next(state):
    state = state + _GOLDEN
    z = state
    z = (z ^ (z >> _S30)) * _MUL1
    z = (z ^ (z >> _S27)) * _MUL2
    return state, z ^ (z >> _S31)


@njit(cache=True)
def draw_spikes(key, steps, thr, out, idx):
    """Fill bool ``out[:steps]`` with the window's input spike train and ``idx`` with the
    spike steps; return (new key, number of spikes)."""
    uthr = np.uint64(thr)
    ns = 0
    for t in range(steps):
        key, z = splitmix_next(key)
        s = (z >> _S11) < uthr
        out[t] = s
        if s:
            idx[ns] = t
            ns += 1
    return key, ns


@njit(cache=True, inline="always")
def pick_index(z, n):
    return np.int64(((z >> _S11) * np.uint64(n)) >> _S53)


# ---- the LIF step of Eq. 1 ----------------------------------------------------------------
@njit(cache=True, inline="always")
def lif(v, ref, cur, thr, fp, ip):
    """One step of a LIF neuron; returns (v, ref, spiked). Same as reference.lif_step."""
    if ip[I_INTEGRATE] == 0:
        if ref > 0:
            return v, ref - 1, False
        v = fp[F_VREST] + fp[F_ALPHA] * (v - fp[F_VREST]) + fp[F_RM] * cur
        if v > thr:
            return fp[F_VRESET], ip[I_REF], True
        return v, ref, False
    v = fp[F_VREST] + fp[F_ALPHA] * (v - fp[F_VREST]) + fp[F_RM] * cur
    if ref > 0:
        return v, ref - 1, False
    if v > thr:
        return fp[F_VRESET], ip[I_REF], True
    return v, ref, False


@njit(cache=True, inline="always")
def astro_step(i, s_in, fp, g, ca, y):
    """One Euler step of glutamate and calcium of astrocyte ``i`` (reference order)."""
    dt = fp[F_DT]
    tau = fp[F_TAU]
    gi = g[i]
    gi = gi + dt * (-fp[F_ALPHAN] * gi + fp[F_KN] * s_in)
    g[i] = gi
    jn = fp[F_A] if gi > fp[F_GTHR] else 0.0
    c = ca[i]
    yy = y[i]
    ca[i] = c + dt * yy
    y[i] = yy + dt * (jn - 2.0 * tau * yy - c) / (tau * tau)


@njit(cache=True, inline="always")
def inter_threshold(i, fp, ip, ca):
    if ip[I_ASTRO] != 0 and ca[i] > fp[F_CATHR]:
        return fp[F_VTHR_I_LOW]
    return fp[F_VTHR_I]


# ---- full (per-step) engine ---------------------------------------------------------------
@njit(cache=True)
def catch_up_full(i, t_target, fp, ip, v_mot, ref_mot, v_int, ref_int, g, ca, y, t_cell):
    """Step idle cell ``i`` (no input, not a candidate) from t_cell[i] to t_target."""
    n = t_target - t_cell[i]
    if n <= 0:
        return
    astro = ip[I_ASTRO] != 0
    neurons = ip[I_RESET] == 0
    if astro or neurons:
        for _ in range(n):
            if astro:
                astro_step(i, 0.0, fp, g, ca, y)
            if neurons:
                thr = inter_threshold(i, fp, ip, ca)
                vi, ri, si = lif(v_int[i], ref_int[i], 0.0 + fp[F_IBIAS], thr, fp, ip)
                v_int[i] = vi
                ref_int[i] = ri
                inh = fp[F_WINH] if si else 0.0
                vm, rm, _sm = lif(v_mot[i], ref_mot[i], 0.0 - inh, fp[F_VTHR_M], fp, ip)
                v_mot[i] = vm
                ref_mot[i] = rm
    t_cell[i] = t_target


@njit(cache=True)
def full_window(fp, ip, tab, cell, cands, n_lanes, spikes, drive, t_now,
                v_mot, ref_mot, v_int, ref_int, g, ca, y, t_cell, counts, dw):
    """One decision window, stepped every time step (see module doc). ``drive[t, lane]`` is
    the excitatory synaptic input of candidate ``lane``. Writes ``counts`` and ``dw``."""
    steps = ip[I_STEPS]
    n_rel = n_lanes + 1
    rel = np.empty(n_rel, dtype=np.int64)
    rel[0] = cell
    for k in range(n_lanes):
        rel[k + 1] = cands[k]
    for k in range(n_rel):
        catch_up_full(rel[k], t_now, fp, ip, v_mot, ref_mot, v_int, ref_int, g, ca, y, t_cell)
    if ip[I_RESET] != 0:
        for k in range(n_rel):
            c = rel[k]
            v_mot[c] = fp[F_VREST]
            v_int[c] = fp[F_VREST]
            ref_mot[c] = 0
            ref_int[c] = 0
    for k in range(n_lanes):
        counts[k] = 0
        dw[k] = 0.0
    astro = ip[I_ASTRO] != 0
    nearest = ip[I_NEAREST] != 0
    x_pre = 0.0
    y_post = np.zeros(4)
    s_int = np.zeros(n_rel, dtype=np.bool_)
    post = np.zeros(4, dtype=np.bool_)
    for t in range(steps):
        s_in = 1.0 if spikes[t] else 0.0
        if astro:
            for k in range(n_rel):
                astro_step(rel[k], s_in if k == 0 else 0.0, fp, g, ca, y)
        for k in range(n_rel):
            c = rel[k]
            thr = inter_threshold(c, fp, ip, ca)
            cur = (fp[F_WININ] * s_in if k == 0 else 0.0) + fp[F_IBIAS]
            vi, ri, si = lif(v_int[c], ref_int[c], cur, thr, fp, ip)
            v_int[c] = vi
            ref_int[c] = ri
            s_int[k] = si
        for k in range(n_rel):
            c = rel[k]
            exc = drive[t, k - 1] if k > 0 else 0.0
            cur = exc - (fp[F_WINH] if s_int[k] else 0.0)
            vm, rm, sm = lif(v_mot[c], ref_mot[c], cur, fp[F_VTHR_M], fp, ip)
            v_mot[c] = vm
            ref_mot[c] = rm
            if k > 0:
                post[k - 1] = sm
                if sm:
                    counts[k - 1] += 1
        if nearest:
            x_pre = 1.0 if s_in != 0.0 else x_pre * fp[F_DECP]
        else:
            x_pre = x_pre * fp[F_DECP] + s_in
        for k in range(n_lanes):
            y_post[k] *= fp[F_DECM]
            if post[k]:
                dw[k] += fp[F_APLUS] * x_pre
            if s_in != 0.0:
                dw[k] -= fp[F_AMINUS] * y_post[k]
            if post[k]:
                y_post[k] = 1.0 if nearest else y_post[k] + 1.0
    for k in range(n_rel):
        t_cell[rel[k]] = t_now + steps


# ---- fast (event-driven) engine: closed forms ---------------------------------------------
@njit(cache=True, inline="always")
def powt(tab, row, base, n):
    """base**n from the table when n is small, else by pow()."""
    if n < tab.shape[1]:
        return tab[row, n]
    return base ** n


@njit(cache=True)
def ca_advance(c0, y0, jn, n, fp, tab):
    """(Ca, y) after n Euler steps with constant drive jn (closed form)."""
    if n <= 0:
        return c0, y0
    dt = fp[F_DT]
    tau = fp[F_TAU]
    lam = fp[F_LAM]
    e0 = c0 - jn
    ln = powt(tab, T_LAMPOW, lam, n)
    ln1 = powt(tab, T_LAMPOW, lam, n - 1)
    r = dt / tau
    e = ln * e0 + n * ln1 * (r * e0 + dt * y0)
    yy = ln * y0 + n * ln1 * (-(r / tau) * e0 - r * y0)
    return jn + e, yy


@njit(cache=True)
def g_active_steps(g0, n, fp, tab):
    """Number of the n idle steps (leading ones) in which G = g0*q^m stays above G_thr."""
    thr = fp[F_GTHR]
    q = fp[F_Q]
    if n <= 0 or g0 * q <= thr:
        return 0
    if g0 * powt(tab, T_QPOW, q, n) > thr:
        return n
    cnt = int(math.floor(math.log(thr / g0) / math.log(q)))
    if cnt < 0:
        cnt = 0
    if cnt > n:
        cnt = n
    while cnt < n and g0 * powt(tab, T_QPOW, q, cnt + 1) > thr:
        cnt += 1
    while cnt > 0 and g0 * powt(tab, T_QPOW, q, cnt) <= thr:
        cnt -= 1
    return cnt


@njit(cache=True)
def advance_idle(i, n, fp, ip, tab, g, ca, y):
    """Advance astrocyte ``i`` by n steps without input."""
    if n <= 0 or ip[I_ASTRO] == 0:
        return
    g0 = g[i]
    cnt = g_active_steps(g0, n, fp, tab)
    c, yy = ca_advance(ca[i], y[i], fp[F_A], cnt, fp, tab)
    c, yy = ca_advance(c, yy, 0.0, n - cnt, fp, tab)
    ca[i] = c
    y[i] = yy
    g[i] = g0 * powt(tab, T_QPOW, fp[F_Q], n)


@njit(cache=True)
def current_cell_astro(i, sp, ns, fp, ip, tab, g, ca, y):
    """Astrocyte of the occupied cell over one window with input spikes at steps sp[:ns].

    G is followed spike by spike; Ca/y are advanced in closed form only where J changes.
    """
    steps = ip[I_STEPS]
    a_amp = fp[F_A]
    dt = fp[F_DT]
    gi = g[i]
    c = ca[i]
    yy = y[i]
    j_run = 0.0   # drive of the pending run of steps
    n_run = 0     # its length
    prev = -1
    for k in range(ns + 1):
        s = sp[k] if k < ns else steps
        gap = s - prev - 1
        if gap > 0:
            cnt = g_active_steps(gi, gap, fp, tab)
            if cnt > 0:
                if j_run != a_amp:
                    c, yy = ca_advance(c, yy, j_run, n_run, fp, tab)
                    j_run = a_amp
                    n_run = 0
                n_run += cnt
            if gap - cnt > 0:
                if j_run != 0.0:
                    c, yy = ca_advance(c, yy, j_run, n_run, fp, tab)
                    j_run = 0.0
                    n_run = 0
                n_run += gap - cnt
            gi = gi * powt(tab, T_QPOW, fp[F_Q], gap)
        if k < ns:
            gi = gi + dt * (-fp[F_ALPHAN] * gi + fp[F_KN] * 1.0)
            jn = a_amp if gi > fp[F_GTHR] else 0.0
            if jn != j_run:
                c, yy = ca_advance(c, yy, j_run, n_run, fp, tab)
                j_run = jn
                n_run = 0
            n_run += 1
        prev = s
    c, yy = ca_advance(c, yy, j_run, n_run, fp, tab)
    g[i] = gi
    ca[i] = c
    y[i] = yy


@njit(cache=True)
def _ca_value(c0, y0, jn, m, fp, tab):
    c, _ = ca_advance(c0, y0, jn, m, fp, tab)
    return c


@njit(cache=True)
def _piece_h(c0, y0, jn, length, t_first, fp, tab, h_on, h_off, n_int, lane, state):
    """Append to lane's H=1 intervals the steps t_first .. t_first+length-1 of an idle
    piece with constant drive jn starting from (c0, y0). ``state`` = [H of the previous
    step, start of the open interval]. Returns the new interval count."""
    if length <= 0:
        return n_int
    thr = fp[F_CATHR]
    lam = fp[F_LAM]
    # unimodal (a + b m) lam^m: check endpoints and the extremum
    const = -1
    if lam > 0.0:
        v1 = _ca_value(c0, y0, jn, 1, fp, tab)
        v2 = _ca_value(c0, y0, jn, length, fp, tab)
        above = v1 > thr
        same = (v2 > thr) == above
        if same:
            dt = fp[F_DT]
            e0 = c0 - jn
            d0 = (dt / fp[F_TAU]) * e0 + dt * y0
            b = d0 / lam
            if b != 0.0:
                m_ext = -1.0 / math.log(lam) - e0 / b
                if 1.0 < m_ext < length:
                    mf = int(math.floor(m_ext))
                    for mm in (mf, mf + 1):
                        if mm >= 1 and mm <= length:
                            if (_ca_value(c0, y0, jn, mm, fp, tab) > thr) != above:
                                same = False
        if same:
            const = 1 if above else 0
    if const >= 0:
        hv = const == 1
        if hv and state[0] == 0:
            state[0] = 1
            state[1] = t_first
        elif not hv and state[0] == 1:
            h_on[lane, n_int] = state[1]
            h_off[lane, n_int] = t_first
            n_int += 1
            state[0] = 0
        return n_int
    # a crossing inside the piece: step it (reference recurrence, constant J)
    dt = fp[F_DT]
    tau = fp[F_TAU]
    c = c0
    yy = y0
    for m in range(length):
        c_new = c + dt * yy
        yy = yy + dt * (jn - 2.0 * tau * yy - c) / (tau * tau)
        c = c_new
        hv = c > thr
        t = t_first + m
        if hv and state[0] == 0:
            state[0] = 1
            state[1] = t
        elif not hv and state[0] == 1:
            if n_int < h_on.shape[1]:
                h_on[lane, n_int] = state[1]
                h_off[lane, n_int] = t
                n_int += 1
            state[0] = 0
    return n_int


@njit(cache=True)
def candidate_astro(i, lane, fp, ip, tab, g, ca, y, h_on, h_off):
    """Idle astrocyte of a candidate over one window: fill lane's H=1 intervals
    [h_on, h_off) (window steps), advance its state. Returns the number of intervals."""
    steps = ip[I_STEPS]
    if ip[I_ASTRO] == 0:
        return 0
    g0 = g[i]
    c0 = ca[i]
    y0 = y[i]
    if (g0 * fp[F_Q] <= fp[F_GTHR] and c0 <= fp[F_CATHR] and y0 <= 0.0
            and fp[F_CATHR] >= 0.0):
        # no drive, calcium below threshold and not rising: stays below (fast path)
        c, yy = ca_advance(c0, y0, 0.0, steps, fp, tab)
        ca[i] = c
        y[i] = yy
        g[i] = g0 * powt(tab, T_QPOW, fp[F_Q], steps)
        return 0
    cnt = g_active_steps(g0, steps, fp, tab)
    state = np.zeros(2, dtype=np.int64)
    n_int = 0
    n_int = _piece_h(c0, y0, fp[F_A], cnt, 0, fp, tab, h_on, h_off, n_int, lane, state)
    c1, y1 = ca_advance(c0, y0, fp[F_A], cnt, fp, tab)
    n_int = _piece_h(c1, y1, 0.0, steps - cnt, cnt, fp, tab, h_on, h_off, n_int, lane,
                     state)
    if state[0] == 1 and n_int < h_on.shape[1]:
        h_on[lane, n_int] = state[1]
        h_off[lane, n_int] = steps
        n_int += 1
    c, yy = ca_advance(c1, y1, 0.0, steps - cnt, fp, tab)
    ca[i] = c
    y[i] = yy
    g[i] = g0 * powt(tab, T_QPOW, fp[F_Q], steps)
    return n_int


@njit(cache=True)
def interneuron_spikes(lane, n_int, h_on, h_off, fp, ip, out):
    """Spike steps of a candidate's interneuron (bias input only, reset at window start)
    given its H=1 intervals; returns the count. Uses the bias-only trajectory tables."""
    steps = ip[I_STEPS]
    ref = ip[I_REF]
    integrate = ip[I_INTEGRATE] != 0
    n_sp = 0
    o = -1             # v(t) = V[t - o]
    rest_table = True  # V = Vrest until the first spike, Vreset afterwards
    t_min = 0
    while t_min < steps:
        kf_lo = ip[I_KF_REST_LO] if rest_table else ip[I_KF_RESET_LO]
        kf_hi = ip[I_KF_REST_HI] if rest_table else ip[I_KF_RESET_HI]
        # find the first spike step >= t_min
        best = NEVER
        # segments: H=0 before the first interval, between intervals and after the last
        prev_end = 0
        for k in range(n_int + 1):
            a0 = prev_end
            b0 = h_on[lane, k] if k < n_int else steps
            if b0 > t_min and kf_hi < NEVER:        # H = 0 segment [a0, b0)
                t = max(a0, t_min, o + kf_hi)
                if t < b0:
                    best = t
                    break
            if k < n_int:
                a1 = h_on[lane, k]
                b1 = h_off[lane, k]
                if b1 > t_min and kf_lo < NEVER:    # H = 1 segment [a1, b1)
                    t = max(a1, t_min, o + kf_lo)
                    if t < b1:
                        best = t
                        break
                prev_end = b1
        if best >= steps:
            break
        out[n_sp] = best
        n_sp += 1
        rest_table = False
        if integrate:
            o = best
        else:
            o = best + ref
        t_min = best + ref + 1
    return n_sp


@njit(cache=True)
def motor_lane(lane, sp, ns, isp, n_isp, exc_w, drive, use_drive, fp, ip, tab, post_out):
    """Event-driven LIF motor neuron of one candidate (reset at window start). Excitatory
    events at the input spikes sp[:ns] (input ``exc_w`` or ``drive[t, lane]``), inhibitory
    events at its interneuron's spikes isp[:n_isp]. Returns the spike count; spike steps go
    to post_out."""
    steps = ip[I_STEPS]
    ref = ip[I_REF]
    integrate = ip[I_INTEGRATE] != 0
    v_rest = fp[F_VREST]
    alpha = fp[F_ALPHA]
    rm = fp[F_RM]
    thr = fp[F_VTHR_M]
    winh = fp[F_WINH]
    v = v_rest
    t_v = -1          # v is the potential after step t_v
    ref_end = -1      # refractory through this step
    check = NEVER     # integrate mode: spike check right after refractoriness
    n_post = 0
    a = 0
    b = 0
    while True:
        ta = sp[a] if a < ns else NEVER
        tb = isp[b] if b < n_isp else NEVER
        t = ta if ta < tb else tb
        if check < t:
            t = check
        if t >= steps:
            break
        cur = 0.0
        exc = 0.0
        if ta == t:
            exc = drive[t, lane] if use_drive else exc_w
            a += 1
        cur = exc - (winh if tb == t else 0.0)
        if tb == t:
            b += 1
        if check == t:
            check = NEVER
        if not integrate:
            if t <= ref_end:
                continue
            n = t - 1 - t_v
            v_prev = v_rest + powt(tab, T_APOW, alpha, n) * (v - v_rest)
            v = v_rest + alpha * (v_prev - v_rest) + rm * cur
            t_v = t
            if v > thr:
                post_out[n_post] = t
                n_post += 1
                v = fp[F_VRESET]
                ref_end = t + ref
                t_v = ref_end
        else:
            n = t - 1 - t_v
            v_prev = v_rest + powt(tab, T_APOW, alpha, n) * (v - v_rest)
            v = v_rest + alpha * (v_prev - v_rest) + rm * cur
            t_v = t
            if t > ref_end:
                if v > thr:
                    post_out[n_post] = t
                    n_post += 1
                    v = fp[F_VRESET]
                    ref_end = t + ref
                    check = ref_end + 1
            elif t == ref_end:
                check = t + 1
            else:
                check = ref_end + 1
    return n_post


@njit(cache=True)
def stdp_lane(sp, ns, post, n_post, fp, ip, tab):
    """Accumulated STDP change of one synapse over a window (event-driven traces)."""
    nearest = ip[I_NEAREST] != 0
    x = 0.0
    yp = 0.0
    t_last = -1
    dwk = 0.0
    a = 0
    b = 0
    while a < ns or b < n_post:
        ta = sp[a] if a < ns else NEVER
        tb = post[b] if b < n_post else NEVER
        t = ta if ta < tb else tb
        pre = ta == t
        po = tb == t
        if t_last >= 0:
            x = x * powt(tab, T_DECP, fp[F_DECP], t - t_last)
            yp = yp * powt(tab, T_DECM, fp[F_DECM], t - t_last)
        t_last = t
        if pre:
            x = 1.0 if nearest else x + 1.0
            a += 1
        if po:
            dwk += fp[F_APLUS] * x
            b += 1
        if pre:
            dwk -= fp[F_AMINUS] * yp
        if po:
            yp = 1.0 if nearest else yp + 1.0
    return dwk


@njit(cache=True)
def fast_window_core(fp, ip, tab, cell, cands, n_lanes, sp, ns, wl, drive, use_drive,
                     t_now, g, ca, y, t_cell, counts, dw, scratch_i, h_on, h_off):
    """Event-driven decision window (see module doc). ``sp[:ns]``: input spike steps;
    excitatory input per candidate ``wl[lane]`` (software weights) or, with
    ``use_drive``, ``drive[t, lane]``. ``scratch_i`` int64[3, steps+1] work space."""
    steps = ip[I_STEPS]
    astro = ip[I_ASTRO] != 0
    if astro:
        advance_idle(cell, t_now - t_cell[cell], fp, ip, tab, g, ca, y)
        for k in range(n_lanes):
            advance_idle(cands[k], t_now - t_cell[cands[k]], fp, ip, tab, g, ca, y)
    isp = scratch_i[0]
    post = scratch_i[1]
    for k in range(n_lanes):
        n_int = 0
        if astro:
            n_int = candidate_astro(cands[k], k, fp, ip, tab, g, ca, y, h_on, h_off)
        n_isp = 0
        if n_int > 0 or ip[I_KF_REST_HI] < NEVER:
            n_isp = interneuron_spikes(k, n_int, h_on, h_off, fp, ip, isp)
        n_post = motor_lane(k, sp, ns, isp, n_isp, wl[k], drive, use_drive, fp, ip, tab,
                            post)
        counts[k] = n_post
        if ip[I_STDP] != STDP_OFF:
            dw[k] = stdp_lane(sp, ns, post, n_post, fp, ip, tab)
        else:
            dw[k] = 0.0
    if astro:
        current_cell_astro(cell, sp, ns, fp, ip, tab, g, ca, y)
    t_cell[cell] = t_now + steps
    for k in range(n_lanes):
        t_cell[cands[k]] = t_now + steps


@njit(cache=True)
def fast_window(fp, ip, tab, cell, cands, n_lanes, spikes, drive, t_now,
                v_mot, ref_mot, v_int, ref_int, g, ca, y, t_cell, counts, dw):
    """Event-driven window with the same signature as :func:`full_window` (per-step
    ``drive``; must be zero at steps without an input spike). Neuron arrays are unused
    (potentials are reset every window in this reading)."""
    steps = ip[I_STEPS]
    sp = np.empty(steps, dtype=np.int64)
    ns = 0
    for t in range(steps):
        if spikes[t]:
            sp[ns] = t
            ns += 1
    scratch = np.empty((2, steps + 1), dtype=np.int64)
    h_on = np.empty((4, 64), dtype=np.int64)
    h_off = np.empty((4, 64), dtype=np.int64)
    wl = np.zeros(4)
    fast_window_core(fp, ip, tab, cell, cands, n_lanes, sp, ns, wl, drive, True, t_now,
                     g, ca, y, t_cell, counts, dw, scratch, h_on, h_off)


# ---- trial loop (software synapses) -------------------------------------------------------
@njit(cache=True)
def choose_lane(counts, n_lanes, z, stay, tied):
    """The decision rule: the lane with the most motor spikes, ties broken by the window's
    draw ``z``; -1 = no move (no lane, or every count zero with ``decision.no_spike=stay``).
    ``tied`` is scratch (int64[4])."""
    mx = -1
    for k in range(n_lanes):
        if counts[k] > mx:
            mx = counts[k]
    if n_lanes == 0 or (mx == 0 and stay):
        return -1
    n_tied = 0
    for k in range(n_lanes):
        if counts[k] == mx:
            tied[n_tied] = k
            n_tied += 1
    return tied[pick_index(z, n_tied)]


@njit(cache=True)
def clip_weight(v, lo, hi):
    """``v`` limited to [lo, hi]."""
    if v < lo:
        return lo
    if v > hi:
        return hi
    return v


@njit(cache=True)
def apply_window_stdp(w, pos, dirs, n_lanes, dw, chosen, target, kf, wmin, wmax):
    """Write one window's STDP change ``dw[k]`` (lane k = synapse ``w[pos, dirs[k]]``).

    The chosen lane gets ``kf * dw``; the others by ``target``: ``all`` their own ``dw``,
    ``chosen`` nothing, ``depress_others`` ``-|dw|``; ``normalize`` = ``all``, then the
    cell's outgoing weights are scaled back to their sum before the update (heterosynaptic
    normalisation). Every written weight is clipped to [wmin, wmax]. ``chosen = -1``: no
    lane was chosen (all lanes are "others").
    """
    before = 0.0
    for k in range(n_lanes):
        before += w[pos, dirs[k]]
    for k in range(n_lanes):
        if k == chosen:
            dk = dw[k] * kf
        elif target == TARGET_CHOSEN:
            continue
        elif target == TARGET_DEPRESS:
            dk = -abs(dw[k])
        else:
            dk = dw[k]
        w[pos, dirs[k]] = clip_weight(w[pos, dirs[k]] + dk, wmin, wmax)
    if target == TARGET_NORMALIZE and n_lanes > 0:
        after = 0.0
        for k in range(n_lanes):
            after += w[pos, dirs[k]]
        if after > 0.0:
            for k in range(n_lanes):
                w[pos, dirs[k]] = clip_weight(w[pos, dirs[k]] * before / after, wmin, wmax)


@njit(cache=True)
def run_trial_kernel(fp, ip, tab, nbr, move, start, goals, w, key,
                     path, counts_hist, v_mot, ref_mot, v_int, ref_int, g, ca, y, t_cell):
    """Run one trial with software weights ``w`` (float64 [N, 4]; receives the learned
    weights unless ``stdp.mode`` is off).

    ``nbr[i, d]``: motor-neuron cell of direction d (-1: no synapse); ``move[i, d]``: cell
    the agent lands in when it chooses d (-1 = stays: a bumping wall). ``goals``: goal
    cells, all must be visited (any order). ``path`` receives the visited cells
    (path[0] = start), ``counts_hist[step, d]`` the spike counts (-1: no candidate).
    Returns (steps, success, new key).
    """
    steps_w = ip[I_STEPS]
    max_steps = ip[I_MAXSTEPS]
    spikes = np.zeros(steps_w, dtype=np.bool_)
    sp = np.zeros(steps_w, dtype=np.int64)
    fast = ip[I_ENGINE] == ENGINE_FAST
    drive = np.zeros((steps_w if not fast else 1, 4))
    cands = np.zeros(4, dtype=np.int64)
    dirs = np.zeros(4, dtype=np.int64)
    counts = np.zeros(4, dtype=np.int64)
    dw = np.zeros(4)
    wl = np.zeros(4)
    tied = np.zeros(4, dtype=np.int64)
    scratch = np.empty((2, steps_w + 1), dtype=np.int64)
    h_on = np.empty((4, 64), dtype=np.int64)
    h_off = np.empty((4, 64), dtype=np.int64)
    n_goals = goals.shape[0]
    reached = np.zeros(n_goals, dtype=np.bool_)
    n_reached = 0
    pos = start
    path[0] = start
    t_now = 0
    stdp = ip[I_STDP]
    # the network reads w_run; STDP writes w (the same array unless stdp.mode=trial_end)
    w_run = w.copy() if stdp == STDP_TRIAL_END else w
    for step in range(max_steps):
        n_lanes = 0
        for d in range(4):
            nb = nbr[pos, d]
            if nb >= 0:
                cands[n_lanes] = nb
                dirs[n_lanes] = d
                wl[n_lanes] = w_run[pos, d]
                n_lanes += 1
        key, ns = draw_spikes(key, steps_w, ip[I_SPIKETHR], spikes, sp)
        if fast:
            fast_window_core(fp, ip, tab, pos, cands, n_lanes, sp, ns, wl, drive, False,
                             t_now, g, ca, y, t_cell, counts, dw, scratch, h_on, h_off)
        else:
            for t in range(steps_w):
                for k in range(n_lanes):
                    drive[t, k] = wl[k] if spikes[t] else 0.0
            full_window(fp, ip, tab, pos, cands, n_lanes, spikes, drive, t_now,
                        v_mot, ref_mot, v_int, ref_int, g, ca, y, t_cell, counts, dw)
        t_now += steps_w
        key, z = splitmix_next(key)
        for d in range(4):
            counts_hist[step, d] = -1
        for k in range(n_lanes):
            counts_hist[step, dirs[k]] = counts[k]
        chosen = choose_lane(counts, n_lanes, z, ip[I_STAY] != 0, tied)
        if stdp != STDP_OFF:
            apply_window_stdp(w, pos, dirs, n_lanes, dw, chosen, ip[I_TARGET], fp[F_K],
                              fp[F_WMIN], fp[F_WMAX])
        if chosen >= 0:
            dest = move[pos, dirs[chosen]]
            if dest >= 0:
                pos = dest
        path[step + 1] = pos
        for gi in range(n_goals):
            if not reached[gi] and goals[gi] == pos:
                reached[gi] = True
                n_reached += 1
        if n_reached == n_goals:
            return step + 1, True, key
    return max_steps, False, key


@njit(cache=True)
def run_batch_kernel(fp, ip, tab, nbr, move, starts, goals, w0, keys, paths, steps_out,
                     success_out, w_out):
    """Run ``len(starts)`` independent trials (fresh network each); ``w0[trial]`` are the
    initial weights, final weights go to ``w_out[trial]``."""
    n_trials = starts.shape[0]
    n_cells = nbr.shape[0]
    counts_hist = np.zeros((ip[I_MAXSTEPS], 4), dtype=np.int64)
    for tr in range(n_trials):
        v_mot = np.full(n_cells, fp[F_VREST])
        v_int = np.full(n_cells, fp[F_VREST])
        ref_mot = np.zeros(n_cells, dtype=np.int64)
        ref_int = np.zeros(n_cells, dtype=np.int64)
        g = np.zeros(n_cells)
        ca = np.zeros(n_cells)
        y = np.zeros(n_cells)
        t_cell = np.zeros(n_cells, dtype=np.int64)
        w = w0[tr].copy()
        st, ok, _k = run_trial_kernel(fp, ip, tab, nbr, move, starts[tr], goals[tr], w,
                                      keys[tr], paths[tr], counts_hist, v_mot, ref_mot,
                                      v_int, ref_int, g, ca, y, t_cell)
        steps_out[tr] = st
        success_out[tr] = ok
        w_out[tr] = w
