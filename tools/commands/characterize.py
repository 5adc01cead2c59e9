"""``snan-hil characterize``: measure ΔG per SET / RESET pulse against G on the chip's cells at
the learning pulse, fit the compact device model and keep it in the board's history database
(:mod:`snan_hil.calibration.characterize`, :mod:`snan_hil.crossbar_model.fitted`; docs/learning.md).

Examples::

    snan-hil characterize --port emu --png fit.png
    snan-hil characterize --port emu --cells 0,0;0,1;5,3 --repeats 3 --model model.json
    snan-hil characterize --port /dev/ttyUSB0 --protocol legacy --max-cells 16
    snan-hil characterize --from lab-pulses.csv --model my-chip.json --png fit.png

The measured cells end at an end of the sweep: synapses of the board's layout measured here
are marked stale (``program-weights`` writes them again). ``--from FILE`` fits the model to
pulses measured elsewhere (a lab's pulse CSV, ``history --export pulses``, ``characterize
--csv``; :mod:`snan_hil.calibration.pulse_files`), no board opened.
"""

from __future__ import annotations

import argparse
import json
import math
import sqlite3
from pathlib import Path
from typing import Any


from snan_hil.calibration.characterize import (Characterization, CharacterizeJob,
                                               check_holdout)
from snan_hil.common.errors import UserError
from snan_hil.crossbar_model.fitted import LearningPulse
from snan_hil.files.atomicio import atomic_write_json
from snan_hil.protocol.board import MEMRICORE
from snan_hil.protocol.safety import requested_write_limit_v
from snan_hil.lab.runner import JobRun
from snan_hil.records.history import History, HistoryError
from snan_hil.tools.commands._board import (add_layout_option, add_png_option, add_result_options,
                                            plan_from_args)
from snan_hil.tools.commands._cells import parse_cell_list
from snan_hil.tools.commands._characterize_from import run_from_file
from snan_hil.tools.commands._characterize_out import (FIT_PNG, MODEL_JSON, SAMPLES_CSV,
                                                       print_holdout, print_model,
                                                       write_samples_csv)
from snan_hil.tools.commands._job import run_on_board
from snan_hil.tools.commands._options import accept_negative_cells
from snan_hil.tools.console import console, warn
from snan_hil.tools.device_figures import plot_device_fit
from snan_hil.tools.ports import add_port_arguments
from snan_hil.tools.titles import figure_title

NAME = "characterize"
HELP = ("measure dG per SET/RESET learning pulse against G on the synapse cells (or chosen "
        "cells), fit the device model (aihwkit's names), store it in the board's history")

RESULT_FORMAT = "snan-hil-characterize/1"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    accept_negative_cells(parser)
    add_port_arguments(parser)
    parser.add_argument("--cells", default="synapses", metavar="WHICH",
                        help="synapses (the cells of the board's layout; without a layout the "
                             "15x8 block of a 6x6 grid, rows 0-14), all (every cell), or a list "
                             "R,C;R,C;...")
    parser.add_argument("--max-cells", type=int, default=None, metavar="N",
                        help="measure only the first N of those cells (default: all of them)")
    pulse = LearningPulse()
    parser.add_argument("--set-v", type=float, default=None,
                        help=f"SET amplitude of the learning pulse, V (default {pulse.set_v:g}; "
                             "with --from: the file's commonest SET pulse)")
    parser.add_argument("--reset-v", type=float, default=None,
                        help=f"RESET amplitude of the learning pulse, V (default "
                             f"{pulse.reset_v:g}; with --from: the file's commonest)")
    parser.add_argument("--width-us", type=int, default=None,
                        help=f"width of the learning pulse, us (default {pulse.width_us}; with "
                             "--from: the file's commonest)")
    parser.add_argument("--repeats", type=int, default=2,
                        help="RESET-then-SET sweeps per cell")
    parser.add_argument("--max-pulses", type=int, default=250,
                        help="longest train of one polarity, pulses")
    add_layout_option(parser, "the board's layout: its read chain, weight map and synapse "
                      "cells (default: the port's layout if it exists)")
    add_png_option(parser, "draw dG against G with the fit, both polarities (default: none)")
    parser.add_argument("--csv", metavar="FILE", default=None,
                        help="write every measured pulse (row, col, polarity, G before/after; "
                             "default: none)")
    parser.add_argument("--model", metavar="FILE", default=None,
                        help="also write the fitted model as JSON (it is always stored in the "
                             "history database; default: none)")
    parser.add_argument("--from", dest="from_file", metavar="FILE", default=None,
                        help="fit the model to pulses measured elsewhere, no board: a lab's CSV "
                             "(cell,polarity,amplitude_v,width_us,g_before_s,g_after_s[,time_s]; "
                             "docs/learning.md), 'history --export pulses' or 'characterize "
                             "--csv' (default: none, measure on the board)")
    parser.add_argument("--holdout", type=int, default=None, metavar="N",
                        help="also fit on all but every N-th train (run of one polarity) of "
                             "each cell and print how the model predicts the held-out pulses "
                             "(default: 3 with --from, off on a board; 0: off)")
    parser.add_argument("--read-noise", type=float, default=None, metavar="REL",
                        help="with --from: the relative std of one read (default: estimated "
                             "from the steps' scatter, as the data hold no repeated reads)")
    add_result_options(parser, json_help="print the result (parameters, per-cell fits) as JSON")


def _cells(args: argparse.Namespace) -> str | list[tuple[int, int]]:
    """``--cells``: "synapses", "all", or the cells of a list (checked on the MemriCore
    array before the board; UserError, one line)."""
    which = str(args.cells).strip()
    if which in ("synapses", "all"):
        return which
    if not which.strip(" ;"):
        raise UserError("--cells: give synapses, all, or cells R,C;R,C")
    return parse_cell_list(which, "--cells", MEMRICORE.rows, MEMRICORE.cols)  # the one rule


def check_pulse_amplitudes(args: argparse.Namespace) -> None:
    """``--set-v`` / ``--reset-v`` against the read ceiling and the host's write limit
    (``--max-write-v``, else the board's), before any board is opened (UserError, one line)."""
    limit = requested_write_limit_v(MEMRICORE, args.max_write_v)
    for opt, v in (("--set-v", args.set_v), ("--reset-v", args.reset_v)):
        if v <= MEMRICORE.max_read_v:
            raise UserError(f"{opt} {v:g} V does not switch a cell (reads are at up to "
                            f"{MEMRICORE.max_read_v} V); give a learning amplitude above it")
        if v > limit:
            raise UserError(f"{opt} {v:g} V is above the host's write limit {limit:g} V "
                            "(--max-write-v)")


NAMES = {"set_v": "--set-v", "reset_v": "--reset-v", "cells": "--cells",
         "max_cells": "--max-cells", "holdout": "--holdout"}
"""The job's fields as this command's options (messages)."""


def run(args: argparse.Namespace) -> int:
    if args.from_file is not None:
        return run_from_file(args)                     # no board: a lab's pulse file
    job = _job(args)                                   # options checked before the board
    plan = plan_from_args(args)
    png = plan.outputs.file("--png", args.png, FIT_PNG) if args.png else None
    csv_path = plan.outputs.file("--csv", args.csv, SAMPLES_CSV) if args.csv else None
    model_path = plan.outputs.file("--model", args.model, MODEL_JSON) if args.model else None
    done = run_on_board(args, job, plan, transient=True)
    run, info = done.result, done.session.info
    stored = _store_model(done, run)
    if model_path is not None:
        atomic_write_json(model_path, run.model.to_dict(), indent=1, allow_nan=False)
    if csv_path is not None:
        write_samples_csv(run.measurement.samples, str(csv_path))
    if png is not None:
        wm = run.measurement.config.weight_map
        plot_device_fit(run.model, run.measurement.samples, png,
                        window_s=(wm.g_min_s, wm.g_max_s),
                        title=figure_title("device response at the learning pulse", info,
                                           args.port))
    if args.json:
        print(json.dumps(_result(run, args, info.board_id, stored), indent=1,
                         allow_nan=False, default=_nan_none))
        return 0
    _print(run.model, run.pulses, run.firmware_pulses, len(run.cells), run.read_chain)
    print_holdout(run.holdout, job.holdout)
    for opt, path in (("--png", args.png), ("--csv", args.csv), ("--model", args.model)):
        if path:
            console.print(f"wrote {opt} {path}", highlight=False)
    if stored is not None:
        console.print(f"model stored in {done.history} (run {done.history_run_id})",
                      highlight=False)
    return 0


def _store_model(done: JobRun[Characterization], run: Characterization) -> Path | None:
    """The fitted model into the board's history database with the run (its
    ``device_models`` table: ``learn`` finds it there); the database, None when the run is
    not recorded or the write failed (one warning line: the result is still printed)."""
    if done.history is None or done.history_run_id is None:
        return None
    try:
        with History.open(done.history, create=False) as db:
            db.add_device_model(done.history_run_id, run.model.to_dict(),
                                board_id=done.session.info.board_id)
    except (sqlite3.Error, OSError, HistoryError) as exc:
        warn(f"history database {done.history}: {exc}; the fitted model is not stored there "
             "(write it with --model)")
        return None
    return done.history


def _result(run: Characterization, args: argparse.Namespace, board_id: str | None,
            stored: Path | None) -> dict[str, Any]:
    fw = run.firmware_pulses
    return {"format": RESULT_FORMAT, "board": {"board_id": board_id, "port": args.port},
            "read_chain": run.read_chain, "config": run.measurement.config.to_dict(),
            "cells": [list(c) for c in run.cells], "pulses": run.pulses,
            "firmware_pulses": fw,
            "pulses_match": None if fw is None else fw == run.host_pulses,
            "history": str(stored) if stored is not None else None,
            "model": run.model.to_dict(),
            "holdout": None if run.holdout is None else run.holdout.to_dict()}


def _job(args: argparse.Namespace) -> CharacterizeJob:
    """The characterisation job of the options (the learning pulse's defaults where not
    given; checked without a board: one line)."""
    _board_defaults(args)
    try:
        pulse = LearningPulse(args.set_v, args.reset_v, args.width_us)
    except ValueError as exc:
        raise UserError(f"characterize: {exc}") from None
    check_pulse_amplitudes(args)
    if args.max_cells is not None and args.max_cells < 1:
        raise UserError(f"--max-cells must be >= 1, got {args.max_cells}")
    holdout = args.holdout or 0                        # off on a board unless asked for
    check_holdout(holdout, "--holdout")
    return CharacterizeJob(_cells(args), pulse=pulse, repeats=args.repeats,
                           max_pulses_per_train=args.max_pulses, max_cells=args.max_cells,
                           holdout=holdout, names=NAMES)


def _board_defaults(args: argparse.Namespace) -> None:
    """On a board: the learning pulse's defaults where not given; --read-noise refused."""
    pulse = LearningPulse()
    for name in ("set_v", "reset_v", "width_us"):
        if getattr(args, name) is None:
            setattr(args, name, getattr(pulse, name))
    if args.read_noise is not None:
        raise UserError("--read-noise is for --from (a board's reads measure it)")


def _nan_none(v: object) -> object:
    return None if isinstance(v, float) and not math.isfinite(v) else str(v)


def _print(model, pulses: int, fw: int | None, n_cells: int, source: str | None) -> None:
    print_model(model, cells_text=f"{sum(1 for c in model.cells if c.ok)} of {n_cells} cells "
                                  "fitted")
    console.print(f"fit quality R^2: SET {model.r2_up:.3f}, RESET {model.r2_down:.3f} (of single "
                  f"noisy steps); {pulses} pulses, board counter "
                  f"{'unknown' if fw is None else fw}; reads via the {source}", highlight=False)
