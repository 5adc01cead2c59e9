"""The cell bench: one board's cells as every job reaches them, built once from the session.

A job never builds its own limits, ledger, read chain or watched client. It receives a
:class:`CellBench` (from the job runner, :mod:`snan_hil.lab.runner`, or a test) that holds:

* ``limits``: the session's one read and write limit (:class:`~snan_hil.protocol.safety.
  HostLimits`: the board's INFO, lowered by ``--max-write-v`` / ``max_write_v``, never
  raised); a job's own amplitude ceiling (write-and-verify's ``v_max``, a ramp's top) is a job
  parameter checked against it (:meth:`CellBench.check_amplitude`), never a second limit;
* the board's layout and its read chain (loaded when first asked for: a job that programs
  the board reads its layout its own way), the nominal chain of the INFO without one;
* ``ledger``: the pulse ledger of the run (:class:`~snan_hil.calibration.board_io.PulseLedger`,
  baselined on the board's pulse counter when the bench is made);
* ``client``: the session's client as the run controls it (pause / stop from ``snan-hil
  watch`` land between pulses: :class:`~snan_hil.calibration.control.ControlledClient`);
* ``observer``: the run's recorder (and any other observer the caller adds): every pulse a
  cell I/O of the bench applies is journalled before it is sent and after its reply
  (:class:`~snan_hil.records.journal.PulseJournal`) and handed to the observer as it is
  applied, so a job reports only its cells' results (``bench.observer.on_cell``).

:meth:`CellBench.cell` gives the :class:`~snan_hil.calibration.board_io.BoardCellIO` of a
cell with all of that wired in.
"""

from __future__ import annotations

import contextlib
import logging
import math
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from snan_hil.board.session import BoardSession
from snan_hil.calibration.board_io import BoardCellIO, CellLimits, PulseLedger
from snan_hil.calibration.control import ControlledClient
from snan_hil.calibration.layout import Layout, load_session_layout
from snan_hil.calibration.observer import CellEvent, CellObserver, Observers, PulseEvent
from snan_hil.calibration.readchain import ReadChain
from snan_hil.common.errors import UserError
from snan_hil.common.polarity import Polarity
from snan_hil.protocol.client import BoardClient
from snan_hil.protocol.messages import Info
from snan_hil.protocol.safety import MAX_WRITE_OPTION, HostLimits
from snan_hil.records.journal import PulseJournal

__all__ = ["CellBench", "NOMINAL_SOURCE", "COMPLIANCE_MARGIN"]

log = logging.getLogger(__name__)

NOMINAL_SOURCE = "board INFO (nominal)"
"""Where the read chain came from when the board has no layout: its INFO constants."""

COMPLIANCE_MARGIN = 0.95
"""A pulse's predicted current stays below this fraction of the board's compliance current
(stated assumption: a 5 % margin for the read noise of the conductance the prediction
uses)."""


class _NoObserver:
    def on_pulses(self, events: Sequence[PulseEvent]) -> None:
        pass

    def on_cell(self, event: CellEvent) -> None:
        pass


class _ResultsOnly:
    def __init__(self, bench: CellBench) -> None:
        self.bench = bench

    def on_pulses(self, events: Sequence[PulseEvent]) -> None:
        pass                                    # recorded by the bench as they were applied

    def on_cell(self, event: CellEvent) -> None:
        self.bench.observer.on_cell(event)


class CellBench:
    """See the module docstring. ``session``: the open board session; ``client``: the
    session's client as the run controls it (default: the session's own); ``observer``: the
    run's recorder and other observers (default: none); ``journal``: the run's pulse journal
    (default: none); ``layout_required``: the layout file was named by the user (a missing one
    is an error, not "no layout")."""

    def __init__(self, session: BoardSession, *, client: BoardClient | None = None,
                 observer: CellObserver | None = None, journal: PulseJournal | None = None,
                 layout_required: bool = False, ledger: PulseLedger | None = None,
                 baseline: bool = True,
                 warn: Callable[[str], object] | None = None) -> None:
        self.session = session
        self.warn: Callable[[str], object] = warn or (lambda line: log.warning("%s", line))
        """Where a job's warning line goes (the CLI's stderr, a notebook's log)."""
        self.client: BoardClient = client if client is not None else session.client
        self.observer: CellObserver = observer if observer is not None else _NoObserver()
        self.journal = journal
        self.layout_required = layout_required
        self.limits: HostLimits = session.limits
        self._ledger = ledger
        if ledger is None and baseline:
            self._ledger = self._baselined()
        self._layout: Layout | None = None
        self._layout_loaded = False

    def attach(self, *, client: BoardClient | None = None,
               observer: CellObserver | None = None,
               journal: PulseJournal | None = None) -> None:
        """The run's controlled client, observers and journal, once the job's plan is made
        (the job runner plans on the bare bench, so a refusal records nothing)."""
        if client is not None:
            self.client = client
        if observer is not None:
            self.observer = observer
        self.journal = journal

    @property
    def ledger(self) -> PulseLedger:
        """The run's pulse ledger on this bench's connection (baselined on the board's pulse
        counter when the bench is made, or, ``baseline=False``, when first asked for: a bench
        on a fresh connection asks the board nothing before its job does)."""
        if self._ledger is None:
            self._ledger = self._baselined()
        return self._ledger

    def _baselined(self) -> PulseLedger:
        ledger = PulseLedger()
        ledger.rebaseline(self.session.client)
        return ledger

    # -- what the board is ------------------------------------------------------------------
    @property
    def info(self) -> Info:
        return self.session.info

    @property
    def layout_path(self) -> Path | None:
        """The board's layout file (it may not exist yet)."""
        return self.session.files.layout

    @property
    def layout(self) -> Layout | None:
        """The board's layout (checked to be this board's and chip's:
        :class:`~snan_hil.calibration.layout.LayoutError`, one line), None when it has none."""
        if not self._layout_loaded:
            path = self.layout_path
            if path is not None and path.is_file():
                self._layout = load_session_layout(self.session)
            elif path is not None and self.layout_required:
                raise UserError(f"--layout {path}: no such file")
            self._layout_loaded = True
        return self._layout

    def forget_layout(self) -> None:
        """The layout file changed (a job rewrote it): load it again when next asked for."""
        self._layout, self._layout_loaded = None, False

    @property
    def chain(self) -> ReadChain:
        """The read chain reads are converted with: the layout's (calibrated or nominal), else
        the board's nominal one from its INFO."""
        layout = self.layout
        if layout is not None and layout.read_chain is not None:
            return layout.read_chain
        return ReadChain.nominal(self.info)

    @property
    def chain_source(self) -> str:
        """Where :attr:`chain` came from (for reports)."""
        layout, path = self.layout, self.layout_path
        if layout is None:
            return NOMINAL_SOURCE
        if layout.read_chain is None:
            return f"{NOMINAL_SOURCE.removesuffix(')')}; {path} holds no read-chain " \
                   "calibration)"
        kind = "calibrated" if layout.read_chain.calibrated else "nominal"
        return f"{kind} read chain of {path}"

    # -- the one limit --------------------------------------------------------------------
    def check_amplitude(self, volts: float, what: str) -> float:
        """``volts`` (V) if a pulse may have it: positive, finite and at most the one write
        limit (:attr:`limits`); UserError (one line naming ``what`` and the limit) otherwise.
        The check every job makes of its own amplitudes before its first pulse."""
        v = float(volts)
        limit = self.limits.max_write_v
        if not (math.isfinite(v) and v > 0):
            raise UserError(f"{what}: {volts!r} is not a positive amplitude in V")
        if v > limit + 1e-9:
            raise UserError(f"{what}: {v:g} V is above the write limit {limit:g} V of this "
                            f"board session (the board's INFO, lowered by {MAX_WRITE_OPTION}); "
                            "nothing was sent")
        return v

    def limits_for(self, *, ceiling_v: float | None = None, read_code: int | None = None,
                   compliance_margin: float = COMPLIANCE_MARGIN) -> CellLimits:
        """The limits of a cell I/O: the one limit, the job's amplitude ceiling (V, checked:
        UserError above the limit) and read code (default: the read limit's code, the
        board's largest single-cell read code)."""
        if ceiling_v is not None:
            self.check_amplitude(ceiling_v, "amplitude ceiling")
        return CellLimits.of(self.limits, self.info, ceiling_v=ceiling_v,
                             compliance_margin=compliance_margin, read_code=read_code)

    # -- cells --------------------------------------------------------------------------------
    def cell(self, row: int, col: int, *, stage: str | None = None, width_us: int = 100,
             ceiling_v: float | None = None, read_code: int | None = None,
             limits: CellLimits | None = None, chain: ReadChain | None = None
             ) -> BoardCellIO:
        """The write-and-verify I/O of cell (``row``, ``col``): reads converted with
        ``chain`` (default :attr:`chain`), pulses of ``width_us`` (us) at most ``ceiling_v``
        (V) and the write limit, each journalled and recorded as it is applied with
        ``stage``."""
        io = BoardCellIO(self.client, chain if chain is not None else self.chain, row, col,
                         limits if limits is not None else
                         self.limits_for(ceiling_v=ceiling_v, read_code=read_code),
                         self.ledger, width_us, sink=self)
        io.stage = stage
        return io

    @contextlib.contextmanager
    def reopened(self) -> Iterator[CellBench]:
        """This bench on a fresh session of its board (:meth:`BoardSession.reopen`: a new
        connection; on the in-process emulator a fresh boot of the saved chip), closed on the
        way out: the same control channel (pause / stop), observer, journal, layout rule and
        warning line; a ledger baselined on the new connection when first asked for (the
        bench sends nothing of its own: the fresh connection carries only the job's
        requests, as a job's own session did). RuntimeError when the
        session cannot be reopened (``session.reopen_with`` is None)."""
        session = self.session.reopen()
        try:
            client: Any = session.client
            if isinstance(self.client, ControlledClient):      # watched as this run is
                client = ControlledClient(client, self.client.check)
            yield CellBench(session, client=client, observer=self.observer,
                            journal=self.journal, layout_required=self.layout_required,
                            warn=self.warn, baseline=False)
        finally:
            session.close()

    def with_observer(self, *extra: CellObserver | None) -> CellBench:
        """This bench (the same client, ledger, journal and layout) with ``extra`` observers
        told of every pulse and cell result too (e.g. a trace figure's collector)."""
        other = object.__new__(CellBench)
        other.__dict__.update(self.__dict__)
        other.observer = Observers(self.observer, *extra)
        return other

    # -- PulseSink (calibration.board_io) --------------------------------------------------
    def sent(self, row: int, col: int, polarity: Polarity, amplitude_v: float,
             width_us: int, stage: str | None) -> int:
        if self.journal is None:
            return -1
        return self.journal.sent(row, col, polarity.name, amplitude_v, width_us, stage)

    def applied(self, token: int, event: PulseEvent) -> None:
        if self.journal is not None and token >= 0:
            self.journal.done(token, event.g_before_s, event.g_after_s)
        self.observer.on_pulses([event])

    def lost(self, token: int) -> None:
        if self.journal is not None and token >= 0:
            self.journal.lost(token)

    @property
    def cell_results(self) -> CellObserver:
        """An observer for the library functions that report both a cell's pulses and its
        result (``observer.on_pulses(io.applied)``, then ``on_cell``): the pulses of this
        bench's cell I/Os are recorded already as they are applied, so only the results go
        on."""
        return _ResultsOnly(self)

    def report(self, event: CellEvent) -> None:
        """A cell's result (the history's cell table, the run's ``cells`` stream)."""
        self.observer.on_cell(event)

    def snapshot(self) -> dict[str, Any]:
        """The session's provenance record (:meth:`BoardSession.snapshot`)."""
        return self.session.snapshot()
