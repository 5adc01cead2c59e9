"""Paired learning sessions with the host's STDP and with the board's (issue 34 stage 1): one
session of the chip arm's task on a programmed chip, the synapses read by the board's decision
window in both, learnt either

* ``host`` — as ``learn --mode on-board --chip-model`` does: the board answers the motor
  spike steps, the host pairs them (STDP), plans the pulses (:class:`~snan_hil.host.hil.
  learning.PulsePlanner`, the chip curve, no budget) and sends each as a WRITE_PULSE; or
* ``board`` — the board pairs, plans and applies (LEARN_WINDOW / LEARN_APPLY,
  :class:`~snan_hil.host.hil.board_learning.BoardLearner`); the host sends no pulse.

:func:`paired_session` is what ``bench/bench_learn_onboard.py`` runs on copies of one emulated
chip for both; its record has the tests' routes, the pulses per cycle (and who sent them), the
wire bytes per cycle and the board's ledger. Not yet the ``learn`` job's unit (no journal, no
history, no resume: docs/learning.md "On-board learning").
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from snan_hil.calibration.layout import Layout
from snan_hil.crossbar_model.fitted import DeviceModel, LearningPulse
from snan_hil.host.hil.board_learning import BoardLearner, learn_block
from snan_hil.host.hil.board_window import OnBoardMotorNeurons
from snan_hil.host.hil.learn_arms import LearnTask
from snan_hil.host.hil.learn_chip import layout_cells, read_weight
from snan_hil.host.hil.learning import ChipMotorNeurons, PulsePlanner
from snan_hil.protocol.client import BoardClient

__all__ = ["PairedSession", "paired_session"]


@dataclass
class PairedSession:
    """One session: per cycle 0..C the test's (steps, success); per cycle 1..C the learning
    pulses applied (SET, RESET), the WRITE_PULSEs the host sent, the wire bytes of the cycle
    (training + plan + pulses + test, both directions) and of its decisions; the board's
    STATUS pulse counter's change over the session."""

    learner: str
    tests: list[tuple[int, bool]] = field(default_factory=list)
    pulses: list[tuple[int, int]] = field(default_factory=list)
    host_pulses: list[int] = field(default_factory=list)
    wire_bytes: list[int] = field(default_factory=list)
    decisions: list[int] = field(default_factory=list)
    board_counter: int = 0
    ledger: dict[str, int] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def _bytes(client: BoardClient) -> int:
    c = client.counters_dict()
    return int(c.get("bytes_in", 0)) + int(c.get("bytes_out", 0))


def paired_session(task: LearnTask, k: int, client: BoardClient, layout: Layout,
                   model: DeviceModel, learner: str, pulse: LearningPulse | None = None
                   ) -> PairedSession:
    """Session ``k`` of ``task`` on the chip behind ``client``, programmed with the session's
    initial weights in ``layout``, learnt by ``learner`` ("host" or "board"; module doc) with
    the fitted ``model``'s chip curve and the learning ``pulse``."""
    pulse = pulse or LearningPulse()
    if learner not in ("host", "board"):
        raise ValueError(f"learner must be host or board, got {learner!r}")
    out = PairedSession(learner)
    cells = layout_cells(layout, task.nbr)
    keys = [key for key in task.keys if key in cells]
    w0 = task.initial(k)
    start = {key: float(w0[key]) for key in keys}
    reads = {key: read_weight(client, layout, *cells[key]) for key in keys}
    reader = OnBoardMotorNeurons(client, layout, task.nbr, task.train_cfg,
                                 conversions=task.lc.conversions)
    info = client.info
    assert info is not None
    amp = {"SET": info.write_dac_code(pulse.set_v), "RESET": info.write_dac_code(pulse.reset_v)}
    counter0 = client.status().pulses_applied
    if learner == "board":
        board = BoardLearner(reader, keys, cells)
        board.setup(learn_block(task.train_cfg, model, layout.weight_map,
                                set_code=amp["SET"], reset_code=amp["RESET"],
                                width_us=pulse.width_us), start, reads)
        backend: Any = board
    else:
        planner = PulsePlanner(model, layout.weight_map, {key: cells[key] for key in keys},
                               task.cfg.stdp.w_min, task.cfg.stdp.w_max, per_cell=False,
                               max_pulses=127)
        planner.start(start, reads)
        backend = ChipMotorNeurons(reader, planner, task.nbr)
    r = task.trial(k, 0, False, backend=backend)
    out.tests.append((int(r.steps), bool(r.success)))
    for c in range(1, task.lc.cycles + 1):
        b0 = _bytes(client)
        sent = 0
        if learner == "board":
            board.begin(c)
            tr = task.trial(k, 2 * c - 1, True, backend=board)
            reply = board.finish()
            n_set = sum(o.count for o in reply.orders if o.polarity == 0)
            n_reset = reply.pulses - n_set
        else:
            tr = task.trial(k, 2 * c - 1, True, backend=backend)
            n_set = n_reset = 0
            for o in planner.plan():
                for _ in o.steps:
                    client.write_pulse(o.row, o.col, o.polarity, amp[o.polarity.name],
                                       pulse.width_us)
                sent += o.count
                if o.polarity.name == "SET":
                    n_set += o.count
                else:
                    n_reset += o.count
        r = task.trial(k, 2 * c, False, backend=backend)
        out.tests.append((int(r.steps), bool(r.success)))
        out.pulses.append((n_set, n_reset))
        out.host_pulses.append(sent)
        out.wire_bytes.append(_bytes(client) - b0)
        out.decisions.append(int(tr.steps) + int(r.steps))
    out.board_counter = client.status().pulses_applied - counter0
    if learner == "board":
        st = client.learn_state()
        out.ledger = {"set": sum(s.n_set for s in st.synapses),
                      "reset": sum(s.n_reset for s in st.synapses)}
    else:
        out.ledger = {"set": sum(p[0] for p in out.pulses),
                      "reset": sum(p[1] for p in out.pulses)}
    return out
