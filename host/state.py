"""State of one SNAN network that carries across decision windows (one array per quantity).

Everything is indexed by cell (input neuron i, interneuron i, astrocyte i and motor neuron i
belong to grid cell i). Weights are stored per cell and direction, ``w[i, d]`` = synapse
from input neuron ``i`` to the motor neuron of its neighbour in direction ``d`` (up, down,
left, right; see :mod:`snan_hil.host.grid`); entries without a neighbour are 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from snan_hil.host.config import SnanConfig


@dataclass
class NetworkState:
    """Membrane potentials, refractory counters (in steps), glutamate G, calcium Ca and its
    rate y, and the time of the last astrocyte update per cell (kernel bookkeeping, steps)."""

    v_mot: np.ndarray
    ref_mot: np.ndarray
    v_int: np.ndarray
    ref_int: np.ndarray
    g: np.ndarray
    ca: np.ndarray
    y: np.ndarray
    t_astro: np.ndarray
    t_now: int = 0

    @classmethod
    def fresh(cls, cfg: SnanConfig) -> "NetworkState":
        n = cfg.n_cells
        v0 = cfg.neuron.v_rest
        return cls(v_mot=np.full(n, v0), ref_mot=np.zeros(n, dtype=np.int64),
                   v_int=np.full(n, v0), ref_int=np.zeros(n, dtype=np.int64),
                   g=np.zeros(n), ca=np.zeros(n), y=np.zeros(n),
                   t_astro=np.zeros(n, dtype=np.int64), t_now=0)

    def copy(self) -> "NetworkState":
        arrays = {f: getattr(self, f).copy() for f in
                  ("v_mot", "ref_mot", "v_int", "ref_int", "g", "ca", "y", "t_astro")}
        return NetworkState(**arrays, t_now=self.t_now)


def initial_weights(cfg: SnanConfig, neighbours: np.ndarray,
                    rng: np.random.Generator) -> np.ndarray:
    """Draw input->motor weights N(w_mean, w_std), clipped (or redrawn, ``init=truncate``)
    to [w_lo, w_hi]; shape [n_cells, 4], zero where ``neighbours`` is -1.

    Always draws 4 values per cell (also for missing neighbours) so the stream does not
    depend on the grid's walls.
    """
    s = cfg.synapse
    w = rng.normal(s.w_mean, s.w_std, size=neighbours.shape)
    if s.init == "truncate":
        bad = (w < s.w_lo) | (w > s.w_hi)
        while bad.any():
            w[bad] = rng.normal(s.w_mean, s.w_std, size=int(bad.sum()))
            bad = (w < s.w_lo) | (w > s.w_hi)
    else:
        w = np.clip(w, s.w_lo, s.w_hi)
    w[neighbours < 0] = 0.0
    return w
