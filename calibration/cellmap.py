"""The conductance map: every cell of the crossbar read once through the read chain.

ADC codes become conductances through :class:`~snan_hil.calibration.readchain.ReadChain` (the
board's constants and formulas, plus the calibration's fitted offsets and gain when a layout
holds one), the conversion every calibrated read uses, so ``map``, write-and-verify and
``read-weights`` agree on a cell (tests/calibration/test_map_readchain.py).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from snan_hil.calibration.bench import CellBench
from snan_hil.calibration.job import ONE, SingleUnit, UnitContext
from snan_hil.calibration.observer import CellEvent
from snan_hil.calibration.readchain import ReadChain
from snan_hil.common.errors import UserError
from snan_hil.common.progress import ProgressCallback, track
from snan_hil.protocol.client import BoardClient

__all__ = ["CellMap", "read_map", "MapConfig", "MapJob"]


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

    def summary(self) -> dict[str, Any]:
        """Cells, readable cells (finite positive conductance), saturated reads (ADC at full
        scale), median / least / largest readable conductance (S; None without one)."""
        g = self.conductance()
        ok = g[(g > 0) & np.isfinite(g)]
        return {"cells": int(g.size), "readable": int(ok.size),
                "saturated": int(np.sum(self.adc >= self.chain.adc_full_scale_code)),
                "median_s": float(np.median(ok)) if ok.size else None,
                "min_s": float(ok.min()) if ok.size else None,
                "max_s": float(ok.max()) if ok.size else None}


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


@dataclass(frozen=True)
class MapConfig:
    """The read DAC code of a map's reads (None: the board's read code from its INFO; at
    least 1, at most its read limit)."""

    read_code: int | None = None


class MapJob:
    """``snan-hil map`` as a board job (:mod:`snan_hil.calibration.job`): one unit, every
    cell read once and converted with the bench's read chain (the layout's, else the
    board's nominal one); each cell's conductance a cell result. ``names``: how the front
    door spells the config's fields in messages."""

    kind: ClassVar[str] = "map"
    restartable: ClassVar[bool] = False

    def __init__(self, config: MapConfig | None = None, *,
                 names: Mapping[str, str] | None = None) -> None:
        self.cfg = config or MapConfig()
        self.names = dict(names or {})
        self._map: CellMap | None = None

    def describe(self) -> dict[str, Any]:
        return {"read_code": self.cfg.read_code}

    def plan(self, bench: CellBench) -> Sequence[SingleUnit]:
        code, info = self.cfg.read_code, bench.info
        name = self.names.get("read_code", "read_code")
        if code is not None and code < 1:
            raise UserError(f"{name} {code}: a read needs a DAC code of at least 1 (a 0 V read "
                            f"sees no current); give 1..{info.max_read_code}")
        if code is not None and code > info.max_read_code:
            raise UserError(f"{name} {code} is above the board's read limit "
                            f"{info.max_read_code} ({info.cell_read_volts(info.max_read_code):.3f}"
                            f" V: higher voltages may change a cell); give 1.."
                            f"{info.max_read_code}")
        _ = bench.chain                    # the layout's chain: another board's refused here
        return ONE

    def run_unit(self, unit: SingleUnit, bench: CellBench, ctx: UnitContext) -> dict[str, Any]:
        cmap = read_map(bench.client, self.cfg.read_code, progress=ctx.progress,
                        chain=bench.chain, source=bench.chain_source)
        g = cmap.conductance()
        for r in range(g.shape[0]):
            for c in range(g.shape[1]):
                bench.report(CellEvent(r, c, "read", float(g[r, c]),
                                       detail={"adc": int(cmap.adc[r, c]),
                                               "read_code": cmap.read_code}))
        self._map = cmap
        return {"read_code": cmap.read_code, "read_chain": cmap.source,
                "adc": cmap.adc.tolist()}

    def restore(self, unit: SingleUnit, record: dict[str, Any]) -> None:
        raise NotImplementedError("a map is not resumed")

    def result(self, records: Mapping[str, dict[str, Any]], status: str) -> CellMap | None:
        """The map (None when the run was stopped before it was read whole)."""
        return self._map if ONE[0].key in records else None

    def summary(self, result: CellMap | None) -> dict[str, Any] | None:
        return None if result is None else {**result.summary(), "chain": result.source}
