"""``snan-hil read-cell``: read one cell -- ADC code, conductance and resistance through the read
chain -- one or more times, recorded in the board's history (kind ``read``).

Example: ``snan-hil read-cell --cell 3,5 --reads 10 --port emu --json``.
"""

from __future__ import annotations

import argparse
import json
from typing import Any

from snan_hil.calibration.cellread import MAX_READS, ReadCellConfig, ReadCellJob
from snan_hil.common.errors import UserError
from snan_hil.protocol.board import MEMRICORE
from snan_hil.tools.commands._board import add_layout_option, add_result_options, plan_from_args
from snan_hil.tools.commands._cells import one_cell
from snan_hil.tools.commands._job import run_on_board
from snan_hil.tools.commands._options import accept_negative_cells
from snan_hil.tools.console import console
from snan_hil.tools.ports import add_port_arguments

NAME = "read-cell"
HELP = "read one cell (ADC code, conductance, resistance), recorded in the history"


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


NAMES = {"cell": "--cell", "reads": "--reads", "read_code": "--read-code"}
"""The job's fields as this command's options (messages)."""


def run(args: argparse.Namespace) -> int:
    row, col = one_cell(args.cell, "--cell", MEMRICORE.rows, MEMRICORE.cols)
    if not 1 <= args.reads <= MAX_READS:
        raise UserError(f"--reads {args.reads}: give 1..{MAX_READS}")
    if args.read_code is not None and not 1 <= args.read_code <= MEMRICORE.max_read_code:
        raise UserError(f"--read-code {args.read_code}: give 1..{MEMRICORE.max_read_code} (the "
                        f"read limit {MEMRICORE.max_read_v} V)")
    job = ReadCellJob(ReadCellConfig(row, col, args.reads, args.read_code), names=NAMES)
    done = run_on_board(args, job, plan_from_args(args), transient=True)
    read = done.result
    data = {"format": "snan-hil-read-cell/1", "run": done.run_block(),
            "board": {"board_id": done.session.info.board_id, "port": args.port,
                      "protocol": args.protocol},
            "read_code": read["read_code"], "read_v": read["read_v"],
            "read_chain": read["read_chain"], **read["summary"], "samples": read["samples"]}
    if args.json:
        print(json.dumps(data, indent=1, allow_nan=False))
        return 0
    _print(data, done.history_run_id, done.metadata.uid)
    return 0


def _print(data: dict[str, Any], run_id: int | None, uid: str) -> None:
    reads, last = data["samples"], data["samples"][-1]
    console.print(f"cell ({data['row']},{data['col']}) read at {data['read_v']:.4f} V (code "
                  f"{data['read_code']}): ADC {last['adc']}, G = {last['g_s'] * 1e6:.2f} uS"
                  + (f", R = {last['r_ohm']:.0f} Ohm" if last["r_ohm"] else " (open)"),
                  highlight=False)
    if len(reads) > 1:
        rel = data["rel_std"]
        console.print(f"{len(reads)} reads: median {data['median_s'] * 1e6:.2f} uS, "
                      f"relative spread {100 * rel:.2f} %" if rel is not None else "",
                      highlight=False)
    console.print(f"(converted with the {data['read_chain']}; run {run_id}, uid "
                  f"{uid[:8]})", highlight=False)
