"""Crossbar synapses read one cell at a time: the hardware back-end over the legacy protocol.

The existing firmware has no column multiply on its serial path (mode 10 is broken) and no
SPIKE_BATCH, so the paper's per-spike column read is not available. What it has is the
single-cell read (mode 9; READ_CELL on the framed protocol). :class:`CellReadSynapses`
implements the agent's ``SynapseBackend`` (host/agent.py) on it, in two named modes, for a
decision window of input neuron ``pre`` with spike train ``S`` (1 ms bins) and the candidate
motor neurons ``posts`` (2-4 synapses, each one cell of the layout):

* ``per_spike``: for every input spike, each synapse cell is read once (fresh read noise per
  spike, as the paper's analog per-spike read): ``spikes x synapses`` reads per window;
* ``per_window``: each synapse cell is read once per window and that reading is applied to
  every spike of the window: ``synapses`` reads per window (none if ``pre`` does not spike).

Each ADC code becomes a weight with the layout's calibrated cell-read chain and weight map
(``Layout.weight_from_cell_code``, not clipped), and ``drive[t, k] = w_read(t, k)`` at the
input spikes, 0 elsewhere — the same drive the SPIKE_BATCH back-end produces, so the agent
and its kernel see no difference but the analog error of the reads. The weights are fixed
during launches (:meth:`apply_update` refuses; no pulse is ever sent from here).
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from snan_hil.calibration.layout import Layout
from snan_hil.host.hil.backend import FixedLayoutSynapses
from snan_hil.protocol.client import BoardClient

CellMode = Literal["per_spike", "per_window"]
CELL_MODES: tuple[str, ...] = ("per_spike", "per_window")


class CellReadSynapses(FixedLayoutSynapses):
    """The input->motor synapses on the crossbar behind ``client``, read cell by cell (see
    module doc). ``nbr``: the agent's neighbour table (int [n_cells, 4], -1 = none);
    ``read_code``: DAC code of the reads (default: the layout's calibrated read code)."""

    def __init__(self, client: BoardClient, layout: Layout, nbr: np.ndarray, *,
                 mode: CellMode = "per_window", read_code: int | None = None) -> None:
        if mode not in CELL_MODES:
            raise ValueError(f"unknown cell-read mode {mode!r} (one of {', '.join(CELL_MODES)})")
        super().__init__(client, layout, nbr, mode, read_code)
        self._cells = {(s.pre, s.post): (s.row, s.col) for s in layout.synapses}

    # ---- reading ----------------------------------------------------------------------
    def _read_spikes(self, pre: int, posts: list[int], bins: np.ndarray,
                     out: np.ndarray) -> None:
        cells = [self._cells[(pre, post)] for post in posts]
        if self.mode == "per_window":
            codes = np.array([[self._read(cell) for cell in cells]], dtype=float)
            w = np.asarray(self.layout.weight_from_cell_code(codes, self.code), dtype=float)
            out[bins, :] = w[0]
            per_synapse = w                          # one reading per synapse
        else:
            codes = np.array([[self._read(cell) for cell in cells] for _ in bins],
                             dtype=float)           # spike by spike, as the spikes arrive
            per_synapse = np.asarray(self.layout.weight_from_cell_code(codes, self.code),
                                     dtype=float)
            out[bins, :] = per_synapse
        self.stats.codes_used += int(codes.size)
        for k, post in enumerate(posts):
            self.stats.add(pre, post, np.ascontiguousarray(per_synapse[:, k]))

    def _read(self, cell: tuple[int, int]) -> int:
        adc = self.client.read_cell(cell[0], cell[1], self.code)
        self.stats.requests += 1
        self.stats.codes_read += 1
        return adc
