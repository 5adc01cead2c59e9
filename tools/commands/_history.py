"""``--history FILE`` and ``--record LEVEL`` of the commands that touch cells, and the
:class:`~snan_hil.history.Recorder` they record through (docs/bench.md).

The database is one per board: by default beside the board's layout
(:func:`snan_hil.tools.layout_paths.default_history_path`). It is checked with the other
outputs before any work (a file that is not ours: one line, exit 2); a damaged or locked
database found later gives one warning line and the command goes on unrecorded.
"""

from __future__ import annotations

import argparse
import shlex
from pathlib import Path
from typing import Any

from snan_hil.history import LEVELS, Recorder
from snan_hil.outputs import Outputs
from snan_hil.protocol.messages import Info
from snan_hil.tools.console import err_console
from snan_hil.tools.layout_paths import default_history_path
from snan_hil.tools.output_kinds import check_history_output

__all__ = ["add_history_arguments", "history_output", "open_recorder", "command_text"]

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


def history_output(outs: Outputs, args: argparse.Namespace) -> Path | None:
    """The history database of this run, checked (None with ``--record off``)."""
    if args.record == "off":
        return None
    default = args.history is None
    path = default_history_path(args.port) if default else Path(args.history)
    return check_history_output(outs, "--history", path, default=default)


def command_text(args: argparse.Namespace) -> str:
    """The command line of this run (for the runs table)."""
    argv = getattr(args, "_argv", None)
    return "snan-hil " + shlex.join(argv) if argv else f"snan-hil {args.command}"


def _warn(line: str) -> None:
    err_console.print(f"warning: {line}", markup=False, highlight=False, soft_wrap=True)


def open_recorder(args: argparse.Namespace, path: Path | None, kind: str, info: Info | None, *,
                  seed: int | None = None, config: Any = None) -> Recorder:
    """A recorder of this run in ``path`` (a no-op recorder when None)."""
    fields: dict[str, Any] = {"port": getattr(args, "port", None),
                              "protocol": getattr(args, "protocol", None),
                              "seed": seed, "config": config}
    if info is not None:
        fields.update(board_id=info.board_id, firmware_version=info.firmware_version)
    level = args.record if args.record != "off" else "runs"
    return Recorder(path, kind, command=command_text(args), level=level, warn=_warn, **fields)
