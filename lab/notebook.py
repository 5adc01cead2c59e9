"""A board from a notebook: ``with snan_hil.open_board("emu://?state=chip.npz&seed=3") as board:``.

:class:`Board` wraps a :class:`~snan_hil.board.session.BoardSession` opened by the opener (the
same checks and order as the command line: outputs, history, emulator state, client, HELLO)
and offers the lab's everyday steps, each returning a dataclass of numbers and numpy arrays
with the unit in every field name:

* :meth:`Board.read_cell` -> :class:`CellReading` (ADC code, read voltage, current,
  conductance of one cell);
* :meth:`Board.map` -> :class:`ConductanceMap` (every cell, rows x cols arrays);
* :meth:`Board.pulse` -> :class:`PulseResult` (one SET/RESET pulse and the read after it);
* :meth:`Board.program_weights` -> :class:`ProgrammingResult` (two-stage write-and-verify of a
  weight matrix, the layout and report kept beside the chip as ``program-weights`` keeps them);
* :meth:`Board.run_scenario` -> :class:`ScenarioRun` (launches of the agent with its synapses
  on the crossbar, or in software).

Conductances convert ADC codes through the board's layout read chain when the board has a
layout (its calibration), else through the nominal chain of its INFO (docs/calibration.md).
The worked session is docs/notebook.md (executed by tests/lab/test_notebook_doc.py).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from snan_hil.board.identity import BoardIdentity
from snan_hil.board.session import BoardSession, Closing
from snan_hil.calibration.board_io import BoardCellIO, BoardLimits, PulseLedger
from snan_hil.calibration.cellmap import read_map
from snan_hil.calibration.layout import Layout, load_session_layout
from snan_hil.calibration.observer import CellObserver
from snan_hil.calibration.programmer import ProgramConfig, program_weights
from snan_hil.calibration.readchain import ReadChain
from snan_hil.calibration.weights_io import load_weight_set
from snan_hil.common.errors import UserError
from snan_hil.common.polarity import Polarity
from snan_hil.lab.opener import FileUse, plan_board
from snan_hil.lab.ports import BoardAddress
from snan_hil.protocol.messages import Info

__all__ = ["Board", "open_board", "CellReading", "ConductanceMap", "PulseResult",
           "ProgrammingResult", "ScenarioRun"]


@dataclass(frozen=True)
class CellReading:
    """One read of cell (``row``, ``col``): the ADC code, the read DAC code and voltage (V),
    the cell's conductance (S, memristor and select transistor in series; 0 for an open
    cell), its resistance (Ohm, inf when open) and the current at the read voltage
    (A, ``read_v * conductance_s``)."""

    row: int
    col: int
    adc_code: int
    read_code: int
    read_v: float
    conductance_s: float
    resistance_ohm: float
    current_a: float


@dataclass(frozen=True)
class ConductanceMap:
    """Every cell read once: ``adc_code`` (rows x cols, int64), ``conductance_s`` (S) and
    ``resistance_ohm`` (Ohm, inf for open cells) of the same shape, the read voltage (V) and
    which read chain converted the codes."""

    adc_code: NDArray[np.int64]
    conductance_s: NDArray[np.float64]
    resistance_ohm: NDArray[np.float64]
    read_v: float
    converted_with: str

    @property
    def readable(self) -> NDArray[np.bool_]:
        """Cells with a finite, positive conductance (rows x cols)."""
        g = self.conductance_s
        return np.asarray((g > 0) & np.isfinite(g))


@dataclass(frozen=True)
class PulseResult:
    """One write pulse on cell (``row``, ``col``): polarity (``SET`` raises the conductance,
    ``RESET`` lowers it), the applied amplitude (V: the write-DAC code's, at most the one
    asked for), the width (us), and the conductance (S) read before and after."""

    row: int
    col: int
    polarity: str
    amplitude_v: float
    width_us: int
    conductance_before_s: float
    conductance_after_s: float


@dataclass(frozen=True)
class ProgrammingResult:
    """A programming run: ``all_ok`` (complete and every synapse inside its window), the
    counts, the median |relative error| of the final conductances, the pulses applied,
    per synapse (in layout order) its target and final conductance (S, NaN where none was
    read), and where the layout and report were written. ``report``: the whole report
    (docs/calibration.md)."""

    all_ok: bool
    synapses: int
    ok: int
    failed: int
    median_abs_rel_error: float | None
    pulses: int
    target_s: NDArray[np.float64]
    final_s: NDArray[np.float64]
    layout_path: Path | None
    report_path: Path | None
    report: dict[str, Any]


@dataclass(frozen=True)
class ScenarioRun:
    """Launches of one scenario on one weight set: path length (steps) and success of each
    launch (arrays of length ``launches``), the median path length of the successful launches
    (None if none), the success rate, the decisions, and per decision the board time (us,
    UART included; None without the board's clock or in software)."""

    scenario: str
    weight_set: int
    seed: int
    path_length_steps: NDArray[np.int64]
    success: NDArray[np.bool_]
    median_steps: float | None
    success_rate: float
    decisions: int
    board_us_per_decision: float | None


class Board(Closing):
    """An opened board for interactive work (see the module docstring). Close it (or use
    ``with``) to release the port and, on the emulator, save the chip."""

    def __init__(self, session: BoardSession):
        self._session: BoardSession | None = session

    @property
    def session(self) -> BoardSession:
        """The open session; UserError once the board is closed."""
        if self._session is None:
            raise UserError("this board is closed; open it again with snan_hil.open_board(...)")
        return self._session

    def _cell(self, row: int, col: int) -> tuple[int, int]:
        """(row, col) as ints inside the array; UserError (one line) otherwise."""
        info = self.info
        out = []
        for name, value, n in (("row", row, info.rows), ("col", col, info.cols)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
                raise UserError(f"{name} must be an integer 0..{n - 1}, got {value!r}")
            if not 0 <= int(value) < n:
                raise UserError(f"{name} {int(value)} outside 0..{n - 1}")
            out.append(int(value))
        return out[0], out[1]

    # -- what it is ---------------------------------------------------------------------------
    @property
    def info(self) -> Info:
        """The board's INFO (its constants: array size, DACs, ADC, limits)."""
        return self.session.info

    @property
    def identity(self) -> BoardIdentity:
        """Board id (with the chip serial) and firmware version."""
        return self.session.identity

    def snapshot(self) -> dict[str, Any]:
        """The session's provenance record (:meth:`BoardSession.snapshot`)."""
        return self.session.snapshot()

    def layout(self) -> Layout | None:
        """The board's layout (checked to be this chip's), None before it is programmed."""
        path = self.session.files.layout
        if path is None or not path.is_file():
            return None
        return load_session_layout(self.session)

    def _chain(self) -> tuple[ReadChain, str]:
        layout = self.layout()
        if layout is not None and layout.read_chain is not None:
            return layout.read_chain, f"read chain of {self.session.files.layout}"
        return ReadChain.nominal(self.info), "board INFO (nominal)"

    # -- reads ------------------------------------------------------------------------------
    def read_cell(self, row: int, col: int, read_code: int | None = None) -> CellReading:
        """One read of cell (``row``, ``col``) at DAC code ``read_code`` (default the board's
        read code; at most its read limit, refused before sending otherwise)."""
        row, col = self._cell(row, col)
        chain, _source = self._chain()
        code = self.info.read_code if read_code is None else int(read_code)
        adc = int(self.session.client.read_cell(row, col, code))
        g = float(chain.cell_conductance(adc, code))
        v = float(chain.cell_read_volts(code))
        r = float(chain.cell_resistance(adc, code))
        return CellReading(row, col, adc, code, v, g, r, v * g)

    def map(self) -> ConductanceMap:
        """Every cell read once at the board's read code."""
        chain, source = self._chain()
        cmap = read_map(self.session.client, chain=chain, source=source)
        return ConductanceMap(cmap.adc, cmap.conductance(), cmap.resistance(), cmap.read_volts,
                              cmap.source)

    # -- writes -----------------------------------------------------------------------------
    def pulse(self, row: int, col: int, *, polarity: str = "set", amplitude_v: float,
              width_us: int = 100) -> PulseResult:
        """One write pulse (``polarity`` "set" or "reset") of ``amplitude_v`` (V, at most the
        host's write limit and the compliance limit at the cell's conductance: refused
        before sending otherwise) and ``width_us`` (us), with a read before and after. A
        programmed synapse on that cell is marked stale in the layout (as ``snan-hil pulse``
        does), so no run takes it for its programmed weight."""
        row, col = self._cell(row, col)
        pol = Polarity.parse(polarity)
        limit_v = self.session.limits.max_write_v
        if not (isinstance(amplitude_v, (int, float, np.floating))
                and np.isfinite(amplitude_v) and 0 < amplitude_v <= limit_v):
            raise UserError(f"amplitude_v must be a number of volts in (0, {limit_v:g}] (the "
                            f"host's write limit), got {amplitude_v!r}; nothing was sent")
        if isinstance(width_us, bool) or not isinstance(width_us, (int, np.integer)) \
                or not 1 <= int(width_us) <= 1_000_000:
            raise UserError(f"width_us must be an integer 1..1000000 (us), got {width_us!r}")
        chain, _source = self._chain()
        ledger = PulseLedger()
        ledger.rebaseline(self.session.client)
        limits = BoardLimits.for_board(self.info, limit_v)
        io = BoardCellIO(self.session.client, chain, row, col, limits, ledger, width_us)
        before = io.read()
        after = io.pulse(pol, amplitude_v)
        applied = io.applied[-1].amplitude_v if io.applied else amplitude_v
        self._mark_stale(row, col, f"notebook pulse {pol.name} {applied:.3f} V: "
                                   f"{before * 1e6:.1f} -> {after * 1e6:.1f} uS")
        return PulseResult(row, col, pol.name, float(applied), int(width_us), before, after)

    def _mark_stale(self, row: int, col: int, why: str) -> None:
        layout = self.layout()
        synapse = layout.synapse_at(row, col) if layout is not None else None
        if layout is None or synapse is None or synapse.weight is None:
            return
        synapse.stale, synapse.ok = why, False
        path = self.session.files.layout
        assert path is not None                         # the layout was loaded from it
        layout.save(path)

    def program_weights(self, weights: str | os.PathLike[str] | NDArray[np.float64], *,
                        weight_set: int = 0, config: ProgramConfig | None = None,
                        observer: CellObserver | None = None) -> ProgrammingResult:
        """Program a weight matrix (a weights file from ``snan-hil train`` / a ``.npy``, its
        set ``weight_set``; or an N x N array of a square grid, weights in [0, 1]) with
        two-stage write-and-verify; the layout and the report go to the board's files."""
        if isinstance(weights, (str, os.PathLike)):
            w, meta = load_weight_set(weights, weight_set)
        else:
            w = np.asarray(weights, dtype=float)
            if w.ndim != 2 or w.shape[0] != w.shape[1] or w.shape[0] < 4 \
                    or round(np.sqrt(w.shape[0])) ** 2 != w.shape[0]:
                raise UserError(f"weights must be an N x N matrix of a square grid's cells "
                                f"(N = side^2, e.g. 36 x 36 for 6x6), got shape {w.shape}")
            side = int(round(np.sqrt(w.shape[0])))
            meta = {"grid": [side, side]}
        result = program_weights(self.session, w, meta, config=config, observer=observer)
        cells = result.report["cells"]
        s = result.report["summary"]

        def column(key: str) -> NDArray[np.float64]:
            return np.array([np.nan if c[key] is None else c[key] for c in cells], dtype=float)
        return ProgrammingResult(result.all_ok, int(s["cells"]), int(s["ok"]), int(s["failed"]),
                                 s["median_abs_rel_error"], int(s["host_pulses"]),
                                 column("target_s"), column("final_s"),
                                 self.session.files.layout, self.session.files.report,
                                 result.report)

    # -- the agent --------------------------------------------------------------------------
    def run_scenario(self, scenario: str, weights: str | os.PathLike[str], *,
                     weight_set: int = 0, launches: int = 10, seed: int = 1,
                     overrides: tuple[str, ...] = ()) -> ScenarioRun:
        """Launch the agent ``launches`` times on the HIL task in ``scenario`` (``sw_*``:
        weights as numbers; ``hw_*``: every synapse read from this board, which must hold
        weight set ``weight_set`` of ``weights``; ``*_astro``: with astrocytes). The launch
        model is configs/hil-6x6.yaml with ``overrides`` (``key=value``), checked against the
        weights file's training config as ``snan-hil run`` checks it."""
        # the SNAN kernels (numba, ~0.1 s of imports) only when a scenario runs: a cell test
        # or a pulse plan from a notebook does without them
        from snan_hil.host.hil.compare import check_weights_grid, task_of
        from snan_hil.host.hil.config import load_hil_config
        from snan_hil.host.hil.runner import check_layout, run_scenario, scenario_parts
        from snan_hil.host.hil.trained_config import check_trained_config
        hw, _astro = scenario_parts(scenario)
        w, meta = load_weight_set(weights, weight_set)
        hil = load_hil_config(None, list(overrides))
        check_weights_grid(meta, hil, str(weights))
        check_trained_config(meta, hil, str(weights))
        start, goal = task_of(meta, hil)
        layout = None
        if hw:
            layout = self.layout()
            if layout is None:
                raise UserError(f"the board on {self.session.port} holds no layout: program "
                                "the weights first (board.program_weights)")
            check_layout(layout, w, tuple(meta["grid"]), port=self.session.port,
                         weights_path=str(weights), set_index=weight_set,
                         board_options=self.session.options)
        res = run_scenario(scenario, w, hil, set_index=weight_set, launches=launches,
                           seed=seed, start=start, goal=goal,
                           client=self.session.client if hw else None, layout=layout,
                           baud=self.session.baud if hw else None)
        decisions = sum(r.decisions for r in res.launches)
        clock = [r.virtual_us for r in res.launches]
        board_us = (sum(c for c in clock if c is not None) / decisions
                    if hw and decisions and all(c is not None for c in clock) else None)
        return ScenarioRun(scenario, weight_set, seed,
                           np.array(res.path_lengths, dtype=np.int64),
                           np.array([r.success for r in res.launches], dtype=bool),
                           res.median_steps, res.success_rate, decisions, board_us)

    def close(self) -> None:
        """Close the port (on the emulator the chip is saved); closing twice is harmless."""
        if self._session is not None:
            session, self._session = self._session, None
            session.close()


def open_board(port: str = "emu", *, protocol: str = "framed", baud: int = 115200,
               timeout: float | None = None, max_write_v: float | None = None,
               layout: str | os.PathLike[str] | None = None) -> Board:
    """Open the board on ``port`` (``emu``, ``emu://?state=FILE&seed=N``, a device path, a
    pyserial URL such as ``socket://HOST:PORT``) through the opener. ``layout``: another
    layout file than the board's own. UserError (one line) when the board cannot be opened or a
    file of it is not snan-hil's."""
    if not isinstance(port, str):
        raise UserError(f"port must be a text such as 'emu' or 'emu://?state=FILE', got "
                        f"{port!r}")
    use = FileUse(layout=None if layout is None else str(layout), updates_layout=True,
                  writes_report=True)
    address = BoardAddress(port, protocol=protocol, baud=baud, timeout=timeout,
                           max_write_v=max_write_v)
    return Board(plan_board(address, use).open())
