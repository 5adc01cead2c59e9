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
import json
import sys
from collections.abc import Iterator

from snan_hil.calibration.console import ConsoleJob, ConsoleReply
from snan_hil.files.userdata import user_data_dir
from snan_hil.lab.runner import run_job
from snan_hil.protocol.messages import Info
from snan_hil.tools.commands._board import add_layout_option, add_result_options, plan_from_args
from snan_hil.tools.commands._job import run_options
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
    interactive = sys.stdin.isatty()

    def lines(info: Info) -> Iterator[str]:
        """The typed lines: from the terminal with a prompt (line editing, a history), or
        from a pipe / file."""
        if interactive and not args.json:
            console.print(f"board {info.board_id or '-'} on {args.port} ({args.protocol}); "
                          "type help, quit to leave (arrow keys edit and recall lines)",
                          highlight=False)
        while True:
            try:
                yield input("snan-hil> " if interactive else "")
            except EOFError:
                return

    def show(reply: ConsoleReply) -> None:
        if args.json:
            print(json.dumps({"command": reply.command, "ok": reply.ok, "reply": reply.text,
                              "request": reply.request, "adc": reply.adc,
                              "g_s": reply.g_s}), flush=True)
        else:
            console.print(reply.text, highlight=False, markup=False)
    # no progress display: it would redraw the terminal under the prompt
    with _line_editing(interactive):
        tally = run_job(ConsoleJob(lines, show, protocol=args.protocol), plan_from_args(args),
                        run_options(args)).result
    refused = tally["commands"] - tally["ok"]
    if refused and not interactive:
        # a script fed from a pipe: its caller learns that lines were refused or failed
        print(f"snan-hil console: {refused} of {tally['commands']} commands refused or "
              "failed", file=sys.stderr)
        return 1
    return 0


@contextlib.contextmanager
def _line_editing(interactive: bool) -> Iterator[None]:
    """On a terminal: GNU readline's line editing and a history of the typed lines, kept in
    the user's data folder (``console-history``, 1000 lines) between sessions."""
    if not interactive:
        yield
        return
    try:
        import readline                 # not in every Python build: plain input() without
    except ImportError:
        yield
        return
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
