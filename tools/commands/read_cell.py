"""``snan-hil read-cell``: read one cell -- ADC code, conductance and resistance through the read
chain -- one or more times, recorded in the board's history (kind ``read``).

Example: ``snan-hil read-cell --cell 3,5 --reads 10 --port emu --json``.
"""

from __future__ import annotations

import argparse
import json
import statistics
from typing import Any

from snan_hil.calibration.observer import CellEvent
from snan_hil.common.errors import UserError
from snan_hil.protocol.board import MEMRICORE
from snan_hil.tools.commands._board import add_layout_option, add_result_options, board_session
from snan_hil.tools.commands._board import layout_outputs, session_layout
from snan_hil.tools.commands._history import open_recorder
from snan_hil.tools.commands._cells import one_cell
from snan_hil.tools.commands._options import accept_negative_cells
from snan_hil.tools.commands._run import controlled, run_block
from snan_hil.tools.console import console
from snan_hil.tools.ports import add_port_arguments

NAME = "read-cell"
HELP = "read one cell (ADC code, conductance, resistance), recorded in the history"
MAX_READS = 10_000


def add_arguments(parser: argparse.ArgumentParser) -> None:
    accept_negative_cells(parser)
    add_port_arguments(parser)
    parser.add_argument("--cell", required=True, metavar="R,C",
                        help="the cell: row (bit line) and column (word line)")
    parser.add_argument("--reads", type=int, default=1, help="reads of the cell")
    parser.add_argument("--read-code", type=int, default=None,
                        help="DAC code of the read voltage (default: the board's read code, at "
                             "most its read limit)")
    add_layout_option(parser, "convert with this layout's calibrated read chain (default: the "
                              "port's layout if it exists, else the board's nominal one)")
    add_result_options(parser, history="cells")


def run(args: argparse.Namespace) -> int:
    row, col = one_cell(args.cell, "--cell", MEMRICORE.rows, MEMRICORE.cols)
    if not 1 <= args.reads <= MAX_READS:
        raise UserError(f"--reads {args.reads}: give 1..{MAX_READS}")
    if args.read_code is not None and not 1 <= args.read_code <= MEMRICORE.max_read_code:
        raise UserError(f"--read-code {args.read_code}: give 1..{MEMRICORE.max_read_code} (the "
                        f"read limit {MEMRICORE.max_read_v} V)")
    outs = layout_outputs(args)
    with board_session(outs, args) as session:
        client, info, history_path = session.client, session.info, session.files.history
        row, col = one_cell(args.cell, "--cell", info.rows, info.cols)
        # the read chain of the board's layout (another board's refused), else the nominal one
        chain, source = session_layout(args, session)[2:]
        code = info.read_code if args.read_code is None else args.read_code
        if code > info.max_read_code:
            raise UserError(f"--read-code {code} is above the board's read limit "
                            f"{info.max_read_code}")
        with open_recorder(args, history_path, "read", info,
                           config={"row": row, "col": col, "reads": args.reads,
                                   "read_code": code}) as rec:
            board = controlled(client, rec)   # reads resent by the session's client
            reads: list[dict[str, Any]] = []
            gs: list[float] = []
            for k in range(args.reads):
                adc = int(board.read_cell(row, col, code))
                g = float(chain.cell_conductance(adc, code))
                gs.append(g)
                reads.append({"n": k + 1, "adc": adc, "g_s": g,
                              "r_ohm": 1 / g if g > 0 else None})
                rec.publisher.event("reads", {"row": row, "col": col, "adc": adc,
                                              "read_code": code,
                                              "read_v": chain.cell_read_volts(code),
                                              "g_s": g, "step": "read-cell"})
            summary: dict[str, Any] = {"row": row, "col": col, "reads": len(reads),
                       "median_s": statistics.median(gs),
                       "rel_std": statistics.stdev(gs) / statistics.fmean(gs)
                       if len(gs) > 1 and statistics.fmean(gs) > 0 else None}
            rec.on_cell(CellEvent(row, col, "read", summary["median_s"],
                                  detail={"adc": reads[-1]["adc"], "read_code": code,
                                          "reads": len(reads)}))
            rec.finish("complete", summary)
    data = {"format": "snan-hil-read-cell/1", "run": run_block(rec, args),
            "board": {"board_id": info.board_id, "port": args.port, "protocol": args.protocol},
            "read_code": code, "read_v": chain.cell_read_volts(code),
            "read_chain": source, **summary, "samples": reads}
    if args.json:
        print(json.dumps(data, indent=1, allow_nan=False))
        return 0
    last = reads[-1]
    g_last = gs[-1]
    console.print(f"cell ({row},{col}) read at {data['read_v']:.4f} V (code {code}): ADC "
                  f"{last['adc']}, G = {g_last * 1e6:.2f} uS"
                  + (f", R = {last['r_ohm']:.0f} Ohm" if last["r_ohm"] else " (open)"),
                  highlight=False)
    if len(reads) > 1:
        rel = summary["rel_std"]
        console.print(f"{len(reads)} reads: median {summary['median_s'] * 1e6:.2f} uS, "
                      f"relative spread {100 * rel:.2f} %" if rel is not None else "",
                      highlight=False)
    console.print(f"(converted with the {data['read_chain']}; run {rec.run_id}, uid "
                  f"{rec.uid[:8]})", highlight=False)
    return 0
