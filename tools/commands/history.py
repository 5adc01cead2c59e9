"""``snan-hil history``: the board's history database — its runs, one cell's life, CSV export.

Examples::

    snan-hil history --port emu                         # the runs, newest first
    snan-hil history --port emu --cell 3,5 --png c.png  # every pulse and result of a cell
    snan-hil history --port emu --export pulses -o pulses.csv
"""

from __future__ import annotations

import argparse
import json
import sqlite3
import sys
from pathlib import Path

from rich.table import Table

from snan_hil.files.atomicio import atomic_path, atomic_write_text
from snan_hil.common.errors import UserError
from snan_hil.records.history import KINDS, History, HistoryError, _sniff
from snan_hil.files.outputs import OutputKind, Outputs
from snan_hil.protocol.board import MEMRICORE
from snan_hil.tools.commands._options import accept_negative_cells, parse_cell
from snan_hil.tools.console import console
from snan_hil.tools.commands._history import board_history_path
from snan_hil.tools.output_kinds import CELL_LIFE_PNG, add_force_option, history_csv_kind
from snan_hil.tools.ports import add_board_argument
from snan_hil.tools.titles import figure_title

NAME = "history"
HELP = "the board's history database: list runs, show one cell's life, export CSV"

EXPORT_TABLES = {"runs": "runs", "cells": "cell_results", "pulses": "pulses"}
EXPORTS = (*EXPORT_TABLES, "documents")
DOCUMENTS_HEADER = '["start",{'              # as written: compact separators (_export)
"""The first bytes of a documents export (JSON Lines of [name, doc], a RunStart first)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    accept_negative_cells(parser)
    parser.add_argument("action", nargs="?", choices=("backup", "recover"), default=None,
                        help="backup: copy the database to -o FILE with SQLite's online backup "
                             "(safe while a job writes to it); recover: copy every row a "
                             "damaged database still holds into a new one, -o FILE (default: "
                             "list the runs)")
    add_board_argument(parser, "history to read (the database beside its layout)")
    parser.add_argument("--history", metavar="FILE", default=None,
                        help="the history database (default: the port's)")
    what = parser.add_mutually_exclusive_group()
    what.add_argument("--cell", metavar="R,C", default=None,
                      help="show one cell's life: every recorded pulse and result (default: "
                           "list the runs)")
    what.add_argument("--export", choices=EXPORTS, default=None,
                      help="write a table as CSV, or documents: the runs' Bluesky event-model "
                           "documents as JSON Lines of [name, doc] (-o FILE, or stdout; "
                           "default: no export)")
    parser.add_argument("--kind", choices=KINDS, default=None,
                        help="list only runs of a kind (default: all kinds)")
    parser.add_argument("--limit", type=int, default=50, help="runs listed")
    parser.add_argument("--run", default=None, metavar="ID",
                        help="with --export: only this run's rows, the run by id or uid (or a "
                             "uid prefix of 6+ characters) as 'snan-hil history' lists them, "
                             "as watch and plan repeat take it (default: all runs)")
    parser.add_argument("--png", metavar="FILE", default=None,
                        help="with --cell: draw its conductance and pulse count over its life "
                             "(default: no figure)")
    parser.add_argument("-o", "--output", metavar="FILE", default=None,
                        help="with --export: the CSV file (default: stdout)")
    parser.add_argument("--json", action="store_true", help="print JSON")
    add_force_option(parser)


def run(args: argparse.Namespace) -> int:
    path = board_history_path(args)
    if args.action == "backup":
        return _backup(args, path)
    if args.action == "recover":
        return _recover(args, path)
    _check_options(args)
    cell = parse_cell(args.cell, "--cell", MEMRICORE.rows, MEMRICORE.cols) \
        if args.cell is not None else None
    outs = Outputs({"--history": path}, force=args.force)
    png = outs.file("--png", args.png, CELL_LIFE_PNG) if args.png else None
    out = None
    if args.export is not None and args.output:
        out = outs.file("-o", args.output, DOCUMENTS if args.export == "documents" else
                        history_csv_kind(EXPORT_TABLES[args.export]))
    try:
        with History.open(path, create=False) as db:
            if cell is not None:
                return _cell(db, cell, png, args)
            if args.export is not None:
                return _export(db, args, path, out)
            return _runs(db, args)
    except sqlite3.Error as exc:
        raise HistoryError(f"history database {path}: {exc} (damaged or locked; 'snan-hil "
                           f"history recover --history {path} -o NEW.sqlite' saves what it "
                           "still holds)") from None


def _check_options(args: argparse.Namespace) -> None:
    """UserError (one line) for options that do not go together, before the file is read."""
    if args.png and args.cell is None:
        raise UserError("--png draws one cell's life: give --cell R,C as well")
    if args.output and args.export is None:
        if args.action != "backup":
            raise UserError("-o writes an export: give --export runs|cells|pulses|documents "
                            "as well (or: history backup -o FILE)")
    if args.run is not None and args.export is None:
        raise UserError("--run selects the rows of an export: give --export runs|cells|pulses "
                        "as well")
    if args.kind is not None and args.export is not None:
        raise UserError("--kind filters the list of runs; an export holds every run's rows: "
                        "select one run with --run ID (its id from 'snan-hil history --kind "
                        f"{args.kind}')")
    if args.limit < 1:
        raise UserError(f"--limit must be >= 1, got {args.limit}")


def _export(db: History, args: argparse.Namespace, path: Path, out: Path | None) -> int:
    """--export TABLE (of one --run, or all): to -o, else to stdout."""
    run_id = None if args.run is None else _run_id(db, args.run, path)
    if args.export == "documents":
        return _export_documents(db, run_id, out)
    text = db.export_csv(EXPORT_TABLES[args.export], run_id)
    if out is None:
        sys.stdout.write(text)
    else:
        atomic_write_text(out, text)
        console.print(f"wrote {text.count(chr(10)) - 1} rows of "
                      f"{EXPORT_TABLES[args.export]} to {out}", highlight=False)
    return 0


DOCUMENTS = OutputKind("a 'snan-hil history --export documents' file",
                       lambda p: _starts_with(p, DOCUMENTS_HEADER.encode()))
BACKUP = OutputKind("a snan-hil history database", lambda p: check_history_ok(p))


def _starts_with(path: Path, head: bytes) -> bool:
    try:
        with open(path, "rb") as fh:
            return fh.read(len(head)) == head
    except OSError:
        return False


def check_history_ok(path: Path) -> bool:
    return path.stat().st_size > 0 and _sniff(path) is None


def _run_id(db: History, ref: str, path: Path) -> int:
    """The id of the run ``--run ref`` names: an id, a uid or a uid prefix (6+ characters)
    naming one run, as ``watch`` and ``plan repeat`` take it; UserError for none."""
    row = db.run(ref)
    if row is None:
        raise UserError(f"--run {ref}: no such run in {path} (give a run id, uid or a uid "
                        "prefix of 6+ characters naming one run, as 'snan-hil history' lists "
                        "them)")
    return row.id


def _export_documents(db: History, run_id: int | None, out: Path | None) -> int:
    runs = [run_id] if run_id is not None else [r.id for r in reversed(db.runs())]
    lines = []
    skipped = 0
    for rid in runs:
        docs = db.documents(rid)
        if not docs:
            skipped += 1            # recorded before schema 2 (no documents) or --record off
            continue
        lines += [json.dumps([name, doc], allow_nan=False, separators=(",", ":"))
                  for _id, name, doc in docs]
    text = "".join(line + "\n" for line in lines)
    if out is None:
        sys.stdout.write(text)
    else:
        atomic_write_text(out, text)
        console.print(f"wrote {len(lines)} documents of {len(runs) - skipped} run(s) to {out}"
                      + (f" ({skipped} run(s) recorded before schema 2 have none)"
                         if skipped else ""), highlight=False)
    return 0


def _backup(args: argparse.Namespace, path: Path) -> int:
    if not args.output:
        raise UserError("history backup: give the copy's file name with -o FILE")
    outs = Outputs({"--history": path}, force=args.force)
    dest = outs.file("-o", args.output, BACKUP)
    try:
        with History.open(path, create=False) as db, atomic_path(dest) as tmp:
            db.backup(tmp)
            with History.open(tmp, create=False) as copy:     # read back before it is kept:
                n = len(copy.runs())                           # a damaged page fails here
    except sqlite3.Error as exc:
        raise HistoryError(f"history database {path}: {exc}; nothing was written to "
                           f"{dest}") from None
    console.print(f"backed up {path} to {dest} ({n} runs; SQLite online backup)",
                  highlight=False)
    return 0


def _recover(args: argparse.Namespace, path: Path) -> int:
    from snan_hil.records.recover import recover
    if not args.output:
        raise UserError("history recover: give the new database's file name with -o FILE")
    if not path.is_file():
        raise UserError(f"history recover: no database at {path}")
    outs = Outputs({"--history": path}, force=args.force)
    dest = outs.file("-o", args.output, BACKUP)
    try:
        with atomic_path(dest) as tmp:
            tmp.unlink(missing_ok=True)
            report = recover(path, tmp)
    except sqlite3.Error as exc:
        raise HistoryError(f"history database {path}: {exc}; it cannot be read at all, "
                           f"nothing was written to {dest}") from None
    from snan_hil.records.pending import pending_dir, pending_files
    waiting = pending_files(path)        # runs a lock kept out: they go into the copy too
    if waiting:
        import shutil
        pending_dir(dest).mkdir(exist_ok=True)
        for f in waiting:
            shutil.copy2(f, pending_dir(dest) / f.name)
    lost = f", {report.total_lost} unreadable" if report.total_lost else ""
    console.print(f"recovered {report.total_copied} rows of {path} into {dest} "
                  f"({report.copied.get('runs', 0)} runs, {report.copied.get('pulses', 0)} "
                  f"pulses{lost}); record into it with --history {dest}", highlight=False)
    return 0


def _runs(db: History, args: argparse.Namespace) -> int:
    runs = db.runs(args.kind, args.limit)
    if args.json:
        print(json.dumps({"history": str(db.path), "runs": [r.to_dict() for r in runs]},
                         default=str))
        return 0
    t = Table(title=f"history {db.path}: {len(runs)} run(s), newest first")
    rows = [(str(r.id), r.kind, r.started_utc[:16].replace("T", " "), r.status,
             r.board_id or "-", r.port or "-", str(r.cells), str(r.pulses),
             " / ".join(x or "-" for x in (r.sample, r.operator)),
             r.command.removeprefix("snan-hil ")) for r in runs]
    # what a user needs to pick a run never truncates (run id, kind, status, counts); the
    # rest folds onto more lines on a narrow terminal
    keep = {"run": 0, "kind": 1, "status": 3, "cells": 6, "pulses": 7}
    for k, col in enumerate(("run", "kind", "started (UTC)", "status", "board", "port",
                             "cells", "pulses", "sample / operator")):
        if col in keep:
            width = max([len(col)] + [len(row[k]) for row in rows])
            t.add_column(col, no_wrap=True, min_width=width)
        else:
            t.add_column(col, overflow="fold")
    t.add_column("command", overflow="fold", ratio=1)
    for row in rows:
        t.add_row(*row)
    console.print(t)
    return 0


def _cell(db: History, cell: tuple[int, int], png: Path | None,
          args: argparse.Namespace) -> int:
    life = db.cell_life(*cell)
    if args.json:
        print(json.dumps({"history": str(db.path), "cell": list(cell),
                          "events": [e.to_dict() for e in life]}))
    else:
        t = Table(title=f"cell ({cell[0]},{cell[1]}): {len(life)} recorded events, "
                        f"{life[-1].pulses_total if life else 0} pulses")
        for col in ("time (UTC)", "run", "kind", "event", "G after uS", "pulses so far"):
            t.add_column(col)
        shown = life if len(life) <= 60 else life[:30] + life[-30:]
        for k, e in enumerate(shown):
            if len(life) > 60 and k == 30:
                t.add_row("...", "", "", "", "", "")
            what = (f"{e.polarity} {e.amplitude_v:.3f} V {e.width_us} us" if e.event == "pulse"
                    else f"result: {e.outcome}")
            g = "-" if e.g_s is None else f"{e.g_s * 1e6:.2f}"
            t.add_row(e.time_utc[:19].replace("T", " "), str(e.run_id), e.kind, what, g,
                      str(e.pulses_total))
        console.print(t)
    if png is not None:
        if not life:
            raise UserError(f"cell ({cell[0]},{cell[1]}) has no recorded events in "
                            f"{db.path}; nothing to draw")
        from snan_hil.tools.bench_figures import plot_cell_life
        runs = [db.run(i) for i in sorted({e.run_id for e in life})]
        ports = sorted({r.port for r in runs if r is not None and r.port})
        boards = sorted({r.board_id for r in runs if r is not None and r.board_id})
        plot_cell_life(life, png, title=figure_title(   # where its runs were, not --port
            f"life of cell ({cell[0]},{cell[1]}) from {db.path.name}", None,
            ", ".join(ports) or None, board_id=", ".join(boards) or None))
        if not args.json:
            console.print(f"wrote --png {args.png}", highlight=False)
    return 0

