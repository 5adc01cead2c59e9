"""``--boards PORT,PORT,...`` / ``--dask tcp://host:8786``: a job over several boards
(:mod:`snan_hil.lab.fanout`; docs/multiboard.md). The options of every command that takes them
(:func:`add_board_options`) and their one check (:func:`board_set`: before a worker starts,
one line for a combination that cannot be); the batch jobs' run on every board's chip
(:func:`every_board`).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import uuid
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from snan_hil.common.errors import BoardLinkError, UserError
from snan_hil.lab.boards import LinkOptions, check_ports
from snan_hil.lab.fanout import BoardSet
from snan_hil.lab.opener import FileUse
from snan_hil.tools import cli
from snan_hil.tools.console import err_console

__all__ = ["add_board_options", "board_set", "print_boards", "add_every_board_options",
           "every_board", "board_argv", "board_output", "command_unit"]

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
    ``plan repeat``): the same job on every board's own chip, one unit per board."""
    parser.add_argument("--boards", default=None, metavar="PORT,PORT,...",
                        help="run the same job on each of these boards' own chips, one worker "
                             "process per board; each board's outputs get '.board-<i>' before "
                             "their suffix (docs/multiboard.md; default: the one board of "
                             "--port)")
    parser.add_argument("--dask", default=None, metavar="ADDRESS",
                        help="run the same job on the chip of every board the workers of this "
                             "Dask scheduler hold (tcp://host:8786; default: no scheduler)")


def board_output(path: str, board: int) -> str:
    """``good.csv`` -> ``good.board-<i>.csv`` (a board's own copy of an output file)."""
    p = Path(path)
    return str(p.with_name(f"{p.stem}.board-{board}{p.suffix}"))


def board_argv(argv: list[str], port: str, board: int, outputs: tuple[str, ...]) -> list[str]:
    """The job's command line for one board: ``--boards``/``--dask`` left out, ``--port PORT``
    added, each output file of ``outputs`` (options taking a file) made the board's own."""
    out: list[str] = []
    it = iter(argv)
    for a in it:
        name, eq, value = a.partition("=")
        if name in ("--boards", "--dask"):
            if not eq:
                next(it, None)
            continue
        if name in outputs:
            value = value if eq else next(it, "")
            out += [name, board_output(value, board)]
            continue
        out.append(a)
    return [*out, "--port", port]


def command_unit(argv: list[str], outputs: tuple[str, ...]) -> dict[str, Any]:
    """The task of one board's share of a batch job (on the worker holding it): the command
    line run with the worker's port (:func:`board_argv`), its exit code and what it
    printed."""
    from snan_hil.lab.boards import _plugin         # distributed: only with --boards/--dask
    plugin = _plugin()
    if plugin.port is None or plugin.index is None:
        raise RuntimeError(plugin.error or "this worker holds no board")
    line = board_argv(argv, plugin.port, plugin.index, outputs)
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        code = cli.main(line)
    return {"board": plugin.index, "port": plugin.port, "worker": plugin.worker_address,
            "argv": line, "exit": int(code),
            "stdout": stdout.getvalue(), "stderr": stderr.getvalue()}


def every_board(args: argparse.Namespace, *, outputs: tuple[str, ...] = (),
                use: FileUse | None = None) -> int | None:
    """With ``--boards``/``--dask``: the job of ``args`` run on every board's own chip, one
    unit per board (each board's history records its own run, each its own output files);
    prints each board's output under a header naming the board; the exit code (0, or the
    first board's that failed; a user mistake: its one line, 2). None without them (one
    board: the caller carries on)."""
    boards = board_set(args, use=use or FileUse(record=True), probe=False, refusals=[
        (getattr(args, "dry_run", False), "--dry-run opens no board; leave --boards/--dask "
                                          "out")])
    if boards is None:
        return None
    from snan_hil.lab.boards import (BoardPlugin, connect_scheduler, install_boards,
                                     local_boards)
    ports = list(boards.ports) if boards.ports is not None else None
    argv = list(getattr(args, "_argv", []))
    plugin = BoardPlugin(boards.use, boards.link, force=args.force,
                         cwd=os.getcwd() if ports is not None else None, probe=False)
    from distributed import wait                # the dask extra

    cluster = local_boards(ports) if ports is not None else \
        connect_scheduler(str(boards.dask))
    with cluster as client:
        found = install_boards(client, plugin, expect=len(ports) if ports is not None else None)
        futures = [client.submit(command_unit, argv, outputs, pure=False,
                                 resources={f"board-{b['board']}": 1},
                                 key=f"snan-hil-job-board-{b['board']}-{uuid.uuid4().hex[:8]}")
                   for b in found]
        wait(futures)
        for b, fut in zip(found, futures):
            if fut.status != "finished":    # a worker killed, a port gone: the board's job
                from snan_hil.lab.boards import _reason
                raise BoardLinkError(f"board {b['board']} ({b['port']}) was lost: "
                                     f"{_reason(fut)}; the other boards' jobs finished; run it "
                                     "again on that board (its history holds what was done)")
        done = [f.result() for f in futures]
    mistakes = [d for d in done if d["exit"] == 2]
    if mistakes:                        # one line: the first board's, its own prefix left out
        first = mistakes[0]
        text = (first["stderr"].strip().splitlines() or ["exit 2"])[-1]
        raise UserError(f"board {first['board']} ({first['port']}): "
                        + text.split(": error: ", 1)[-1])
    code = 0
    for d in done:
        err_console.print(f"board {d['board']} ({d['port']}, worker {d['worker']}): exit "
                          f"{d['exit']}", highlight=False, soft_wrap=True, markup=False)
        if d["stdout"]:
            print(d["stdout"], end="" if d["stdout"].endswith("\n") else "\n", flush=True)
        if d["stderr"]:
            err_console.print(d["stderr"].rstrip(), highlight=False, soft_wrap=True,
                              markup=False)
        code = code or d["exit"]
    return code
