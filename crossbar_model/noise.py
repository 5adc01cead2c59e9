"""The three separate error models of the array (as CrossSim and aihwkit separate them).

* Programming (cycle-to-cycle) error — each pulse's switching dose is multiplied by a log-normal
  factor ``exp(sigma_log * xi - sigma_log**2 / 2)`` (mean 1), and the resulting state step gets a
  random-walk term ``hop_sigma * sqrt(|ds|) * xi'`` (many small ionic hops). Only pulses that
  switch (above threshold) are affected.
* Read noise — every read of a cell sees ``G_read = G * (1 + relative_sigma * xi) +
  absolute_sigma_s * xi'``, independent per read and per cell, never below 0.
* Drift — ``G(t) = G_prog * ((t - t_prog + t0) / t0) ** (-nu)``, ``nu ~ N(nu_mean, nu_sigma)`` per
  cell; zero by default (the paper's chip shows no relaxation over 10,000 reads).
"""

from __future__ import annotations

import math

import numpy as np

from snan_hil.crossbar_model.config import DriftConfig, ProgrammingNoiseConfig, ReadNoiseConfig


def programming_dose_factor(cfg: ProgrammingNoiseConfig, rng: np.random.Generator) -> float:
    """Log-normal multiplier (mean 1) of one pulse's switching dose."""
    if cfg.step_sigma_log == 0:
        return 1.0
    sig = cfg.step_sigma_log
    return math.exp(sig * float(rng.standard_normal()) - 0.5 * sig * sig)


def programming_hop(cfg: ProgrammingNoiseConfig, ds: float, rng: np.random.Generator) -> float:
    """Random-walk addition (state units) to a switching step ds; 0 when nothing switched."""
    if cfg.hop_sigma == 0 or ds == 0:
        return 0.0
    return cfg.hop_sigma * math.sqrt(abs(ds)) * float(rng.standard_normal())


def read_conductance(cfg: ReadNoiseConfig, g: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Noisy read of conductance(s) g (S); one independent sample per element."""
    if cfg.relative_sigma == 0 and cfg.absolute_sigma_s == 0:
        return g
    z = rng.standard_normal((2,) + np.shape(g))
    return np.maximum(g * (1.0 + cfg.relative_sigma * z[0]) + cfg.absolute_sigma_s * z[1], 0.0)


def read_conductance_scalar(cfg: ReadNoiseConfig, g: float, rng: np.random.Generator) -> float:
    """Noisy read of one conductance (S)."""
    if cfg.relative_sigma == 0 and cfg.absolute_sigma_s == 0:
        return g
    z0, z1 = rng.standard_normal(2)
    return max(g * (1.0 + cfg.relative_sigma * z0) + cfg.absolute_sigma_s * z1, 0.0)


def read_conductance_draws(cfg: ReadNoiseConfig, g: np.ndarray | float, n: int,
                           rng: np.random.Generator) -> np.ndarray:
    """``n`` independent noisy reads of conductance(s) g (S): shape ``(n,) + shape(g)``.

    Draws the same normals in the same order as ``n`` calls of :func:`read_conductance` (or of
    :func:`read_conductance_scalar` for a scalar g), and applies the same float operations, so
    the values are identical to those calls' results and the generator ends in the same state.
    """
    g = np.asarray(g, dtype=float)
    if cfg.relative_sigma == 0 and cfg.absolute_sigma_s == 0:
        return np.broadcast_to(g, (n,) + g.shape).copy()
    z = rng.standard_normal((n, 2) + g.shape)
    return np.maximum(g * (1.0 + cfg.relative_sigma * z[:, 0]) + cfg.absolute_sigma_s * z[:, 1], 0.0)


def sample_drift_nu(cfg: DriftConfig, shape: tuple[int, ...], rng: np.random.Generator) -> np.ndarray:
    """Per-cell drift exponents (>= 0)."""
    if cfg.nu_mean == 0 and cfg.nu_sigma == 0:
        return np.zeros(shape)
    return np.maximum(cfg.nu_mean + cfg.nu_sigma * rng.standard_normal(shape), 0.0)


def drift_factor(cfg: DriftConfig, nu: np.ndarray, elapsed_s: np.ndarray) -> np.ndarray:
    """Multiplier G(t)/G_prog after elapsed_s (s) since programming."""
    return ((np.maximum(elapsed_s, 0.0) + cfg.t0_s) / cfg.t0_s) ** (-nu)
