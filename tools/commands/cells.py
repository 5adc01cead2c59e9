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
import csv
import json
import math
import sqlite3
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rich.table import Table

from snan_hil.common.version import __version__
from snan_hil.files.atomicio import atomic_write_json
from snan_hil.calibration.screening import (CLASSES, CellClass, ScreenConfig, ScreenJob,
                                            ScreenRun, UserCriteria)
from snan_hil.lab.fanout import BoardSet
from snan_hil.files.atomicio import atomic_path
from snan_hil.files.outputs import csv_kind, png_kind
from snan_hil.tools.bench_figures import CRITERIA_PNG_FORMAT, plot_cell_classes, plot_criteria
from snan_hil.tools.commands._cells import add_cell_selection, cells_from_selection
from snan_hil.tools.commands._options import add_renamed_option
from snan_hil.common.errors import UserError
from snan_hil.records.history import History, HistoryError
from snan_hil.files.outputs import Outputs
from snan_hil.protocol.board import MEMRICORE, BoardConstants
from snan_hil.protocol.safety import requested_write_limit_v
from snan_hil.tools.commands._board import (add_layout_option, add_png_option, add_result_options,
                                            file_use, plan_from_args)
from snan_hil.tools.commands._history import board_history_path
from snan_hil.tools.commands._job import run_on_board
from snan_hil.tools.console import console
from snan_hil.tools.output_kinds import CELLS_FORMAT, CELLS_JSON, CELLS_PNG
from snan_hil.tools.commands._boards import (add_every_board_options, board_header,
                                             board_outputs, every_board, every_board_set,
                                             print_written)
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
    add_every_board_options(test)                  # the same test on every board's chip
    add_cell_selection(test, "the cells to test")
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
    test.add_argument("--v-max", type=float, default=None,
                      help=f"largest probe amplitude, V (default: {d.v_max}, or the host's "
                           "--max-write-v when lower; at most the board's write limit)")
    dc = UserCriteria()
    crit = test.add_argument_group(
        "user criteria (on top of the classes: the switching window of every responsive cell "
        f"is measured with full ramps, SET then RESET from {dc.ramp_start_v} V up to the ramp's "
        "top and held there until G settles: R_min, R_max; verdict good = class good and every "
        "criterion met)")
    crit.add_argument("--rmin-below", metavar="OHM", type=float, default=None,
                      help="pass only if R_min (after the full SET ramp) is below this")
    crit.add_argument("--rmax-above", metavar="OHM", type=float, default=None,
                      help="pass only if R_max (after the full RESET ramp) is above this")
    crit.add_argument("--ratio-above", metavar="K", type=float, default=None,
                      help="pass only if the window's ON/OFF ratio R_max/R_min is above this "
                           "(e.g. 2)")
    crit.add_argument("--ramp-set-v", type=float, default=None,
                      help=f"top of the SET ramp, V (default: {dc.set_v}; with criteria only)")
    crit.add_argument("--ramp-reset-v", type=float, default=None,
                      help=f"top of the RESET ramp, V (default: {dc.reset_v}; with criteria "
                           "only)")
    add_renamed_option(test, "--pair-set-v", "--ramp-set-v V (the window is measured with "
                                             "full ramps, no longer one pulse pair)")
    add_renamed_option(test, "--pair-reset-v", "--ramp-reset-v V (the window is measured with "
                                               "full ramps, no longer one pulse pair)")
    crit.add_argument("--good-csv", metavar="FILE", default=None,
                      help="write the cells that pass as a cell list (row,col,...; "
                           "program-weights --cells-only reads it; default: none)")
    crit.add_argument("--bad-csv", metavar="FILE", default=None,
                      help="write the cells that fail, with the reasons (program-weights "
                           "--cells-avoid reads it; default: none)")
    crit.add_argument("--criteria-png", metavar="FILE", default=None,
                      help="heat map of R_max/R_min with the failing cells crossed "
                           "(default: none)")
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
    return cells_from_selection(args, rows, cols)


def _criteria(args: argparse.Namespace) -> UserCriteria | None:
    given = {"--rmin-below": args.rmin_below, "--rmax-above": args.rmax_above,
             "--ratio-above": args.ratio_above}
    outputs = {"--good-csv": args.good_csv, "--bad-csv": args.bad_csv,
               "--criteria-png": args.criteria_png}
    pair = {"--ramp-set-v": args.ramp_set_v, "--ramp-reset-v": args.ramp_reset_v}
    if all(v is None for v in given.values()):
        named = [k for k, v in outputs.items() if v]
        if named:
            raise UserError(f"{named[0]} writes the verdict of user criteria: give "
                            "--rmin-below, --rmax-above or --ratio-above as well")
        named = [k for k, v in pair.items() if v is not None]
        if named:                      # the window is measured for the criteria alone
            raise UserError(f"{named[0]} is the top of a ramp of the user criteria's window "
                            "measurement, which runs only with criteria: give --rmin-below, "
                            f"--rmax-above or --ratio-above as well, or leave {named[0]} out")
        return None
    dc = UserCriteria()
    set_v = dc.set_v if args.ramp_set_v is None else args.ramp_set_v
    reset_v = dc.reset_v if args.ramp_reset_v is None else args.ramp_reset_v
    for opt, v in given.items():
        if v is not None and not (math.isfinite(v) and v > 0):
            raise UserError(f"{opt} {v}: give a positive number")
    if args.ratio_above is not None and args.ratio_above <= 1:
        raise UserError(f"--ratio-above {args.ratio_above}: R_max/R_min is at least 1; give a "
                        "ratio above 1, e.g. 2")
    for opt, v in (("--ramp-set-v", set_v), ("--ramp-reset-v", reset_v)):
        if not MEMRICORE.max_read_v < v <= MEMRICORE.max_write_v or v > args.v_max + 1e-9:
            raise UserError(f"{opt} {v} V: give {MEMRICORE.max_read_v}..{args.v_max} V (above "
                            "the read limit, at most --v-max)")
    return UserCriteria(args.rmin_below, args.rmax_above, args.ratio_above, set_v, reset_v)


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
    (``--max-write-v``, else the MemriCore default) before the board is opened; the board's
    own limit is checked by the job after HELLO."""
    if max_write_v is not None:
        host = requested_write_limit_v(board, max_write_v)
        if v_max > host + 1e-9:
            raise UserError(f"--v-max {v_max} V is above the host's write limit {host:g} V "
                            "(--max-write-v); lower --v-max or raise --max-write-v")
    if v_max > board.max_write_v + 1e-9:
        raise UserError(f"--v-max {v_max} V is above the board's write limit "
                        f"{board.max_write_v} V")


NAMES = {"cells": "--cells", "v_max": "--v-max"}
"""The job's fields as this command's options (messages)."""


@dataclass
class _Tested:
    """What one board's cell test leaves for its outputs (the run on this host's board, or a
    board's result over ``--boards``/``--dask``: no session here): the job's result, the board
    (identity and port), the session's snapshot, the run block, the array's shape and the
    board id and port the figures name."""

    run: ScreenRun
    board: dict[str, Any]
    session: dict[str, Any]
    run_block: dict[str, Any]
    shape: tuple[int, int]
    board_id: str | None
    port: str | None
    number: int | None = None
    """The board's number over ``--boards``/``--dask`` (its files' ``.board-<i>``)."""


def _test(args: argparse.Namespace) -> int:
    boards = every_board_set(args, file_use(args))      # --boards/--dask: docs/multiboard.md
    cells = cells_from_selection(args, MEMRICORE.rows, MEMRICORE.cols,
                                 bounded=boards is None)   # else each board checks its own
    if args.v_max is None:                # a lowered host limit lowers the default with it
        args.v_max = min(ScreenConfig().v_max,
                         requested_write_limit_v(MEMRICORE, args.max_write_v))
    elif not math.isfinite(args.v_max):
        raise UserError(f"--v-max {args.v_max}: give a number of volts, e.g. 1.2")
    cfg = _config(args)
    criteria = _criteria(args)
    _check_v_max(cfg.v_max, args.max_write_v, MEMRICORE)
    job = ScreenJob(None if getattr(args, "all", False) else cells, cfg, criteria, names=NAMES)
    if boards is not None:
        return _test_on_boards(args, job, boards)
    plan = plan_from_args(args)
    paths = {opt: plan.outputs.file(opt, getattr(args, name), kind)
             for opt, name, kind in FILES if getattr(args, name)}
    done = run_on_board(args, job, plan)
    session = done.session
    info = session.info
    return _outputs(args, job, _Tested(
        done.result, session.identity.to_dict(port=args.port), session.snapshot(),
        done.run_block(), (info.rows, info.cols), info.board_id, args.port), paths)


def _test_on_boards(args: argparse.Namespace, job: ScreenJob, boards: BoardSet) -> int:
    """The test replicated on every board's chip (:func:`every_board`); each board's output
    files (``.board-<i>``, checked once the boards answered, before any pulse) written and
    its report printed here, under a line naming the board."""
    outs = Outputs({"--cells-file": getattr(args, "cells_file", None)}, force=args.force)
    paths, check = board_outputs(args, outs, FILES)
    for r in every_board(args, job, boards, before=check):
        snap = r.run["session"]
        board_header(r)
        _outputs(args, job, _Tested(
            job.result(r.records, "complete"), {**r.run["identity"], "port": r.port}, snap,
            r.run["block"], (int(snap["info"]["rows"]), int(snap["info"]["cols"])),
            r.run["identity"].get("board_id"), r.port, r.board), paths[r.board])
    return 0


def _outputs(args: argparse.Namespace, job: ScreenJob, done: _Tested,
             paths: dict[str, Path]) -> int:
    """One board's files (``paths``: option -> file) and printed report."""
    run, cfg, criteria = done.run, job.cfg, job.criteria
    results, summary = run.results, run.summary
    data = {"format": CELLS_FORMAT, "version": __version__,
            "board": done.board, "session": done.session,
            "config": cfg.to_dict(), "read_chain": run.read_chain,
            "summary": summary, "layout_marked": run.marked, "layout_cleared": run.cleared,
            "cells": [r.to_dict() for r in results]}
    if criteria is not None:
        data["criteria"] = criteria.to_dict()
        data["run"] = done.run_block
        for opt, verdict in (("--good-csv", "good"), ("--bad-csv", "bad")):
            if opt in paths:
                write_cell_list(paths[opt], [r for r in results if r.verdict == verdict])
        if "--criteria-png" in paths:
            plot_criteria(results, done.shape, paths["--criteria-png"],
                          title=figure_title("cell test with user criteria", None, done.port,
                                             board_id=done.board_id),
                          criteria=criteria)
    if "-o" in paths:
        atomic_write_json(paths["-o"], data, indent=1, allow_nan=False)
    if "--png" in paths:
        plot_cell_classes({(r.row, r.col): r.cls for r in results}, done.shape, paths["--png"],
                          title=figure_title("cell test", None, done.port,
                                             board_id=done.board_id))
    if args.json:
        print(json.dumps(data, indent=1, allow_nan=False))
        return 0
    _print(results, summary, run.marked, run.cleared, run.layout_path)
    if criteria is not None:
        _print_criteria(results, summary)
    print_written(args, FILES, paths, done.number)
    return 0


CELL_LIST_HEADER = "row,col,verdict,class,r_min_ohm,r_max_ohm,ratio,reasons"
CELL_LIST_CSV = csv_kind(CELL_LIST_HEADER, "a 'snan-hil cells test' cell list")
CRITERIA_PNG = png_kind(CRITERIA_PNG_FORMAT, "a 'snan-hil cells test' criteria map")
FILES = (("-o", "output", CELLS_JSON), ("--png", "png", CELLS_PNG),
         ("--good-csv", "good_csv", CELL_LIST_CSV), ("--bad-csv", "bad_csv", CELL_LIST_CSV),
         ("--criteria-png", "criteria_png", CRITERIA_PNG))
"""The test's output files: option, argument, kind."""


def write_cell_list(path: Path, results: list[CellClass]) -> None:
    """A cell list (tools/commands/_cells.py reads it back): one row per cell."""
    def num(x: float | None) -> str:
        return "" if x is None or not math.isfinite(x) else f"{x:.6g}"
    try:
        with atomic_path(path) as tmp, open(tmp, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(CELL_LIST_HEADER.split(","))
            for r in results:
                w.writerow([r.row, r.col, r.verdict, r.cls, num(r.r_min_ohm), num(r.r_max_ohm),
                            num(r.ratio), "; ".join(r.reasons)])
    except OSError as exc:
        raise UserError(f"cannot write {path}: {exc.strerror or exc}") from None


def _print_criteria(results: list[CellClass], summary: dict) -> None:
    bad = [r for r in results if r.verdict == "bad"]
    if bad:
        t = Table(title="cells that fail the user criteria")
        for col in ("cell", "class", "R_min Ohm", "R_max Ohm", "ratio", "why"):
            t.add_column(col, overflow="fold")
        for r in bad:
            t.add_row(f"({r.row},{r.col})", r.cls,
                      "-" if r.r_min_ohm is None else f"{r.r_min_ohm:.0f}",
                      "-" if r.r_max_ohm is None else f"{r.r_max_ohm:.0f}",
                      "-" if r.ratio is None else f"{r.ratio:.2f}", "; ".join(r.reasons))
        console.print(t)
    console.print(f"user criteria: {summary['criteria_good']} good, {summary['criteria_bad']} "
                  f"bad ({summary['criteria_good_pct']:.0f} % good)", highlight=False)


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
        plot_cell_classes(classes, (MEMRICORE.rows, MEMRICORE.cols), png,
                          title=figure_title("cell classes (last test of each cell)", None,
                                             args.port))
        if not args.json:
            console.print(f"wrote --png {args.png}", highlight=False)
    return 0
