"""``snan-hil mac``: accuracy of the crossbar's column multiply against numpy (paper Fig. 10B).

Uses the weights programmed on the board (its layout), or programs them first (``--weights
FILE`` or ``--weights random``), applies ``--vectors`` random row-voltage vectors (at most the
read limit, 0.3 V) and compares each column's multiply-accumulate with the numpy reference of
the same voltages and the target conductances (:mod:`snan_hil.calibration.mac`). Writes
``mac.json``, ``mac.csv`` and ``mac.png`` (measured vs reference with the identity line, error
histogram) into ``--out``.

On the framed protocol every multiply is one READ_COLUMN; on ``--protocol legacy`` (no column
read) it is the sum of single-cell reads, and every output says so.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
from rich.table import Table

from snan_hil.common.version import __version__
from snan_hil.files.atomicio import atomic_path, atomic_write_json
from snan_hil.board.session import BoardSession
from snan_hil.calibration.mac import MacConfig, MacJob, MacResult, MacRun
from snan_hil.calibration.programmer import ProgramConfig, ProgramJob
from snan_hil.calibration.testing import grid_weights
from snan_hil.calibration.weights_io import load_weight_set
from snan_hil.common.errors import UserError
from snan_hil.protocol.board import MEMRICORE
from snan_hil.tools.commands._board import (add_layout_option, add_result_options, file_use,
                                            plan_from_args)
from snan_hil.tools.commands._job import run_on_board
from snan_hil.tools.commands._options import add_weight_set_option
from snan_hil.tools.console import console, warn_stale_synapses
from snan_hil.tools.output_kinds import MAC_CSV, MAC_CSV_HEADER, MAC_JSON, MAC_PNG
from snan_hil.tools.ports import add_port_arguments
from snan_hil.tools.titles import figure_title

NAME = "mac"
HELP = ("column multiply-accumulate accuracy vs numpy on the programmed weights (paper Fig. "
        "10B): scatter, error histogram, RMS / max error")

PAPER_FIG10B = ("paper Fig. 10B shows the board's multiplication results (blue dots) against "
                "the reference (orange line) without numbers in the text; the figure image is "
                "not in the paper's source (docs/bench.md)")


MAC = MacConfig()
"""The MAC run's defaults the options start from."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_port_arguments(parser)
    parser.add_argument("--vectors", type=int, default=MAC.vectors,
                        help="random row-voltage vectors; each multiplies every used column")
    parser.add_argument("--seed", type=int, default=MAC.seed, help="seed of the vectors (and of "
                                                            "--weights random)")
    parser.add_argument("--v-max", type=float, default=None,
                        help="largest row voltage, V (default: the board's read limit, "
                             f"{MEMRICORE.max_read_v} V)")
    parser.add_argument("--weights", metavar="FILE|random", default=None,
                        help="program these weights first (a weights file, or 'random': "
                             "uniform weights on a --grid; default: use the weights the "
                             "board's layout records as programmed)")
    add_weight_set_option(parser, help="weight set of a K x N x N --weights file")
    parser.add_argument("--grid", type=int, default=6,
                        help="grid side of --weights random (6: the paper's 120 synapses)")
    add_layout_option(parser, "the board's layout (default: the port's)")
    parser.add_argument("--out", default="mac-results", metavar="DIR",
                        help="folder for mac.json, mac.csv, mac.png")
    add_result_options(parser, json_help="print the summary as JSON")


def _weights(args: argparse.Namespace) -> tuple[np.ndarray, dict] | None:
    if args.weights is None:
        return None
    if args.weights == "random":
        if not 2 <= args.grid <= 6:
            raise UserError(f"--grid {args.grid}: give 2..6 (a 6x6 grid fills 15 of the 32 rows; "
                            "larger grids do not fit the 32x8 array)")
        w = grid_weights(args.grid, args.grid, seed=args.seed)
        return w, {"grid": [args.grid, args.grid], "path": "random", "seed": args.seed}
    return load_weight_set(args.weights, args.set_index)


def _weights_record(args: argparse.Namespace, weights: tuple[np.ndarray, dict] | None
                    ) -> dict[str, Any]:
    """What ``mac.json`` records of the weights: programmed here (``--weights FILE`` or
    ``random``, with the grid, seed and weight set) or those already on the board."""
    if weights is None:
        return {"source": "layout (weights already programmed)"}
    meta = weights[1]
    rec: dict[str, Any] = {"source": "random" if args.weights == "random" else "file",
                           "weights": args.weights}
    rec.update({k: meta.get(k) for k in ("path", "grid", "seed", "set_index") if k in meta})
    return rec


FIX = ("program weights first (snan-hil program-weights FILE --port ...), or give "
       "--weights FILE or --weights random")


def run(args: argparse.Namespace) -> int:
    cfg = _config(args)
    weights = _weights(args)
    programs = weights is not None
    plan = plan_from_args(args, use=file_use(args, updates_layout=programs,
                                             writes_report=programs,
                                             report_option="program report"),
                          weights=None if args.weights in (None, "random") else args.weights)
    folder = plan.outputs.folder("--out", args.out, files={
        "mac.json": MAC_JSON, "mac.csv": MAC_CSV, "mac.png": MAC_PNG})
    known = plan.files.layout
    if not programs and known is not None and not known.is_file():
        raise UserError(f"no layout for port {args.port} ({known}): {FIX}")
    with plan.open() as session:     # one connection: the programming, then the multiplies
        if weights is not None:
            pcfg = ProgramConfig().within(session.limits.max_write_v)
            run_on_board(args, ProgramJob(*weights, pcfg, cell_tests=False), session,
                         seed=args.seed)
        done = run_on_board(args, MacJob(cfg, hint=FIX, names={"v_max": "--v-max"}), session,
                            seed=args.seed)
    run = done.result
    warn_stale_synapses(run.layout, run.layout_path)
    summary = _write(folder, run, session, cfg, _weights_record(args, weights), args)
    if args.json:
        print(json.dumps({"summary": summary, "paper": PAPER_FIG10B,
                          "files": {k: str(folder / k) for k in ("mac.json", "mac.csv",
                                                                 "mac.png")}}, indent=1))
        return 0
    _print(summary, folder)
    return 0


def _write(folder: Path, run: MacRun, session: BoardSession, cfg: MacConfig,
           weights: dict[str, Any], args: argparse.Namespace) -> dict[str, Any]:
    """mac.json, mac.csv and mac.png into ``folder``; the run's summary."""
    folder.mkdir(parents=True, exist_ok=True)
    summary = run.result.summary()
    data = {"format": "snan-hil-mac/1", "version": __version__, "weights": weights,
            "board": session.identity.to_dict(port=args.port, protocol=args.protocol),
            "session": session.snapshot(),
            "config": cfg.to_dict(), "layout": str(run.layout_path), "summary": summary,
            "stale_synapses": run.stale,
            "paper": PAPER_FIG10B, "samples": [s.__dict__ for s in run.result.samples]}
    atomic_write_json(folder / "mac.json", data, indent=1, allow_nan=False)
    _write_csv(run.result, folder / "mac.csv")
    from snan_hil.tools.bench_figures import plot_mac
    plot_mac(run.result, folder / "mac.png",
             title=figure_title(f"column multiply vs numpy ({args.vectors} vectors, seed "
                                f"{args.seed})", session.info, args.port))
    return summary


def _config(args: argparse.Namespace) -> MacConfig:
    """The run's settings from the options (UserError, one line, before the board)."""
    step = max(MEMRICORE.dac_volts(1), MEMRICORE.write_dac_volts(1))
    if args.v_max is not None and not (math.isfinite(args.v_max) and args.v_max >= step):
        raise UserError(f"--v-max {args.v_max:g} V is below one DAC step ({step * 1e3:.2f} mV): "
                        f"the row voltages would all be 0 V; give {step:.4f}.."
                        f"{MEMRICORE.max_read_v:g} V")
    cfg = MacConfig(vectors=args.vectors, seed=args.seed, v_max_v=args.v_max)
    if cfg.v_max_v is not None and cfg.v_max_v > MEMRICORE.max_read_v:
        raise UserError(f"--v-max {cfg.v_max_v:g} V is above the read limit "
                        f"{MEMRICORE.max_read_v:g} V: higher row voltages could change the "
                        "cells")
    return cfg


def _write_csv(result: MacResult, path: Path) -> None:
    err = result.errors_pct("reference")
    err_rb = result.errors_pct("readback")
    with atomic_path(path) as tmp, open(tmp, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(MAC_CSV_HEADER.split(","))
        for s, e, e2 in zip(result.samples, err, err_rb):
            w.writerow([s.vector, s.column, s.rows, f"{s.measured_a:.6e}", f"{s.reference_a:.6e}",
                        f"{s.readback_a:.6e}", f"{e:.5f}", f"{e2:.5f}",
                        "" if s.adc is None else s.adc, int(s.scaled), int(s.saturated)])


def _print(s: dict, folder: Path) -> None:
    t = Table(title=f"column multiply vs numpy: {s['method']}", show_header=False)
    t.add_column("quantity", style="bold")
    t.add_column("value", justify="right")
    rows = [
        ("multiplies (vectors x columns)", s["samples"]),
        ("programmed cells used", s["cells"]),
        ("full scale (column ADC range)", f"{s['full_scale_a'] * 1e3:.3f} mA"),
        ("largest row voltage", f"{s['v_max_v']:.4f} V"),
        ("RMS error vs target G", f"{s['rms_error_pct_fs']:.3f} % FS"),
        ("max |error| vs target G", f"{s['max_error_pct_fs']:.3f} % FS"),
        ("mean error vs target G", f"{s['mean_error_pct_fs']:+.3f} % FS"),
        ("RMS error vs read-back G", f"{s['rms_error_pct_fs_readback']:.3f} % FS"),
        ("max |error| vs read-back G", f"{s['max_error_pct_fs_readback']:.3f} % FS"),
        ("vectors scaled to stay in range", s["scaled"]),
        ("saturated reads", s["saturated"]),
    ]
    for k, v in rows:
        t.add_row(k, str(v))
    console.print(t)
    console.print(PAPER_FIG10B, highlight=False)
    console.print(f"wrote {folder / 'mac.json'}, mac.csv, mac.png", highlight=False)
