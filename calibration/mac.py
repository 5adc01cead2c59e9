"""Accuracy of the crossbar's column multiply-accumulate against numpy (the paper's Fig. 10B).

For ``vectors`` random row-voltage vectors over the rows the layout uses, every used column
``c`` is multiplied. A vector first draws a density ``d`` uniform in (0, 1); each row is driven
with probability ``d`` (at least one row), at a voltage uniform in ``[0, v_max_v]`` (at most the
board's read limit, 0.3 V on MemriCore), so the multiplies cover the whole output range from a
single driven cell to a full column (dense vectors alone would sit near full scale).
In each column only the rows whose cell in column ``c`` holds a programmed synapse are driven
(the others at 0 V), so the reference is exactly ``I_ref = sum_i V_i G_i`` (numpy, A) over
cells with a known target conductance ``G_i`` (S). The voltages are the row DAC's: each entry
is floored to a DAC code and the reference uses the code's voltage (the same vector the board
applied).

Measured current:

* framed protocol: one READ_COLUMN per (vector, column), converted with the layout's
  calibrated read chain (:meth:`~snan_hil.protocol.board.BoardConstants.column_current_a`);
* legacy protocol (no column read, shared/reference/memricore-board.md): the **sum of
  single-cell reads** — each driven cell read (mode 9) at its own voltage code, ``V_i G_i``
  from the cell-read conductance, summed on the host. Labelled as such in every output.

Errors are given in percent of the column path's full scale ``I_FS`` (the current of the
largest ADC code, 1.38 mA on MemriCore: 14-bit ADC, 5 V reference, gain 11, 330 Ohm
transimpedance). A vector whose reference current would exceed ``fill`` of ``I_FS`` in a column
(15 rows at up to 0.3 V and up to 1 mS can ask for 4.5 mA) is scaled down for that column, so
no read saturates by design; how many were scaled is reported. A second reference uses the
conductances read back cell by cell before the multiplies (``readback``): its error isolates
the analog multiply from the programming error.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from snan_hil.calibration.bench import CellBench
from snan_hil.calibration.job import ONE, SingleUnit, UnitContext
from snan_hil.calibration.layout import Layout
from snan_hil.calibration.readchain import ReadChain
from snan_hil.common.errors import UserError
from snan_hil.common.progress import ProgressCallback, track
from snan_hil.protocol.client import BoardClient
from snan_hil.protocol.messages import Capability, Info

Floats = NDArray[np.float64]
"""A float64 array (shape and unit in each docstring)."""

__all__ = ["MAC_FORMAT", "METHOD_COLUMN", "METHOD_CELL_SUM", "MacConfig", "MacSample",
           "MacResult", "mac_cells", "row_v_max", "run_mac", "error_stats", "MacJob", "MacRun"]

MAC_FORMAT = "snan-hil-mac/1"
METHOD_COLUMN = "READ_COLUMN (column multiply on the board)"
METHOD_CELL_SUM = "sum of single-cell reads (legacy protocol: no column read)"


@dataclass(frozen=True)
class MacConfig:
    """Settings of a MAC accuracy run (V, fractions, counts)."""

    vectors: int = 100
    seed: int = 0
    v_max_v: float | None = None      # None: the board's read limit (its max read code)
    fill: float = 0.9                 # reference current at most this fraction of full scale
    readback_reads: int = 4           # cell reads averaged for the read-back reference

    def __post_init__(self) -> None:
        if self.vectors < 1:
            raise UserError(f"--vectors must be >= 1, got {self.vectors}")
        if not 0 < self.fill <= 1:
            raise UserError(f"fill must be in (0, 1], got {self.fill}")
        if self.v_max_v is not None and not (math.isfinite(self.v_max_v) and self.v_max_v > 0):
            raise UserError(f"--v-max must be a positive number of volts, got {self.v_max_v}")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class MacSample:
    """One column multiply: vector ``k``, column, rows driven, currents (A)."""

    vector: int
    column: int
    rows: int
    measured_a: float
    reference_a: float
    readback_a: float
    adc: int | None
    scaled: bool
    saturated: bool


@dataclass
class MacResult:
    """All multiplies of a run and their error statistics (percent of full scale)."""

    method: str
    full_scale_a: float
    v_max_v: float
    samples: list[MacSample] = field(default_factory=list)
    cells: int = 0
    columns: list[int] = field(default_factory=list)

    def arrays(self) -> dict[str, Floats]:
        s = self.samples
        return {"measured": np.array([x.measured_a for x in s]),
                "reference": np.array([x.reference_a for x in s]),
                "readback": np.array([x.readback_a for x in s])}

    def errors_pct(self, against: str = "reference") -> Floats:
        a = self.arrays()
        return 100.0 * (a["measured"] - a[against]) / self.full_scale_a

    def summary(self) -> dict[str, Any]:
        target = error_stats(self.errors_pct("reference"))
        readback = error_stats(self.errors_pct("readback"))
        return {"method": self.method, "samples": len(self.samples), "cells": self.cells,
                "columns": self.columns, "full_scale_a": self.full_scale_a,
                "v_max_v": self.v_max_v,
                "rms_error_pct_fs": target["rms"], "max_error_pct_fs": target["max_abs"],
                "mean_error_pct_fs": target["mean"],
                "rms_error_pct_fs_readback": readback["rms"],
                "max_error_pct_fs_readback": readback["max_abs"],
                "mean_error_pct_fs_readback": readback["mean"],
                "scaled": sum(x.scaled for x in self.samples),
                "saturated": sum(x.saturated for x in self.samples)}


def error_stats(err: Floats) -> dict[str, float | None]:
    """RMS, largest magnitude and mean of errors (same unit as ``err``)."""
    e = np.asarray(err, dtype=float)
    if e.size == 0:
        return {"rms": None, "max_abs": None, "mean": None}
    return {"rms": float(np.sqrt(np.mean(e * e))), "max_abs": float(np.max(np.abs(e))),
            "mean": float(np.mean(e))}


def mac_cells(layout: Layout) -> dict[int, list[tuple[int, float]]]:
    """Per used column, its programmed cells: {col: [(row, target G in S), ...]} (rows
    ascending). UserError if the layout holds no programmed synapse."""
    out: dict[int, list[tuple[int, float]]] = {}
    for s in layout.synapses:
        if s.target_s is None or not s.target_s > 0:
            continue
        out.setdefault(s.col, []).append((s.row, float(s.target_s)))
    if not out:
        raise UserError("the layout holds no programmed synapse; program weights first "
                        "(snan-hil program-weights, or mac --weights FILE|random)")
    return {c: sorted(cells) for c, cells in sorted(out.items())}


def row_v_max(info: Info, cfg: MacConfig, name: str = "--v-max") -> float:
    """The largest row voltage of the run (V): ``cfg.v_max_v``, default the board's read
    limit (its largest row-DAC code's voltage); UserError (one line naming ``name``) above
    it."""
    top_code = info.max_read_code
    v_limit = info.dac_volts(top_code)
    v_max = v_limit if cfg.v_max_v is None else float(cfg.v_max_v)
    if v_max > v_limit + 1e-12:
        raise UserError(f"{name} {v_max:g} V is above the board's read limit "
                        f"{info.max_read_v:g} V (largest row-DAC code {top_code} = "
                        f"{v_limit:.4f} V): higher row voltages could change the cells")
    return v_max


def _readback(client: BoardClient, chain: ReadChain, cells: dict[int, list[tuple[int, float]]],
              reads: int) -> dict[tuple[int, int], float]:
    code = chain.read_code
    out = {}
    for col, rows in cells.items():
        for row, _g in rows:
            g = [chain.cell_conductance(client.read_cell(row, col, code), code)
                 for _ in range(max(1, reads))]
            out[(row, col)] = float(np.mean(g))
    return out


def run_mac(client: BoardClient, layout: Layout, cfg: MacConfig, *,
            progress: ProgressCallback | None = None) -> MacResult:
    """The MAC accuracy run (module docstring) on the board behind ``client`` (HELLO done)
    holding ``layout``'s programmed weights. ``progress`` gets the task "column multiplies"
    (one unit per vector)."""
    info = client.info or client.hello()
    chain = layout.read_chain if layout.read_chain is not None else ReadChain.nominal(info)
    cells = mac_cells(layout)
    column = info.has(Capability.READ_COLUMN)
    top_code = info.max_read_code
    v_max = row_v_max(info, cfg)
    full_scale = float(chain.column_current_a(chain.adc_full_scale_code))
    res = MacResult(METHOD_COLUMN if column else METHOD_CELL_SUM, full_scale, v_max,
                    cells=sum(len(v) for v in cells.values()), columns=list(cells))
    readback = _readback(client, chain, cells, cfg.readback_reads)
    used_rows = sorted({r for rows in cells.values() for r, _ in rows})
    rng = np.random.default_rng(cfg.seed)
    bar = track(progress, "column multiplies", cfg.vectors,
                f"{len(cells)} columns, {'READ_COLUMN' if column else 'cell reads'}")
    for k in range(cfg.vectors):
        density = rng.uniform(0.0, 1.0)
        active = rng.random(len(used_rows)) < density
        active[rng.integers(len(used_rows))] = True            # never an all-zero vector
        amp = rng.uniform(0.0, v_max, size=len(used_rows))
        volts = dict(zip(used_rows, np.where(active, amp, 0.0)))
        for col, rows in cells.items():
            g = np.array([gt for _r, gt in rows])
            g_read = np.array([readback[(r, col)] for r, _ in rows])
            v = np.array([volts[r] for r, _ in rows])
            scaled = False
            ref_plan = float(v @ g)
            if ref_plan > cfg.fill * full_scale:
                v = v * (cfg.fill * full_scale / ref_plan)
                scaled = True
            codes = [info.dac_floor_code(float(x)) for x in v]
            codes = [min(c, top_code) for c in codes]
            v_applied = np.array([chain.row_volts(c) for c in codes])
            adc: int | None = None
            if column:
                row_codes = [0] * info.rows
                for (r, _), c in zip(rows, codes):
                    row_codes[r] = c
                adc = int(client.read_column(col, row_codes))
                measured = float(chain.column_current_a(adc))
                saturated = adc >= chain.adc_full_scale_code
            else:
                measured, saturated = 0.0, False
                for (r, _), c in zip(rows, codes):
                    if c <= 0:
                        continue
                    a = client.read_cell(r, col, c)
                    saturated |= a >= chain.adc_full_scale_code
                    measured += chain.cell_read_volts(c) * float(chain.cell_conductance(a, c))
            res.samples.append(MacSample(k, col, len(rows), measured, float(v_applied @ g),
                                         float(v_applied @ g_read), adc, scaled,
                                         bool(saturated)))
        bar.advance(1)
    return res


@dataclass
class MacRun:
    """A MAC accuracy run as :class:`MacJob` ran it: the result, the layout it multiplied
    with (and its file), the synapses a pulse changed after programming (``stale``: pre,
    post, row, col, why; their targets no longer describe the cells)."""

    result: MacResult
    layout: Layout
    layout_path: Path | None
    stale: list[dict[str, Any]]


class MacJob:
    """``snan-hil mac`` as a board job (:mod:`snan_hil.calibration.job`): one unit, the
    multiplies on the weights the board's layout records as programmed. ``hint``: what the
    front door tells a user whose board holds no layout; ``names``: how it spells the
    config's fields in messages (``v_max``)."""

    kind: ClassVar[str] = "mac"
    restartable: ClassVar[bool] = False

    def __init__(self, config: MacConfig | None = None, *,
                 hint: str = "program the weights first",
                 names: Mapping[str, str] | None = None) -> None:
        self.cfg = config or MacConfig()
        self.hint = hint
        self.names = dict(names or {})
        self._layout: Layout | None = None
        self._run: MacRun | None = None

    def describe(self) -> dict[str, Any]:
        return self.cfg.to_dict()

    def plan(self, bench: CellBench) -> Sequence[SingleUnit]:
        from snan_hil.calibration.layout import load_session_layout
        path, session = bench.layout_path, bench.session
        if path is None or not path.is_file():
            raise UserError(f"no layout for board {session.identity.board_id} on "
                            f"{session.port} ({path}): {self.hint}")
        self._layout = load_session_layout(session)
        mac_cells(self._layout)                     # a layout without programmed synapses
        row_v_max(bench.info, self.cfg, self.names.get("v_max", "v_max"))
        return ONE

    def run_unit(self, unit: SingleUnit, bench: CellBench, ctx: UnitContext) -> dict[str, Any]:
        layout = self._layout
        assert layout is not None                               # plan() loaded it
        result = run_mac(bench.client, layout, self.cfg, progress=ctx.progress)
        stale = [{"pre": s.pre, "post": s.post, "row": s.row, "col": s.col, "why": s.stale}
                 for s in layout.stale_synapses()]
        self._run = MacRun(result, layout, bench.layout_path, stale)
        return {"summary": result.summary()}

    def restore(self, unit: SingleUnit, record: dict[str, Any]) -> None:
        raise NotImplementedError("a MAC run is not resumed")

    def result(self, records: Mapping[str, dict[str, Any]], status: str) -> MacRun | None:
        """The run (None when it was stopped before its multiplies ended)."""
        return self._run if ONE[0].key in records else None

    def summary(self, result: MacRun | None) -> dict[str, Any] | None:
        return None if result is None else result.result.summary()
