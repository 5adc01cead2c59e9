"""``snan-hil read-weights``: read the programmed synapses back into a weight matrix."""

from __future__ import annotations

import argparse
import json
from typing import Any

import numpy as np
from rich.table import Table

from snan_hil.files.atomicio import atomic_path
from snan_hil.calibration.readback import (READ_PATHS, ReadWeightsConfig, ReadWeightsJob,
                                           WeightsRead, weight_errors)
from snan_hil.tools.commands._board import (add_layout_option, add_result_options, file_use,
                                            plan_from_args)
from snan_hil.calibration.weights_io import load_weight_set
from snan_hil.common.errors import UserError
from snan_hil.tools.commands._job import run_on_board
from snan_hil.tools.commands._options import add_weight_set_option
from snan_hil.tools.console import console, warn_stale_synapses
from snan_hil.tools.ports import add_port_arguments

NAME = "read-weights"
HELP = "read the layout's cells back into a weight matrix and compare with the weights"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_port_arguments(parser)
    add_layout_option(parser, "layout JSON written by program-weights (default: the port's)")
    parser.add_argument("-o", "--output", default=None,
                        help="write the read weight matrix (N x N) to this .npy file "
                             "(default: not written)")
    parser.add_argument("--weights", default=None,
                        help="compare against this weights file (default: the weights the "
                             "layout was last programmed with)")
    add_weight_set_option(parser, help="weight set of --weights")
    parser.add_argument("--reads", type=int, default=4, help="reads averaged per cell")
    parser.add_argument("--path", choices=READ_PATHS, default="cell",
                        help="cell: READ_CELL per cell; column: spikes + column reads, as "
                             "the agent's hardware runs see them")
    add_result_options(parser, history=None)


def run(args: argparse.Namespace) -> int:
    if args.reads < 1:
        raise UserError(f"--reads must be >= 1, got {args.reads}")
    if args.output and not str(args.output).endswith(".npy"):
        raise UserError(f"-o {args.output}: the output must be a .npy file")
    reference = None
    if args.weights:                            # validated before any I/O
        weights, meta = load_weight_set(args.weights, args.set_index)
        reference = (weights, meta, args.weights)
    plan = plan_from_args(args, use=file_use(args, record=False), weights=args.weights)
    out = plan.outputs.file("-o", args.output, None) if args.output else None
    job = ReadWeightsJob(ReadWeightsConfig(args.reads, args.path), reference=reference)
    read = run_on_board(args, job, plan, transient=True).result
    warn_stale_synapses(read.layout, plan.files.layout)
    w, g, layout = read.weights, read.conductances_s, read.layout
    # The file is weights to program back: a cell read a little outside the mapping window
    # (read noise around a weight of exactly 0 or 1) is written at the window's edge, so
    # program-weights takes the file; the errors are of the reads as they are.
    clipped = int(np.count_nonzero((w < 0.0) | (w > 1.0)))
    if out is not None:
        with atomic_path(out, suffix=".tmp.npy") as tmp:
            np.save(tmp, np.clip(w, 0.0, 1.0))
    errors = weight_errors(w, read.reference, layout) if read.reference is not None else None
    if args.json:
        print(json.dumps({"output": args.output, "reference": read.source, "errors": errors,
                          "stale_synapses": read.stale, "clipped_to_window": clipped,
                          "g_min_s": float(g.min()), "g_max_s": float(g.max())}, indent=2))
        return 0
    _print(read, errors, clipped, args)
    return 0


def _print(read: WeightsRead, errors: dict[str, Any] | None, clipped: int,
           args: argparse.Namespace) -> None:
    layout, g = read.layout, read.conductances_s
    t = Table(title=f"read-weights: {layout.n_synapses} synapses, {args.reads} read(s) each, "
                    f"{args.path} path", show_header=False)
    t.add_column("quantity", style="bold")
    t.add_column("value", justify="right")
    t.add_row("conductance range read", f"{g.min() * 1e6:.1f} .. {g.max() * 1e6:.1f} uS")
    t.add_row("weight map", f"{layout.weight_map.g_min_s * 1e6:g} uS (w=0) .. "
                            f"{layout.weight_map.g_max_s * 1e6:g} uS (w=1)")
    if errors:
        t.add_row("compared with", str(read.source))
        t.add_row("mean |weight error|", f"{errors['mean_abs']:.4f}")
        t.add_row("median |weight error|", f"{errors['median_abs']:.4f}")
        t.add_row("max |weight error|", f"{errors['max_abs']:.4f} (synapse "
                                        f"{errors['worst']['pre']}->{errors['worst']['post']})")
        t.add_row("rms / bias", f"{errors['rms']:.4f} / {errors['bias']:+.4f}")
    else:
        t.add_row("compared with", "nothing (no --weights, layout holds no weights)")
    if args.output:
        t.add_row("written", str(args.output) + (
            f" ({clipped} weight(s) read outside [0, 1] written at the edge)" if clipped
            else ""))
    console.print(t)
