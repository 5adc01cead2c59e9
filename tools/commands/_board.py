"""What the board commands (map, pulse, cells, mac, retention, read-weights) share.

* Options: ``--layout``, ``--png FILE``, and the tail ``--json`` / ``--history`` /
  ``--record`` / ``--force`` (help texts stay each command's own).
* Opening the board in the one safe order: outputs checked first (:class:`Outputs`, keyed by
  the port's layout as an input never overwritten), then the history database, the emulator's
  state, and only then the client, closed on the way out; after HELLO the history path of
  this board.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from snan_hil.files.outputs import Outputs
from snan_hil.protocol.client import BoardClient
from snan_hil.protocol.messages import Info
from snan_hil.tools.commands._history import HistoryCheck, add_history_arguments
from snan_hil.tools.layout_paths import known_layout_path
from snan_hil.tools.output_kinds import add_force_option, check_emu_state
from snan_hil.tools.ports import client_from_args

__all__ = ["add_layout_option", "add_png_option", "add_result_options", "greeted_board",
           "layout_outputs", "open_board"]


def add_layout_option(parser: argparse.ArgumentParser, help: str) -> None:
    """``--layout FILE`` (default None: the port's layout)."""
    parser.add_argument("--layout", default=None, help=help)


def add_png_option(parser: argparse.ArgumentParser, help: str) -> None:
    """``--png FILE`` (default None: no figure)."""
    parser.add_argument("--png", metavar="FILE", default=None, help=help)


def add_result_options(parser: argparse.ArgumentParser, *,
                       json_help: str = "print the result as JSON",
                       history: str | None = "pulses") -> None:
    """``--json``, then (``history`` not None: its default ``--record``) ``--history`` and
    ``--record``, then ``--force``."""
    parser.add_argument("--json", action="store_true", help=json_help)
    if history is not None:
        add_history_arguments(parser, default=history)
    add_force_option(parser)


def layout_outputs(args: argparse.Namespace, **inputs: Any) -> Outputs:
    """The command's outputs, with the port's layout (``--layout``) and ``inputs`` (option ->
    path or None; ``weights="x"`` stands for ``--weights``) as inputs never overwritten."""
    named = {f"--{k.replace('_', '-')}": v for k, v in inputs.items()}
    return Outputs({"--layout": known_layout_path(args.port, args.layout), **named},
                   force=args.force)


@contextmanager
def open_board(outs: Outputs, args: argparse.Namespace
               ) -> Iterator[tuple[BoardClient, Info, HistoryCheck]]:
    """After the outputs are declared: the history database and the emulator's state are
    checked, then the board client opened and greeted (its INFO; HELLO if it has none yet);
    yields (client, info, history check) and closes the client on the way out."""
    history = HistoryCheck(outs, args)
    check_emu_state(outs, args.port)
    client = client_from_args(args)
    try:
        yield client, client.info or client.hello(), history
    finally:
        client.close()


@contextmanager
def greeted_board(outs: Outputs, args: argparse.Namespace
                  ) -> Iterator[tuple[BoardClient, Info, Path | None]]:
    """:func:`open_board` yielding this board's history path (checked after HELLO) instead of
    the history check."""
    with open_board(outs, args) as (client, info, history):
        yield client, info, history.after_hello(info)
