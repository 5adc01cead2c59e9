"""``snan-hil program-weights``: two-stage write-and-verify of a weight matrix into the crossbar."""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path
from typing import Any

from rich.table import Table

from snan_hil.calibration.mapping import DEFAULT_G_MAX_S, DEFAULT_G_MIN_S, WeightMap
from snan_hil.calibration.observer import TraceCollector
from snan_hil.calibration.programmer import CellChoice, ProgramConfig, ProgramJob
from snan_hil.calibration.weights_io import load_weight_set
from snan_hil.calibration.wv import WVConfig
from snan_hil.common.errors import UserError
from snan_hil.protocol.safety import requested_write_limit_v
from snan_hil.tools.commands._board import file_use, plan_from_args
from snan_hil.tools.commands._history import add_history_arguments
from snan_hil.tools.commands._job import run_on_board
from snan_hil.tools.commands._options import add_weight_set_option
from snan_hil.protocol.board import MEMRICORE
from snan_hil.tools.console import console
from snan_hil.tools.output_kinds import PROGRAM_TRACE, add_force_option
from snan_hil.tools.ports import add_port_arguments
from snan_hil.tools.titles import figure_title

NAME = "program-weights"
HELP = "program a weight matrix into the crossbar (two-stage write-and-verify, paper's method)"


WV = WVConfig()
"""The write-and-verify defaults the options start from."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("weights", help="weights.npy (N x N or K x N x N) or .npz from "
                                        "'snan-hil train'")
    add_weight_set_option(parser, help="which weight set of a K x N x N stack or .npz")
    add_port_arguments(parser)
    parser.add_argument("--layout", default=None,
                        help="layout JSON (default: next to the emulator's chip file for "
                             "--port emu, else ~/.local/share/snan-hil/layouts/BOARD-ID.json, "
                             "keyed by the board and chip identity from INFO)")
    parser.add_argument("--report", default=None,
                        help="report JSON (default: LAYOUT-STEM.program-report.json)")
    parser.add_argument("--fresh-layout", action="store_true",
                        help="place the synapses afresh, ignoring an existing layout file")
    parser.add_argument("--g-min-us", type=float, default=DEFAULT_G_MIN_S * 1e6,
                        help="cell conductance of weight 0, uS")
    parser.add_argument("--g-max-us", type=float, default=DEFAULT_G_MAX_S * 1e6,
                        help="cell conductance of weight 1, uS")
    parser.add_argument("--tolerance", type=float, default=WV.tolerance,
                        help="stage-1 window, relative (the paper: 0.10)")
    parser.add_argument("--v-max", type=float, default=None,
                        help=f"largest write amplitude, V (default: {WV.v_max}, or the host's "
                             "--max-write-v when lower; at most the board's limit)")
    parser.add_argument("--width-us", type=int, default=WV.width_us,
                        help="write pulse width, us")
    parser.add_argument("--max-pulses-stage1", type=int, default=WV.max_pulses_stage1,
                        help="pulse budget of stage 1 per cell and round")
    parser.add_argument("--max-pulses-stage2", type=int, default=WV.max_pulses_stage2,
                        help="pulse budget of stage 2 per cell and round")
    parser.add_argument("--no-spares", action="store_true",
                        help="do not move failing synapses to spare rows")
    parser.add_argument("--no-screen", action="store_true",
                        help="skip the read of all cells that flags stuck cells")
    parser.add_argument("--no-calibrate", action="store_true",
                        help="keep the stored (or nominal) read-chain calibration")
    parser.add_argument("--trace", metavar="FILE.png", default=None,
                        help="also draw the conductance of sample cells against pulse number "
                             "with the stage-1 window and the stage-2 target (the paper's Fig. "
                             "10A; default: no figure)")
    parser.add_argument("--no-cell-tests", action="store_true",
                        help="do not use the cell classes of 'snan-hil cells test' from the "
                             "history database for spare selection")
    which = parser.add_mutually_exclusive_group()
    which.add_argument("--cells-only", metavar="FILE.csv", default=None,
                       help="place synapses only on the cells of this cell list (e.g. the "
                            "--good-csv of 'cells test' with user criteria); the others count "
                            "as bad for this run (default: every cell)")
    which.add_argument("--cells-avoid", metavar="FILE.csv", default=None,
                       help="keep synapses off the cells of this cell list (e.g. --bad-csv of "
                            "'cells test') for this run (default: none)")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    add_history_arguments(parser)
    add_force_option(parser)


def _config(args: argparse.Namespace) -> ProgramConfig:
    """The run's settings from the options (ranges an option must keep whatever the board;
    the write amplitude meets the board's and the host's limits once, after HELLO, in
    :meth:`~snan_hil.board.session.BoardSession.check_write_amplitude`)."""
    if not 0 < args.tolerance < 1:
        raise UserError(f"--tolerance must be in (0, 1), got {args.tolerance}")
    if args.v_max is None:                # a lowered host limit lowers the default with it
        args.v_max = min(WV.v_max, requested_write_limit_v(MEMRICORE, args.max_write_v))
    if not WV.v_threshold < args.v_max <= MEMRICORE.write_dac_vref_v:
        raise UserError(f"--v-max must be above {WV.v_threshold} V (no change below) and at "
                        f"most the write DAC's {MEMRICORE.write_dac_vref_v} V, got {args.v_max}")
    if args.width_us < 1 or args.max_pulses_stage1 < 1 or args.max_pulses_stage2 < 1:
        raise UserError("--width-us and the pulse budgets must be >= 1")
    wm = WeightMap(args.g_min_us * 1e-6, args.g_max_us * 1e-6)
    try:
        wv = dataclasses.replace(
            WV, tolerance=args.tolerance,
            fine_tolerance=min(WV.fine_tolerance, args.tolerance / 2), v_max=args.v_max,
            fine_v_max=min(WV.fine_v_max, args.v_max), width_us=args.width_us,
            v_floor=min(WV.v_floor, args.v_max), max_pulses_stage1=args.max_pulses_stage1,
            max_pulses_stage2=args.max_pulses_stage2)
    except ValueError as exc:
        raise UserError(f"inconsistent write-and-verify options: {exc}") from None
    return ProgramConfig(wv=wv, weight_map=wm, spares=not args.no_spares,
                         screen=not args.no_screen, calibrate=not args.no_calibrate,
                         fresh_layout=args.fresh_layout)


def names(args: argparse.Namespace) -> dict[str, str]:
    """The job's fields as this command's options (messages)."""
    return {"v_max": "--v-max",
            "cells": "--cells-avoid" if getattr(args, "cells_avoid", None) else "--cells-only"}


def run(args: argparse.Namespace) -> int:
    weights, meta = load_weight_set(args.weights, args.set_index)   # validated before any I/O
    cfg = _config(args)
    cells = cell_choice(args, MEMRICORE.rows, MEMRICORE.cols)      # a bad list: before the board
    # every output checked before the board is opened (docs/outputs.md); the files of a
    # board other than the in-process emulator are keyed by its identity and checked by the
    # opener right after HELLO, before any pulse
    use = file_use(args, updates_layout=True, writes_report=True,
                   amplitude=(cfg.wv.v_max, "--v-max"))
    plan = plan_from_args(args, use=use, named={"weights": args.weights})
    trace_path = plan.outputs.file("--trace", args.trace, PROGRAM_TRACE) if args.trace else None
    trace = TraceCollector() if trace_path is not None else None
    job = ProgramJob(weights, meta, cfg, cells=cells, cell_tests=not args.no_cell_tests,
                     names=names(args))
    try:
        done = run_on_board(args, job, plan, observers=(trace,) if trace is not None else ())
    except BaseException as exc:
        # no board, or no pulse counter: an earlier run's complete report must not stay
        # beside the layout
        job.failed_before_start(plan.files.report, exc, port=args.port)
        raise
    result = done.result
    if trace is not None and trace_path is not None:
        from snan_hil.tools.bench_figures import plot_program_trace
        plot_program_trace(trace, trace_path, tolerance=cfg.wv.tolerance,
                           title=figure_title("write-and-verify", done.session.info, args.port))
    if args.json:
        print(json.dumps({"summary": result.report["summary"],
                          "layout": str(result.layout_path),
                          "report": str(result.report_path)}, indent=2))
    else:
        _print_summary(result.report, result.layout_path, result.report_path)
    return 0 if result.all_ok else 1


def cell_choice(args: argparse.Namespace, rows: int, cols: int) -> CellChoice:
    """The cells ``--cells-only`` keeps or ``--cells-avoid`` names (checked on a ``rows`` x
    ``cols`` array; UserError, one line, for a bad list)."""
    from snan_hil.tools.commands._cells import read_cell_file
    if getattr(args, "cells_only", None):
        keep = read_cell_file(args.cells_only, "--cells-only", rows, cols)
        return CellChoice(only=frozenset(keep), source=f"--cells-only {args.cells_only}")
    if getattr(args, "cells_avoid", None):
        avoid = read_cell_file(args.cells_avoid, "--cells-avoid", rows, cols)
        return CellChoice(avoid=frozenset(avoid), source=f"--cells-avoid {args.cells_avoid}")
    return CellChoice()


def _print_summary(report: dict[str, Any], layout_path: Path | None,
                   report_path: Path | None) -> None:
    s = report["summary"]
    tol = report["config"]["wv"]["tolerance"]
    t = Table(title="program-weights summary", show_header=False)
    t.add_column("quantity", style="bold")
    t.add_column("value", justify="right")
    pct = lambda x: "-" if x is None else f"{100 * x:.2f} %"  # noqa: E731
    rows = [
        ("cells (synapses)", s["cells"]),
        (f"ok (within +-{tol:.0%})", s["ok"]),
        ("failed", s["failed"]),
        (f"within +-{tol:.0%} after stage 1", s["stage1_ok"]),
        ("median |relative error|", pct(s["median_abs_rel_error"])),
        ("max |relative error|", pct(s["max_abs_rel_error"])),
        ("median / max pulses per cell", f"{s['median_pulses']} / {s['max_pulses']}"),
        ("pulses applied (host / board counter)",
         f"{s['host_pulses']} / "
         + ("n/a (no STATUS)" if s["firmware_pulses"] is None else str(s["firmware_pulses"]))),
        ("synapses moved to spares", s["relocated"]),
        ("bad cells", s["bad_cells"]),
        ("read-chain gain factor", f"{(report['read_chain'] or {}).get('gain_factor', 1):.5f}"),
        ("virtual board time", "-" if s["virtual_s"] is None else f"{s['virtual_s']:.2f} s"),
        ("wall time", f"{s['wall_s']:.2f} s"),
        ("layout", str(layout_path)),
        ("report", str(report_path)),
    ]
    for k, v in rows:
        t.add_row(k, str(v))
    console.print(t)
    bad = [c for c in report["cells"] if not c["ok"]]
    if bad:
        ft = Table(title="cells outside their window")
        for col in ("synapse", "cell", "target uS", "final uS", "error", "reason"):
            ft.add_column(col)
        for c in bad:
            ft.add_row(f"{c['pre']}->{c['post']}", f"({c['row']},{c['col']})",
                       f"{c['target_s'] * 1e6:.1f}",
                       "-" if c["final_s"] is None else f"{c['final_s'] * 1e6:.1f}",
                       pct(c["rel_error"]), c["reason"])
        console.print(ft)
    if report["bad_cells"]:
        console.print("bad cells: " + ", ".join(f"({b['row']},{b['col']}) {b['reason']}"
                                                for b in report["bad_cells"]))

