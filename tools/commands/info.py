"""``snan-hil info``: the board's HELLO/INFO, its counters and the host link counters.

Over the legacy line protocol the board's mode-100 line carries at most its id, firmware
version and geometry; every other field is a host default (the MemriCore reference facts) or
host policy (the read/write limits), and is shown with its source (``info_sources`` in the
JSON) so it is not taken for a board fact. ``host_limits``: the limits this host enforces
(``--max-write-v``), either protocol."""

from __future__ import annotations

import argparse
import dataclasses
import json
from typing import Any

from rich.table import Table

from snan_hil.protocol.errors import UnsupportedError
from snan_hil.protocol.legacy_codec import info_sources
from snan_hil.protocol.messages import Capability
from snan_hil.protocol.safety import HostLimits
from snan_hil.tools.console import console
from snan_hil.tools.ports import add_port_arguments, session_from_args

NAME = "info"
HELP = "connect to a board (or the emulator) and print its description and link counters"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_port_arguments(parser)
    parser.add_argument("--json", action="store_true", help="print one JSON object instead")


def run(args: argparse.Namespace) -> int:
    session = session_from_args(args)
    client, info = session.client, session.info
    limits = session.limits                    # what the client enforces, decided once
    try:
        board: dict[str, dict] = {}
        for what, call in (("status", client.status), ("clock", client.clock)):
            try:
                board[what] = dataclasses.asdict(call())
            except UnsupportedError:
                pass
        link = client.counters_dict()
        reported = getattr(client, "reported_fields", None)
    finally:
        session.close()
    data = {"port": args.port, "baud": args.baud, "protocol": args.protocol,
            "info": info.to_dict(), **board, "link_counters": link,
            "host_limits": {"max_read_v": limits.max_read_v, "max_write_v": limits.max_write_v,
                            "max_cell_read_code": limits.max_cell_read_code,
                            "max_write_code": limits.max_write_code}}
    sources = info_sources(tuple(reported)) if reported is not None else None
    if sources is not None:
        # over the line protocol most fields are host defaults or host policy, not board facts
        data["info_sources"] = sources
    if "status" in data:        # the counters belong to this boot (the nonce names it)
        data["status"]["since_boot_nonce"] = info.boot_nonce
    data["info"]["capabilities_names"] = [c.name for c in Capability
                                          if c and info.capabilities & c]
    if args.json:
        print(json.dumps(data, indent=2))
        return 0
    _print(args, data, sources, limits, info.boot_nonce)
    return 0


def _print(args: argparse.Namespace, data: dict[str, Any], sources: dict[str, str] | None,
           limits: HostLimits, boot_nonce: int) -> None:
    """The board's INFO (with each field's source over the line protocol), the host's limits
    and the board's counters, as tables."""
    table = Table(title=f"board on {args.port} ({args.protocol} protocol)",
                  show_header=sources is not None)
    table.add_column("field", style="bold")
    table.add_column("value")
    if sources is not None:
        table.add_column("source")
    for key, value in data["info"].items():
        if key == "boot_nonce":
            value = f"0x{value:08x}"
        src = [] if sources is None else [
            sources.get("capabilities" if key == "capabilities_names" else key,
                        "").split(":")[0]]
        table.add_row(key, str(value), *src)
    console.print(table)
    if sources is not None:
        console.print("source: board = its mode-100 line; assumed = the MemriCore board's "
                      "documented value (protocol/board.py), not reported by this board; host "
                      "policy = a limit this host sets; none = not in the line protocol "
                      "(details: --json, info_sources)", highlight=False)
    console.print(f"host limits (this host's policy, both protocols): reads <= "
                  f"{limits.max_read_v:g} V, writes <= {limits.max_write_v:g} V (write-DAC code "
                  f"{limits.max_write_code}; --max-write-v)", highlight=False)
    since = (f" since boot nonce 0x{boot_nonce:08x} (restart at every power-on, "
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
