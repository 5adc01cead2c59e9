"""On-board learning on the emulated MCU (issue 34 stage 1; docs/protocol.md, "On-board
learning"): LEARN_SETUP, LEARN_WINDOW, LEARN_APPLY, LEARN_STATE.

The arithmetic is the readable reference :mod:`snan_hil.firmware_emu.learn_fixed` (the
Python MCU runs it as it is: a window's pairing is a few hundred integer operations). The
learning state is RAM: HELLO keeps it, RESET and a power cycle lose it (:meth:`LearnOp.clear`).
Pulses go through the firmware's own pulse path with WRITE_PULSE's checks (the compliance
prediction from the cell's last reading; a cell not read since boot is read first), counted in
STATUS ``pulses_applied``. The pairing and the plan cost no MCU time on the Python MCU's
clock yet (the C firmware, which does not implement LEARN yet, will give the figures to fit,
as ``decision_window.MCU_US_*``); the pulses cost theirs (the pulse path's).

Checks of LEARN_SETUP (ERROR OUT_OF_RANGE unless said; ``detail`` in brackets), in order:
flags [0] (MALFORMED at decode), ``table_bits`` 4..7 [1], ``max_pulses`` 1..127 [2], each
amplitude code within the write DAC [the code] and its write limit (SAFETY_LIMIT [the code]),
``width_us`` 1..the longest pulse [the width], ``0 <= w_min <= w_max <= 2^30`` [19 (the
offset of w_min)], the step tables' signs (SET >= 0, RESET <= 0) [the table's offset], ``n_syn``
1..128 [n_syn], each cell in the array and named once [its byte]. LEARN_WINDOW and LEARN_APPLY
without a learning state: [0]; a LEARN_WINDOW of a trial already applied: [the trial].
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from snan_hil.common.polarity import Polarity
from snan_hil.firmware_emu import learn_fixed as lf
from snan_hil.firmware_emu.decision_window import DecisionWindowOp
from snan_hil.protocol import learn_messages as lm
from snan_hil.protocol.errors import OutOfRangeError, SafetyLimitError

if TYPE_CHECKING:                                  # pragma: no cover - typing only
    from snan_hil.firmware_emu.firmware import Firmware

log = logging.getLogger(__name__)

W_MIN_OFFSET = 19
"""Byte offset of ``w_min`` in LEARN_SETUP (the detail of its refusal)."""
STEPS_OFFSET = 299
"""Byte offset of the SET step table (the RESET table follows it)."""


class LearnOp:
    """The board's learning state and its four operations (module doc)."""

    def __init__(self) -> None:
        self.state: lf.LearnState | None = None
        self.pulse: tuple[int, int, int] = (0, 0, 0)     # set code, reset code, width (us)
        self.pending_id: tuple[int, int] | None = None   # (trial, window) of the pending window

    def clear(self) -> None:
        """Forget the learning state (RESET, power-on)."""
        self.state = None
        self.pending_id = None

    # ------------------------------------------------------------------ LEARN_SETUP
    def _check_setup(self, fw: "Firmware", req: lm.LearnSetup) -> None:
        cfg = fw.config
        if req.table_bits not in lf.TABLE_BITS:
            fw._refuse(OutOfRangeError(f"table_bits {req.table_bits} outside 4..7", detail=1))
        if not 1 <= req.max_pulses <= 127:
            fw._refuse(OutOfRangeError(f"max_pulses {req.max_pulses} outside 1..127",
                                       detail=2))
        for code in (req.set_code, req.reset_code):
            if not 1 <= code <= cfg.write_dac_full_scale_code:
                fw._refuse(OutOfRangeError(f"learning pulse code {code} outside 1.."
                                           f"{cfg.write_dac_full_scale_code}", detail=code))
            if code > cfg.max_write_code:
                fw._refuse(SafetyLimitError(f"learning pulse code {code} above the write "
                                                 f"limit code {cfg.max_write_code}",
                                                 detail=code))
        if not 1 <= req.width_us <= cfg.max_pulse_width_us:
            fw._refuse(OutOfRangeError(f"learning pulse width {req.width_us} us",
                                       detail=req.width_us))
        if not 0 <= req.w_min <= req.w_max <= lf.ONE_W:
            fw._refuse(OutOfRangeError("w_min/w_max outside 0 <= w_min <= w_max <= 1",
                                       detail=W_MIN_OFFSET))
        n_pts = (1 << req.table_bits) + 1
        if any(s < 0 for s in req.set_steps):
            fw._refuse(OutOfRangeError("a negative SET step", detail=STEPS_OFFSET))
        if any(s > 0 for s in req.reset_steps):
            fw._refuse(OutOfRangeError("a positive RESET step", detail=STEPS_OFFSET + 4 * n_pts))
        if not 1 <= len(req.synapses) <= lm.LEARN_MAX_SYNAPSES:
            fw._refuse(OutOfRangeError(f"{len(req.synapses)} synapses, 1.."
                                       f"{lm.LEARN_MAX_SYNAPSES}", detail=len(req.synapses)))
        seen: set[int] = set()
        for s in req.synapses:
            row, col = lm.cell_of(s.cell)
            if row >= cfg.rows or col >= cfg.cols or s.cell in seen:
                fw._refuse(OutOfRangeError(f"synapse cell ({row},{col}) outside the array or "
                                           "named twice", detail=s.cell))
            seen.add(s.cell)

    def setup(self, fw: "Firmware", req: lm.LearnSetup) -> lm.LearnSetupReply:
        self._check_setup(fw, req)
        self.state = lf.LearnState(lf.rule_of(req), [s.cell for s in req.synapses],
                                   [s.w_int for s in req.synapses],
                                   [s.w_est for s in req.synapses], last_trial=req.last_trial)
        self.pending_id = None
        self.pulse = (req.set_code, req.reset_code, req.width_us)
        return lm.LearnSetupReply(len(req.synapses), fw.status()["pulses_applied"])

    # ------------------------------------------------------------------ windows
    def _need_state(self, fw: "Firmware") -> lf.LearnState:
        if self.state is None:
            fw._refuse(OutOfRangeError("no learning state: send LEARN_SETUP first", detail=0))
        assert self.state is not None
        return self.state

    def _settle(self, st: lf.LearnState, trial: int, window: int, decided: int) -> None:
        """The pending window gets the host's decision if it is (trial, window - 1), else it is
        dropped unapplied (docs/protocol.md)."""
        if self.pending_id == (trial, window - 1):
            st.decide(decided)
        st.pending = []
        self.pending_id = None

    def window(self, fw: "Firmware", op: DecisionWindowOp, req: lm.LearnWindow
               ) -> lm.LearnWindowReply:
        """A learning window: settle the pending window, run the window (DECISION_WINDOW,
        its checks first), keep its lanes' changes pending."""
        st = self._need_state(fw)
        if req.trial <= st.last_trial:
            fw._refuse(OutOfRangeError(f"trial {req.trial} was applied already (the board's "
                                       f"last trial is {st.last_trial})", detail=req.trial))
        w = req.window_req
        reply = op.run(fw, w, keep_post=True)
        self._settle(st, req.trial, req.window, req.decided)
        post: list[list[int]] = [[] for _ in w.candidates]
        for t, k in op.last_post:
            post[k].append(t)
        lanes = [st.index(lm.cell_byte(w.rows[c.row_index], c.col)) for c in w.candidates]
        st.window(lanes, op.last_pre, post)
        self.pending_id = (req.trial, req.window)
        return lm.LearnWindowReply(reply.n_input_spikes, reply.counts, reply.motor_spikes,
                                   reply.trace)

    # ------------------------------------------------------------------ a trial's end
    def apply(self, fw: "Firmware", req: lm.LearnApply) -> lm.LearnApplyReply:
        """Settle the last window, plan, apply the pulses; ALREADY for a trial applied."""
        st = self._need_state(fw)
        if req.trial <= st.last_trial:
            return lm.LearnApplyReply(True, req.trial, fw.status()["pulses_applied"])
        self._settle(st, req.trial, req.window + 1, req.decided)
        orders = []                         # st.touched: the trial's changes so far, kept
        for j in range(len(st.cells)):
            pol, n, _w = lf.plan_ref(st.rule, st.w_int[j], st.w_est[j])
            if not n:
                continue
            done = self._pulses(fw, st, j, pol, n)
            st.w_est[j] = lf.advance_ref(st.rule, pol, st.w_est[j], done)
            if pol == lf.SET:
                st.n_set[j] += done
            else:
                st.n_reset[j] += done
            st.touch(j)
            if done:
                orders.append(lm.LearnOrder(j, pol, done))
        st.last_trial = req.trial
        touched = tuple(lm.LearnTouched(j, st.w_int[j], st.w_est[j]) for j in sorted(st.touched))
        st.touched = []
        return lm.LearnApplyReply(False, req.trial, fw.status()["pulses_applied"],
                                  tuple(orders), touched)

    def _pulses(self, fw: "Firmware", st: lf.LearnState, j: int, pol: int, n: int) -> int:
        """Apply ``n`` pulses of polarity ``pol`` to synapse ``j``; a refused pulse ends the
        order. Returns the pulses applied."""
        row, col = lm.cell_of(st.cells[j])
        amp = self.pulse[0] if pol == lf.SET else self.pulse[1]
        polarity = Polarity.SET if pol == lf.SET else Polarity.RESET
        for i in range(n):
            try:
                fw._check_write(row, col, amp, self.pulse[2], fw.config.read_code)
            except (SafetyLimitError, OutOfRangeError) as exc:   # counted as a refusal too
                log.info("learning pulse %d of %d on (%d,%d) refused: %s", i + 1, n, row, col,
                         exc)
                return i
            fw._pulse(row, col, polarity, amp, self.pulse[2])
        return n

    # ------------------------------------------------------------------ the ledger
    def read_state(self, fw: "Firmware", req: lm.LearnState) -> lm.LearnStateReply:
        pulses = fw.status()["pulses_applied"]
        st = self.state
        if st is None:
            return lm.LearnStateReply(0, pulses, 0, req.first, ())
        n = len(st.cells)
        last = min(n, req.first + req.count)
        syn = tuple(lm.LearnSynapseState(st.cells[j], st.w_int[j], st.w_est[j], st.n_set[j],
                                         st.n_reset[j]) for j in range(req.first, last))
        return lm.LearnStateReply(st.last_trial, pulses, n, req.first, syn)
