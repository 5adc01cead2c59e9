"""The board's fixed-point arithmetic of one decision window (DECISION_WINDOW, issue 23).

The MIK32 has no FPU, so the board integrates the candidate motor neurons in integers. This
module is the arithmetic, twice: readable pure-Python references on Python ints
(``*_ref``) and the numba kernels the emulated MCU runs (:func:`spike_steps`,
:func:`drives`, :func:`integrate`); ``tests/firmware/test_decision_window.py`` checks that they
agree
bit for bit, and the C firmware (``firmware/src/window.c``) performs the same operations
(the conformance vectors and a differential test check the replies byte for byte).
Self-contained (numpy and numba only), as every numba module of the project
(``tests/agent/test_kernel_cache.py``).

**Formats** (docs/protocol.md, "0x0A DECISION_WINDOW"):

* potential ``u = v - v_rest``: int64 **Q32.32** (``u * 2^-32`` in the model's units; the
  paper's potentials are a few units: threshold 7, inhibition -50), saturating at
  +-2^62 (+-2^30 units);
* decay over k steps ``alpha^k = exp(-k dt / tau_m)``, k = 1..16: uint64 **Q0.64** (a table
  in the parameter block), split in 32-bit halves ``a_h, a_l``; ``a * u = round(u a_h / 2^32)
  + round(u a_l / 2^64)`` (the first exact, the second after one floor), in 64-bit products of
  32-bit halves (no 128-bit arithmetic, which RV32 lacks); a gap of m > 16 steps chains alpha^16;
* the motor neurons are updated only at their events (input spikes, interneuron spikes, the end
  of an integrating refractory period), ``u <- alpha^(t - t_u) u + input`` — the event-driven
  form of the host's kernel, which decays with the exact ``alpha^m`` between events;
* drive of a read: ``x = code * 2^32 - offset`` (Q32.32 codes), ``q = floor((x <<
  num_shift) / ((d - x) >> den_shift))`` (``q = y 2^(32 + q_shift)``, ``y = x / (d - x)``; a
  64-by-32-bit division with a 32-bit quotient), ``drive = floor(floor(k1 q / 2^32) /
  2^q_shift) - k0`` (Q32.32): the host's calibrated chain ``w = (G - G_min) / span``,
  ``G = 1 / (1/G_eff - R_sw)``, ``G_eff = x / scale``, times R, since
  ``G = y / R_sw`` with ``d = scale / R_sw``; ``x <= 0`` (at or below the offset) gives
  ``G = 0``, as the host's chain does.

**Error bound** against the host's float64 LIF on the same reads (the derivation is in
docs/protocol.md): each event's product loses <= 1.5 LSB (1.5 2^-32, unbiased; one more per 16
steps of a longer gap) and carries the table's rounding (2^-65 relative), a drive
``delta_d <= k1 2^-(32 + q_shift) + 2^-31 + k1 y 2^-den_bits`` (~2e-9 per read on MemriCore);
both decay with the potential, so ``|u_fixed - u_float| <= (1.5 2^-32 + delta_d) / (1 -
alpha^g)`` for events g steps apart on average (g ~ 6.7 at p = 0.15: ~2e-8 model units, 3e8
times below the threshold of 7). A window's counts differ only where the float potential
passes within that distance of the threshold (bench/bench_window.py measures how often:
docs/hil.md).
"""

from __future__ import annotations

import numpy as np
from numba import njit

MASK32 = (1 << 32) - 1
HALF = 1 << 31
MASK64 = (1 << 64) - 1
GOLDEN = 0x9E3779B97F4A7C15
MUL1 = 0xBF58476D1CE4E5B9
MUL2 = 0x94D049BB133111EB
POTENTIAL_LIMIT = 1 << 62
"""Saturation of the potential (Q32.32), as DW_POTENTIAL_LIMIT of the protocol."""
TRACE_MIN, TRACE_MAX = -(1 << 31), (1 << 31) - 1


# ------------------------------------------------------------------------------ spikes
def spike_steps_ref(key: int, n_bins: int, threshold: int) -> list[int]:
    """The window's input spike steps, one splitmix64 draw per step (the host's stream,
    snan_hil.host.rng): step t spikes iff ``mix(key + (t + 1) GOLDEN) >> 11 < threshold``."""
    out = []
    for t in range(n_bins):
        z = (key + (t + 1) * GOLDEN) & MASK64
        z = ((z ^ (z >> 30)) * MUL1) & MASK64
        z = ((z ^ (z >> 27)) * MUL2) & MASK64
        z ^= z >> 31
        if (z >> 11) < threshold:
            out.append(t)
    return out


def spike_steps(key: int, n_bins: int, threshold: int) -> np.ndarray:
    """int64[ns]: :func:`spike_steps_ref`, vectorised in uint64 (wrapping) arithmetic."""
    if n_bins <= 0:
        return np.zeros(0, dtype=np.int64)
    t = np.arange(1, n_bins + 1, dtype=np.uint64)
    z = np.uint64(key & MASK64) + t * np.uint64(GOLDEN)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(MUL1)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(MUL2)
    z ^= z >> np.uint64(31)
    return np.flatnonzero((z >> np.uint64(11)) < np.uint64(threshold)).astype(np.int64)


# ------------------------------------------------------------------------------ drives
def drive_ref(code: int, offset: int, d: int, num_shift: int, den_shift: int, q_shift: int,
              k1: int, k0: int) -> int:
    """Q32.32 drive of one read ``code`` (module doc; Python ints, exact floors)."""
    x = (code << 32) - offset
    q = 0
    if x > 0:
        q = (x << num_shift) // ((d - x) >> den_shift)
    return (((k1 >> 32) * q + (((k1 & MASK32) * q) >> 32)) >> q_shift) - k0


def drives(codes: np.ndarray, offset: int, d: int, num_shift: int, den_shift: int,
           q_shift: int, k1: int, k0: int) -> np.ndarray:
    """int64 array: :func:`drive_ref` of every code (any shape). The caller has checked the
    parameter bounds (docs/protocol.md), so no intermediate leaves int64/uint64."""
    x = (np.asarray(codes, dtype=np.int64) << np.int64(32)) - np.int64(offset)
    pos = x > 0
    den = np.where(pos, (np.int64(d) - x) >> np.int64(den_shift), 1)
    q = np.where(pos, (np.where(pos, x, 0) << np.int64(num_shift)) // den, 0)
    k1h, k1l = np.int64(k1 >> 32), np.uint64(k1 & MASK32)
    lo = ((q.astype(np.uint64) * k1l) >> np.uint64(32)).astype(np.int64)
    return ((k1h * q + lo) >> np.int64(q_shift)) - np.int64(k0)


# ------------------------------------------------------------------------------ the LIF
def mul_alpha_ref(u: int, a: int) -> int:
    """``a * u`` in Q32.32 for a Q0.64 factor ``a`` (module doc): ``round(u a_h / 2^32)``
    exactly, plus ``u a_l / 2^64`` rounded after one floor."""
    ah, al = a >> 32, a & MASK32
    uh, ul = u >> 32, u & MASK32
    return (uh * ah + ((ul * ah + HALF) >> 32)
            + ((uh * al + ((ul * al) >> 32) + HALF) >> 32))


def decay_ref(u: int, m: int, alpha_pow: tuple[int, ...]) -> int:
    """``alpha^m u``: ``m`` > 0 steps as products with the table's alpha^16 while more than 16
    are left, then one with alpha^m."""
    top = len(alpha_pow)
    while m > top:
        u = mul_alpha_ref(u, alpha_pow[top - 1])
        m -= top
    return mul_alpha_ref(u, alpha_pow[m - 1]) if m > 0 else u


def integrate_ref(n_bins: int, spiking: list[bool], drive: dict[tuple[int, int], int],
                  inh_steps: list[list[int]], alpha_pow: tuple[int, ...], thr: int, reset: int,
                  inh: int, ref_steps: int, integrate_refractory: bool, stride: int = 0
                  ) -> tuple[list[int], list[tuple[int, int]], list[list[int]]]:
    """The motor neurons of one window, event by event (paper Eq. 1 in Q32.32, as the host's
    event-driven kernel computes it in float).

    A lane's events: every step with an input spike (``spiking[t]``; its drive
    ``drive[(t, k)]``, 0 if absent), every interneuron spike (``inh_steps[k]``, each subtracts
    ``inh``) and, with ``integrate_refractory``, the step after each refractory period. At an
    event at step t: refractory lanes ignore it (unless they integrate); else ``u = sat(
    alpha^(t - t_u) u + input)`` (``t_u``: the step ``u`` belongs to; :func:`decay_ref`),
    and outside refractoriness a spike iff ``u > thr``: then ``u = reset`` and ``ref_steps``
    refractory steps (a clamped lane is held at ``reset`` through them: ``t_u`` = their end).
    Returns (counts, motor spikes (step, lane) in time order, trace: at every ``stride``-th
    step ``floor(alpha^(t - t_u) u / 2^16)`` clipped to int32, per lane)."""
    lanes = len(inh_steps)
    u = [0] * lanes
    t_u = [-1] * lanes
    ref_end = [-1] * lanes
    check = [-1] * lanes
    counts = [0] * lanes
    inh_sets = [set(x) for x in inh_steps]
    spikes: list[tuple[int, int]] = []
    trace: list[list[int]] = []
    for t in range(n_bins):
        for k in range(lanes):
            inhibited = t in inh_sets[k]
            if not (spiking[t] or inhibited or t == check[k]):
                continue
            current = (drive.get((t, k), 0) if spiking[t] else 0) - (inh if inhibited else 0)
            free = t > ref_end[k]
            if not (free or integrate_refractory):
                continue
            v = decay_ref(u[k], t - t_u[k], alpha_pow) + current
            v = max(-POTENTIAL_LIMIT, min(POTENTIAL_LIMIT, v))
            t_u[k] = t
            if free and v > thr:
                v = reset
                ref_end[k] = t + ref_steps
                counts[k] += 1
                spikes.append((t, k))
                if integrate_refractory:
                    check[k] = ref_end[k] + 1
                else:
                    t_u[k] = ref_end[k]
            u[k] = v
        if stride and t % stride == 0:
            trace.append([max(TRACE_MIN, min(TRACE_MAX, decay_ref(u[k], t - t_u[k],
                                                                  alpha_pow) >> 16))
                          for k in range(lanes)])
    return counts, spikes, trace


@njit(cache=True)
def _mul_alpha(u, ah, al):
    uh = u >> 32
    ul = np.uint64(u & 0xFFFFFFFF)
    p1 = uh * ah + np.int64((ul * np.uint64(ah) + np.uint64(0x80000000)) >> np.uint64(32))
    p2 = (uh * al + np.int64((ul * np.uint64(al)) >> np.uint64(32)) + 0x80000000) >> 32
    return p1 + p2


@njit(cache=True)
def _decay(u, m, ah, al):
    top = ah.shape[0]
    while m > top:
        u = _mul_alpha(u, ah[top - 1], al[top - 1])
        m -= top
    if m > 0:
        u = _mul_alpha(u, ah[m - 1], al[m - 1])
    return u


@njit(cache=True)
def _integrate(n_bins, spiking, drive, inhibited, ah, al, thr, reset, inh, ref_steps, integ,
               stride, counts, spk_t, spk_lane, trace, limit, tmin, tmax):
    lanes = drive.shape[1]
    u = np.zeros(lanes, dtype=np.int64)
    t_u = np.full(lanes, -1, dtype=np.int64)
    ref_end = np.full(lanes, -1, dtype=np.int64)
    check = np.full(lanes, -1, dtype=np.int64)
    n_spk = 0
    point = 0
    for t in range(n_bins):
        for k in range(lanes):
            if not (spiking[t] or inhibited[t, k] or t == check[k]):
                continue
            cur = drive[t, k] if spiking[t] else 0
            if inhibited[t, k]:
                cur -= inh
            free = t > ref_end[k]
            if not (free or integ):
                continue
            v = _decay(u[k], t - t_u[k], ah, al) + cur
            if v > limit:
                v = limit
            elif v < -limit:
                v = -limit
            t_u[k] = t
            if free and v > thr:
                v = reset
                ref_end[k] = t + ref_steps
                counts[k] += 1
                spk_t[n_spk] = t
                spk_lane[n_spk] = k
                n_spk += 1
                if integ:
                    check[k] = ref_end[k] + 1
                else:
                    t_u[k] = ref_end[k]
            u[k] = v
        if stride > 0 and t % stride == 0:
            for k in range(lanes):
                x = _decay(u[k], t - t_u[k], ah, al) >> 16
                if x < tmin:
                    x = tmin
                elif x > tmax:
                    x = tmax
                trace[point, k] = x
            point += 1
    return n_spk


def integrate(n_bins: int, spiking: np.ndarray, drive: np.ndarray, inhibited: np.ndarray,
              alpha_pow: tuple[int, ...], thr: int, reset: int, inh: int, ref_steps: int,
              integrate_refractory: bool, stride: int = 0
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`integrate_ref` on dense arrays: ``spiking`` bool[n_bins] (input spike steps),
    ``drive`` int64[n_bins, lanes], ``inhibited`` bool[n_bins, lanes]. Returns (counts
    int64[lanes], motor spikes int64[n, 2] of (step, lane) in time order, trace int64[points,
    lanes])."""
    lanes = drive.shape[1]
    counts = np.zeros(lanes, dtype=np.int64)
    cap = lanes * (n_bins // (ref_steps + 1) + 1)
    spk_t = np.zeros(cap, dtype=np.int64)
    spk_lane = np.zeros(cap, dtype=np.int64)
    points = (n_bins + stride - 1) // stride if stride > 0 else 0
    trace = np.zeros((points, lanes), dtype=np.int64)
    table = np.asarray([int(a) for a in alpha_pow], dtype=np.uint64)
    ah = (table >> np.uint64(32)).astype(np.int64)
    al = (table & np.uint64(MASK32)).astype(np.int64)
    n = _integrate(int(n_bins), np.ascontiguousarray(spiking, dtype=np.bool_),
                   np.ascontiguousarray(drive, dtype=np.int64),
                   np.ascontiguousarray(inhibited, dtype=np.bool_), ah, al, np.int64(thr),
                   np.int64(reset), np.int64(inh), np.int64(ref_steps),
                   bool(integrate_refractory), np.int64(stride), counts, spk_t, spk_lane,
                   trace, np.int64(POTENTIAL_LIMIT), np.int64(TRACE_MIN), np.int64(TRACE_MAX))
    return counts, np.stack([spk_t[:n], spk_lane[:n]], axis=1), trace


# An unreadable cache entry is compiled again instead of failing every run (the wrapper is
# plain Python around numba's cache loader; no compiled code depends on it).
from snan_hil.common.numba_cache import tolerate_damaged_cache  # noqa: E402

tolerate_damaged_cache(globals())
