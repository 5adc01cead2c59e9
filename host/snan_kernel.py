"""The SNAN trial kernel (numba): one event-driven window engine and one trial loop.

Every caller runs trials here: the agent (:func:`snan_hil.host.agent.run_trial`), batches
(:func:`snan_hil.host.simulate.simulate`), the experiments (figures 3-7) and the hardware
runs (a crossbar back-end supplies the synaptic drive window by window through
:func:`begin_window` / :func:`end_window`). The plain per-step reference
(:mod:`snan_hil.host.snan_reference`) is the test oracle: the tests compare paths, spike
counts and weights with it, trial for trial.

Parameters come as one :class:`KernelParams` (built from the config by
:func:`snan_hil.host.kernel_params.kernel_params`), per-trial arrays as one
:class:`TrialState`; the entry points pass both on by reference (:class:`ParamsRef`,
:class:`StateRef`: named tuples are passed by value, ~60 values per call).

**Window engine** (:func:`window`). The same recurrences as the reference, evaluated only
where something happens:

* astrocytes are advanced in closed form between changes of their glutamate drive ``J``
  (the Euler step of the calcium model has the double eigenvalue ``lam = 1 - dt/tau``, so
  ``M^n = lam^n I + n lam^(n-1) (M - lam I)``); the steps with ``Ca > Ca_thr`` (interneuron
  threshold lowered) come as intervals: the closed form on a piece of constant ``J`` is
  unimodal, so its ends and its extremum decide and bisection finds a crossing (the piece
  is stepped with the reference recurrence only when a value next to a crossing lies within
  ``CROSS_TOL`` of the threshold, so the result is the stepped one);
* an interneuron follows its bias-only trajectory (a bit-exact table from ``v_rest`` or
  ``v_reset``, else the closed form ``v_rest + u_inf + alpha^n (v0 - v_rest - u_inf)``)
  between input events; its first threshold crossing is looked up or solved (``log``);
* a motor neuron is updated only at excitatory (input spike) and inhibitory (interneuron
  spike) events, with the exact decay ``alpha^n`` in between; pair-based STDP traces are
  updated at the same events; the candidates' motor neurons go in lock step, spike by
  spike (:func:`motor_lanes`), so their independent chains of operations overlap;
* cells nobody looks at are not touched: when a cell becomes relevant (occupied or a
  candidate) it is first brought up to date. With ``neuron.reset_each_window = true`` only
  its astrocyte matters; with ``false`` (state carried across windows) its interneuron and
  motor neuron are advanced too (bias input, calcium-gated threshold, inhibition), and the
  occupied cell's interneuron (input spikes) and motor neuron (inhibition) are followed
  through the window.

These are the reference's recurrences, so only floating-point rounding differs (~1e-12
relative); spike counts and paths equal the reference's except in threshold ties of that
size (tested on many trials and readings).

**Random stream**: the splitmix64 window stream of :mod:`snan_hil.host.rng` (same integer
arithmetic): ``steps`` draws for the input spike train, then one for the tie-break.

**Cache**: the kernels compile once per machine (``cache=True``). Numba keys a cached
kernel on its own source file only, so a cached kernel calling a function of another file
would keep that function's old code after it changes. Therefore every numba function of the
trial kernel lives in this one module and uses only names defined here (plus numpy/math); the
emulator's spike fast path (:mod:`snan_hil.firmware_emu.spike_fastpath`) is the one other
kernel module, self-contained the same way. ``tests/agent/test_kernel_cache.py`` checks both and
that an edited source is recompiled. A damaged cache entry is compiled again rather than
failing every run (:func:`snan_hil.common.numba_cache.tolerate_damaged_cache`, applied at the
end of this module).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit
from numba.core import types
from numba.experimental import structref

NEVER = 1 << 40  #: "no such step"

STDP_OFF, STDP_WINDOW, STDP_TRIAL_END = 0, 1, 2
STDP_MODES = {"off": STDP_OFF, "window": STDP_WINDOW, "trial_end": STDP_TRIAL_END}
#: ``stdp.target``: which candidate synapses a window's STDP change goes to (docs/model.md)
TARGET_ALL, TARGET_CHOSEN, TARGET_DEPRESS, TARGET_NORMALIZE = 0, 1, 2, 3
TARGET_CODES = {"all": TARGET_ALL, "chosen": TARGET_CHOSEN,
                "depress_others": TARGET_DEPRESS, "normalize": TARGET_NORMALIZE}

#: interneuron trajectory anchors: bias-only table from v_rest / v_reset, or closed form
ANCHOR_REST, ANCHOR_RESET, ANCHOR_FREE = 0, 1, 2
#: rows of the H-interval scratch: lanes 0..3, the occupied cell, a cell being caught up
ROW_OCCUPIED, ROW_CATCH_UP = 4, 5
H_ROWS, H_CAP = 6, 64

# rows of TrialState.lane_f / lane_i (per-lane state of the lock-step motor loop)
LF_V, LF_DW, LF_V0, LF_Y, LF_W, LF_CUR, LF_ROWS = 0, 1, 2, 3, 4, 5, 6
LI_N_ISP, LI_R0, LI_TV, LI_REF_END, LI_NEXT, LI_ROWS = 0, 1, 2, 3, 4, 5
ROW_SINGLE = 4  #: isp/post row of the occupied cell and of a cell being caught up

# TrialState.iv slots
IV_POS, IV_STEP, IV_REACHED, IV_T_NOW, IV_DONE, IV_SUCCESS, IV_LANES, IV_NS = range(8)
IV_CHOSEN, IV_START = 8, 9
N_IV = 10

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MUL1 = np.uint64(0xBF58476D1CE4E5B9)
_MUL2 = np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _S11, _S53 = (np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11),
                                np.uint64(53))


class KernelParams(NamedTuple):
    """Everything a trial kernel needs: the config's values, derived constants and tables
    (see :mod:`snan_hil.host.kernel_params`, whose :func:`~snan_hil.host.kernel_params.
    kernel_params` builds it from a config). Units as in the config (times in ms), table
    indices and ``steps``/``ref_steps`` in time steps."""

    # ---- time, grid, decision
    steps: int                   #: time steps per decision window
    dt_ms: float
    max_steps: int               #: decisions per trial at most
    spike_threshold: int         #: input spike iff draw53 < this (snan_hil.host.rng)
    no_spike_stay: bool          #: decision.no_spike == "stay"
    return_to_start: bool        #: after every goal, the trial ends back on the start
    # ---- neurons (Eq. 1)
    alpha: float                 #: exp(-dt / tau_m)
    v_rest: float
    v_reset: float
    v_thr_motor: float
    v_thr_inter: float
    v_thr_inter_low: float       #: v_thr_inter / (1 + eta) (astrocyte active)
    r_m: float
    i_bias: float
    u_inf_bias: float            #: r_m * i_bias / (1 - alpha): bias-only limit above v_rest
    log_alpha: float
    ref_steps: int
    integrate: bool              #: neuron.refractory == "integrate"
    reset_each_window: bool
    # ---- synapses
    w_in_inter: float
    w_inh: float
    # ---- astrocytes
    astro: bool
    alpha_n: float               #: glutamate clearance per ms
    k_n: float
    g_thr: float
    a_ca: float                  #: calcium impulse amplitude A
    tau_ca_ms: float
    ca_thr: float
    q: float                     #: 1 - alpha_n * dt (glutamate decay per step)
    lam: float                   #: 1 - dt / tau_ca (double eigenvalue of the calcium step)
    log_q: float
    log_lam: float
    # ---- STDP (Eq. 2) and where its change goes
    stdp_mode: int               #: STDP_OFF | STDP_WINDOW | STDP_TRIAL_END
    target: int                  #: TARGET_*
    nearest: bool                #: stdp.pairing == "nearest"
    a_plus: float
    a_minus: float
    dec_plus: float              #: exp(-dt / tau_plus)
    dec_minus: float
    w_min: float
    w_max: float
    k: float
    vteam: bool                  #: VTEAM device lookup instead of the additive rule
    vteam_lut: np.ndarray
    vteam_dt0_ms: float
    vteam_dtstep_ms: float
    vteam_latency_ms: float
    # ---- tables
    pow_q: np.ndarray
    pow_lam: np.ndarray
    pow_alpha: np.ndarray
    pow_dec_plus: np.ndarray
    pow_dec_minus: np.ndarray
    v_bias_rest: np.ndarray
    v_bias_reset: np.ndarray
    kf_rest_hi: int
    kf_rest_lo: int
    kf_reset_hi: int
    kf_reset_lo: int


@structref.register
class ParamsRefType(types.StructRef):
    """numba type of :class:`ParamsRef`."""

    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(typ)) for name, typ in fields)


class ParamsRef(structref.StructRefProxy):
    """:class:`KernelParams` by reference: the kernels pass one pointer between them instead
    of ~60 values (a named tuple is passed by value), so an inner call costs nanoseconds.
    Made by :func:`params_ref`; the entry points below convert on entry."""


structref.define_proxy(ParamsRef, ParamsRefType, list(KernelParams._fields))


@njit(cache=True)
def params_ref(kp):
    """:class:`ParamsRef` holding the fields of ``kp`` (a :class:`KernelParams`)."""
    return ParamsRef(*kp)


#: the arrays of a :class:`TrialState`, in order
TRIAL_FIELDS = ("iv", "key", "path", "counts_hist", "reached", "cands", "dirs", "counts",
                "tied", "dw", "upd", "wl", "wdev", "sp", "flags", "isp", "post", "lane_f",
                "lane_i", "et", "h_on", "h_off", "v_mot", "ref_mot", "v_int", "ref_int",
                "g", "ca", "y", "t_cell", "no_drive")


class TrialState(NamedTuple):
    """Arrays of one running trial (made by :func:`new_trial_state`,
    reused across trials): bookkeeping ``iv`` (``IV_*`` slots) and the window-stream ``key``; the
    path and spike counts per decision (``counts_hist[step, d]``, -1 = no candidate); the
    window's candidates (``cands``/``dirs``, their weights ``wl`` as the network sees them and
    ``wdev`` as stored), counts, STDP changes (``dw`` before, ``upd`` after the target rule and
    ``k``); the input spike steps ``sp`` (``flags``: the spike train as 0/1); scratch
    (interneuron and motor spike steps ``isp``/``post`` per lane and a row ``ROW_SINGLE``,
    per-lane state ``lane_f``/``lane_i``, H intervals); the network state per cell (motor and
    interneuron potentials and refractory steps left, glutamate ``g``, calcium ``ca`` and its
    rate ``y``, and the step ``t_cell`` each cell is up to date with); ``no_drive`` (zeros
    [1, 4]) stands for the drive array when the weights are software."""

    iv: np.ndarray
    key: np.ndarray
    path: np.ndarray
    counts_hist: np.ndarray
    reached: np.ndarray
    cands: np.ndarray
    dirs: np.ndarray
    counts: np.ndarray
    tied: np.ndarray
    dw: np.ndarray
    upd: np.ndarray
    wl: np.ndarray
    wdev: np.ndarray
    sp: np.ndarray
    flags: np.ndarray
    isp: np.ndarray
    post: np.ndarray
    lane_f: np.ndarray
    lane_i: np.ndarray
    et: np.ndarray
    h_on: np.ndarray
    h_off: np.ndarray
    v_mot: np.ndarray
    ref_mot: np.ndarray
    v_int: np.ndarray
    ref_int: np.ndarray
    g: np.ndarray
    ca: np.ndarray
    y: np.ndarray
    t_cell: np.ndarray
    no_drive: np.ndarray


assert TrialState._fields == TRIAL_FIELDS


@structref.register
class StateRefType(types.StructRef):
    """numba type of :class:`StateRef`."""

    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(typ)) for name, typ in fields)


class StateRef(structref.StructRefProxy):
    """:class:`TrialState` by reference (one pointer between kernels; see :class:`ParamsRef`).
    Made by :func:`state_ref`: it holds the same arrays, so both see every change."""


structref.define_proxy(StateRef, StateRefType, list(TrialState._fields))


@njit(cache=True)
def state_ref(ts):
    """:class:`StateRef` holding the arrays of ``ts`` (a :class:`TrialState`)."""
    return StateRef(*ts)


# =========================================================================================
# random stream (same integer arithmetic as snan_hil.host.rng)
@njit(cache=True, inline="always")
def splitmix_next(state):
    state = state + _GOLDEN
    z = state
    z = (z ^ (z >> _S30)) * _MUL1
    z = (z ^ (z >> _S27)) * _MUL2
    return state, z ^ (z >> _S31)


@njit(cache=True)
def draw_spikes(key, steps, thr, sp, flags):
    """The window's input spike train from stream state ``key``: ``flags[t]`` = 1 at a spike,
    ``sp[:ns]`` the spike steps. Returns (new key, ns). The draws are independent
    (``z_t = mix(key + (t+1) * golden)``), so the first loop vectorises."""
    uthr = np.uint64(thr)
    for t in range(steps):
        z = key + np.uint64(t + 1) * _GOLDEN
        z = (z ^ (z >> _S30)) * _MUL1
        z = (z ^ (z >> _S27)) * _MUL2
        z = z ^ (z >> _S31)
        flags[t] = (z >> _S11) < uthr
    ns = 0
    for t in range(steps):
        sp[ns] = t
        ns += flags[t]
    return key + np.uint64(steps) * _GOLDEN, ns


@njit(cache=True, inline="always")
def pick_index(z, n):
    return np.int64(((z >> _S11) * np.uint64(n)) >> _S53)


@njit(cache=True, inline="always")
def powt(table, base, n):
    """``base**n`` from ``table`` (``table[k] = base**k``) when n is small, else by pow()."""
    if n < table.shape[0]:
        return table[n]
    return base ** n


# =========================================================================================
# astrocytes
@njit(cache=True)
def astro_step(p, i, s_in, g, ca, y):
    """One Euler step of glutamate and calcium of astrocyte ``i`` (reference order)."""
    dt = p.dt_ms
    tau = p.tau_ca_ms
    gi = g[i]
    gi = gi + dt * (-p.alpha_n * gi + p.k_n * s_in)
    g[i] = gi
    jn = p.a_ca if gi > p.g_thr else 0.0
    c = ca[i]
    yy = y[i]
    ca[i] = c + dt * yy
    y[i] = yy + dt * (jn - 2.0 * tau * yy - c) / (tau * tau)


@njit(cache=True)
def ca_advance(p, c0, y0, jn, n):
    """(Ca, y) after n Euler steps with constant drive jn (closed form)."""
    if n <= 0:
        return c0, y0
    dt = p.dt_ms
    tau = p.tau_ca_ms
    lam = p.lam
    e0 = c0 - jn
    ln = powt(p.pow_lam, lam, n)
    ln1 = powt(p.pow_lam, lam, n - 1)
    r = dt / tau
    e = ln * e0 + n * ln1 * (r * e0 + dt * y0)
    yy = ln * y0 + n * ln1 * (-(r / tau) * e0 - r * y0)
    return jn + e, yy


@njit(cache=True)
def g_active_steps(p, g0, n):
    """Number of the n idle steps (leading ones) in which G = g0*q^m stays above G_thr."""
    thr = p.g_thr
    q = p.q
    if n <= 0 or g0 * q <= thr:
        return 0
    if g0 * powt(p.pow_q, q, n) > thr:
        return n
    cnt = int(math.floor(math.log(thr / g0) / p.log_q))
    if cnt < 0:
        cnt = 0
    if cnt > n:
        cnt = n
    while cnt < n and g0 * powt(p.pow_q, q, cnt + 1) > thr:
        cnt += 1
    while cnt > 0 and g0 * powt(p.pow_q, q, cnt) <= thr:
        cnt -= 1
    return cnt


@njit(cache=True)
def advance_idle(p, i, n, g, ca, y):
    """Advance astrocyte ``i`` by n steps without input."""
    if n <= 0 or not p.astro:
        return
    g0 = g[i]
    if g0 == 0.0 and ca[i] == 0.0 and y[i] == 0.0:
        return                      # at rest: stays there
    cnt = g_active_steps(p, g0, n)
    c, yy = ca_advance(p, ca[i], y[i], p.a_ca, cnt)
    c, yy = ca_advance(p, c, yy, 0.0, n - cnt)
    ca[i] = c
    y[i] = yy
    g[i] = g0 * powt(p.pow_q, p.q, n)


@njit(cache=True, inline="always")
def astro_quiet(p, i, g, ca, y):
    """True if astrocyte ``i`` left alone keeps Ca <= Ca_thr for ever: no drive from the next
    step on, calcium at or below its threshold and not rising (critically damped decay)."""
    return (g[i] * p.q <= p.g_thr and ca[i] <= p.ca_thr and y[i] <= 0.0
            and p.ca_thr >= 0.0)


@njit(cache=True)
def _ca_value(p, c0, y0, jn, m):
    c, _ = ca_advance(p, c0, y0, jn, m)
    return c


@njit(cache=True)
def _h_emit(hv, t, h_on, h_off, row, n_int, state):
    """H is ``hv`` from step t on: open or close an interval of ``row``."""
    if hv and state[0] == 0:
        state[0] = 1
        state[1] = t
    elif not hv and state[0] == 1:
        if n_int < h_on.shape[1]:
            h_on[row, n_int] = state[1]
            h_off[row, n_int] = t
            n_int += 1
        state[0] = 0
    return n_int


#: a calcium value this close to Ca_thr (relative to the piece's scale) may fall on either
#: side when stepped: the crossing search then steps (the stepping error is < 2e-13 of the
#: scale, measured over pieces of up to 60,000 steps)
CROSS_TOL = 1e-9


@njit(cache=True)
def _piece_crossings(p, c0, y0, jn, length, mf, h_on, h_off, row, n_int, state, t_first):
    """H of a piece with a threshold crossing, from the closed form: the piece is monotone
    on [1, mf] and [mf + 1, length] (``mf`` < 1: on all of it), so bisection finds each
    change. Returns -1 (nothing written) if a value next to a change or at an end is within
    ``CROSS_TOL`` of the threshold: the caller steps the piece."""
    thr = p.ca_thr
    tol = CROSS_TOL * (abs(c0) + abs(jn) + abs(y0) * p.tau_ca_ms + abs(thr) + 1.0)
    pts = np.empty(4, dtype=np.int64)
    n_pts = 0
    pts[n_pts] = 1
    n_pts += 1
    for mm in (mf, mf + 1, length):
        if mm > pts[n_pts - 1] and mm <= length:
            pts[n_pts] = mm
            n_pts += 1
    hv = np.empty(4, dtype=np.bool_)
    for i in range(n_pts):
        v = _ca_value(p, c0, y0, jn, pts[i])
        if abs(v - thr) <= tol:
            return -1
        hv[i] = v > thr
    changes = np.empty(3, dtype=np.int64)
    n_ch = 0
    for i in range(n_pts - 1):
        if hv[i] != hv[i + 1]:
            lo = pts[i]
            hi = pts[i + 1]
            want = hv[i + 1]
            while hi - lo > 1:
                mid = (lo + hi) // 2
                if (_ca_value(p, c0, y0, jn, mid) > thr) == want:
                    hi = mid
                else:
                    lo = mid
            if (abs(_ca_value(p, c0, y0, jn, hi) - thr) <= tol
                    or abs(_ca_value(p, c0, y0, jn, hi - 1) - thr) <= tol):
                return -1
            changes[n_ch] = hi
            n_ch += 1
    n_int = _h_emit(hv[0], t_first, h_on, h_off, row, n_int, state)
    h = hv[0]
    for i in range(n_ch):
        h = not h
        n_int = _h_emit(h, t_first + changes[i] - 1, h_on, h_off, row, n_int, state)
    return n_int


@njit(cache=True)
def _piece_h(p, c0, y0, jn, length, t_first, h_on, h_off, row, n_int, state):
    """Append to ``row``'s H=1 intervals the steps t_first .. t_first+length-1 of a piece
    with constant drive jn starting from (c0, y0). ``state`` = [H of the previous step,
    start of the open interval]. Returns the new interval count."""
    if length <= 0:
        return n_int
    thr = p.ca_thr
    lam = p.lam
    if lam > 0.0:
        # unimodal (a + b m) lam^m: the ends and the extremum decide
        v1 = _ca_value(p, c0, y0, jn, 1)
        v2 = _ca_value(p, c0, y0, jn, length)
        above = v1 > thr
        mf = -1
        dt = p.dt_ms
        e0 = c0 - jn
        d0 = (dt / p.tau_ca_ms) * e0 + dt * y0
        b = d0 / lam
        if b != 0.0:
            m_ext = -1.0 / p.log_lam - e0 / b
            if 1.0 < m_ext < length:
                mf = int(math.floor(m_ext))
        same = (v2 > thr) == above
        if same and mf >= 1:
            for mm in (mf, mf + 1):
                if mm >= 1 and mm <= length:
                    if (_ca_value(p, c0, y0, jn, mm) > thr) != above:
                        same = False
        if same:
            return _h_emit(above, t_first, h_on, h_off, row, n_int, state)
        found = _piece_crossings(p, c0, y0, jn, length, mf, h_on, h_off, row, n_int, state,
                                 t_first)
        if found >= 0:
            return found
    # step the piece (reference recurrence, constant J)
    dt = p.dt_ms
    tau = p.tau_ca_ms
    c = c0
    yy = y0
    for m in range(length):
        c_new = c + dt * yy
        yy = yy + dt * (jn - 2.0 * tau * yy - c) / (tau * tau)
        c = c_new
        n_int = _h_emit(c > thr, t_first + m, h_on, h_off, row, n_int, state)
    return n_int


@njit(cache=True)
def idle_astro(p, i, n, g, ca, y, h_on, h_off, row):
    """Astrocyte ``i`` without input over n steps: fill ``row``'s H=1 intervals
    [h_on, h_off) (steps 0..n-1 of the span), advance its state. Returns the number of
    intervals."""
    if not p.astro:
        return 0
    g0 = g[i]
    c0 = ca[i]
    y0 = y[i]
    if astro_quiet(p, i, g, ca, y):
        # no drive, calcium below threshold and not rising: stays below (fast path)
        c, yy = ca_advance(p, c0, y0, 0.0, n)
        ca[i] = c
        y[i] = yy
        g[i] = g0 * powt(p.pow_q, p.q, n)
        return 0
    cnt = g_active_steps(p, g0, n)
    state = np.zeros(2, dtype=np.int64)
    n_int = 0
    n_int = _piece_h(p, c0, y0, p.a_ca, cnt, 0, h_on, h_off, row, n_int, state)
    c1, y1 = ca_advance(p, c0, y0, p.a_ca, cnt)
    n_int = _piece_h(p, c1, y1, 0.0, n - cnt, cnt, h_on, h_off, row, n_int, state)
    if state[0] == 1 and n_int < h_on.shape[1]:
        h_on[row, n_int] = state[1]
        h_off[row, n_int] = n
        n_int += 1
    c, yy = ca_advance(p, c1, y1, 0.0, n - cnt)
    ca[i] = c
    y[i] = yy
    g[i] = g0 * powt(p.pow_q, p.q, n)
    return n_int


@njit(cache=True, inline="always")
def _glutamate_spike(gi, dt, alpha_n, kn):
    """G after a step with an input spike from G = ``gi`` before it (reference order;
    ``dt = 1`` skips an exact multiplication)."""
    if dt == 1.0:
        return gi + (-alpha_n * gi + kn)
    return gi + dt * (-alpha_n * gi + kn)


@njit(cache=True)
def _glutamate_spikes(p, gi, sp, k0, ns, prev):
    """G after the window's last step, from G = ``gi`` after step ``prev`` and the input
    spikes ``sp[k0:ns]`` (the reference's step at each spike, decay in between)."""
    for k in range(k0, ns):
        s = sp[k]
        gi = _glutamate_spike(gi * powt(p.pow_q, p.q, s - prev - 1), p.dt_ms, p.alpha_n,
                              p.k_n * 1.0)
        prev = s
    return gi * powt(p.pow_q, p.q, p.steps - prev - 1)


@njit(cache=True)
def occupied_astro(p, i, sp, ns, g, ca, y, want_h, h_on, h_off, row, defer):
    """Astrocyte of the occupied cell over one window with input spikes at steps sp[:ns].

    G is followed spike by spike; Ca/y are advanced in closed form only where J changes.
    With ``want_h`` the H=1 intervals go to ``row``. Once G stays above G_thr to the end, J
    is known and only G's own chain is left: with ``defer`` that chain (spikes from index
    k0 on, G = g0 after step ``prev``) is left to the caller and ``g[i]`` is not written.
    Returns (number of H intervals, k0 or -1 if nothing is deferred, prev, g0)."""
    steps = p.steps
    a_amp = p.a_ca
    dt = p.dt_ms
    gi = g[i]
    c = ca[i]
    yy = y[i]
    j_run = 0.0   # drive of the pending run of steps
    n_run = 0     # its length
    t_run = 0     # its first step
    state = np.zeros(2, dtype=np.int64)
    n_h = 0
    prev = -1
    k_defer = -1
    prev_defer = -1
    for k in range(ns + 1):
        if (j_run == a_amp or n_run == 0) and (gi * powt(p.pow_q, p.q, steps - 1 - prev)
                                               > p.g_thr * (1.0 + 1e-9)):
            # G stays above G_thr to the end even without input (a spike only adds to
            # it): J = A from here on, so only G itself is left to follow
            if j_run != a_amp:          # nothing pending yet: one run with J = A
                j_run = a_amp
            n_run += steps - 1 - prev
            if defer:
                k_defer = k
                prev_defer = prev
            else:
                gi = _glutamate_spikes(p, gi, sp, k, ns, prev)
            break
        s = sp[k] if k < ns else steps
        gap = s - prev - 1
        if gap > 0:
            cnt = g_active_steps(p, gi, gap)
            if cnt > 0:
                if j_run != a_amp:
                    if want_h:
                        n_h = _piece_h(p, c, yy, j_run, n_run, t_run, h_on, h_off, row, n_h,
                                       state)
                    c, yy = ca_advance(p, c, yy, j_run, n_run)
                    t_run += n_run
                    j_run = a_amp
                    n_run = 0
                n_run += cnt
            if gap - cnt > 0:
                if j_run != 0.0:
                    if want_h:
                        n_h = _piece_h(p, c, yy, j_run, n_run, t_run, h_on, h_off, row, n_h,
                                       state)
                    c, yy = ca_advance(p, c, yy, j_run, n_run)
                    t_run += n_run
                    j_run = 0.0
                    n_run = 0
                n_run += gap - cnt
            gi = gi * powt(p.pow_q, p.q, gap)
        if k < ns:
            gi = gi + dt * (-p.alpha_n * gi + p.k_n * 1.0)
            jn = a_amp if gi > p.g_thr else 0.0
            if jn != j_run:
                if want_h:
                    n_h = _piece_h(p, c, yy, j_run, n_run, t_run, h_on, h_off, row, n_h, state)
                c, yy = ca_advance(p, c, yy, j_run, n_run)
                t_run += n_run
                j_run = jn
                n_run = 0
            n_run += 1
        prev = s
    if want_h:
        n_h = _piece_h(p, c, yy, j_run, n_run, t_run, h_on, h_off, row, n_h, state)
        if state[0] == 1 and n_h < h_on.shape[1]:
            h_on[row, n_h] = state[1]
            h_off[row, n_h] = steps
            n_h += 1
    c, yy = ca_advance(p, c, yy, j_run, n_run)
    if k_defer < 0:
        g[i] = gi
    ca[i] = c
    y[i] = yy
    return n_h, k_defer, prev_defer, gi


# =========================================================================================
# interneurons: bias input, calcium-gated threshold, optional input events
@njit(cache=True)
def bias_value(p, kind, a_t, v_a, s):
    """Interneuron potential at step ``s`` on bias input alone since its anchor: value
    ``v_a`` at step ``a_t`` (held before), then the table (kinds REST/RESET) or the closed
    form (FREE)."""
    m = s - a_t
    if m <= 0:
        return v_a
    if kind == ANCHOR_FREE:
        return (p.v_rest + p.u_inf_bias
                + powt(p.pow_alpha, p.alpha, m) * (v_a - p.v_rest - p.u_inf_bias))
    tab = p.v_bias_rest if kind == ANCHOR_REST else p.v_bias_reset
    if m < tab.shape[0]:
        return tab[m]
    return tab[tab.shape[0] - 1]


@njit(cache=True)
def first_above(p, a_t, v_a, thr, lo, hi):
    """First step in [lo, hi) (lo > a_t) at which the bias-only trajectory from potential
    ``v_a`` after step ``a_t`` (closed form) is above ``thr``, or NEVER."""
    if lo >= hi:
        return NEVER
    d = (v_a - p.v_rest) - p.u_inf_bias
    if d >= 0.0:
        # falling towards v_rest + u_inf: above thr only at the beginning
        return lo if bias_value(p, ANCHOR_FREE, a_t, v_a, lo) > thr else NEVER
    thr_u = thr - p.v_rest
    if p.u_inf_bias <= thr_u:
        return NEVER
    # rising: smallest m with u_inf + alpha^m d > thr_u, i.e. alpha^m < r
    r = (thr_u - p.u_inf_bias) / d
    m_lo = lo - a_t
    if r >= 1.0:
        m = m_lo
    else:
        m = int(math.floor(math.log(r) / p.log_alpha)) + 1
        if m < m_lo:
            m = m_lo
    while m > m_lo and bias_value(p, ANCHOR_FREE, a_t, v_a, a_t + m - 1) > thr:
        m -= 1
    while bias_value(p, ANCHOR_FREE, a_t, v_a, a_t + m) <= thr:
        m += 1
        if a_t + m >= hi:
            return NEVER
    s = a_t + m
    return s if s < hi else NEVER


@njit(cache=True)
def drift_spike(p, a_t, v_a, lo, hi, h_on, h_off, row, n_h):
    """First step in [lo, hi) at which the bias-only trajectory from potential ``v_a`` after
    step ``a_t`` (closed form) exceeds the threshold of that step (lowered inside the H=1
    intervals of ``row``), or NEVER. (Table trajectories use the known first steps above
    the thresholds instead: :func:`inter_run`.)"""
    if n_h == 0:
        return first_above(p, a_t, v_a, p.v_thr_inter, lo, hi)
    prev_end = 0
    for k in range(n_h + 1):
        b0 = h_on[row, k] if k < n_h else hi
        s0 = max(prev_end, lo)
        s1 = min(b0, hi)
        if s0 < s1:
            t = first_above(p, a_t, v_a, p.v_thr_inter, s0, s1)
            if t < NEVER:
                return t
        if k < n_h:
            s0 = max(h_on[row, k], lo)
            s1 = min(h_off[row, k], hi)
            if s0 < s1:
                t = first_above(p, a_t, v_a, p.v_thr_inter_low, s0, s1)
                if t < NEVER:
                    return t
            prev_end = h_off[row, k]
        if prev_end >= hi:
            break
    return NEVER


@njit(cache=True)
def inter_threshold_at(p, t, h_on, h_off, row, n_h):
    for k in range(n_h):
        if h_on[row, k] <= t < h_off[row, k]:
            return p.v_thr_inter_low
    return p.v_thr_inter


@njit(cache=True)
def inter_run(p, v0, r0, n, ev, nev, amount, h_on, h_off, row, n_h, out):
    """An interneuron over steps 0..n-1 of a span: potential ``v0`` and ``r0`` refractory
    steps left at its start, bias input every step, input ``amount`` at the steps
    ``ev[:nev]`` (sorted), threshold lowered inside ``row``'s H=1 intervals. Writes the
    spike steps to ``out``; returns (spikes, potential after step n-1, refractory steps
    left). Same step rule as ``reference.lif_step``."""
    rs = p.ref_steps
    integ = p.integrate
    if r0 > 0 and not integ:
        a_t = r0 - 1                      # clamped: held through the refractory steps
    else:
        a_t = -1
    if v0 == p.v_rest:
        kind = ANCHOR_REST
    elif v0 == p.v_reset:
        kind = ANCHOR_RESET
    else:
        kind = ANCHOR_FREE
    v_a = v0
    ref_end = r0 - 1
    t_allow = r0 if r0 > 0 else 0
    n_spk = 0
    e = 0
    hk = 0                             # first H interval not yet behind
    cur = amount + p.i_bias
    while True:
        te = ev[e] if e < nev else n
        if te > n:
            te = n
        if te < n and not integ and te <= ref_end:
            e += 1                         # clamped: input ignored while refractory
            continue
        lo = t_allow if t_allow > a_t + 1 else a_t + 1
        ts = NEVER
        if lo < te:      # a spike on the bias alone before the next input?
            if kind == ANCHOR_FREE:
                ts = drift_spike(p, a_t, v_a, lo, te, h_on, h_off, row, n_h)
            else:
                # a table trajectory: the first step above each threshold is known; walk
                # the threshold segments from the H interval cursor hk (lo only grows)
                while True:
                    while hk < n_h and h_off[row, hk] <= lo:
                        hk += 1
                    low = hk < n_h and h_on[row, hk] <= lo
                    if low:
                        seg_end = h_off[row, hk]
                        kf = p.kf_rest_lo if kind == ANCHOR_REST else p.kf_reset_lo
                    else:
                        seg_end = h_on[row, hk] if hk < n_h else NEVER
                        kf = p.kf_rest_hi if kind == ANCHOR_REST else p.kf_reset_hi
                    end = seg_end if seg_end < te else te
                    if kf < NEVER:
                        t = a_t + kf
                        if t < lo:
                            t = lo
                        if t < end:
                            ts = t
                            break
                    if seg_end >= te:
                        break
                    lo = seg_end
        if ts >= te:
            if te >= n:
                break
            v_prev = bias_value(p, kind, a_t, v_a, te - 1)
            v = p.v_rest + p.alpha * (v_prev - p.v_rest) + p.r_m * cur
            e += 1
            if te < t_allow or v <= inter_threshold_at(p, te, h_on, h_off, row, n_h):
                kind = ANCHOR_FREE
                v_a = v
                a_t = te
                continue
            ts = te
        out[n_spk] = ts                    # a spike at ts: reset, refractory
        n_spk += 1
        kind = ANCHOR_RESET
        v_a = p.v_reset
        a_t = ts if integ else ts + rs
        ref_end = ts + rs
        t_allow = ts + rs + 1
    v_end = bias_value(p, kind, a_t, v_a, n - 1)
    r_end = ref_end - (n - 1) if ref_end > n - 1 else 0
    return n_spk, v_end, r_end


# =========================================================================================
# motor neurons and plasticity
@njit(cache=True)
def motor_lane(p, lane, et, ne, w_exc, drive, use_drive, isp, n_isp, v0, r0, n, post_out):
    """A motor neuron over steps 0..n-1: potential ``v0`` and ``r0`` refractory steps left
    at the start; excitatory events at ``et[:ne]`` (input ``w_exc``, or ``drive[t, lane]``
    with ``use_drive``), inhibitory events at its interneuron's spikes ``isp[:n_isp]``.
    Spike steps go to ``post_out``; any refractoriness reading, excitation at any steps (the
    lock-step :func:`motor_lanes` is the fast path of the common case). Returns (spikes,
    potential after step n-1, refractory steps left)."""
    rs = p.ref_steps
    integ = p.integrate
    v_rest = p.v_rest
    alpha = p.alpha
    rm = p.r_m
    thr = p.v_thr_motor
    winh = p.w_inh
    v = v0
    t_v = -1          # v is the potential after step t_v
    ref_end = r0 - 1  # refractory through this step
    if r0 > 0 and not integ:
        t_v = ref_end
    # integrate mode: spike check right after refractoriness (or at once: a carried
    # potential above threshold)
    check = NEVER
    if integ and (r0 > 0 or v0 > thr):
        check = r0
    n_post = 0
    a = 0
    b = 0
    while True:
        ta = et[a] if a < ne else NEVER
        tb = isp[b] if b < n_isp else NEVER
        t = ta if ta < tb else tb
        if check < t:
            t = check
        if t >= n:
            break
        pre = ta == t
        exc = 0.0
        if pre:
            exc = drive[t, lane] if use_drive else w_exc
            a += 1
        cur = exc - (winh if tb == t else 0.0)
        if tb == t:
            b += 1
        if check == t:
            check = NEVER
        spiked = False
        if not integ:
            if t > ref_end:
                m = t - 1 - t_v
                v_prev = v_rest + powt(p.pow_alpha, alpha, m) * (v - v_rest)
                v = v_rest + alpha * (v_prev - v_rest) + rm * cur
                t_v = t
                if v > thr:
                    spiked = True
                    v = p.v_reset
                    ref_end = t + rs
                    t_v = ref_end
        else:
            m = t - 1 - t_v
            v_prev = v_rest + powt(p.pow_alpha, alpha, m) * (v - v_rest)
            v = v_rest + alpha * (v_prev - v_rest) + rm * cur
            t_v = t
            if t > ref_end:
                if v > thr:
                    spiked = True
                    v = p.v_reset
                    ref_end = t + rs
                    check = ref_end + 1
            elif t == ref_end:
                check = t + 1
            else:
                check = ref_end + 1
        if spiked:
            post_out[n_post] = t
            n_post += 1
    if (not integ and ref_end >= n - 1) or t_v >= n - 1:
        v_end = v
    else:
        v_end = v_rest + powt(p.pow_alpha, alpha, n - 1 - t_v) * (v - v_rest)
    r_end = ref_end - (n - 1) if ref_end > n - 1 else 0
    return n_post, v_end, r_end


@njit(cache=True, inline="always")
def _motor_event(v, t_v, t, cur, apow, alpha, v_rest, rm):
    """Potential after step ``t`` of a motor neuron last updated after step ``t_v`` (exact
    decay ``apow[m] = alpha**m`` in between), input ``cur`` at step t; the arithmetic of
    ``reference.lif_step``."""
    m = t - 1 - t_v
    a = apow[m] if m < apow.shape[0] else alpha ** m
    if v_rest == 0.0:
        # the same operations without the exact zero terms (equal values)
        return alpha * (a * v) + rm * cur
    v_prev = v_rest + a * (v - v_rest)
    return v_rest + alpha * (v_prev - v_rest) + rm * cur


@njit(cache=True)
def _lanes_inhibit(t, n_lanes, isp, n_isp, nxt, v, t_v, ref_end, cur, winh, apow, alpha,
                   v_rest, rm):
    """The lanes' inhibitory events before step t (no spike possible: potential only), and
    those at step t added to the input ``cur``. Returns the next inhibitory event's step."""
    next_inh = NEVER
    for k in range(n_lanes):
        b = nxt[k]
        while b < n_isp[k] and isp[k, b] < t:
            ti = isp[k, b]
            b += 1
            if ti > ref_end[k]:
                v[k] = _motor_event(v[k], t_v[k], ti, 0.0 - winh, apow, alpha, v_rest, rm)
                t_v[k] = ti
        if b < n_isp[k] and isp[k, b] == t:
            cur[k] = cur[k] - winh
            b += 1
        else:
            cur[k] = cur[k] - 0.0
        nxt[k] = b
        if b < n_isp[k] and isp[k, b] < next_inh:
            next_inh = isp[k, b]
    return next_inh


@njit(cache=True)
def motor_lanes(p, ts, n_lanes, ns, drive, use_drive, fuse, keep_post, g_from, g_prev, gi):
    """The candidates' motor neurons in lock step (clamped refractoriness, excitation at the
    input spikes ``ts.sp[:ns]``: ``ts.wl[k]`` or ``drive[t, k]``): the same updates as
    :func:`motor_lane`, but spike by spike for all lanes at once, so their independent
    chains of floating-point operations overlap (~3x faster than lane after lane).
    Inhibitory events: ``ts.isp[k, :ts.lane_i[LI_N_ISP, k]]``; start state
    ``ts.lane_f[LF_V0]``/``ts.lane_i[LI_R0]``.
    Writes ``ts.counts``, the end state (``LF_V``, ``LI_R0``), with ``fuse`` the STDP
    change (``LF_DW``; the traces as :func:`stdp_lane` keeps them) and with ``keep_post``
    the spike steps (``ts.post[k]``). On the way it follows the occupied cell's glutamate
    from spike index ``g_from`` on (G = ``gi`` after step ``g_prev``; see
    :func:`occupied_astro`), a chain that overlaps with the lanes' for free; returns G after
    the last spike and that spike's step."""
    n = p.steps
    sp = ts.sp
    pow_plus = p.pow_dec_plus
    pow_minus = p.pow_dec_minus
    dec_plus = p.dec_plus
    dec_minus = p.dec_minus
    post = ts.post
    isp = ts.isp
    counts = ts.counts
    lf = ts.lane_f
    li = ts.lane_i
    apow = p.pow_alpha
    alpha = p.alpha
    v_rest = p.v_rest
    rm = p.r_m
    thr = p.v_thr_motor
    v_reset = p.v_reset
    rs = p.ref_steps
    a_plus = p.a_plus
    a_minus = p.a_minus
    nearest = p.nearest
    winh = p.w_inh
    zero_rest = v_rest == 0.0
    qpow = p.pow_q
    q = p.q
    dt = p.dt_ms
    g_a = p.alpha_n
    g_kn = p.k_n * 1.0
    v = lf[LF_V]               # potential after step t_v
    y = lf[LF_Y]               # post-synaptic STDP trace
    dw = lf[LF_DW]
    w = lf[LF_W]
    cur = lf[LF_CUR]
    t_v = li[LI_TV]
    ref_end = li[LI_REF_END]
    nxt = li[LI_NEXT]
    n_isp = li[LI_N_ISP]
    next_inh = NEVER
    x = 0.0
    dmj = 1.0
    for k in range(n_lanes):
        v[k] = lf[LF_V0, k]
        y[k] = 0.0
        dw[k] = 0.0
        r0 = li[LI_R0, k]
        ref_end[k] = r0 - 1
        t_v[k] = r0 - 1 if r0 > 0 else -1
        nxt[k] = 0
        w[k] = ts.wl[k]
        cur[k] = w[k]
        counts[k] = 0
        if n_isp[k] > 0 and isp[k, 0] < next_inh:
            next_inh = isp[k, 0]
    for j in range(ns):
        t = sp[j]
        if use_drive:
            for k in range(n_lanes):
                cur[k] = drive[t, k]
        inhibited = t >= next_inh
        if inhibited:
            next_inh = _lanes_inhibit(t, n_lanes, isp, n_isp, nxt, v, t_v, ref_end, cur, winh,
                                      apow, alpha, v_rest, rm)
        if fuse:
            # the pre-synaptic trace (shared by the lanes) and the post traces' decay
            # since the previous input spike (as stdp_lane: decay, then the spike)
            if j > 0:
                gap = t - sp[j - 1]
                x = x * powt(pow_plus, dec_plus, gap)
                dmj = powt(pow_minus, dec_minus, gap)
            else:
                dmj = 1.0
            x = 1.0 if nearest else x + 1.0
        if j >= g_from:          # the occupied cell's glutamate
            gi = _glutamate_spike(gi * powt(qpow, q, t - g_prev - 1), dt, g_a, g_kn)
            g_prev = t
        for k in range(n_lanes):
            spiked = False
            if t > ref_end[k]:
                m = t - 1 - t_v[k]
                if zero_rest:   # m < steps + 2: inside the table
                    vk = alpha * (apow[m] * v[k]) + rm * cur[k]
                else:
                    vk = v_rest + alpha * ((v_rest + apow[m] * (v[k] - v_rest)) - v_rest) \
                        + rm * cur[k]
                t_v[k] = t
                if vk > thr:
                    spiked = True
                    vk = v_reset
                    ref_end[k] = t + rs
                    t_v[k] = t + rs
                    if keep_post:
                        post[k, counts[k]] = t
                    counts[k] += 1
                v[k] = vk
            if fuse:
                yk = y[k] * dmj
                dk = dw[k]
                if spiked:
                    dk += a_plus * x
                dk -= a_minus * yk
                if spiked:
                    yk = 1.0 if nearest else yk + 1.0
                y[k] = yk
                dw[k] = dk
        if inhibited and not use_drive:
            for k in range(n_lanes):
                cur[k] = w[k]
    for k in range(n_lanes):
        # inhibitory events after the last input spike, then the state after step n-1
        vk = v[k]
        tk = t_v[k]
        for b in range(nxt[k], n_isp[k]):
            ti = isp[k, b]
            if ti > ref_end[k]:
                vk = _motor_event(vk, tk, ti, 0.0 - winh, apow, alpha, v_rest, rm)
                tk = ti
        if ref_end[k] < n - 1 and tk < n - 1:
            vk = v_rest + powt(apow, alpha, n - 1 - tk) * (vk - v_rest)
        v[k] = vk
        li[LI_R0, k] = ref_end[k] - (n - 1) if ref_end[k] > n - 1 else 0
    return gi, g_prev


@njit(cache=True)
def stdp_lane(p, sp, ns, post, n_post):
    """Accumulated pair-based STDP change of one synapse over a window (event-driven
    traces; any spike times)."""
    nearest = p.nearest
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
            x = x * powt(p.pow_dec_plus, p.dec_plus, t - t_last)
            yp = yp * powt(p.pow_dec_minus, p.dec_minus, t - t_last)
        t_last = t
        if pre:
            x = 1.0 if nearest else x + 1.0
            a += 1
        if po:
            dwk += p.a_plus * x
            b += 1
        if pre:
            dwk -= p.a_minus * yp
        if po:
            yp = 1.0 if nearest else yp + 1.0
    return dwk


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
def vteam_lane(p, sp, ns, post, n_post, w0):
    """Window change of one synapse (device state ``w0``) from its pre (``sp[:ns]``) and
    post (``post[:n_post]``) spike steps under the VTEAM lookup. A pair's delay is
    ``(t_post - t_pre)*dt + latency`` ms (a motor spike caused by an input spike of the same
    step comes ``latency`` after it). All pairs within the lookup's range (``nearest``: each
    post spike with the latest pre spike at or before it, each pre spike with the latest
    post spike before it)."""
    lut = p.vteam_lut
    dt = p.dt_ms
    lat = p.vteam_latency_ms
    dt0 = p.vteam_dt0_ms
    dts = p.vteam_dtstep_ms
    span = -dt0 + lat
    dwk = 0.0
    if p.nearest:
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


# =========================================================================================
# one decision window
@njit(cache=True)
def catch_up(p, ts, i, gap):
    """Bring cell ``i`` (idle: no input, not a candidate) ``gap`` steps forward: its
    astrocyte, and with state carried across windows its interneuron (bias input) and motor
    neuron (inhibition only)."""
    if gap <= 0:
        return
    if p.reset_each_window:
        advance_idle(p, i, gap, ts.g, ts.ca, ts.y)
        return
    steps = p.steps
    # a span may hold at most steps+1 interneuron spikes (the scratch size)
    long_span = steps * (p.ref_steps + 1)
    fires_alone = p.v_rest + p.u_inf_bias > p.v_thr_inter
    rem = gap
    while rem > 0:
        quiet = (not p.astro) or astro_quiet(p, i, ts.g, ts.ca, ts.y)
        span = rem
        if quiet:
            if fires_alone and span > long_span:
                span = long_span
            advance_idle(p, i, span, ts.g, ts.ca, ts.y)
            n_h = 0
        else:
            if span > long_span:
                span = long_span
            n_h = idle_astro(p, i, span, ts.g, ts.ca, ts.y, ts.h_on, ts.h_off, ROW_CATCH_UP)
        isp = ts.isp[ROW_SINGLE]
        n_isp, vi, ri = inter_run(p, ts.v_int[i], ts.ref_int[i], span, ts.sp, 0, 0.0,
                                  ts.h_on, ts.h_off, ROW_CATCH_UP, n_h, isp)
        _np, vm, rmo = motor_lane(p, 0, ts.sp, 0, 0.0, ts.no_drive, False, isp, n_isp,
                                  ts.v_mot[i], ts.ref_mot[i], span, ts.post[ROW_SINGLE])
        ts.v_int[i] = vi
        ts.ref_int[i] = ri
        ts.v_mot[i] = vm
        ts.ref_mot[i] = rmo
        rem -= span


@njit(cache=True)
def window(p, ts, cell, n_lanes, t_now, drive, use_drive):
    """One decision window with the agent on ``cell`` (see module doc). Candidates
    ``ts.cands[:n_lanes]``; input spike steps ``ts.sp[:ts.iv[IV_NS]]``; excitatory input of
    lane k: ``ts.wl[k]`` at each input spike (software weights), or with ``use_drive``
    ``drive[t, k]`` (float[steps, 4], a synapse back-end; non-zero anywhere). Writes
    ``ts.counts`` and ``ts.dw`` (before ``k`` and the target rule) and advances the
    network state of every cell it touches to ``t_now + steps``."""
    steps = p.steps
    ns = ts.iv[IV_NS]
    sp = ts.sp
    carried = not p.reset_each_window
    for k in range(n_lanes + 1):
        c = ts.cands[k] if k < n_lanes else cell
        catch_up(p, ts, c, t_now - ts.t_cell[c])
        ts.t_cell[c] = t_now
    # excitation only at the input spikes? then the motor loop can fold in the STDP traces
    at_spikes = True
    if use_drive:
        for t in range(steps):
            if ts.flags[t] == 0:
                for k in range(n_lanes):
                    if drive[t, k] != 0.0:
                        at_spikes = False
    additive = p.stdp_mode != STDP_OFF and not p.vteam
    lockstep = at_spikes and not p.integrate
    fuse = additive and lockstep
    for k in range(n_lanes):
        c = ts.cands[k]
        n_h = 0
        if p.astro:
            n_h = idle_astro(p, c, steps, ts.g, ts.ca, ts.y, ts.h_on, ts.h_off, k)
        if carried:
            vi0 = ts.v_int[c]
            ri0 = ts.ref_int[c]
            ts.lane_f[LF_V0, k] = ts.v_mot[c]
            ts.lane_i[LI_R0, k] = ts.ref_mot[c]
        else:
            vi0 = p.v_rest
            ri0 = 0
            ts.lane_f[LF_V0, k] = p.v_rest
            ts.lane_i[LI_R0, k] = 0
        n_isp = 0
        if carried or n_h > 0 or p.kf_rest_hi < NEVER:
            n_isp, vi, ri = inter_run(p, vi0, ri0, steps, sp, 0, 0.0, ts.h_on, ts.h_off, k,
                                      n_h, ts.isp[k])
            if carried:
                ts.v_int[c] = vi
                ts.ref_int[c] = ri
        ts.lane_i[LI_N_ISP, k] = n_isp
    # the occupied cell's astrocyte (its glutamate chain rides along the motor lanes)
    n_h_occ = 0
    g_from = -1
    g_prev = -1
    g0 = 0.0
    if p.astro:
        n_h_occ, g_from, g_prev, g0 = occupied_astro(p, cell, sp, ns, ts.g, ts.ca, ts.y,
                                                     carried, ts.h_on, ts.h_off,
                                                     ROW_OCCUPIED, lockstep)
    if lockstep:
        gi, g_prev = motor_lanes(p, ts, n_lanes, ns, drive, use_drive, fuse, not fuse,
                                 g_from if g_from >= 0 else ns, g_prev, g0)
        if g_from >= 0:
            ts.g[cell] = gi * powt(p.pow_q, p.q, steps - g_prev - 1)
    for k in range(n_lanes):
        if not lockstep:
            et = sp
            ne = ns
            if not at_spikes:
                et = ts.et
                ne = 0
                for t in range(steps):
                    if drive[t, k] != 0.0:
                        et[ne] = t
                        ne += 1
            n_post, vm, rmo = motor_lane(p, k, et, ne, ts.wl[k], drive, use_drive,
                                         ts.isp[k], ts.lane_i[LI_N_ISP, k],
                                         ts.lane_f[LF_V0, k], ts.lane_i[LI_R0, k], steps,
                                         ts.post[k])
            ts.counts[k] = n_post
            ts.lane_f[LF_V, k] = vm
            ts.lane_i[LI_R0, k] = rmo
        if p.stdp_mode == STDP_OFF:
            ts.dw[k] = 0.0
        elif p.vteam:
            ts.dw[k] = vteam_lane(p, sp, ns, ts.post[k], ts.counts[k], ts.wdev[k])
        elif fuse:
            ts.dw[k] = ts.lane_f[LF_DW, k]
        else:
            ts.dw[k] = stdp_lane(p, sp, ns, ts.post[k], ts.counts[k])
        if carried:
            c = ts.cands[k]
            ts.v_mot[c] = ts.lane_f[LF_V, k]
            ts.ref_mot[c] = ts.lane_i[LI_R0, k]
    if carried:
        isp = ts.isp[ROW_SINGLE]
        n_isp, vi, ri = inter_run(p, ts.v_int[cell], ts.ref_int[cell], steps, sp, ns,
                                  p.w_in_inter * 1.0, ts.h_on, ts.h_off, ROW_OCCUPIED,
                                  n_h_occ, isp)
        _np, vm, rmo = motor_lane(p, 0, sp, 0, 0.0, ts.no_drive, False, isp, n_isp,
                                  ts.v_mot[cell], ts.ref_mot[cell], steps, ts.post[ROW_SINGLE])
        ts.v_int[cell] = vi
        ts.ref_int[cell] = ri
        ts.v_mot[cell] = vm
        ts.ref_mot[cell] = rmo
    for k in range(n_lanes + 1):
        c = ts.cands[k] if k < n_lanes else cell
        ts.t_cell[c] = t_now + steps


# =========================================================================================
# decision and weight updates
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
def window_changes(p, dw, n_lanes, chosen, upd):
    """The window's weight change per lane (``upd``): the chosen lane ``k * dw``, the others
    by ``p.target``: ``all``/``normalize`` their own ``dw``, ``chosen`` nothing,
    ``depress_others`` ``-|dw|``. ``chosen = -1``: no lane was chosen."""
    for k in range(n_lanes):
        if k == chosen:
            upd[k] = dw[k] * p.k
        elif p.target == TARGET_CHOSEN:
            upd[k] = 0.0
        elif p.target == TARGET_DEPRESS:
            upd[k] = -abs(dw[k])
        else:
            upd[k] = dw[k]


@njit(cache=True)
def apply_window_stdp(p, w, pos, dirs, n_lanes, upd, chosen):
    """Add the window's changes ``upd[k]`` to the synapses ``w[pos, dirs[k]]``, each clipped
    to [w_min, w_max] (``target=chosen``: the other lanes are not written).
    ``normalize``: then the cell's outgoing weights are scaled back to their sum before the
    update (heterosynaptic normalisation), clipped again."""
    before = 0.0
    for k in range(n_lanes):
        before += w[pos, dirs[k]]
    for k in range(n_lanes):
        if k != chosen and p.target == TARGET_CHOSEN:
            continue
        w[pos, dirs[k]] = clip_weight(w[pos, dirs[k]] + upd[k], p.w_min, p.w_max)
    if p.target == TARGET_NORMALIZE and n_lanes > 0:
        after = 0.0
        for k in range(n_lanes):
            after += w[pos, dirs[k]]
        if after > 0.0:
            for k in range(n_lanes):
                w[pos, dirs[k]] = clip_weight(w[pos, dirs[k]] * before / after, p.w_min,
                                              p.w_max)


# =========================================================================================
# trials
@njit(cache=True)
def new_trial_state(p, n_cells, n_goals):
    """Arrays for trials of ``p`` on ``n_cells`` cells with ``n_goals`` goals."""
    steps = p.steps
    return TrialState(
        np.zeros(N_IV, dtype=np.int64), np.zeros(1, dtype=np.uint64),
        np.full(p.max_steps + 1, -1, dtype=np.int64),
        np.full((p.max_steps, 4), -1, dtype=np.int64), np.zeros(n_goals, dtype=np.bool_),
        np.zeros(4, dtype=np.int64), np.zeros(4, dtype=np.int64),
        np.zeros(4, dtype=np.int64), np.zeros(4, dtype=np.int64),
        np.zeros(4), np.zeros(4), np.zeros(4), np.zeros(4),
        np.zeros(steps + 1, dtype=np.int64), np.zeros(steps, dtype=np.uint8),
        np.zeros((5, steps + 1), dtype=np.int64), np.zeros((5, steps + 1), dtype=np.int64),
        np.zeros((LF_ROWS, 4)), np.zeros((LI_ROWS, 4), dtype=np.int64),
        np.zeros(steps + 1, dtype=np.int64),
        np.zeros((H_ROWS, H_CAP), dtype=np.int64), np.zeros((H_ROWS, H_CAP), dtype=np.int64),
        np.zeros(n_cells), np.zeros(n_cells, dtype=np.int64), np.zeros(n_cells),
        np.zeros(n_cells, dtype=np.int64), np.zeros(n_cells), np.zeros(n_cells),
        np.zeros(n_cells), np.zeros(n_cells, dtype=np.int64), np.zeros((1, 4)))


@njit(cache=True)
def trial_start(p, ts, start, key):
    """Fresh network (potentials at rest, astrocytes at zero) and bookkeeping for a trial
    from ``start`` with window-stream state ``key``."""
    ts.iv[:] = 0
    ts.iv[IV_POS] = start
    ts.iv[IV_START] = start
    ts.iv[IV_CHOSEN] = -1
    ts.key[0] = key
    ts.path[:] = -1
    ts.path[0] = start
    ts.counts_hist[:, :] = -1
    ts.reached[:] = False
    ts.v_mot[:] = p.v_rest
    ts.v_int[:] = p.v_rest
    ts.ref_mot[:] = 0
    ts.ref_int[:] = 0
    ts.g[:] = 0.0
    ts.ca[:] = 0.0
    ts.y[:] = 0.0
    ts.t_cell[:] = 0


@njit(cache=True)
def begin_window(p, ts, nbr, w_run, w):
    """Candidates of the current cell (``nbr[i, d]``: motor-neuron cell of direction d,
    -1 = none), their weights as the network sees them (``w_run``) and as stored (``w``),
    and the window's input spike train. Returns the number of candidates."""
    pos = ts.iv[IV_POS]
    n_lanes = 0
    for d in range(4):
        nb = nbr[pos, d]
        if nb >= 0:
            ts.cands[n_lanes] = nb
            ts.dirs[n_lanes] = d
            ts.wl[n_lanes] = w_run[pos, d]
            ts.wdev[n_lanes] = w[pos, d]
            n_lanes += 1
    ts.iv[IV_LANES] = n_lanes
    key, ns = draw_spikes(ts.key[0], p.steps, p.spike_threshold, ts.sp, ts.flags)
    ts.key[0] = key
    ts.iv[IV_NS] = ns
    return n_lanes


@njit(cache=True)
def end_window(kp, ts, move, goals, w, drive, use_drive, apply_w):
    """Run the window begun by :func:`begin_window`, decide, learn and move.

    ``move[i, d]``: the cell the agent lands in when it chooses d (-1 = stays: a bumping
    wall). ``goals``: every one must be visited (any order; with ``return_to_start`` the
    trial then ends back on its start). The window's weight changes are in ``ts.upd`` and,
    with ``apply_w``, added to ``w``. Returns True when the trial is over (``ts.iv[
    IV_SUCCESS]`` says how)."""
    return _end_window(params_ref(kp), state_ref(ts), move, goals, w, drive, use_drive,
                       apply_w)


@njit(cache=True)
def _end_window(p, ts, move, goals, w, drive, use_drive, apply_w):
    window(p, ts, ts.iv[IV_POS], ts.iv[IV_LANES], ts.iv[IV_T_NOW], drive, use_drive)
    return _decide(p, ts, move, goals, w, apply_w)


@njit(cache=True)
def _decide(p, ts, move, goals, w, apply_w):
    """After the window's network has run (``ts.counts``, ``ts.dw``): the decision, the
    weight changes and the move (see :func:`end_window`)."""
    pos = ts.iv[IV_POS]
    step = ts.iv[IV_STEP]
    n_lanes = ts.iv[IV_LANES]
    ts.iv[IV_T_NOW] += p.steps
    key, z = splitmix_next(ts.key[0])
    ts.key[0] = key
    for k in range(n_lanes):
        ts.counts_hist[step, ts.dirs[k]] = ts.counts[k]
    chosen = choose_lane(ts.counts, n_lanes, z, p.no_spike_stay, ts.tied)
    ts.iv[IV_CHOSEN] = chosen
    if p.stdp_mode != STDP_OFF:
        window_changes(p, ts.dw, n_lanes, chosen, ts.upd)
        if apply_w:
            apply_window_stdp(p, w, pos, ts.dirs, n_lanes, ts.upd, chosen)
    if chosen >= 0:
        dest = move[pos, ts.dirs[chosen]]
        if dest >= 0:
            pos = dest
    step += 1
    ts.iv[IV_POS] = pos
    ts.iv[IV_STEP] = step
    ts.path[step] = pos
    for gi in range(goals.shape[0]):
        if not ts.reached[gi] and goals[gi] == pos:
            ts.reached[gi] = True
            ts.iv[IV_REACHED] += 1
    if ts.iv[IV_REACHED] == goals.shape[0] and (not p.return_to_start
                                               or pos == ts.iv[IV_START]):
        ts.iv[IV_SUCCESS] = 1
        ts.iv[IV_DONE] = 1
    elif step >= p.max_steps:
        ts.iv[IV_DONE] = 1
    return ts.iv[IV_DONE] != 0


@njit(cache=True)
def run_trial_kernel(kp, ts, nbr, move, start, goals, w, key):
    """One trial with software weights ``w`` (float64 [N, 4]; receives the learned weights
    unless ``stdp.mode`` is off; with ``trial_end`` the network reads a copy). The path,
    counts and network state stay in ``ts``. Returns (steps, success)."""
    return _run_trial(params_ref(kp), state_ref(ts), nbr, move, start, goals, w, key)


@njit(cache=True)
def _run_trial(p, ts, nbr, move, start, goals, w, key):
    trial_start(p, ts, start, key)
    w_run = w.copy() if p.stdp_mode == STDP_TRIAL_END else w
    while True:
        begin_window(p, ts, nbr, w_run, w)
        if _end_window(p, ts, move, goals, w, ts.no_drive, False, True):
            break
    return ts.iv[IV_STEP], ts.iv[IV_SUCCESS] != 0


@njit(cache=True)
def run_batch_kernel(kp, nbr, move, starts, goals, n_goals, w0, keys, paths, steps_out,
                     success_out, w_out):
    """``len(starts)`` independent trials (fresh network each). ``nbr``/``move``: int64
    [1 or trials, N, 4] (one environment for all, or one per trial); ``goals[tr, :
    n_goals[tr]]`` the goals of trial tr; ``w0[tr]`` its initial weights, the final ones
    go to ``w_out[tr]``; ``paths[tr]`` (int64 [max_steps + 1], -1 after the end)."""
    p = params_ref(kp)
    n_trials = starts.shape[0]
    ts = state_ref(new_trial_state(p, nbr.shape[1], goals.shape[1]))
    for tr in range(n_trials):
        e = tr if nbr.shape[0] > 1 else 0
        w = w0[tr].copy()
        g = goals[tr, :n_goals[tr]]
        if g.shape[0] != ts.reached.shape[0]:
            ts = state_ref(new_trial_state(p, nbr.shape[1], g.shape[0]))
        st, ok = _run_trial(p, ts, nbr[e], move[e], starts[tr], g, w, keys[tr])
        steps_out[tr] = st
        success_out[tr] = ok
        paths[tr, :] = ts.path
        w_out[tr] = w


# =========================================================================================
# experiments' helper: the calcium response to one visit
@njit(cache=True)
def calcium_event_kernel(p, n_visit, rate, max_steps):
    """Calcium of one astrocyte (:func:`astro_step`) with input spikes at the steps t <
    ``n_visit`` where ``floor((t+1) rate) > floor(t rate)``, then none, until the calcium has
    risen above Ca_thr and fallen back for good. Returns (first step above, last step above
    + 1, peak); -1 steps if it never rose above."""
    g = np.zeros(1)
    ca = np.zeros(1)
    y = np.zeros(1)
    thr = p.ca_thr
    t_on = -1
    t_off = -1
    peak = 0.0
    for t in range(max_steps):
        s = 0.0
        if t < n_visit and math.floor((t + 1) * rate) > math.floor(t * rate):
            s = 1.0
        astro_step(p, 0, s, g, ca, y)
        if ca[0] > peak:
            peak = ca[0]
        if ca[0] > thr:
            if t_on < 0:
                t_on = t
            t_off = t + 1
        elif t >= n_visit and g[0] <= p.g_thr and y[0] <= 0.0:
            break  # no drive, calcium below threshold and falling: it stays below
    return t_on, t_off, peak


# =========================================================================================
# motor neurons on the board (DECISION_WINDOW, issue 23)
@njit(cache=True)
def board_window_inputs(kp, ts):
    """After :func:`begin_window`, for a window whose motor neurons run on the board: bring
    the cells up to date, run the candidates' interneurons (their spike steps go to
    ``ts.isp[k, :ts.lane_i[LI_N_ISP, k]]``: what the host sends the board) and the occupied
    cell's astrocyte. The operations of :func:`window` before its motor loop, for
    ``neuron.reset_each_window = true`` (the board starts the motor neurons at rest)."""
    p = params_ref(kp)
    s = state_ref(ts)
    _board_inputs(p, s, s.iv[IV_POS], s.iv[IV_LANES], s.iv[IV_T_NOW])


@njit(cache=True)
def _board_inputs(p, ts, cell, n_lanes, t_now):
    steps = p.steps
    ns = ts.iv[IV_NS]
    sp = ts.sp
    for k in range(n_lanes + 1):
        c = ts.cands[k] if k < n_lanes else cell
        catch_up(p, ts, c, t_now - ts.t_cell[c])
        ts.t_cell[c] = t_now
    for k in range(n_lanes):
        c = ts.cands[k]
        n_h = 0
        if p.astro:
            n_h = idle_astro(p, c, steps, ts.g, ts.ca, ts.y, ts.h_on, ts.h_off, k)
        n_isp = 0
        if n_h > 0 or p.kf_rest_hi < NEVER:
            n_isp, _vi, _ri = inter_run(p, p.v_rest, 0, steps, sp, 0, 0.0, ts.h_on, ts.h_off,
                                        k, n_h, ts.isp[k])
        ts.lane_i[LI_N_ISP, k] = n_isp
    if p.astro:
        occupied_astro(p, cell, sp, ns, ts.g, ts.ca, ts.y, False, ts.h_on, ts.h_off,
                       ROW_OCCUPIED, False)


@njit(cache=True)
def board_window_end(kp, ts, move, goals, w, counts, post, apply_w):
    """The board's answer to the window of :func:`board_window_inputs` — ``counts[k]``
    motor spikes of lane k at the steps ``post[k, :counts[k]]`` (needed only when STDP is
    on) — then the STDP change, the decision and the move as :func:`end_window`. Returns
    True when the trial is over."""
    p = params_ref(kp)
    s = state_ref(ts)
    n_lanes = s.iv[IV_LANES]
    ns = s.iv[IV_NS]
    for k in range(n_lanes):
        n_post = counts[k]
        s.counts[k] = n_post
        for j in range(n_post if p.stdp_mode != STDP_OFF else 0):
            s.post[k, j] = post[k, j]
        if p.stdp_mode == STDP_OFF:
            s.dw[k] = 0.0
        elif p.vteam:
            s.dw[k] = vteam_lane(p, s.sp, ns, s.post[k], n_post, s.wdev[k])
        else:
            s.dw[k] = stdp_lane(p, s.sp, ns, s.post[k], n_post)
    cell = s.iv[IV_POS]
    t_end = s.iv[IV_T_NOW] + p.steps
    for k in range(n_lanes + 1):
        c = s.cands[k] if k < n_lanes else cell
        s.t_cell[c] = t_end
    return _decide(p, s, move, goals, w, apply_w)


@njit(cache=True)
def float_motor_window(kp, sp, ns, drive, n_lanes, isp, n_isp, post):
    """The host's float LIF of a window's candidates from rest (what the batch mode runs):
    input spikes at the steps ``sp[:ns]`` with the weight read ``drive[t, k]``
    (float64[steps, 4]), interneuron spikes ``isp[k, :n_isp[k]]``. What the board's
    fixed-point integration is checked against (bench/bench_window.py, tests). Spike steps go
    to ``post[k]``; returns the counts."""
    p = params_ref(kp)
    counts = np.zeros(n_lanes, dtype=np.int64)
    for k in range(n_lanes):
        n_post, _v, _r = motor_lane(p, k, sp, ns, 0.0, drive, True, isp[k], n_isp[k],
                                    p.v_rest, 0, p.steps, post[k])
        counts[k] = n_post
    return counts


@njit(cache=True)
def astro_window_all(dt, alpha_n, k_n, g_thr, a_ca, tau, cell, spikes, g, ca, y):
    """One decision window of every astrocyte, stepped (in place; float64[n_cells] ``g``,
    ``ca``, ``y``), the agent on ``cell`` emitting ``spikes`` (bool[T]): the reference's
    :func:`snan_hil.host.snan_reference.astro_step` once per time step, the same operations
    in the same order (so the same floats), ~300 times faster. What
    :func:`snan_hil.host.calcium_trace.calcium_trace` re-runs a trial's calcium with; tested
    equal to the reference's :func:`~snan_hil.host.calcium_trace.astro_window`."""
    n = g.shape[0]
    tt = tau * tau
    two_tau = 2.0 * tau
    for t in range(spikes.shape[0]):
        s_in = 1.0 if spikes[t] else 0.0
        for i in range(n):
            s = s_in if i == cell else 0.0
            gi = g[i] + dt * (-alpha_n * g[i] + k_n * s)
            g[i] = gi
            jn = a_ca if gi > g_thr else 0.0
            c = ca[i]
            yy = y[i]
            ca[i] = c + dt * yy
            y[i] = yy + dt * (jn - two_tau * yy - c) / tt


# An unreadable cache entry is compiled again instead of failing every run (the wrapper is
# plain Python around numba's cache loader; no compiled code depends on it).
from snan_hil.common.numba_cache import tolerate_damaged_cache  # noqa: E402

tolerate_damaged_cache(globals())
