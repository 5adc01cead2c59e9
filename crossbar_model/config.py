"""Configuration of the emulated 1T1R YSZ crossbar: dataclasses and the sourced YAML format.

Every parameter in a device YAML is a mapping with ``value`` and a ``source`` (or
``assumption``) string, grouped in sections that match the dataclasses below::

    switching:
      v_threshold_v:
        value: 0.3
        source: "board reference: reads at 0.3 V must not change the cell"

``configs/device-ysz.yaml`` (shipped with the package) is the single place where default values
live; :meth:`ArrayConfig.default` loads it. Files are read, and values checked, by the project's
one loader (:mod:`snan_hil.config.loader`: YAML 1.2, strict types, unknown keys named); this module
adds the sourced-leaf format and the physical range checks (:func:`_validate`).
"""

from __future__ import annotations

import dataclasses
import importlib.resources
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from snan_hil.config import loader as configio
from snan_hil.config.loader import ConfigError


class DeviceConfigError(ConfigError):
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
class BreakdownConfig:
    """Damage: a pulse that puts more than ``v_breakdown_v`` (V) across the memristor breaks
    the oxide down; the cell is shorted for good at ``g_short_s`` (S)."""

    v_breakdown_v: float
    g_short_s: float


@dataclass(frozen=True)
class WearConfig:
    """Wear-out of the switching layer: a cell's memory window closes as it is switched.

    ``wear`` of a cell counts full-window swings, ``sum |ds| / 2`` over its switching pulses
    (a swing 0 -> 1 -> 0 is one cycle; a 1 % learning step is 0.005 of one). Each cell's
    endurance (cycles) is log-normal around ``endurance_cycles`` with ``endurance_sigma_log``.
    At wear fraction ``f = wear / endurance`` both bounds move towards their geometric middle
    by ``window_closure * f`` of the log-window; at ``f >= 1`` the cell is worn out and stuck
    at the conductance it has."""

    endurance_cycles: float
    endurance_sigma_log: float
    window_closure: float


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
    "breakdown": BreakdownConfig,
    "wear": WearConfig,
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
    breakdown: BreakdownConfig
    wear: WearConfig
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
        """Load a sourced device YAML (None: the packaged configs/device-ysz.yaml).

        Raises :class:`DeviceConfigError` (one line) if the file is missing, not YAML 1.2,
        has unknown or missing keys, a leaf without its source, or a value out of range."""
        if path is None:
            source: Any = importlib.resources.files("snan_hil").joinpath("configs",
                                                                         "device-ysz.yaml")
            where = "configs/device-ysz.yaml"
        else:
            source, where = Path(path), str(path)
        try:
            tree = configio.read_yaml(source, what="device config")
        except ConfigError as exc:
            raise DeviceConfigError(f"{exc}; give the path of a device YAML such as "
                                    "configs/device-ysz.yaml") from None
        return cls.from_sourced_tree(tree, where)

    @classmethod
    def from_sourced_tree(cls, tree: Any, where: str = "<config>") -> "ArrayConfig":
        """Build from the YAML tree (every leaf a {value, source|assumption} mapping)."""
        if not isinstance(tree, dict):
            raise DeviceConfigError(f"device config {where}: top level must be a mapping")
        plain: dict[str, Any] = {}
        for key, node in tree.items():
            if key == "name":
                plain["name"] = node
            elif key == "array" and isinstance(node, dict):      # rows, cols of the array
                plain.update(_unsourced(node, "array", where))
            elif isinstance(node, dict):
                plain[key] = _unsourced(node, key, where)
            else:
                plain[key] = node          # not a section: from_dict names the problem
        plain.setdefault("name", Path(where).stem)
        return cls.from_dict(plain, where=f"device config {where}")

    @classmethod
    def from_dict(cls, plain: dict[str, Any], *, where: str = "device config"
                  ) -> "ArrayConfig":
        """Build from plain values ({section: {field: value}}, rows, cols, name), as written by
        :meth:`to_dict`. Raises :class:`DeviceConfigError`."""
        try:
            return configio.from_tree(cls, plain, where=where)
        except ConfigError as exc:
            raise DeviceConfigError(str(exc)) from None

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True)

    def with_overrides(self, overrides: dict[str, Any]) -> "ArrayConfig":
        """A copy with dotted keys set to typed values, e.g. ``{"stuck.fraction": 0.0,
        "rows": 16}``. Raises :class:`DeviceConfigError` (unknown key, wrong type, range)."""
        try:
            return configio.apply(self, overrides)
        except ConfigError as exc:
            raise DeviceConfigError(str(exc)) from None

    def ideal(self) -> "ArrayConfig":
        """A copy without variability, noise, drift or stuck cells (for tests and references)."""
        return self.with_overrides({
            "variability.g_min_sigma_log": 0.0, "variability.g_max_sigma_log": 0.0,
            "variability.rate_sigma_log": 0.0, "variability.threshold_sigma_v": 0.0,
            "programming_noise.step_sigma_log": 0.0, "programming_noise.hop_sigma": 0.0,
            "read_noise.relative_sigma": 0.0, "read_noise.absolute_sigma_s": 0.0,
            "drift.nu_mean": 0.0, "drift.nu_sigma": 0.0, "stuck.fraction": 0.0,
            "initial_state.sigma": 0.0, "wear.endurance_sigma_log": 0.0,
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


def _unsourced(node: dict[str, Any], section: str, where: str) -> dict[str, Any]:
    """{key: {value, source|assumption}} -> {key: value}; every leaf must carry its source."""
    out: dict[str, Any] = {}
    for key, leaf in node.items():
        dotted = f"{section}.{key}"
        if not isinstance(leaf, dict) or "value" not in leaf:
            raise DeviceConfigError(f"device config {where}: '{dotted}' must be a mapping with "
                                    "'value' and 'source' (or 'assumption')")
        note = leaf.get("source") or leaf.get("assumption")
        if not isinstance(note, str) or not note.strip():
            raise DeviceConfigError(f"device config {where}: '{dotted}' has no 'source' or "
                                    "'assumption' text")
        out[key] = leaf["value"]
    return out


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
    need(c.breakdown.v_breakdown_v > s.v_threshold_v,
         "breakdown.v_breakdown_v must be above switching.v_threshold_v")
    need(c.breakdown.g_short_s > 0, "breakdown.g_short_s must be > 0")
    need(c.wear.endurance_cycles > 0, "wear.endurance_cycles must be > 0")
    need(c.wear.endurance_sigma_log >= 0, "wear.endurance_sigma_log must be >= 0")
    need(0 <= c.wear.window_closure < 1, "wear.window_closure must be in [0, 1)")
    need(0 <= c.initial_state.mean <= 1 and c.initial_state.sigma >= 0,
         "initial_state needs mean in [0, 1] and sigma >= 0")
