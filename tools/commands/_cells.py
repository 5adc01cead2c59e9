"""Which cells a command works on: ``--cells R,C ...``, ``--cells-file FILE.csv`` or ``--all``
(plans, cell tests), and the cell-list files themselves (``cells screen`` writes them,
``program-weights --cells-only / --cells-avoid`` and ``--cells-file`` read them).

A cell-list file is CSV: a header line naming ``row`` and ``col`` columns (any others, such as
the screening's ``verdict`` or ``g_s``, are ignored), one cell per line; a file without a
header may give ``R,C`` per line. ``#`` starts a comment line.
"""

from __future__ import annotations

import argparse
import csv
import io
from pathlib import Path

from snan_hil.common.errors import UserError
from snan_hil.tools.commands._options import accept_negative_cells, parse_cell

__all__ = ["add_cell_selection", "cells_from_selection", "read_cell_file"]


def add_cell_selection(parser: argparse.ArgumentParser, what: str = "the cells") -> None:
    accept_negative_cells(parser)
    which = parser.add_mutually_exclusive_group()
    which.add_argument("--cells", nargs="*", metavar="R,C", default=None,
                       help=f"{what}, e.g. --cells 0,0 3,5 (default: none; give --cells, "
                            "--cells-file or --all)")
    which.add_argument("--cells-file", metavar="FILE.csv", default=None,
                       help="the cells listed in a CSV file with row,col columns (e.g. the "
                            "good list of 'cells screen')")
    which.add_argument("--all", action="store_true", help="every cell of the array")


def read_cell_file(path: str | Path, option: str, rows: int, cols: int
                   ) -> list[tuple[int, int]]:
    """The cells of a cell-list file (module docstring), in order, duplicates dropped;
    UserError (one line naming the line) for a bad file or a cell outside the array."""
    p = Path(path).expanduser()
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise UserError(f"{option} {p}: no such file") from None
    except IsADirectoryError:
        raise UserError(f"{option} {p}: is a folder; give a CSV file of cells") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise UserError(f"{option} {p}: cannot read it "
                        f"({getattr(exc, 'strerror', None) or exc})") from None
    lines = [(n, line) for n, line in enumerate(text.splitlines(), 1)
             if line.strip() and not line.lstrip().startswith("#")]
    if not lines:
        raise UserError(f"{option} {p}: no cells in the file; give one cell per line (row,col)")
    first = next(csv.reader(io.StringIO(lines[0][1])))
    header = [h.strip().lower() for h in first]
    cells: list[tuple[int, int]] = []
    if "row" in header and "col" in header:
        ir, ic = header.index("row"), header.index("col")
        body = lines[1:]
    elif all(h.lstrip("-").isdigit() for h in header[:2]) and len(header) >= 2:
        ir, ic = 0, 1
        body = lines
    else:
        raise UserError(f"{option} {p}: line {lines[0][0]}: expected a header with row and "
                        f"col columns (or R,C lines), got {lines[0][1].strip()!r}")
    for n, line in body:
        fields = next(csv.reader(io.StringIO(line)))
        try:
            text_cell = f"{fields[ir].strip()},{fields[ic].strip()}"
        except IndexError:
            raise UserError(f"{option} {p}: line {n}: expected row and col, got "
                            f"{line.strip()!r}") from None
        cells.append(parse_cell(text_cell, f"{option} {p} line {n}:", rows, cols))
    return list(dict.fromkeys(cells))


def cells_from_selection(args: argparse.Namespace, rows: int, cols: int
                         ) -> list[tuple[int, int]]:
    """The selected cells in order, duplicates dropped; UserError for none or a bad one."""
    if getattr(args, "all", False):
        return [(r, c) for r in range(rows) for c in range(cols)]
    if getattr(args, "cells_file", None):
        return read_cell_file(args.cells_file, "--cells-file", rows, cols)
    if args.cells is None:
        raise UserError("give the cells: --cells R,C [R,C ...], --cells-file FILE.csv or --all")
    if not [t for t in args.cells if t.strip()]:
        raise UserError("--cells: empty cell list; give at least one cell as R,C, or --all")
    cells = [parse_cell(t, "--cells", rows, cols) for t in args.cells if t.strip()]
    return list(dict.fromkeys(cells))
