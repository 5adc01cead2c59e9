"""How the agent's input->motor synapses learn: the plasticity options of the trial kernel
(:class:`Plasticity`) and the memristive rule built from the VTEAM device
(:class:`VteamRule`, :func:`vteam_rule`).

The kernel's parameters (:func:`snan_hil.host.kernel_params.kernel_params`) and the
experiments' trials (:mod:`snan_hil.host.experiments.trials`) both read this module; the device
lookup is :mod:`snan_hil.crossbar_model.vteam_stdp`.
"""

from __future__ import annotations

import functools
from dataclasses import asdict, dataclass
from typing import Any, Literal, NamedTuple

import numpy as np

from snan_hil.common.errors import UserError
from snan_hil.crossbar_model.vteam import VTEAMParams
from snan_hil.crossbar_model.vteam_stdp import BiTriangularSpike, StdpLookup, default_stdp_lookup
from snan_hil.host import snan_kernel as K
from snan_hil.host.config import SnanConfig

PLASTICITY_RULES = ("additive", "vteam")


class VteamRule(NamedTuple):
    """The VTEAM device lookup as a plasticity rule (see :class:`Plasticity`):
    ``lut[w_index, dt_index]`` on w = 0..1 in equal steps and dt = ``dt0_ms`` +
    ``dtstep_ms`` * j; a pair's delay is ``(t_post - t_pre) * dt + latency_ms``."""

    lut: np.ndarray
    dt0_ms: float
    dtstep_ms: float
    latency_ms: float = 1.0


@dataclass(frozen=True)
class Plasticity:
    """How the input->motor synapses learn (options of :mod:`snan_hil.host.snan_kernel`).

    ``rule``: ``additive`` (the agent's pair-based STDP, Eq. 2) or ``vteam`` (the VTEAM
    device lookup of :mod:`snan_hil.crossbar_model.vteam_stdp`, built from the config's
    ``vteam`` section — spike, orientation, weight mapping, bounds — and scaled so that its
    largest potentiation per spike pair at w = 0.5 equals ``vteam_peak``, default
    ``vteam.peak`` or else ``stdp.a_plus``; a pair's delay is ``(t_post - t_pre) * dt +
    latency_ms``; ``vteam_depression``: None keeps the balance of ``vteam.balance`` (0: the
    device's own depression/potentiation ratio), a number rescales the depression branch
    (dt < 0) alone so that its largest change at w = 0.5 is ``-vteam_depression``).
    ``rule``/``latency_ms`` None: the config's ``stdp.rule`` / ``vteam.latency_ms``.
    ``target``: which synapses a window's change goes to (``all`` | ``chosen`` |
    ``depress_others`` | ``normalize``).
    """

    rule: Literal["additive", "vteam"] | None = None
    #: None = the config's ``stdp.target`` (if the agent has that option), else ``all``
    target: Literal["all", "chosen", "depress_others", "normalize"] | None = None
    vteam_peak: float | None = None
    vteam_depression: float | None = None
    latency_ms: float | None = None

    def __post_init__(self) -> None:
        if self.rule is not None and self.rule not in PLASTICITY_RULES:
            raise UserError(f"unknown plasticity {self.rule!r} ({', '.join(PLASTICITY_RULES)})")
        if self.target is not None and self.target not in K.TARGET_CODES:
            raise UserError(f"unknown plasticity target {self.target!r} "
                            f"({', '.join(K.TARGET_CODES)})")
        for name in ("vteam_peak", "vteam_depression"):
            v = getattr(self, name)
            if v is not None and not v > 0:
                raise UserError(f"{name} must be > 0, got {v}")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@functools.lru_cache(maxsize=32)
def _device_lookup(spike: tuple[float, ...], orientation: int, mapping: str, bounds: str):
    """The unscaled VTEAM STDP lookup of one reading (cached per process)."""
    return StdpLookup.build(BiTriangularSpike(*spike), VTEAMParams.paper(bounds),
                            orientation=orientation, mapping=mapping)


def _spike_of(cfg: SnanConfig) -> tuple[float, ...]:
    v = cfg.vteam
    return (v.spike_a_pos_v, v.spike_t_pos_ms, v.spike_a_neg_v, v.spike_t_neg_peak_ms,
            v.spike_t_neg_ms)


@functools.lru_cache(maxsize=32)
def vteam_lookup(peak: float, depression: float | None = None,
                 reading: tuple | None = None):
    """The VTEAM STDP lookup scaled so its largest potentiation at w = 0.5 is ``peak``; with
    ``depression``, the depression branch (the side of dt whose changes at w = 0.5 go most
    negative: dt < 0 for the default orientation, dt > 0 mirrored) is rescaled on its own so
    its largest depression at w = 0.5 is ``-depression`` (a window without depression is left
    as it is) (cached per process). ``reading``: (spike tuple, orientation,
    mapping, bounds) of the config's ``vteam`` section (None: the defaults). Returns
    (lookup, potentiation gain, depression gain)."""
    base = default_stdp_lookup() if reading is None else _device_lookup(*reading)
    look = base.normalized_to(peak)
    dep_gain = look.gain
    if depression is not None:
        row = look.delta_w(np.full(look.dt_grid_ms.size, 0.5), look.dt_grid_ms)
        below, above = look.dt_grid_ms < 0, look.dt_grid_ms > 0
        neg = below if row[below].min(initial=0.0) <= row[above].min(initial=0.0) else above
        lowest = float(row[neg].min(initial=0.0))
        factor = depression / -lowest if lowest < 0 else 1.0
        table = look.table.copy()
        table[:, neg] *= factor
        dep_gain = look.gain * factor
        look = StdpLookup(look.w_grid, look.dt_grid_ms, table, look.gain, dict(look.meta))
    return look, float(look.gain), float(dep_gain)


def vteam_rule(cfg: SnanConfig, plasticity: Plasticity = Plasticity()
               ) -> tuple[VteamRule, tuple[float, float]]:
    """The VTEAM plasticity rule of ``cfg``'s ``vteam`` section (explicit ``plasticity``
    values win) and its (potentiation, depression) gains against the device."""
    v = cfg.vteam
    peak = float(plasticity.vteam_peak or v.peak or cfg.stdp.a_plus)
    depression = plasticity.vteam_depression
    if depression is None and v.balance > 0:
        depression = v.balance * peak
    look, g_pot, g_dep = vteam_lookup(peak, depression,
                                      (_spike_of(cfg), int(v.orientation), v.mapping, v.bounds))
    latency = plasticity.latency_ms if plasticity.latency_ms is not None else v.latency_ms
    rule = VteamRule(np.ascontiguousarray(look.table, dtype=np.float64),
                     float(look.dt_grid_ms[0]), float(look.dt_grid_ms[1] - look.dt_grid_ms[0]),
                     float(latency))
    return rule, (g_pot, g_dep)
