"""``--boards PORT,PORT,...`` / ``--dask tcp://host:8786``: a job over several boards
(:mod:`snan_hil.lab.fanout`; docs/multiboard.md). The options of every command that takes them
(:func:`add_board_options`) and their one check (:func:`board_set`: before a worker starts,
one line for a combination that cannot be); the batch jobs (``cells test``, ``plan run``,
``plan repeat``) replicated on every board's chip through the same loop (:func:`every_board`):
the command writes and prints each board's outputs here from that board's result.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from snan_hil.calibration.job import BoardJob
from snan_hil.common.errors import UserError
from snan_hil.lab.boards import LinkOptions, RunLink, check_ports
from snan_hil.lab.fanout import BoardResult, BoardSet, run_on_boards
from snan_hil.lab.opener import FileUse
from snan_hil.tools.commands._job import run_options
from snan_hil.tools.console import console, err_console

__all__ = ["add_board_options", "board_set", "print_boards", "add_every_board_options",
           "every_board_set", "every_board", "board_output", "board_outputs", "board_header"]

HELP = {
    "sets": ("run the sets over several boards on this machine, one worker process per board "
             "(the sets balanced over the boards by their predicted board time); e.g. "
             "'emu://?state=a.npz,emu://?state=b.npz' (docs/multiboard.md; default: the one "
             "board of --port)",
             "run the sets over the boards held by the workers of this Dask scheduler "
             "(tcp://host:8786; one worker per board, started with SNAN_HIL_BOARD=PORT and "
             "--resources board=1,board-<i>=1; default: no scheduler, the boards of --boards "
             "or --port)",
             "with --boards/--dask: move the sets of a board lost mid-run to the other boards "
             "(programmed there first); without it the run stops once the other boards are "
             "done (continue with --resume)"),
    "sessions": ("run the chip arm's sessions over several boards on this machine, one worker "
                 "process per board (session k on board k mod B, each on its own chip); needs "
                 "--model (docs/multiboard.md; default: the one board of --port)",
                 "run the chip arm's sessions over the boards held by the workers of this Dask "
                 "scheduler (tcp://host:8786; default: no scheduler)",
                 "with --boards/--dask: move the unfinished sessions of a board lost mid-run to "
                 "a board still held, where each goes on from its last committed cycle after "
                 "that chip is reprogrammed to the session's weights (the lost board's pulses "
                 "stay counted on it); without it the run stops once the other boards are done "
                 "(continue with --resume)"),
}
"""The options' help by what the boards share out (a comparison's sets, learn's sessions)."""


def add_board_options(parser: argparse.ArgumentParser, what: str = "sets") -> None:
    """``--boards``, ``--dask``, ``--reassign`` of a job whose ``what`` (``sets``,
    ``sessions``) are shared out over the boards."""
    boards, dask, reassign = HELP[what]
    parser.add_argument("--boards", default=None, metavar="PORT,PORT,...", help=boards)
    parser.add_argument("--dask", default=None, metavar="ADDRESS", help=dask)
    parser.add_argument("--reassign", action="store_true", help=reassign)


def board_set(args: argparse.Namespace, *, use: FileUse, what: str = "sets",
              refusals: Sequence[tuple[bool, str]] = (), probe: bool = True,
              reassign_note: str = "") -> BoardSet | None:
    """The boards of ``--boards``/``--dask``, checked before any work (the one check of every
    command that takes them): None without them; UserError (one line) for both, ``--port``
    or ``--layout`` with them, the first of ``refusals`` (condition, line) that holds, a bad
    port (:func:`~snan_hil.lab.boards.check_ports`), ``--reassign`` without them."""
    boards, dask = getattr(args, "boards", None), getattr(args, "dask", None)
    if boards is None and dask is None:
        if getattr(args, "reassign", False):
            raise UserError(f"--reassign moves {what} between boards; give --boards or "
                            f"--dask{reassign_note}")
        return None
    if boards is not None and dask is not None:
        raise UserError("give --boards (workers on this machine) or --dask (a scheduler's "
                        "workers), not both")
    for bad, line in refusals:
        if bad:
            raise UserError(line)
    if args.port is not None:
        raise UserError("--port names one board; with --boards/--dask each worker holds its "
                        "own (leave --port out)")
    if getattr(args, "layout", None) is not None:
        raise UserError("--layout names one board's layout; with --boards/--dask each board "
                        "uses its own (leave --layout out)")
    link = LinkOptions(protocol=args.protocol, baud=args.baud, timeout=args.timeout,
                       mcu=getattr(args, "mcu", None),
                       max_write_v=getattr(args, "max_write_v", None))
    ports = check_ports(boards.split(","), link) if boards is not None else None
    return BoardSet(tuple(ports) if ports is not None else None, dask, link, use,
                    force=bool(getattr(args, "force", False)),
                    reassign=bool(getattr(args, "reassign", False)), probe=probe)


def print_boards(found: list[dict[str, Any]]) -> None:
    """The boards that answered, one line."""
    err_console.print(f"{len(found)} boards: " + ", ".join(
        f"{b['board']}={b['port']}" for b in found), highlight=False, soft_wrap=True)


# -- the lab-bench batch jobs: the same job on every board's chip ----------------------------

def add_every_board_options(parser: argparse.ArgumentParser) -> None:
    """``--boards`` / ``--dask`` of a lab-bench batch job (``cells test``, ``plan run``,
    ``plan repeat``): the same job on every board's own chip, a result per board."""
    parser.add_argument("--boards", default=None, metavar="PORT,PORT,...",
                        help="run the same job on each of these boards' own chips, one worker "
                             "process per board; each board's outputs get '.board-<i>' before "
                             "their suffix (docs/multiboard.md; default: the one board of "
                             "--port)")
    parser.add_argument("--dask", default=None, metavar="ADDRESS",
                        help="run the same job on the chip of every board the workers of this "
                             "Dask scheduler hold (tcp://host:8786; default: no scheduler)")


def board_outputs(args: argparse.Namespace, outs: Any, files: Sequence[tuple[str, str, Any]]
                  ) -> tuple[dict[int, dict[str, Path]], Callable[[list[dict[str, Any]]], None]]:
    """Each board's own output files of a replicated job: (board -> {option: path}, filled
    by the callback :func:`every_board` calls once the boards answered, before any pulse).
    ``files``: (option, args attribute, file kind) of the command's outputs; each given one
    is checked by ``outs`` (an :class:`~snan_hil.files.outputs.Outputs`) as ``.board-<i>``."""
    paths: dict[int, dict[str, Path]] = {}

    def check(found: list[dict[str, Any]]) -> None:
        for b in found:
            i = int(b["board"])
            paths[i] = {opt: outs.file(opt, board_output(getattr(args, name), i), kind)
                        for opt, name, kind in files if getattr(args, name)}
    return paths, check


def print_written(args: argparse.Namespace, files: Sequence[tuple[str, str, Any]],
                  paths: dict[str, Path], board: int | None) -> None:
    """Say each output file written (``files``: (option, args attribute, kind); ``paths``:
    the options written), as the user gave it or, for one board of several, its
    :func:`board_output` name."""
    for opt, name, _kind in files:
        if opt in paths:
            given = getattr(args, name)
            if board is not None:
                given = board_output(given, board)
            console.print(f"wrote {opt} {given}", highlight=False)


def board_output(path: str, board: int) -> str:
    """``good.csv`` -> ``good.board-<i>.csv`` (a board's own copy of an output file)."""
    p = Path(path)
    return str(p.with_name(f"{p.stem}.board-{board}{p.suffix}"))


def every_board_set(args: argparse.Namespace, use: FileUse) -> BoardSet | None:
    """The boards of a lab-bench batch job's ``--boards``/``--dask`` (:func:`board_set`:
    ``--dry-run`` refused with them; no probe: each board is opened once, by its job, as on
    one board), None without them."""
    return board_set(args, use=use, probe=False, refusals=[
        (getattr(args, "dry_run", False), "--dry-run opens no board; leave --boards/--dask "
                                          "out")])


def every_board(args: argparse.Namespace, job: BoardJob[Any, Any], boards: BoardSet, *,
                before: Callable[[list[dict[str, Any]]], None] | None = None
                ) -> list[BoardResult]:
    """``job`` replicated on every board's own chip (:func:`snan_hil.lab.fanout.run_on_boards`:
    the one scheduling loop; each board's history records its own run with the options'
    metadata); ``before(boards)``: told once the boards answered, before anything runs (the
    command checks each board's own output files there). Each board's result (its records,
    port, identity, session snapshot, run block), by board number. UserError (one line, the
    board named) for a user mistake on a board; BoardLinkError for a board lost."""
    options = run_options(args)
    m = options.metadata
    assert m is not None
    link = RunLink(metadata={"sample": m.sample, "operator": m.operator, "note": m.note,
                             "tags": tuple(m.tags)})

    def answered(found: list[dict[str, Any]]) -> None:
        if before is not None:
            before(found)
    done = run_on_boards(job, boards, options, link=link, on_boards=answered)
    return done.per_board


def board_header(r: BoardResult) -> None:
    """The line naming the board whose output follows."""
    err_console.print(f"board {r.board} ({r.port}, worker {r.unit.get('worker')})",
                      highlight=False, soft_wrap=True, markup=False)
