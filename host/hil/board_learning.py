"""On-board learning (issue 34 stage 1): the host's side of the board's learning block.

:func:`learn_rule` turns the model's STDP (``stdp.*`` of the config, through
:func:`~snan_hil.host.kernel_params.kernel_params`) and the chip's fitted device model (its
chip-level curve, as ``learn --chip-model`` plans) into the board's fixed-point
:class:`~snan_hil.firmware_emu.learn_fixed.LearnRule` (formats and the rule's source in
:mod:`snan_hil.firmware_emu.learn_fixed`; the wire block in docs/protocol.md, "On-board
learning"). :func:`to_q30` / :func:`from_q30` convert weights.

What the board cannot run is refused in one line (:class:`UserError`): a rule other than the
additive one, a target other than ``chosen``, STDP outside ``trial_end``, ``k a_plus`` or
``k a_minus`` of 1 or more, a pulse budget (the board plans without one).
"""

from __future__ import annotations

from fractions import Fraction

from snan_hil.calibration.mapping import WeightMap
from snan_hil.common.errors import UserError
from snan_hil.common.polarity import Polarity
from snan_hil.crossbar_model.fitted import DeviceModel
from snan_hil.firmware_emu.learn_fixed import ONE_W, TABLE_BITS, LearnRule
from snan_hil.host.config import SnanConfig
from snan_hil.host.hil.learning import PulseBudget, PulsePlanner
from snan_hil.host.kernel_params import kernel_params

__all__ = ["DEFAULT_TABLE_BITS", "learn_rule", "to_q30", "from_q30", "check_learnable"]

DEFAULT_TABLE_BITS = 6
"""2^6 = 64 intervals of the step table over the weight window (65 points a polarity, 520 B
of board RAM for both): the chord error it leaves is measured in tests/firmware/
test_learn_fixed.py."""
DECAY_TABLE = 16
"""Powers m = 1..16 of each trace's decay (as DECISION_WINDOW's alpha table)."""
Q064 = 1 << 64


def to_q30(w: float) -> int:
    """round(w * 2^30), a weight (or a change, a step) in Q1.30."""
    return int(round(float(w) * ONE_W))


def from_q30(q: int) -> float:
    return q / ONE_W


def _q064(value: float, what: str) -> int:
    if not 0.0 <= value < 1.0:
        raise UserError(f"{what} = {value:g} must be in [0, 1) for the board's learning "
                        f"(Q0.64); lower stdp.k or the amplitudes, or learn on the host "
                        f"(--mode on-board)")
    return min(int(round(value * Q064)), Q064 - 1)


def _powers(base: float) -> tuple[int, ...]:
    exact = Fraction(float(base))
    return tuple(min(round(exact ** m * Q064), Q064 - 1) for m in range(1, DECAY_TABLE + 1))


def check_learnable(cfg: SnanConfig, budget: PulseBudget | None = None) -> None:
    """UserError (one line) where the board's learning cannot run the model's rule."""
    d = cfg.stdp
    if d.rule != "additive":
        raise UserError(f"stdp.rule {d.rule}: the board learns with the additive rule only; "
                        "use --mode on-board (the host's STDP) for this rule")
    if d.target != "chosen":
        raise UserError(f"stdp.target {d.target}: the board learns with target chosen only; "
                        "use --mode on-board (the host's STDP) for this target")
    if d.mode != "trial_end":
        raise UserError(f"stdp.mode {d.mode}: the board plans its pulses at a trial's end "
                        "(stdp.mode trial_end); use --mode on-board for this mode")
    if budget is not None and budget.limited:
        raise UserError("a pulse budget (--pulse-budget/--cell-budget/--plan-pulses/"
                        "--threshold-steps) is planned on the host only; drop it or use "
                        "--mode on-board")


def learn_rule(cfg: SnanConfig, model: DeviceModel, weight_map: WeightMap, *,
               max_pulses: int = 127, table_bits: int = DEFAULT_TABLE_BITS) -> LearnRule:
    """The board's learning block of ``cfg``'s STDP and ``model``'s chip-level curve on
    ``weight_map`` (module doc). ``max_pulses``: most pulses of one synapse in one plan
    (1..127: the wire's 7 bits; the host's planner allows 200, a bound on a runaway that the
    6x6 task's plans never reach). UserError for what the board cannot run."""
    check_learnable(cfg)
    if table_bits not in TABLE_BITS:
        raise ValueError(f"table_bits must be one of {TABLE_BITS}, got {table_bits}")
    if not 1 <= max_pulses <= 127:
        raise ValueError(f"max_pulses must be 1..127, got {max_pulses}")
    kp = kernel_params(cfg)
    d = cfg.stdp
    planner = PulsePlanner(model, weight_map, {(0, 0): (-1, -1)}, d.w_min, d.w_max,
                           per_cell=False)             # the chip curve (the host's --chip-model)
    n = 1 << table_bits
    grid = [i / n for i in range(n + 1)]
    set_steps = tuple(to_q30(planner.step((0, 0), Polarity.SET, w)) for w in grid)
    reset_steps = tuple(to_q30(planner.step((0, 0), Polarity.RESET, w)) for w in grid)
    return LearnRule(
        dec_plus_pow=_powers(kp.dec_plus), dec_minus_pow=_powers(kp.dec_minus),
        k_a_plus=_q064(kp.k * kp.a_plus, "stdp.k * stdp.a_plus"),
        k_a_minus=_q064(kp.k * kp.a_minus, "stdp.k * stdp.a_minus"),
        w_min=to_q30(d.w_min), w_max=to_q30(d.w_max), nearest=bool(kp.nearest),
        max_pulses=int(max_pulses), table_bits=int(table_bits),
        set_steps=set_steps, reset_steps=reset_steps)
