"""``snan-hil pulse``: one pulse ticket — a planned pulse experiment on one cell, a read after
every pulse, stopping at a condition (:mod:`snan_hil.calibration.tickets`).

Examples::

    snan-hil pulse --port emu --cell 3,5 --polarity set --amplitude 0.3:1.2:0.01 --until-g 500
    snan-hil pulse --port emu --cell 3,5 --polarity reset --amplitude 0.8 --count 20 \\
        --window 200uS+-5% --png reset.png --csv reset.csv

A cell that holds a programmed synapse may be pulsed (that is what a bench is for), but the
command warns, and once a pulse was applied the board's layout marks that synapse *stale*:
``read-weights`` and ``mac`` name it in a warning (their targets no longer describe the cell)
until ``program-weights`` writes it again.
"""

from __future__ import annotations

import argparse
import csv
import json

from rich.table import Table

from snan_hil.files.atomicio import atomic_path
from snan_hil.calibration.tickets import (PulseTicket, PulseTicketJob, TicketResult,
                                          check_ticket, parse_amplitudes, parse_conductance,
                                          parse_window)
from snan_hil.common.errors import UserError
from snan_hil.common.polarity import Polarity
from snan_hil.protocol.board import MEMRICORE
from snan_hil.protocol.safety import requested_write_limit_v
from snan_hil.tools.commands._board import (add_layout_option, add_png_option,
                                            add_result_options, plan_from_args)
from snan_hil.tools.commands._cells import one_cell
from snan_hil.tools.commands._options import accept_negative_cells
from snan_hil.tools.commands._job import run_on_board
from snan_hil.tools.console import console
from snan_hil.tools.output_kinds import TICKET_CSV, TICKET_CSV_HEADER, TICKET_FORMAT, TICKET_PNG
from snan_hil.tools.ports import add_port_arguments
from snan_hil.tools.titles import figure_title

NAME = "pulse"
HELP = ("one pulse ticket on a cell: pulses of one polarity (an amplitude or a ramp), a read "
        "after each, until a condition")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    accept_negative_cells(parser)
    add_port_arguments(parser)
    parser.add_argument("--cell", required=True, metavar="R,C",
                        help="the cell: row (bit line) and column (word line)")
    parser.add_argument("--polarity", required=True, choices=("set", "reset"),
                        help="set (conductance up) or reset (conductance down)")
    parser.add_argument("--amplitude", required=True, metavar="V|START:STOP:STEP",
                        help="pulse amplitude in V, or a ramp, e.g. 0.3:1.2:0.01 (at most the "
                             f"host's write limit, {MEMRICORE.max_write_v} V on MemriCore)")
    parser.add_argument("--width-us", type=int, default=100, help="pulse width, us")
    parser.add_argument("--count", type=int, default=1,
                        help="pulses at each amplitude (a single amplitude: the number of "
                             "pulses)")
    stop = parser.add_mutually_exclusive_group()
    stop.add_argument("--until-g", metavar="G", default=None,
                      help="stop once G >= this (set) or <= this (reset); uS unless a unit "
                           "is given: 500, 500uS, 0.5mS (default: no condition)")
    stop.add_argument("--window", metavar="G±P", default=None,
                      help="stop at the first read inside G +- P %%, e.g. 500±10%% or "
                           "500uS+-10%% (default: no condition)")
    add_layout_option(parser, "convert reads with this layout's calibrated read chain "
                      "(default: the port's layout if it exists, else the board's nominal one)")
    add_png_option(parser, "draw the conductance trace and the amplitudes (default: none)")
    parser.add_argument("--csv", metavar="FILE", default=None,
                        help="write one row per pulse (default: none)")
    add_result_options(parser)


def ticket_from_args(args: argparse.Namespace) -> PulseTicket:
    """The ticket, checked against the MemriCore defaults and the host's write limit
    (``--max-write-v``) before the board is opened (UserError, one line)."""
    row, col = one_cell(args.cell, "--cell", MEMRICORE.rows, MEMRICORE.cols)
    ticket = PulseTicket(
        row, col, Polarity.parse(args.polarity), parse_amplitudes(args.amplitude),
        width_us=args.width_us, count=args.count,
        until_g_s=parse_conductance(args.until_g) if args.until_g is not None else None,
        window=parse_window(args.window) if args.window is not None else None)
    check_ticket(ticket, MEMRICORE, None if args.max_write_v is None else
                 requested_write_limit_v(MEMRICORE, args.max_write_v),
                 names=NAMES)
    return ticket


NAMES = {"cell": "--cell", "amplitude": "--amplitude", "width_us": "--width-us",
         "count": "--count", "max_write_v": "--max-write-v"}
"""The ticket's fields as this command's options (messages)."""


def run(args: argparse.Namespace) -> int:
    ticket = ticket_from_args(args)
    plan = plan_from_args(args)
    png = plan.outputs.file("--png", args.png, TICKET_PNG) if args.png else None
    csv_path = plan.outputs.file("--csv", args.csv, TICKET_CSV) if args.csv else None
    done = run_on_board(args, PulseTicketJob(ticket, names=NAMES), plan, transient=True)
    run, session = done.result, done.session
    res = run.result
    if csv_path is not None:
        _write_csv(res, str(csv_path))
    if png is not None:
        from snan_hil.tools.bench_figures import plot_ticket
        plot_ticket(res, png, title=figure_title(
            f"pulse ticket on cell ({ticket.row},{ticket.col})", session.info, args.port))
    data = {"format": TICKET_FORMAT, **res.to_dict(), "read_chain": run.read_chain,
            "stale_synapse": run.stale,
            "board": session.identity.to_dict(port=args.port), "session": session.snapshot()}
    if args.json:
        print(json.dumps(data, indent=1, allow_nan=False))
        return 0
    _print(res, run.read_chain)
    if run.stale is not None:
        console.print(f"layout {run.stale['layout']}: synapse {run.stale['pre']}->"
                      f"{run.stale['post']} marked stale (re-run program-weights to restore "
                      "its weight)", highlight=False)
    for opt, path in (("--csv", args.csv), ("--png", args.png)):
        if path:
            console.print(f"wrote {opt} {path}", highlight=False)
    return 0


def _write_csv(res: TicketResult, path: str) -> None:
    t = res.ticket
    try:
        with atomic_path(path) as tmp, open(tmp, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(TICKET_CSV_HEADER.split(","))
            for s in res.steps:
                w.writerow([s.n, t.polarity.name, f"{s.amplitude_v:.6g}", t.width_us,
                            f"{s.g_before_s:.6g}", f"{s.g_after_s:.6g}"])
    except OSError as exc:
        raise UserError(f"cannot write --csv {path}: {exc.strerror or exc}") from None


def _print(res: TicketResult, source: str | None) -> None:
    t = res.ticket
    table = Table(title=f"pulse ticket: cell ({t.row},{t.col}), {t.polarity.name}, "
                        f"{t.width_us} us, stop at {t.condition()}")
    for col in ("pulse", "amplitude V", "G before uS", "G after uS", "change"):
        table.add_column(col, justify="right")
    steps = res.steps
    shown = steps if len(steps) <= 40 else steps[:20] + steps[-20:]
    for k, s in enumerate(shown):
        if len(steps) > 40 and k == 20:
            table.add_row("...", "", "", "", "")
        table.add_row(str(s.n), f"{s.amplitude_v:.3f}", f"{s.g_before_s * 1e6:.2f}",
                      f"{s.g_after_s * 1e6:.2f}", f"{s.g_after_s / s.g_before_s - 1:+.1%}")
    console.print(table)
    console.print(f"{len(steps)} pulses: {res.initial_s * 1e6:.2f} uS -> "
                  f"{res.final_s * 1e6:.2f} uS; {res.stopped} (reads via the {source})",
                  highlight=False)
