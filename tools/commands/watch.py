"""``snan-hil watch``: the live view of a run in the terminal (also over SSH) -- the
conductance heat map as cells are programmed or pulsed, each task's progress, the pulse log,
and for hardware runs the 6 x 6 grid with the agent's path and calcium per cell and the
running medians per scenario (:mod:`snan_hil.tools.watch_app`). ``p`` pauses / resumes the job,
``s`` stops it before its next pulse, ``q`` leaves the view.

It follows the run through the board's history database (WAL mode: the view never blocks the
job), so it works from another terminal while the job runs, and replays a finished run.

Examples::

    snan-hil watch --port emu                  # the running run (else the newest one)
    snan-hil watch --port emu --run 12         # a run by id or uid; a finished one is replayed
    snan-hil watch --port emu --run 12 --screenshot run12.svg   # headless: an SVG of the view
"""

from __future__ import annotations

import argparse
import sqlite3
import sys
from pathlib import Path

from snan_hil.common.errors import UserError
from snan_hil.files.atomicio import atomic_write_text
from snan_hil.files.outputs import OutputKind, Outputs
from snan_hil.tools.commands._history import board_history_path
from snan_hil.tools.ports import add_board_argument
from snan_hil.tools.watch_state import HistorySource, ReplaySource

NAME = "watch"
HELP = ("live view of a running job (or replay of a finished one): heat map, progress, pulse "
        "log, the agent's grid; pause and stop the job")

SVG_MARK = "<metadata>snan-hil-watch-screenshot/1</metadata>"
"""Written right after the ``<svg ...>`` tag of every screenshot: the signature that makes an
existing SVG ours (any other SVG is replaced only with --force)."""


def _owns_svg(path: Path) -> bool:
    try:
        with open(path, "rb") as fh:
            head = fh.read(4096)
    except OSError:
        return False
    return head.lstrip().startswith(b"<svg") and SVG_MARK.encode() in head


SVG = OutputKind("a 'snan-hil watch' screenshot", _owns_svg, ".svg")


def _signed(svg: str) -> str:
    """``svg`` with :data:`SVG_MARK` after its opening tag."""
    start = svg.find("<svg")
    end = svg.find(">", start)
    if start < 0 or end < 0:
        return svg
    return svg[:end + 1] + "\n    " + SVG_MARK + svg[end + 1:]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_board_argument(parser, "history holds the run")
    parser.add_argument("--history", metavar="FILE", default=None,
                        help="the history database (default: the port's)")
    parser.add_argument("--run", metavar="ID", default=None,
                        help="the run: id or uid as 'snan-hil history' lists them (default: "
                             "the running one, else the newest)")
    parser.add_argument("--replay-rate", type=int, default=0, metavar="N",
                        help="replay a finished run N documents per 0.25 s (default 0: show "
                             "its final state at once)")
    parser.add_argument("--screenshot", metavar="FILE.svg", default=None,
                        help="no terminal: draw the view of the run's documents so far once, "
                             "write it as SVG and exit (default: the interactive view)")
    parser.add_argument("--size", default="130x44", metavar="COLSxROWS",
                        help="with --screenshot: the terminal size drawn")
    parser.add_argument("--force", action="store_true",
                        help="replace an existing file of another kind")


def _size(text: str) -> tuple[int, int]:
    try:
        cols, rows = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise UserError(f"--size {text!r}: give COLSxROWS, e.g. 130x44") from None
    if not (60 <= cols <= 400 and 20 <= rows <= 200):
        raise UserError(f"--size {text}: give 60..400 columns and 20..200 rows")
    return cols, rows


def run(args: argparse.Namespace) -> int:
    from snan_hil.tools.watch_app import WatchApp   # textual (~0.15 s): only for the live view
    if not args.screenshot and not (sys.stdin.isatty() and sys.stdout.isatty()):
        raise UserError("watch draws in a terminal, and this one has none (a pipe or no tty); "
                        "give --screenshot FILE.svg for a picture of the run")
    if args.replay_rate < 0:
        raise UserError(f"--replay-rate {args.replay_rate}: give 0 (at once) or more")
    path = board_history_path(args)
    shot = None
    size = _size(args.size)
    if args.screenshot:
        shot = Outputs({"--history": path}, force=args.force).file("--screenshot",
                                                                   args.screenshot, SVG)
    try:
        followed = HistorySource(path, args.run)
    except sqlite3.DatabaseError as exc:
        raise UserError(f"--history {path}: cannot be read ({exc}); the database is damaged: "
                        "use a backup copy") from None
    source: HistorySource | ReplaySource = followed
    try:
        if followed.run.status != "running" and (args.replay_rate or shot is not None):
            docs = followed.poll()
            followed.close()
            source = ReplaySource(docs, 0 if shot is not None else args.replay_rate)
        app = WatchApp(source)
        if shot is not None:
            import asyncio       # only for a screenshot (start-up cost of every command)
            asyncio.run(_screenshot(app, str(shot), size))
            print(f"wrote --screenshot {shot}")
            return 0
        app.run()
    finally:
        source.close()
    return 0


async def _screenshot(app: object, path: str, size: tuple[int, int]) -> None:
    async with app.run_test(size=size) as pilot:        # type: ignore[attr-defined]
        await pilot.pause()
        app.refresh_view()                               # type: ignore[attr-defined]
        await pilot.pause()
        svg = app.export_screenshot()                    # type: ignore[attr-defined]
    atomic_write_text(path, _signed(svg))
