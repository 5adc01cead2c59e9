"""On-board learning (issue 34 stage 1): the host's side of the board's learning block.

:func:`learn_block` turns the model's STDP (``stdp.*`` of the config, through
:func:`~snan_hil.host.kernel_params.kernel_params`) and the chip's fitted device model (its
chip-level curve, as ``learn --chip-model`` plans) into the LEARN_SETUP request the board
keeps (:class:`~snan_hil.protocol.learn_messages.LearnSetup`; formats and the board's
arithmetic in docs/protocol.md "On-board learning" and ``firmware_emu/learn_fixed.py``).
:func:`with_synapses` adds a session's synapses; :func:`to_q30` / :func:`from_q30` convert
weights.

What the board cannot run is refused in one line (:class:`UserError`,
:func:`check_learnable`): a rule other than the additive one, a target other than ``chosen``,
STDP outside ``trial_end``, ``k a_plus`` or ``k a_minus`` of 1 or more, a pulse budget (the
board plans without one).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from fractions import Fraction

import numpy as np

from snan_hil.calibration.mapping import WeightMap
from snan_hil.common.errors import UserError
from snan_hil.common.polarity import Polarity
from snan_hil.crossbar_model.fitted import DeviceModel
from snan_hil.host.agent import BoardWindow, MotorBackend
from snan_hil.host.config import SnanConfig
from snan_hil.host.hil.board_window import OnBoardMotorNeurons
from snan_hil.host.hil.learning import PulseBudget, PulsePlanner
from snan_hil.host.kernel_params import kernel_params
from snan_hil.protocol.errors import ProtocolError
from snan_hil.protocol.learn_messages import (LEARN_NO_LANE, LEARN_TABLE_BITS, LEARN_W_ONE,
                                              LearnApplyReply, LearnSetup, LearnSynapse,
                                              cell_byte)
from snan_hil.protocol.messages import DW_ALPHA_TABLE

__all__ = ["DEFAULT_TABLE_BITS", "learn_block", "with_synapses", "to_q30", "from_q30",
           "check_learnable", "BoardLearner"]

DEFAULT_TABLE_BITS = 6
"""2^6 = 64 intervals of the step tables over the weight window (65 points a polarity: 520 B
of board RAM for both); with the board's quadratic interpolation no plan of 600 random trials
differed from the host's float plan (tests/firmware/test_learn_fixed.py, docs/protocol.md)."""
Q064 = 1 << 64


def to_q30(w: float) -> int:
    """round(w * 2^30): a weight (or a change, a step) in Q1.30."""
    return int(round(float(w) * LEARN_W_ONE))


def from_q30(q: int) -> float:
    """A Q1.30 value as a float (exact)."""
    return q / LEARN_W_ONE


def _q064(value: float, what: str) -> int:
    if not 0.0 <= value < 1.0:
        raise UserError(f"{what} = {value:g} must be in [0, 1) for the board's learning "
                        f"(Q0.64); lower stdp.k or the amplitudes, or learn on the host "
                        f"(--mode on-board)")
    return min(int(round(value * Q064)), Q064 - 1)


def _powers(base: float) -> tuple[int, ...]:
    """base^m, m = 1..16, of the host's float64 base exactly, rounded to Q0.64."""
    exact = Fraction(float(base))
    return tuple(min(round(exact ** m * Q064), Q064 - 1) for m in range(1, DW_ALPHA_TABLE + 1))


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


def learn_block(cfg: SnanConfig, model: DeviceModel, weight_map: WeightMap, *,
                set_code: int, reset_code: int, width_us: int, max_pulses: int = 127,
                table_bits: int = DEFAULT_TABLE_BITS) -> LearnSetup:
    """The board's learning block (a LEARN_SETUP without synapses) of ``cfg``'s STDP and
    ``model``'s chip-level curve on ``weight_map`` (module doc); the learning pulse's write-DAC
    codes and width (µs). ``max_pulses``: most pulses of one synapse in one plan (1..127: the
    wire's 7 bits; the host's planner allows 200, a bound on a runaway). UserError for what
    the board cannot run."""
    check_learnable(cfg)
    if table_bits not in LEARN_TABLE_BITS:
        raise ValueError(f"table_bits must be one of {LEARN_TABLE_BITS}, got {table_bits}")
    if not 1 <= max_pulses <= 127:
        raise ValueError(f"max_pulses must be 1..127, got {max_pulses}")
    kp = kernel_params(cfg)
    d = cfg.stdp
    key = (0, 0)
    planner = PulsePlanner(model, weight_map, {key: (-1, -1)}, d.w_min, d.w_max,
                           per_cell=False)             # the chip curve (the host's --chip-model)
    n = 1 << table_bits
    grid = [i / n for i in range(n + 1)]
    return LearnSetup(
        flags=1 if kp.nearest else 0, table_bits=int(table_bits), max_pulses=int(max_pulses),
        set_code=int(set_code), reset_code=int(reset_code), width_us=int(width_us),
        k_a_plus=_q064(kp.k * kp.a_plus, "stdp.k * stdp.a_plus"),
        k_a_minus=_q064(kp.k * kp.a_minus, "stdp.k * stdp.a_minus"),
        w_min=to_q30(d.w_min), w_max=to_q30(d.w_max),
        dec_plus_pow=_powers(kp.dec_plus), dec_minus_pow=_powers(kp.dec_minus),
        set_steps=tuple(to_q30(planner.step(key, Polarity.SET, w)) for w in grid),
        reset_steps=tuple(to_q30(planner.step(key, Polarity.RESET, w)) for w in grid))


def with_synapses(block: LearnSetup, cells: Mapping[tuple[int, int], tuple[int, int]],
                  w_int: Mapping[tuple[int, int], float], w_est: Mapping[tuple[int, int], float],
                  last_trial: int = 0) -> LearnSetup:
    """``block`` with the session's synapses: ``cells`` synapse -> (row, col), in the order
    the board keeps them (the host's synapse order), their intended weights and estimates."""
    syn = tuple(LearnSynapse(cell_byte(*cells[k]), to_q30(w_int[k]), to_q30(w_est[k]))
                for k in cells)
    return dataclasses.replace(block, synapses=syn, last_trial=int(last_trial))


Key = tuple[int, int]


class BoardLearner(MotorBackend):
    """The agent's motor back-end when the board learns (issue 34 stage 1): the windows of a
    training trial (between :meth:`begin` and :meth:`finish`) go as LEARN_WINDOW — the board
    pairs its own motor spikes with the input spikes it drew, keeps the changes pending until
    the host's decision (:meth:`decided`, which :class:`~snan_hil.host.agent.WindowTrial`
    calls) — and :meth:`finish` ends the trial with LEARN_APPLY (the board plans and applies
    the pulses); other windows (tests) go as DECISION_WINDOW through ``reader``. The host keeps
    a mirror of the board's weights (``w_int``, ``w_est``: from LEARN_SETUP and each
    LEARN_APPLY's touched synapses), which it needs only to set the board up again after a
    board reset, and computes no STDP (the motor spikes are not asked for).

    ``keys``: the synapses in the board's table order, ``cells``: synapse -> (row, col)."""

    def __init__(self, reader: OnBoardMotorNeurons, keys: Sequence[Key],
                 cells: Mapping[Key, tuple[int, int]]) -> None:
        self.reader, self.client = reader, reader.client
        self.keys = list(keys)
        self.cells = dict(cells)
        self.w_int: dict[Key, float] = {}
        self.w_est: dict[Key, float] = {}
        self.trial: int | None = None
        self.window = 0
        self.last = LEARN_NO_LANE
        self.last_trial = 0

    def setup(self, block: LearnSetup, w_int: Mapping[Key, float],
              w_est: Mapping[Key, float], last_trial: int = 0) -> None:
        """Give the board ``block`` with the synapses' intended weights and estimates."""
        req = with_synapses(block, {k: self.cells[k] for k in self.keys}, w_int, w_est,
                            last_trial)
        self.client.learn_setup(req)
        self.w_int = {k: from_q30(s.w_int) for k, s in zip(self.keys, req.synapses)}
        self.w_est = {k: from_q30(s.w_est) for k, s in zip(self.keys, req.synapses)}
        self.last_trial = int(last_trial)

    def begin(self, trial: int) -> None:
        """The next windows are training trial ``trial``'s (> the board's last trial)."""
        self.trial, self.window, self.last = int(trial), 0, LEARN_NO_LANE

    def motor_window(self, pre: int, dirs: Sequence[int], key: int, n_spikes: int,
                     inh: Sequence[np.ndarray], want_spikes: bool
                     ) -> tuple[np.ndarray, list[np.ndarray]]:
        if self.trial is None:
            return self.reader.motor_window(pre, dirs, key, n_spikes, inh, False)
        req = self.reader.request(BoardWindow(pre, list(dirs), key, n_spikes, list(inh),
                                              False))
        reply = self.client.learn_window(self.trial, self.window, self.last, key, req.rows,
                                         req.candidates, self.reader.params)
        if reply.n_input_spikes != n_spikes:
            raise ProtocolError(f"board on {getattr(self.client, 'name', '?')} drew "
                                f"{reply.n_input_spikes} input spikes for this window, the "
                                f"host {n_spikes}: its spike stream differs")
        self.window += 1
        return (np.asarray(reply.counts, dtype=np.int64),
                [np.zeros(0, dtype=np.int64) for _ in dirs])

    def decided(self, lane: int) -> None:
        self.last = lane if 0 <= lane < 4 else LEARN_NO_LANE

    def finish(self) -> LearnApplyReply:
        """End the training trial: LEARN_APPLY; the mirror follows the touched synapses."""
        assert self.trial is not None, "finish() without begin()"
        reply = self.client.learn_apply(self.trial, max(self.window - 1, 0), self.last)
        for t in reply.touched:
            k = self.keys[t.synapse]
            self.w_int[k], self.w_est[k] = from_q30(t.w_int), from_q30(t.w_est)
        self.last_trial = self.trial
        self.trial = None
        return reply

    def order_cells(self, reply: LearnApplyReply) -> list[tuple[Key, int, int, Polarity, int]]:
        """The reply's orders as (synapse, row, col, polarity, count)."""
        out = []
        for o in reply.orders:
            k = self.keys[o.synapse]
            row, col = self.cells[k]
            out.append((k, row, col, Polarity.SET if o.polarity == 0 else Polarity.RESET,
                        o.count))
        return out

    def apply_update(self, pre: int, dirs: Sequence[int], dw: np.ndarray) -> None:
        """The board learns: the host's own pairing (without motor spikes) is not used."""

    def weights(self) -> np.ndarray:
        """The intended weights of the mirror, float[n_cells, 4]."""
        out = np.zeros(self.reader.nbr.shape)
        for (i, d), w in self.w_int.items():
            out[i, d] = w
        return out
