"""``--history FILE`` and ``--record LEVEL`` of the commands that touch cells, and the
:class:`~snan_hil.records.history.Recorder` they record through (docs/bench.md).

The database is one per board: by default beside the board's layout, keyed the same way
(:func:`snan_hil.tools.layout_paths.default_history_path`). It is checked with the other
outputs before any work — for a board other than the in-process emulator right after HELLO,
when its identity is known — (a file that is not ours: one line, exit 2); a damaged or locked
database found later gives one warning line and the command goes on unrecorded.
"""

from __future__ import annotations

import argparse
import shlex
from pathlib import Path
from typing import Any

from snan_hil.common.errors import UserError
from snan_hil.records.history import LEVELS, Recorder
from snan_hil.files.outputs import Outputs
from snan_hil.protocol.messages import Info
from snan_hil.tools.console import err_console
from snan_hil.firmware_emu.config import BoardConfig, board_id_text
from snan_hil.firmware_emu.durable import chip_serial
from snan_hil.tools.layout_paths import (default_history_path, emu_state_of_port,
                                         history_path_beside, known_history_path,
                                         layout_path_of_board, layouts_dir)
from snan_hil.tools.output_kinds import check_history_output

__all__ = ["add_history_arguments", "history_output", "history_known", "HistoryCheck",
           "open_recorder", "command_text", "board_history_path"]

RECORD_CHOICES = ("off", *LEVELS)


def add_history_arguments(parser: argparse.ArgumentParser, *, default: str = "pulses") -> None:
    parser.add_argument("--history", metavar="FILE", default=None,
                        help="the board's history database (SQLite; default: beside the "
                             "board's layout, e.g. emu-chip.history.sqlite next to the "
                             "emulator's chip)")
    parser.add_argument("--record", choices=RECORD_CHOICES, default=default,
                        help="what goes into the history database: runs, cells (+ one result "
                             "per cell), pulses (+ every pulse), off (nothing); default: "
                             f"{default}")
    from snan_hil.tools.commands._run import add_run_metadata_options
    add_run_metadata_options(parser)


def history_output(outs: Outputs, args: argparse.Namespace,
                   info: Info | None = None) -> Path | None:
    """The history database of this run, checked (None with ``--record off``).

    The default database is keyed like the board's layout
    (:func:`~snan_hil.tools.layout_paths.default_history_path`): known before the board is
    opened for the in-process emulator, from the board's ``info`` (after HELLO) for any other
    board — call :func:`history_known` first to check it as early as possible."""
    if args.record == "off":
        return None
    default = args.history is None
    path = default_history_path(args.port, info) if default else Path(args.history)
    return check_history_output(outs, "--history", path, default=default)


def history_known(args: argparse.Namespace) -> bool:
    """Whether this run's history database is known before the board answers (``--history``,
    ``--record off``, or the in-process emulator's)."""
    return args.record == "off" or args.history is not None or \
        known_history_path(args.port) is not None


class HistoryCheck:
    """The history database checked as early as it is known: before the board is opened when
    it does not depend on the board, else right after HELLO (before anything is applied)."""

    def __init__(self, outs: Outputs, args: argparse.Namespace, *, enabled: bool = True):
        self.outs, self.args, self.enabled = outs, args, enabled
        self.path: Path | None = None
        self.done = not enabled
        if enabled and history_known(args):
            self.path = history_output(outs, args)
            self.done = True

    def after_hello(self, info: Info) -> Path | None:
        """The checked database (``info``: the board's INFO)."""
        if not self.done:
            self.path = history_output(self.outs, self.args, info)
            self.done = True
        return self.path


def board_history_path(args: argparse.Namespace) -> Path:
    """The history database a command reads without opening the board (``history``, ``cells
    show``): ``--history``, else that of ``--board ID`` (the board id INFO reports, e.g.
    ``EMU-4D430001/8B297CA46845``; the in-process emulator's chip is found by its id too), else
    the in-process emulator's (beside its chip). UserError (naming the known boards) for a
    ``--board`` without a database, or another port without ``--board``: the database is
    keyed by the board, not the port."""
    if getattr(args, "history", None):
        return Path(args.history).expanduser()
    board = getattr(args, "board", None)
    known_boards = _known_boards(args.port)
    if board:
        want = board.strip()
        for board_id, path in known_boards.items():
            if want in (board_id, _safe_id(board_id)) and path.is_file():
                return path
        path = history_path_beside(layout_path_of_board(want))
        if path.is_file():
            return path
        raise UserError(f"--board {board}: no history database of that board ({path} does "
                        f"not exist){_listing(known_boards)}; give a board id as 'snan-hil "
                        "info' shows it, or --history FILE")
    known = known_history_path(args.port)
    if known is not None:
        return known
    raise UserError(f"the history of the board on {args.port} is kept by its board id, not "
                    f"the port: give --board ID (as 'snan-hil info --port {args.port}' shows "
                    f"it){_listing(known_boards)}, or --history FILE")


def _safe_id(board_id: str) -> str:
    return layout_path_of_board(board_id).name[:-len(".json")]


def _known_boards(port: str) -> dict[str, Path]:
    """Board id (or its file-safe name) -> history database, for every board with one: the
    in-process emulator's chip (of ``port`` if it is one, else of ``--port emu``) and the
    databases in the user's layouts folder."""
    found: dict[str, Path] = {}
    emu_port = port if known_history_path(port) is not None else "emu"
    state = emu_state_of_port(emu_port)
    emu_history = known_history_path(emu_port)
    if state is not None and emu_history is not None and emu_history.is_file():
        try:
            serial = chip_serial(state)
        except Exception:                      # an unreadable chip file: not listed
            serial = None
        found[board_id_text(BoardConfig().board_id, serial)] = emu_history
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


def command_text(args: argparse.Namespace) -> str:
    """The command line of this run (for the runs table)."""
    argv = getattr(args, "_argv", None)
    return "snan-hil " + shlex.join(argv) if argv else f"snan-hil {args.command}"


def _warn(line: str) -> None:
    err_console.print(f"warning: {line}", markup=False, highlight=False, soft_wrap=True)


def open_recorder(args: argparse.Namespace, path: Path | None, kind: str, info: Info | None, *,
                  seed: int | None = None, config: Any = None,
                  subscribers: Any = ()) -> Recorder:
    """A recorder of this run in ``path`` (no database when None): its document stream
    carries the run's metadata (``--sample`` ..., :func:`~snan_hil.tools.commands._run.
    metadata_from_args`) and goes to ``subscribers`` too."""
    from snan_hil.tools.commands._run import metadata_from_args
    fields: dict[str, Any] = {"port": getattr(args, "port", None),
                              "protocol": getattr(args, "protocol", None),
                              "seed": seed, "config": config}
    if info is not None:
        fields.update(board_id=info.board_id, firmware_version=info.firmware_version)
    level = args.record if args.record != "off" else "runs"
    return Recorder(path, kind, command=command_text(args), level=level, warn=_warn,
                    metadata=metadata_from_args(args), subscribers=subscribers, **fields)
