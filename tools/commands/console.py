"""``snan-hil console``: a raw command console on a board, either protocol: typed commands (or
the existing firmware's request lines), replies decoded, the host's safety policy on every
request, every command recorded in the board's history (kind ``console``: one ``console``
event per line, pulses in the pulses table) (:mod:`snan_hil.calibration.console`).

Reads lines from the terminal (with a prompt) or from a pipe / file::

    snan-hil console --port emu
    printf 'read 3,5\\npulse set 3,5 0.8\\n9,246,1,5,3\\n' | snan-hil console --port emu --json
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import sys
from collections.abc import Iterator

from snan_hil.calibration.board_io import BoardLimits, PulseLedger
from snan_hil.calibration.console import BoardConsole, ConsoleReply, run_lines
from snan_hil.calibration.readchain import ReadChain
from snan_hil.calibration.observer import CellEvent
from snan_hil.tools.commands._board import add_layout_option, add_result_options, board_session
from snan_hil.tools.commands._board import chain_for, layout_outputs
from snan_hil.tools.commands._history import open_recorder
from snan_hil.tools.commands._run import controlled
from snan_hil.tools.commands.pulse import host_write_limit
from snan_hil.tools.console import console
from snan_hil.tools.ports import add_port_arguments

NAME = "console"
HELP = ("raw command console on the board (read, pulse, column, info, status, clock, or legacy "
        "request lines): replies decoded, host limits enforced, every command recorded")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_port_arguments(parser)
    add_layout_option(parser, "convert reads with this layout's calibrated read chain "
                              "(default: the port's layout if it exists)")
    add_result_options(parser, json_help="print one JSON object per command (JSON Lines)")


def run(args: argparse.Namespace) -> int:
    outs = layout_outputs(args)
    interactive = sys.stdin.isatty()
    with board_session(outs, args) as session:
        client, info, history_path = session.client, session.info, session.files.history
        chain, _source = chain_for(args, session)
        chain = chain or ReadChain.nominal(info)
        limits = dataclasses.replace(BoardLimits.for_board(info),
                                     max_write_v=host_write_limit(args, info))
        with open_recorder(args, history_path, "console", info,
                           config={"protocol": args.protocol}) as rec:
            board = controlled(client, rec)   # reads resent by the session's client
            con = BoardConsole(board, chain, limits, PulseLedger())
            if interactive and not args.json:
                console.print(f"board {info.board_id or '-'} on {args.port} ({args.protocol}); "
                              "type help, quit to leave (arrow keys edit and recall lines)",
                              highlight=False)

            def show(reply: ConsoleReply) -> None:
                rec.publisher.event("console", {"command": reply.command,
                                                "request": reply.request, "reply": reply.text,
                                                "ok": reply.ok, "adc": reply.adc,
                                                "g_s": reply.g_s})
                if reply.pulse is not None:
                    rec.on_pulses([reply.pulse])
                    rec.on_cell(CellEvent(reply.pulse.row, reply.pulse.col, "console pulse",
                                          reply.g_s, pulses=1))
                if args.json:
                    print(json.dumps({"command": reply.command, "ok": reply.ok,
                                      "reply": reply.text, "request": reply.request,
                                      "adc": reply.adc, "g_s": reply.g_s}), flush=True)
                else:
                    console.print(reply.text, highlight=False, markup=False)

            with _line_editing(interactive):
                tally = run_lines(con, _lines(interactive), show)
            rec.finish("complete", {"commands": tally.commands, "ok": tally.ok})
    if tally.refused and not interactive:
        # a script fed from a pipe: its caller learns that lines were refused or failed
        print(f"snan-hil console: {tally.refused} of {tally.commands} commands refused or "
              "failed", file=sys.stderr)
        return 1
    return 0


def _lines(interactive: bool) -> Iterator[str]:
    """Typed lines until end of input: with a prompt (and line editing) on a terminal."""
    while True:
        try:
            yield input("snan-hil> " if interactive else "")
        except EOFError:
            return


@contextlib.contextmanager
def _line_editing(interactive: bool) -> Iterator[None]:
    """On a terminal: GNU readline's line editing and a history of the typed lines, kept in
    the user's data folder (``console-history``, 1000 lines) between sessions."""
    if not interactive:
        yield
        return
    try:
        import readline
    except ImportError:                 # a Python built without it: plain input()
        yield
        return
    from snan_hil.files.userdata import user_data_dir
    path = user_data_dir() / "console-history"
    try:
        readline.read_history_file(path)
    except OSError:
        pass
    readline.set_history_length(1000)
    try:
        yield
    finally:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            readline.write_history_file(path)
        except OSError:
            pass
