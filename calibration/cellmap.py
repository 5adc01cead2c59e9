"""The conductance map: every cell of the crossbar read once through the read chain.

ADC codes become conductances through :class:`~snan_hil.calibration.readchain.ReadChain` (the
board's constants and formulas, plus the calibration's fitted offsets and gain when a layout
holds one), the conversion every calibrated read uses, so ``map``, write-and-verify and
``read-weights`` agree on a cell (tests/calibration/test_map_readchain.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from snan_hil.calibration.readchain import ReadChain
from snan_hil.common.progress import ProgressCallback, track
from snan_hil.protocol.client import BoardClient

__all__ = ["CellMap", "read_map"]


@dataclass(frozen=True)
class CellMap:
    """ADC codes of all cells (``adc``: rows x cols, int64), the read DAC code they were read
    at and the chain that converts them (``source`` says where the chain came from)."""

    adc: NDArray[np.int64]
    read_code: int
    chain: ReadChain
    source: str = "board INFO (nominal)"

    @property
    def read_volts(self) -> float:
        """Read voltage of the cell reads (V)."""
        return float(self.chain.cell_read_volts(self.read_code))

    def resistance(self) -> NDArray[np.float64]:
        """Cell + select-transistor resistance (Ohm, rows x cols),
        :meth:`ReadChain.cell_resistance` (inf for open cells)."""
        return np.asarray(self.chain.cell_resistance(self.adc, self.read_code), dtype=float)

    def conductance(self) -> NDArray[np.float64]:
        """1 / resistance (S, rows x cols); 0 for open cells."""
        return np.asarray(self.chain.cell_conductance(self.adc, self.read_code), dtype=float)


def read_map(client: BoardClient, read_code: int | None = None,
             progress: ProgressCallback | None = None,
             chain: ReadChain | None = None, source: str | None = None) -> CellMap:
    """Read all cells with ``client.read_cell`` at DAC code ``read_code`` (default: the
    board's read code from INFO); ``progress`` gets the task "reading cells" (one unit per
    cell). ``chain``: the read chain to convert with (default: the nominal chain of the
    board's INFO)."""
    info = client.info or client.hello()
    code = info.read_code if read_code is None else int(read_code)
    adc = np.zeros((info.rows, info.cols), dtype=np.int64)
    bar = track(progress, "reading cells", info.rows * info.cols)
    for row in range(info.rows):
        for col in range(info.cols):
            adc[row, col] = client.read_cell(row, col, code)
            bar.advance()
    if chain is None:
        return CellMap(adc, code, ReadChain.nominal(info), source or "board INFO (nominal)")
    return CellMap(adc, code, chain, source or "given read chain")
