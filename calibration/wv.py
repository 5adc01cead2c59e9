"""Two-stage write-and-verify of one cell (the paper's "Hardware implementation" section).

Pure logic against an abstract :class:`CellIO` (read the cell's conductance; apply one pulse and
read it after), so it runs the same on a board, the emulator or a model cell in a unit test.

**Stage 1** (window): while the read conductance G is outside ``G_t (1 +- tolerance)`` apply a
write pulse followed by a read: RESET (G down) while above the window, SET (G up) while below.
Within one polarity the amplitude ramps up from the model's threshold (the board's read limit,
0.3 V) towards the configured maximum (the board's write limit, 1.4 V).
The ramp is *adaptive* (docs/calibration.md): instead of fixed 0.01 V steps it starts at the
amplitude a response model predicts for the change still needed and rises by at most
``max_rise_v`` per pulse while the cell responds less than predicted; when the last pulse
showed that a smaller amplitude suffices, the next one is lower. The model is
``|ln(G_after/G_before)| = k_p (V - 0.3 V)^2`` per polarity p; ``k_p`` is learned from every
pulse — chip-wide (the start of each cell) and per cell (the next pulse of this cell).

**Stage 2** (fine tuning, small pulses capped at ``fine_v_max``): RESET pulses until G <= G_t,
then SET pulses until G >= G_t, each aimed at a fraction of the remaining distance. A cell
already within ``fine_tolerance`` of its target skips stage 2 (so reprogramming a chip that
holds the weights applies no pulses).

Bounds: at most ``max_pulses_stage1`` / ``max_pulses_stage2`` pulses per round and
``max_rounds`` rounds (a round is stage 1 + stage 2; a second one runs only if stage 2 left the
window); a cell that does not respond at the largest allowed amplitude for ``stall_pulses``
pulses in a row, or whose compliance limit forbids any useful amplitude, fails early. Every
amplitude is clipped to ``[v_floor, min(v_max, io.amplitude_cap(...))]``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Annotated, Any, Protocol

from annotated_types import Ge, Gt, Interval

from snan_hil.common.polarity import Polarity
from snan_hil.config import loader as configio
from snan_hil.protocol.board import MEMRICORE

__all__ = ["CellIO", "PulseNotApplied", "WVConfig", "ResponseModel",
           "CellOutcome", "PulseRecord", "write_and_verify"]

SET, RESET = Polarity.SET, Polarity.RESET


class PulseNotApplied(Exception):
    """Raised by :meth:`CellIO.pulse` when the pulse was verifiably not applied (link loss)."""


class CellIO(Protocol):
    """One cell as write-and-verify sees it (conductances in S, amplitudes in V)."""

    def read(self) -> float:
        """Read the cell at the read voltage; its conductance (S)."""

    def pulse(self, polarity: Polarity, amplitude_v: float) -> float:
        """Apply one write pulse (``SET`` raises G, ``RESET`` lowers it), then read; G (S).

        Raises :class:`PulseNotApplied` if the pulse is known not to have happened."""

    def amplitude_cap(self, polarity: Polarity, conductance_s: float) -> float:
        """Largest amplitude (V) allowed now on this cell at conductance G (compliance and
        configured limits)."""


@dataclass(frozen=True)
class WVConfig:
    """Write-and-verify settings (relative tolerances, V, us, pulse counts); each field's
    bounds are declared beside it and checked on construction (a one-line
    :class:`~snan_hil.config.loader.ConfigError` naming the field), the checks across fields
    after them (``ValueError``)."""

    #: stage-1 window: |G/G_t - 1| <= tolerance (relative)
    tolerance: Annotated[float, Interval(gt=0, lt=1)] = 0.10
    #: stage 2 skipped when already within this (relative)
    fine_tolerance: Annotated[float, Interval(gt=0, lt=1)] = 0.02
    #: below this no cell changes (a read must not change it: model zero point = read limit), V
    v_threshold: Annotated[float, Ge(0)] = MEMRICORE.max_read_v
    v_floor: Annotated[float, Gt(0)] = 0.35          # lowest amplitude applied, V
    v_max: Annotated[float, Gt(0)] = MEMRICORE.max_write_v   # configured max write amplitude, V
    fine_v_max: Annotated[float, Gt(0)] = 1.0        # stage-2 amplitude cap, V
    #: stage-2 "small pulses": predicted |dlnG| at most this
    fine_max_step: Annotated[float, Gt(0)] = 0.03
    #: ramp: largest amplitude increase from one pulse to the next, V
    max_rise_v: Annotated[float, Gt(0)] = 0.25
    width_us: Annotated[int, Ge(1)] = 100            # pulse width, us
    max_pulses_stage1: Annotated[int, Ge(1)] = 40    # pulse budget of stage 1 per cell and round
    max_pulses_stage2: Annotated[int, Ge(1)] = 30    # pulse budget of stage 2 per cell and round
    max_rounds: Annotated[int, Ge(1)] = 2            # rounds (stage 1 + stage 2) per cell
    #: pulses at the cap without response -> unresponsive
    stall_pulses: Annotated[int, Ge(1)] = 4
    #: |ln G ratio| below this counts as "no response"
    stall_step: Annotated[float, Ge(0)] = 0.01
    #: stage 2 aims at this fraction of a distance > fine_last
    fine_approach: Annotated[float, Interval(gt=0, le=1)] = 0.7
    #: below this distance stage 2 aims past the target by ...
    fine_last: Annotated[float, Ge(0)] = 0.02
    fine_margin: Annotated[float, Ge(0)] = 0.005     # ... this much (relative)
    prior_k_set: Annotated[float, Gt(0)] = 0.3       # initial |dlnG| per V^2 of overdrive, SET
    prior_k_reset: Annotated[float, Gt(0)] = 0.3     # initial |dlnG| per V^2 of overdrive, RESET
    exponent: Annotated[float, Gt(0)] = 2.0          # overdrive exponent of the response model
    #: observations with smaller predicted & observed steps (|dlnG|) are not informative
    min_signal: Annotated[float, Ge(0)] = 0.015
    #: per-cell offset update weight (log domain)
    cell_learning: Annotated[float, Interval(ge=0, le=1)] = 0.6
    #: chip-wide fit: weight lost per new observation
    chip_forgetting: Annotated[float, Interval(ge=0, lt=1)] = 0.01
    #: chip-wide fit: pseudo-observations of the prior
    prior_weight: Annotated[float, Gt(0)] = 5.0
    #: spread of ln(G/G_ref) assumed for the prior points
    prior_spread: Annotated[float, Gt(0)] = 0.5
    #: stage 2: responsiveness divisor after a weak small pulse ...
    fine_boost: Annotated[float, Gt(0)] = 2.0
    #: ... i.e. one that moved less than this fraction of its aim
    fine_boost_below: Annotated[float, Ge(0)] = 0.3
    #: stage 2: first pulse of a polarity on a cell aims at this fraction of the distance (cell
    #: offset unknown)
    fine_first: Annotated[float, Interval(gt=0, le=1)] = 0.5
    #: a read below this is an open cell, S (assumption: far below the device's G_min, 25 uS in
    #: device-ysz.yaml, and the screen's 15 uS stuck-low limit; ~30 ADC LSB of a MemriCore cell
    #: read, above its read-noise floor)
    open_below_s: Annotated[float, Ge(0)] = 1e-6

    def __post_init__(self) -> None:
        configio.check_bounds(self)     # the bounds beside the fields (ConfigError, a UserError)
        if not 0 < self.fine_tolerance < self.tolerance < 1:
            raise ValueError("need 0 < fine_tolerance < tolerance < 1")
        if not self.v_threshold < self.v_floor <= self.fine_v_max <= self.v_max:
            raise ValueError("need v_threshold < v_floor <= fine_v_max <= v_max")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


class ResponseModel:
    """Predicts one pulse's effect: ``|dlnG| = k_p(G) (V - v_th)^e`` per polarity p.

    ``ln k_p(G) = a_p + b_p ln(G / G_ref)``: the chip-wide part, fitted by exponentially
    forgetting weighted least squares over every informative pulse of the chip (with a prior
    pseudo-observation at ``k = prior_k``, ``b = 0``), so a memristor whose steps shrink near a
    bound (SET near G_max, RESET near G_min) is predicted as such. A per-cell offset on top of it
    is learned by :class:`_Cell` from the cell's own pulses.
    """

    G_REF_S = 3e-4

    def __init__(self, cfg: WVConfig):
        self.cfg = cfg
        self.observations = {SET: 0, RESET: 0}
        # weighted sums: w, w x, w y, w x^2, w x y (x = ln(G/G_ref), y = ln k)
        self._sums = {}
        for pol, k in ((SET, cfg.prior_k_set), (RESET, cfg.prior_k_reset)):
            w0 = cfg.prior_weight
            self._sums[pol] = [w0, 0.0, w0 * math.log(k), w0 * cfg.prior_spread ** 2, 0.0]

    def overdrive(self, v: float) -> float:
        return max(v - self.cfg.v_threshold, 1e-6) ** self.cfg.exponent

    def _x(self, g: float) -> float:
        return math.log(max(g, 1e-9) / self.G_REF_S)

    def coefficients(self, polarity: Polarity) -> tuple[float, float]:
        """(a, b) of ``ln k = a + b ln(G/G_ref)``."""
        w, sx, sy, sxx, sxy = self._sums[polarity]
        mx, my = sx / w, sy / w
        var = sxx / w - mx * mx
        cov = sxy / w - mx * my
        b = cov / var if var > 1e-12 else 0.0
        b = max(-3.0, min(3.0, b))
        return my - b * mx, b

    def log_k(self, polarity: Polarity, g: float) -> float:
        """Chip-wide ln k for a cell now at conductance ``g`` (S)."""
        a, b = self.coefficients(polarity)
        return a + b * self._x(g)

    def predict(self, log_k: float, v: float) -> float:
        """Predicted |dlnG| of one pulse at ``v`` with model parameter ``log_k``."""
        return math.exp(log_k) * self.overdrive(v)

    def amplitude_for(self, log_k: float, step: float) -> float:
        """Amplitude (V) whose predicted |dlnG| equals ``step`` (> 0)."""
        return self.cfg.v_threshold + (max(step, 1e-9) / math.exp(log_k)) ** (1 / self.cfg.exponent)

    def observed_log_k(self, v: float, step: float) -> float:
        """ln k implied by an observed |dlnG| ``step`` (in the pulse's direction) at ``v``."""
        return math.log(max(step, self.cfg.stall_step * 0.3) / self.overdrive(v))

    def learn(self, polarity: Polarity, g_before: float, log_k_obs: float) -> None:
        """Fold one informative observation (cell at ``g_before``) into the chip-wide fit."""
        lam = 1.0 - self.cfg.chip_forgetting
        x, y = self._x(g_before), log_k_obs
        sums = self._sums[polarity]
        for i, term in enumerate((1.0, x, y, x * x, x * y)):
            sums[i] = lam * sums[i] + term
        self.observations[polarity] += 1

    def state(self) -> dict[str, Any]:
        out: dict[str, Any] = {"observations": {p.name: n for p, n in self.observations.items()},
                     "g_ref_s": self.G_REF_S}
        for pol in (SET, RESET):
            a, b = self.coefficients(pol)
            out[pol.name.lower()] = {"k_at_g_ref": math.exp(a), "b": b}
        return out


@dataclass(frozen=True)
class PulseRecord:
    """One applied pulse: stage (1 or 2), polarity, amplitude (V), G after (S)."""

    stage: int
    polarity: Polarity
    amplitude_v: float
    g_after_s: float


@dataclass
class CellOutcome:
    """Result of :func:`write_and_verify` for one cell (conductances in S)."""

    target_s: float
    initial_s: float
    final_s: float = math.nan
    stage1_s: float = math.nan        # G when stage 1 ended
    pulses_stage1: int = 0
    pulses_stage2: int = 0
    rounds: int = 0
    ok: bool = False
    stage1_ok: bool = False
    reason: str = ""
    not_applied: int = 0              # pulses the link lost and the board never executed
    trace: list[PulseRecord] = field(default_factory=list)

    @property
    def pulses(self) -> int:
        return self.pulses_stage1 + self.pulses_stage2

    @property
    def rel_error(self) -> float:
        return self.final_s / self.target_s - 1.0


class _Unusable(Exception):
    """A read without a usable conductance (an open cell reading 0 S or less, NaN or
    infinite): write-and-verify of the cell ends there with ``ok`` False and this reason."""

    def __init__(self, g: float, reason: str) -> None:
        super().__init__(reason)
        self.g, self.reason = g, reason


def _usable(g: float, when: str, cfg: WVConfig) -> float:
    """``g`` (S) if it is a conductance the method can work with, else :class:`_Unusable`
    naming what was read ``when``."""
    g = float(g)
    if not math.isfinite(g):
        raise _Unusable(g, f"no valid read {when}: the read gave {g} (check the read chain "
                           "and the cell's wiring)")
    if g < cfg.open_below_s:
        raise _Unusable(g, f"open cell: reads {g:.3g} S {when} (below {cfg.open_below_s:g} S)")
    return g


class _Cell:
    """Per-cell state of one write-and-verify run."""

    def __init__(self, io: CellIO, cfg: WVConfig, model: ResponseModel, out: CellOutcome,
                 on_stage: Callable[[int], object] | None = None):
        self.io, self.cfg, self.model, self.out = io, cfg, model, out
        self.on_stage = on_stage
        self.offset = {SET: 0.0, RESET: 0.0}      # per-cell ln k offset from the chip fit
        self.seen = {SET: 0, RESET: 0}            # informative pulses of this cell
        self.g = out.initial_s

    def log_k(self, polarity: Polarity) -> float:
        return self.model.log_k(polarity, self.g) + self.offset[polarity]

    def cap(self, polarity: Polarity, limit: float) -> float:
        return min(limit, self.cfg.v_max, float(self.io.amplitude_cap(polarity, self.g)))

    def pulse(self, stage: int, polarity: Polarity, v: float) -> tuple[float, bool]:
        """Apply one pulse and learn from it.

        Returns (signed |dlnG| in the pulse's direction, whether the pulse was informative,
        i.e. predicted or observed step >= ``min_signal``)."""
        before = self.g
        log_k = self.log_k(polarity)
        if self.on_stage is not None:
            self.on_stage(stage)
        try:
            after = self.io.pulse(polarity, v)
        except PulseNotApplied:
            self.out.not_applied += 1
            self.g = _usable(self.io.read(), "after a lost pulse", self.cfg)
            return 0.0, False
        if stage == 1:
            self.out.pulses_stage1 += 1
        else:
            self.out.pulses_stage2 += 1
        self.out.trace.append(PulseRecord(stage, polarity, round(v, 4), after))
        self.g = _usable(after, f"after a {polarity.name} pulse at {v:.2f} V", self.cfg)
        if before <= 0 or after <= 0:
            return 0.0, False
        step = math.log(after / before) * (1 if polarity == SET else -1)
        predicted = self.model.predict(log_k, v)
        informative = max(predicted, step) >= self.cfg.min_signal
        if informative:
            obs = self.model.observed_log_k(v, step)
            self.offset[polarity] += self.cfg.cell_learning * (obs - log_k)
            self.seen[polarity] += 1
            if step >= self.cfg.min_signal:       # only real responses teach the chip model
                self.model.learn(polarity, before, obs)
        return step, informative


def _err(g: float, target: float) -> float:
    return g / target - 1.0


def _stage1(cell: _Cell, target: float) -> str:
    """Ramp into the window; returns '' on success or the failure reason."""
    cfg = cell.cfg
    used = 0
    polarity, last_v, stall = None, None, 0
    while abs(_err(cell.g, target)) > cfg.tolerance:
        if used >= cfg.max_pulses_stage1:
            return f"stage 1: {used} pulses without reaching +-{cfg.tolerance:.0%}"
        pol = SET if cell.g < target else RESET
        if pol != polarity:                       # a new ramp starts
            polarity, last_v, stall = pol, None, 0
        cap = cell.cap(pol, cfg.v_max)
        if cap < cfg.v_floor:
            return (f"stage 1: compliance allows at most {cap:.2f} V on this cell "
                    f"(G = {cell.g * 1e6:.0f} uS)")
        need = abs(math.log(target / cell.g))
        v = cell.model.amplitude_for(cell.log_k(pol), need)
        if last_v is not None:
            v = min(v, last_v + cfg.max_rise_v)
        v = min(max(v, cfg.v_floor), cap)
        step, _ = cell.pulse(1, pol, v)
        used += 1
        stall = stall + 1 if (v >= cap - 1e-9 and step < cfg.stall_step) else 0
        if stall >= cfg.stall_pulses:
            return (f"stage 1: no response to {stall} {pol.name} pulses at {v:.2f} V "
                    f"(G = {cell.g * 1e6:.0f} uS, target {target * 1e6:.0f} uS)")
        last_v = v
    return ""


def _stage2(cell: _Cell, target: float) -> None:
    """RESET until G <= G_t, then SET until G >= G_t, with small pulses (bounded)."""
    cfg = cell.cfg
    used = 0
    for pol in (RESET, SET):
        stall = 0
        while (cell.g > target if pol == RESET else cell.g < target):
            if used >= cfg.max_pulses_stage2 or abs(_err(cell.g, target)) > cfg.tolerance:
                return
            cap = cell.cap(pol, cfg.fine_v_max)
            if cap < cfg.v_floor:
                return
            dist = abs(math.log(target / cell.g))
            # far: approach in a fraction of the distance; near: aim just past the target
            aim = cfg.fine_approach * dist if dist > cfg.fine_last else dist + cfg.fine_margin
            if not cell.seen[pol]:                # no own response seen yet: be careful
                aim = min(aim, max(cfg.fine_first * dist, cfg.fine_margin))
            aim = min(aim, cfg.fine_max_step)
            v = min(max(cell.model.amplitude_for(cell.log_k(pol), aim), cfg.v_floor), cap)
            step, informative = cell.pulse(2, pol, v)
            used += 1
            if not informative and step < cfg.fine_boost_below * aim:
                # a small pulse moved the cell less than expected: ramp up (next amplitude
                # chosen as if the cell were fine_boost times less responsive)
                cell.offset[pol] -= math.log(cfg.fine_boost)
            stall = stall + 1 if (v >= cap - 1e-9 and step < cfg.stall_step * 0.2) else 0
            if stall >= cfg.stall_pulses:
                return


def write_and_verify(io: CellIO, target_s: float, cfg: WVConfig,
                     model: ResponseModel | None = None, *, verify_reads: int = 1,
                     on_stage: Callable[[int], object] | None = None) -> CellOutcome:
    """Program one cell to ``target_s`` (S) with the two-stage method; never raises on a cell
    that does not converge (``ok`` False, ``reason`` says why), nor on one that reads no usable
    conductance (an open cell reading below ``cfg.open_below_s``, a NaN read: ``ok`` False,
    the reason names it and when it was read; no further pulse is applied to it).
    ``on_stage``: called with the stage (1 or 2) before each pulse (a board cell's pulses
    are recorded as they are applied, labelled with their stage)."""
    if not target_s > 0:
        raise ValueError(f"target conductance must be positive, got {target_s}")
    model = model or ResponseModel(cfg)
    out = CellOutcome(target_s=target_s, initial_s=float(io.read()))
    try:
        _usable(out.initial_s, "before any pulse", cfg)
        _program(io, cfg, model, out, verify_reads, on_stage)
    except _Unusable as exc:
        out.final_s, out.ok, out.reason = exc.g, False, exc.reason
    return out


def _program(io: CellIO, cfg: WVConfig, model: ResponseModel, out: CellOutcome,
             verify_reads: int, on_stage: Callable[[int], object] | None = None) -> None:
    """The rounds of stage 1 and 2 and the final reads (:func:`write_and_verify`)."""
    target_s = out.target_s
    cell = _Cell(io, cfg, model, out, on_stage)
    reason = ""
    for rnd in range(cfg.max_rounds):
        out.rounds = rnd + 1
        reason = _stage1(cell, target_s)
        if rnd == 0:
            out.stage1_s = cell.g
            out.stage1_ok = not reason
        if reason:
            break
        if abs(_err(cell.g, target_s)) > cfg.fine_tolerance:
            _stage2(cell, target_s)
        if abs(_err(cell.g, target_s)) <= cfg.tolerance:
            break
        reason = "stage 2 left the window"
    reads = [_usable(io.read(), "at the final read", cfg) for _ in range(max(1, verify_reads))]
    out.final_s = sum(reads) / len(reads)
    out.ok = abs(out.rel_error) <= cfg.tolerance
    if out.ok:
        reason = ""
    elif not reason:
        reason = f"final read {out.rel_error:+.1%} outside +-{cfg.tolerance:.0%}"
    out.reason = reason
