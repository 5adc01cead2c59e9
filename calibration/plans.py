"""Pulse plans: ordered SET / RESET / read steps from a YAML file, run on one cell or many
(``snan-hil plan``).

A plan (the existing host's *ticket*, chained by its *planner*; shared/reference/anchors.md)
is a YAML 1.2 file, validated strictly (pydantic v2 strict models, unknown keys named with the
keys that exist there, every error one line)::

    format: snan-hil-plan/1
    name: switching-sweep
    description: SET ramp up and down, then RESET ramp up and down
    repeats: 1                       # the whole list of steps, again
    stop_when:                       # optional: ends the plan on the cell (after any read)
      conductance_s: {">": 1.3e-3}
    steps:
      - action: set                  # set | reset | read
        ramp: {start_v: 0.05, stop_v: 1.4, step_v: 0.05}   # or amplitude_v: 0.8
        # (a read step: none, the board's read voltage; or amplitude_v / ramp within the
        #  read limit: the current measured at each, an I-V in the read range)
        width_us: 100
        count: 1                     # pulses at each amplitude (a read step: reads)
        repeats: 1                   # the step's amplitudes, again
        interval_ms: 0               # wait after each pulse or read
        stop_when:                   # optional: ends this step, the plan goes on
          adc_code: {in: [7000, 7400]}

A ramp goes up (stop_v > start_v) or down (stop_v < start_v) by ``step_v`` (> 0), the stop
value included when the steps land on it. A terminator (``stop_when``) tests the conductance
(``conductance_s``, S) or the ADC code of the read (``adc_code``) with one of ``==``, ``<``,
``>``, ``in`` [low, high] or ``out`` [low, high] (the existing host's terminators);
``tolerance`` (relative, 0..1) widens ``==`` (needed for a conductance). It is tested before a
step's first pulse and after every read (each pulse is followed by one).

**Current.** The board measures the cell's current only with the ADC of a cell read, at a read
voltage (at most its read limit, 0.3 V); a write pulse has no ADC on its path. Every record
therefore carries ``read_v`` and ``current_a``: the voltage of its read (a pulse's: the read
after it) and the current the board measured there (:meth:`BoardConstants.cell_current_a
<snan_hil.protocol.board.BoardConstants.cell_current_a>`). A read step with ``amplitude_v`` or
a ``ramp`` reads at those voltages (refused above the read limit): an I-V of the cell in the
read range (the ``iv-curve`` preset, around a SET and a RESET ramp); ``switching-sweep`` is the
existing host's "IV" ticket, the conductance after each pulse of a sweep to 1.4 V.

Safety (host policy, :mod:`snan_hil.protocol.safety`): :func:`check_plan` refuses, before
anything is sent, a plan with any amplitude above the host's write limit or below one write-DAC
step, a width outside 1..:data:`MAX_WIDTH_US` us, or more than :data:`MAX_PLAN_PULSES` pulses
per cell -- one line naming the step. While running, a pulse the compliance limit forbids at the
cell's last conductance (``BoardCellIO.amplitude_cap``) ends its step ("compliance"); the plan
goes on with the next step (a RESET after a SET ramp is the usual way down). The cell's IO
(:class:`~snan_hil.calibration.board_io.BoardCellIO`) checks every pulse again.

Estimated time of a pulse (:func:`pulse_time_s`, dry run): its width, the board's documented
read time (``conversion_us``: DAC settling + 11 ADC conversions) and the request and reply on
the UART at the line rate (framed: the frames' wire size, an upper bound; legacy: the lines),
plus ``interval_ms``. Within 10 % of the emulated board's clock (framed;
tests/lab/test_plans.py); a real board adds MCU and SPI time the estimate does not know.

The preset library (:func:`preset_names`, :func:`load_preset`) ships with the package
(``calibration/plan_presets/*.yaml``) and covers the existing host's stock tickets, within
this board's 1.4 V write limit.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, ClassVar, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from snan_hil.calibration.job import check_cells
from snan_hil.calibration.layout import check_layout_writable
from snan_hil.calibration.observer import CellEvent, CellObserver, PulseEvent
from snan_hil.calibration.wv import PulseNotApplied
from snan_hil.common.errors import UserError
from snan_hil.common.polarity import Polarity
from snan_hil.common.progress import ProgressCallback, ProgressTracker, track
from snan_hil.config.loader import ConfigError, parse_yaml
from snan_hil.protocol.board import BoardConstants
from snan_hil.protocol.frames import wire_size
from snan_hil.protocol.legacy_codec import LegacyPulse, LegacyRead, format_reply, format_request
from snan_hil.protocol.messages import ReadCell, ReadCellReply, WritePulse, WritePulseReply
from snan_hil.protocol.safety import MAX_WRITE_OPTION
from snan_hil.protocol.transport import wire_seconds

__all__ = ["PLAN_FORMAT", "MAX_PLAN_PULSES", "MAX_WIDTH_US", "PlanError", "Ramp", "Condition",
           "RENAMED_PRESETS",
           "StopWhen", "Step", "Plan", "PlannedPulse", "parse_plan", "load_plan",
           "preset_names", "load_preset", "preset_text", "expand", "check_plan",
           "compliance_g_limit_s", "pulse_time_s", "PlanRecord", "CellPlanResult", "run_plan",
           "run_plan_on_cell", "INTERRUPTED", "PlanCell", "PlanRun", "PlanJob"]

log = logging.getLogger(__name__)

PLAN_FORMAT = "snan-hil-plan/1"
MAX_PLAN_PULSES = 100_000
"""Most pulses (and reads) a plan may plan on one cell (the existing host's largest stock
ticket has ~564; an endurance test of 50,000 cycles fits)."""
MAX_WIDTH_US = 1_000_000
"""Longest pulse, us (the emulated firmware's limit,
``firmware_emu.config.BoardConfig.max_pulse_width_us``; the real board's is not public)."""
PRESETS_PACKAGE = "snan_hil.calibration"
PRESETS_FOLDER = "plan_presets"


class PlanError(UserError):
    """A plan that cannot be used as given (one line, exit code 2)."""


class _Strict(BaseModel):
    model_config = ConfigDict(strict=True, extra="forbid", allow_inf_nan=False, frozen=True,
                              populate_by_name=True)


class Ramp(_Strict):
    """Amplitudes from ``start_v`` to ``stop_v`` (up or down) by ``step_v`` (V, > 0)."""

    start_v: float = Field(gt=0)
    stop_v: float = Field(gt=0)
    step_v: float = Field(gt=0)

    @model_validator(mode="after")
    def _not_too_long(self) -> Ramp:
        # counted before any amplitude is built: a tiny step_v must not fill the memory
        if self.count() > MAX_PLAN_PULSES:
            raise ValueError(f"a ramp of {self.count():.3g} amplitudes; at most "
                             f"{MAX_PLAN_PULSES} (give a larger step_v)")
        return self

    def count(self) -> int:
        """Number of amplitudes of the ramp (the stop included when a step lands on it)."""
        if self.start_v == self.stop_v:
            return 1
        return int(math.floor(abs(self.stop_v - self.start_v) / self.step_v + 1e-9)) + 1

    def amplitudes(self) -> tuple[float, ...]:
        if self.start_v == self.stop_v:
            return (self.start_v,)
        sign = 1.0 if self.stop_v > self.start_v else -1.0
        return tuple(round(self.start_v + sign * i * self.step_v, 6) for i in range(self.count()))

    def text(self) -> str:
        return f"ramp {self.start_v:g}->{self.stop_v:g} V by {self.step_v:g} V"


class Condition(_Strict):
    """One test of a reading: exactly one of ``==``, ``<``, ``>``, ``in``, ``out``."""

    eq: float | None = Field(None, alias="==")
    lt: float | None = Field(None, alias="<")
    gt: float | None = Field(None, alias=">")
    inside: list[float] | None = Field(None, alias="in", min_length=2, max_length=2)
    outside: list[float] | None = Field(None, alias="out", min_length=2, max_length=2)
    tolerance: float = Field(0.0, ge=0, lt=1)

    @model_validator(mode="after")
    def _one(self) -> Condition:
        given = [k for k in ("eq", "lt", "gt", "inside", "outside")
                 if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError("give exactly one of ==, <, >, in, out")
        for k in ("inside", "outside"):
            pair = getattr(self, k)
            if pair is not None and not pair[0] <= pair[1]:
                raise ValueError(f"{'in' if k == 'inside' else 'out'}: give [low, high] with "
                                 "low <= high")
        return self

    def met(self, x: float) -> bool:
        if not math.isfinite(x):
            return False
        if self.eq is not None:
            return abs(x - self.eq) <= self.tolerance * abs(self.eq)
        if self.lt is not None:
            return x < self.lt
        if self.gt is not None:
            return x > self.gt
        if self.inside is not None:
            return self.inside[0] <= x <= self.inside[1]
        assert self.outside is not None
        return not self.outside[0] <= x <= self.outside[1]

    def text(self, fmt: Callable[[float], str]) -> str:
        if self.eq is not None:
            tol = f" +-{self.tolerance:.0%}" if self.tolerance else ""
            return f"== {fmt(self.eq)}{tol}"
        if self.lt is not None:
            return f"< {fmt(self.lt)}"
        if self.gt is not None:
            return f"> {fmt(self.gt)}"
        pair = self.inside if self.inside is not None else self.outside
        assert pair is not None
        return f"{'in' if self.inside is not None else 'out of'} [{fmt(pair[0])}, {fmt(pair[1])}]"


class StopWhen(_Strict):
    """A terminator on the conductance (S) or the ADC code of a read (exactly one)."""

    conductance_s: Condition | None = None
    adc_code: Condition | None = None

    @model_validator(mode="after")
    def _one(self) -> StopWhen:
        if (self.conductance_s is None) == (self.adc_code is None):
            raise ValueError("give exactly one of conductance_s, adc_code")
        c = self.conductance_s
        if c is not None and c.eq is not None and c.tolerance == 0:
            raise ValueError("conductance_s ==: give a tolerance (relative, e.g. 0.05); a "
                             "noisy conductance is never exactly equal")
        return self

    def met(self, g_s: float, adc: int | None) -> bool:
        if self.conductance_s is not None:
            return self.conductance_s.met(g_s)
        assert self.adc_code is not None
        return adc is not None and self.adc_code.met(float(adc))

    def text(self) -> str:
        if self.conductance_s is not None:
            return "G " + self.conductance_s.text(lambda s: f"{s * 1e6:g} uS")
        assert self.adc_code is not None
        return "ADC " + self.adc_code.text(lambda c: f"{c:g}")


class Step(_Strict):
    """One step: ``action`` set / reset (pulses; ``amplitude_v`` or ``ramp``) or read."""

    action: Literal["set", "reset", "read"]
    amplitude_v: float | None = Field(None, gt=0)
    ramp: Ramp | None = None
    width_us: int = Field(100, ge=1, le=MAX_WIDTH_US)
    count: int = Field(1, ge=1)
    repeats: int = Field(1, ge=1)
    interval_ms: float = Field(0.0, ge=0, le=3_600_000)
    stop_when: StopWhen | None = None
    name: str | None = None

    @model_validator(mode="after")
    def _amplitudes(self) -> Step:
        if self.action == "read":
            if self.amplitude_v is not None and self.ramp is not None:
                raise ValueError("a read step takes amplitude_v or ramp (read voltages, at "
                                 "most the board's read limit), not both")
        elif (self.amplitude_v is None) == (self.ramp is None):
            raise ValueError(f"a {self.action} step needs exactly one of amplitude_v, ramp")
        return self

    @property
    def measures(self) -> bool:
        """A read step at voltages of its own (``amplitude_v`` or ``ramp``): it records the
        current the board measures at each (an I-V sweep within the read range)."""
        return self.action == "read" and (self.amplitude_v is not None or self.ramp is not None)

    @property
    def polarity(self) -> Polarity | None:
        return None if self.action == "read" else Polarity.parse(self.action)

    def amplitudes(self) -> tuple[float, ...]:
        """The step's amplitudes in order (V; a read step at the board's read voltage: one
        entry, 0)."""
        if self.ramp is not None:
            return self.ramp.amplitudes()
        return (self.amplitude_v,) if self.amplitude_v is not None else (0.0,)

    def n_pulses(self) -> int:
        """Pulses (a read step: reads) the step plans, at most (before terminators)."""
        return len(self.amplitudes()) * self.count * self.repeats

    def text(self) -> str:
        at = ("" if not self.measures else " at " + (self.ramp.text() if self.ramp is not None
                                                      else f"{self.amplitude_v:g} V"))
        what = (f"{self.count} read(s){at}" if self.action == "read" else
                f"{self.action.upper()} " + (self.ramp.text() if self.ramp is not None
                                             else f"{self.amplitude_v:g} V")
                + (f" x{self.count}" if self.count > 1 else "") + f", {self.width_us} us")
        if self.repeats > 1:
            what += f", {self.repeats} times"
        if self.stop_when is not None:
            what += f", until {self.stop_when.text()}"
        return (f"{self.name}: " if self.name else "") + what


class Plan(_Strict):
    """A pulse plan (module docstring)."""

    format: Literal["snan-hil-plan/1"]
    name: str = Field(min_length=1)
    description: str = ""
    repeats: int = Field(1, ge=1)
    stop_when: StopWhen | None = None
    steps: list[Step] = Field(min_length=1)

    def n_pulses(self) -> int:
        """Pulses and reads the plan plans on one cell, at most."""
        return self.repeats * sum(s.n_pulses() for s in self.steps)

    def n_write_pulses(self) -> int:
        return self.repeats * sum(s.n_pulses() for s in self.steps if s.action != "read")

    def to_tree(self) -> dict[str, Any]:
        """The plan as the YAML/JSON tree it was read from (aliases, defaults left out)."""
        return self.model_dump(by_alias=True, exclude_none=True, exclude_defaults=True) | {
            "format": PLAN_FORMAT, "name": self.name}


# ------------------------------------------------------------------ reading a plan
_PHRASES = {
    "int_type": "expected an integer", "float_type": "expected a number",
    "string_type": "expected a text", "bool_type": "expected true or false",
    "finite_number": "expected a finite number", "literal_error": "expected one of {expected}",
    "greater_than": "must be > {gt}", "greater_than_equal": "must be >= {ge}",
    "less_than": "must be < {lt}", "less_than_equal": "must be <= {le}",
    "list_type": "expected a list", "model_type": "expected a mapping of keys to values",
    "dict_type": "expected a mapping of keys to values",
    "too_short": "expected at least {min_length} item(s)",
    "too_long": "expected at most {max_length} item(s)",
    "missing": "missing (required)",
}


def _model_at(loc: Sequence[Any]) -> type[BaseModel] | None:
    """The model class that holds the last key of ``loc`` (for the list of known keys)."""
    model: Any = Plan
    for part in loc[:-1]:
        if isinstance(part, int):
            continue
        fields = model.model_fields
        name = next((n for n, f in fields.items() if part in (n, f.alias)), None)
        if name is None:
            return None
        ann = fields[name].annotation
        inner = _model_of(ann)
        if inner is None:
            return None
        model = inner
    return model


def _model_of(ann: Any) -> type[BaseModel] | None:
    if isinstance(ann, type) and issubclass(ann, BaseModel):
        return ann
    for arg in getattr(ann, "__args__", ()) or ():
        found = _model_of(arg)
        if found is not None:
            return found
    return None


def _path(loc: Sequence[Any]) -> str:
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out or "the top level"


def _one_line(exc: ValidationError, where: str) -> PlanError:
    err = exc.errors()[0]
    loc = [p for p in err.get("loc", ()) if not (isinstance(p, str) and "[" in p)]
    kind = err["type"]
    if kind == "extra_forbidden":
        model = _model_at(loc)
        known = sorted((f.alias or n) for n, f in model.model_fields.items()) if model else []
        return PlanError(f"{where}: unknown key {_path(loc)}"
                         + (f" (known there: {', '.join(known)})" if known else ""))
    if kind == "value_error":
        msg = str(err.get("msg", "")).removeprefix("Value error, ")
        return PlanError(f"{where}: {_path(loc)}: {msg}")
    phrase = _PHRASES.get(kind)
    text = phrase.format(**err.get("ctx", {})) if phrase else str(err.get("msg"))
    got = "" if kind == "missing" else f", got {err.get('input')!r}"
    return PlanError(f"{where}: {_path(loc)}: {text}{got}")


def parse_plan(tree: Any, where: str = "plan") -> Plan:
    """A :class:`Plan` from a mapping (a YAML file's or a history run's); PlanError (one line
    naming the key) otherwise."""
    if not isinstance(tree, dict):
        raise PlanError(f"{where}: expected a mapping with format: {PLAN_FORMAT}, name: and "
                        "steps:, got " + type(tree).__name__)
    if tree.get("format") != PLAN_FORMAT:
        raise PlanError(f"{where}: not a pulse plan (its format: is {tree.get('format')!r}, "
                        f"a plan has format: {PLAN_FORMAT}); see 'snan-hil plan presets'")
    try:
        return Plan.model_validate(tree)
    except ValidationError as exc:
        raise _one_line(exc, where) from None


RENAMED_PRESETS = {
    "iv-curve-reversed": "switching-sweep-reversed",
    "iv-curve-set": "switching-sweep-set",
    "iv-curve-reset": "switching-sweep-reset",
}
"""Presets of an earlier version named for what they did not record (they read G after each
pulse; the board measures no current during a pulse): the old name -> the new one. The old
``iv-curve`` is ``switching-sweep``; ``iv-curve`` now measures current in the read range."""


def load_plan(path: str | Path) -> Plan:
    """Read a plan file, or a preset by its name (``iv-curve``) when no such file exists."""
    p = Path(path).expanduser()
    if not p.exists() and str(path) in preset_names():
        return load_preset(str(path))
    if not p.exists() and str(path) in RENAMED_PRESETS:
        raise PlanError(f"preset {path} is now {RENAMED_PRESETS[str(path)]}: it records the "
                        "conductance after each pulse, not a current (iv-curve measures the "
                        "current in the read range)")
    if p.is_dir():
        raise PlanError(f"plan {p}: is a folder; give a plan file (YAML)")
    if not p.is_file():
        hint = ", ".join(preset_names())
        raise PlanError(f"plan {p}: no such file, and not a preset (presets: {hint})")
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise PlanError(f"plan {p}: cannot read it ({getattr(exc, 'strerror', None) or exc})"
                        ) from None
    try:
        tree = parse_yaml(text, f"plan {p}")
    except ConfigError as exc:
        raise PlanError(str(exc)) from None
    return parse_plan(tree, f"plan {p}")


def _presets() -> Any:
    return resources.files(PRESETS_PACKAGE).joinpath(PRESETS_FOLDER)


def preset_names() -> list[str]:
    """Names of the shipped presets (sorted)."""
    return sorted(f.name[:-len(".yaml")] for f in _presets().iterdir()
                  if f.name.endswith(".yaml"))


def preset_text(name: str) -> str:
    """The YAML text of preset ``name`` (PlanError naming the presets for an unknown one)."""
    if name not in preset_names():
        raise PlanError(f"no preset {name!r}; presets: {', '.join(preset_names())}")
    return str(_presets().joinpath(f"{name}.yaml").read_text(encoding="utf-8"))


def load_preset(name: str) -> Plan:
    try:
        tree = parse_yaml(preset_text(name), f"preset {name}")
    except ConfigError as exc:
        raise PlanError(str(exc)) from None
    return parse_plan(tree, f"preset {name}")


# ------------------------------------------------------------------ what a plan sends
@dataclass(frozen=True)
class PlannedPulse:
    """One pulse (or read) a plan plans on a cell, before terminators: ``step`` and the
    repeats are 1-based; ``amplitude_v`` as asked, ``applied_v`` the write-DAC code's voltage
    (floor: never above), ``code`` that code (reads: 0)."""

    n: int
    plan_repeat: int
    step: int
    step_repeat: int
    action: str
    amplitude_v: float
    applied_v: float
    code: int
    width_us: int
    interval_ms: float


def _dac_floor(board: BoardConstants, volts: float) -> int:
    return int(math.floor(volts * board.write_dac_full_scale_code / board.write_dac_vref_v
                          + 1e-9))


def expand(plan: Plan, board: BoardConstants) -> Iterator[PlannedPulse]:
    """Every pulse and read the plan plans on one cell, in order (no terminator applied)."""
    n = 0
    for rep in range(1, plan.repeats + 1):
        for i, step in enumerate(plan.steps, 1):
            for srep in range(1, step.repeats + 1):
                for amp in step.amplitudes():
                    plain_read = step.action == "read" and not step.measures
                    code = 0 if plain_read else _dac_floor(board, amp)
                    applied = 0.0 if plain_read else board.write_dac_volts(code)
                    for _ in range(step.count):
                        n += 1
                        yield PlannedPulse(n, rep, i, srep, step.action, amp, applied, code,
                                           step.width_us, step.interval_ms)


def check_plan(plan: Plan, board: BoardConstants, max_write_v: float | None = None,
               where: str = "plan") -> None:
    """PlanError (one line naming the step) unless every pulse of ``plan`` fits the host's
    limits: amplitudes at most the write limit (``max_write_v``: the one set with
    ``--max-write-v``; None: the board's) and at least one write-DAC step, at most
    :data:`MAX_PLAN_PULSES` pulses and reads per cell. Called before anything is sent."""
    limit = board.max_write_v if max_write_v is None else float(max_write_v)
    lsb = board.write_dac_volts(1)
    for i, step in enumerate(plan.steps, 1):
        if step.action == "read" and not step.measures:
            continue
        amps = step.amplitudes()
        top, low = max(amps), min(amps)
        label = f"{where} {plan.name}: step {i} ({step.text()})"
        if step.action == "read":
            read_top = board.write_dac_volts(board.max_read_code)
            if top > read_top + 1e-9:
                raise PlanError(f"{label}: a read at {top:g} V is above the board's read "
                                f"limit {board.max_read_v:g} V (the largest read code is "
                                f"{board.max_read_code} = {read_top:.4f} V: higher voltages "
                                "would change the cell); nothing was sent")
            if low < lsb:
                raise PlanError(f"{label}: a read at {low:g} V is below the DAC's smallest "
                                f"step {lsb:.4f} V; nothing was sent")
            continue
        if top > limit + 1e-9:
            whose = (f"the board's max_write_v; {MAX_WRITE_OPTION} can only lower it"
                     if max_write_v is None else f"the board's, lowered by {MAX_WRITE_OPTION}")
            raise PlanError(f"{label}: {top:g} V is above the host's write limit {limit:g} V "
                            f"({whose}); nothing was sent")
        if low < lsb:
            raise PlanError(f"{label}: {low:g} V is below the write DAC's smallest step "
                            f"{lsb:.4f} V; nothing was sent")
    n = plan.n_pulses()
    if n > MAX_PLAN_PULSES:
        raise PlanError(f"{where} {plan.name}: {n} pulses and reads per cell; at most "
                        f"{MAX_PLAN_PULSES} (fewer repeats or larger ramp steps)")


def compliance_g_limit_s(board: BoardConstants, volts: float, margin: float = 0.95) -> float:
    """The largest cell conductance (S) at which a pulse of ``volts`` stays under the
    compliance current (``margin`` x ``compliance_a``; predicted I = V / (1/G + R_sw), the
    host's rule, :class:`~snan_hil.calibration.board_io.BoardCellIO`); inf when no
    conductance reaches it."""
    i_max = board.compliance_a * margin
    denom = volts - i_max * board.r_switch_ohm
    return math.inf if denom <= 0 else i_max / denom


def pulse_time_s(board: BoardConstants, pulse: PlannedPulse, *, protocol: str = "framed",
                 baud: int | None = 115200) -> float:
    """Estimated time of one planned pulse or read (s; module docstring: a lower bound)."""
    full = board.adc_full_scale_code if hasattr(board, "adc_full_scale_code") else 16383
    if protocol == "legacy":
        req = (format_request(LegacyRead(board.read_code, 4096, 7, 31)) if pulse.action == "read"
               else format_request(LegacyPulse(pulse.code, pulse.width_us // 1000,
                                               pulse.width_us % 1000, 1, 4096, 7, 31)))
        n_bytes = len(req) + len(format_reply(full, 4096))
    else:
        if pulse.action == "read":
            n_bytes = (wire_size(len(ReadCell(31, 7, board.read_code).encode()))
                       + wire_size(len(ReadCellReply(full).encode())))
        else:
            n_bytes = (wire_size(len(WritePulse(31, 7, Polarity.SET, pulse.code, pulse.width_us,
                                                board.read_code).encode()))
                       + wire_size(len(WritePulseReply(full).encode())))
    width = 0 if pulse.action == "read" else pulse.width_us
    return ((width + board.conversion_us) * 1e-6 + wire_seconds(n_bytes, baud)
            + pulse.interval_ms * 1e-3)


# ------------------------------------------------------------------ running a plan
@dataclass(frozen=True)
class PlanRecord:
    """One pulse or read a plan applied (V, us, S; ``adc`` the read's code)."""

    n: int
    plan_repeat: int
    step: int
    action: str
    amplitude_v: float
    width_us: int
    g_before_s: float
    g_after_s: float
    adc: int | None
    read_v: float | None = None
    """The voltage of the read (V; a pulse's: the read after it)."""
    current_a: float | None = None
    """The cell's current the board measured at ``read_v`` (A; the read's ADC code through the
    read chain): the board measures current only at read voltages, never during a pulse."""
    cell_v: float | None = None
    """The voltage across the cell (memristor and select transistor) during that read (V):
    ``read_v`` less the drop over the read chain's load and switch resistors."""


@dataclass
class CellPlanResult:
    """What a plan did on one cell: the read before, every pulse and read, why each step and
    the plan ended."""

    row: int
    col: int
    initial_s: float
    records: list[PlanRecord] = field(default_factory=list)
    steps: list[dict[str, Any]] = field(default_factory=list)
    stopped: str = ""

    @property
    def final_s(self) -> float:
        return self.records[-1].g_after_s if self.records else self.initial_s

    @property
    def pulses(self) -> int:
        return sum(1 for r in self.records if r.action != "read")

    def to_dict(self, records: bool = True) -> dict[str, Any]:
        d: dict[str, Any] = {"row": self.row, "col": self.col, "initial_s": self.initial_s,
                             "final_s": self.final_s, "pulses": self.pulses,
                             "reads": sum(1 for r in self.records if r.action == "read"),
                             "stopped": self.stopped, "steps": self.steps}
        if records:
            d["records"] = [r.__dict__ for r in self.records]
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> CellPlanResult:
        """The result :meth:`to_dict` (with its records) gave."""
        return cls(int(d["row"]), int(d["col"]), float(d["initial_s"]),
                   [PlanRecord(**r) for r in d.get("records", [])], list(d.get("steps", [])),
                   str(d.get("stopped", "")))


INTERRUPTED = "interrupted: the run was stopped before the plan ended on this cell"
"""``CellPlanResult.stopped`` of the cell a run was interrupted on (:func:`run_plan`)."""


class _PlanEnd(Exception):
    """The plan's own terminator was met on this cell."""


def run_plan(make_io: Callable[[int, int], Any], cells: Sequence[tuple[int, int]], plan: Plan,
             *, observer: CellObserver | None = None, progress: ProgressCallback | None = None,
             on_read: Callable[..., None] | None = None,
             sleep: Callable[[float], None] = time.sleep,
             results: list[CellPlanResult] | None = None) -> list[CellPlanResult]:
    """Run ``plan`` on each of ``cells`` in turn (``make_io(row, col)``: the cell's IO, a
    :class:`~snan_hil.calibration.board_io.BoardCellIO` in practice; its ``last_adc`` feeds
    ADC terminators). Check the plan first (:func:`check_plan`: the caller's job, before the
    board is opened).

    ``observer`` gets every pulse as soon as it was applied (``on_pulses`` with one event,
    stage "plan step K") and each cell's result (outcome = why the plan ended there);
    ``on_read(row, col, adc, g_s, what, read_v=V, current_a=A)`` every read of a read step
    (its voltage and the current measured; None where unknown); ``progress`` the task
    "plan NAME" (one unit per planned pulse or read, over all cells).

    ``results``: the list the cells' results are appended to (returned; default a new one).
    When the run is interrupted (KeyboardInterrupt: Ctrl-C, or a stop from ``snan-hil watch``
    between two requests) the cell in progress is appended with what it applied,
    ``stopped`` = :data:`INTERRUPTED` (no cell result goes to ``observer``), and the
    exception goes on: the caller's list holds every pulse and read applied."""
    results = [] if results is None else results
    bar = track(progress, f"plan {plan.name}", plan.n_pulses() * len(cells))
    for k, (row, col) in enumerate(cells):
        run_plan_on_cell(make_io(row, col), (row, col), plan, observer=observer, on_read=on_read,
                         sleep=sleep, bar=bar, base=k * plan.n_pulses(), results=results)
    return results


def run_plan_on_cell(io: Any, cell: tuple[int, int], plan: Plan, *,
                     observer: CellObserver | None = None,
                     on_read: Callable[[int, int, int | None, float, str], None] | None = None,
                     sleep: Callable[[float], None] = time.sleep,
                     bar: ProgressTracker | None = None, base: int = 0,
                     results: list[CellPlanResult] | None = None) -> CellPlanResult:
    """Run ``plan`` on ``cell`` (row, col) through its IO ``io`` (see :func:`run_plan`): its
    result, appended to ``results`` too (also the cut one when the run is interrupted,
    ``stopped`` = :data:`INTERRUPTED`, before the exception goes on). ``bar``: the run's
    progress task, at ``base`` units done when this cell starts. Each pulse goes out with
    the step's width and, on a :class:`~snan_hil.calibration.board_io.BoardCellIO`, as
    stage "plan step K"."""
    results = [] if results is None else results
    bar = bar if bar is not None else track(None, f"plan {plan.name}", plan.n_pulses())
    row, col = int(cell[0]), int(cell[1])
    res = CellPlanResult(row, col, float(io.read()))
    state: dict[str, Any] = {"g": res.initial_s, "adc": getattr(io, "last_adc", None)}
    res.stopped = f"all {plan.repeats} repeat(s) of the plan done"
    done = 0
    try:
        if plan.stop_when is not None and plan.stop_when.met(state["g"], state["adc"]):
            raise _PlanEnd(f"plan condition {plan.stop_when.text()} already met")
        for rep in range(1, plan.repeats + 1):
            for i, step in enumerate(plan.steps, 1):
                outcome, n = _run_step(io, plan, step, i, rep, res, state, observer,
                                       on_read, sleep, bar, base + done)
                done += step.n_pulses()
                res.steps.append({"plan_repeat": rep, "step": i, "applied": n,
                                  "stopped": outcome})
    except _PlanEnd as end:
        res.stopped = str(end)
    except KeyboardInterrupt:
        res.stopped = INTERRUPTED
        results.append(res)
        raise
    bar.update(base + plan.n_pulses(), f"cell ({row},{col}): {res.stopped}")
    results.append(res)
    if observer is not None:
        observer.on_cell(CellEvent(row, col, res.stopped, res.final_s, pulses=res.pulses,
                                   detail={"initial_s": res.initial_s, "plan": plan.name,
                                           "steps": res.steps}))
    return res


def _run_step(io: Any, plan: Plan, step: Step, index: int, rep: int, res: CellPlanResult,
              state: dict[str, Any], observer: CellObserver | None,
              on_read: Callable[..., None] | None, sleep: Callable[[float], None],
              bar: Any, base: int) -> tuple[str, int]:
    """Apply one step; returns (why it ended, pulses/reads applied). Raises _PlanEnd."""
    applied = 0
    stage = f"plan step {index}"
    if step.stop_when is not None and step.stop_when.met(state["g"], state["adc"]):
        return f"condition {step.stop_when.text()} already met", 0
    pol = step.polarity
    if pol is not None and hasattr(io, "width_us"):
        io.width_us = step.width_us               # the step's pulses, at the step's width
    if hasattr(io, "stage"):
        io.stage = stage                          # what the bench records them as
    for _srep in range(step.repeats):
        for amp in step.amplitudes():
            for _ in range(step.count):
                g = state["g"]
                got = _apply_one(io, step, pol, amp, g)
                if isinstance(got, str):
                    return got, applied              # the compliance rule ends the step
                if got is None:                      # a pulse that verifiably did not run
                    state["g"] = float(io.read())
                    state["adc"] = getattr(io, "last_adc", None)
                    continue
                after, v_applied, width, read_v, current = got
                adc = getattr(io, "last_adc", None)
                if read_v is None:
                    read_v, current = _read_current(io, adc)
                applied += 1
                res.records.append(PlanRecord(len(res.records) + 1, rep, index, step.action,
                                              v_applied, width, g, after, adc, read_v,
                                              current, _cell_v(io, read_v, current)))
                if pol is not None and observer is not None:
                    observer.on_pulses([PulseEvent(res.row, res.col, pol, v_applied, width, g,
                                                   after, stage)])
                elif pol is None and on_read is not None:
                    on_read(res.row, res.col, adc, after, stage, read_v=read_v,
                            current_a=current)
                state["g"], state["adc"] = after, adc
                bar.update(base + applied,
                           f"cell ({res.row},{res.col}) step {index}: "
                           + (f"{v_applied:.3f} V -> " if pol is not None else "read ")
                           + f"{after * 1e6:.1f} uS")
                if step.interval_ms:
                    sleep(step.interval_ms * 1e-3)
                if plan.stop_when is not None and plan.stop_when.met(after, adc):
                    raise _PlanEnd(f"plan condition {plan.stop_when.text()} met")
                if step.stop_when is not None and step.stop_when.met(after, adc):
                    return f"condition {step.stop_when.text()} met", applied
    return "all planned pulses applied" if pol is not None else "all reads done", applied


def _apply_one(io: Any, step: Step, pol: Polarity | None, amp: float, g: float
               ) -> tuple[float, float, int, float | None, float | None] | str | None:
    """One pulse (``pol``) or read of a step at ``amp`` (V) on a cell at ``g`` (S): (G after,
    the applied amplitude V, width us, read voltage V, current A; the last two None when the
    read was at the usual read code), the line that ends the step when the compliance rule
    forbids the pulse, None when the pulse verifiably did not run."""
    if pol is None and step.measures:
        after, current, read_v = io.measure(amp)
        return float(after), read_v, 0, read_v, current
    if pol is None:
        return float(io.read()), 0.0, 0, None, None
    cap = float(io.amplitude_cap(pol, g)) if g > 0 else amp
    if amp > cap + 1e-9:
        return (f"compliance: a {amp:g} V pulse at G = {g * 1e6:.1f} uS would draw more than "
                f"the current limit (at most {cap:.2f} V now)")
    log_ = getattr(io, "applied", None)
    before_len = len(log_) if log_ is not None else 0
    try:
        after = float(io.pulse(pol, amp))
    except PulseNotApplied:
        return None
    v_applied = (float(log_[-1].amplitude_v)
                 if log_ is not None and len(log_) > before_len else amp)
    return after, v_applied, step.width_us, None, None


def _read_current(io: Any, adc: int | None) -> tuple[float | None, float | None]:
    """(read voltage V, current A) of the cell's last read at its usual read code, through
    its read chain; (None, None) for an IO without one (a model of the array)."""
    chain, limits = getattr(io, "chain", None), getattr(io, "limits", None)
    if adc is None or chain is None or limits is None:
        return None, None
    return (float(chain.cell_read_volts(limits.read_code)),
            float(chain.cell_current_a(adc)))


def _cell_v(io: Any, read_v: float | None, current: float | None) -> float | None:
    """The voltage across the cell during a read (V): ``read_v - I (R_load + R_sw)``."""
    chain = getattr(io, "chain", None)
    if read_v is None or current is None or chain is None:
        return None
    return float(read_v - current * (chain.r_load_ohm + chain.r_switch_ohm))


# ------------------------------------------------------------------ the plan as a board job
@dataclass(frozen=True)
class PlanCell:
    """A cell a plan runs on (a unit of :class:`PlanJob`)."""

    row: int
    col: int

    @property
    def key(self) -> str:
        return f"cell-{self.row}-{self.col}"

    @property
    def group(self) -> str | None:
        return None


@dataclass
class PlanRun:
    """What a plan run gave: per cell its result in run order (an interrupted run: the cells
    that finished, then the one it was cut on, ``stopped`` = :data:`INTERRUPTED`), where
    the reads' conductances came from (``read_chain``) and the status."""

    cells: list[CellPlanResult]
    read_chain: str
    status: str = "complete"


class PlanJob:
    """``snan-hil plan run`` / ``plan repeat`` as a board job (:mod:`snan_hil.calibration.job`):
    ``plan`` on ``cells`` (a unit per cell, in order). ``source``: where the plan came from
    (a file, a preset, a history run), ``extra``: more of the run's config (``repeat_of``),
    both recorded with the run (``plan repeat`` reads them back); ``names``: how the front
    door spells the config's fields in messages (default the field names). Every pulse is
    journalled and recorded by the bench as it is applied (stage "plan step K"); the reads
    of read steps go to the run's ``reads`` stream; synapses of the board's layout on cells
    the plan pulses are marked stale as each cell ends (or is cut)."""

    kind: ClassVar[str] = "plan"
    restartable: ClassVar[bool] = False

    def __init__(self, plan: Plan, cells: Sequence[tuple[int, int]], *, source: str,
                 extra: dict[str, Any] | None = None, names: dict[str, str] | None = None,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        self.plan_ = plan
        self.cells = [(int(r), int(c)) for r, c in cells]
        self.source, self.extra = source, dict(extra or {})
        self.names = names or {}
        self.sleep = sleep
        self.read_chain = ""
        self.cut: CellPlanResult | None = None
        """The cell a stop or Ctrl-C cut short (what it applied), for an interrupted run."""
        self._stale: dict[tuple[int, int], Any] = {}
        self._bar: ProgressTracker | None = None

    def describe(self) -> dict[str, Any]:
        return {"plan": self.plan_.to_tree(), "source": self.source,
                "cells": [list(c) for c in self.cells], **self.extra}

    def plan(self, bench: Any) -> list[PlanCell]:
        """The cells checked against the board, the plan against its limits (PlanError,
        one line naming the step); the layout checked writable when the plan pulses cells
        that hold programmed synapses (a warning names them)."""
        check_cells(self.cells, bench.info, self.names.get("cells", "cells"))
        limit = float(bench.limits.max_write_v)
        check_plan(self.plan_, bench.info,
                   limit if limit < float(bench.info.max_write_v) - 1e-9 else None)
        self.read_chain = bench.chain_source
        layout = bench.layout
        found = [(c, layout.synapse_at(*c)) for c in self.cells] if layout is not None else []
        self._stale = {c: s for c, s in found if s is not None and s.weight is not None}
        if self._stale and self.plan_.n_write_pulses():
            check_layout_writable(bench.layout_path)
            bench.warn(f"{len(self._stale)} of the cells hold programmed synapses of "
                       f"{bench.layout_path}; the plan changes them, so the layout marks them "
                       "stale until program-weights writes them again")
        return [PlanCell(r, c) for r, c in self.cells]

    def run_unit(self, unit: PlanCell, bench: Any, ctx: Any) -> dict[str, Any]:
        plan, per_cell = self.plan_, self.plan_.n_pulses()
        if self._bar is None:
            self._bar = track(ctx.progress, f"plan {plan.name}", per_cell * len(self.cells))
        io = bench.cell(unit.row, unit.col, stage="plan")
        info = bench.info

        def on_read(row: int, col: int, adc: int | None, g: float, what: str, *,
                    read_v: float | None = None, current_a: float | None = None) -> None:
            v = info.write_dac_volts(io.limits.read_code) if read_v is None else read_v
            ctx.emit("reads", {"row": row, "col": col, "adc": adc,
                               "read_code": info.write_dac_floor_code(v), "read_v": v,
                               "g_s": g, "current_a": current_a, "step": what})
        done: list[CellPlanResult] = []
        try:
            run_plan_on_cell(io, (unit.row, unit.col), plan, observer=bench.cell_results,
                             on_read=on_read, sleep=self.sleep, bar=self._bar,
                             base=self.cells.index((unit.row, unit.col)) * per_cell,
                             results=done)
        except KeyboardInterrupt:
            self.cut = done[-1] if done else None
            self._mark_stale(bench, done)
            raise
        self._mark_stale(bench, done)
        return {**done[-1].to_dict(), "read_chain": bench.chain_source}

    def restore(self, unit: PlanCell, record: dict[str, Any]) -> None:
        pass                                    # the record is the cell's result

    def result(self, records: Any, status: str) -> PlanRun:
        cells = [CellPlanResult.from_dict(records[f"cell-{r}-{c}"]) for r, c in self.cells
                 if f"cell-{r}-{c}" in records]
        if status == "complete" and len(cells) < len(self.cells):
            raise RuntimeError("the plan did not run on every cell")
        if status != "complete" and self.cut is not None:
            cells.append(self.cut)
        chain = next((records[k].get("read_chain") for k in records), None) or self.read_chain
        return PlanRun(cells, chain, status)

    def summary(self, result: PlanRun) -> dict[str, Any]:
        return {"plan": self.plan_.name, "cells": len(result.cells),
                "pulses": sum(r.pulses for r in result.cells),
                "stopped": {f"{r.row},{r.col}": r.stopped for r in result.cells}}

    def _mark_stale(self, bench: Any, done: list[CellPlanResult]) -> None:
        """The synapses on the cells of ``done`` that the plan pulsed: marked stale (not
        ok) in the board's layout, saved."""
        changed = [r for r in done if r.pulses and (r.row, r.col) in self._stale]
        for res in changed:
            syn = self._stale[(res.row, res.col)]
            syn.stale = (f"plan {self.plan_.name}: {res.pulses} pulses, "
                         f"{res.initial_s * 1e6:.1f} -> {res.final_s * 1e6:.1f} uS")
            syn.ok = False
        if changed:
            bench.layout.save(bench.layout_path)
