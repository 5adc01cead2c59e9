"""SNAN configuration: dataclasses loaded from YAML with strict key checking.

Every model parameter of the paper (Table tab_1) and every reading of an ambiguity
(docs/model.md) is a named field here. Presets live in ``configs/snan-3x3.yaml`` and
``configs/snan-10x10.yaml``; any value can be overridden with ``section.key=value``
strings (the CLI's ``--set``). Unknown keys, wrong types and out-of-range values raise
:class:`snan_hil.errors.UserError` with one line naming the key.

Units: times in ms unless the field name says otherwise; potentials and currents in the
paper's dimensionless units (R = 1 so R*I is a potential increment per ms step).
"""

from __future__ import annotations

import copy
import dataclasses
import math
import pathlib
from dataclasses import dataclass, field, fields, is_dataclass
from typing import Any, get_args, get_origin, get_type_hints, Literal

import yaml

from snan_hil.errors import UserError

CONFIG_DIR = pathlib.Path(__file__).resolve().parent.parent / "configs"


class ConfigError(UserError):
    """A configuration file or override is invalid (one line, exit code 2)."""


@dataclass
class GridConfig:
    """Environment: an M x K grid, four moves, trial step limit."""

    rows: int = 3
    cols: int = 3
    max_steps: int = 100
    #: how an inner wall acts: "prune" = no synapse / no candidate move through it;
    #: "bump" = the synapse exists, a chosen move into a wall leaves the agent in place.
    walls: Literal["prune", "bump"] = "prune"


@dataclass
class InputConfig:
    """Bernoulli input spike train of the occupied cell's input neuron."""

    p: float = 0.15            #: spike probability per time step
    t_stim_ms: float = 1000.0  #: stimulation / decision window
    dt_ms: float = 1.0         #: simulation step


@dataclass
class NeuronConfig:
    """LIF motor neurons and interneurons (Eq. 1)."""

    tau_m_ms: float = 150.0
    v_rest: float = 0.0
    v_thr_motor: float = 7.0
    v_thr_inter: float = 7.0     #: baseline interneuron threshold v_thr*
    v_reset: float = 0.0
    t_ref_ms: float = 40.0
    r_m: float = 1.0             #: membrane resistance (1 MOhm in the paper; numerically 1)
    i_bias: float = 0.02         #: interneuron bias current
    #: "clamp": a refractory neuron ignores input and holds v_reset (paper: "cannot receive
    #: signals"); "integrate": it integrates input but cannot spike.
    refractory: Literal["clamp", "integrate"] = "clamp"
    #: reset membrane potentials and refractory counters of all neurons at the start of
    #: every decision window (True) or let them carry over between windows (False).
    reset_each_window: bool = True


@dataclass
class SynapseConfig:
    """Input->motor plastic weights, fixed input->interneuron and interneuron->motor."""

    w_mean: float = 0.65
    w_std: float = 0.1
    w_lo: float = 0.5
    w_hi: float = 0.8
    #: "clip": draw N(mean, std) and clip to [w_lo, w_hi]; "truncate": redraw until inside.
    init: Literal["clip", "truncate"] = "clip"
    w_in_inter: float = 1.0      #: input -> interneuron weight ("identity")
    w_inh: float = 20.0          #: interneuron -> motor inhibitory weight magnitude w_I


@dataclass
class StdpConfig:
    """Pair-based additive STDP on input->motor synapses (Eq. 2)."""

    #: "off": no plasticity; "window": the accumulated change of every decision window is
    #: written at the end of that window (the network uses it from the next window on);
    #: "trial_end": the same changes are accumulated on a copy that becomes the weights at
    #: the end of the trial (the trial itself runs on its initial weights).
    mode: Literal["off", "window", "trial_end"] = "trial_end"
    a_plus: float = 0.04
    a_minus: float = 0.03
    tau_plus_ms: float = 8.0
    tau_minus_ms: float = 8.0
    w_min: float = 0.001
    w_max: float = 1.0
    k: float = 1.5               #: factor on the chosen move's accumulated change
    pairing: Literal["all_to_all", "nearest"] = "all_to_all"
    #: which candidate synapses receive a window's change: "all" = every candidate its own
    #: change (the chosen move's times k); "chosen" = only the chosen move's synapse (k times
    #: its change), the other candidates unchanged (route learning, Fig. 7);
    #: "depress_others" = chosen k*dw, the other candidates -|dw|; "normalize" = as "all",
    #: then the cell's outgoing weights are scaled back to their sum before the update
    #: (heterosynaptic normalisation; the HIL training reading, docs/hil.md).
    target: Literal["all", "chosen", "depress_others", "normalize"] = "all"


@dataclass
class AstroConfig:
    """Glutamate, reduced 2nd-order calcium model, calcium-gated interneuron threshold."""

    enabled: bool = True
    a: float = 0.73              #: calcium impulse amplitude A
    tau_ca: float = 1.2          #: calcium time constant, in units of ``tau_ca_unit``
    tau_ca_unit: Literal["s", "ms"] = "s"
    alpha_n_per_ms: float = 0.001  #: glutamate clearance rate
    k_n: float = 0.2             #: glutamate release per input spike
    g_thr: float = 0.2
    ca_thr: float = 0.2
    eta: float = 5.0

    @property
    def tau_ca_ms(self) -> float:
        return self.tau_ca * (1000.0 if self.tau_ca_unit == "s" else 1.0)


@dataclass
class DecisionConfig:
    """Decision rule at the end of a window."""

    #: when every candidate motor neuron stayed silent: "random" = pick a neighbour at
    #: random (the tie rule over all-zero counts); "stay" = do not move (the step counts).
    no_spike: Literal["random", "stay"] = "random"


@dataclass
class SnanConfig:
    """Complete SNAN agent + environment configuration."""

    name: str = "snan"
    grid: GridConfig = field(default_factory=GridConfig)
    input: InputConfig = field(default_factory=InputConfig)
    neuron: NeuronConfig = field(default_factory=NeuronConfig)
    synapse: SynapseConfig = field(default_factory=SynapseConfig)
    stdp: StdpConfig = field(default_factory=StdpConfig)
    astro: AstroConfig = field(default_factory=AstroConfig)
    decision: DecisionConfig = field(default_factory=DecisionConfig)

    # ---- derived quantities -------------------------------------------------------
    @property
    def n_cells(self) -> int:
        return self.grid.rows * self.grid.cols

    @property
    def window_steps(self) -> int:
        """Time steps per decision window (1000 for 1 s at 1 ms)."""
        return int(round(self.input.t_stim_ms / self.input.dt_ms))

    @property
    def ref_steps(self) -> int:
        """Refractory period in time steps."""
        return int(round(self.neuron.t_ref_ms / self.input.dt_ms))

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def replace(self, **sections: Any) -> "SnanConfig":
        """Copy with whole sections or dotted overrides applied (``{"astro.enabled": False}``)."""
        cfg = copy.deepcopy(self)
        for key, value in sections.items():
            _set_path(cfg, key.replace("__", "."), value, raw=False)
        validate(cfg)
        return cfg


# ---------------------------------------------------------------------------------------
# loading, overriding, validation

def _coerce(value: Any, hint: Any, where: str) -> Any:
    origin = get_origin(hint)
    if origin is Literal:
        choices = get_args(hint)
        if isinstance(value, bool):  # YAML 1.1 reads off/on/no/yes as booleans
            value = {False: "off", True: "on"}[value]
        if value not in choices:
            raise ConfigError(f"{where}: {value!r} is not one of {', '.join(map(str, choices))}")
        return value
    if hint is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true or false, got {value!r}")
        return value
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or (
                isinstance(value, float) and not value.is_integer()):
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return int(value)
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        value = float(value)
        if not math.isfinite(value):
            raise ConfigError(f"{where}: expected a finite number, got {value!r}")
        return value
    if hint is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
        return value
    raise TypeError(f"unsupported config type {hint!r}")  # pragma: no cover


def _from_mapping(cls: type, data: Any, where: str) -> Any:
    if not isinstance(data, dict):
        raise ConfigError(f"{where or 'config'}: expected a mapping, got {type(data).__name__}")
    hints = get_type_hints(cls)
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(data) - known)
    if unknown:
        prefix = f"{where}." if where else ""
        raise ConfigError(f"unknown config key {prefix}{unknown[0]} "
                          f"(known: {', '.join(sorted(known))})")
    obj = cls()
    for name, value in data.items():
        key = f"{where}.{name}" if where else name
        hint = hints[name]
        if isinstance(hint, type) and is_dataclass(hint):
            setattr(obj, name, _from_mapping(hint, value, key))
        else:
            setattr(obj, name, _coerce(value, hint, key))
    return obj


def from_dict(data: dict[str, Any]) -> SnanConfig:
    """Build and validate a config from a (YAML) mapping; missing keys take paper defaults."""
    cfg = _from_mapping(SnanConfig, data, "")
    validate(cfg)
    return cfg


def _set_path(cfg: SnanConfig, path: str, value: Any, raw: bool) -> None:
    parts = path.split(".")
    obj: Any = cfg
    for i, part in enumerate(parts):
        if not is_dataclass(obj) or part not in {f.name for f in fields(obj)}:
            known = (f"; known keys here: {', '.join(sorted(f.name for f in fields(obj)))}"
                     if is_dataclass(obj) else "")
            raise ConfigError(f"unknown config key {'.'.join(parts[:i + 1])}{known}")
        hint = get_type_hints(type(obj))[part]
        if i == len(parts) - 1:
            if isinstance(hint, type) and is_dataclass(hint):
                if raw or isinstance(value, dict):
                    setattr(obj, part, _from_mapping(hint, value, path))
                else:
                    setattr(obj, part, value)
            else:
                setattr(obj, part, _coerce(value, hint, path))
        else:
            obj = getattr(obj, part)


def apply_overrides(cfg: SnanConfig, overrides: list[str] | tuple[str, ...]) -> SnanConfig:
    """Apply ``section.key=value`` strings (value parsed as YAML) and re-validate."""
    cfg = copy.deepcopy(cfg)
    for item in overrides:
        if "=" not in item:
            raise ConfigError(f"override {item!r} must look like section.key=value")
        path, text = item.split("=", 1)
        try:
            value = yaml.safe_load(text) if text.strip() else None
        except yaml.YAMLError:
            value = text
        _set_path(cfg, path.strip(), value, raw=True)
    validate(cfg)
    return cfg


def preset_path(name: str) -> pathlib.Path:
    return CONFIG_DIR / f"{name}.yaml"


def load_config(path: str | pathlib.Path | None = None, *, preset: str | None = None,
                overrides: list[str] | tuple[str, ...] = ()) -> SnanConfig:
    """Load a YAML file (or a named preset such as ``snan-3x3``) and apply overrides."""
    if path is None and preset is None:
        preset = "snan-3x3"
    p = pathlib.Path(path) if path is not None else preset_path(str(preset))
    if not p.is_file():
        raise ConfigError(f"config file {p} not found")
    try:
        data = yaml.safe_load(p.read_text(encoding="utf-8"))
    except yaml.YAMLError as exc:
        line = getattr(getattr(exc, "problem_mark", None), "line", None)
        at = f" (line {line + 1})" if line is not None else ""
        raise ConfigError(f"config file {p} is not valid YAML{at}") from None
    if data is None:
        data = {}
    try:
        cfg = from_dict(data)
    except ConfigError as exc:
        raise ConfigError(f"{p.name}: {exc}") from None
    return apply_overrides(cfg, overrides)


def _check(cond: bool, msg: str) -> None:
    if not cond:
        raise ConfigError(msg)


def validate(cfg: SnanConfig) -> None:
    """Range checks; raises ConfigError naming the first offending key."""
    g, i, n, s, d, a = cfg.grid, cfg.input, cfg.neuron, cfg.synapse, cfg.stdp, cfg.astro
    _check(g.rows >= 1 and g.cols >= 1, f"grid size must be positive, got {g.rows}x{g.cols}")
    _check(g.rows * g.cols >= 2, "grid must have at least 2 cells (start != goal)")
    _check(g.max_steps >= 1, f"grid.max_steps must be >= 1, got {g.max_steps}")
    _check(0.0 <= i.p <= 1.0, f"input.p must be in [0, 1], got {i.p}")
    _check(i.dt_ms > 0, f"input.dt_ms must be > 0, got {i.dt_ms}")
    _check(i.t_stim_ms > 0, f"input.t_stim_ms must be > 0, got {i.t_stim_ms}")
    steps = i.t_stim_ms / i.dt_ms
    _check(abs(steps - round(steps)) < 1e-9,
           "input.t_stim_ms must be a whole number of input.dt_ms steps")
    _check(n.tau_m_ms > 0, f"neuron.tau_m_ms must be > 0, got {n.tau_m_ms}")
    _check(n.t_ref_ms >= 0, f"neuron.t_ref_ms must be >= 0, got {n.t_ref_ms}")
    rs = n.t_ref_ms / i.dt_ms
    _check(abs(rs - round(rs)) < 1e-9, "neuron.t_ref_ms must be a whole number of dt steps")
    _check(n.v_thr_motor > n.v_rest, "neuron.v_thr_motor must be above neuron.v_rest")
    _check(n.v_thr_inter > n.v_rest, "neuron.v_thr_inter must be above neuron.v_rest")
    _check(n.v_reset < n.v_thr_motor and n.v_reset < n.v_thr_inter / (1 + max(a.eta, 0.0)),
           "neuron.v_reset must be below every (lowered) threshold")
    _check(n.r_m > 0, f"neuron.r_m must be > 0, got {n.r_m}")
    _check(s.w_std >= 0, f"synapse.w_std must be >= 0, got {s.w_std}")
    _check(s.w_lo <= s.w_hi, "synapse.w_lo must be <= synapse.w_hi")
    _check(s.w_lo >= 0, f"synapse.w_lo must be >= 0, got {s.w_lo}")
    _check(s.w_inh >= 0, f"synapse.w_inh must be >= 0 (it is a magnitude), got {s.w_inh}")
    _check(s.w_in_inter >= 0, f"synapse.w_in_inter must be >= 0, got {s.w_in_inter}")
    if s.init == "truncate":
        _check(s.w_std > 0 or s.w_lo <= s.w_mean <= s.w_hi,
               "synapse.init=truncate needs w_std > 0 or w_mean inside [w_lo, w_hi]")
    _check(d.tau_plus_ms > 0 and d.tau_minus_ms > 0, "stdp time constants must be > 0")
    _check(d.w_min <= d.w_max, "stdp.w_min must be <= stdp.w_max")
    _check(d.a_plus >= 0 and d.a_minus >= 0, "stdp amplitudes must be >= 0")
    _check(d.k >= 0, f"stdp.k must be >= 0, got {d.k}")
    _check(a.tau_ca > 0, f"astro.tau_ca must be > 0, got {a.tau_ca}")
    _check(a.tau_ca_ms >= i.dt_ms,
           "astro.tau_ca must be at least one time step (Euler is unstable below)")
    _check(0 < a.alpha_n_per_ms * i.dt_ms < 1,
           "astro.alpha_n_per_ms * input.dt_ms must be in (0, 1)")
    _check(a.k_n >= 0, f"astro.k_n must be >= 0, got {a.k_n}")
    _check(a.eta >= 0, f"astro.eta must be >= 0, got {a.eta}")
    _check(a.a >= 0, f"astro.a must be >= 0, got {a.a}")
