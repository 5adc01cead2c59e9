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
* The board's layout once it is open: :func:`chain_for` (the read chain of ``--layout`` or of
  the board's layout file, None without one) and :func:`session_layout` (the layout file, the
  layout if there is one, and the read chain with the board's nominal one as the fallback):
  what ``pulse``, ``characterize``, ``plan``, ``cells test`` and ``read-cell`` start with.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, NamedTuple

from snan_hil.board.session import BoardSession
from snan_hil.calibration.layout import Layout, load_session_layout
from snan_hil.calibration.readchain import ReadChain
from snan_hil.files.outputs import Outputs
from snan_hil.lab.opener import BoardPlan, FileUse, plan_board
from snan_hil.tools.commands._history import add_history_arguments, recording
from snan_hil.tools.output_kinds import add_force_option
from snan_hil.tools.ports import address_from_args, board_options

__all__ = ["add_layout_option", "add_png_option", "add_result_options", "layout_outputs",
           "board_session", "file_use", "plan_from_args", "chain_for", "SessionLayout",
           "session_layout", "NOMINAL_SOURCE"]

NOMINAL_SOURCE = "board INFO (nominal)"
"""Where the read chain came from when the board has no layout: its INFO constants."""


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


CELL_LIST_INPUTS = ("--cells-file", "--cells-only", "--cells-avoid")
"""The options that name a cell-list file a command reads (tools/commands/_cells.py)."""


def plan_from_args(args: argparse.Namespace, *, use: FileUse | None = None,
                   outputs: Outputs | None = None, named: dict[str, Any] | None = None,
                   **inputs: Any) -> BoardPlan:
    """The opener's plan of the board the options name (step 1: options, the board's known
    files, the layout as an input, the files the job rewrites checked); ``inputs`` (option ->
    path or None; ``weights="x"`` stands for ``--weights``) and ``named`` (name -> path, as
    given) are inputs never overwritten."""
    named = {**(named or {}), **{f"--{k.replace('_', '-')}": v for k, v in inputs.items()}}
    for opt in CELL_LIST_INPUTS:              # a cell list read is never an output too
        path = getattr(args, opt.lstrip("-").replace("-", "_"), None)
        if isinstance(path, str) and path:
            named.setdefault(opt, path)
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


def _layout_chain(layout: Layout, path: Path) -> tuple[ReadChain | None, str]:
    chain = layout.read_chain
    if chain is None:
        return None, f"board INFO (nominal; {path} holds no read-chain calibration)"
    kind = "calibrated" if chain.calibrated else "nominal"
    return chain, f"{kind} read chain of {path}"


def _board_layout(args: argparse.Namespace, session: BoardSession) -> Layout | None:
    """``--layout`` or the board's layout file (checked to be this board's: LayoutError, one
    line); None when no ``--layout`` is given and the board has no layout file."""
    path = session.files.layout
    if path is None or (not getattr(args, "layout", None) and not path.is_file()):
        return None
    return load_session_layout(session)


def chain_for(args: argparse.Namespace, session: BoardSession
              ) -> tuple[ReadChain | None, str | None]:
    """The read chain of ``--layout`` (or of the board's layout, if it exists) and where it
    came from; chain None when there is none (then the board's nominal chain is used). A
    layout of another board or chip is refused (LayoutError)."""
    layout = _board_layout(args, session)
    if layout is None:
        return None, None
    assert session.files.layout is not None                  # _board_layout found it
    return _layout_chain(layout, session.files.layout)


class SessionLayout(NamedTuple):
    """The board's layout as an open session sees it: ``path`` the board's layout file
    (resolved after HELLO; it may not exist), ``layout`` (None without one), ``chain`` the
    read chain reads are converted with (the layout's calibrated or nominal one, else the
    board's nominal one from INFO) and ``source`` where it came from (for the report); a
    tuple, so ``path, layout, chain, source = session_layout(args, session)``."""

    path: Path
    layout: Layout | None
    chain: ReadChain
    source: str


def session_layout(args: argparse.Namespace, session: BoardSession) -> SessionLayout:
    """The board's layout (``--layout``, or the board's file if it exists; one of another
    board or chip refused: LayoutError) and the read chain to use (:class:`SessionLayout`)."""
    path = session.files.layout
    assert path is not None                                   # resolved after HELLO
    layout = _board_layout(args, session)
    chain, source = _layout_chain(layout, path) if layout is not None else (None, None)
    if chain is None:
        chain, source = ReadChain.nominal(session.info), source or NOMINAL_SOURCE
    assert source is not None
    return SessionLayout(path, layout, chain, source)
