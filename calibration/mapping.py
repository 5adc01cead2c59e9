"""Linear map between a synaptic weight in [0, 1] and a target cell conductance (S).

``G = G_min + w (G_max - G_min)`` and back. Conductances are those of the whole 1T1R cell
(memristor in series with its select transistor), i.e. what the board's read chain measures and
what a column read sums (see :mod:`snan_hil.calibration.readchain`).

Defaults: ``G_min = 50 uS`` (20 kOhm), ``G_max = 1 mS`` (1 kOhm) — the usable range of the YSZ
cells (docs/crossbar_model.md): weight 0.65, the paper's mean weight, maps to 667 uS = 1.5 kOhm,
the paper's mean synapse resistance. Both ends are options of ``program-weights``; the chosen
pair is stored in the layout file so ``read-weights`` and ``run`` invert the same map.
"""

from __future__ import annotations

from typing import Any

from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import ArrayLike

from snan_hil.common.errors import UserError

__all__ = ["WeightMap", "DEFAULT_G_MIN_S", "DEFAULT_G_MAX_S"]

DEFAULT_G_MIN_S = 50e-6
DEFAULT_G_MAX_S = 1e-3


@dataclass(frozen=True)
class WeightMap:
    """Weight <-> cell conductance (S), linear between ``g_min_s`` (w = 0) and ``g_max_s``
    (w = 1)."""

    g_min_s: float = DEFAULT_G_MIN_S
    g_max_s: float = DEFAULT_G_MAX_S

    def __post_init__(self) -> None:
        if not (np.isfinite(self.g_min_s) and np.isfinite(self.g_max_s)
                and 0.0 < self.g_min_s < self.g_max_s):
            raise UserError(f"conductance range must satisfy 0 < G_min < G_max, got "
                            f"G_min = {self.g_min_s * 1e6:g} uS, G_max = {self.g_max_s * 1e6:g} uS")

    @property
    def span_s(self) -> float:
        return self.g_max_s - self.g_min_s

    def conductance(self, weight: ArrayLike) -> Any:
        """Target conductance (S) of ``weight`` (scalar or array; clipped to [0, 1]): a float
        for a scalar, a float64 array of the same shape for an array."""
        w = np.clip(np.asarray(weight, dtype=float), 0.0, 1.0)
        g = self.g_min_s + w * self.span_s
        return float(g) if g.ndim == 0 else g

    def weight(self, conductance_s: ArrayLike, clip: bool = True) -> Any:
        """Weight of a conductance (S; scalar or array, a float or float64 array as for
        :meth:`conductance`); ``clip`` limits it to [0, 1]."""
        w = (np.asarray(conductance_s, dtype=float) - self.g_min_s) / self.span_s
        if clip:
            w = np.clip(w, 0.0, 1.0)
        return float(w) if w.ndim == 0 else w

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "WeightMap":
        return cls(float(data["g_min_s"]), float(data["g_max_s"]))
