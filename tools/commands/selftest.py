"""``snan-hil selftest``: a lab's first-day acceptance test of a board, cable and chip.

Parses the options into a :class:`~snan_hil.calibration.selftest.SelfTestConfig`, runs
:class:`~snan_hil.calibration.selftest.SelfTestJob` through the job runner (non-destructive
unless ``--allow-pulses`` names cells; recorded in the chip's history), writes the JSON report
(``--report``, with the session's provenance) and prints the pass/fail table. Exit code 0 when
every item passed, 1 when one failed, 2 for bad input.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from rich.table import Table

from snan_hil.calibration.selftest import ITEMS, SelfTestConfig, SelfTestJob, SelfTestResult
from snan_hil.common.version import __version__
from snan_hil.files.atomicio import atomic_write_json
from snan_hil.protocol.board import MEMRICORE
from snan_hil.tools.commands._board import add_result_options, file_use, plan_from_args
from snan_hil.tools.commands._cells import parse_cell_list
from snan_hil.tools.commands._job import run_on_board
from snan_hil.tools.console import console
from snan_hil.tools.output_kinds import SELFTEST_JSON
from snan_hil.tools.ports import add_port_arguments

NAME = "selftest"
HELP = ("acceptance test of a board: identity, link, timing, read chain on every cell, ADC bits, "
        "column path, row DACs, gain, conformance vectors, MAC; pulses only on named cells")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_port_arguments(parser)
    parser.add_argument("--allow-pulses", metavar="CELLS", default=None,
                        help="cells ('R,C R,C ...') the pulse check may pulse (one SET and one "
                             "RESET each); default: none, nothing is pulsed")
    parser.add_argument("--only", metavar="ITEMS", default=None,
                        help="run only these items (comma-separated; default: all): "
                             + ", ".join(ITEMS))
    parser.add_argument("--round-trips", type=int, default=SelfTestConfig.round_trips,
                        help="round trips of the link check (default %(default)s)")
    parser.add_argument("--report", metavar="FILE", default="selftest-report.json",
                        help="the JSON report (default %(default)s)")
    add_result_options(parser, json_help="print the report's summary as JSON")


def _config(args: argparse.Namespace) -> SelfTestConfig:
    cells = () if args.allow_pulses is None else tuple(
        parse_cell_list(args.allow_pulses, "--allow-pulses", MEMRICORE.rows, MEMRICORE.cols))
    only = () if args.only is None else tuple(t.strip() for t in args.only.split(",")
                                              if t.strip())
    return SelfTestConfig(round_trips=args.round_trips, allow_pulses=cells, only=only)


def run(args: argparse.Namespace) -> int:
    cfg = _config(args)
    plan = plan_from_args(args, use=file_use(args))
    report = plan.outputs.file("--report", args.report, SELFTEST_JSON)
    result = run_on_board(args, SelfTestJob(cfg), plan, seed=cfg.seed).result
    data = {**result.to_dict(), "version": __version__, "port": args.port}
    atomic_write_json(report, data, indent=1, allow_nan=False)
    if args.json:
        print(json.dumps({**result.summary(), "report": str(report)}, indent=1))
    else:
        _print(result, report)
    return 0 if result.passed else 1


def _print(result: SelfTestResult, report: Path) -> None:
    t = Table(title="board self-test")
    for name in ("item", "result", "measured", "expected", "likely cause / note"):
        t.add_column(name, overflow="fold")
    style = {"pass": "green", "fail": "bold red", "skip": "dim"}
    for i in result.items:
        t.add_row(i.item, f"[{style[i.status]}]{i.status.upper()}[/]", i.measured, i.expected,
                  i.cause)
    console.print(t)
    s = result.summary()
    verdict = "PASSED" if result.passed else f"FAILED ({s['fail']} item(s))"
    console.print(f"self-test {verdict}: {s['pass']} passed, {s['fail']} failed, {s['skip']} "
                  f"skipped; report {report}", highlight=False)
