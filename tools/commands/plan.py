"""``snan-hil plan``: pulse plans from YAML files -- SET / RESET / read steps, ramps, counts,
repeats and terminators -- on one cell, a list, a CSV of cells or all cells
(:mod:`snan_hil.calibration.plans`).

Examples::

    snan-hil plan presets                                    # the shipped library
    snan-hil plan show switching-sweep --yaml > mine.yaml    # start from a preset
    snan-hil plan run my-iv.yaml --cells 3,5 --dry-run       # every pulse, no board opened
    snan-hil plan run my-iv.yaml --cells 3,5 4,5 --port emu --sample chip7 --operator ana
    snan-hil plan run endurance --cells-file good.csv --port /dev/ttyUSB0
    snan-hil plan repeat 12 --cells 6,1                      # run 12 of the history again

Every run lands in the board's history database (kind ``plan``) with the plan itself, its
cells and the run's metadata; ``plan repeat RUN`` (an id or uid) runs the recorded plan again
on the same cells or on others. The host's write limit and the compliance rule hold for every
pulse: a plan above the limit is refused, before the board is opened, with one line naming
the step.
"""

from __future__ import annotations

import argparse
import csv
import json
import sqlite3
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rich.table import Table

from snan_hil.common.version import __version__
from snan_hil.calibration.plans import (MAX_PLAN_PULSES, Plan, PlanJob, PlanRun, check_plan,
                                        compliance_g_limit_s, expand, load_plan, parse_plan,
                                        preset_names, preset_text, pulse_time_s)
from snan_hil.common.errors import UserError
from snan_hil.files.atomicio import atomic_path, atomic_write_json
from snan_hil.files.outputs import Outputs, csv_kind, json_kind
from snan_hil.lab.fanout import BoardSet
from snan_hil.lab.runner import JobInterrupted, JobRun
from snan_hil.protocol.board import MEMRICORE, BoardConstants
from snan_hil.protocol.safety import offline_write_limit_v, requested_write_limit_v
from snan_hil.records.documents import DocumentCollector
from snan_hil.records.history import History, HistoryError
from snan_hil.tools.commands._board import (add_layout_option, add_result_options, file_use,
                                            plan_from_args)
from snan_hil.tools.commands._cells import add_cell_selection, cells_from_selection
from snan_hil.tools.commands._history import board_history_path
from snan_hil.tools.commands._job import run_on_board
from snan_hil.tools.console import console, err_console
from snan_hil.tools import output_kinds
from snan_hil.tools.titles import figure_title
from snan_hil.tools.commands._boards import (add_every_board_options, board_header,
                                             board_outputs, every_board, every_board_set,
                                             print_written)
from snan_hil.tools.ports import add_port_arguments

NAME = "plan"
HELP = ("pulse plans from YAML files (SET/RESET/read steps, ramps, terminators): run, dry-run, "
        "show, presets, repeat from the history")

PLAN_RUN_FORMAT = "snan-hil-plan-run/1"
PLAN_JSON = json_kind(PLAN_RUN_FORMAT, "a 'snan-hil plan run' result")
PLAN_CSV_HEADER = ("row,col,n,plan_repeat,step,action,amplitude_v,width_us,g_before_s,"
                   "g_after_s,adc,read_v,current_a,cell_v")
PLAN_CSV_HEADER_V1 = ("row,col,n,plan_repeat,step,action,amplitude_v,width_us,g_before_s,"
                      "g_after_s,adc")
PLAN_CSV = csv_kind(PLAN_CSV_HEADER, "a 'snan-hil plan run' CSV", earlier=(PLAN_CSV_HEADER_V1,))
DRY_ROWS_SHOWN = 2000
"""Pulses listed one by one by ``--dry-run`` before the table is cut (the JSON has all)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="plan_action", metavar="ACTION", required=True)
    fmt = parser.formatter_class
    presets = sub.add_parser("presets", help="list the shipped presets", formatter_class=fmt,
                             description="The preset plans shipped with snan-hil.")
    presets.add_argument("--json", action="store_true", help="print them as JSON")

    show = sub.add_parser("show", help="show a plan's steps (a file or a preset name)",
                          formatter_class=fmt,
                          description="Check a plan and show its steps, pulse count and "
                                      "estimated time per cell (no board).")
    show.add_argument("plan", metavar="PLAN", help="a plan file (YAML) or a preset name")
    show.add_argument("--yaml", action="store_true",
                      help="print the plan's YAML (a preset's file, to copy and edit)")
    show.add_argument("--json", action="store_true", help="print the plan as JSON")

    run = sub.add_parser("run", help="run a plan on cells (or --dry-run: list every pulse)",
                         formatter_class=fmt,
                         description="Run a pulse plan on cells, one cell after the other; "
                                     "--dry-run lists every pulse without opening the board.")
    run.add_argument("plan", metavar="PLAN", help="a plan file (YAML) or a preset name")
    _run_options(run)

    rep = sub.add_parser("repeat", help="run a plan of the history again",
                         formatter_class=fmt,
                         description="Run the plan a recorded plan run used again, on the "
                                     "same cells or on the cells given.")
    rep.add_argument("run_ref", metavar="RUN", help="the run's id or uid (snan-hil history)")
    _run_options(rep, same_cells=True)


def _run_options(p: argparse.ArgumentParser, same_cells: bool = False) -> None:
    add_port_arguments(p)
    add_every_board_options(p)                     # the same plan on every board's chip
    add_cell_selection(p, "the cells to run the plan on" + (
        " (default: the run's own cells)" if same_cells else ""))
    if same_cells:
        p.add_argument("--board", metavar="ID", default=None,
                       help="for a board other than the in-process emulator: the board id "
                            "whose history holds the run (default: the port's; or --history)")
    p.add_argument("--dry-run", action="store_true",
                   help="list every pulse (volts, width, estimated time, host-limit and "
                        "compliance verdict) and the total; nothing is sent, the board is not "
                        "opened")
    add_layout_option(p, "convert reads with this layout's calibrated read chain; synapses "
                         "of it on pulsed cells are marked stale (default: the port's layout "
                         "if it exists)")
    p.add_argument("--csv", metavar="FILE", default=None,
                   help="write one row per pulse and read (default: none)")
    p.add_argument("-o", "--output", metavar="FILE", default=None,
                   help="write the result as JSON (default: none)")
    p.add_argument("--png", metavar="FILE", default=None,
                   help="draw each cell's conductance and the amplitude of every pulse against "
                        "the pulse number (and, for reads at their own voltages, the measured "
                        "I-V) (default: no figure)")
    add_result_options(p)


def run(args: argparse.Namespace) -> int:
    if args.plan_action == "presets":
        return _presets(args)
    if args.plan_action == "show":
        return _show(args)
    if args.plan_action == "run":
        load_plan(args.plan)            # a bad plan: one line before any board
    boards = every_board_set(args, file_use(args))    # --boards/--dask: docs/multiboard.md
    if args.plan_action == "repeat":
        if boards is not None and not getattr(args, "history", None) and not args.board:
            raise UserError("plan repeat over several boards reads the run from one history "
                            "database: give --history FILE or --board ID")
        plan, source, cells, extra = _from_history(args)
        return _run(args, plan, source, cells, extra, boards)
    plan = load_plan(args.plan)
    return _run(args, plan, str(args.plan), None, {}, boards)


# ------------------------------------------------------------------ presets / show
def _presets(args: argparse.Namespace) -> int:
    rows: list[dict[str, Any]] = []
    for name in preset_names():
        from snan_hil.calibration.plans import load_preset
        p = load_preset(name)
        est = sum(pulse_time_s(MEMRICORE, x) for x in expand(p, MEMRICORE))
        rows.append({"name": name, "description": p.description, "steps": len(p.steps),
                     "pulses": p.n_write_pulses(), "reads_and_pulses": p.n_pulses(),
                     "estimated_s": est})
    if args.json:
        print(json.dumps({"presets": rows}, indent=1))
        return 0
    t = Table(title=f"{len(rows)} preset plans (snan-hil plan show NAME --yaml to copy one)")
    for col in ("name", "what it does", "pulses", "est. time / cell"):
        t.add_column(col, overflow="fold")
    for r in rows:
        t.add_row(r["name"], r["description"], str(r["pulses"]), f"{r['estimated_s']:.2f} s")
    console.print(t)
    return 0


def _show(args: argparse.Namespace) -> int:
    plan = load_plan(args.plan)
    if args.yaml:
        p = Path(args.plan).expanduser()
        sys.stdout.write(p.read_text(encoding="utf-8") if p.is_file() else
                         preset_text(str(args.plan)))
        return 0
    if args.json:
        print(json.dumps(plan.to_tree(), indent=1))
        return 0
    _print_plan(plan, MEMRICORE, "framed", 115200)
    return 0


def _print_plan(plan: Plan, board: BoardConstants, protocol: str, baud: int) -> None:
    t = Table(title=f"plan {plan.name}: {plan.description}".rstrip(": "))
    for col in ("step", "what", "pulses (at most)"):
        t.add_column(col, overflow="fold")
    for i, s in enumerate(plan.steps, 1):
        t.add_row(str(i), s.text(), str(s.n_pulses()))
    console.print(t)
    est = sum(pulse_time_s(board, x, protocol=protocol, baud=baud) for x in expand(plan, board))
    tail = f"; the plan stops on a cell when {plan.stop_when.text()}" if plan.stop_when else ""
    console.print(f"{plan.repeats} repeat(s): at most {plan.n_write_pulses()} pulses and "
                  f"{plan.n_pulses() - plan.n_write_pulses()} reads per cell, about "
                  f"{est:.2f} s per cell ({protocol} at {baud} baud){tail}", highlight=False)


# ------------------------------------------------------------------ repeat
def _from_history(args: argparse.Namespace
                  ) -> tuple[Plan, str, list[tuple[int, int]] | None, dict[str, Any]]:
    path = board_history_path(args)
    try:
        with History.open(path, create=False) as db:
            row = db.run(args.run_ref)
    except sqlite3.Error as exc:
        raise HistoryError(f"history database {path}: {exc}") from None
    if row is None:
        raise UserError(f"RUN {args.run_ref}: no such run in {path} (give a run id or uid as "
                        "'snan-hil history' lists them)")
    cfg = row.config if isinstance(row.config, dict) else {}
    if row.kind != "plan" or "plan" not in cfg:
        raise UserError(f"run {row.id} is a {row.kind} run, not a plan run; only plan runs can "
                        "be repeated (snan-hil history --kind plan)")
    plan = parse_plan(cfg["plan"], f"run {row.id}'s plan")
    for key in ("sample", "operator"):     # the same sample by the same hands, unless given
        if getattr(args, key, None) is None:
            setattr(args, key, getattr(row, key))
    cells = [tuple(c) for c in cfg.get("cells", [])]
    return plan, f"history run {row.id} ({cfg.get('source', '?')})", \
        [(int(r), int(c)) for r, c in cells], {"repeat_of": {"run_id": row.id, "uid": row.uid}}


# ------------------------------------------------------------------ run
def _cells(args: argparse.Namespace, default: list[tuple[int, int]] | None,
           rows: int, cols: int, bounded: bool = True) -> list[tuple[int, int]]:
    if default is not None and not args.all and args.cells is None and not args.cells_file:
        for r, c in default:
            if not (0 <= r < rows and 0 <= c < cols):
                raise UserError(f"the recorded cell ({r},{c}) is outside the {rows}x{cols} "
                                "array; give --cells")
        return default
    return cells_from_selection(args, rows, cols, bounded=bounded)


NAMES = {"cells": "--cells"}
"""How the plan job's messages name its config's fields on the command line."""


@dataclass
class _Ran:
    """What one board's plan run leaves for its outputs (the run on this host's board, or a
    board's result over ``--boards``/``--dask``: no session here): the job's result, its
    status, the run block (uid, metadata, history run id, exit status), the board (board id,
    port, protocol)."""

    result: PlanRun
    status: str
    run: dict[str, Any]
    board: dict[str, Any]
    number: int | None = None
    """The board's number over ``--boards``/``--dask`` (its files' ``.board-<i>``)."""


FILES = (("--csv", "csv", PLAN_CSV), ("-o", "output", PLAN_JSON),
         ("--png", "png", output_kinds.PLAN_PNG))
"""The run's output files: option, argument, kind."""


def _run(args: argparse.Namespace, plan: Plan, source: str,
         default_cells: list[tuple[int, int]] | None, extra: dict[str, Any],
         boards: BoardSet | None = None) -> int:
    cells = _cells(args, default_cells, MEMRICORE.rows, MEMRICORE.cols,
                   bounded=boards is None)          # else each board checks its own array
    host_v = (None if args.max_write_v is None
              else requested_write_limit_v(MEMRICORE, args.max_write_v))
    if args.dry_run:
        for opt, value in (("--csv", args.csv), ("-o", args.output), ("--png", args.png)):
            if value:        # nothing runs, so there is no result to write (docs/bench.md)
                raise UserError(f"--dry-run sends nothing, so {opt} would get no result; "
                                "drop it, or save the list of pulses with --dry-run --json "
                                "> FILE")
        if args.baud < 1:
            raise UserError(f"--baud must be positive, got {args.baud}")
        if host_v is not None:       # no board answers a dry run: MemriCore's declared limit
            host_v = offline_write_limit_v(MEMRICORE, host_v)             # never raised
        return _dry_run(args, plan, cells, host_v)
    check_plan(plan, MEMRICORE, host_v)                # before anything is opened
    job = PlanJob(plan, cells, source=source, extra=extra, names=NAMES)
    if boards is not None:
        return _run_on_boards(args, plan, source, job, boards)
    board = plan_from_args(args, cells_file=args.cells_file)
    outs = board.outputs
    if getattr(args, "plan", None) and Path(args.plan).is_file():
        outs.inputs["PLAN"] = Path(args.plan)
    paths = {opt: outs.file(opt, getattr(args, name), kind)
             for opt, name, kind in FILES if getattr(args, name)}
    collector = DocumentCollector()

    def ran(done: JobRun[PlanRun]) -> _Ran:
        return _Ran(done.result, done.status, {**done.run_block(), **collector.run_block()},
                    {"board_id": done.session.info.board_id, "port": args.port,
                     "protocol": args.protocol})
    try:
        done = run_on_board(args, job, board, subscribers=(collector,))
    except JobInterrupted as stop:   # Ctrl-C, or a stop from snan-hil watch: the run ended
        if stop.run.result is not None:  # as interrupted; what was applied goes on record
            _write_outputs(args, plan, source, ran(stop.run), paths)
        raise
    return _report(args, plan, source, ran(done), paths)


def _run_on_boards(args: argparse.Namespace, plan: Plan, source: str, job: PlanJob,
                   boards: BoardSet) -> int:
    """The plan replicated on every board's chip (:func:`every_board`); each board's output
    files (``.board-<i>``, checked once the boards answered, before any pulse) written and
    its report printed here, under a line naming the board."""
    outs = Outputs({"--cells-file": getattr(args, "cells_file", None)}, force=args.force)
    if getattr(args, "plan", None) and Path(args.plan).is_file():
        outs.inputs["PLAN"] = Path(args.plan)
    paths, check = board_outputs(args, outs, FILES)
    for r in every_board(args, job, boards, before=check):
        board_header(r)
        _report(args, plan, source, _Ran(
            job.result(r.records, "complete"), "complete",
            {**r.run["block"], **r.run["documents"]},
            {"board_id": r.run["identity"].get("board_id"), "port": r.port,
             "protocol": args.protocol}, r.board), paths[r.board])
    return 0


def _report(args: argparse.Namespace, plan: Plan, source: str, ran: _Ran,
            paths: dict[str, Path]) -> int:
    data = _write_outputs(args, plan, source, ran, paths)
    if args.json:
        print(json.dumps(data, indent=1, allow_nan=False))
        return 0
    _print_results(plan, ran)
    print_written(args, FILES, paths, ran.number)
    return 0


def _write_outputs(args: argparse.Namespace, plan: Plan, source: str, ran: _Ran,
                   paths: dict[str, Path]) -> dict[str, Any]:
    """``--csv``, ``-o`` and ``--png`` (``paths``: option -> file) of a plan run that ended
    (complete, or interrupted: then the result holds what was applied, the last cell's cut
    short); returns the JSON report."""
    res, status = ran.result, ran.status
    data = {"format": PLAN_RUN_FORMAT, "version": __version__, "status": status,
            "run": ran.run, "plan": plan.to_tree(), "source": source,
            "read_chain": res.read_chain, "board": ran.board,
            "cells": [r.to_dict() for r in res.cells]}
    if "--csv" in paths:
        _write_csv(res.cells, paths["--csv"])
    if "-o" in paths:
        atomic_write_json(paths["-o"], data, indent=1, allow_nan=False)
    if "--png" in paths and res.cells:
        from snan_hil.tools.plan_figures import plot_plan_run
        plot_plan_run(res.cells, paths["--png"], step_names=[s.name for s in plan.steps],
                      title=figure_title(f"plan {plan.name}", None, ran.board["port"],
                                         board_id=ran.board["board_id"]))
    if status != "complete":
        for opt, path in paths.items():
            err_console.print(f"note: wrote {opt} {path}: what was applied before the "
                              f"run was {status}", markup=False, highlight=False,
                              soft_wrap=True)
    return data


def _print_results(plan: Plan, ran: _Ran) -> None:
    results, uid, run_id = ran.result.cells, str(ran.run["uid"]), ran.run["history_run_id"]
    t = Table(title=f"plan {plan.name} on {len(results)} cell(s) (run "
                    f"{run_id if run_id is not None else '-'}, uid {uid[:8]})")
    for col in ("cell", "G before uS", "G after uS", "pulses", "reads", "why it ended"):
        t.add_column(col, overflow="fold")
    for r in results:
        d = r.to_dict(records=False)
        t.add_row(f"({r.row},{r.col})", f"{r.initial_s * 1e6:.2f}", f"{r.final_s * 1e6:.2f}",
                  str(d["pulses"]), str(d["reads"]), r.stopped)
    console.print(t)
    console.print(f"reads via the {ran.result.read_chain}; repeat it with: snan-hil plan "
                  f"repeat {uid[:8]}", highlight=False)


def _write_csv(results: list[Any], path: Path) -> None:
    try:
        with atomic_path(path) as tmp, open(tmp, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(PLAN_CSV_HEADER.split(","))
            for res in results:
                for r in res.records:
                    w.writerow([res.row, res.col, r.n, r.plan_repeat, r.step, r.action,
                                f"{r.amplitude_v:.6g}", r.width_us, f"{r.g_before_s:.6g}",
                                f"{r.g_after_s:.6g}", "" if r.adc is None else r.adc,
                                *("" if v is None else f"{v:.6g}"
                                  for v in (r.read_v, r.current_a, r.cell_v))])
    except OSError as exc:
        raise UserError(f"cannot write --csv {path}: {exc.strerror or exc}") from None


# ------------------------------------------------------------------ dry run
def _dry_run(args: argparse.Namespace, plan: Plan, cells: list[tuple[int, int]],
             host_v: float | None) -> int:
    board = MEMRICORE
    limit = board.max_write_v if host_v is None else host_v
    check_plan(plan, board, host_v)       # a refused plan: its one error line, nothing else
    rows: list[dict[str, Any]] = []
    total = 0.0
    for p in expand(plan, board):
        est = pulse_time_s(board, p, protocol=args.protocol, baud=args.baud)
        total += est
        if p.action == "read":
            host, comp = "read at the read limit", "-"
        elif p.amplitude_v > limit + 1e-9:
            host, comp = f"REFUSED: above {limit:g} V", "-"
        elif p.code < 1:
            host, comp = "REFUSED: below one DAC step", "-"
        else:
            g_max = compliance_g_limit_s(board, p.applied_v)
            host = "ok"
            comp = "any G" if g_max == float("inf") else f"G <= {g_max * 1e6:.0f} uS"
        rows.append({"n": p.n, "plan_repeat": p.plan_repeat, "step": p.step,
                     "step_repeat": p.step_repeat, "action": p.action,
                     "amplitude_v": p.amplitude_v, "applied_v": p.applied_v,
                     "dac_code": p.code, "width_us": p.width_us if p.action != "read" else 0,
                     "estimated_s": est, "host_limit": host, "compliance": comp})
    if args.json:
        print(json.dumps({"format": "snan-hil-plan-dry-run/1", "plan": plan.to_tree(),
                          "cells": [list(c) for c in cells], "host_write_limit_v": limit,
                          "compliance_a": board.compliance_a, "pulses": rows,
                          "per_cell_s": total, "total_s": total * len(cells),
                          "refused": None}, indent=1))
    else:
        t = Table(title=f"dry run of plan {plan.name} (nothing is sent): every pulse on each "
                        f"of {len(cells)} cell(s)")
        for col in ("n", "step", "rep", "action", "V", "applied V (code)", "width us",
                    "est. ms", "host limit", "compliance ok while"):
            t.add_column(col, overflow="fold", no_wrap=col == "host limit",
                         justify="right" if col in ("n", "V", "width us", "est. ms")
                         else "left")
        shown = rows if len(rows) <= DRY_ROWS_SHOWN else rows[:DRY_ROWS_SHOWN]
        for r in shown:
            t.add_row(str(r["n"]), str(r["step"]), f"{r['plan_repeat']}.{r['step_repeat']}",
                      r["action"], "-" if r["action"] == "read" else f"{r['amplitude_v']:.3f}",
                      "-" if r["action"] == "read" else
                      f"{r['applied_v']:.4f} ({r['dac_code']})",
                      str(r["width_us"]) if r["width_us"] else "-",
                      f"{r['estimated_s'] * 1e3:.3f}", r["host_limit"], r["compliance"])
        console.print(t)
        if len(rows) > len(shown):
            console.print(f"... {len(rows) - len(shown)} more (--json lists all)")
        cells_text = ", ".join(f"({r},{c})" for r, c in cells[:8]) + \
            (", ..." if len(cells) > 8 else "")
        console.print(f"{plan.n_write_pulses()} pulses and "
                      f"{plan.n_pulses() - plan.n_write_pulses()} reads per cell at most "
                      f"(terminators may end steps earlier; at most {MAX_PLAN_PULSES}); "
                      f"about {total:.2f} s per cell, {total * len(cells):.1f} s for "
                      f"{len(cells)} cell(s) {cells_text} ({args.protocol}, {args.baud} baud)",
                      highlight=False)
    return 0
