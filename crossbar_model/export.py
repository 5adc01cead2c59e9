"""A fitted device model in the forms the field's simulators read: an IBM aihwkit device
configuration and a CrossSim-style ΔG lookup table (``snan-hil export-device``).

**The weight of the exports.** Both simulators update a *weight* by pulses. The fitted model
lives in the log-conductance ``x = ln G`` of the whole cell (:mod:`.fitted`); the aihwkit
export maps it linearly onto a symmetric weight,

    w = (x - x_c) / s,   x_c = (x_max + x_min) / 2,   s = (x_max - x_min) / 2

(``x_max``, ``x_min`` the chip curve's bounds ``ln g_max_s``, ``ln g_min_s``), so ``w_min = -1``
and ``w_max = +1`` and a step of ``Δx`` is ``Δw = Δx / s``. The CrossSim table is in siemens
(CrossSim reads conductances and ΔG and scales them itself).

**aihwkit** (:func:`aihwkit_export`; aihwkit's ``PulsedDevice`` semantics: an up step is
``dw_min (1 + up_down)``, a down step ``dw_min (1 - up_down)``, both times ``1 + dw_min_std ξ``):

======================  =======================================================================
aihwkit field           from the model
======================  =======================================================================
``dw_min``              mean ``|Δx|`` of one pulse at ``x_c``, both directions, ``/ s``
``up_down``             ``(up - down) / (up + down)`` of the chip curve's steps at ``x_c``
``dw_min_dtod``         ``dw_min_dtod`` (relative, the same definition)
``up_down_dtod``        ``up_down_dtod`` (the std of the cells' ``up_down``: same definition)
``dw_min_std``          ``dw_min_std`` (relative cycle-to-cycle spread of one step, read noise
                        removed; aihwkit multiplies each step by ``1 + dw_min_std ξ``)
``w_min``, ``w_max``    ``-1``, ``+1`` (the chip curve's bounds)
``w_min_dtod``          ``g_min_dtod / s`` (aihwkit: relative to ``|w_min| = 1``)
``w_max_dtod``          ``g_max_dtod / s``
``piecewise_up/down``   ``PiecewiseStepDevice`` only: the chip curve's SET / RESET step at 21
                        equally spaced weights from ``w_min`` to ``w_max`` divided by the step
                        at ``x_c`` (so the curve's divider slopes and soft bounds are kept
                        exactly at the nodes, linear between)
forward ``w_noise``     ``read_noise / s``, ``w_noise_type = ADDITIVE_CONSTANT``: a read's noise
                        as weight noise of each forward pass (aihwkit ``IOParameters``)
``drift`` (``nu``,      the aging term's retention drift (``DriftParameter``: ``nu``,
``t_0``)                ``t_0``), where fitted; else none
======================  =======================================================================

Two devices are given: ``PiecewiseStepDevice`` (the whole curve) and ``SoftBoundsDevice``
(aihwkit's soft bounds, which takes the curve's bounds and its steps at ``x_c`` but not the
slopes). Not exported (aihwkit has no such term): the wear of the aging term (a window that
closes with use), the per-cell fits (aihwkit draws its own devices from the ``*_dtod``
spreads), the 1T1R divider at other amplitudes.

**CrossSim** (:func:`crosssim_tables`, :func:`write_crosssim`): CrossSim's ``DG_LOOKUP`` update
model reads two text files, ``dG_increasing.txt`` (SET) and ``dG_decreasing.txt`` (RESET):
line 1 a header, line 2 the conductances ``G`` (S, comma-separated, uniformly spaced: CrossSim's
fast interpolator needs it), line 3 the cumulative probabilities ``CDF`` (uniform, 0 to 1),
then one line per ``CDF`` value with the step ``ΔG`` (S) at each ``G``: the quantile of one
pulse's step. Here ``ΔG = G (exp(E[Δx](G) max(1 + dw_min_std Φ⁻¹(p), 0)) - 1)``, the chip
curve's cycle-to-cycle distribution (``p`` kept inside ``[0.5/n, 1 - 0.5/n]``), on 51
conductances from ``g_min_s`` to ``g_max_s`` and 101 CDF values. Device-to-device spread is
CrossSim's own setting (not in one table); read noise likewise (``read_noise`` in the JSON
beside the tables).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from snan_hil.common.polarity import Polarity
from snan_hil.crossbar_model.fitted import DeviceModel
from snan_hil.files.atomicio import atomic_write_json, atomic_write_text

__all__ = ["AIHWKIT_FORMAT", "CROSSSIM_FORMAT", "aihwkit_export", "weight_scale",
           "crosssim_tables", "write_crosssim", "read_crosssim_table"]

AIHWKIT_FORMAT = "snan-hil-aihwkit/1"
CROSSSIM_FORMAT = "snan-hil-crosssim/1"
PIECEWISE_NODES = 21
CROSSSIM_FILES = {Polarity.SET: "dG_increasing.txt", Polarity.RESET: "dG_decreasing.txt"}


def weight_scale(model: DeviceModel) -> tuple[float, float]:
    """``(x_c, s)`` of the aihwkit weight ``w = (ln G - x_c) / s`` (module doc)."""
    return (model.x_max + model.x_min) / 2.0, (model.x_max - model.x_min) / 2.0


def _finite(v: float, default: float = 0.0) -> float:
    return float(v) if math.isfinite(v) else default


def aihwkit_export(model: DeviceModel, nodes: int = PIECEWISE_NODES) -> dict[str, Any]:
    """The aihwkit device configuration of ``model`` (module doc): a JSON-able dict with the
    two devices' class names and keyword arguments, the forward noise, the drift, the weight
    map and the mapping of every field."""
    x_c, s = weight_scale(model)
    g_c = math.exp(x_c)
    up_c = float(model.mean_dx(Polarity.SET, g_c))
    down_c = -float(model.mean_dx(Polarity.RESET, g_c))
    dw_min = (up_c + down_c) / 2.0 / s
    up_down = (up_c - down_c) / (up_c + down_c)
    w = np.linspace(-1.0, 1.0, nodes)
    g = np.exp(x_c + s * w)
    piece_up = np.asarray(model.mean_dx(Polarity.SET, g)) / up_c
    piece_down = -np.asarray(model.mean_dx(Polarity.RESET, g)) / down_c
    common = {"dw_min": dw_min, "up_down": up_down,
              "dw_min_dtod": _finite(model.dw_min_dtod), "up_down_dtod": _finite(model.up_down_dtod),
              "dw_min_std": _finite(model.dw_min_std), "w_min": -1.0, "w_max": 1.0,
              "w_min_dtod": _finite(model.g_min_dtod) / s,
              "w_max_dtod": _finite(model.g_max_dtod) / s}
    doc: dict[str, Any] = {
        "format": AIHWKIT_FORMAT,
        "device": {"class": "PiecewiseStepDevice",
                   "parameters": {**common, "piecewise_up": [float(v) for v in piece_up],
                                  "piecewise_down": [float(v) for v in piece_down]}},
        "soft_bounds_device": {"class": "SoftBoundsDevice", "parameters": dict(common)},
        "forward": {"w_noise": _finite(model.read_noise) / s,
                    "w_noise_type": "ADDITIVE_CONSTANT"},
        "drift": None,
        "weight_map": {"formula": "w = (ln G - x_c) / s, G the cell conductance in S",
                       "x_c": x_c, "s": s, "g_min_s": model.g_min_s, "g_max_s": model.g_max_s,
                       "g_center_s": g_c},
        "pulse": model.pulse.to_dict(),
        "not_exported": {
            "wear": (model.aging.wear_source if model.aging is not None else "no aging term"),
            "per_cell_fits": f"{sum(1 for c in model.cells if c.ok)} cells (aihwkit draws its "
                             "devices from the *_dtod spreads)",
            "amplitude_dependence": "one learning pulse measured"},
        "mapping": MAPPING,
    }
    if model.aging is not None and model.aging.drift_fitted:
        doc["drift"] = {"class": "DriftParameter", "parameters": {
            "nu": model.aging.drift_nu, "t_0": model.aging.drift_t0_s}}
    return doc


MAPPING = {
    "dw_min": "mean |d ln G| of one pulse at x_c (both directions) / s",
    "up_down": "(up - down) / (up + down) of the chip curve's steps at x_c",
    "dw_min_dtod": "the model's dw_min_dtod (relative spread of a cell's mean step)",
    "up_down_dtod": "the model's up_down_dtod (std of the cells' up_down)",
    "dw_min_std": "the model's dw_min_std (relative cycle-to-cycle spread of one step)",
    "w_min / w_max": "-1 / +1: ln g_min_s / ln g_max_s of the chip curve",
    "w_min_dtod / w_max_dtod": "g_min_dtod / s, g_max_dtod / s (std of ln bounds, relative "
                               "to |w| = 1)",
    "piecewise_up / piecewise_down": "chip curve's SET / RESET step at 21 equally spaced "
                                     "weights, relative to its step at x_c",
    "forward.w_noise": "read_noise / s (ADDITIVE_CONSTANT weight noise per forward pass)",
    "drift": "aging term's nu and t_0 (DriftParameter) where fitted",
}


# ---- CrossSim ------------------------------------------------------------------------------
def crosssim_tables(model: DeviceModel, g_points: int = 51, cdf_points: int = 101
                    ) -> dict[Polarity, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per polarity ``(G (S, shape (g_points,)), CDF (shape (cdf_points,)), ΔG (S, shape
    (cdf_points, g_points)))`` (module doc)."""
    from scipy.stats import norm

    g = np.linspace(model.g_min_s, model.g_max_s, g_points)
    cdf = np.linspace(0.0, 1.0, cdf_points)
    p = np.clip(cdf, 0.5 / cdf_points, 1.0 - 0.5 / cdf_points)
    factor = np.maximum(1.0 + _finite(model.dw_min_std) * norm.ppf(p), 0.0)
    out = {}
    for pol in (Polarity.SET, Polarity.RESET):
        mean = np.asarray(model.mean_dx(pol, g), dtype=float)
        dg = g[None, :] * np.expm1(mean[None, :] * factor[:, None])
        out[pol] = (g, cdf, dg)
    return out


def write_crosssim(model: DeviceModel, folder: str | Path) -> list[Path]:
    """Write ``dG_increasing.txt``, ``dG_decreasing.txt`` and ``lookup.json`` (format, pulse,
    read noise, what the tables hold) into ``folder`` (made if missing); the paths written."""
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for pol, (g, cdf, dg) in crosssim_tables(model).items():
        direction = "increasing (SET)" if pol == Polarity.SET else "decreasing (RESET)"
        lines = [f"snan-hil device model {direction}: line 2 G (S), line 3 CDF, then dG (S) "
                 "per CDF row and G column",
                 ",".join(f"{v:.9g}" for v in g), ",".join(f"{v:.9g}" for v in cdf)]
        lines += [",".join(f"{v:.9g}" for v in row) for row in dg]
        path = out / CROSSSIM_FILES[pol]
        atomic_write_text(path, "\n".join(lines) + "\n")
        written.append(path)
    meta = {"format": CROSSSIM_FORMAT, "pulse": model.pulse.to_dict(),
            "files": {"increasing": CROSSSIM_FILES[Polarity.SET],
                      "decreasing": CROSSSIM_FILES[Polarity.RESET]},
            "read_noise": _finite(model.read_noise), "dw_min_dtod": _finite(model.dw_min_dtod),
            "g_min_dtod": _finite(model.g_min_dtod), "g_max_dtod": _finite(model.g_max_dtod),
            "note": "the chip curve with its cycle-to-cycle spread; device-to-device spread "
                    "and read noise are CrossSim settings (values here)"}
    path = out / "lookup.json"
    atomic_write_json(path, meta, indent=1)
    written.append(path)
    return written


def read_crosssim_table(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(G, CDF, ΔG)`` of a table file, read as CrossSim reads it (line 2, line 3, the rest;
    comma-separated). ValueError when the shapes do not agree."""
    text = Path(path).read_text(encoding="utf-8").splitlines()
    g = np.array([float(v) for v in text[1].split(",")])
    cdf = np.array([float(v) for v in text[2].split(",")])
    dg = np.array([[float(v) for v in line.split(",")] for line in text[3:] if line.strip()])
    if dg.shape != (cdf.size, g.size):
        raise ValueError(f"{path}: dG is {dg.shape}, not (len CDF {cdf.size}, len G {g.size})")
    return g, cdf, dg
