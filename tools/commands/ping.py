"""``snan-hil ping``: round-trip latency and link health to a board."""

from __future__ import annotations

import argparse
import json
import statistics
import time

from snan_hil.common.errors import UserError
from snan_hil.tools.console import console
from snan_hil.tools.ports import add_port_arguments, client_from_args

NAME = "ping"
HELP = "send N harmless requests to a board and print round-trip times and link counters"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_port_arguments(parser)
    parser.add_argument("-n", "--count", type=int, default=100, help="number of requests")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead")


def run(args: argparse.Namespace) -> int:
    if args.count < 1:
        raise UserError(f"--count must be >= 1, got {args.count}")
    client = client_from_args(args)
    times = []
    try:
        # framed: STATUS (no effect on the array); legacy: a 0.3 V read of cell (0, 0)
        call = (lambda: client.read_cell(0, 0)) if args.protocol == "legacy" \
            else client.status
        for _ in range(args.count):
            t0 = time.perf_counter()
            call()
            times.append(time.perf_counter() - t0)
        counters = client.counters_dict()
    finally:
        client.close()
    ms = [t * 1e3 for t in times]
    result = {"port": args.port, "protocol": args.protocol, "count": len(ms),
              "rtt_ms_mean": statistics.fmean(ms), "rtt_ms_median": statistics.median(ms),
              "rtt_ms_max": max(ms), "requests_per_s": len(ms) / (sum(times) or 1e-12),
              "link_counters": counters}
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        console.print(f"{len(ms)} requests to {args.port}: round trip mean "
                      f"{result['rtt_ms_mean']:.3f} ms, median {result['rtt_ms_median']:.3f} ms, "
                      f"max {result['rtt_ms_max']:.3f} ms ({result['requests_per_s']:.0f}/s)")
        console.print("link: " + ", ".join(f"{k} {v}" for k, v in counters.items() if v))
    return 0
