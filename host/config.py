"""SNAN configuration: dataclasses loaded from YAML with strict key checking.

Every model parameter of the paper (Table tab_1) and every reading of an ambiguity
(docs/model.md) is a named field here. Presets live in ``configs/snan-3x3.yaml`` and
``configs/snan-10x10.yaml``; any value can be overridden with ``section.key=value``
strings (the CLI's ``--set``) or a mapping of dotted keys to typed values. Files and
overrides go through the project's one loader, :mod:`snan_hil.config.loader` (YAML 1.2 numbers,
strict types, unknown keys named with the known ones); the cross-field checks are
:func:`validate`, run whenever a :class:`SnanConfig` is built. Every error is a
:class:`ConfigError` (a :class:`snan_hil.common.errors.UserError`) of one line naming the key.

Units: times in ms unless the field name says otherwise (``astro.tau_ca_s`` is in s);
potentials and currents in the paper's dimensionless units (R = 1 so R*I is a potential
increment per ms step).
"""

from __future__ import annotations

import copy
import dataclasses
import pathlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Annotated, Any, Literal, Union

from annotated_types import Ge, Gt, Interval

from snan_hil.config import loader as configio
from snan_hil.config.loader import ConfigError

__all__ = ["ConfigError", "SnanConfig", "GridConfig", "InputConfig", "NeuronConfig",
           "SynapseConfig", "StdpConfig", "VteamConfig", "AstroConfig", "DecisionConfig",
           "CONFIG_DIR", "RENAMED", "from_dict", "from_stored", "apply_overrides", "load_config",
           "preset_path", "validate"]

CONFIG_DIR = pathlib.Path(__file__).resolve().parent.parent / "configs"


@dataclass
class GridConfig:
    """Environment: an M x K grid, four moves, trial step limit."""

    rows: Annotated[int, Ge(1)] = 3        #: grid rows M (cells)
    cols: Annotated[int, Ge(1)] = 3        #: grid columns K (cells)
    max_steps: Annotated[int, Ge(1)] = 100  #: trial step limit (moves)
    #: how an inner wall acts: "prune" = no synapse / no candidate move through it;
    #: "bump" = the synapse exists, a chosen move into a wall leaves the agent in place.
    walls: Literal["prune", "bump"] = "prune"


@dataclass
class InputConfig:
    """Bernoulli input spike train of the occupied cell's input neuron."""

    p: Annotated[float, Interval(ge=0, le=1)] = 0.15   #: spike probability per time step
    t_stim_ms: Annotated[float, Gt(0)] = 1000.0  #: stimulation / decision window, ms
    dt_ms: Annotated[float, Gt(0)] = 1.0         #: simulation step, ms


@dataclass
class NeuronConfig:
    """LIF motor neurons and interneurons (Eq. 1)."""

    tau_m_ms: Annotated[float, Gt(0)] = 150.0   #: membrane time constant, ms
    v_rest: float = 0.0          #: resting potential (dimensionless, like every potential)
    v_thr_motor: float = 7.0
    v_thr_inter: float = 7.0     #: baseline interneuron threshold v_thr*
    v_reset: float = 0.0
    t_ref_ms: Annotated[float, Ge(0)] = 40.0    #: refractory period, ms
    r_m: Annotated[float, Gt(0)] = 1.0   #: membrane resistance (1 MOhm in the paper; numerically 1)
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

    w_mean: float = 0.65         #: mean of the initial weights (dimensionless, like all weights)
    w_std: Annotated[float, Ge(0)] = 0.1    #: spread of the initial weights
    w_lo: Annotated[float, Ge(0)] = 0.5     #: lowest initial weight
    w_hi: float = 0.8                       #: highest initial weight (>= w_lo)
    #: "clip": draw N(mean, std) and clip to [w_lo, w_hi]; "truncate": redraw until inside.
    init: Literal["clip", "truncate"] = "clip"
    w_in_inter: Annotated[float, Ge(0)] = 1.0   #: input -> interneuron weight ("identity")
    w_inh: Annotated[float, Ge(0)] = 50.0   #: interneuron -> motor inhibitory weight magnitude w_I


@dataclass
class StdpConfig:
    """Pair-based additive STDP on input->motor synapses (Eq. 2)."""

    #: "off": no plasticity; "window": the accumulated change of every decision window is
    #: written at the end of that window (the network uses it from the next window on);
    #: "trial_end": the same changes are accumulated on a copy that becomes the weights at
    #: the end of the trial (the trial itself runs on its initial weights).
    mode: Literal["off", "window", "trial_end"] = "trial_end"
    a_plus: Annotated[float, Ge(0)] = 0.04      #: potentiation amplitude A+ (weight per pair)
    a_minus: Annotated[float, Ge(0)] = 0.03     #: depression amplitude A- (weight per pair)
    tau_plus_ms: Annotated[float, Gt(0)] = 8.0  #: potentiation window time constant, ms
    tau_minus_ms: Annotated[float, Gt(0)] = 8.0  #: depression window time constant, ms
    w_min: float = 0.001         #: lowest weight STDP leaves (dimensionless)
    w_max: float = 1.0           #: highest weight STDP leaves (>= w_min)
    k: Annotated[float, Ge(0)] = 1.5    #: factor on the chosen move's accumulated change
    pairing: Literal["all_to_all", "nearest"] = "all_to_all"
    #: which candidate synapses receive a window's change: "all" = every candidate its own
    #: change (the chosen move's times k); "chosen" = only the chosen move's synapse (k times
    #: its change), the other candidates unchanged (route learning, Fig. 7);
    #: "depress_others" = chosen k*dw, the other candidates -|dw|; "normalize" = as "all",
    #: then the cell's outgoing weights are scaled back to their sum before the update
    #: (heterosynaptic normalisation; the HIL training reading, docs/hil.md).
    target: Literal["all", "chosen", "depress_others", "normalize"] = "chosen"
    #: "additive": the pair rule above (Eq. 2); "vteam": the memristive STDP of section 2.3,
    #: each pair's change read from the VTEAM device's STDP window (the ``vteam`` section)
    rule: Literal["additive", "vteam"] = "additive"


@dataclass
class VteamConfig:
    """Memristive STDP (section 2.3, Table tab_2, Fig. 2D): how the VTEAM device's window is
    read into the SNAN. The paper shows the spike and the weight <-> state mapping only as
    figures; every field is a named reading (docs/learning.md §5, the search).
    Used when ``stdp.rule = vteam``.

    Spike (both neurons emit it; the memristor sees post minus pre): a positive triangle of
    ``spike_a_pos_v`` and ``spike_t_pos_ms``, then a negative triangle of ``spike_a_neg_v``
    peaking ``spike_t_neg_peak_ms`` after it starts and ending ``spike_t_neg_ms`` later. Each
    lobe stays below the 0.6 V thresholds (only the overlap of two spikes switches).

    Defaults: the reading the search of docs/learning.md §5 found closest to the paper's Fig. 7
    on its seed (seed 1, 200 sessions per size): an 8 ms negative lobe, the barrier-state
    mapping, depression at a quarter of potentiation. Its figures on twenty seeds the search
    never used (the ones to quote): docs/learning.md §5.1 (``host/heldout.py``). The device's
    own balance and a 30 ms lobe (the crossbar model's
    :class:`~snan_hil.crossbar_model.vteam_stdp.BiTriangularSpike` defaults) do not learn
    (10x10: 24 % success after 20 cycles)."""

    spike_a_pos_v: Annotated[float, Gt(0)] = 0.5
    spike_t_pos_ms: Annotated[float, Gt(0)] = 1.0
    spike_a_neg_v: Annotated[float, Gt(0)] = 0.5
    spike_t_neg_peak_ms: Annotated[float, Gt(0)] = 0.5
    spike_t_neg_ms: Annotated[float, Gt(0)] = 8.0
    #: +1: post minus pre across the memristor (post after pre potentiates with a leading
    #: positive lobe); -1 the mirror image
    orientation: Literal[1, -1] = 1
    #: "conductance": w = normalized conductance (G - G_off)/(G_on - G_off), so steps grow
    #: with w (exponential memristance); "state": w = normalized barrier state
    #: (x_off - x)/(x_off - x_on), linear in ln G
    mapping: Literal["conductance", "state"] = "state"
    #: x_on..x_off of the device (not in the paper): "tunnel-3nm" or "window-40nm"
    bounds: Literal["tunnel-3nm", "window-40nm"] = "tunnel-3nm"
    #: largest potentiation of one pair at w = 0.5 (the window is scaled to it; 0: stdp.a_plus)
    peak: Annotated[float, Ge(0)] = 0.0
    #: depression / potentiation balance: 0 keeps the device's own; r > 0 rescales the
    #: depression branch so its largest change at w = 0.5 is r x the potentiation peak
    balance: Annotated[float, Ge(0)] = 0.25
    #: delay of a motor spike after the input spike of the same step (ms)
    latency_ms: Annotated[float, Ge(0)] = 1.0


@dataclass
class AstroConfig:
    """Glutamate, reduced 2nd-order calcium model, calcium-gated interneuron threshold."""

    enabled: bool = True
    a: Annotated[float, Ge(0)] = 0.73   #: calcium impulse amplitude A (dimensionless)
    #: calcium time constant tau_Ca in seconds (Table tab_1 gives 1.2 / 22 without a unit;
    #: the seconds reading and the measurements behind it are in docs/model.md)
    tau_ca_s: Annotated[float, Gt(0)] = 1.2
    alpha_n_per_ms: Annotated[float, Gt(0)] = 0.001  #: glutamate clearance rate, per ms
    k_n: Annotated[float, Ge(0)] = 0.2  #: glutamate release per input spike (dimensionless)
    g_thr: float = 0.2           #: glutamate threshold of a calcium impulse (dimensionless)
    ca_thr: float = 0.2          #: calcium threshold of the threshold drop (dimensionless)
    eta: Annotated[float, Ge(0)] = 5.0  #: astrocytic influence on v_thr_inter (dimensionless)

    @property
    def tau_ca_ms(self) -> float:
        """tau_Ca in ms (the simulation's time unit)."""
        return self.tau_ca_s * 1000.0


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
    vteam: VteamConfig = field(default_factory=VteamConfig)
    astro: AstroConfig = field(default_factory=AstroConfig)
    decision: DecisionConfig = field(default_factory=DecisionConfig)

    def __post_init__(self) -> None:
        validate(self)

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
        """Copy with whole sections or dotted keys set to typed values
        (``cfg.replace(**{"astro.enabled": False})``, ``cfg.replace(astro__a=6.0)``)."""
        return configio.apply(self, {k.replace("__", "."): v for k, v in sections.items()},
                              renamed=RENAMED)


# ---------------------------------------------------------------------------------------
# loading and overriding (the project's one loader, :mod:`snan_hil.config.loader`)

#: Keys of earlier versions, with what to give instead (shown in place of "unknown key").
RENAMED = {
    "astro.tau_ca": "give astro.tau_ca_s (the calcium time constant in seconds)",
    "astro.tau_ca_unit": "give astro.tau_ca_s in seconds (the old tau_ca_unit=ms reading is "
                         "tau_ca_s = tau_ca / 1000)",
}

Overrides = Union[Sequence[str], Mapping[str, Any]]


def from_dict(data: Mapping[str, Any], *, where: str = "") -> SnanConfig:
    """Build and validate a config from a (YAML) mapping; missing keys take the defaults."""
    return configio.from_tree(SnanConfig, data, where=where, renamed=RENAMED)


def from_stored(data: Mapping[str, Any], *, where: str = "stored config") -> SnanConfig:
    """A config saved by an earlier run (``to_dict()``, e.g. in a weights file), including
    the keys of earlier versions (``astro.tau_ca`` with ``astro.tau_ca_unit``)."""
    data = copy.deepcopy(dict(data))
    astro = data.get("astro")
    if isinstance(astro, dict) and "tau_ca" in astro and "tau_ca_s" not in astro:
        unit = astro.pop("tau_ca_unit", "s")
        tau = astro.pop("tau_ca")
        if isinstance(tau, (int, float)) and not isinstance(tau, bool):
            astro["tau_ca_s"] = float(tau) if unit == "s" else float(tau) / 1000.0
    return from_dict(data, where=where)


def apply_overrides(cfg: SnanConfig, overrides: Overrides, *, option: str = "--set"
                    ) -> SnanConfig:
    """A copy with overrides applied: ``section.key=value`` texts (the CLI's ``--set``, each
    value read for its field's type) or a mapping of dotted keys to typed values."""
    if isinstance(overrides, Mapping):
        return configio.apply(cfg, overrides, renamed=RENAMED)
    typed = configio.parse_assignments(SnanConfig, overrides, option=option, renamed=RENAMED)
    return configio.apply(cfg, typed, renamed=RENAMED)


def preset_path(name: str) -> pathlib.Path:
    return CONFIG_DIR / f"{name}.yaml"


def load_config(path: str | pathlib.Path | None = None, *, preset: str | None = None,
                overrides: Overrides = ()) -> SnanConfig:
    """Load a YAML file (or a named preset such as ``snan-3x3``) and apply overrides."""
    if path is None and preset is None:
        preset = "snan-3x3"
    p = pathlib.Path(path) if path is not None else preset_path(str(preset))
    if path is None and not p.is_file():
        known = ", ".join(sorted(q.stem for q in CONFIG_DIR.glob("snan-*.yaml")))
        raise ConfigError(f"no preset {preset!r} (presets: {known})")
    cfg = configio.load(SnanConfig, p, renamed=RENAMED)
    return apply_overrides(cfg, overrides)


def _check(cond: bool, msg: str) -> None:
    if not cond:
        raise ConfigError(msg)


def validate(cfg: SnanConfig) -> None:
    """The bounds declared beside the fields (:func:`snan_hil.config.loader.check_bounds`),
    then the checks across fields; raises ConfigError naming the first offending key."""
    configio.check_bounds(cfg)
    g, i, n, s, d, a = cfg.grid, cfg.input, cfg.neuron, cfg.synapse, cfg.stdp, cfg.astro
    _check(g.rows * g.cols >= 2, f"grid must have at least 2 cells (start != goal), got "
                                 f"grid.rows={g.rows}, grid.cols={g.cols}")
    steps = i.t_stim_ms / i.dt_ms
    _check(abs(steps - round(steps)) < 1e-9,
           f"input.t_stim_ms must be a whole number of input.dt_ms steps, got "
           f"{i.t_stim_ms} / {i.dt_ms}")
    rs = n.t_ref_ms / i.dt_ms
    _check(abs(rs - round(rs)) < 1e-9, f"neuron.t_ref_ms must be a whole number of "
                                       f"input.dt_ms steps, got {n.t_ref_ms} / {i.dt_ms}")
    _check(n.v_thr_motor > n.v_rest, f"neuron.v_thr_motor must be above neuron.v_rest, got "
                                     f"{n.v_thr_motor} <= {n.v_rest}")
    _check(n.v_thr_inter > n.v_rest, f"neuron.v_thr_inter must be above neuron.v_rest, got "
                                     f"{n.v_thr_inter} <= {n.v_rest}")
    lowest = min(n.v_thr_motor, n.v_thr_inter / (1 + max(a.eta, 0.0)))
    _check(n.v_reset < lowest, f"neuron.v_reset must be below every (astrocyte-lowered) "
                               f"threshold, got {n.v_reset} >= {lowest:g}")
    _check(s.w_lo <= s.w_hi, f"synapse.w_lo must be <= synapse.w_hi, got {s.w_lo} > {s.w_hi}")
    if s.init == "truncate":
        _check(s.w_std > 0 or s.w_lo <= s.w_mean <= s.w_hi,
               "synapse.init=truncate needs w_std > 0 or w_mean inside [w_lo, w_hi]")
    _check(d.w_min <= d.w_max, f"stdp.w_min must be <= stdp.w_max, got {d.w_min} > {d.w_max}")
    v = cfg.vteam
    _check(v.spike_t_neg_peak_ms < v.spike_t_neg_ms,
           "vteam.spike_t_neg_peak_ms must be below vteam.spike_t_neg_ms")
    _check(max(v.spike_a_pos_v, v.spike_a_neg_v) < 0.6,
           "vteam spike lobes must stay below the 0.6 V switching thresholds (Table tab_2): "
           "only the overlap of two spikes may switch the device")
    _check(a.tau_ca_ms >= i.dt_ms,
           f"astro.tau_ca_s must be at least one time step input.dt_ms (Euler is unstable "
           f"below), got {a.tau_ca_s} s < {i.dt_ms} ms")
    _check(0 < a.alpha_n_per_ms * i.dt_ms < 1,
           f"astro.alpha_n_per_ms * input.dt_ms must be in (0, 1), got {a.alpha_n_per_ms} * "
           f"{i.dt_ms}")

