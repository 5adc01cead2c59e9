"""``--history FILE`` and ``--record LEVEL`` of the commands that touch cells, and the
:class:`~snan_hil.records.history.Recorder` they record through (docs/bench.md).

The database is one per board: by default beside the board's layout, keyed the same way
(:class:`snan_hil.board.files.BoardFiles`). The opener checks it with the other outputs before
any work — for a board whose files depend on its identity right after HELLO —
(:mod:`snan_hil.lab.opener`; a file that is not ours: one line, exit 2); a damaged or locked
database found later gives one warning line and the command goes on unrecorded.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from snan_hil.lab.opener import history_of_board
from snan_hil.records.history import LEVELS
from snan_hil.tools.commands._run import add_run_metadata_options

__all__ = ["add_history_arguments", "board_history_path", "recording"]

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
    add_run_metadata_options(parser)


def recording(args: argparse.Namespace) -> bool:
    """Whether this run adds to the history database (not ``--record off``)."""
    return getattr(args, "record", "off") != "off"


def board_history_path(args: argparse.Namespace) -> Path:
    """The history database a command reads without opening the board (``history``, ``cells
    show``): ``--history``, else that of ``--board ID``, else the in-process emulator's
    (:func:`snan_hil.lab.opener.history_of_board`)."""
    return history_of_board(history=getattr(args, "history", None),
                            board=getattr(args, "board", None), port=args.port)


