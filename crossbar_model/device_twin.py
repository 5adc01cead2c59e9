"""A fitted device model made physical: the emulated chip of a lab's measured device.

:mod:`.fitted` describes a chip by what its cells do at one learning pulse, in the
log-conductance of the whole 1T1R cell as the board's read chain sees it. The emulator needs
more than that: a physical YSZ cell (:mod:`.device`: state, bounds, switching rate, threshold,
the 1T1R divider) that answers *any* pulse. :func:`twin_spec` inverts the fitted model into
that physics, cell by cell:

* every measured cell with a usable fit gets its own device at its own place (row, col): per
  branch the device bound (``g_max`` for SET, ``g_min`` for RESET, memristor conductance, S)
  and the switching rate (1/s) that make the physical model's noise-free step at the learning
  pulse, integrated exactly as :func:`.device.pulse_response` integrates it, match the cell's
  fitted step curve over the measured conductance range (least squares in Δ ln G, scipy).
  SET steps depend on ``g_max`` and the SET rate only, RESET steps on ``g_min`` and the RESET
  rate only (the soft bound in ln G), so the two branches are fitted apart;
* the threshold and the overdrive exponents are **not** identifiable from one amplitude (the
  rate takes up the threshold: checked on the emulated chip, a free threshold runs to its
  bound). The twin keeps the packaged exponents and puts every cell's threshold at the
  packaged ``v_threshold_v`` plus the mean of its half-normal excess (an assumption, stated
  in the twin's sources); at the learning pulse the response is the measured one, at other
  amplitudes it is the packaged power law's extrapolation;
* cells that were not measured (the rest of the 32x8 array) are drawn from the measured
  population: the chip-level values are the geometric means of the measured cells' devices,
  the device-to-device sigmas their standard deviations in ln (:class:`~.config.ArrayConfig`);
  measured cells without a usable fit are stuck cells, and the stuck fraction is theirs;
* cycle-to-cycle: the dose factor's log-normal sigma is set so that one step's relative std at
  the reference conductance equals the model's ``dw_min_std`` with the packaged random-walk
  term (``var = exp(sigma^2) - 1 + hop^2 / |Δs|``);
* read noise: the model's ``read_noise`` is what the host saw per read; a board averages
  ``read_draws`` conversions per read (each its own draw of the chip's read noise), so the
  chip's per-draw relative sigma is ``read_noise * sqrt(read_draws)`` (the caller knows its
  board: :mod:`snan_hil.firmware_emu` passes its ADC averages);
* wear and drift: the model's :class:`~.fitted.AgingTerm` (fitted where the data showed it,
  else the packaged assumption) becomes the config's ``wear`` and ``drift`` sections.

Everything else (transistor, breakdown, initial states, stuck conductances) is the packaged
device's (:meth:`ArrayConfig.default`), an assumption the twin's ``sources`` name.

The round trip is the check that the inversion is right: characterise the twin on the emulated
board, fit again, and the parameters come back (tests/crossbar/test_device_twin.py;
docs/crossbar_model.md §7).
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from snan_hil.common.errors import UserError
from snan_hil.common.polarity import Polarity
from snan_hil.crossbar_model.array import CrossbarArray
from snan_hil.crossbar_model.config import ArrayConfig
from snan_hil.crossbar_model.fitted import MODEL_FORMAT, AgingTerm, CellFit, DeviceModel

__all__ = ["TWIN_FORMAT", "TwinCell", "TwinSpec", "twin_spec", "physical_step",
           "load_device_model", "model_digest", "spec_from_mapping"]

TWIN_FORMAT = "snan-hil-twin/1"

_HALF_NORMAL_MEAN = math.sqrt(2.0 / math.pi)     # E|xi| of a standard normal


@dataclass(frozen=True)
class TwinCell:
    """The physical device of one measured cell (memristor bounds in S, rates in 1/s,
    thresholds in V); ``misfit_up`` / ``misfit_down``: RMS of (physical - fitted) step over
    the measured range, relative to the mean fitted step (how well the physics takes the
    fitted curve)."""

    row: int
    col: int
    g_min_s: float
    g_max_s: float
    rate_set: float
    rate_reset: float
    vth_set: float
    vth_reset: float
    misfit_up: float = 0.0
    misfit_down: float = 0.0


@dataclass(frozen=True)
class TwinSpec:
    """Everything that makes the twin chip: the array config (the population), the measured
    cells' own devices, the measured cells that are stuck, where it came from and the source
    of every value (``sources``: dotted config key -> ``"fitted: ..."`` or
    ``"assumption: ..."``)."""

    config: ArrayConfig
    cells: tuple[TwinCell, ...]
    stuck: tuple[tuple[int, int], ...] = ()
    digest: str = ""
    sources: dict[str, str] = field(default_factory=dict)

    def build(self, seed: int = 0) -> CrossbarArray:
        """The twin chip: a :class:`CrossbarArray` of :attr:`config` from ``seed`` (its
        unmeasured cells, initial states, stuck cells and noise streams), with every measured
        cell's own device put in its place and the measured stuck cells stuck. Cells outside
        the array are left out (they still shaped the population)."""
        arr = CrossbarArray(self.config, seed=seed)
        p = arr.cells
        inside = [c for c in self.cells if 0 <= c.row < arr.rows and 0 <= c.col < arr.cols]
        for c in inside:
            r, k = c.row, c.col
            p.g_min[r, k], p.g_max[r, k] = c.g_min_s, c.g_max_s
            p.rate_set[r, k], p.rate_reset[r, k] = c.rate_set, c.rate_reset
            p.vth_set[r, k], p.vth_reset[r, k] = c.vth_set, c.vth_reset
            arr.stuck_mask[r, k] = arr.stuck_high[r, k] = False      # a measured good cell
        for r, k in self.stuck:
            if 0 <= r < arr.rows and 0 <= k < arr.cols:
                arr.stuck_mask[r, k] = True
        arr.stuck_high &= arr.stuck_mask
        arr._setup()                       # bounds, caches from the cells put in place
        return arr

    def to_dict(self) -> dict[str, Any]:
        return {"format": TWIN_FORMAT, "digest": self.digest, "config": self.config.to_dict(),
                "cells": [asdict(c) for c in self.cells], "stuck": [list(s) for s in self.stuck],
                "sources": dict(self.sources)}


def model_digest(model: DeviceModel) -> str:
    """SHA-256 (hex) of the model's stored form: names the twin of one model."""
    text = json.dumps(model.to_dict(), sort_keys=True, allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()


def load_device_model(path: str | Path) -> DeviceModel:
    """Read a device model JSON (``snan-hil characterize --model``); UserError (one line)
    when the file is missing, not JSON or not a device model."""
    p = Path(path).expanduser()
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise UserError(f"device model {p} does not exist; write one with 'snan-hil "
                        "characterize --model FILE' (or --from a pulse CSV)") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise UserError(f"cannot read device model {p}: {getattr(exc, 'strerror', None) or exc}"
                        ) from None
    except ValueError as exc:
        raise UserError(f"device model {p} is not JSON ({exc}); give a file written by "
                        "'snan-hil characterize --model'") from None
    if not isinstance(data, dict):
        raise UserError(f"device model {p} is not a JSON object ({MODEL_FORMAT})")
    try:
        return DeviceModel.from_dict(data)
    except ValueError as exc:
        raise UserError(f"device model {p}: {exc}") from None


# ---- the physics of one branch, vectorised --------------------------------------------------
def physical_step(g_cell_s: np.ndarray, polarity: Polarity, *, bound_s: float, rate: float,
                  vth: float, exponent: float, amplitude_v: float, width_s: float,
                  config: ArrayConfig, substeps: int | None = None) -> np.ndarray:
    """Noise-free Δ ln G of one pulse on cells at cell conductances ``g_cell_s`` (S, any
    shape; memristor + select transistor, as the read chain gives them), for a device with
    soft bound ``bound_s`` (memristor S: ``g_max`` for SET, ``g_min`` for RESET), ``rate``
    (1/s), threshold ``vth`` (V), ``exponent``; same shape.

    The integration of :func:`.device.pulse_response` (the soft bound exact in
    ``v = -ln((x_b - x)/(x_b - x_0))``, the divider by 4th-order Runge-Kutta), vectorised:
    with ``substeps`` None the sub-step dose is at most the config's ``max_substep_dose`` of
    the nominal dose, as there (agreement < 1e-9 in Δ ln G, tests/crossbar/test_device_twin.py)."""
    t = config.transistor
    r_t = t.on_resistance_ohm
    r_series = r_t + t.write_series_ohm
    i_sat = t.saturation_current_a
    gc = np.asarray(g_cell_s, dtype=float)
    g0 = gc / (1.0 - gc * r_t)                     # memristor conductance
    x0 = np.log(g0)
    xb = math.log(bound_s)
    up = polarity == Polarity.SET
    if amplitude_v <= vth or width_s <= 0:
        return np.zeros_like(gc)
    if substeps is None:
        nominal = rate * (amplitude_v - vth) ** exponent * width_s
        substeps = int(min(4096, max(1, math.ceil(nominal / config.switching.max_substep_dose))))
    span = xb - x0 if up else x0 - xb              # > 0 inside the bound

    def x_of(v: np.ndarray) -> np.ndarray:
        return xb - span * np.exp(-v) if up else xb + span * np.exp(-v)

    def nu(v: np.ndarray) -> np.ndarray:
        g = np.exp(x_of(v))
        i = np.minimum(amplitude_v / (1.0 / g + r_series), i_sat)
        over = np.maximum(i / g - vth, 0.0)
        return rate * over ** exponent

    v = np.zeros_like(x0)
    dt = width_s / substeps
    for _ in range(substeps):
        k1 = nu(v)
        k2 = nu(v + 0.5 * dt * k1)
        k3 = nu(v + 0.5 * dt * k2)
        k4 = nu(v + dt * k3)
        v = v + dt * (k1 + 2.0 * k2 + 2.0 * k3 + k4) / 6.0
    g1 = np.exp(x_of(v))
    out = np.log(g1 / (1.0 + g1 * r_t)) - np.log(gc)
    return np.where(span > 0, out, 0.0)


def _fit_branch(fit: CellFit, polarity: Polarity, grid: np.ndarray, *, vth: float,
                exponent: float, amplitude_v: float, width_s: float, config: ArrayConfig,
                rate0: float) -> tuple[float, float, float]:
    """(bound_s, rate, misfit) of one branch of one cell (module doc)."""
    from scipy.optimize import least_squares

    target = np.asarray(fit.mean_dx(polarity, grid), dtype=float)
    r_t = config.transistor.on_resistance_ohm
    up = polarity == Polarity.SET
    gb_cell = math.exp(fit.x_max if up else fit.x_min)
    gb0 = gb_cell / (1.0 - gb_cell * r_t) if gb_cell * r_t < 0.9 else 10.0 / r_t
    lo_x = math.log(grid.max() / (1.0 - grid.max() * r_t)) if up else math.log(gb0) - 3.0
    hi_x = math.log(gb0) + 3.0 if up else math.log(grid.min() / (1.0 - grid.min() * r_t))
    x0 = min(max(math.log(gb0), lo_x + 1e-3), hi_x - 1e-3)

    def resid(p: np.ndarray) -> np.ndarray:
        return physical_step(grid, polarity, bound_s=math.exp(p[0]), rate=math.exp(p[1]),
                             vth=vth, exponent=exponent, amplitude_v=amplitude_v,
                             width_s=width_s, config=config, substeps=8) - target

    res = least_squares(resid, [x0, math.log(rate0)], bounds=([lo_x, -5.0], [hi_x, 25.0]),
                        x_scale=[0.1, 0.3])
    scale = float(np.mean(np.abs(target))) or 1.0
    misfit = float(np.sqrt(np.mean(res.fun ** 2)) / scale)
    return math.exp(float(res.x[0])), math.exp(float(res.x[1])), misfit


def _measured_range(model: DeviceModel) -> tuple[float, float]:
    """(low, high) cell conductance (S) the model's data covered: the characterisation's
    sweep, else the data's range, else the model's own bounds."""
    meta = model.meta or {}
    sweep = meta.get("sweep") or {}
    for lo, hi in ((sweep.get("g_low_s"), sweep.get("g_high_s")),
                   tuple(meta.get("g_range_s") or (None, None))):
        if lo and hi and 0 < float(lo) < float(hi):
            return float(lo), float(hi)
    return model.g_min_s * 1.1, model.g_max_s * 0.95


def _cells(model: DeviceModel, base: ArrayConfig, grid: np.ndarray, vth: float
           ) -> list[TwinCell]:
    p = model.pulse
    sw = base.switching
    width = p.width_us * 1e-6
    out = []
    for f in model.cells:
        if not f.ok:
            continue
        g_max, r_set, m_up = _fit_branch(
            f, Polarity.SET, grid, vth=vth, exponent=sw.set_exponent, amplitude_v=p.set_v,
            width_s=width, config=base, rate0=sw.set_rate_per_s)
        g_min, r_reset, m_down = _fit_branch(
            f, Polarity.RESET, grid, vth=vth, exponent=sw.reset_exponent,
            amplitude_v=p.reset_v, width_s=width, config=base, rate0=sw.reset_rate_per_s)
        if not g_min < g_max:
            continue
        out.append(TwinCell(f.row, f.col, g_min, g_max, r_set, r_reset, vth, vth, m_up, m_down))
    return out


def _hop_share(base: ArrayConfig, cells: Sequence[TwinCell], model: DeviceModel) -> float:
    """hop^2 / |Δs| at the reference conductance for the median measured device: the part of
    one step's relative variance the random-walk term gives."""
    hop = base.programming_noise.hop_sigma
    if hop == 0 or not cells:
        return 0.0
    g_min = float(np.exp(np.median([math.log(c.g_min_s) for c in cells])))
    g_max = float(np.exp(np.median([math.log(c.g_max_s) for c in cells])))
    ds = model.dw_min / math.log(g_max / g_min)        # one mean step in state units
    return hop * hop / max(ds, 1e-9)


def twin_spec(model: DeviceModel, *, base: ArrayConfig | None = None, read_draws: int = 1,
              digest: str | None = None) -> TwinSpec:
    """The physical chip of ``model`` (module doc). ``base``: the packaged device whose
    transistor, exponents, breakdown and initial states the twin keeps (default
    :meth:`ArrayConfig.default`); ``read_draws``: conversions the board averages per read.
    UserError (one line) when no cell of the model can be made physical."""
    base = base if base is not None else ArrayConfig.default()
    sw = base.switching
    var = base.variability
    vth = sw.v_threshold_v + var.threshold_sigma_v * _HALF_NORMAL_MEAN
    lo, hi = _measured_range(model)
    grid = np.geomspace(lo, hi, 32)
    cells = _cells(model, base, grid, vth)
    if not cells:
        raise UserError("the device model has no cell that gives a physical device (no usable "
                        "per-cell fit); characterise the chip again with more pulses per cell")
    ln = {k: np.log([getattr(c, k) for c in cells])
          for k in ("g_min_s", "g_max_s", "rate_set", "rate_reset")}

    def sd(a: np.ndarray) -> float:
        return float(a.std(ddof=1)) if a.size > 1 else 0.0

    rate_sigma = math.sqrt((sd(ln["rate_set"]) ** 2 + sd(ln["rate_reset"]) ** 2) / 2.0)
    g_min_s, g_max_s = float(np.exp(ln["g_min_s"].mean())), float(np.exp(ln["g_max_s"].mean()))
    usable_min, usable_max = base.conductance.usable_min_s, base.conductance.usable_max_s
    if not (g_min_s < usable_min and usable_max < g_max_s):
        # the packaged usable range does not fit this device's window: the middle 80 % of it
        span = math.log(g_max_s / g_min_s)
        usable_min = g_min_s * math.exp(0.1 * span)
        usable_max = g_max_s * math.exp(-0.1 * span)
    c2c = model.dw_min_std if math.isfinite(model.dw_min_std) else 0.0
    c2c_var = max(c2c * c2c - _hop_share(base, cells, model), 0.0)
    step_sigma = math.sqrt(math.log1p(c2c_var))
    read_sigma = (model.read_noise * math.sqrt(max(int(read_draws), 1))
                  if math.isfinite(model.read_noise) else base.read_noise.relative_sigma)
    measured = [f for f in model.cells]
    stuck = tuple((f.row, f.col) for f in measured if not f.ok)
    stuck_fraction = len(stuck) / len(measured) if measured else base.stuck.fraction
    overrides: dict[str, Any] = {
        "conductance.g_min_s": g_min_s, "conductance.g_max_s": g_max_s,
        "conductance.usable_min_s": usable_min, "conductance.usable_max_s": usable_max,
        "switching.set_rate_per_s": float(np.exp(ln["rate_set"].mean())),
        "switching.reset_rate_per_s": float(np.exp(ln["rate_reset"].mean())),
        "variability.g_min_sigma_log": sd(ln["g_min_s"]),
        "variability.g_max_sigma_log": sd(ln["g_max_s"]),
        "variability.rate_sigma_log": rate_sigma,
        "programming_noise.step_sigma_log": step_sigma,
        "read_noise.relative_sigma": read_sigma,
        "stuck.fraction": stuck_fraction,
    }
    sources = _sources(model, len(cells), read_draws)
    if model.aging is not None:
        overrides.update(_aging_overrides(model.aging, base, model, cells))
        sources.update({"wear": model.aging.wear_source, "drift": model.aging.drift_source})
    config = base.with_overrides(overrides)
    config = _renamed(config, model)
    return TwinSpec(config, tuple(cells), stuck, digest or model_digest(model), sources)


def _aging_overrides(aging: AgingTerm, base: ArrayConfig, model: DeviceModel,
                     cells: Sequence[TwinCell]) -> dict[str, Any]:
    """The config's ``wear`` and ``drift`` values of a fitted aging term (an assumed part
    keeps the packaged values). A model cycle is a swing of the model's window ``W`` in the
    cell's ln G; an emulator cycle a swing of the device state ``s`` (the memristor's window
    ``L``): one pulse's ``|Δs| = |Δx_cell| (1 + G R_T) / L``, so ``k = W (1 + G_ref R_T) / L``
    emulator cycles per model cycle at the reference (memristor conductance, median cell)."""
    out: dict[str, Any] = {}
    if aging.wear_fitted and aging.window_loss_per_cycle > 0:
        r_t = base.transistor.on_resistance_ohm
        g_mem = model.g_ref_s / (1.0 - model.g_ref_s * r_t)
        big_l = float(np.median([math.log(c.g_max_s / c.g_min_s) for c in cells]))
        w = math.log(model.g_max_s / model.g_min_s)
        k = w * (1.0 + g_mem * r_t) / big_l
        out["wear.endurance_cycles"] = aging.endurance_cycles * k
        out["wear.window_closure"] = aging.window_closure
    if aging.drift_fitted:
        out["drift.nu_mean"] = max(aging.drift_nu, 0.0)
        out["drift.t0_s"] = aging.drift_t0_s
    return out


def _renamed(config: ArrayConfig, model: DeviceModel) -> ArrayConfig:
    from dataclasses import replace
    board = (model.meta or {}).get("board_id") or (model.meta or {}).get("source") or "a model"
    return replace(config, name=f"twin of {board}")


def _sources(model: DeviceModel, n_cells: int, read_draws: int) -> dict[str, str]:
    p = model.pulse
    at = f"SET {p.set_v:g} V / RESET {p.reset_v:g} V, {p.width_us} us"
    fitted = f"fitted: {n_cells} measured cells at {at}"
    return {
        "cells": f"{fitted}; each measured cell its own device (bound and rate per branch)",
        "conductance.g_min_s": f"{fitted}: geometric mean of the cells' RESET bounds",
        "conductance.g_max_s": f"{fitted}: geometric mean of the cells' SET bounds",
        "switching.set_rate_per_s": f"{fitted}: geometric mean of the cells' SET rates",
        "switching.reset_rate_per_s": f"{fitted}: geometric mean of the cells' RESET rates",
        "variability.g_min_sigma_log": f"{fitted}: std of ln of the cells' RESET bounds",
        "variability.g_max_sigma_log": f"{fitted}: std of ln of the cells' SET bounds",
        "variability.rate_sigma_log": f"{fitted}: std of ln of the cells' rates (both branches)",
        "programming_noise.step_sigma_log": "fitted: the model's dw_min_std with the packaged "
                                            "random-walk term",
        "read_noise.relative_sigma": f"fitted: the model's read_noise x sqrt({read_draws}) "
                                     "(the board averages that many draws per read)",
        "stuck.fraction": "fitted: the measured cells without a usable fit",
        "switching.v_threshold_v": "assumption: packaged; one amplitude cannot separate the "
                                   "threshold from the rate (every cell at the packaged "
                                   "threshold plus its mean excess)",
        "switching.set_exponent": "assumption: packaged (one amplitude measured)",
        "switching.reset_exponent": "assumption: packaged (one amplitude measured)",
        "transistor": "assumption: packaged (the board's 1T1R stack)",
        "breakdown": "assumption: packaged",
        "initial_state": "assumption: packaged",
        "wear": "assumption: packaged (the model has no aging term)",
        "drift": "assumption: packaged (the model has no aging term)",
    }


def spec_from_mapping(data: Mapping[str, Any]) -> TwinSpec:
    """Inverse of :meth:`TwinSpec.to_dict`; ValueError for another format."""
    if data.get("format") != TWIN_FORMAT:
        raise ValueError(f"not a twin ({TWIN_FORMAT}): format {data.get('format')!r}")
    return TwinSpec(ArrayConfig.from_dict(dict(data["config"])),
                    tuple(TwinCell(**c) for c in data.get("cells", [])),
                    tuple((int(r), int(c)) for r, c in data.get("stuck", [])),
                    str(data.get("digest", "")), dict(data.get("sources", {})))
