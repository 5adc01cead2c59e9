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
adds the sourced-leaf format; each field's physical bounds are declared beside it (checked by
the loader for files and overrides, by :func:`snan_hil.config.loader.check_bounds` for objects
built in code), the checks across fields in :func:`_validate`.
"""

from __future__ import annotations

import dataclasses
import importlib.resources
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

from annotated_types import Ge, Gt, Interval

from snan_hil.config import loader as configio
from snan_hil.config.loader import ConfigError


class DeviceConfigError(ConfigError):
    """A device/array YAML file is missing, malformed or has an invalid value."""


@dataclass(frozen=True)
class ConductanceConfig:
    """Device conductance bounds (S) and the usable programming range (S)."""

    g_min_s: Annotated[float, Gt(0)]
    g_max_s: Annotated[float, Gt(0)]
    usable_min_s: Annotated[float, Gt(0)]
    usable_max_s: Annotated[float, Gt(0)]


@dataclass(frozen=True)
class SwitchingConfig:
    """Pulse response: rate nu = rate * ((|V_mem| - v_th)/1 V)**exponent (1/s) above v_th (V)."""

    #: >= 0.3 V: reads at 0.3 V must not change a cell
    v_threshold_v: Annotated[float, Ge(0.3)]
    set_rate_per_s: Annotated[float, Gt(0)]
    set_exponent: Annotated[float, Gt(0)]            # dimensionless
    reset_rate_per_s: Annotated[float, Gt(0)]
    reset_exponent: Annotated[float, Gt(0)]          # dimensionless
    #: largest dose nu*dt of one integration sub-step (dimensionless)
    max_substep_dose: Annotated[float, Interval(gt=0, le=0.5)]


@dataclass(frozen=True)
class TransistorConfig:
    """1T1R select transistor (Ohm, A) and fixed series resistances of the board (Ohm)."""

    on_resistance_ohm: Annotated[float, Ge(0)]
    saturation_current_a: Annotated[float, Gt(0)]
    write_series_ohm: Annotated[float, Ge(0)]
    mac_row_series_ohm: Annotated[float, Ge(0)]


@dataclass(frozen=True)
class VariabilityConfig:
    """Device-to-device spread: log-normal sigmas of bounds and rates, threshold excess (V)."""

    g_min_sigma_log: Annotated[float, Ge(0)]         # sigma of ln g_min (dimensionless)
    g_max_sigma_log: Annotated[float, Ge(0)]         # sigma of ln g_max (dimensionless)
    rate_sigma_log: Annotated[float, Ge(0)]          # sigma of ln rate (dimensionless)
    threshold_sigma_v: Annotated[float, Ge(0)]


@dataclass(frozen=True)
class ProgrammingNoiseConfig:
    """Cycle-to-cycle error of one pulse: log-normal dose factor and a random-walk term."""

    step_sigma_log: Annotated[float, Ge(0)]          # sigma of ln dose factor (dimensionless)
    hop_sigma: Annotated[float, Ge(0)]               # times sqrt(|ds|), normalized state units


@dataclass(frozen=True)
class ReadNoiseConfig:
    """Per-read conductance noise: relative sigma (1) and absolute floor (S)."""

    relative_sigma: Annotated[float, Ge(0)]          # of G (dimensionless)
    absolute_sigma_s: Annotated[float, Ge(0)]


@dataclass(frozen=True)
class DriftConfig:
    """Power-law drift G(t) = G_prog * ((t - t_prog + t0)/t0)**(-nu), nu ~ N(nu_mean, nu_sigma)."""

    nu_mean: float                                   # drift exponent (dimensionless)
    nu_sigma: Annotated[float, Ge(0)]                # (dimensionless)
    t0_s: Annotated[float, Gt(0)]


@dataclass(frozen=True)
class StuckConfig:
    """Stuck cells: fraction of all cells; of those, fraction stuck high; their conductances (S)."""

    fraction: Annotated[float, Interval(ge=0, le=1)]       # of all cells
    high_fraction: Annotated[float, Interval(ge=0, le=1)]  # of the stuck cells
    g_high_s: Annotated[float, Gt(0)]
    g_low_s: Annotated[float, Gt(0)]


@dataclass(frozen=True)
class BreakdownConfig:
    """Damage: a pulse that puts more than ``v_breakdown_v`` (V) across the memristor breaks
    the oxide down; the cell is shorted for good at ``g_short_s`` (S)."""

    v_breakdown_v: float                             # > switching.v_threshold_v
    g_short_s: Annotated[float, Gt(0)]


@dataclass(frozen=True)
class WearConfig:
    """Wear-out of the switching layer: a cell's memory window closes as it is switched.

    ``wear`` of a cell counts full-window swings, ``sum |ds| / 2`` over its switching pulses
    (a swing 0 -> 1 -> 0 is one cycle; a 1 % learning step is 0.005 of one). Each cell's
    endurance (cycles) is log-normal around ``endurance_cycles`` with ``endurance_sigma_log``.
    At wear fraction ``f = wear / endurance`` both bounds move towards their geometric middle
    by ``window_closure * f`` of the log-window; at ``f >= 1`` the cell is worn out and stuck
    at the conductance it has."""

    endurance_cycles: Annotated[float, Gt(0)]               # full-window swings
    endurance_sigma_log: Annotated[float, Ge(0)]            # sigma of ln(endurance)
    window_closure: Annotated[float, Interval(ge=0, lt=1)]  # of the log-window at f = 1


@dataclass(frozen=True)
class InitialStateConfig:
    """Normalized state s (0 = g_min, 1 = g_max, log scale) of a fresh chip: mean and sigma."""

    mean: Annotated[float, Interval(ge=0, le=1)]     # normalized state
    sigma: Annotated[float, Ge(0)]                   # normalized state


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
    rows: Annotated[int, Ge(1)]                      # word lines
    cols: Annotated[int, Ge(1)]                      # bit lines
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
    configio.check_bounds(c)          # the bounds beside the fields
    g = c.conductance
    need(0 < g.g_min_s < g.usable_min_s < g.usable_max_s < g.g_max_s,
         "conductance needs 0 < g_min_s < usable_min_s < usable_max_s < g_max_s")
    s = c.switching
    need(c.breakdown.v_breakdown_v > s.v_threshold_v,
         "breakdown.v_breakdown_v must be above switching.v_threshold_v")
