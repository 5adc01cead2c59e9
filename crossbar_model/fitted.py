"""A compact pulsed-device model fitted to measured pulse responses (``snan-hil characterize``).

The measured data are, per cell and polarity, pairs (G before a pulse, G after it) at one
learning pulse (amplitude, width). The model is a *soft-bounds device in the log-conductance*
``x = ln G`` (the form the YSZ state takes, docs/crossbar_model.md §2.1)::

    SET   (up):    E[Δx] =  up_rate   * exp(up_slope   (x - x_ref)) * (x_max - x)   > 0 below x_max
    RESET (down):  E[Δx] = -down_rate * exp(down_slope (x - x_ref)) * (x - x_min)   < 0 above x_min
    one pulse:     Δx = E[Δx] * (1 + dw_min_std * ξ)    (multiplicative cycle-to-cycle noise)

with ``x_ref = ln g_ref_s``, fitted per cell and branch by nonlinear least squares of ``Δx`` on
``x`` (scipy). ``*_slope = 0`` is aihwkit's ``SoftBoundsDevice`` in ln G; the slopes take up the
1T1R divider: the voltage across the memristor falls as G rises, so a SET pulse slows (and
stops where it no longer reaches threshold: ``x_max`` is the pulse's own bound, below the
device's), a RESET pulse speeds up as G falls. On the emulated chip the form leaves ~1 % (SET)
and ~5 % (RESET) of the mean step unexplained, the soft-bounds line alone 2 % and 12 %. The chip-level parameters carry IBM
aihwkit's names where they mean the same (``PulsedDevice``/``SoftBoundsDevice``: a device's
state is its weight there, ln G here; all dimensionless):

* ``dw_min`` — mean |Δx| of one pulse at ``g_ref_s`` (the weight map's middle), over cells and
  both directions; ``up_down`` — the directional bias there: up step ``dw_min (1 + up_down)``,
  down step ``dw_min (1 - up_down)``;
* ``dw_min_dtod`` — device-to-device std of a cell's mean step, relative to ``dw_min``;
  ``up_down_dtod`` — std of the cells' ``up_down``;
* ``dw_min_std`` — cycle-to-cycle std of one step, relative to its mean (the read noise of
  the measurement removed);
* ``w_min``/``w_max`` in the conductance domain: ``g_min_s``/``g_max_s`` (S, where the
  chip-level mean step vanishes: the chip curve has the cells' median rates and their mean
  steps at ``g_ref_s``), ``g_min_dtod``/``g_max_dtod`` (std over cells of ln of a cell's own
  bound, i.e. its relative spread).

Conductance-domain equivalents: :meth:`DeviceModel.mean_step_s` (ΔG in S of one pulse at G).
Pure computation (numpy), no I/O; :meth:`DeviceModel.to_dict` / :meth:`from_dict` are the stored
form (history database, JSON).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from snan_hil.common.polarity import Polarity

__all__ = ["MODEL_FORMAT", "LearningPulse", "CellFit", "DeviceModel", "PulseSample",
           "AgingTerm", "fit_cell", "fit_device"]

MODEL_FORMAT = "snan-hil-device-model/1"


@dataclass(frozen=True)
class LearningPulse:
    """The pulse a learning rule sends (V, us): SET raises G, RESET lowers it.

    Defaults (an assumption, measured on the emulated YSZ chip, docs/learning.md): 0.8 V SET and
    0.6 V RESET of 100 us move a cell at the weight map's middle (525 uS) by ~+5 % and ~-3.5 %,
    i.e. 0.02-0.03 of the weight range per pulse: an STDP update of 0.1-0.3 is a handful of
    pulses, and the smallest updates accumulate in a remainder."""

    set_v: float = 0.8
    reset_v: float = 0.6
    width_us: int = 100

    def __post_init__(self) -> None:
        for name in ("set_v", "reset_v"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive amplitude in V, got {v}")
        if not 0 < int(self.width_us) <= 100_000:
            raise ValueError(f"width_us must be 1..100000, got {self.width_us}")

    def amplitude(self, polarity: Polarity) -> float:
        return self.set_v if polarity == Polarity.SET else self.reset_v

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class PulseSample:
    """One measured pulse: cell, polarity, G read before and after (S).

    Optional, for the aging term (:mod:`.aging`): ``swing_before`` — the cell's cumulative
    ``|Δ ln G|`` over the pulses of the data before this one (any amplitude; dimensionless),
    ``time_s`` — when the pulse was applied (s, any origin; None: unknown)."""

    row: int
    col: int
    polarity: Polarity
    g_before_s: float
    g_after_s: float
    swing_before: float | None = None
    time_s: float | None = None


@dataclass(frozen=True)
class AgingTerm:
    """How a chip's response changes with use and time (:mod:`.aging` fits it).

    Wear, in the emulator's form (docs/crossbar_model.md §2.1): a cell's window in ln G
    closes linearly with the *cycles* it has been switched through — full-window swings,
    ``sum |Δ ln G| / (2 W)`` with ``W = ln(g_max_s / g_min_s)`` of the model — and its mean
    step at the reference changes with them. ``window_loss_per_cycle``: fraction of ``W``
    lost per cycle (the emulator's ``window_closure / endurance``); ``step_change_per_cycle``:
    relative change of the mean step at ``g_ref_s`` per cycle; ``window_closure``: the
    fraction of the window lost when a cell is worn out (an assumption: 0.5, the packaged
    device's). Retention drift: ``G(t) = G_prog ((t - t_prog + t0) / t0) ** -drift_nu``.

    Each part carries where it came from (``wear_source``, ``drift_source``: ``"fitted: ..."``
    where the data showed it — the 95 % interval excludes no change —, else ``"assumption:
    ..."`` with the packaged value) and its 95 % interval (``*_ci``; NaNs when the data could
    not bound it)."""

    window_loss_per_cycle: float
    step_change_per_cycle: float
    drift_nu: float
    wear_source: str
    drift_source: str
    window_loss_ci: tuple[float, float] = (math.nan, math.nan)
    step_change_ci: tuple[float, float] = (math.nan, math.nan)
    drift_nu_ci: tuple[float, float] = (math.nan, math.nan)
    window_closure: float = 0.5
    drift_t0_s: float = 1.0
    cycles_seen: float = 0.0
    """The largest number of cycles a cell went through in the data."""

    @property
    def wear_fitted(self) -> bool:
        return self.wear_source.startswith("fitted")

    @property
    def drift_fitted(self) -> bool:
        return self.drift_source.startswith("fitted")

    @property
    def endurance_cycles(self) -> float:
        """Cycles until a cell's window has lost ``window_closure`` (inf: no loss)."""
        if not self.window_loss_per_cycle > 0:
            return math.inf
        return self.window_closure / self.window_loss_per_cycle

    def to_dict(self) -> dict[str, Any]:
        def num(v: float) -> float | None:
            return float(v) if math.isfinite(v) else None
        d: dict[str, Any] = {}
        for k, v in asdict(self).items():
            if isinstance(v, tuple):
                d[k] = [num(x) for x in v]
            elif isinstance(v, float):
                d[k] = num(v)
            else:
                d[k] = v
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "AgingTerm":
        def f(v: Any) -> float:
            return math.nan if v is None else float(v)

        def pair(k: str) -> tuple[float, float]:
            v = d.get(k) or [None, None]
            return (f(v[0]), f(v[1]))
        return cls(f(d["window_loss_per_cycle"]), f(d["step_change_per_cycle"]),
                   f(d["drift_nu"]), str(d["wear_source"]), str(d["drift_source"]),
                   pair("window_loss_ci"), pair("step_change_ci"), pair("drift_nu_ci"),
                   f(d.get("window_closure", 0.5)), f(d.get("drift_t0_s", 1.0)),
                   f(d.get("cycles_seen", 0.0)))


@dataclass(frozen=True)
class CellFit:
    """One cell's fitted response (see module doc). ``ok`` False: too few points or no
    response in a direction (the cell is left out of the chip-level numbers)."""

    row: int
    col: int
    x_ref: float
    up_rate: float
    up_slope: float
    x_max: float
    down_rate: float
    down_slope: float
    x_min: float
    n_up: int = 0
    n_down: int = 0
    ok: bool = True
    reason: str = ""

    def mean_dx(self, polarity: Polarity, g: np.ndarray | float) -> np.ndarray:
        """E[Δ ln G] of one pulse at conductance ``g`` (S): >= 0 for SET, <= 0 for RESET."""
        x = np.log(np.maximum(np.asarray(g, dtype=float), 1e-12))
        d = x - self.x_ref
        if polarity == Polarity.SET:
            return np.maximum(self.up_rate * np.exp(self.up_slope * d) * (self.x_max - x), 0.0)
        return -np.maximum(self.down_rate * np.exp(self.down_slope * d) * (x - self.x_min), 0.0)

    def to_dict(self) -> dict[str, Any]:
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "CellFit":
        def f(k: str) -> float:
            v = d.get(k)
            return float("nan") if v is None else float(v)
        return cls(int(d["row"]), int(d["col"]), f("x_ref"), f("up_rate"), f("up_slope"),
                   f("x_max"), f("down_rate"), f("down_slope"), f("x_min"),
                   int(d.get("n_up", 0)), int(d.get("n_down", 0)), bool(d.get("ok", True)),
                   str(d.get("reason", "")))


def _branch(x: np.ndarray, y: np.ndarray, x_ref: float, up: bool) -> tuple[float, float, float]:
    """(rate, slope, bound) of one branch: ``y = rate exp(slope (x - x_ref)) (x_max - x)`` (up)
    or ``(x - x_min)`` (down), ``y`` the step towards the branch's bound (> 0). Starts from the
    soft-bounds line; NaNs when the data show no such response."""
    from scipy.optimize import least_squares   # ~0.3 s to import: only when fitting

    sign = 1.0 if up else -1.0
    a, b = np.polyfit(x, y, 1)[::-1]
    rate0 = -b * sign
    if not rate0 > 0:
        return math.nan, math.nan, math.nan
    bound0 = a / rate0 if up else -a / rate0

    def resid(p: np.ndarray) -> np.ndarray:
        return p[0] * np.exp(p[1] * (x - x_ref)) * sign * (p[2] - x) - y

    scale = max(float(np.abs(y).mean()), 1e-9)
    res = least_squares(resid, [rate0, 0.0, bound0], x_scale=[rate0, 0.3, 1.0],
                        f_scale=scale, loss="soft_l1", max_nfev=200)
    rate, slope, bound = (float(v) for v in res.x)
    if not (res.success and rate > 0 and abs(slope) < 5 and math.isfinite(bound)):
        return rate0, 0.0, bound0              # the soft-bounds line, which is well defined
    return rate, slope, bound


def fit_cell(row: int, col: int, samples: Sequence[PulseSample], *, g_ref_s: float,
             min_points: int = 6) -> CellFit:
    """Fit one cell's SET and RESET branches (module doc) from its samples."""
    x_ref = math.log(g_ref_s)
    out: dict[str, tuple[float, float, float]] = {}
    counts = {}
    for pol, key in ((Polarity.SET, "up"), (Polarity.RESET, "down")):
        pts = [(s.g_before_s, s.g_after_s) for s in samples
               if s.polarity == pol and s.g_before_s > 0 and s.g_after_s > 0]
        counts[key] = len(pts)
        if len(pts) < min_points:
            nan = math.nan
            return CellFit(row, col, x_ref, nan, nan, nan, nan, nan, nan, counts.get("up", 0),
                           counts.get("down", 0), False,
                           f"{len(pts)} {pol.name} pulses with a reading (need {min_points})")
        gb = np.array([p[0] for p in pts])
        ga = np.array([p[1] for p in pts])
        x = np.log(gb)
        dx = np.log(ga / gb)
        out[key] = _branch(x, dx if pol == Polarity.SET else -dx, x_ref, pol == Polarity.SET)
    (ur, us, ub), (dr, ds, db) = out["up"], out["down"]
    ok = all(math.isfinite(v) for v in (ur, us, ub, dr, ds, db)) and ur > 0 and dr > 0 \
        and db < ub
    reason = "" if ok else "no consistent response (a step that does not shrink towards a bound)"
    return CellFit(row, col, x_ref, ur, us, ub, dr, ds, db, counts["up"], counts["down"], ok,
                   reason)


@dataclass(frozen=True)
class DeviceModel:
    """The fitted model of one chip at one learning pulse (module doc). Conductances in S."""

    pulse: LearningPulse
    g_ref_s: float
    dw_min: float
    up_down: float
    dw_min_dtod: float
    up_down_dtod: float
    dw_min_std: float
    g_min_s: float
    g_max_s: float
    g_min_dtod: float
    g_max_dtod: float
    up_rate: float
    up_slope: float
    down_rate: float
    down_slope: float
    read_noise: float
    """Relative std of one read during the measurement (removed from ``dw_min_std``)."""
    cells: tuple[CellFit, ...] = ()
    points: int = 0
    r2_up: float = math.nan
    r2_down: float = math.nan
    meta: dict = field(default_factory=dict)
    aging: AgingTerm | None = None
    """Wear and retention drift (None: not fitted; the packaged device's assumptions hold)."""

    # ---- the chip-level mean response ---------------------------------------------------
    @property
    def x_max(self) -> float:
        return math.log(self.g_max_s)

    @property
    def x_min(self) -> float:
        return math.log(self.g_min_s)

    def chip_cell(self) -> CellFit:
        """The chip-level response as a :class:`CellFit` (row, col -1)."""
        return CellFit(-1, -1, math.log(self.g_ref_s), self.up_rate, self.up_slope, self.x_max,
                       self.down_rate, self.down_slope, self.x_min)

    def mean_dx(self, polarity: Polarity, g: np.ndarray | float) -> np.ndarray:
        """Chip-level E[Δ ln G] of one pulse at ``g`` (S)."""
        return self.chip_cell().mean_dx(polarity, g)

    def mean_step_s(self, polarity: Polarity, g: np.ndarray | float) -> np.ndarray:
        """Conductance-domain equivalent: E[ΔG] (S) of one pulse at ``g`` (S)."""
        g = np.asarray(g, dtype=float)
        return g * np.expm1(self.mean_dx(polarity, g))

    def cell_fit(self, row: int, col: int) -> CellFit | None:
        """The usable fit of cell (row, col), None if it was not measured or not usable."""
        return next((c for c in self.cells if (c.row, c.col) == (row, col) and c.ok), None)

    # ---- persistence --------------------------------------------------------------------
    def parameters(self) -> dict[str, float]:
        """The chip-level parameters by name (aihwkit's names where they mean the same)."""
        return {k: getattr(self, k) for k in (
            "dw_min", "up_down", "dw_min_dtod", "up_down_dtod", "dw_min_std", "g_min_s",
            "g_max_s", "g_min_dtod", "g_max_dtod", "up_rate", "up_slope", "down_rate",
            "down_slope", "g_ref_s", "read_noise")}

    def to_dict(self) -> dict[str, Any]:
        def num(v: float) -> float | None:
            return float(v) if math.isfinite(v) else None
        return {"format": MODEL_FORMAT, "pulse": self.pulse.to_dict(),
                **{k: num(v) for k, v in self.parameters().items()},
                "points": self.points, "r2_up": num(self.r2_up), "r2_down": num(self.r2_down),
                "cells": [c.to_dict() for c in self.cells], "meta": dict(self.meta),
                "aging": None if self.aging is None else self.aging.to_dict()}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "DeviceModel":
        """Inverse of :meth:`to_dict`; ValueError for another format or a missing key."""
        if d.get("format") != MODEL_FORMAT:
            raise ValueError(f"not a device model ({MODEL_FORMAT}): format {d.get('format')!r}")
        try:
            def f(k: str) -> float:
                v = d.get(k)
                return math.nan if v is None else float(v)
            p = d["pulse"]
            names = ("g_ref_s", "dw_min", "up_down", "dw_min_dtod", "up_down_dtod",
                     "dw_min_std", "g_min_s", "g_max_s", "g_min_dtod", "g_max_dtod", "up_rate",
                     "up_slope", "down_rate", "down_slope", "read_noise")
            values: dict[str, Any] = {k: f(k) for k in names}
            return cls(pulse=LearningPulse(float(p["set_v"]), float(p["reset_v"]),
                                           int(p["width_us"])),
                       cells=tuple(CellFit.from_dict(c) for c in d.get("cells", [])),
                       points=int(d.get("points", 0)), r2_up=f("r2_up"), r2_down=f("r2_down"),
                       meta=dict(d.get("meta") or {}),
                       aging=AgingTerm.from_dict(d["aging"]) if d.get("aging") else None,
                       **values)
        except (KeyError, TypeError, IndexError) as exc:
            raise ValueError(f"device model is incomplete ({exc})") from None


def _r2(cells: Sequence[CellFit], samples: Sequence[PulseSample], pol: Polarity) -> float:
    by = {(c.row, c.col): c for c in cells if c.ok}
    obs, pred = [], []
    for s in samples:
        c = by.get((s.row, s.col))
        if c is None or s.polarity != pol or s.g_before_s <= 0 or s.g_after_s <= 0:
            continue
        obs.append(math.log(s.g_after_s / s.g_before_s))
        pred.append(float(c.mean_dx(pol, s.g_before_s)))
    if len(obs) < 3:
        return math.nan
    o, p = np.array(obs), np.array(pred)
    ss = float(((o - o.mean()) ** 2).sum())
    return 1.0 - float(((o - p) ** 2).sum()) / ss if ss > 0 else math.nan


def _cycle_to_cycle(samples: Sequence[PulseSample], cells: Sequence[CellFit],
                    read_noise: float) -> float:
    """Relative std of one step about its mean, read noise removed: per cell and polarity the
    steps' mean is a quadratic in x (so the divider's curvature is not counted as noise);
    ``var(residual) = dw_min_std^2 E[Δx]^2 + 2 read_noise^2`` over the informative steps."""
    num = den = 0.0
    by = {(c.row, c.col) for c in cells if c.ok}
    groups: dict[tuple[int, int, Polarity], list[tuple[float, float]]] = {}
    for s in samples:
        if (s.row, s.col) in by and s.g_before_s > 0 and s.g_after_s > 0:
            groups.setdefault((s.row, s.col, s.polarity), []).append(
                (math.log(s.g_before_s), math.log(s.g_after_s / s.g_before_s)))
    floor = 3.0 * math.sqrt(2.0) * read_noise
    for pts in groups.values():
        if len(pts) < 8:
            continue
        x = np.array([p[0] for p in pts])
        y = np.array([p[1] for p in pts])
        coef = np.polyfit(x, y, 2)
        mean = np.polyval(coef, x)
        use = np.abs(mean) > floor
        if use.sum() < 4:
            continue
        dof = use.sum() / max(use.sum() - 3, 1)
        num += float(((y[use] - mean[use]) ** 2).sum() * dof - 2 * read_noise ** 2 * use.sum())
        den += float((mean[use] ** 2).sum())
    return math.sqrt(max(num, 0.0) / den) if den > 0 else math.nan


def fit_device(samples: Sequence[PulseSample], pulse: LearningPulse, *, g_ref_s: float,
               read_noise: float, min_points: int = 6, meta: Mapping[str, Any] | None = None
               ) -> DeviceModel:
    """Fit every cell of ``samples`` and summarise them (module doc).

    ``g_ref_s`` (S): where ``dw_min`` and ``up_down`` are stated (the weight map's middle);
    ``read_noise``: relative std of one read during the measurement. Raises ValueError when no
    cell gives a usable fit."""
    by_cell: dict[tuple[int, int], list[PulseSample]] = {}
    for s in samples:
        by_cell.setdefault((s.row, s.col), []).append(s)
    cells = tuple(fit_cell(r, c, pts, g_ref_s=g_ref_s, min_points=min_points)
                  for (r, c), pts in sorted(by_cell.items()))
    good = [c for c in cells if c.ok]
    if not good:
        raise ValueError("no cell gave a usable fit (every cell: too few pulses with a "
                         "reading, or no response); "
                         + "; ".join(f"({c.row},{c.col}): {c.reason}" for c in cells[:3]))
    up = np.array([float(c.mean_dx(Polarity.SET, g_ref_s)) for c in good])
    down = np.array([-float(c.mean_dx(Polarity.RESET, g_ref_s)) for c in good])
    mean_cell = (up + down) / 2.0
    dw_min = float(mean_cell.mean())
    up_down = float((up.mean() - down.mean()) / (up.mean() + down.mean()))
    beta = (up - down) / np.maximum(up + down, 1e-12)
    x_max = np.array([c.x_max for c in good])
    x_min = np.array([c.x_min for c in good])
    up_rate = float(np.median([c.up_rate for c in good]))
    down_rate = float(np.median([c.down_rate for c in good]))
    up_slope = float(np.median([c.up_slope for c in good]))
    down_slope = float(np.median([c.down_slope for c in good]))
    # chip-level bounds such that the chip curve gives the chip's mean steps at g_ref
    x_ref = math.log(g_ref_s)
    g_max = math.exp(x_ref + float(up.mean()) / up_rate)
    g_min = math.exp(x_ref - float(down.mean()) / down_rate)
    seen = [v for s in samples for v in (s.g_before_s, s.g_after_s) if v > 0]
    meta = {"g_range_s": [float(min(seen)), float(max(seen))], **dict(meta or {})}
    return DeviceModel(
        pulse=pulse, g_ref_s=float(g_ref_s), dw_min=dw_min, up_down=up_down,
        dw_min_dtod=float(mean_cell.std(ddof=1) / dw_min) if len(good) > 1 else 0.0,
        up_down_dtod=float(beta.std(ddof=1)) if len(good) > 1 else 0.0,
        dw_min_std=_cycle_to_cycle(samples, cells, read_noise),
        g_min_s=g_min, g_max_s=g_max,
        g_min_dtod=float(x_min.std(ddof=1)) if len(good) > 1 else 0.0,
        g_max_dtod=float(x_max.std(ddof=1)) if len(good) > 1 else 0.0,
        up_rate=up_rate, up_slope=up_slope, down_rate=down_rate, down_slope=down_slope,
        read_noise=float(read_noise), cells=cells,
        points=len(samples), r2_up=_r2(cells, samples, Polarity.SET),
        r2_down=_r2(cells, samples, Polarity.RESET), meta=meta)
