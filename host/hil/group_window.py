"""The on-board decision windows of one network spread over a group of chips (issue 35).

Each chip of the group holds the synapses of some input neurons (its layout's ``pres``,
:mod:`snan_hil.calibration.chip_group`) and runs the decision windows of those neurons itself:
:class:`GroupMotorNeurons` keeps one :class:`~snan_hil.host.hil.board_window.OnBoardMotorNeurons`
per chip (its parameter block from the chip's own read-chain calibration and weight map) and
sends each window to the chip of its input neuron, one DECISION_WINDOW round trip, as on one
chip. A window never needs two chips (a window is one input neuron's, and a neuron's synapses
stay on one chip), so the host combines nothing: no partial sums cross the link.

The counters (:class:`~snan_hil.host.hil.backend.ReadStats`) are the group's: every chip's
back-end adds to one. Launches may run interleaved (:mod:`snan_hil.host.hil.interleave`):
a window goes on the line while another is outstanding when every chip's link keeps two
requests (the two may be on different chips; each chip's link then has at most two).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from snan_hil.calibration.layout import Layout
from snan_hil.common.errors import UserError
from snan_hil.host.agent import BoardWindow, MotorBackend
from snan_hil.host.config import SnanConfig
from snan_hil.host.hil.backend import FixedWeightsError, ReadStats
from snan_hil.host.hil.board_window import OnBoardMotorNeurons
from snan_hil.protocol.client import BoardClient
from snan_hil.protocol.messages import DecisionWindow

__all__ = ["GroupMotorNeurons"]


class GroupMotorNeurons(MotorBackend):
    """The motor neurons of a network over ``chips`` ((client, layout) per chip, each
    layout a share of the grid: :attr:`Layout.pres`) — see the module doc. ``nbr``: the
    agent's neighbour table (int [n_cells, 4]); ``cfg``: the launch config; ``conversions``
    as :class:`OnBoardMotorNeurons`. UserError (one line) when an input neuron is on two
    chips or on none."""

    mode = "on_board"

    def __init__(self, chips: Sequence[tuple[BoardClient, Layout]], nbr: np.ndarray,
                 cfg: SnanConfig, *, conversions: int | None = None) -> None:
        if not chips:
            raise UserError("a chip group needs at least one chip")
        self.stats = ReadStats()
        self.chips = [OnBoardMotorNeurons(client, layout, nbr, cfg, conversions=conversions)
                      for client, layout in chips]
        self.owner: dict[int, int] = {}
        for k, (client, layout) in enumerate(chips):
            self.chips[k].stats = self.stats            # one set of counters for the group
            for pre in {s.pre for s in layout.synapses}:
                if pre in self.owner:
                    raise UserError(
                        f"input neuron {pre} is on chip {self.owner[pre]} and chip {k} of the "
                        f"group ({getattr(client, 'name', '?')}): program the group again "
                        "(its layouts are of two different plans)")
                self.owner[pre] = k
        n_in = int(np.asarray(nbr).shape[0])
        missing = sorted(set(range(n_in)) - set(self.owner))
        has_synapse = np.any(np.asarray(nbr) >= 0, axis=1)
        missing = [p for p in missing if has_synapse[p]]
        if missing:
            raise UserError(f"input neuron {missing[0]} (and {len(missing) - 1} more) is on no "
                            "chip of the group: the group's layouts do not cover the network")
        self.conversions = self.chips[0].conversions
        self.decisions_per_chip = [0] * len(self.chips)

    # -- MotorBackend ------------------------------------------------------------------------
    def motor_window(self, pre: int, dirs: Sequence[int], key: int, n_spikes: int,
                     inh: Sequence[np.ndarray], want_spikes: bool
                     ) -> tuple[np.ndarray, list[np.ndarray]]:
        """The window on the chip of input neuron ``pre`` (agent.MotorBackend)."""
        return self.collect(self.submit(BoardWindow(pre, list(dirs), key, n_spikes,
                                                    list(inh), want_spikes)))

    def apply_update(self, pre: int, dirs: Sequence[int], dw: np.ndarray) -> None:
        raise FixedWeightsError("the crossbar weights are fixed during launches; run with "
                                "stdp.mode=off (no write pulses while the agent runs)")

    def weights(self) -> np.ndarray:
        """The programmed weights of the whole network (every chip's share), float[n, 4]."""
        out = np.zeros_like(self.chips[0].weights())
        for k, chip in enumerate(self.chips):
            mine = [p for p, c in self.owner.items() if c == k]
            out[mine] = chip.weights()[mine]
        return out

    # -- the window protocol of OnBoardMotorNeurons (interleaving) -----------------------------
    def chip_of(self, pre: int) -> int:
        return self.owner[int(pre)]

    def request(self, w: BoardWindow) -> DecisionWindow:
        """The DECISION_WINDOW of ``w`` for the chip of its input neuron."""
        return self.chips[self.chip_of(w.pre)].request(w)

    def pipelinable(self, req: DecisionWindow) -> bool:
        """Whether ``req`` may go on the line while another window is outstanding: every
        chip's link keeps two requests and takes this one (the other may be on any chip)."""
        return all(chip.pipelinable(req) for chip in self.chips)

    def submit(self, w: BoardWindow, req: DecisionWindow | None = None) -> Any:
        k = self.chip_of(w.pre)
        self.decisions_per_chip[k] += 1
        return k, self.chips[k].submit(w, req)

    def collect(self, ticket: Any) -> tuple[np.ndarray, list[np.ndarray]]:
        k, inner = ticket
        return self.chips[k].collect(inner)

    @property
    def clients(self) -> list[BoardClient]:
        return [chip.client for chip in self.chips]
