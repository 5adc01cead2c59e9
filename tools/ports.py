"""The command line's board options: ``--port`` and the link options, and what they stand for.

What a port string means, how it is opened and every emulator special case belong to the
opener (:mod:`snan_hil.lab.ports`, :mod:`snan_hil.lab.opener`); this module only adds the
options to a sub-command, fills in an omitted ``--port`` (``$SNAN_HIL_PORT``, else the
command's default, with a note when a serial device exists) and turns the parsed options into
a :class:`~snan_hil.lab.ports.BoardAddress`.
"""

from __future__ import annotations

import argparse
import glob
import os
import shlex
from collections.abc import Callable

from snan_hil.board.session import BoardSession
from snan_hil.common.errors import UserError
from snan_hil.lab.opener import plan_board
from snan_hil.lab.ports import (EMU_PORT, PROTOCOLS, BoardAddress, default_chip_text,
                                open_client, open_transport, protocol_of_port, resolve_mcu)
from snan_hil.protocol.board import MEMRICORE
from snan_hil.protocol.client import BoardClient
from snan_hil.protocol.link import (DEFAULT_CONNECT_TIMEOUT_S, DEFAULT_MAX_RTO_S,
                                    MAX_STALL_BUDGET_S, MAX_TIMEOUT_S, MAX_WAIT_S, LinkTimes)
from snan_hil.protocol.safety import MAX_WRITE_OPTION
from snan_hil.protocol.transport import DEFAULT_BAUD

__all__ = ["EMU_PORT", "PROTOCOLS", "PORT_ENV", "add_port_arguments", "add_board_argument",
           "resolve_port", "serial_devices", "board_options", "address_from_args",
           "client_from_args", "session_from_args", "open_client", "open_transport"]

PORT_ENV = "SNAN_HIL_PORT"
"""Environment variable giving ``--port`` when the option is omitted."""
SERIAL_GLOBS = ("/dev/ttyUSB*", "/dev/ttyACM*")
"""Serial devices that may be a MemriCore board (USB-UART bridges, CDC-ACM)."""


def add_port_arguments(parser: argparse.ArgumentParser,
                       default_port: str | None = EMU_PORT) -> None:
    """Add ``--port``, ``--baud``, ``--protocol`` and ``--timeout`` to a sub-command.
    An omitted ``--port`` is filled in by :func:`resolve_port` (``$SNAN_HIL_PORT``, else
    ``default_port``, with a note when a serial device exists). The time options' defaults
    and bounds are :class:`~snan_hil.protocol.link.LinkTimes`'s."""
    times = LinkTimes()
    parser.set_defaults(_port_fallback=default_port, _port_notice=True)
    parser.add_argument("--port", default=None,
                        help="board: 'emu' (in-process emulator, short for "
                             "emu://?protocol=PROTOCOL; its chip is kept in "
                             f"{default_chip_text()}, reset with 'snan-hil emu --reset-chip'), "
                             "a device path such as /dev/ttyUSB0 or a pty from 'snan-hil emu', "
                             "or a URL socket://HOST:PORT, rfc2217://HOST:PORT, loop://, "
                             f"emu://?state=FILE&seed=N (default: ${PORT_ENV} if set, else "
                             + (f"{default_port}; the command says so when a serial device "
                                "such as /dev/ttyUSB0 exists)" if default_port else
                                "required)"))
    parser.add_argument("--baud", type=int, default=DEFAULT_BAUD, help="serial line rate")
    parser.add_argument("--protocol", choices=PROTOCOLS, default=None,
                        help="framed (this project's firmware/emulator) or legacy (the old "
                             "ASCII line protocol); default: the one an emu:// URL names, "
                             "else framed")
    parser.add_argument("--timeout", type=float, default=None,
                        help="framed: the longest the line may stay silent during one request "
                             "before the command stops, in seconds (default "
                             f"{times.timeout_s:g}; {DEFAULT_CONNECT_TIMEOUT_S:g} until the "
                             "board first answers; the link resends sooner, at the measured "
                             "round trip); legacy: the wait per try, 0.25 unless given; "
                             f"above 0, at most {MAX_TIMEOUT_S:g}")
    parser.add_argument("--stall-budget", dest="stall_budget_s", type=float, default=None,
                        metavar="SECONDS",
                        help="framed: the total of the line's stalls (silences longer than "
                             f"{DEFAULT_MAX_RTO_S:g} s) a run rides out before it stops "
                             f"(default {times.stall_budget_s:g}; above 0, at most "
                             f"{MAX_STALL_BUDGET_S:g})")
    parser.add_argument("--wait", dest="wait_s", type=float, default=times.wait_s,
                        metavar="SECONDS",
                        help="when another host holds the board (a shared 'snan-hil emu "
                             "--socket' answers BUSY) or another program holds its port: wait "
                             "up to SECONDS for it, saying who holds it (default 0: stop at "
                             f"once; at most {MAX_WAIT_S:g})")
    parser.add_argument("--mcu", choices=("model", "firmware"), default=None,
                        help="with --port emu or emu://: the MCU of the emulated board, the "
                             "Python firmware model (default) or the C firmware ELF on an "
                             "instruction-level RISC-V CPU (make firmware builds it; "
                             "$SNAN_HIL_FIRMWARE_ELF names another). Only for the in-process "
                             "emulator: a pty or socket server chooses its own (snan-hil emu "
                             "--mcu)")
    parser.add_argument(MAX_WRITE_OPTION, dest="max_write_v", type=float, default=None,
                        metavar="V",
                        help="host safety limit of write pulses in volts, either protocol: a "
                             "pulse above it is refused before it is sent (the write-DAC code "
                             "is the largest at or below it; default: the board's "
                             f"{MEMRICORE.max_write_v} V). Reads are always kept at or below "
                             f"{MEMRICORE.max_read_v} V")
    parser.add_argument("--legacy-refusals", action="store_true",
                        help="with --protocol legacy: understand the -CODE,id refusal replies "
                             "of a board started with the same option (this project's "
                             "extension; the existing firmware never sends them)")
    parser.add_argument("--device", metavar="MODEL.json", default=None,
                        help="with --port emu or emu://: the emulated chip is the twin of this "
                             "fitted device model ('snan-hil characterize --model', or --from a "
                             "lab's pulse CSV), kept in its own chip file unless state= names "
                             "one (docs/crossbar_model.md section 7; default: none, the packaged "
                             "YSZ chip)")


def address_from_args(args: argparse.Namespace) -> BoardAddress:
    """The board the options of :func:`add_port_arguments` name."""
    return BoardAddress(args.port, protocol=getattr(args, "protocol", "framed"),
                        baud=getattr(args, "baud", DEFAULT_BAUD),
                        timeout=getattr(args, "timeout", None), mcu=getattr(args, "mcu", None),
                        max_write_v=getattr(args, "max_write_v", None),
                        legacy_refusals=getattr(args, "legacy_refusals", False),
                        stall_budget_s=getattr(args, "stall_budget_s", None),
                        wait_s=getattr(args, "wait_s", 0.0),
                        device=getattr(args, "device", None))


def session_from_args(args: argparse.Namespace) -> BoardSession:
    """A session on the board the options name, opened through the opener (no files of the
    board checked: for commands that only talk to it, such as ``info``): its client, its INFO
    and the host's limits, decided once (:attr:`BoardSession.limits`)."""
    return plan_board(address_from_args(args), options=board_options(args)).open()


def client_from_args(args: argparse.Namespace) -> BoardClient:
    """The client of :func:`session_from_args` (for commands that only send requests)."""
    return session_from_args(args).client


def board_options(args: argparse.Namespace) -> str:
    """The command-line options (of :func:`add_port_arguments`, plus ``--layout`` where the
    command has one) that reach the same board as ``args`` did, for hints that name another
    command: ``--port P`` and every option the user changed from its default (``--protocol
    legacy``, ``--baud``, ``--mcu``, ``--timeout``, ``--stall-budget``, ``--wait``,
    ``--max-write-v``, ``--legacy-refusals``,
    ``--layout``), shell-quoted. A hint without ``--protocol legacy`` would fail on a legacy
    board."""
    opts = ["--port", str(args.port)]
    if getattr(args, "protocol", "framed") != "framed":
        opts += ["--protocol", args.protocol]
    if getattr(args, "baud", DEFAULT_BAUD) != DEFAULT_BAUD:
        opts += ["--baud", str(args.baud)]
    if getattr(args, "mcu", "model") not in ("model", None):
        opts += ["--mcu", args.mcu]
    if getattr(args, "timeout", None) is not None:
        opts += ["--timeout", f"{args.timeout:g}"]
    if getattr(args, "stall_budget_s", None) is not None:
        opts += ["--stall-budget", f"{args.stall_budget_s:g}"]
    if getattr(args, "wait_s", 0.0):
        opts += ["--wait", f"{args.wait_s:g}"]
    if getattr(args, "max_write_v", None) is not None:
        opts += [MAX_WRITE_OPTION, f"{args.max_write_v:g}"]
    if getattr(args, "legacy_refusals", False):
        opts.append("--legacy-refusals")
    if getattr(args, "device", None):
        opts += ["--device", str(args.device)]
    if getattr(args, "layout", None):
        opts += ["--layout", str(args.layout)]
    return shlex.join(opts)


def add_board_argument(parser: argparse.ArgumentParser, what: str) -> None:
    """``--port`` of a command that does not open the board but reads what belongs to it
    (its history database): ``$SNAN_HIL_PORT`` if set, else ``emu``; and ``--board ID``, the
    identity that keys the files of a board other than the in-process emulator."""
    parser.set_defaults(_port_fallback=EMU_PORT, _port_notice=False)
    parser.add_argument("--port", default=None,
                        help=f"the board whose {what}: 'emu' or its port (default: "
                             f"${PORT_ENV} if set, else emu)")
    parser.add_argument("--board", metavar="ID", default=None,
                        help="for a board other than the in-process emulator: its board id as "
                             "INFO reports it ('snan-hil info' shows it), which keys its files "
                             "(default: none; needed unless --port is emu or --history is given)")


def serial_devices() -> list[str]:
    """Serial devices present that may be a board (:data:`SERIAL_GLOBS`), sorted."""
    return sorted({p for pattern in SERIAL_GLOBS for p in glob.glob(pattern)})


def resolve_port(args: argparse.Namespace, notice: Callable[[str], object]) -> None:
    """Fill in an omitted ``--port``: ``$SNAN_HIL_PORT``, else the command's default. No
    silent emulator: when that default is the emulator and a serial device such as
    /dev/ttyUSB0 exists, ``notice`` gets one line saying the emulator is used and how to
    choose the board. UserError when the command needs a port and none is given.
    Then ``--mcu`` is checked against the port and set to the MCU it stands for
    (:func:`~snan_hil.lab.ports.resolve_mcu`)."""
    _resolve_port(args, notice)
    resolve_protocol(args)
    if hasattr(args, "_port_fallback") and hasattr(args, "mcu") and args.port:
        args.mcu = resolve_mcu(args.port, args.mcu)


def resolve_protocol(args: argparse.Namespace) -> None:
    """Fill in an omitted ``--protocol``: the one ``--port``'s emu:// URL names, else framed
    (a given one that contradicts the URL is refused when the port is opened)."""
    if hasattr(args, "protocol") and args.protocol is None:
        args.protocol = protocol_of_port(getattr(args, "port", None))


def _resolve_port(args: argparse.Namespace, notice: Callable[[str], object]) -> None:
    if not hasattr(args, "_port_fallback") or getattr(args, "port", None) is not None:
        return
    env = os.environ.get(PORT_ENV, "").strip()
    if env:
        args.port = env
        return
    if args._port_fallback is None:
        raise UserError(f"--port is required (a device such as /dev/ttyUSB0, a URL, or emu); "
                        f"or set {PORT_ENV}")
    args.port = args._port_fallback
    if args.port == EMU_PORT and args._port_notice:
        devices = serial_devices()
        if devices:
            notice(f"using the board emulator (--port emu), not the serial device"
                   f"{'s' if len(devices) > 1 else ''} {', '.join(devices)}: no --port given "
                   f"and ${PORT_ENV} is not set; to use the board give --port {devices[0]} "
                   f"or set {PORT_ENV}={devices[0]}")
