"""Configuration of the hardware-in-the-loop 6x6 task (paper "Hardware implementation").

``configs/hil-6x6.yaml`` does not repeat the SNAN model: it names a ``base`` preset (every
model parameter, with the readings documented in docs/model.md) and lists only what the 6x6
task changes (``set``: dotted keys as ``--set`` takes them), the task (start, goal, training
cycles) and what changes during training (``train_set``). So the HIL runs follow the agent
model as it is tuned. A plain SNAN config file (no ``base`` key) is accepted too.

Launches (the four scenarios) always run with ``stdp.mode=off``: the weights are fixed during
launches, in software as on the crossbar (no write pulses while the agent runs).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from snan_hil.host.config import (CONFIG_DIR, ConfigError, SnanConfig, apply_overrides,
                                  from_dict, load_config)

DEFAULT_HIL_CONFIG = CONFIG_DIR / "hil-6x6.yaml"

SCENARIOS = ("sw_noastro", "sw_astro", "hw_noastro", "hw_astro")
SCENARIO_LABELS = {
    "sw_noastro": "software",
    "sw_astro": "software + astrocytes",
    "hw_noastro": "memristor",
    "hw_astro": "memristor + astrocytes",
}


@dataclass
class HilTask:
    """The route task and its training: start/goal cells, cycles per weight set."""

    start: int = 18
    goal: int = 0
    cycles: int = 20


@dataclass
class HilConfig:
    """A resolved HIL configuration: the SNAN model, the task, training overrides."""

    model: SnanConfig
    task: HilTask = field(default_factory=HilTask)
    train_overrides: tuple[str, ...] = ()
    source: str = ""
    base: str | None = None
    overrides: tuple[str, ...] = ()

    def train_config(self) -> SnanConfig:
        """The model as used while training (astrocytes on unless ``train_set`` says else)."""
        return apply_overrides(self.model, ["astro.enabled=true", *self.train_overrides])

    def launch_config(self, astro: bool) -> SnanConfig:
        """The model of a launch: weights fixed (``stdp.mode=off``), astrocytes on/off."""
        return apply_overrides(self.model, [f"astro.enabled={'true' if astro else 'false'}",
                                            "stdp.mode=off"])

    def to_dict(self) -> dict[str, Any]:
        return {"source": self.source, "base": self.base, "overrides": list(self.overrides),
                "task": {"start": self.task.start, "goal": self.task.goal,
                         "cycles": self.task.cycles},
                "train_overrides": list(self.train_overrides),
                "launch_overrides": ["astro.enabled=<scenario>", "stdp.mode=off"],
                "model": self.model.to_dict()}


def _dotted(mapping: Any, where: str) -> list[str]:
    if mapping is None:
        return []
    if not isinstance(mapping, dict):
        raise ConfigError(f"{where}: expected a mapping of dotted keys to values")
    return [f"{k}={json.dumps(v) if not isinstance(v, str) else v}" for k, v in mapping.items()]


def load_hil_config(path: str | Path | None = None, overrides: list[str] | tuple[str, ...] = ()
                    ) -> HilConfig:
    """Load ``configs/hil-6x6.yaml`` (or ``path``) and apply ``--set`` style overrides."""
    p = Path(path) if path is not None else DEFAULT_HIL_CONFIG
    if not p.is_file():
        raise ConfigError(f"config file {p} not found")
    try:
        data = yaml.safe_load(p.read_text(encoding="utf-8")) or {}
    except yaml.YAMLError:
        raise ConfigError(f"config file {p} is not valid YAML") from None
    if not isinstance(data, dict):
        raise ConfigError(f"config file {p}: expected a mapping")
    if "base" not in data:                      # a plain SNAN config file
        model = apply_overrides(load_config(p), list(overrides))
        return HilConfig(model=model, source=str(p), overrides=tuple(overrides))
    known = {"base", "name", "set", "task", "train_set"}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ConfigError(f"{p.name}: unknown key {unknown[0]} (known: {', '.join(sorted(known))})")
    base = str(data["base"])
    sets = _dotted(data.get("set"), f"{p.name}: set")
    if "name" in data:
        sets.insert(0, f"name={data['name']}")
    try:
        model = load_config(preset=base, overrides=sets + list(overrides))
    except ConfigError as exc:
        raise ConfigError(f"{p.name}: {exc}") from None
    task_data = data.get("task") or {}
    if not isinstance(task_data, dict):
        raise ConfigError(f"{p.name}: task must be a mapping")
    task = HilTask()
    for key, value in task_data.items():
        if key not in ("start", "goal", "cycles"):
            raise ConfigError(f"{p.name}: unknown key task.{key} (known: cycles, goal, start)")
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{p.name}: task.{key} must be an integer, got {value!r}")
        setattr(task, key, value)
    train = tuple(_dotted(data.get("train_set"), f"{p.name}: train_set"))
    cfg = HilConfig(model=model, task=task, train_overrides=train, source=str(p), base=base,
                    overrides=tuple(sets + list(overrides)))
    cfg.train_config()      # validate the training overrides now (one clear line)
    return cfg


def model_from_dict(data: dict[str, Any]) -> SnanConfig:
    """A SnanConfig from a stored ``to_dict()`` (e.g. the config saved in a weights file)."""
    return from_dict(data)
