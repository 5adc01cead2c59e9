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

import contextlib
import dataclasses
import functools
import os
import re
import sys
import uuid
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from snan_hil.board.identity import BoardIdentity
from snan_hil.board.session import BoardSession, Closing
from snan_hil.calibration.cellmap import MapJob
from snan_hil.calibration.cellread import ReadCellConfig, ReadCellJob
from snan_hil.calibration.layout import Layout, load_session_layout
from snan_hil.calibration.job import BoardJob
from snan_hil.calibration.observer import CellObserver
from snan_hil.calibration.programmer import ProgramConfig, ProgramJob
from snan_hil.calibration.readchain import ReadChain
from snan_hil.calibration.screening import ScreenConfig, ScreenJob, ScreenRun, UserCriteria
from snan_hil.calibration.tickets import MAX_WIDTH_US, PulseTicket, PulseTicketJob
from snan_hil.calibration.weights_io import load_weight_set, validate_weights
from snan_hil.common.errors import UserError
from snan_hil.common.polarity import Polarity
from snan_hil.common.progress import ProgressCallback, ProgressEvent
from snan_hil.lab.opener import FileUse, plan_board
from snan_hil.lab.ports import BoardAddress
from snan_hil.lab.runner import JobRun, RunOptions, run_job
from snan_hil.protocol.messages import Info
from snan_hil.records.documents import RunMetadata, check_tag, control_character
from snan_hil.records.history import LEVELS

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


OPTION_KEYWORDS = {"--max-write-v": "max_write_v", "--timeout": "timeout", "--baud": "baud",
                   "--protocol": "protocol", "--port": "port", "--layout": "layout",
                   "--history": "history", "--record": "record", "--weight-set": "weight_set",
                   "--launches": "launches", "--seed": "seed", "--set": "overrides",
                   "--sample": "sample", "--operator": "operator", "--note": "note",
                   "--tag": "tags", "--v-max": "config.wv.v_max", "--cells": "cells"}
"""The command line's options a shared check may name, as this API's keywords."""

_OPTION = re.compile(r"(?<![\w-])--[a-z][a-z0-9-]*")

_F = TypeVar("_F", bound=Callable[..., Any])


def speaks_keywords(fn: _F) -> _F:
    """``fn`` with its UserErrors naming this API's keywords where a check shared with the
    command line names its options (``--max-write-v`` -> ``max_write_v``); the same one
    line otherwise."""
    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return fn(*args, **kwargs)
        except UserError as exc:
            if exc.args and isinstance(exc.args[0], str):
                exc.args = (_OPTION.sub(lambda m: OPTION_KEYWORDS.get(m.group(0), m.group(0)),
                                        exc.args[0]), *exc.args[1:])
            raise
    return wrapper  # type: ignore[return-value]


class Board(Closing):
    """An opened board for interactive work (see the module docstring). Close it (or use
    ``with``) to release the port and, on the emulator, save the chip.

    Every step that touches the chip runs as a job through the job runner
    (:mod:`snan_hil.lab.runner`), as the command line's do: recorded in the chip's history
    database (``record``: "pulses" by default, "cells", "runs", or "off"), pausable and
    stoppable from ``snan-hil watch``, with a progress display (``progress``: True for a bar
    on stderr, a callback of :class:`~snan_hil.common.progress.ProgressEvent`, or None). The
    run's metadata (``sample``, ``operator``, ``note``, ``tags``) goes with every run."""

    def __init__(self, session: BoardSession, *, record: str = "pulses",
                 metadata: RunMetadata | None = None,
                 progress: bool | ProgressCallback | None = True) -> None:
        if record not in ("off", *LEVELS):
            raise UserError(f"record must be one of off, {', '.join(LEVELS)}; got {record!r}")
        self._session: BoardSession | None = session
        self.record = record
        self.metadata = metadata or RunMetadata()
        self.progress = progress
        self.last_run: JobRun[Any] | None = None
        """The last job's run: its status, history run id and uid, the result."""

    @speaks_keywords
    def run(self, job: BoardJob[Any, Any], *, what: str | None = None,
            observers: tuple[CellObserver, ...] = ()) -> JobRun[Any]:
        """Run ``job`` (any :class:`~snan_hil.calibration.job.BoardJob`) on this board through
        the job runner: recorded, pausable, with progress (see the class docstring);
        ``observers`` get its pulses and cell results too. The run
        (:class:`~snan_hil.lab.runner.JobRun`); a stop or Ctrl-C raises
        :class:`~snan_hil.lab.runner.JobInterrupted` (its ``run`` holds what finished)."""
        label = what or type(job).__name__
        meta = dataclasses.replace(self.metadata, uid=str(uuid.uuid4()))
        with _progress(self.progress) as show:
            options = RunOptions(record=self.record, metadata=meta, progress=show,
                                 command=f"snan_hil.open_board({self.session.port!r})"
                                         f".{label}", observers=observers)
            done = run_job(job, self.session, options)
        self.last_run = done
        return done

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
    @speaks_keywords
    def read_cell(self, row: int, col: int, read_code: int | None = None) -> CellReading:
        """One read of cell (``row``, ``col``) at DAC code ``read_code`` (default the board's
        read code; at most its read limit, refused before sending otherwise), recorded as
        ``snan-hil read-cell`` records it (:class:`~snan_hil.calibration.cellread.
        ReadCellJob`)."""
        row, col = self._cell(row, col)
        code = None if read_code is None else _whole("read_code", read_code, 0,
                                                     self.info.max_read_code)
        job = ReadCellJob(ReadCellConfig(row, col, 1, code), names={"cell": "row, col"})
        done = self.run(job, what="read_cell").result
        chain, _source = self._chain()
        adc, code = int(done["samples"][-1]["adc"]), int(done["read_code"])
        g = float(chain.cell_conductance(adc, code))
        v = float(chain.cell_read_volts(code))
        r = float(chain.cell_resistance(adc, code))
        return CellReading(row, col, adc, code, v, g, r, v * g)

    @speaks_keywords
    def map(self) -> ConductanceMap:
        """Every cell read once at the board's read code."""
        cmap = self.run(MapJob(), what="map").result      # recorded as snan-hil map's
        return ConductanceMap(cmap.adc, cmap.conductance(), cmap.resistance(), cmap.read_volts,
                              cmap.source)

    # -- writes -----------------------------------------------------------------------------
    @speaks_keywords
    def pulse(self, row: int, col: int, *, polarity: str = "set", amplitude_v: float,
              width_us: int = 100) -> PulseResult:
        """One write pulse (``polarity`` "set" or "reset") of ``amplitude_v`` (V, at most the
        host's write limit and the compliance limit at the cell's conductance: refused
        before sending otherwise) and ``width_us`` (us), with a read before and after: a pulse
        ticket of one pulse (:class:`~snan_hil.calibration.tickets.PulseTicketJob`, as
        ``snan-hil pulse`` runs it). A programmed synapse on that cell is marked stale in the
        layout, so no run takes it for its programmed weight."""
        row, col = self._cell(row, col)
        pol = _polarity(polarity)
        limit_v = self.session.limits.max_write_v
        if isinstance(amplitude_v, bool) or not isinstance(amplitude_v,
                                                          (int, float, np.floating)) \
                or not np.isfinite(amplitude_v) or not 0 < amplitude_v <= limit_v:
            raise UserError(f"amplitude_v must be a number of volts in (0, {limit_v:g}] (the "
                            f"write limit), got {amplitude_v!r}; nothing was sent")
        if isinstance(width_us, bool) or not isinstance(width_us, (int, np.integer)) \
                or not 1 <= int(width_us) <= MAX_WIDTH_US:
            raise UserError(f"width_us must be an integer 1..{MAX_WIDTH_US} (us), got "
                            f"{width_us!r}")
        ticket = PulseTicket(row, col, pol, (float(amplitude_v),), width_us=int(width_us))
        run = self.run(PulseTicketJob(ticket), what="pulse").result
        res = run.result
        if not res.steps:
            raise UserError(f"pulse on ({row},{col}) not sent: {res.stopped}")
        step = res.steps[0]
        return PulseResult(row, col, pol.name, float(step.amplitude_v), int(width_us),
                           step.g_before_s, step.g_after_s)

    @speaks_keywords
    def cell_test(self, cells: Sequence[tuple[int, int]] | None = None, *,
                  criteria: UserCriteria | None = None, **config: Any) -> ScreenRun:
        """Probe ``cells`` (default: every cell) and classify each (good, stuck high, stuck
        low, noisy, unresponsive), as ``snan-hil cells test`` does
        (:class:`~snan_hil.calibration.screening.ScreenJob`); ``config``: fields of
        :class:`~snan_hil.calibration.screening.ScreenConfig` (``reads``, ``v_max``, ...);
        ``criteria``: the user's pass criteria. The board's layout marks the bad cells."""
        chosen = None if cells is None else [self._cell(*c) for c in cells]
        try:
            cfg = ScreenConfig(**config)
        except TypeError as exc:
            raise UserError(f"cell_test: {exc}; the settings are the fields of ScreenConfig "
                            f"({', '.join(f.name for f in dataclasses.fields(ScreenConfig))})"
                            ) from None
        except ValueError as exc:
            raise UserError(f"cell_test: {exc}") from None
        return self.run(ScreenJob(chosen, cfg, criteria), what="cell_test").result

    @speaks_keywords
    def program_weights(self, weights: str | os.PathLike[str] | NDArray[np.float64], *,
                        weight_set: int = 0, config: ProgramConfig | None = None,
                        observer: CellObserver | None = None) -> ProgrammingResult:
        """Program a weight matrix (a weights file from ``snan-hil train`` / a ``.npy``, its
        set ``weight_set``; or an N x N array of a square grid, weights in [0, 1]) with
        two-stage write-and-verify (:class:`~snan_hil.calibration.programmer.ProgramJob`,
        recorded as ``program-weights`` records it; the cells a cell test found bad are
        avoided); the layout and the report go to the board's files; ``observer`` gets the
        run's pulses and cell results too."""
        if isinstance(weights, (str, os.PathLike)):
            w, meta = load_weight_set(weights, weight_set)
        else:
            w = np.asarray(weights, dtype=float)
            if w.ndim != 2 or w.shape[0] != w.shape[1] or w.shape[0] < 4 \
                    or round(np.sqrt(w.shape[0])) ** 2 != w.shape[0]:
                raise UserError(f"weights must be an N x N matrix of a square grid's cells "
                                f"(N = side^2, e.g. 36 x 36 for 6x6), got shape {w.shape}")
            side = int(round(np.sqrt(w.shape[0])))
            w = validate_weights(w, side, side)  # what program-weights refuses (one line)
            meta = {"grid": [side, side]}
        job = ProgramJob(w, meta, config, names={"v_max": "config.wv.v_max"})
        result = self.run(job, what="program_weights",
                          observers=(observer,) if observer is not None else ()).result
        cells = result.report["cells"]
        s = result.report["summary"]

        def column(key: str) -> NDArray[np.float64]:
            return np.array([np.nan if c[key] is None else c[key] for c in cells], dtype=float)
        return ProgrammingResult(result.all_ok, int(s["cells"]), int(s["ok"]), int(s["failed"]),
                                 s["median_abs_rel_error"], int(s["host_pulses"]),
                                 column("target_s"), column("final_s"),
                                 result.layout_path, result.report_path,
                                 result.report)

    # -- the agent --------------------------------------------------------------------------
    @speaks_keywords
    def run_scenario(self, scenario: str, weights: str | os.PathLike[str], *,
                     weight_set: int = 0, launches: int = 10, seed: int = 1,
                     overrides: tuple[str, ...] = ()) -> ScenarioRun:
        """Launch the agent ``launches`` times on the HIL task in ``scenario`` (``sw_*``:
        weights as numbers; ``hw_*``: every synapse read from this board, which must hold
        weight set ``weight_set`` of ``weights``; ``*_astro``: with astrocytes). The launch
        model is configs/hil-6x6.yaml with ``overrides`` (``key=value``), checked against the
        weights file's training config as ``snan-hil run`` checks it."""
        from snan_hil.host.hil.config import load_hil_config
        from snan_hil.host.hil.scenario import ScenarioConfig, ScenarioJob
        from snan_hil.host.hil.trained_config import check_trained_config
        launches = _whole("launches", launches, 1)
        seed = _whole("seed", seed, 0, 2**63 - 1)
        weight_set = _whole("weight_set", weight_set, 0)
        if not isinstance(weights, (str, os.PathLike)):
            raise UserError(f"weights must be a weights file (from snan-hil train or "
                            f"board.program_weights' source), got {type(weights).__name__}")
        hil = load_hil_config(None, list(overrides))
        job = ScenarioJob(ScenarioConfig(scenario, str(weights), weight_set, launches, seed),
                          hil, program_hint="program the weights first (board.program_weights)")
        check_trained_config(job.meta, hil, str(weights))
        hw = job.hw
        res = self.run(job, what="run_scenario").result if hw else job.run_without_board()
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


def _whole(name: str, value: Any, lo: int, hi: int | None = None) -> int:
    """``value`` as an int in ``lo..hi``; UserError (one line, naming the keyword ``name``)
    for a bool, a float, a string or a number outside the range: never truncated."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise UserError(f"{name} must be a whole number, got {value!r}")
    v = int(value)
    if v < lo or (hi is not None and v > hi):
        span = f"{lo}..{hi}" if hi is not None else f">= {lo}"
        raise UserError(f"{name} {v} outside {span}")
    return v


def _polarity(polarity: Any) -> Polarity:
    """``polarity`` ("set" / "reset", any case, or a Polarity); UserError naming the keyword."""
    try:
        return Polarity.parse(polarity)
    except (ValueError, KeyError, TypeError, AttributeError):
        raise UserError(f"polarity must be 'set' or 'reset', got {polarity!r}; nothing was "
                        "sent") from None


@contextlib.contextmanager
def _progress(progress: bool | ProgressCallback | None) -> Iterator[ProgressCallback | None]:
    """A progress callback for one run: True -> bars on stderr (rich; in a notebook too),
    a callable -> itself, None / False -> none."""
    if progress is None or progress is False:
        yield None
        return
    if callable(progress):
        yield progress
        return
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                  console=Console(file=sys.stderr), transient=True) as bar:
        tasks: dict[str, Any] = {}

        def show(event: ProgressEvent) -> None:
            if event.task not in tasks:
                tasks[event.task] = bar.add_task(event.task, total=event.total)
            bar.update(tasks[event.task], completed=event.done, total=event.total,
                       description=f"{event.task} {event.detail or ''}".strip())
        yield show


@speaks_keywords
def open_board(port: str = "emu", *, protocol: str = "framed", baud: int = 115200,
               timeout: float | None = None, max_write_v: float | None = None,
               layout: str | os.PathLike[str] | None = None, record: str = "pulses",
               history: str | os.PathLike[str] | None = None, sample: str | None = None,
               operator: str | None = None, note: str | None = None,
               tags: Sequence[str] = (),
               progress: bool | ProgressCallback | None = True) -> Board:
    """Open the board on ``port`` (``emu``, ``emu://?state=FILE&seed=N``, a device path, a
    pyserial URL such as ``socket://HOST:PORT``) through the opener. ``layout``: another
    layout file than the board's own; ``max_write_v`` (V): lowers the board's write limit
    (never raises it); ``record`` / ``history``: what goes into which history database (the
    chip's own by default: every run of this board is recorded, as the command line's are);
    ``sample``, ``operator``, ``note``, ``tags``: recorded with every run; ``progress``: see
    :class:`Board`. UserError (one line, naming the keyword) when the board cannot be opened
    or a file of it is not snan-hil's."""
    if not isinstance(port, str):
        raise UserError(f"port must be a text such as 'emu' or 'emu://?state=FILE', got "
                        f"{port!r}")
    if record not in ("off", *LEVELS):
        raise UserError(f"record must be one of off, {', '.join(LEVELS)}; got {record!r}")
    if isinstance(tags, str):
        raise UserError(f"tags must be a list of texts, e.g. tags=[{tags!r}]; got the text "
                        f"{tags!r}")
    meta = _metadata(sample=sample, operator=operator, note=note, tags=tags)
    use = FileUse(layout=None if layout is None else str(layout),
                  history=None if history is None else str(history),
                  record=record != "off", updates_layout=True, writes_report=True)
    address = BoardAddress(port, protocol=protocol, baud=baud, timeout=timeout,
                           max_write_v=max_write_v)
    return Board(plan_board(address, use).open(), record=record, metadata=meta,
                 progress=progress)


def _metadata(**fields: Any) -> RunMetadata:
    """The run metadata from the keywords (checked as the command line checks its options:
    UserError naming the keyword)."""
    out: dict[str, Any] = {}
    for key in ("sample", "operator", "note"):
        value = fields[key]
        if value is None:
            continue
        text = str(value).strip()
        if not text or control_character(text) is not None:
            raise UserError(f"{key} must be plain text (no blank value, no control "
                            f"characters), got {value!r}")
        out[key] = text
    try:
        tags = tuple(dict.fromkeys(check_tag(t) for t in fields["tags"]))
    except ValueError as exc:
        raise UserError(f"tags: {exc}") from None
    return RunMetadata(tags=tags, **out)
