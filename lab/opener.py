"""The opener: the one place a :class:`~snan_hil.board.session.BoardSession` is built, in the
one safe order (docs/outputs.md, docs/architecture.md):

1. :func:`plan_board` — the options checked, the board's files known so far resolved (all of
   them for the in-process emulator: beside its chip), the layout declared as an input never
   overwritten, and the files the job rewrites (layout, program report) checked as outputs;
   the caller then checks its own outputs on :attr:`BoardPlan.outputs`;
2. :meth:`BoardPlan.open` — the history database (when known already), the emulated chip's
   state file, the client and HELLO; then, for a board whose files depend on who it is, the
   files resolved from its identity and checked before anything is applied; the client is
   closed again on any failure.

Every emulator special case of the command line lives here and in :mod:`snan_hil.lab.ports` /
:mod:`snan_hil.lab.chips`: which chip file, the chip's snapshots, where a served chip's files
are, the first sequence number of an in-process link.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from snan_hil.board.files import (BoardFiles, history_beside, layout_beside_chip,
                                  layout_path_of_board, layouts_dir)
from snan_hil.board.identity import BoardIdentity
from snan_hil.board.session import BoardSession
from snan_hil.common.errors import UserError
from snan_hil.files.outputs import Outputs
from snan_hil.firmware_emu.config import BoardConfig, board_id_text
from snan_hil.firmware_emu.durable import chip_serial
from snan_hil.lab.chips import (EmuChipSnapshots, check_chip_state_output, state_served_on,
                                files_of_served_chip, served_chip_state)
from snan_hil.lab.kinds import LAYOUT, PROGRAM_REPORT, check_history_output
from snan_hil.lab.ports import EMU_PORT, BoardAddress, connect, resolve_mcu
from snan_hil.protocol.safety import MAX_WRITE_OPTION

__all__ = ["FileUse", "BoardPlan", "plan_board", "open_session", "history_of_board"]


@dataclass(frozen=True)
class FileUse:
    """What a job does with the board's files. ``layout`` / ``report`` / ``history``: the
    files the user named (None: the board's own); ``record``: the job adds to the history
    database (False: ``--record off``, no database); ``updates_layout``: it rewrites the
    layout (programming); ``writes_report``: it writes a program report (and keeps the last
    complete one beside it)."""

    layout: str | None = None
    report: str | None = None
    history: str | None = None
    record: bool = False
    updates_layout: bool = False
    writes_report: bool = False
    report_option: str = "--report"
    """How messages name the program report (a job without a ``--report`` option)."""
    amplitude: tuple[float, str] | None = None
    """The job's largest write amplitude (V) and the option that sets it (``--v-max``):
    checked once against each limit — the host's ``--max-write-v`` before the board is
    opened, the board's ``max_write_v`` right after HELLO, before anything is applied."""


class BoardPlan:
    """A board about to be opened (step 1 done, see the module docstring): :attr:`files`
    holds what is known before HELLO, :attr:`outputs` the checked outputs (add the job's
    own before :meth:`open`)."""

    def __init__(self, address: BoardAddress, use: FileUse, outputs: Outputs,
                 options: str | None):
        self.address, self.use, self.outputs, self.options = address, use, outputs, options
        state = address.chip_state
        known = BoardFiles.beside_chip(state) if state is not None else BoardFiles()
        self.files = self._named(known)
        self.snapshots = EmuChipSnapshots(state) if state is not None else None
        self.mcu = resolve_mcu(address.port, address.mcu)
        self._opened: BoardSession | None = None
        if use.amplitude is not None and address.max_write_v is not None:
            _check_amplitude(*use.amplitude, address.max_write_v, host=True)
        self._check_job_files(self.files)

    @property
    def port(self) -> str:
        return self.address.port

    @property
    def protocol(self) -> str:
        return self.address.protocol

    @property
    def baud(self) -> int:
        return self.address.baud

    def _named(self, files: BoardFiles) -> BoardFiles:
        """``files`` with the ones the user named; no history without recording."""
        use = self.use
        files = files.overridden(layout=use.layout, report=use.report, history=use.history)
        return files if use.record else dataclasses.replace(files, history=None)

    def _check_job_files(self, files: BoardFiles, before: BoardFiles | None = None) -> None:
        """The layout and report the job rewrites, checked as outputs (those not checked
        already in ``before``)."""
        outs, use = self.outputs, self.use
        if use.updates_layout and files.layout is not None and \
                (before is None or before.layout is None):
            outs.file("--layout", files.layout, LAYOUT, updates=True,
                      create_folder=use.layout is None)
        if use.writes_report and files.report is not None and \
                (before is None or before.report is None):
            named, option = use.report is not None, use.report_option
            outs.file(option, files.report, PROGRAM_REPORT, create_folder=not named)
            prev = files.previous_report
            assert prev is not None                     # set with the report
            outs.file(option, prev, PROGRAM_REPORT, create_folder=not named,
                      label=f"{prev} (where a failed run keeps the last complete {option})")

    def _check_history(self, files: BoardFiles, before: BoardFiles | None = None) -> None:
        if files.history is not None and (before is None or before.history is None):
            check_history_output(self.outputs, "--history", files.history,
                                 default=self.use.history is None)

    def open(self) -> BoardSession:
        """Open the board (step 2): a connected session; the first call checks the history
        database and the emulated chip's state file before connecting and the files that
        depend on the board's identity right after HELLO, later calls (a fresh connection per
        set of a comparison) check that the same board answers."""
        first = self._opened is None
        address = self.address
        if first:
            self._check_history(self.files)
            state = address.chip_state
            if state is not None:
                check_chip_state_output(self.outputs, state, default=address.port == EMU_PORT
                                        and not address.state_file)
        client = connect(address)
        try:
            session = BoardSession.attach(client, port=address.port, files=self.files,
                                          baud=address.baud, mcu=self.mcu,
                                          options=self.options, reopen_with=self.open,
                                          snapshots=self.snapshots)
            if first:
                if self.use.amplitude is not None:
                    _check_amplitude(*self.use.amplitude, session.info.max_write_v, host=False)
                session.files = self._resolve(session.identity)
            else:
                self._same_board(session.identity)
                session.files = self.files
        except BaseException:
            client.close()
            raise
        if first:
            self.files = session.files
            self._opened = session
        return session

    def _resolve(self, identity: BoardIdentity) -> BoardFiles:
        """The board's files once its identity is known (in-process: as planned), checked."""
        if self.address.in_process:
            return self.files
        own = files_of_served_chip(identity) or BoardFiles.of_board(identity,
                                                                   self.address.port)
        files = self._named(own)
        self._check_job_files(files, self.files)
        self._check_history(files, self.files)
        return files

    def _same_board(self, identity: BoardIdentity) -> None:
        assert self._opened is not None
        was = self._opened.identity
        if identity.known and was.known and identity.board_id != was.board_id:
            raise UserError(f"the board on {self.address.port} is now {identity.board_id}, "
                            f"not {was.board_id} as when this run started; reconnect that "
                            "board, or start a new run for this one")


def _check_amplitude(volts: float, option: str, limit_v: float, *, host: bool) -> None:
    """UserError (one line naming ``option``) when a job's largest write amplitude is above
    the host's write limit (``host``, ``--max-write-v``) or the board's."""
    if volts <= limit_v + 1e-9:
        return
    if host:
        raise UserError(f"{option} {volts} V is above the host's write limit {limit_v:g} V "
                        f"({MAX_WRITE_OPTION}); lower {option} or raise {MAX_WRITE_OPTION}")
    raise UserError(f"{option} {volts} V is above the board's write limit {limit_v} V")


def plan_board(address: BoardAddress, use: FileUse | None = None, *,
               inputs: Mapping[str, str | os.PathLike[str] | None] | None = None,
               outputs: Outputs | None = None, force: bool = False,
               options: str | None = None) -> BoardPlan:
    """Plan opening ``address`` (step 1, see the module docstring): the options checked, the
    board's known files resolved, ``inputs`` (option -> path the job reads) and the layout
    declared as inputs never overwritten (in ``outputs`` when given, else in new
    :class:`Outputs` with ``force``: outputs of another kind may be replaced), the layout and
    report the job rewrites (``use``) checked. ``options``: the command-line options that
    reach this board again, for hints (default ``--port PORT``)."""
    address.check()
    use = use or FileUse()
    state = address.chip_state
    layout = use.layout if use.layout is not None else (
        BoardFiles.beside_chip(state).layout if state is not None else None)
    declared = {"--layout": layout, **(inputs or {})}
    if outputs is None:
        outputs = Outputs(declared, force=force)
    else:
        for name, path in Outputs(declared).inputs.items():
            outputs.inputs.setdefault(name, path)
    return BoardPlan(address, use, outputs, options)


def open_session(address: BoardAddress | str, use: FileUse | None = None) -> BoardSession:
    """Plan and open ``address`` (a :class:`BoardAddress` or a port string / URL) at once."""
    if isinstance(address, str):
        address = BoardAddress(address)
    return plan_board(address, use).open()


def history_of_board(*, history: str | None, board: str | None, port: str) -> Path:
    """The history database a command reads without opening the board (``history``, ``cells
    show``): ``history`` if given, else that of ``board`` (the board id INFO reports, e.g.
    ``EMU-4D430001/8B297CA46845``: beside its chip when it is an emulated chip this machine
    knows, else by board id in the user's data folder), else the in-process emulator's of
    ``port``. UserError (naming the known boards) for a ``board`` without a database, or
    another port without ``board``: the database is keyed by the board, not the port."""
    if history:
        return Path(history).expanduser()
    known_boards = _known_boards(port)
    if board:
        want = board.strip()
        for board_id, path in known_boards.items():
            if want in (board_id, _safe_id(board_id)) and path.is_file():
                return path
        state = served_chip_state(BoardIdentity(want))
        if state is not None and history_beside(layout_beside_chip(state)).is_file():
            return history_beside(layout_beside_chip(state))
        path = history_beside(layout_path_of_board(want))
        if path.is_file():
            return path
        raise UserError(f"--board {board}: no history database of that board ({path} does "
                        f"not exist){_listing(known_boards)}; give a board id as 'snan-hil "
                        "info' shows it, or --history FILE")
    state = BoardAddress(port).chip_state or state_served_on(port)   # emulated: its chip's
    if state is not None:
        return history_beside(layout_beside_chip(state))
    raise UserError(f"the history of the board on {port} is kept by its board id, not "
                    f"the port: give --board ID (as 'snan-hil info --port {port}' shows "
                    f"it){_listing(known_boards)}, or --history FILE")


def _safe_id(board_id: str) -> str:
    return layout_path_of_board(board_id).name[:-len(".json")]


def _known_boards(port: str) -> dict[str, Path]:
    """Board id (or its file-safe name) -> history database, for every board with one: the
    in-process emulator's chip (of ``port`` if it is one, else of ``--port emu``) and the
    databases in the user's layouts folder."""
    found: dict[str, Path] = {}
    address = BoardAddress(port if BoardAddress(port).in_process else EMU_PORT)
    state = address.chip_state
    assert state is not None                       # an in-process emulator port
    history = history_beside(layout_beside_chip(state))
    if history.is_file():
        try:
            serial = chip_serial(state)
        except Exception:                      # an unreadable chip file: not listed
            serial = None
        found[board_id_text(BoardConfig().board_id, serial)] = history
    for p in sorted(layouts_dir().glob("*.history.sqlite")):
        found.setdefault(p.name[:-len(".history.sqlite")], p)
    return found


def _listing(known: dict[str, Path]) -> str:
    if not known:
        return f" (no board has a history database yet in {layouts_dir()} or beside the " \
               "emulator's chip)"
    names = list(known)
    return " (boards with a history: " + ", ".join(names[:6]) + \
        (", ..." if len(names) > 6 else "") + ")"
