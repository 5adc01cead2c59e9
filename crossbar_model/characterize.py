"""Characterisation helpers: the mean pulse response of a chip model (for docs, bench, calibration)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from snan_hil.crossbar_model.array import CrossbarArray
from snan_hil.crossbar_model.config import ArrayConfig
from snan_hil.crossbar_model.device import POLARITIES
from snan_hil.polarity import Polarity


@dataclass(frozen=True)
class StepStats:
    """Relative conductance change G_after/G_before - 1 of one pulse, over many cells."""

    polarity: Polarity
    amplitude_v: float
    width_s: float
    mean: float
    std: float
    n: int


def pulse_steps(config: ArrayConfig | None = None, amplitudes: tuple[float, ...] = (0.4, 0.5, 0.8, 1.1, 1.4),
                width_s: float = 100e-6, start_g: float | None = None, repeats: int = 4,
                seed: int = 0) -> list[StepStats]:
    """Mean and spread of the step of a single pulse from ``start_g`` (S; default: the geometric
    middle of the usable range), over every non-stuck cell of a fresh chip, ``repeats`` times.
    Includes device-to-device and cycle-to-cycle variability (no read noise: true conductance)."""
    cfg = config if config is not None else ArrayConfig.default()
    lo, hi = cfg.conductance.usable_min_s, cfg.conductance.usable_max_s
    g0 = start_g if start_g is not None else math.sqrt(lo * hi)
    arr = CrossbarArray(cfg, seed=seed)
    cells = [(r, c) for r in range(arr.rows) for c in range(arr.cols) if not arr.stuck_mask[r, c]]
    out = []
    for polarity in POLARITIES:
        for amp in amplitudes:
            rel = []
            for _ in range(repeats):
                for r, c in cells:
                    arr.set_conductance(r, c, g0)
                    before = arr.conductance()[r, c]
                    arr.apply_pulse(r, c, amp, polarity, width_s)
                    rel.append(arr.conductance()[r, c] / before - 1.0)
            out.append(StepStats(polarity, amp, width_s, float(np.mean(rel)), float(np.std(rel)), len(rel)))
    return out
