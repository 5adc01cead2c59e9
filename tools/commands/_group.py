"""``--group``: one network over a group of chips, one instrument (issue 35; docs/multiboard.md
"A chip group"). Distinct from ``--boards`` (several independent boards, each running whole
units of a job on its own chip): every chip of a group takes part in every launch.

:func:`add_group_option` adds the option; :func:`group_plans` checks it against the other
options and the ports (one line, exit 2, before any board is opened or file written) and
gives the opener's plan of each chip.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence

from snan_hil.common.errors import UserError
from snan_hil.files.outputs import Outputs
from snan_hil.lab.boards import LinkOptions
from snan_hil.lab.group_run import check_group_ports
from snan_hil.lab.opener import BoardPlan
from snan_hil.tools.commands._board import file_use, plan_from_args
from snan_hil.tools.commands._history import recording

__all__ = ["add_group_option", "group_ports", "group_plans"]


def add_group_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--group", default=None, metavar="PORT,PORT,...",
        help="one network over a group of chips (a network larger than one chip, e.g. the "
             "10x10 field's 360 synapses over 2-3 chips): each chip holds the synapses of some "
             "input neurons and runs their decision windows; every chip takes part in every "
             "launch (unlike --boards: independent boards). Emulated chips: "
             "emu://?state=a.npz,emu://?state=b.npz (default: one board, --port)")


def group_ports(args: argparse.Namespace,
                refusals: Sequence[tuple[bool, str]] = ()) -> list[str] | None:
    """The ports of ``--group``, checked (UserError, one line): None without it; refused
    with ``--boards``/``--dask``, ``--port``, ``--layout``, the first of ``refusals``
    (condition, line) that holds, and by :func:`check_group_ports`."""
    group = getattr(args, "group", None)
    if group is None:
        return None
    if getattr(args, "boards", None) is not None or getattr(args, "dask", None) is not None:
        raise UserError("--group makes several chips one instrument, --boards/--dask run "
                        "independent boards: give one of them")
    if getattr(args, "port", None) is not None:
        raise UserError("--group names every chip's port; leave --port out")
    if getattr(args, "layout", None) is not None:
        raise UserError("--layout names one board's layout; each chip of a group keeps its "
                        "own beside it (leave --layout out)")
    for bad, line in refusals:
        if bad:
            raise UserError(line)
    link = LinkOptions(protocol=args.protocol, baud=args.baud, timeout=args.timeout,
                       mcu=getattr(args, "mcu", None),
                       max_write_v=getattr(args, "max_write_v", None))
    return check_group_ports(group.split(","), link)


def group_plans(args: argparse.Namespace, ports: Sequence[str], outs: Outputs, *,
                updates_layout: bool, inputs: dict[str, str | None]) -> list[BoardPlan]:
    """The opener's plan of each chip of the group (its files checked against ``outs``, the
    command's outputs; ``inputs``: option -> the file the command reads, never
    overwritten)."""
    plans = []
    for port in ports:
        chip = argparse.Namespace(**{**vars(args), "port": port})
        plans.append(plan_from_args(chip, use=file_use(chip, record=recording(chip),
                                                        updates_layout=updates_layout),
                                    outputs=outs, named=dict(inputs)))
    return plans
