"""``snan-hil retention``: repeated reads of the programmed cells; drift per cell (Fig. 10A)."""

from __future__ import annotations

import argparse
import json
import math

from rich.table import Table

from snan_hil.files.atomicio import atomic_write_json
from snan_hil.calibration.observer import CellEvent
from snan_hil.calibration.readback import (READ_PATHS, check_read_path, read_series,
                                           retention_stats, summarize_retention)
from snan_hil.protocol.client import BoardClient
from snan_hil.tools.bench_figures import plot_retention
from snan_hil.calibration.layout import load_session_layout
from snan_hil.tools.commands._board import (add_layout_option, add_png_option, add_result_options,
                                            board_session, layout_outputs)
from snan_hil.common.errors import UserError
from snan_hil.tools.console import console, progress_display
from snan_hil.tools.commands._history import open_recorder
from snan_hil.tools.commands._run import controlled, progress_to
from snan_hil.tools.output_kinds import RETENTION, RETENTION_FORMAT, RETENTION_PNG
from snan_hil.tools.ports import add_port_arguments
from snan_hil.tools.resources import check_memory
from snan_hil.tools.titles import figure_title

NAME = "retention"
HELP = "read the programmed cells many times and print the drift of each cell"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_port_arguments(parser)
    add_layout_option(parser, "layout JSON written by program-weights (default: the port's)")
    parser.add_argument("--reads", type=int, default=10000, help="read cycles per cell")
    parser.add_argument("--path", choices=READ_PATHS, default="column",
                        help="column: one spike per row + column reads, many cycles per "
                             "request (fast); cell: one READ_CELL per read")
    parser.add_argument("--cells", type=int, default=None,
                        help="only the first N synapses of the layout (default: all)")
    parser.add_argument("--z-limit", type=float, default=4.0,
                        help="a drift larger than the read noise is still 'stable' if below "
                             "this many standard errors")
    parser.add_argument("-o", "--output", default=None,
                        help="write per-cell results (JSON; default: not written)")
    add_png_option(parser, "draw the weights of sample cells over the reads with their "
                           "read-noise band (the paper's Fig. 10A; default: none)")
    add_result_options(parser, history="cells")


def run(args: argparse.Namespace) -> int:
    if args.reads < 2:
        raise UserError(f"--reads must be >= 2, got {args.reads}")
    if args.cells is not None and args.cells < 1:
        raise UserError(f"--cells must be >= 1, got {args.cells}")
    if not math.isfinite(args.z_limit) or args.z_limit <= 0:
        raise UserError(f"--z-limit must be a positive number of standard errors, got "
                        f"{args.z_limit:g}")
    if args.protocol == "legacy" and args.path == "column":
        raise UserError("--path column needs SPIKE_BATCH, which the legacy protocol lacks; "
                        "give --path cell")
    outs = layout_outputs(args)
    output = outs.file("-o", args.output, RETENTION) if args.output else None
    png = outs.file("--png", args.png, RETENTION_PNG) if args.png else None
    with board_session(outs, args) as session:
        client, info = session.client, session.info
        layout = load_session_layout(session)
        check_read_path(client, args.path)          # before anything is recorded
        if args.cells is not None:
            layout.synapses = layout.synapses[:args.cells]
        # the series is float64[reads, cells], held in memory: checked before any read
        check_memory(8 * args.reads * max(1, len(layout.synapses)),
                     f"{args.reads} reads of {len(layout.synapses)} cells",
                     "give fewer --reads (or --cells)")
        with open_recorder(args, session.files.history, "retention", session,
                           config={"reads": args.reads, "path": args.path,
                                   "z_limit": args.z_limit, "cells": args.cells}) as rec:
            t0 = _clock(client)
            with progress_display(enabled=not args.json) as progress:
                # pause / stop from 'snan-hil watch' land between two read requests
                series = read_series(controlled(client, rec), layout, args.reads, args.path,
                                     progress=progress_to(progress, rec))
            cells = retention_stats(series, layout, z_limit=args.z_limit)
            t1 = _clock(client)
            summary = summarize_retention(cells)
            summary["reads"] = args.reads
            summary["path"] = args.path
            summary["virtual_s"] = None if t0 is None or t1 is None else (t1 - t0) * 1e-6
            rec.on_cells([CellEvent(c.row, c.col, "stable" if c.stable else "unstable",
                                    c.mean_s, target_s=s.target_s, detail=c.to_dict())
                          for c, s in zip(cells, layout.synapses)])
            rec.finish("complete", summary)
    if png is not None:
        weights = layout.weight_map.weight(series, clip=False)
        plot_retention(weights, [s.weight for s in layout.synapses],
                       [f"({s.row},{s.col})" for s in layout.synapses], png,
                       title=figure_title(f"weights held over {args.reads} reads "
                                          f"({args.path} path)", info, args.port))
    data = {"format": RETENTION_FORMAT, "summary": summary,
            "cells": [c.to_dict() for c in cells]}
    if output is not None:
        atomic_write_json(output, data, indent=1, allow_nan=False)
    if args.json:
        print(json.dumps(data, indent=1))
    else:
        t = Table(title=f"retention: {args.reads} reads per cell ({args.path} path)")
        for col in ("synapse", "cell", "mean uS", "noise %", "drift %", "z", "stable"):
            t.add_column(col, justify="right")
        for c in cells:
            t.add_row(f"{c.pre}->{c.post}", f"({c.row},{c.col})", f"{c.mean_s * 1e6:.2f}",
                      f"{100 * c.noise_rel:.3f}", f"{100 * c.drift_rel:+.3f}",
                      f"{c.drift_z:+.1f}", "yes" if c.stable else "[red]NO[/red]")
        console.print(t)
        console.print(f"{summary['stable']} of {summary['cells']} cells stable; max |drift| "
                      f"{100 * (summary['max_abs_drift_rel'] or 0):.3f} %, median read noise "
                      f"{100 * (summary['median_noise_rel'] or 0):.3f} %"
                      + ("" if summary["virtual_s"] is None
                         else f"; board time {summary['virtual_s']:.1f} s"))
        if args.png:
            console.print(f"wrote --png {args.png}", highlight=False)
    return 0 if summary["stable"] == summary["cells"] else 1


def _clock(client: BoardClient) -> int | None:
    try:
        return int(client.clock().time_us)
    except UserError:   # CLOCK is optional (legacy boards: UnsupportedError)
        return None
