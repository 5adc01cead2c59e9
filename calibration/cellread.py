"""Single reads of one cell (``snan-hil read-cell``): its ADC code, conductance and resistance
through the board's read chain, one or more times, as a board job
(:mod:`snan_hil.calibration.job`).

Conductances convert ADC codes with the read chain of the board's layout (calibrated where
programming calibrated it), else the nominal chain of its INFO
(:attr:`snan_hil.calibration.bench.CellBench.chain`), the conversion ``map``,
write-and-verify and ``read-weights`` use.
"""

from __future__ import annotations

import statistics
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any, ClassVar

from snan_hil.calibration.bench import CellBench
from snan_hil.calibration.job import ONE, SingleUnit, UnitContext, check_cells
from snan_hil.calibration.observer import CellEvent
from snan_hil.common.errors import UserError

__all__ = ["MAX_READS", "ReadCellConfig", "ReadCellJob"]

MAX_READS = 10_000
"""Most reads of one cell one job makes (the reads are kept in memory and in the history's
``reads`` stream)."""


@dataclass(frozen=True)
class ReadCellConfig:
    """The cell (``row``, ``col``), how many ``reads``, and the read DAC code (None: the
    board's read code from its INFO; at most its read limit)."""

    row: int
    col: int
    reads: int = 1
    read_code: int | None = None

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


class ReadCellJob:
    """``snan-hil read-cell`` as a board job: one unit, ``reads`` READ_CELLs of one cell (each
    an event of the run's ``reads`` stream), the median conductance the cell's result.
    ``names``: how the front door spells the config's fields in messages."""

    kind: ClassVar[str] = "read"
    restartable: ClassVar[bool] = False

    def __init__(self, config: ReadCellConfig, *, names: Mapping[str, str] | None = None
                 ) -> None:
        self.cfg = config
        self.names = dict(names or {})

    def describe(self) -> dict[str, Any]:
        return self.cfg.to_dict()

    def _name(self, field: str) -> str:
        return self.names.get(field, field)

    def plan(self, bench: CellBench) -> Sequence[SingleUnit]:
        cfg, info = self.cfg, bench.info
        check_cells([(cfg.row, cfg.col)], info, self._name("cell"))
        if not 1 <= cfg.reads <= MAX_READS:
            raise UserError(f"{self._name('reads')} {cfg.reads}: give 1..{MAX_READS}")
        code = self.code(bench)
        if not 1 <= code <= info.max_read_code:
            raise UserError(f"{self._name('read_code')} {code} is above the board's read limit "
                            f"{info.max_read_code}" if code > 0 else
                            f"{self._name('read_code')} {code}: give 1..{info.max_read_code}")
        _ = bench.chain                    # the layout's chain: another board's refused here
        return ONE

    def code(self, bench: CellBench) -> int:
        """The read DAC code of the reads."""
        return bench.info.read_code if self.cfg.read_code is None else int(self.cfg.read_code)

    def run_unit(self, unit: SingleUnit, bench: CellBench, ctx: UnitContext) -> dict[str, Any]:
        cfg, chain, code = self.cfg, bench.chain, self.code(bench)
        samples: list[dict[str, Any]] = []
        for k in range(cfg.reads):
            adc = int(bench.client.read_cell(cfg.row, cfg.col, code))
            g = float(chain.cell_conductance(adc, code))
            samples.append({"n": k + 1, "adc": adc, "g_s": g, "r_ohm": 1 / g if g > 0 else None})
            ctx.emit("reads", {"row": cfg.row, "col": cfg.col, "adc": adc, "read_code": code,
                               "read_v": chain.cell_read_volts(code), "g_s": g,
                               "step": "read-cell"})
        gs = [s["g_s"] for s in samples]
        mean = statistics.fmean(gs)
        summary = {"row": cfg.row, "col": cfg.col, "reads": len(samples),
                   "median_s": statistics.median(gs),
                   "rel_std": statistics.stdev(gs) / mean if len(gs) > 1 and mean > 0 else None}
        bench.report(CellEvent(cfg.row, cfg.col, "read", summary["median_s"],
                               detail={"adc": samples[-1]["adc"], "read_code": code,
                                       "reads": len(samples)}))
        return {"summary": summary, "read_code": code, "read_v": chain.cell_read_volts(code),
                "read_chain": bench.chain_source, "samples": samples}

    def restore(self, unit: SingleUnit, record: dict[str, Any]) -> None:
        pass                                    # the record is all the result needs

    def result(self, records: Mapping[str, dict[str, Any]], status: str
               ) -> dict[str, Any] | None:
        """The record of the reads (None when the run was stopped before they ended):
        ``summary`` (row, col, reads, median conductance in S, relative spread),
        ``read_code``, ``read_v`` (V), ``read_chain`` (where the conversion came from) and
        every read in ``samples`` (n, ADC code, S, Ohm)."""
        return records.get(ONE[0].key)

    def summary(self, result: dict[str, Any] | None) -> dict[str, Any] | None:
        if result is None:
            return None
        return {**result["summary"], "read_code": result["read_code"]}
