"""Helpers for tests and benchmarks of the calibration package (no board needed).

* :func:`grid_weights` — a random valid weight matrix (or stack) of a grid SNAN;
* :class:`ArrayCellIO` — a :class:`~snan_hil.calibration.wv.CellIO` straight on a crossbar model
  cell (no protocol), recording every read and pulse, for fast write-and-verify tests;
* :func:`session_of` — the board session of a client a test opened itself, with a layout and a
  report file.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from snan_hil.board.files import BoardFiles, previous_report_path
from snan_hil.board.session import BoardSession
from snan_hil.calibration.weights_io import grid_synapses
from snan_hil.crossbar_model.array import CrossbarArray
from snan_hil.common.polarity import Polarity
from snan_hil.protocol.board import MEMRICORE
from snan_hil.protocol.client import BoardClient

__all__ = ["grid_weights", "ArrayCellIO", "session_of"]


def grid_weights(rows: int, cols: int, seed: int = 0, k: int | None = None,
                 low: float = 0.0, high: float = 1.0) -> NDArray[np.float64]:
    """Uniform random weights on the neighbour synapses of a grid: N x N (or K x N x N)."""
    rng = np.random.default_rng(seed)
    n = rows * cols
    pairs = grid_synapses(rows, cols)
    out = np.zeros((k or 1, n, n))
    for i in range(k or 1):
        for pre, post in pairs:
            out[i, pre, post] = rng.uniform(low, high)
    return out if k else out[0]


@dataclass
class ArrayCellIO:
    """One cell of a ``CrossbarArray`` as a CellIO: G = the noisy cell conductance including
    the select transistor (what the board's read chain reports)."""

    array: CrossbarArray
    row: int
    col: int
    v_max: float = MEMRICORE.max_write_v
    compliance_a: float = MEMRICORE.compliance_a
    r_switch_ohm: float = MEMRICORE.r_switch_ohm
    reads: int = 0
    pulses: list[tuple[Polarity, float]] = field(default_factory=list)

    def _g(self) -> float:
        # cell_current at the read limit with no extra series resistance -> V / (1/G_mem + R_T)
        v = MEMRICORE.max_read_v
        return float(self.array.cell_current(self.row, self.col, v, 0.0)) / v

    def read(self) -> float:
        self.reads += 1
        return self._g()

    def pulse(self, polarity: Polarity, amplitude_v: float) -> float:
        if amplitude_v > self.v_max + 1e-12:
            raise AssertionError(f"pulse {amplitude_v} V above v_max {self.v_max} V")
        self.pulses.append((polarity, float(amplitude_v)))
        self.array.apply_pulse(self.row, self.col, float(amplitude_v), polarity, 100e-6)
        return self.read()

    def amplitude_cap(self, polarity: Polarity, conductance_s: float) -> float:
        return min(self.v_max, self.compliance_a * 0.95 * (1 / conductance_s + self.r_switch_ohm))


def session_of(client: BoardClient, layout: str | os.PathLike[str] | None = None,
               report: str | os.PathLike[str] | None = None, *, port: str = "emu",
               baud: int = 115200) -> BoardSession:
    """:meth:`BoardSession.attach` of ``client`` (HELLO sent if it has none yet) with the
    layout file ``layout`` and the program report ``report`` (None: not written)."""
    files = BoardFiles(Path(layout) if layout is not None else None,
                       Path(report) if report is not None else None,
                       previous_report_path(report) if report is not None else None)
    return BoardSession.attach(client, port=port, files=files, baud=baud)
