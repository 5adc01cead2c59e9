"""Emulated chips seen from the host: where a chip's files are, its snapshots, its identity.

One chip has one layout and one history database however it is reached (issue 27, item 9):
in-process (``--port emu``, ``emu://?state=FILE``) or served by ``snan-hil emu --state FILE``
over a pty or a socket. Both keep them beside the chip's state file
(:meth:`~snan_hil.board.files.BoardFiles.beside_chip`). In-process the opener knows the file;
a served chip is found by its serial: ``snan-hil emu`` records, when it starts serving,
which state file holds the chip of that serial (:func:`register_served_chip`,
``chips/<serial>.json`` in the user's data folder); after HELLO the opener looks the chip up
(:func:`served_chip_state`) and checks the record against the chip file itself (a reset or
replaced chip has another serial: the record is ignored). A board whose chip is not found
that way (a real board, an emulator on another machine) keeps its files by board id in the
user's data folder.
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path

from snan_hil.board.files import (BoardFiles, history_beside, layout_beside_chip,
                                  layout_path_of_board, previous_report_path, report_beside,
                                  safe_name)
from snan_hil.board.identity import BoardIdentity
from snan_hil.common.errors import UserError
from snan_hil.crossbar_model.array import CrossbarArray
from snan_hil.files.atomicio import atomic_write_bytes, atomic_write_json
from snan_hil.files.outputs import OutputError, Outputs
from snan_hil.files.userdata import user_data_dir
from snan_hil.firmware_emu import durable, state as chip_state
from snan_hil.firmware_emu.chip_identity import firmware_board_id_text
from snan_hil.firmware_emu.config import BoardConfig, board_id_text
from snan_hil.firmware_emu.durable import chip_serial, copy_chip, remove_chip, restore_chip
from snan_hil.firmware_emu.state import STATE_ENV, made_by_us
from snan_hil.lab.kinds import CHIP_STATE

__all__ = ["EmuChipSnapshots", "register_served_chip", "served_chip_state", "state_served_on",
           "emulated_board_id", "check_chip_state_output", "forget_chip_layouts",
           "files_of_served_chip", "SERVED_CHIP_FORMAT"]

log = logging.getLogger(__name__)

SERVED_CHIP_FORMAT = "snan-hil-served-chip/1"


def _record_path(serial: str) -> Path:
    return user_data_dir() / "chips" / f"{safe_name(serial)}.json"


def register_served_chip(serial: str, state: Path, served_on: str | None = None
                         ) -> Path | None:
    """Record that the chip ``serial`` is kept in the state file ``state`` (called by
    ``snan-hil emu`` before it serves the chip), and ``served_on``: the pty path or
    ``socket://`` URL it is served on (so a command that does not open the board, ``watch``,
    ``history``, finds the chip's files from the port: :func:`state_served_on`); returns the
    record's path, None when it could not be written (logged: hosts then key the chip's
    files by board id)."""
    path = _record_path(serial)
    record: dict[str, object] = {"format": SERVED_CHIP_FORMAT, "serial": serial,
                                 "state": str(Path(state).expanduser().resolve())}
    if served_on:                       # by this process, now: the record's served_on holds
        import datetime as _dt          # while it runs (state_served_on)
        import socket
        record.update(served_on=served_on, pid=os.getpid(), host=socket.gethostname(),
                      since_utc=_dt.datetime.now(_dt.timezone.utc).isoformat())
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_json(path, record, indent=1)
    except OSError as exc:
        log.warning("cannot record where chip %s is kept (%s): hosts will key its layout by "
                    "board id", serial, exc)
        return None
    return path


def _same_port(a: str, b: str) -> bool:
    if a == b:
        return True
    try:
        return Path(a).resolve() == Path(b).resolve()
    except (OSError, ValueError):
        return False


def state_served_on(port: str) -> Path | None:
    """The state file of the emulated chip a running ``snan-hil emu`` serves on ``port`` (a
    pty path, a ``socket://`` URL) when that file still holds the recorded chip, else None
    (another program's port, an emulator that has stopped: the port may serve something else
    now, or a chip served before this record existed)."""
    from snan_hil.firmware_emu.durable import chip_serial
    from snan_hil.records.history import process_alive
    folder = user_data_dir() / "chips"
    found: list[tuple[float, Path]] = []
    for record in folder.glob("*.json") if folder.is_dir() else ():
        try:
            data = json.loads(record.read_text(encoding="utf-8"))
            when = record.stat().st_mtime
        except (OSError, ValueError):
            continue
        if not isinstance(data, dict) or data.get("format") != SERVED_CHIP_FORMAT or \
                not _same_port(str(data.get("served_on", "")), port) or \
                not process_alive(data.get("pid"), data.get("host"), data.get("since_utc")):
            continue
        state = Path(str(data.get("state")))
        try:
            if chip_serial(state) == data.get("serial"):
                found.append((when, state))
        except UserError:
            continue
    return max(found)[1] if found else None


def served_chip_state(identity: BoardIdentity) -> Path | None:
    """The state file of the emulated chip that answered with ``identity`` when
    ``snan-hil emu`` recorded one on this machine and it still holds that chip, else None."""
    serial = identity.chip_id
    if not serial:
        return None
    try:
        data = json.loads(_record_path(serial).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or data.get("format") != SERVED_CHIP_FORMAT \
            or data.get("serial") != serial:
        return None
    state = Path(str(data.get("state")))
    try:
        if chip_serial(state) != serial:
            return None                 # reset or replaced since: not this chip any more
    except UserError:
        return None
    return state


def emulated_board_id(state: Path, mcu: str = "model", seed: int = 0) -> str:
    """The board id INFO will report for the in-process emulator on the chip file ``state``
    (``EMU-4D430001/<serial>``, the C firmware's ``MC-4D430001/<serial>`` with ``mcu``
    "firmware"), without booting it: the chip is created from ``seed`` if none exists yet (as
    the first boot would)."""
    release = chip_state.acquire(state)       # not while an emulator runs on this chip
    try:
        if not state.exists():
            durable.create_chip(state, seed)
        serial = durable.chip_serial(state)
    finally:
        release()
    if mcu == "firmware":
        return firmware_board_id_text(BoardConfig().board_id, serial)
    return board_id_text(BoardConfig().board_id, serial)


def check_chip_state_output(outs: Outputs, state: Path, *, default: bool) -> Path:
    """The in-process emulator rewrites its chip state file: checked like an output (a chip
    state or new, in a writable folder; only the default chip's folder in the user's data
    folder is made). ``default``: the file is ``$SNAN_HIL_EMU_STATE`` or the default chip
    (not named in the port)."""
    if default:
        label = f"chip state (${STATE_ENV})"
        where = f"chip state {state} (${STATE_ENV} or the default)"
        fix = f"point ${STATE_ENV} at another file or move it away"
    else:
        label, where = "chip state", f"chip state {state}"
        fix = "give another state= in --port or move it away"
    if state.is_file() and not CHIP_STATE.owns(state):
        raise OutputError(f"{where} exists and is not {CHIP_STATE.name}; {fix}")
    return outs.file(label, state, CHIP_STATE, updates=True,
                     create_folder=made_by_us(state))


def forget_chip_layouts(state: Path, serial: str | None) -> tuple[list[Path], Path | None]:
    """After ``snan-hil emu --reset-chip``: remove the old chip's layouts and program reports
    (beside the chip, and by board id where an older version kept a served chip's) and set
    its history database aside as ``<stem>.history-<serial>.sqlite`` (a record, never
    deleted). Returns (removed files, kept history or None)."""
    layouts = [layout_beside_chip(state)]
    if serial:
        board = BoardConfig().board_id
        layouts += [layout_path_of_board(board_id_text(board, serial)),
                    layout_path_of_board(firmware_board_id_text(board, serial))]
        _record_path(serial).unlink(missing_ok=True)
    removed = []
    for layout in layouts:
        report = report_beside(layout)
        for f in (layout, report, previous_report_path(report)):
            if f.is_file():
                f.unlink()
                removed.append(f)
    history = history_beside(layout_beside_chip(state))
    kept = None
    if history.is_file():
        kept = history.with_name(history.name.replace(".history.sqlite",
                                                      f".history-{serial or 'old'}.sqlite"))
        os.replace(history, kept)
        from snan_hil.records.pending import pending_dir
        if pending_dir(history).is_dir():        # the old chip's runs waiting for a lock:
            os.replace(pending_dir(history), pending_dir(kept))   # with its database
    return removed, kept


class EmuChipSnapshots:
    """The in-process emulator's chip saved and put back at the set boundaries of a run
    (:class:`snan_hil.board.session.ChipSnapshots`), so a resumed run redoes an unfinished
    set on the chip that set started from."""

    def __init__(self, state_file: Path):
        self.state_file = state_file

    def save(self, dest: Path) -> None:
        if self.state_file.exists():
            copy_chip(self.state_file, dest)
        else:                               # no chip yet: an empty snapshot says so
            atomic_write_bytes(dest, b"")

    def check(self, src: Path) -> None:
        """UserError (one line naming ``src``) unless ``src`` is a readable chip (or the
        empty snapshot of no chip); reads only."""
        if not src.is_file():
            raise UserError(f"--resume: the checkpoint lacks the chip snapshot {src}; start a "
                            "new run in another --out")
        if src.stat().st_size == 0:
            return
        try:
            CrossbarArray.load(str(src))
        except UserError as exc:
            reason = str(getattr(exc, "reason", exc)).replace(f"chip state {src} ", "") \
                .replace(str(src), "the file")
            what = reason if reason.startswith("is ") else f"is damaged ({reason})"
            raise UserError(f"--resume: the chip snapshot {src} in the checkpoint {what}; the "
                            f"chip {self.state_file} was left untouched; start the run again "
                            "in a new --out") from None

    def restore(self, src: Path) -> None:
        self.check(src)
        if src.stat().st_size == 0:
            remove_chip(self.state_file)    # the run started before the chip existed
        else:
            restore_chip(src, self.state_file)


def files_of_served_chip(identity: BoardIdentity) -> BoardFiles | None:
    """The files of a chip served by ``snan-hil emu`` on this machine (beside its state file),
    None when it is not found (:func:`served_chip_state`)."""
    state = served_chip_state(identity)
    return BoardFiles.beside_chip(state) if state is not None else None
