"""The board's fixed-point arithmetic of on-board learning (LEARN, issue 34 stage 1): the
readable pure-Python reference of the STDP update of a learning window and of the pulse plan
of a trial's end, on Python ints.

The rule is the host's (the source of every formula here):

* the window's pair-based STDP change of one synapse is
  :func:`snan_hil.host.snan_kernel.stdp_lane` (event-driven traces ``x`` (pre) and ``y``
  (post), decaying by ``exp(-dt / tau_plus)`` / ``exp(-dt / tau_minus)`` per step, ``+1`` per
  spike — or set to 1 with ``stdp.pairing = nearest`` —; at a post spike ``dw += a_plus x``,
  at a pre spike ``dw -= a_minus y``, a pre and a post spike of the same step counted in that
  order), times ``stdp.k`` for the chosen move, nothing for the other candidates
  (``stdp.target = chosen``, :func:`~snan_hil.host.snan_kernel.window_changes`);
* the intended weight ``w_int = clip(w_int + dw, w_min, w_max)`` per update and the pulse plan
  of :class:`snan_hil.host.hil.learning.PulsePlanner` without a budget (``threshold_steps``
  0.5, ``max_pulses`` per synapse and plan) with the chip-level curve of the fitted device
  model (``--chip-model``): SET while the pending change is at least half a predicted SET step
  above 0, RESET while at least half a RESET step below, no pulse that ends beyond the window
  by more than half a step; the estimate ``w_est`` moves by each predicted step.

**Formats** (docs/protocol.md, "On-board learning"):

* weights, their changes and the predicted steps: int32 **Q1.30** (``w * 2^30``; the weight
  window is 0..1);
* traces and their sums: int64 **Q32.32**, decayed by the Q0.64 tables ``dec_plus^m``,
  ``dec_minus^m`` (m = 1..16, a gap of more than 16 steps chains the 16th) with the LIF's
  product (:func:`~snan_hil.firmware_emu.lif_fixed.mul_alpha_ref`);
* ``k a_plus``, ``k a_minus``: Q0.64 (below 1), so the window's change of the chosen lane is
  ``mul(k a_plus, P) - mul(k a_minus, D)`` (Q32.32) with ``P`` the sum of ``x`` at the post
  spikes and ``D`` the sum of ``y`` at the pre spikes, rounded to Q1.30;
* the predicted step of one pulse at ``w``: a table of ``2^b + 1`` Q1.30 values per polarity
  at ``w = i / 2^b`` (i = 0..2^b; the host samples its float step at them), interpolated by
  the quadratic through three neighbouring points (:func:`step_ref`) at ``w_c = clip(w, 0,
  1)`` (the weight map clips a weight to 0..1 before it becomes a conductance, so the host's
  step is constant outside). A chord (linear interpolation) of 64 intervals left plans that
  differed in 0.7 % of random trials, 128 intervals 0.17 %: the quadratic's error is ~h^3.

Where it differs from the host's float: the roundings (2^-30 per weight, 2^-32 per trace
product) and the table's interpolation (the quadratic between the table's points against the float
curve). ``tests/firmware/test_learn_fixed.py`` measures how often a plan differs.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from snan_hil.firmware_emu.lif_fixed import decay_ref
from snan_hil.protocol.learn_messages import LEARN_TABLE_BITS, LEARN_W_ONE, LearnSetup

W_SHIFT = 30
ONE_W = LEARN_W_ONE
"""1.0 in Q1.30."""
ONE_T = 1 << 32
"""1.0 in Q32.32 (a trace's increment)."""
TABLE_BITS = LEARN_TABLE_BITS
SET, RESET = 0, 1
"""Polarity codes (the wire's: SET 0, RESET 1; :class:`~snan_hil.common.polarity.Polarity`)."""
NEVER = 1 << 62


@dataclass(frozen=True)
class LearnRule:
    """The learning block's values, board units (module doc).

    ``dec_plus_pow``, ``dec_minus_pow``: Q0.64, ``exp(-m dt / tau)`` for m = 1..16;
    ``k_a_plus``, ``k_a_minus``: Q0.64; ``w_min``, ``w_max``: Q1.30; ``nearest``: the pairing;
    ``max_pulses``: most pulses of one synapse in one plan (1..127); ``table_bits``: b;
    ``set_steps``, ``reset_steps``: the predicted step tables (Q1.30, 2^b + 1 each; SET >= 0,
    RESET <= 0)."""

    dec_plus_pow: tuple[int, ...]
    dec_minus_pow: tuple[int, ...]
    k_a_plus: int
    k_a_minus: int
    w_min: int
    w_max: int
    nearest: bool
    max_pulses: int
    table_bits: int
    set_steps: tuple[int, ...]
    reset_steps: tuple[int, ...]


def rule_of(setup: LearnSetup) -> LearnRule:
    """The rule of a LEARN_SETUP request (its block; the synapses are the state's)."""
    return LearnRule(tuple(setup.dec_plus_pow), tuple(setup.dec_minus_pow), setup.k_a_plus,
                     setup.k_a_minus, setup.w_min, setup.w_max, setup.nearest,
                     setup.max_pulses, setup.table_bits, tuple(setup.set_steps),
                     tuple(setup.reset_steps))


# ------------------------------------------------------------------------------ STDP
def mul_q064(a: int, u: int) -> int:
    """``a * u`` for a Q0.64 ``a`` and an int64 ``u`` (the LIF's product, lif_fixed)."""
    return decay_ref(u, 1, (a,))


def window_dw_ref(rule: LearnRule, pre: list[int], post: list[int]) -> int:
    """The chosen lane's STDP change of one window, Q1.30 (rounded half up from Q32.32):
    the pairs of the input spike steps ``pre`` and the lane's motor spike steps ``post``
    (both ascending), event by event as the host's ``stdp_lane``, times k."""
    x = y = 0
    p_sum = d_sum = 0
    t_last = -1
    a = b = 0
    while a < len(pre) or b < len(post):
        ta = pre[a] if a < len(pre) else NEVER
        tb = post[b] if b < len(post) else NEVER
        t = min(ta, tb)
        if t_last >= 0 and t > t_last:
            x = decay_ref(x, t - t_last, rule.dec_plus_pow)
            y = decay_ref(y, t - t_last, rule.dec_minus_pow)
        t_last = t
        if ta == t:
            x = ONE_T if rule.nearest else x + ONE_T
            a += 1
        if tb == t:
            p_sum += x
            b += 1
        if ta == t:
            d_sum += y
        if tb == t:
            y = ONE_T if rule.nearest else y + ONE_T
    dw = mul_q064(rule.k_a_plus, p_sum) - mul_q064(rule.k_a_minus, d_sum)
    return (dw + 2) >> 2


def add_update_ref(rule: LearnRule, w_int: int, dw: int) -> int:
    """``clip(w_int + dw, w_min, w_max)`` (Q1.30)."""
    return min(max(w_int + dw, rule.w_min), rule.w_max)


# ------------------------------------------------------------------------------ the plan
def step_ref(rule: LearnRule, polarity: int, w: int) -> int:
    """Predicted signed change of one pulse of ``polarity`` at weight ``w`` (Q1.30): the
    table's quadratic through three points (Newton's forward form) at ``w_c = clip(w, 0, 1)``:
    ``j = min(w_c >> (30 - b), 2^b - 2)``, ``F = w_c - j 2^(30-b)``, ``H = 2^(30-b)``,
    ``s = T[j] + ((T[j+1] - T[j]) F >> (30-b)) + ((T[j+2] - 2 T[j+1] + T[j])
    ((F (F - H)) >> (30-b)) >> (31-b))`` (arithmetic shifts: floors)."""
    table = rule.set_steps if polarity == SET else rule.reset_steps
    shift = W_SHIFT - rule.table_bits
    wc = min(max(w, 0), ONE_W)
    j = min(wc >> shift, (1 << rule.table_bits) - 2)
    f = wc - (j << shift)
    d1 = table[j + 1] - table[j]
    d2 = table[j + 2] - 2 * table[j + 1] + table[j]
    return table[j] + ((d1 * f) >> shift) + ((d2 * ((f * (f - (1 << shift))) >> shift))
                                             >> (shift + 1))


def plan_ref(rule: LearnRule, w_int: int, w_est: int) -> tuple[int, int, int]:
    """One synapse's pulses: (polarity, count, the new estimate), PulsePlanner's loop."""
    pending = w_int - w_est
    pol = SET if pending > 0 else RESET
    if pending == 0:
        return pol, 0, w_est
    sign = 1 if pending > 0 else -1
    w = w_est
    n = 0
    while n < rule.max_pulses:
        s = step_ref(rule, pol, w)
        mag = sign * s
        if mag <= 1 or 2 * sign * (w_int - w) < mag:
            break
        if 2 * (rule.w_min - (w + s)) > mag or 2 * (w + s - rule.w_max) > mag:
            break
        w += s
        n += 1
    return pol, n, w


def advance_ref(rule: LearnRule, polarity: int, w: int, n: int) -> int:
    """The estimate after ``n`` predicted steps of ``polarity`` from ``w`` (the plan's moves:
    ``plan_ref``'s new estimate when ``n`` is its count)."""
    for _ in range(n):
        w += step_ref(rule, polarity, w)
    return w


# ------------------------------------------------------------------------------ the state
@dataclass
class LearnState:
    """The board's learning state (module doc; RAM, lost at RESET and power-on): the synapse
    table in the host's order (cell ``row << 3 | col``), intended weights and estimates
    (Q1.30), the SET/RESET pulses applied per synapse (the ledger), the last trial applied,
    the pending window (lanes' synapse index and change) and the synapses a trial touched."""

    rule: LearnRule
    cells: list[int]
    w_int: list[int]
    w_est: list[int]
    n_set: list[int] = field(default_factory=list)
    n_reset: list[int] = field(default_factory=list)
    last_trial: int = 0
    pending: list[tuple[int, int]] = field(default_factory=list)
    touched: list[int] = field(default_factory=list)

    def __post_init__(self) -> None:
        n = len(self.cells)
        self.n_set = self.n_set or [0] * n
        self.n_reset = self.n_reset or [0] * n

    def index(self, cell: int) -> int:
        """The synapse of ``cell``, -1 when the table has none."""
        try:
            return self.cells.index(cell)
        except ValueError:
            return -1

    def touch(self, j: int) -> None:
        if j not in self.touched:
            self.touched.append(j)

    def decide(self, chosen: int) -> None:
        """The host's decision on the pending window: its lane ``chosen`` (0..3; anything
        else: no lane) gets its change (clipped), the others nothing (target chosen)."""
        for lane, (j, dw) in enumerate(self.pending):
            if lane == chosen and j >= 0:
                self.w_int[j] = add_update_ref(self.rule, self.w_int[j], dw)
                if dw:
                    self.touch(j)
        self.pending = []

    def window(self, lanes: list[int], pre: list[int], post: list[list[int]]) -> None:
        """A learning window's changes, pending until the host's decision: ``lanes`` the
        candidates' synapse indices (-1: a cell outside the table, never changed)."""
        self.pending = [(j, window_dw_ref(self.rule, pre, post[k]) if j >= 0 else 0)
                        for k, j in enumerate(lanes)]

    def plan(self) -> list[tuple[int, int, int]]:
        """The trial's pulse orders (synapse, polarity, count), in table order; estimates and
        ledger moved as if they were applied."""
        orders = []
        for j in range(len(self.cells)):
            pol, n, w = plan_ref(self.rule, self.w_int[j], self.w_est[j])
            if n:
                self.w_est[j] = w
                if pol == SET:
                    self.n_set[j] += n
                else:
                    self.n_reset[j] += n
                self.touch(j)
                orders.append((j, pol, n))
        return orders
