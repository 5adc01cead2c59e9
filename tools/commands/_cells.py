"""Which cells a command works on: ``--cells R,C ...``, ``--cells-file FILE.csv`` or ``--all``
(plans, cell tests), and the cell-list files themselves (``cells screen`` writes them,
``program-weights --cells-only / --cells-avoid`` and ``--cells-file`` read them).

A cell-list file is CSV: a header line naming ``row`` and ``col`` columns (any others, such as
the screening's ``verdict`` or ``g_s``, are ignored), one cell per line; a file without a
header may give ``R,C`` per line. ``#`` starts a comment line. Every line has as many fields
as the header (two without one): a line with more or fewer is refused, naming it (``1,2,3``
is not the cell 1,2). UTF-8, with or without a byte-order mark (spreadsheets write one).

One rule for every command that takes cells (``plan``, ``cells test``, ``characterize``,
``read-cell``, ``pulse``, ``program-weights --cells-only/--cells-avoid``), kept here
(:func:`parse_cell_list`, :func:`one_cell`, :func:`read_cell_file`): a cell is ``R,C`` (bit
line, word line) inside the array; a list is cells separated by spaces or ``;``; a list or a
file with no cell, or naming a cell twice, is refused with one line (a repeated cell is
usually a typo, and pulsing it twice is never what a list means).
"""

from __future__ import annotations

import argparse
import csv
import io
import re
from collections.abc import Sequence
from pathlib import Path

from snan_hil.common.errors import UserError
from snan_hil.tools.commands._options import accept_negative_cells, parse_cell

__all__ = ["add_cell_selection", "cells_from_selection", "read_cell_file", "parse_cell_list",
           "one_cell", "unique_cells"]


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


def unique_cells(cells: Sequence[tuple[int, int]], what: str,
                 where: Sequence[str] | None = None) -> list[tuple[int, int]]:
    """``cells`` as a list, checked to be non-empty and to name each cell once (UserError,
    one line: ``what`` is the option (and file); ``where[k]`` says where cell ``k`` was
    given, e.g. "line 4")."""
    if not cells:
        raise UserError(f"{what}: no cells given; give at least one cell as R,C (or --all)")
    first: dict[tuple[int, int], int] = {}
    for k, cell in enumerate(cells):
        if cell in first:
            at = "" if where is None else f" ({where[first[cell]]} and {where[k]})"
            raise UserError(f"{what}: cell ({cell[0]},{cell[1]}) is named twice{at}; give "
                            "each cell once")
        first[cell] = k
    return list(cells)


def parse_cell_list(tokens: str | Sequence[str], option: str, rows: int | None,
                    cols: int | None) -> list[tuple[int, int]]:
    """Cells ``R,C`` separated by spaces or ``;`` (one text or the tokens of ``nargs``), in
    order; UserError (one line) for none, a bad spelling, a cell outside ``rows`` x ``cols``
    or a cell named twice (module docstring)."""
    texts = [tokens] if isinstance(tokens, str) else list(tokens)
    parts = [t for text in texts
             for t in re.sub(r"\s*,\s*", ",", str(text)).replace(";", " ").split() if t]
    return unique_cells([parse_cell(t, option, rows, cols) for t in parts], option)


def one_cell(text: str, option: str, rows: int | None, cols: int | None) -> tuple[int, int]:
    """The single cell of ``option`` (``--cell R,C``), by the rule of :func:`parse_cell_list`."""
    cells = parse_cell_list(text, option, rows, cols)
    if len(cells) != 1:
        raise UserError(f"{option} {text!r}: give one cell as ROW,COL, e.g. 3,5")
    return cells[0]


def read_cell_file(path: str | Path, option: str, rows: int, cols: int
                   ) -> list[tuple[int, int]]:
    """The cells of a cell-list file (module docstring), in order; UserError (one line
    naming the line) for a bad file, a file without cells, a cell outside the array or a
    cell listed twice."""
    p = Path(path).expanduser()
    try:
        text = p.read_text(encoding="utf-8-sig")          # a spreadsheet's byte-order mark
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
    where: list[str] = []
    if "row" in header and "col" in header:
        ir, ic = header.index("row"), header.index("col")
        body = lines[1:]
    elif all(h.lstrip("-").isdigit() for h in header[:2]) and len(header) >= 2:
        ir, ic = 0, 1
        body = lines
    else:
        raise UserError(f"{option} {p}: line {lines[0][0]}: expected a header with row and "
                        f"col columns (or R,C lines), got {lines[0][1].strip()!r}")
    width = len(header) if body is not lines else 2
    for n, line in body:
        fields = next(csv.reader(io.StringIO(line)))
        if len(fields) != width:
            expected = (f"the header's {width} fields ({lines[0][1].strip()})"
                        if body is not lines else "2 fields (row,col)")
            raise UserError(f"{option} {p}: line {n}: {len(fields)} field(s) where "
                            f"{expected} are expected, got {line.strip()!r}; give one cell "
                            "per line")
        text_cell = f"{fields[ir].strip()},{fields[ic].strip()}"
        cells.append(parse_cell(text_cell, f"{option} {p} line {n}:", rows, cols))
        where.append(f"line {n}")
    if not cells:
        raise UserError(f"{option} {p}: no cells in the file (a header only); give one cell "
                        "per line (row,col)")
    return unique_cells(cells, f"{option} {p}", where)


def cells_from_selection(args: argparse.Namespace, rows: int, cols: int, *,
                         bounded: bool = True) -> list[tuple[int, int]]:
    """The selected cells in order; UserError (one line) for none, a bad one or one named
    twice (:func:`parse_cell_list`). ``bounded=False``: cells of ``--cells`` are not checked
    against ``rows`` x ``cols`` here (a job over several boards checks them against each
    board's own array)."""
    if getattr(args, "all", False):
        return [(r, c) for r in range(rows) for c in range(cols)]
    if getattr(args, "cells_file", None):
        return read_cell_file(args.cells_file, "--cells-file", rows, cols)
    if args.cells is None:
        raise UserError("give the cells: --cells R,C [R,C ...], --cells-file FILE.csv or --all")
    if not [t for t in args.cells if t.strip(" ;")]:
        raise UserError("--cells: empty cell list; give at least one cell as R,C, or --all")
    return parse_cell_list(args.cells, "--cells", rows if bounded else None,
                           cols if bounded else None)
