"""``snan-hil map``: read every cell of the crossbar and show the conductance map.

ADC codes become conductances through the read chain of
:class:`~snan_hil.calibration.readchain.ReadChain` (the board's constants and formulas, plus the
calibration's fitted offsets and gain when a layout holds one), the same conversion every
calibrated read uses, so ``map`` and write-and-verify / ``read-weights`` agree on a cell.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
from typing import TYPE_CHECKING, Any

import numpy as np
from rich.table import Table

from snan_hil.common.version import __version__
from snan_hil.files.atomicio import atomic_path
from snan_hil.board.session import BoardSession
from snan_hil.calibration.cellmap import CellMap, MapConfig, MapJob
from snan_hil.common.errors import UserError
from snan_hil.protocol.board import MEMRICORE
from snan_hil.host.plots import pyplot
from snan_hil.files.outputs import png_metadata
from snan_hil.tools.commands._board import (add_layout_option, add_png_option, add_result_options,
                                            plan_from_args)
from snan_hil.tools.commands._job import run_on_board
from snan_hil.tools.console import console
from snan_hil.tools.output_kinds import MAP_CSV, MAP_CSV_HEADER, MAP_PNG, MAP_PNG_FORMAT
from snan_hil.tools.ports import add_port_arguments
from snan_hil.tools.titles import figure_title

if TYPE_CHECKING:
    from rich.table import Table

NAME = "map"
HELP = "read all cells through the board protocol and print the conductance map (log-shaded)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_port_arguments(parser)
    parser.add_argument("--read-code", type=int, default=None,
                        help="DAC code of the read voltage (default: the board's read_code "
                             f"from INFO, {MEMRICORE.read_code} = {MEMRICORE.v_read_v:.4f} V on "
                             "MemriCore)")
    add_layout_option(parser, "convert with the calibrated read chain of this layout JSON "
                      "(default: the port's layout if it exists, else the board's nominal "
                      "constants from INFO)")
    parser.add_argument("--csv", metavar="FILE", default=None,
                        help="also write row,col,adc,resistance_ohm,conductance_s per cell "
                             "(default: no CSV)")
    add_png_option(parser, "also write the map as an image (needs matplotlib; default: no image)")
    add_result_options(parser, json_help="print the map as JSON (ADC codes, resistances, "
                                         "conductances) instead of the table", history="cells")


def _shade(g: float, lo: float, hi: float) -> str:
    """Background colour on a log scale from dark blue (lo) to yellow (hi)."""
    if g <= 0 or not math.isfinite(g):
        return "on grey15"
    t = 0.0 if hi <= lo else (math.log10(g) - lo) / (hi - lo)
    t = min(max(t, 0.0), 1.0)
    # A short viridis-like ramp.
    stops = [(68, 1, 84), (59, 82, 139), (33, 145, 140), (94, 201, 98), (253, 231, 37)]
    x = t * (len(stops) - 1)
    i = min(int(x), len(stops) - 2)
    f = x - i
    r, gg, b = (round(a + (c - a) * f) for a, c in zip(stops[i], stops[i + 1]))
    fg = "black" if t > 0.55 else "white"
    return f"{fg} on rgb({r},{gg},{b})"


def render_table(cmap: CellMap, title: str | None = None) -> Table:
    """A rich Table of conductances in uS, log-shaded per cell (``title`` above it: board,
    port, date)."""
    g = cmap.conductance()
    finite = g[(g > 0) & np.isfinite(g)]
    lo, hi = (math.log10(finite.min()), math.log10(finite.max())) if finite.size else (0, 1)
    head = f"{title}\n" if title else ""
    table = Table(title=f"{head}conductance (uS) read at {cmap.read_volts:.3f} V; rows = bit "
                        "lines, columns = word lines", show_lines=False, pad_edge=False)
    table.add_column("row", justify="right", style="bold")
    for col in range(g.shape[1]):
        table.add_column(f"WL{col}", justify="right")
    full = cmap.chain.adc_full_scale_code
    for row in range(g.shape[0]):
        cells = []
        for col in range(g.shape[1]):
            value = g[row, col]
            if cmap.adc[row, col] >= full:
                text = "sat"
            elif value <= 0:
                text = "open"
            else:
                us = value * 1e6
                text = f"{us:.1f}" if us < 100 else f"{us:.0f}"
            cells.append(f"[{_shade(value, lo, hi)}]{text:>6}[/]")
        table.add_row(str(row), *cells)
    return table


def write_csv(cmap: CellMap, path: str) -> None:
    r, g = cmap.resistance(), cmap.conductance()
    try:
        with atomic_path(path) as tmp, open(tmp, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(MAP_CSV_HEADER.split(","))
            for row in range(r.shape[0]):
                for col in range(r.shape[1]):
                    w.writerow([row, col, int(cmap.adc[row, col]), f"{r[row, col]:.6g}",
                                f"{g[row, col]:.6g}"])
    except OSError as exc:
        raise UserError(f"cannot write --csv {path}: {exc.strerror or exc}") from None


def write_png(cmap: CellMap, path: str, title: str = "conductance map") -> None:
    plt = pyplot("--png needs matplotlib")
    from matplotlib.colors import LogNorm
    g = cmap.conductance() * 1e6
    masked = np.ma.masked_where(~(g > 0) | ~np.isfinite(g), g)
    fig, ax = plt.subplots(figsize=(4, 9))
    im = ax.imshow(masked, aspect="auto", cmap="viridis", norm=LogNorm())
    ax.set_xticks(range(g.shape[1]))
    ax.set_xlabel("word line (column)")
    ax.set_ylabel("bit line (row)")
    ax.set_title(title, fontsize=7, wrap=True)
    fig.colorbar(im, ax=ax, label="conductance (uS, log scale; white: open cell)")
    fig.tight_layout()
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=120, format="png", metadata=png_metadata(MAP_PNG_FORMAT))
    except OSError as exc:
        raise UserError(f"cannot write --png {path}: {exc.strerror or exc}") from None
    finally:
        plt.close(fig)


NAMES = {"read_code": "--read-code"}
"""The job's fields as this command's options (messages)."""


def run(args: argparse.Namespace) -> int:
    if args.read_code is not None and args.read_code < 1:
        raise UserError(f"--read-code {args.read_code}: a read needs a DAC code of at least 1 "
                        f"(a 0 V read sees no current); give 1..the board's read limit "
                        f"({MEMRICORE.max_read_code} on MemriCore), or leave it out for the "
                        "board's read code")
    plan = plan_from_args(args)
    csv_path = plan.outputs.file("--csv", args.csv, MAP_CSV) if args.csv else None
    png_path = plan.outputs.file("--png", args.png, MAP_PNG) if args.png else None
    done = run_on_board(args, MapJob(MapConfig(args.read_code), names=NAMES), plan,
                        transient=True)
    cmap, session = done.result, done.session
    title = figure_title("conductance map", session.info, args.port)
    if csv_path is not None:
        write_csv(cmap, str(csv_path))
    if png_path is not None:
        write_png(cmap, str(png_path), title)
    if args.json:
        print(json.dumps(map_json(cmap, session, title), allow_nan=False))
        return 0
    _print(cmap, title, args)
    return 0


def _print(cmap: CellMap, title: str, args: argparse.Namespace) -> None:
    console.print(render_table(cmap, title))
    console.print(f"converted with the {cmap.source}", highlight=False)
    g = cmap.conductance()
    ok = g[(g > 0) & np.isfinite(g)]
    if ok.size:
        console.print(f"{ok.size} readable cells: median {np.median(ok) * 1e6:.1f} uS "
                      f"({1 / np.median(ok):.0f} Ohm incl. transistor), range "
                      f"{ok.min() * 1e6:.1f}..{ok.max() * 1e6:.1f} uS", highlight=False)
    for path in (args.csv, args.png):
        if path:
            console.print(f"wrote {path}", highlight=False)


def map_json(cmap: CellMap, session: BoardSession, title: str) -> dict[str, Any]:
    """The map as a JSON-able dict: matrices [row][col] of ADC codes, resistance (Ohm, null
    for an open cell) and conductance (S); the board's session snapshot."""
    r = cmap.resistance()
    return {"format": "snan-hil-map/1", "version": __version__, "title": title,
            "board": session.identity.to_dict(port=session.port),
            "session": session.snapshot(),
            "read_code": cmap.read_code, "read_v": cmap.read_volts, "converted_with": cmap.source,
            "rows": int(cmap.adc.shape[0]), "cols": int(cmap.adc.shape[1]),
            "summary": cmap.summary(), "adc": cmap.adc.tolist(),
            "resistance_ohm": [[None if not math.isfinite(x) else float(x) for x in row]
                               for row in r],
            "conductance_s": cmap.conductance().tolist()}
