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
import csv
import dataclasses
import json
import math

from rich.table import Table

from snan_hil.calibration.board_io import BoardLimits, PulseLedger
from snan_hil.calibration.characterize import (CharacterizeConfig, characterize_cells,
                                               fit_measurement, validate_holdout)
from snan_hil.calibration.layout import Layout
from snan_hil.calibration.mapping import WeightMap
from snan_hil.common.errors import UserError
from snan_hil.crossbar_model.fitted import MODEL_FORMAT, LearningPulse
from snan_hil.files.atomicio import atomic_path, atomic_write_json
from snan_hil.files.outputs import csv_kind, json_kind, png_kind
from snan_hil.protocol.board import MEMRICORE
from snan_hil.tools.commands._board import (add_layout_option, add_png_option, add_result_options,
                                            board_session, layout_outputs, session_layout)
from snan_hil.tools.commands._history import open_recorder
from snan_hil.tools.commands._run import controlled, progress_to
from snan_hil.tools.commands._cells import parse_cell_list
from snan_hil.tools.commands._options import accept_negative_cells
from snan_hil.tools.commands.pulse import host_write_limit
from snan_hil.tools.console import console, progress_display, warn
from snan_hil.tools.device_figures import DEVICE_FIT_PNG_FORMAT, plot_device_fit
from snan_hil.tools.output_kinds import LAYOUT
from snan_hil.tools.ports import add_port_arguments
from snan_hil.tools.titles import figure_title

NAME = "characterize"
HELP = ("measure dG per SET/RESET learning pulse against G on the synapse cells (or chosen "
        "cells), fit the device model (aihwkit's names), store it in the board's history")

RESULT_FORMAT = "snan-hil-characterize/1"
SAMPLES_HEADER = "row,col,polarity,g_before_s,g_after_s"
RESULT_JSON = json_kind(RESULT_FORMAT, "a 'snan-hil characterize' result")
MODEL_JSON = json_kind(MODEL_FORMAT, "a snan-hil device model")
SAMPLES_CSV = csv_kind(SAMPLES_HEADER, "a 'snan-hil characterize' CSV")
FIT_PNG = png_kind(DEVICE_FIT_PNG_FORMAT, "a 'snan-hil characterize' figure")

#: what each parameter means, for the printed table
MEANING = {
    "dw_min": "mean |dlnG| of one pulse at g_ref (both directions)",
    "up_down": "up/down bias: SET step dw_min(1+up_down), RESET dw_min(1-up_down)",
    "dw_min_dtod": "device-to-device spread of a cell's mean step (relative)",
    "up_down_dtod": "device-to-device spread of up_down",
    "dw_min_std": "cycle-to-cycle spread of one step (relative; read noise removed)",
    "g_min_s": "lower bound of the chip curve (S; aihwkit w_min)",
    "g_max_s": "upper bound of the chip curve (S; aihwkit w_max)",
    "g_min_dtod": "spread of the cells' lower bounds (std of ln)",
    "g_max_dtod": "spread of the cells' upper bounds (std of ln)",
    "up_rate": "SET: dlnG = up_rate exp(up_slope (x - x_ref)) (x_max - x)",
    "up_slope": "SET rate change per unit ln G (the 1T1R divider)",
    "down_rate": "RESET: -dlnG = down_rate exp(down_slope (x - x_ref)) (x - x_min)",
    "down_slope": "RESET rate change per unit ln G",
    "g_ref_s": "where dw_min is stated (S; weight 0.5 of the map)",
    "read_noise": "relative std of one read during the measurement",
}


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


def _cells(args: argparse.Namespace, layout: Layout | None, rows: int,
           cols: int) -> list[tuple[int, int]]:
    which = str(args.cells).strip()
    if which == "synapses":
        if layout is not None:
            cells = [(s.row, s.col) for s in layout.synapses]
        else:
            cells = [(r, c) for r in range(15) for c in range(cols)]
        bad = set(layout.bad_cells) if layout is not None else set()
        cells = [c for c in cells if c not in bad]
    elif which == "all":
        bad = set(layout.bad_cells) if layout is not None else set()
        cells = [(r, c) for r in range(rows) for c in range(cols) if (r, c) not in bad]
    else:
        if not which.strip(" ;"):
            raise UserError("--cells: give synapses, all, or cells R,C;R,C")
        cells = parse_cell_list(which, "--cells", rows, cols)   # the one rule (_cells)
    if args.max_cells is not None:
        if args.max_cells < 1:
            raise UserError(f"--max-cells must be >= 1, got {args.max_cells}")
        cells = cells[:args.max_cells]
    return cells


def _config(args: argparse.Namespace, weight_map: WeightMap) -> CharacterizeConfig:
    try:
        pulse = LearningPulse(args.set_v, args.reset_v, args.width_us)
        return CharacterizeConfig(pulse=pulse, weight_map=weight_map, repeats=args.repeats,
                                  max_pulses_per_train=args.max_pulses)
    except ValueError as exc:
        raise UserError(f"characterize: {exc}") from None


def check_pulse_amplitudes(args: argparse.Namespace) -> None:
    """``--set-v`` / ``--reset-v`` against the read ceiling and the host's write limit
    (``--max-write-v``, else the board's), before any board is opened (UserError, one line)."""
    limit = host_write_limit(args)
    for opt, v in (("--set-v", args.set_v), ("--reset-v", args.reset_v)):
        if v <= MEMRICORE.max_read_v:
            raise UserError(f"{opt} {v:g} V does not switch a cell (reads are at up to "
                            f"{MEMRICORE.max_read_v} V); give a learning amplitude above it")
        if v > limit:
            raise UserError(f"{opt} {v:g} V is above the host's write limit {limit:g} V "
                            "(--max-write-v)")


def run(args: argparse.Namespace) -> int:
    if args.from_file is not None:
        from snan_hil.tools.commands._characterize_from import run_from_file
        return run_from_file(args)
    _board_defaults(args)
    _config(args, WeightMap())                         # options checked before the board
    check_pulse_amplitudes(args)
    if args.cells not in ("synapses", "all"):
        _cells(args, None, MEMRICORE.rows, MEMRICORE.cols)
    outs = layout_outputs(args)
    png = outs.file("--png", args.png, FIT_PNG) if args.png else None
    csv_path = outs.file("--csv", args.csv, SAMPLES_CSV) if args.csv else None
    model_path = outs.file("--model", args.model, MODEL_JSON) if args.model else None
    with board_session(outs, args) as session:
        info, history_path = session.info, session.files.history
        # the board's layout and read chain (a layout of another board refused)
        layout_path, layout, chain, source = session_layout(args, session)
        cells = _cells(args, layout, info.rows, info.cols)
        cfg = _config(args, layout.weight_map if layout is not None else WeightMap())
        touched = [s for s in (layout.synapses if layout is not None else [])
                   if (s.row, s.col) in set(cells) and s.weight is not None]
        if touched:
            outs.file("--layout", layout_path, LAYOUT, updates=True)
            warn(f"{len(touched)} cell(s) hold synapses of {layout_path}; the sweep changes "
                 "them, so the layout marks them stale until program-weights writes them again")
        board = session.client                    # reads resent after a lost reply
        ledger = PulseLedger()
        ledger.rebaseline(board)
        limits = dataclasses.replace(BoardLimits.for_board(info),
                                     max_write_v=host_write_limit(args, info))
        with open_recorder(args, history_path, NAME, session, config=cfg.to_dict()) as rec, \
                progress_display(transient=True, enabled=not args.json) as progress:
            try:
                # pause / stop from 'snan-hil watch' land between two pulses
                m = characterize_cells(controlled(board, rec), chain, cells, limits, ledger,
                                       cfg, progress=progress_to(progress, rec), observer=rec)
            finally:
                if touched and layout is not None:
                    for s in touched:
                        s.stale = "characterize: swept over the whole window"
                        s.ok = False
                    layout.save(layout_path)
            try:
                model = fit_measurement(m, meta={"board_id": info.board_id, "port": args.port,
                                                 "read_chain": source})
            except ValueError as exc:
                raise UserError(f"characterize: {exc}; check the cells (snan-hil cells test) "
                                "or choose others with --cells") from None
            held = _holdout(m.samples, model, args.holdout or 0)
            fw = ledger.firmware_delta(board)
            summary = {"cells": len(cells), "fitted": sum(1 for c in model.cells if c.ok),
                       "pulses": ledger.confirmed, "firmware_pulses": fw,
                       **model.parameters()}
            rec.add_device_model(model.to_dict(), info.board_id)
            rec.finish("complete", summary)
    result = {"format": RESULT_FORMAT, "board": {"board_id": info.board_id, "port": args.port},
              "read_chain": source, "config": cfg.to_dict(), "cells": [list(c) for c in cells],
              "pulses": ledger.confirmed, "firmware_pulses": fw,
              "pulses_match": None if fw is None else fw == ledger.host_pulses,
              "history": str(history_path) if history_path and rec.run_id else None,
              "model": model.to_dict(),
              "holdout": None if held is None else held.to_dict()}
    if model_path is not None:
        atomic_write_json(model_path, model.to_dict(), indent=1, allow_nan=False)
    if csv_path is not None:
        _write_csv(m.samples, str(csv_path))
    if png is not None:
        wm = cfg.weight_map
        plot_device_fit(model, m.samples, png, window_s=(wm.g_min_s, wm.g_max_s),
                        title=figure_title("device response at the learning pulse", info,
                                           args.port))
    if args.json:
        print(json.dumps(result, indent=1, allow_nan=False, default=_nan_none))
        return 0
    _print(model, ledger.confirmed, fw, len(cells), source)
    print_holdout(held, args.holdout or 0)
    for opt, path in (("--png", args.png), ("--csv", args.csv), ("--model", args.model)):
        if path:
            console.print(f"wrote {opt} {path}", highlight=False)
    if history_path and rec.run_id:
        console.print(f"model stored in {history_path} (run {rec.run_id})", highlight=False)
    return 0


def _board_defaults(args: argparse.Namespace) -> None:
    """On a board: the learning pulse's defaults where not given; --read-noise refused."""
    pulse = LearningPulse()
    for name in ("set_v", "reset_v", "width_us"):
        if getattr(args, name) is None:
            setattr(args, name, getattr(pulse, name))
    if args.read_noise is not None:
        raise UserError("--read-noise is for --from (a board's reads measure it)")


def _holdout(samples, model, every: int):
    """The held-out validation of ``--holdout N`` (None: off)."""
    if not every:
        return None
    if every < 2:
        raise UserError(f"--holdout must be >= 2 (every N-th train held out) or 0, got {every}")
    try:
        return validate_holdout(samples, model.pulse, g_ref_s=model.g_ref_s,
                                read_noise=model.read_noise, every=every)
    except ValueError as exc:
        warn(f"held-out validation skipped: {exc}")
        return None


def print_holdout(held, every: int) -> None:
    """The held-out validation's lines (nothing when it was off)."""
    if held is None:
        return
    console.print(
        f"held out every {_ordinal(every)} train: {held.n} pulses; |dlnG observed - "
        f"predicted| median {held.median_abs_sigma:.2f} read-noise sigma "
        f"({held.median_abs_sigma_delta:.2f} sigma of a dlnG, two reads; a perfect model: "
        f"{held.floor_sigma:.2f}, the stated noise alone), bias {held.bias_sigma:+.2f}; "
        f"the model's error on held-out means {held.binned_sigma:.2f} sigma ({held.bins} "
        f"groups of cell, polarity, G); sigma = {held.read_noise:.4g}", highlight=False)


def _ordinal(n: int) -> str:
    return f"{n}{'th' if 10 <= n % 100 <= 20 else {1: 'st', 2: 'nd', 3: 'rd'}.get(n % 10, 'th')}"


def _nan_none(v: object) -> object:
    return None if isinstance(v, float) and not math.isfinite(v) else str(v)


def _write_csv(samples, path: str) -> None:
    try:
        with atomic_path(path) as tmp, open(tmp, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(SAMPLES_HEADER.split(","))
            for s in samples:
                w.writerow([s.row, s.col, s.polarity.name, f"{s.g_before_s:.6g}",
                            f"{s.g_after_s:.6g}"])
    except OSError as exc:
        raise UserError(f"cannot write --csv {path}: {exc.strerror or exc}") from None


def print_model(model, *, cells_text: str) -> None:
    """The parameter table and the mean steps in siemens of ``model``."""
    p = model.pulse
    t = Table(title=f"device model at SET {p.set_v:g} V / RESET {p.reset_v:g} V, {p.width_us} us "
                    f"({cells_text}, {model.points} pulses)")
    t.add_column("parameter")
    t.add_column("value", justify="right")
    t.add_column("meaning")
    for k, v in model.parameters().items():
        text = f"{v * 1e6:.2f} uS" if k.endswith("_s") and math.isfinite(v) else f"{v:.4g}"
        t.add_row(k, text, MEANING.get(k, ""))
    console.print(t)
    from snan_hil.common.polarity import Polarity
    for polarity in (Polarity.SET, Polarity.RESET):
        steps = [model.mean_step_s(polarity, g) * 1e6 for g in (60e-6, 300e-6, 950e-6)]
        console.print(f"{polarity.name} mean step at 60 / 300 / 950 uS: "
                      + " / ".join(f"{s:+.2f}" for s in steps) + " uS", highlight=False)
    if model.aging is not None:
        a = model.aging
        console.print(f"wear: window loss {a.window_loss_per_cycle:.3g} per cycle, endurance "
                      f"{a.endurance_cycles:.3g} cycles ({a.wear_source})", highlight=False)
        console.print(f"drift: nu {a.drift_nu:.3g} ({a.drift_source})", highlight=False)


def _print(model, pulses: int, fw: int | None, n_cells: int, source: str | None) -> None:
    print_model(model, cells_text=f"{sum(1 for c in model.cells if c.ok)} of {n_cells} cells "
                                  "fitted")
    console.print(f"fit quality R^2: SET {model.r2_up:.3f}, RESET {model.r2_down:.3f} (of single "
                  f"noisy steps); {pulses} pulses, board counter "
                  f"{'unknown' if fw is None else fw}; reads via the {source}", highlight=False)
