"""The aging term of a fitted device model: wear (the window and the step change with the
switching a cell has had) and retention drift, fitted where the data show them, else the
packaged device's assumptions (:class:`~.fitted.AgingTerm`).

**Wear** (:func:`fit_aging`). Each sample carries its cell's cumulative ``|Δ ln G|`` before it
(``swing_before``: every pulse of the cell in the data, any amplitude, counted by whoever read
the data, :mod:`snan_hil.calibration.pulse_files`); in *cycles* that is ``swing / (2 W)``,
``W = ln(g_max_s / g_min_s)`` of the model (a full window down and up is one cycle, the
emulator's wear unit). A cell's samples are cut into *sweeps* — a train of each polarity,
in order — and each sweep but the first (which starts wherever the cell was, so its fit sees
one end less: a bias, not wear) fitted alone (:func:`~.fitted.fit_cell`). Its ``x_max -
x_min`` would be the window, but bounds extrapolated from one sweep trade off against the
rate and the slope; the mean steps at ``g_ref_s`` are interpolated and well determined. So per
cell the straight-line slopes of its SET and RESET steps at ``g_ref_s`` against the sweep's
mean cycles (relative to the cell's mean step), ``s_up`` and ``s_down``, and — the soft bound:
a step at ``x_ref`` is proportional to the distance to its bound, the rate unchanged, as the
emulator's wear moves only the bounds — the window's loss per cycle ``-(s_up (x_max - x_ref) +
s_down (x_ref - x_min)) / W``; the mean step's relative slope is ``step_change_per_cycle``.
Over the cells, the mean with its 95 % interval (Student t over cells). *Fitted* when
the interval excludes 0 (>= 3 cells with >= 2 sweeps, a loss that is positive: the emulator
models closure only), else the packaged assumption (``configs/device-ysz.yaml`` ``wear``:
closure 0.5 of the window at an endurance of 1e5 cycles of the device state, converted to the
model's cycles), with the data's interval beside it.

Read noise inflates the counted swing a little (each reading adds ``|noise|``); the counted
cycles of a characterisation's trains are an overestimate of about ``2 σ / |step|`` near the
bounds, where the steps are small.

**Drift** (:func:`fit_aging`, ``retention``): pairs of a cell's consecutive pulses with the
time between them, ``(Δt, G after the first, G before the second)``: with power-law drift from
the last pulse ``ln(G_before / G_after) = -ν ln((Δt + t0) / t0)`` plus the two readings' noise
``N(0, 2 σ²)``; ``ν`` by weighted least squares through 0, its 95 % interval ``± 1.96 √2 σ /
√Σ z²``. *Fitted* when the interval excludes 0 and some gap is >= 10 t0 (the data hold
retention), else the packaged assumption ``ν = 0`` (paper Fig. 10A: no relaxation over 10,000
reads), with the data's interval beside it when they have gaps.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from snan_hil.common.polarity import Polarity
from snan_hil.crossbar_model.config import ArrayConfig
from snan_hil.crossbar_model.fitted import AgingTerm, DeviceModel, PulseSample, fit_cell

__all__ = ["fit_aging", "packaged_wear_per_cycle", "sweeps"]

T0_S = 1.0      #: reference time of the drift law (s), the packaged ``drift.t0_s``


def sweeps(samples: Sequence[PulseSample]) -> list[list[PulseSample]]:
    """One cell's samples (in order) cut into sweeps: consecutive pairs of trains (runs of
    one polarity); a last lone train joins the sweep before it."""
    trains: list[list[PulseSample]] = []
    for s in samples:
        if trains and trains[-1][0].polarity == s.polarity:
            trains[-1].append(s)
        else:
            trains.append([s])
    out = [trains[i] + trains[i + 1] for i in range(0, len(trains) - 1, 2)]
    if len(trains) % 2 and out:
        out[-1] = out[-1] + trains[-1]
    return out


def packaged_wear_per_cycle(model: DeviceModel, base: ArrayConfig | None = None
                            ) -> tuple[float, float]:
    """(window loss per model cycle, closure) of the packaged device's wear, converted from
    its device-state cycles: ``k = W (1 + G_ref R_T) / L`` device cycles per model cycle
    (:mod:`.device_twin`)."""
    base = base if base is not None else ArrayConfig.default()
    w = base.wear
    r_t = base.transistor.on_resistance_ohm
    g_mem = model.g_ref_s / (1.0 - model.g_ref_s * r_t)
    big_l = math.log(base.conductance.g_max_s / base.conductance.g_min_s)
    k = math.log(model.g_max_s / model.g_min_s) * (1.0 + g_mem * r_t) / big_l
    return w.window_closure / (w.endurance_cycles / k), w.window_closure


def _t_interval(values: np.ndarray) -> tuple[float, float, float]:
    from scipy.stats import t as student
    m = float(values.mean())
    if values.size < 2:
        return m, math.nan, math.nan
    half = float(student.ppf(0.975, values.size - 1) * values.std(ddof=1)
                 / math.sqrt(values.size))
    return m, m - half, m + half


def _wear_slopes(samples: Sequence[PulseSample], model: DeviceModel
                 ) -> tuple[np.ndarray, np.ndarray, float]:
    """Per cell: the window's loss per cycle (relative, through the steps: module doc) and
    the slope of its mean step at g_ref (relative, per cycle) over its sweeps; the most
    cycles a cell went through."""
    width = math.log(model.g_max_s / model.g_min_s)
    x_ref = math.log(model.g_ref_s)
    top, bottom = model.x_max - x_ref, x_ref - model.x_min
    by: dict[tuple[int, int], list[PulseSample]] = {}
    for s in samples:
        if s.swing_before is not None:
            by.setdefault((s.row, s.col), []).append(s)
    loss, step = [], []
    seen = 0.0
    for (r, c), pts in by.items():
        seen = max(seen, max(float(p.swing_before or 0.0) for p in pts) / (2 * width))
        rows = []
        for sw in sweeps(pts)[1:]:         # the first starts wherever the cell was: not whole
            f = fit_cell(r, c, sw, g_ref_s=model.g_ref_s)
            if not f.ok:
                continue
            cyc = float(np.mean([p.swing_before or 0.0 for p in sw])) / (2 * width)
            rows.append((cyc, float(f.mean_dx(Polarity.SET, model.g_ref_s)),
                         -float(f.mean_dx(Polarity.RESET, model.g_ref_s))))
        if len(rows) < 2:
            continue
        a = np.array(rows)
        if np.ptp(a[:, 0]) <= 0:
            continue
        up = np.polyfit(a[:, 0], a[:, 1] / a[:, 1].mean(), 1)[0]
        down = np.polyfit(a[:, 0], a[:, 2] / a[:, 2].mean(), 1)[0]
        loss.append(-(up * top + down * bottom) / width)
        both = a[:, 1] + a[:, 2]
        step.append(np.polyfit(a[:, 0], both / both.mean(), 1)[0])
    return np.array(loss), np.array(step), seen


def _drift(retention: Sequence[tuple[float, float, float]], sigma: float
           ) -> tuple[float, tuple[float, float], bool]:
    """(ν, 95 % interval, whether the data hold retention) from consecutive-pulse pairs."""
    z, y = [], []
    longest = 0.0
    for gap, g_after, g_before in retention:
        if not (gap >= 0 and g_after > 0 and g_before > 0):
            continue
        if g_before == g_after:           # the same reading used twice: no information
            continue
        z.append(math.log((gap + T0_S) / T0_S))
        y.append(math.log(g_before / g_after))
        longest = max(longest, gap)
    if not z or not sigma > 0:
        return math.nan, (math.nan, math.nan), False
    za, ya = np.array(z), np.array(y)
    s2 = float((za ** 2).sum())
    if s2 <= 0:
        return math.nan, (math.nan, math.nan), False
    nu = float(-(ya * za).sum() / s2)
    half = 1.96 * math.sqrt(2.0) * sigma / math.sqrt(s2)
    return nu, (nu - half, nu + half), longest >= 10 * T0_S


def fit_aging(samples: Sequence[PulseSample], model: DeviceModel, *,
              retention: Sequence[tuple[float, float, float]] = (),
              base: ArrayConfig | None = None) -> AgingTerm:
    """The aging term of ``model`` from its ``samples`` (with ``swing_before``) and the
    consecutive-pulse ``retention`` pairs ``(gap s, G after S, G before S)`` (module doc)."""
    base = base if base is not None else ArrayConfig.default()
    loss_cells, step, seen = _wear_slopes(samples, model)
    loss_pkg, closure = packaged_wear_per_cycle(model, base)
    w_mean = w_lo = w_hi = s_mean = s_lo = s_hi = math.nan
    if loss_cells.size >= 3:
        m, lo, hi = _t_interval(loss_cells)
        w_mean, w_lo, w_hi = m, lo, hi
        s_mean, s_lo, s_hi = _t_interval(step)
    shown = loss_cells.size >= 3 and w_lo > 0
    if shown:
        wear_source = (f"fitted: {loss_cells.size} cells, up to {seen:.3g} cycles each; window loss "
                       f"{w_mean:.3g} [{w_lo:.3g}, {w_hi:.3g}] per cycle (closure "
                       f"{closure:g} at the end of life: assumption, packaged)")
        loss = w_mean
    else:
        why = ("no cell has two sweeps with the pulses counted" if loss_cells.size < 3 else
               f"the data bound the loss to [{w_lo:.3g}, {w_hi:.3g}] per cycle over "
               f"{seen:.3g} cycles: no change shown")
        wear_source = (f"assumption: packaged wear (closure {closure:g} of the window at "
                       f"{base.wear.endurance_cycles:g} device cycles, configs/device-ysz.yaml; "
                       f"ZrO2(Y) devices last >= 1000 training cycles, Koryazhkina et al. 2023)"
                       f"; {why}")
        loss = loss_pkg
    nu, nu_ci, informative = _drift(retention, model.read_noise)
    if informative and nu_ci[0] > 0:
        drift_source = (f"fitted: {len(retention)} consecutive-pulse pairs; nu {nu:.3g} "
                        f"[{nu_ci[0]:.3g}, {nu_ci[1]:.3g}]")
        drift = nu
    else:
        bound = (f"; the data bound nu to [{nu_ci[0]:.3g}, {nu_ci[1]:.3g}]"
                 if math.isfinite(nu) else "; the data hold no times between pulses")
        drift_source = ("assumption: packaged nu = 0 (paper Fig. 10A: no relaxation over "
                        "10,000 reads)" + bound)
        drift = base.drift.nu_mean
    return AgingTerm(window_loss_per_cycle=float(loss),
                     step_change_per_cycle=float(s_mean) if shown else 0.0,
                     drift_nu=float(drift), wear_source=wear_source,
                     drift_source=drift_source, window_loss_ci=(w_lo, w_hi),
                     step_change_ci=(s_lo, s_hi), drift_nu_ci=nu_ci,
                     window_closure=closure, drift_t0_s=T0_S, cycles_seen=float(seen))
