"""``snan-hil cells``: test cells (good, stuck high, stuck low, noisy, unresponsive) and show
the classes (:mod:`snan_hil.calibration.screening`).

``cells test`` probes each cell with a bounded number of pulses, restores its conductance,
records the classes in the board's history database, marks the bad ones in the board's layout
(if it has one) and draws the array coloured by class; ``program-weights`` then keeps synapses
off them (spare selection). ``cells show`` draws the last recorded classes without the board.

Examples::

    snan-hil cells test --port emu --all --png cells.png
    snan-hil cells test --port emu --cells 0,0 3,5 12,4 --json
    snan-hil cells show --port emu --png cells.png
"""

from __future__ import annotations

import argparse
import json
import sqlite3
from pathlib import Path

from rich.table import Table

from snan_hil import __version__
from snan_hil.files.atomicio import atomic_write_json
from snan_hil.calibration.board_io import BoardCellIO, BoardLimits, PulseLedger
from snan_hil.calibration.layout import CELL_TEST_MARK, Layout, load_session_layout
from snan_hil.calibration.readchain import ReadChain
from snan_hil.calibration.screening import (BAD_CLASSES, CLASSES, CellClass, ScreenConfig,
                                            screen_cells, summarize)
from snan_hil.common.errors import UserError
from snan_hil.records.history import History, HistoryError
from snan_hil.files.outputs import Outputs
from snan_hil.protocol.board import MEMRICORE, BoardConstants
from snan_hil.protocol.safety import check_max_write_v
from snan_hil.tools.commands._board import (add_layout_option, add_png_option, add_result_options,
                                            plan_from_args)
from snan_hil.tools.commands._history import board_history_path, open_recorder
from snan_hil.tools.commands._options import accept_negative_cells, parse_cell
from snan_hil.tools.commands.map import chain_for
from snan_hil.tools.console import console, progress_display
from snan_hil.tools.output_kinds import CELLS_FORMAT, CELLS_JSON, CELLS_PNG, LAYOUT
from snan_hil.tools.ports import add_board_argument, add_port_arguments
from snan_hil.tools.titles import figure_title

NAME = "cells"
HELP = "test cells (good / stuck high / stuck low / noisy / unresponsive) or show their classes"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="cells_action", metavar="ACTION", required=True)
    test = sub.add_parser("test", help="probe cells with a few pulses and classify them",
                          formatter_class=parser.formatter_class,
                          description="Probe each cell (reads, a SET and a RESET ramp of at "
                                      "most --max-probe-pulses pulses each, then restore its "
                                      "conductance) and classify it.")
    add_port_arguments(test)
    which = test.add_mutually_exclusive_group()
    which.add_argument("--cells", nargs="*", metavar="R,C", default=None,
                       help="the cells to test, e.g. --cells 0,0 3,5 (default: none; give "
                            "--cells or --all)")
    which.add_argument("--all", action="store_true", help="test every cell of the array")
    accept_negative_cells(test)      # --cells -1,0: "outside the array", not argparse's line
    d = ScreenConfig()
    test.add_argument("--reads", type=int, default=d.reads,
                      help=f"reads per cell for its conductance and read noise (default: "
                           f"{d.reads})")
    test.add_argument("--max-probe-pulses", type=int, default=d.max_probe_pulses,
                      help=f"pulses per probe ramp, SET and RESET (default: "
                           f"{d.max_probe_pulses})")
    test.add_argument("--max-restore-pulses", type=int, default=d.max_restore_pulses,
                      help="pulses to write a good cell back to its conductance (default: "
                           f"{d.max_restore_pulses})")
    test.add_argument("--no-restore", action="store_true",
                      help="leave the cells where the probes left them")
    test.add_argument("--noise-limit", type=float, default=d.noise_limit,
                      help="relative read noise above which a cell is noisy (default: "
                           f"{d.noise_limit})")
    test.add_argument("--v-max", type=float, default=d.v_max,
                      help=f"largest probe amplitude, V (default: {d.v_max}; at most the "
                           "board's write limit)")
    add_layout_option(test, "the board's layout: its read chain converts reads and the bad "
                            "cells found are marked in it (default: the port's layout if it "
                            "exists)")
    add_png_option(test, "draw the array coloured by class (default: none)")
    test.add_argument("-o", "--output", metavar="FILE", default=None,
                      help="write the classes as JSON (default: none)")
    add_result_options(test)

    show = sub.add_parser("show", help="the last recorded class of every cell (no board needed)",
                          formatter_class=parser.formatter_class,
                          description="The last class of every tested cell, from the board's "
                                      "history database.")
    add_board_argument(show, "cell classes to show")
    show.add_argument("--history", metavar="FILE", default=None,
                      help="the history database (default: the port's)")
    add_png_option(show, "draw the classes (default: no figure)")
    add_result_options(show, json_help="print the classes as JSON", history=None)


def run(args: argparse.Namespace) -> int:
    if args.cells_action == "show":
        return _show(args)
    return _test(args)


def cells_from_args(args: argparse.Namespace, rows: int, cols: int) -> list[tuple[int, int]]:
    """The cells to test (in the given order, duplicates dropped); UserError for none, a bad
    spelling or a cell outside ``rows`` x ``cols``."""
    if args.all:
        return [(r, c) for r in range(rows) for c in range(cols)]
    if args.cells is None:
        raise UserError("give the cells to test: --cells R,C [R,C ...] or --all")
    if not [t for t in args.cells if t.strip()]:
        raise UserError("--cells: empty cell list; give at least one cell as R,C, or --all")
    cells = [parse_cell(t, "--cells", rows, cols) for t in args.cells if t.strip()]
    return list(dict.fromkeys(cells))


def _config(args: argparse.Namespace) -> ScreenConfig:
    d = ScreenConfig()
    if args.reads < 2:
        raise UserError(f"--reads {args.reads}: give at least 2 (the read noise needs two "
                        "reads)")
    if args.max_probe_pulses < 1:
        raise UserError(f"--max-probe-pulses {args.max_probe_pulses}: give at least 1 pulse "
                        "per probe ramp")
    if args.max_restore_pulses < 2:
        raise UserError(f"--max-restore-pulses {args.max_restore_pulses}: give at least 2")
    if not 0 < args.noise_limit < 1:
        raise UserError(f"--noise-limit {args.noise_limit}: give a relative read noise "
                        "between 0 and 1, e.g. 0.05 for 5 %")
    if not d.v_start <= args.v_max:
        raise UserError(f"--v-max {args.v_max} V is below the first probe amplitude "
                        f"{d.v_start} V; give {d.v_start}..{MEMRICORE.max_write_v} V")
    try:
        return ScreenConfig(reads=args.reads, max_probe_pulses=args.max_probe_pulses,
                            max_restore_pulses=args.max_restore_pulses,
                            restore=not args.no_restore, noise_limit=args.noise_limit,
                            v_max=args.v_max)
    except ValueError as exc:
        raise UserError(f"cells test: {exc}") from None


def _check_v_max(v_max: float, max_write_v: float | None, board: BoardConstants) -> None:
    """UserError unless the probes' largest amplitude fits the host's write limit
    (``--max-write-v``, else the board's) and the board's own (checked before any pulse)."""
    if max_write_v is not None:
        host = check_max_write_v(board, max_write_v)
        if v_max > host + 1e-9:
            raise UserError(f"--v-max {v_max} V is above the host's write limit {host:g} V "
                            "(--max-write-v); lower --v-max or raise --max-write-v")
    if v_max > board.max_write_v + 1e-9:
        raise UserError(f"--v-max {v_max} V is above the board's write limit "
                        f"{board.max_write_v} V")


def _test(args: argparse.Namespace) -> int:
    cells = cells_from_args(args, MEMRICORE.rows, MEMRICORE.cols)
    cfg = _config(args)
    _check_v_max(cfg.v_max, args.max_write_v, MEMRICORE)
    plan = plan_from_args(args)
    known = plan.files.layout if args.layout else None
    outs = plan.outputs
    png = outs.file("--png", args.png, CELLS_PNG) if args.png else None
    out = outs.file("-o", args.output, CELLS_JSON) if args.output else None
    if args.layout and known is not None and not known.is_file():
        raise UserError(f"--layout {args.layout}: no such file")
    with plan.open() as session:
        info, history_path = session.info, session.files.history
        # the board's layout (keyed by its identity), checked before any pulse
        layout_path = session.files.layout
        assert layout_path is not None            # resolved after HELLO
        layout = None
        if layout_path.is_file():
            layout = load_session_layout(session)
            outs.file("--layout", layout_path, LAYOUT, updates=True)
        chain, source = chain_for(args, session)
        cells = cells_from_args(args, info.rows, info.cols)
        _check_v_max(cfg.v_max, args.max_write_v, info)
        board = session.client                    # reads resent after a lost reply
        ledger = PulseLedger()
        ledger.rebaseline(board)
        chain = chain or ReadChain.nominal(info)
        limits = BoardLimits.for_board(info, cfg.v_max)

        def make_io(row: int, col: int) -> BoardCellIO:
            return BoardCellIO(board, chain, row, col, limits, ledger, cfg.width_us)
        with open_recorder(args, history_path, "screen", session,
                           config=cfg.to_dict()) as rec, \
                progress_display(enabled=not args.json) as progress:
            results = screen_cells(make_io, cells, cfg, observer=rec, progress=progress)
            summary = summarize(results)
            rec.finish("complete", summary)
    marked, cleared = _mark_layout(layout, layout_path, results)
    title = figure_title("cell test", info, args.port)
    data = {"format": CELLS_FORMAT, "version": __version__,
            "board": session.identity.to_dict(port=args.port), "session": session.snapshot(),
            "config": cfg.to_dict(), "read_chain": source or "board INFO (nominal)",
            "summary": summary, "layout_marked": marked,
            "layout_cleared": cleared,
            "cells": [r.to_dict() for r in results]}
    if out is not None:
        atomic_write_json(out, data, indent=1, allow_nan=False)
    if png is not None:
        from snan_hil.tools.bench_figures import plot_cell_classes
        plot_cell_classes({(r.row, r.col): r.cls for r in results}, (info.rows, info.cols), png,
                          title=title)
    if args.json:
        print(json.dumps(data, indent=1, allow_nan=False))
        return 0
    _print(results, summary, marked, cleared, layout_path if layout is not None else None)
    for opt, path in (("-o", args.output), ("--png", args.png)):
        if path:
            console.print(f"wrote {opt} {path}", highlight=False)
    return 0


def _mark_layout(layout: Layout | None, path: Path,
                 results: list[CellClass]) -> tuple[list[list[int]], list[list[int]]]:
    """Bring the board's layout up to the classes just found (saved if changed): bad cells
    marked, and the cell-test marks of cells now found good removed (the last class counts);
    returns (newly marked, cleared) cells."""
    if layout is None:
        return [], []
    new, cleared = [], []
    changed = False
    for r in results:
        cell = (r.row, r.col)
        have = layout.bad_cells.get(cell)
        if r.cls in BAD_CLASSES:
            if have is None or (have.startswith(CELL_TEST_MARK)
                                and have != f"{CELL_TEST_MARK}: {r.cls}"):
                layout.mark_bad(r.row, r.col, f"{CELL_TEST_MARK}: {r.cls}")
                changed = True
                if have is None:
                    new.append([r.row, r.col])
        elif r.good and have is not None and have.startswith(CELL_TEST_MARK):
            del layout.bad_cells[cell]
            cleared.append([r.row, r.col])
    if changed or cleared:
        layout.save(path)
    return new, cleared


def _print(results: list[CellClass], summary: dict, marked: list[list[int]],
           cleared: list[list[int]], layout_path: Path | None) -> None:
    bad = [r for r in results if not r.good]
    if bad:
        t = Table(title="cells that are not good")
        for col in ("cell", "class", "G0 uS", "noise", "SET move", "RESET move", "pulses"):
            width = max([len(col)] + [len(r.cls) if col == "class" else 0 for r in bad])
            t.add_column(col, no_wrap=True, min_width=width if col in ("cell", "class")
                         else None)
        t.add_column("note", overflow="fold", ratio=1)
        for r in bad:
            t.add_row(f"({r.row},{r.col})", r.cls, f"{r.g0_s * 1e6:.1f}", f"{r.noise_rel:.1%}",
                      f"{r.moves.get('SET', 0):+.0%}", f"{r.moves.get('RESET', 0):+.0%}",
                      str(r.pulses), r.note)
        console.print(t)
    counts = ", ".join(f"{summary[c]} {c.replace('_', ' ')}" for c in CLASSES)
    console.print(f"{summary['cells']} cells tested: {counts}; {summary['pulses_total']} pulses "
                  f"(at most {summary['max_pulses_per_cell']} on one cell); restored "
                  f"{summary['restored']}, restore failed {summary['restore_failed']}",
                  highlight=False)
    if layout_path is not None:
        console.print(f"layout {layout_path}: {len(marked)} cell(s) newly marked bad, "
                      f"{len(cleared)} cell(s) found good again unmarked", highlight=False)


def _show(args: argparse.Namespace) -> int:
    path = board_history_path(args)
    png = (Outputs({"--history": path}, force=args.force).file("--png", args.png, CELLS_PNG)
           if args.png else None)
    try:
        with History.open(path, create=False) as db:
            latest = db.latest_cell_results("screen")
    except sqlite3.Error as exc:
        raise HistoryError(f"history database {path}: {exc}") from None
    classes = {cell: cls for cell, (cls, _t, _run) in latest.items()}
    if args.json:
        print(json.dumps({"history": str(path), "cells": [
            {"row": r, "col": c, "class": cls, "time_utc": latest[(r, c)][1],
             "run": latest[(r, c)][2]} for (r, c), cls in sorted(classes.items())]}, indent=1))
    else:
        counts = {c: sum(1 for v in classes.values() if v == c) for c in CLASSES}
        console.print(f"{len(classes)} cells with a recorded class in {path}: " +
                      ", ".join(f"{n} {c.replace('_', ' ')}" for c, n in counts.items()),
                      highlight=False)
        bad = sorted(cell for cell, cls in classes.items() if cls != "good")
        if bad:
            console.print("not good: " + ", ".join(f"({r},{c}) {classes[(r, c)]}"
                                                   for r, c in bad), highlight=False)
    if png is not None:
        from snan_hil.tools.bench_figures import plot_cell_classes
        plot_cell_classes(classes, (MEMRICORE.rows, MEMRICORE.cols), png,
                          title=figure_title("cell classes (last test of each cell)", None,
                                             args.port))
        if not args.json:
            console.print(f"wrote --png {args.png}", highlight=False)
    return 0
