"""Configuration of the hardware-in-the-loop 6x6 task (paper "Hardware implementation").

``configs/hil-6x6.yaml`` does not repeat the SNAN model: it names a ``base`` preset (every
model parameter, with the readings documented in docs/model.md) and lists only what the 6x6
task changes (``set``: dotted keys as ``--set`` takes them, with typed YAML 1.2 values that are
checked for their field's type and applied as they are, never through text), the task (start,
goal, training cycles) and what changes during training (``train_set``, the same form). So the
HIL runs follow the agent model as it is tuned. A plain SNAN config file (no ``base`` key) is
accepted too. The file is read by :mod:`snan_hil.config.loader` (unknown keys named).

Launches (the four scenarios) always run with ``stdp.mode=off``: the weights are fixed during
launches, in software as on the crossbar (no write pulses while the agent runs).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

from annotated_types import Ge

from snan_hil.config import loader as configio
from snan_hil.host.config import (CONFIG_DIR, RENAMED, ConfigError, SnanConfig,
                                  apply_overrides, load_config)

DEFAULT_HIL_CONFIG = CONFIG_DIR / "hil-6x6.yaml"

SCENARIOS = ("sw_noastro", "sw_astro", "hw_noastro", "hw_astro")
SCENARIO_LABELS = {
    "sw_noastro": "software",
    "sw_astro": "software + astrocytes",
    "hw_noastro": "memristor",
    "hw_astro": "memristor + astrocytes",
}

PAPER_MEDIANS = {False: 14.0, True: 7.0}
"""The paper's median path lengths on the 6x6 field ("Hardware implementation": 14 steps
without and 7 with astrocytic modulation, software and hardware alike)."""

PAPER_MEDIANS_10X10 = {False: 362.0, True: 55.0}
"""The paper's median path lengths on the 10x10 field (section 3.2, Fig. 4B1/B2: 362 steps
without, 55 with astrocytes). The paper ran 10x10 in software only, with fresh weights and a
random start and goal every trial; the hardware comparison launches weights trained on one
route (configs/hil-10x10.yaml), so these are the paper's figures beside ours, not the same
protocol (docs/hil.md, "The 10x10 field over a chip group")."""


def paper_median(scenario: str, grid: tuple[int, int] = (6, 6)) -> float | None:
    """The paper's median path length (steps) of a scenario on ``grid``: 6x6 ``*_astro`` 7,
    else 14 (:data:`PAPER_MEDIANS`); 10x10 55 / 362 (:data:`PAPER_MEDIANS_10X10`); None for
    a field the paper gives no median for."""
    astro = scenario.endswith("_astro")
    if tuple(grid) == (10, 10):
        return PAPER_MEDIANS_10X10[astro]
    if tuple(grid) == (6, 6):
        return PAPER_MEDIANS[astro]
    return None


@dataclass
class HilTask:
    """The route task and its training: start/goal cells, cycles per weight set."""

    start: Annotated[int, Ge(0)] = 18      #: start cell (row-major index)
    goal: Annotated[int, Ge(0)] = 0        #: goal cell (row-major index)
    cycles: Annotated[int, Ge(1)] = 20     #: training trials per weight set (paper 3.5: 20)


@dataclass
class HilFile:
    """The HIL config file as written (``configs/hil-6x6.yaml``): the base preset, its
    changes (dotted keys to typed values), the task and the training-only changes."""

    base: str
    name: str | None = None
    set: dict[str, Any] | None = None
    task: HilTask = field(default_factory=HilTask)
    train_set: dict[str, Any] | None = None


@dataclass
class HilConfig:
    """A resolved HIL configuration: the SNAN model, the task, training overrides.

    ``overrides`` and ``train_overrides`` map dotted keys to typed values (checked against
    :class:`SnanConfig` when the config is loaded)."""

    model: SnanConfig
    task: HilTask = field(default_factory=HilTask)
    train_overrides: dict[str, Any] = field(default_factory=dict)
    source: str = ""
    base: str | None = None
    overrides: dict[str, Any] = field(default_factory=dict)

    def train_config(self) -> SnanConfig:
        """The model as used while training (astrocytes on unless ``train_set`` says else)."""
        return apply_overrides(self.model, {"astro.enabled": True, **self.train_overrides})

    def launch_config(self, astro: bool) -> SnanConfig:
        """The model of a launch: weights fixed (``stdp.mode=off``), astrocytes on/off."""
        return apply_overrides(self.model, {"astro.enabled": bool(astro), "stdp.mode": "off"})

    def to_dict(self) -> dict[str, Any]:
        return {"source": self.source, "base": self.base, "overrides": dict(self.overrides),
                "task": dataclasses.asdict(self.task),
                "train_overrides": dict(self.train_overrides),
                "launch_overrides": {"astro.enabled": "<scenario>", "stdp.mode": "off"},
                "model": self.model.to_dict()}


def _typed(mapping: Mapping[str, Any] | None, where: str) -> dict[str, Any]:
    """Dotted keys of a ``set``/``train_set`` mapping, checked against SnanConfig (unknown
    keys named, values checked for their field's type, nothing converted through text)."""
    return configio.check_keys(SnanConfig, mapping or {}, where=where, renamed=RENAMED)


def load_hil_config(path: str | Path | None = None,
                    overrides: Sequence[str] | Mapping[str, Any] = ()) -> HilConfig:
    """Load ``configs/hil-6x6.yaml`` (or ``path``) and apply overrides (``--set`` texts or a
    mapping of dotted keys to typed values). Raises :class:`ConfigError` (one line)."""
    p = Path(path) if path is not None else DEFAULT_HIL_CONFIG
    data = configio.read_yaml(p)
    if isinstance(data, dict) and "base" not in data:          # a plain SNAN config file
        model = apply_overrides(load_config(p), overrides)
        extra = (dict(overrides) if isinstance(overrides, Mapping) else
                 configio.parse_assignments(SnanConfig, overrides, renamed=RENAMED))
        return HilConfig(model=model, source=str(p), overrides=extra)
    where = f"config file {p}"
    spec = configio.from_tree(HilFile, data, where=where)
    sets = _typed(spec.set, f"{where}: set")
    if spec.name is not None:
        sets = {"name": spec.name, **sets}
    cli = (dict(overrides) if isinstance(overrides, Mapping) else
           configio.parse_assignments(SnanConfig, overrides, renamed=RENAMED))
    try:
        model = load_config(preset=spec.base, overrides={**sets, **cli})
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    train = _typed(spec.train_set, f"{where}: train_set")
    cfg = HilConfig(model=model, task=spec.task, train_overrides=train, source=str(p),
                    base=spec.base, overrides={**sets, **cli})
    cfg.train_config()      # validate the training overrides now (one clear line)
    return cfg
