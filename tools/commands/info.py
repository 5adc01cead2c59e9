"""``snan-hil info``: the board's HELLO/INFO, its counters and the host link counters."""

from __future__ import annotations

import argparse
import dataclasses
import json

from rich.table import Table

from snan_hil.protocol.errors import UnsupportedError
from snan_hil.protocol.messages import Capability
from snan_hil.tools.console import console
from snan_hil.tools.ports import add_port_arguments, client_from_args

NAME = "info"
HELP = "connect to a board (or the emulator) and print its description and link counters"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_port_arguments(parser)
    parser.add_argument("--json", action="store_true", help="print one JSON object instead")


def run(args: argparse.Namespace) -> int:
    client = client_from_args(args)
    try:
        info = client.info
        assert info is not None
        board: dict[str, dict] = {}
        for what, call in (("status", client.status), ("clock", client.clock)):
            try:
                board[what] = dataclasses.asdict(call())
            except UnsupportedError:
                pass
        link = client.counters_dict()
    finally:
        client.close()
    data = {"port": args.port, "baud": args.baud, "protocol": args.protocol,
            "info": info.to_dict(), **board, "link_counters": link}
    if "status" in data:        # the counters belong to this boot (the nonce names it)
        data["status"]["since_boot_nonce"] = info.boot_nonce
    data["info"]["capabilities_names"] = [c.name for c in Capability
                                          if c and info.capabilities & c]
    if args.json:
        print(json.dumps(data, indent=2))
        return 0
    table = Table(title=f"board on {args.port} ({args.protocol} protocol)", show_header=False)
    table.add_column("field", style="bold")
    table.add_column("value")
    for key, value in data["info"].items():
        if key == "boot_nonce":
            value = f"0x{value:08x}"
        table.add_row(key, str(value))
    console.print(table)
    since = (f" since boot nonce 0x{info.boot_nonce:08x} (restart at every power-on, "
             "emulator start or RESET)")
    for title in ("status", "clock", "link_counters"):
        if title in data:
            t = Table(title=title.replace("_", " ") + (since if title != "link_counters"
                                                       else " (this session)"),
                      show_header=False)
            t.add_column("counter", style="bold")
            t.add_column("value", justify="right")
            for key, value in data[title].items():
                t.add_row(key, f"{value:.6g}" if isinstance(value, float) else str(value))
            console.print(t)
    return 0
