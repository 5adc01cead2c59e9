"""What the board commands (map, pulse, cells, mac, retention, read-weights, ...) share.

* Options: ``--layout``, ``--png FILE``, and the tail ``--json`` / ``--history`` /
  ``--record`` / ``--force`` (help texts stay each command's own).
* Opening the board: every command goes through the opener (:mod:`snan_hil.lab.opener`), in
  its one safe order — outputs checked first (:class:`Outputs`, with the board's layout as an
  input never overwritten), then the history database, the emulator's state, and only then
  the client and HELLO; the files that depend on the board's identity right after HELLO.
  :func:`plan_from_args` is the opener's plan of the board the options name (:func:`file_use`:
  the board files and what the job does with them); :func:`layout_outputs` its
  :class:`Outputs`, on which a command declares its own; :func:`board_session` opens the
  board and yields the :class:`~snan_hil.board.session.BoardSession`.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from snan_hil.board.session import BoardSession
from snan_hil.files.outputs import Outputs
from snan_hil.lab.opener import BoardPlan, FileUse, plan_board
from snan_hil.tools.commands._history import add_history_arguments, recording
from snan_hil.tools.output_kinds import add_force_option
from snan_hil.tools.ports import address_from_args, board_options

__all__ = ["add_layout_option", "add_png_option", "add_result_options", "layout_outputs",
           "board_session", "file_use", "plan_from_args"]


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


def file_use(args: argparse.Namespace, **job: Any) -> FileUse:
    """The board files the options name (``--layout``, ``--report``, ``--history``,
    ``--record``) and what the job does with them (``job``: ``updates_layout``,
    ``writes_report``, or ``record=False`` for a job that records nothing)."""
    fields: dict[str, Any] = {"layout": getattr(args, "layout", None),
                              "report": getattr(args, "report", None),
                              "history": getattr(args, "history", None),
                              "record": recording(args)}
    fields.update(job)
    return FileUse(**fields)


def plan_from_args(args: argparse.Namespace, *, use: FileUse | None = None,
                   outputs: Outputs | None = None, named: dict[str, Any] | None = None,
                   **inputs: Any) -> BoardPlan:
    """The opener's plan of the board the options name (step 1: options, the board's known
    files, the layout as an input, the files the job rewrites checked); ``inputs`` (option ->
    path or None; ``weights="x"`` stands for ``--weights``) and ``named`` (name -> path, as
    given) are inputs never overwritten."""
    named = {**(named or {}), **{f"--{k.replace('_', '-')}": v for k, v in inputs.items()}}
    return plan_board(address_from_args(args), use if use is not None else file_use(args),
                      inputs=named, outputs=outputs, force=getattr(args, "force", False),
                      options=board_options(args))


def layout_outputs(args: argparse.Namespace, **inputs: Any) -> Outputs:
    """The command's outputs, with the board's layout (``--layout``, or the in-process
    emulator's) and ``inputs`` (option -> path or None; ``weights="x"`` stands for
    ``--weights``) as inputs never overwritten; pass them to :func:`board_session` /
    :func:`open_board`."""
    return plan_from_args(args, **inputs).outputs


@contextmanager
def board_session(outs: Outputs, args: argparse.Namespace, *, use: FileUse | None = None
                  ) -> Iterator[BoardSession]:
    """After the command's own outputs are declared on ``outs``: the board opened through
    the opener (history database, emulator state, client, HELLO, the identity's files), its
    session yielded and closed on the way out."""
    with plan_from_args(args, use=use, outputs=outs).open() as session:
        yield session
