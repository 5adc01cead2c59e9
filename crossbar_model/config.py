"""Configuration of the emulated 1T1R YSZ crossbar: dataclasses and the sourced YAML format.

Every parameter in a device YAML is a mapping with ``value`` and a ``source`` (or
``assumption``) string, grouped in sections that match the dataclasses below::

    switching:
      v_threshold_v:
        value: 0.3
        source: "board reference: reads at 0.3 V must not change the cell"

``configs/device-ysz.yaml`` (shipped with the package) is the single place where default values
live; :meth:`ArrayConfig.default` loads it.
"""

from __future__ import annotations

import dataclasses
import importlib.resources
import json
import math
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import yaml

from snan_hil.errors import UserError


class DeviceConfigError(UserError):
    """A device/array YAML file is missing, malformed or has an invalid value."""


@dataclass(frozen=True)
class ConductanceConfig:
    """Device conductance bounds (S) and the usable programming range (S)."""

    g_min_s: float
    g_max_s: float
    usable_min_s: float
    usable_max_s: float


@dataclass(frozen=True)
class SwitchingConfig:
    """Pulse response: rate nu = rate * ((|V_mem| - v_th)/1 V)**exponent (1/s) above v_th (V)."""

    v_threshold_v: float
    set_rate_per_s: float
    set_exponent: float
    reset_rate_per_s: float
    reset_exponent: float
    max_substep_dose: float


@dataclass(frozen=True)
class TransistorConfig:
    """1T1R select transistor (Ohm, A) and fixed series resistances of the board (Ohm)."""

    on_resistance_ohm: float
    saturation_current_a: float
    write_series_ohm: float
    mac_row_series_ohm: float


@dataclass(frozen=True)
class VariabilityConfig:
    """Device-to-device spread: log-normal sigmas of bounds and rates, threshold excess (V)."""

    g_min_sigma_log: float
    g_max_sigma_log: float
    rate_sigma_log: float
    threshold_sigma_v: float


@dataclass(frozen=True)
class ProgrammingNoiseConfig:
    """Cycle-to-cycle error of one pulse: log-normal dose factor and a random-walk term."""

    step_sigma_log: float
    hop_sigma: float


@dataclass(frozen=True)
class ReadNoiseConfig:
    """Per-read conductance noise: relative sigma (1) and absolute floor (S)."""

    relative_sigma: float
    absolute_sigma_s: float


@dataclass(frozen=True)
class DriftConfig:
    """Power-law drift G(t) = G_prog * ((t - t_prog + t0)/t0)**(-nu), nu ~ N(nu_mean, nu_sigma)."""

    nu_mean: float
    nu_sigma: float
    t0_s: float


@dataclass(frozen=True)
class StuckConfig:
    """Stuck cells: fraction of all cells; of those, fraction stuck high; their conductances (S)."""

    fraction: float
    high_fraction: float
    g_high_s: float
    g_low_s: float


@dataclass(frozen=True)
class InitialStateConfig:
    """Normalized state s (0 = g_min, 1 = g_max, log scale) of a fresh chip: mean and sigma."""

    mean: float
    sigma: float


_SECTIONS: dict[str, type] = {
    "conductance": ConductanceConfig,
    "switching": SwitchingConfig,
    "transistor": TransistorConfig,
    "variability": VariabilityConfig,
    "programming_noise": ProgrammingNoiseConfig,
    "read_noise": ReadNoiseConfig,
    "drift": DriftConfig,
    "stuck": StuckConfig,
    "initial_state": InitialStateConfig,
}


@dataclass(frozen=True)
class ArrayConfig:
    """Everything that defines an emulated chip; see docs/crossbar_model.md for the physics."""

    name: str
    rows: int
    cols: int
    conductance: ConductanceConfig
    switching: SwitchingConfig
    transistor: TransistorConfig
    variability: VariabilityConfig
    programming_noise: ProgrammingNoiseConfig
    read_noise: ReadNoiseConfig
    drift: DriftConfig
    stuck: StuckConfig
    initial_state: InitialStateConfig

    def __post_init__(self) -> None:
        _validate(self)

    # --- construction -----------------------------------------------------------------
    @classmethod
    def default(cls) -> "ArrayConfig":
        """The packaged ``configs/device-ysz.yaml``."""
        return cls.from_yaml(None)

    @classmethod
    def from_yaml(cls, path: str | Path | None = None) -> "ArrayConfig":
        """Load a sourced device YAML (None: the packaged configs/device-ysz.yaml)."""
        if path is None:
            resource = importlib.resources.files("snan_hil").joinpath("configs", "device-ysz.yaml")
            text = resource.read_text(encoding="utf-8")
            where = "configs/device-ysz.yaml"
        else:
            where = str(path)
            try:
                text = Path(path).read_text(encoding="utf-8")
            except OSError as exc:
                raise DeviceConfigError(f"cannot read device config {where}: {exc.strerror}; "
                                        "give the path of a device YAML such as configs/device-ysz.yaml") from None
        try:
            tree = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            raise DeviceConfigError(f"device config {where} is not valid YAML: {exc}") from None
        return cls.from_sourced_tree(tree, where)

    @classmethod
    def from_sourced_tree(cls, tree: Any, where: str = "<config>") -> "ArrayConfig":
        """Build from the YAML tree (every leaf a {value, source|assumption} mapping)."""
        if not isinstance(tree, dict):
            raise DeviceConfigError(f"device config {where}: top level must be a mapping")
        plain: dict[str, Any] = {"name": str(tree.get("name", Path(where).stem))}
        array = tree.get("array")
        if not isinstance(array, dict):
            raise DeviceConfigError(f"device config {where}: missing section 'array' (rows, cols)")
        for key in ("rows", "cols"):
            plain[key] = _leaf_value(array, key, f"array.{key}", where)
        for section, klass in _SECTIONS.items():
            node = tree.get(section)
            if not isinstance(node, dict):
                raise DeviceConfigError(f"device config {where}: missing section '{section}'")
            names = {f.name for f in fields(klass)}
            unknown = sorted(set(node) - names)
            if unknown:
                raise DeviceConfigError(f"device config {where}: unknown key(s) {unknown} in '{section}'; "
                                        f"allowed: {sorted(names)}")
            plain[section] = {n: _leaf_value(node, n, f"{section}.{n}", where) for n in names}
        try:
            return cls.from_dict(plain)
        except (TypeError, ValueError) as exc:
            raise DeviceConfigError(f"device config {where}: {exc}") from None

    @classmethod
    def from_dict(cls, plain: dict[str, Any]) -> "ArrayConfig":
        """Build from plain values ({section: {field: value}}), as written by :meth:`to_dict`."""
        kwargs: dict[str, Any] = {"name": str(plain["name"]), "rows": int(plain["rows"]), "cols": int(plain["cols"])}
        for section, klass in _SECTIONS.items():
            kwargs[section] = klass(**{k: float(v) for k, v in plain[section].items()})
        return cls(**kwargs)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True)

    def with_overrides(self, overrides: dict[str, Any]) -> "ArrayConfig":
        """A copy with dotted keys replaced, e.g. ``{"stuck.fraction": 0.0, "rows": 16}``."""
        plain = self.to_dict()
        for key, value in overrides.items():
            parts = key.split(".")
            node = plain
            for part in parts[:-1]:
                if part not in node or not isinstance(node[part], dict):
                    raise ValueError(f"unknown config key {key!r}")
                node = node[part]
            if parts[-1] not in node:
                raise ValueError(f"unknown config key {key!r}")
            node[parts[-1]] = value
        return ArrayConfig.from_dict(plain)

    def ideal(self) -> "ArrayConfig":
        """A copy without variability, noise, drift or stuck cells (for tests and references)."""
        return self.with_overrides({
            "variability.g_min_sigma_log": 0.0, "variability.g_max_sigma_log": 0.0,
            "variability.rate_sigma_log": 0.0, "variability.threshold_sigma_v": 0.0,
            "programming_noise.step_sigma_log": 0.0, "programming_noise.hop_sigma": 0.0,
            "read_noise.relative_sigma": 0.0, "read_noise.absolute_sigma_s": 0.0,
            "drift.nu_mean": 0.0, "drift.nu_sigma": 0.0, "stuck.fraction": 0.0,
            "initial_state.sigma": 0.0,
        })


def sourced_leaves(tree: dict[str, Any], prefix: str = "") -> dict[str, dict[str, Any]]:
    """All {value, source|assumption} leaves of a device YAML tree, by dotted key."""
    out: dict[str, dict[str, Any]] = {}
    for key, node in tree.items():
        if not isinstance(node, dict):
            continue
        dotted = f"{prefix}{key}"
        if "value" in node:
            out[dotted] = node
        else:
            out.update(sourced_leaves(node, dotted + "."))
    return out


def _leaf_value(node: dict[str, Any], key: str, dotted: str, where: str) -> Any:
    leaf = node.get(key)
    if not isinstance(leaf, dict) or "value" not in leaf:
        raise DeviceConfigError(f"device config {where}: '{dotted}' must be a mapping with 'value' and "
                                "'source' (or 'assumption')")
    note = leaf.get("source") or leaf.get("assumption")
    if not isinstance(note, str) or not note.strip():
        raise DeviceConfigError(f"device config {where}: '{dotted}' has no 'source' or 'assumption' text")
    value = leaf["value"]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise DeviceConfigError(f"device config {where}: '{dotted}' value must be a number, got {value!r}")
    return value


def _validate(c: ArrayConfig) -> None:
    def need(cond: bool, what: str) -> None:
        if not cond:
            raise ValueError(what)

    for section in _SECTIONS:
        for key, value in dataclasses.asdict(getattr(c, section)).items():
            need(math.isfinite(value), f"{section}.{key} must be finite, got {value}")
    need(c.rows >= 1 and c.cols >= 1, f"rows and cols must be >= 1, got {c.rows}x{c.cols}")
    g = c.conductance
    need(0 < g.g_min_s < g.usable_min_s < g.usable_max_s < g.g_max_s,
         "conductance needs 0 < g_min_s < usable_min_s < usable_max_s < g_max_s")
    s = c.switching
    need(s.v_threshold_v >= 0.3, f"switching.v_threshold_v must be >= 0.3 V (reads at 0.3 V must not "
                                 f"change a cell), got {s.v_threshold_v}")
    need(s.set_rate_per_s > 0 and s.reset_rate_per_s > 0, "switching rates must be > 0")
    need(s.set_exponent > 0 and s.reset_exponent > 0, "switching exponents must be > 0")
    need(0 < s.max_substep_dose <= 0.5, "switching.max_substep_dose must be in (0, 0.5]")
    t = c.transistor
    need(t.on_resistance_ohm >= 0 and t.write_series_ohm >= 0 and t.mac_row_series_ohm >= 0,
         "transistor resistances must be >= 0")
    need(t.saturation_current_a > 0, "transistor.saturation_current_a must be > 0")
    for key, value in dataclasses.asdict(c.variability).items():
        need(value >= 0, f"variability.{key} must be >= 0")
    need(c.programming_noise.step_sigma_log >= 0 and c.programming_noise.hop_sigma >= 0,
         "programming_noise sigmas must be >= 0")
    need(c.read_noise.relative_sigma >= 0 and c.read_noise.absolute_sigma_s >= 0, "read_noise sigmas must be >= 0")
    need(c.drift.nu_sigma >= 0 and c.drift.t0_s > 0, "drift needs nu_sigma >= 0 and t0_s > 0")
    need(0 <= c.stuck.fraction <= 1 and 0 <= c.stuck.high_fraction <= 1, "stuck fractions must be in [0, 1]")
    need(c.stuck.g_high_s > 0 and c.stuck.g_low_s > 0, "stuck conductances must be > 0")
    need(0 <= c.initial_state.mean <= 1 and c.initial_state.sigma >= 0,
         "initial_state needs mean in [0, 1] and sigma >= 0")
