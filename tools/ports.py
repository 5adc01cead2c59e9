"""Open a board from a ``--port`` string: the one place the CLI turns a port into a client.

Port forms: a device path (``/dev/ttyUSB0``, ``COM3``, a pty slave printed by ``snan-hil emu``)
or a pyserial URL (``socket://host:port``, ``rfc2217://host:port``, ``loop://``, and the
in-process emulator's ``emu://?state=PATH&seed=N&protocol=...``, registered here from
:mod:`snan_hil.firmware_emu.protocol_emu`). ``emu`` is shorthand for the emulator's URL with
the command's ``--protocol`` (and a state file / seed given by the caller): :func:`port_url` is
the one place that maps it. Every failure becomes one :class:`UserError` line that names the
port and what to do.
"""

from __future__ import annotations

import argparse
import glob
import logging
import math
import os
import shlex
import time
import zlib
from collections.abc import Callable
from typing import Any
from urllib.parse import parse_qs, urlsplit

import numpy as np

from snan_hil.common.errors import UserError
from snan_hil.firmware_emu.protocol_emu import emu_url, register_url_handler
from snan_hil.firmware_emu.state import STATE_ENV, default_state_path, user_state_path
from snan_hil.protocol.client import BoardClient
from snan_hil.protocol.board import MEMRICORE
from snan_hil.protocol.errors import (BoardBusyError, BoardResetError, LinkTimeoutError,
                                      ProtocolError, TransportError, VersionMismatchError)
from snan_hil.protocol.legacy_client import LegacyClient
from snan_hil.protocol.link import (DEFAULT_CONNECT_TIMEOUT_S, DEFAULT_MAX_RTO_S,
                                    DEFAULT_RETRIES, DEFAULT_STALL_BUDGET_S, DEFAULT_TIMEOUT_S,
                                    LinkClient)
from snan_hil.protocol.retry import RetryingClient
from snan_hil.protocol.safety import MAX_WRITE_OPTION, check_max_write_v
from snan_hil.protocol.transport import DEFAULT_BAUD, SerialTransport, Transport

__all__ = ["EMU_PORT", "PROTOCOLS", "PORT_ENV", "add_port_arguments", "add_board_argument",
           "resolve_port", "serial_devices", "port_url", "open_transport", "open_client",
           "client_from_args", "is_emu_port", "emu_first_seq", "resolve_mcu"]

log = logging.getLogger(__name__)

EMU_PORT = "emu"
"""Shorthand for the in-process emulator's ``emu://`` URL (see :func:`port_url`)."""
PROTOCOLS = ("framed", "legacy")
PORT_ENV = "SNAN_HIL_PORT"
"""Environment variable giving ``--port`` when the option is omitted."""
SERIAL_GLOBS = ("/dev/ttyUSB*", "/dev/ttyACM*")
"""Serial devices that may be a MemriCore board (USB-UART bridges, CDC-ACM)."""

register_url_handler()      # emu:// is a transport like socket://


def add_port_arguments(parser: argparse.ArgumentParser,
                       default_port: str | None = EMU_PORT) -> None:
    """Add ``--port``, ``--baud``, ``--protocol`` and ``--timeout`` to a sub-command.
    An omitted ``--port`` is filled in by :func:`resolve_port` (``$SNAN_HIL_PORT``, else
    ``default_port``, with a note when a serial device exists)."""
    parser.set_defaults(_port_fallback=default_port, _port_notice=True)
    parser.add_argument("--port", default=None,
                        help="board: 'emu' (in-process emulator, short for "
                             "emu://?protocol=PROTOCOL; its chip is kept in "
                             f"{_emu_state_text()}, reset with 'snan-hil emu --reset-chip'), "
                             "a device path such as /dev/ttyUSB0 or a pty from 'snan-hil emu', "
                             "or a URL socket://HOST:PORT, rfc2217://HOST:PORT, loop://, "
                             f"emu://?state=FILE&seed=N (default: ${PORT_ENV} if set, else "
                             + (f"{default_port}; the command says so when a serial device "
                                "such as /dev/ttyUSB0 exists)" if default_port else
                                "required)"))
    parser.add_argument("--baud", type=int, default=DEFAULT_BAUD, help="serial line rate")
    parser.add_argument("--protocol", choices=PROTOCOLS, default="framed",
                        help="framed (this project's firmware/emulator) or legacy (the old "
                             "ASCII line protocol)")
    parser.add_argument("--timeout", type=float, default=None,
                        help="framed: the longest the line may stay silent during one request "
                             "before the command stops, in seconds (default "
                             f"{DEFAULT_TIMEOUT_S:g}; {DEFAULT_CONNECT_TIMEOUT_S:g} until the "
                             "board first answers; the link resends sooner, at the measured "
                             "round trip); legacy: the wait per try, 0.25 unless given")
    parser.add_argument("--stall-budget", dest="stall_budget_s", type=float, default=None,
                        metavar="SECONDS",
                        help="framed: the total of the line's stalls (silences longer than "
                             f"{DEFAULT_MAX_RTO_S:g} s) a run rides out before it stops "
                             f"(default {DEFAULT_STALL_BUDGET_S:g})")
    parser.add_argument("--wait", dest="wait_s", type=float, default=0.0, metavar="SECONDS",
                        help="when another host holds the board (a shared 'snan-hil emu "
                             "--socket' answers BUSY) or another program holds its port: wait "
                             "up to SECONDS for it, saying who holds it (default 0: stop at "
                             "once)")
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


def board_options(args: argparse.Namespace) -> str:
    """The command-line options (of :func:`add_port_arguments`, plus ``--layout`` where the
    command has one) that reach the same board as ``args`` did, for hints that name another
    command: ``--port P`` and every option the user changed from its default (``--protocol
    legacy``, ``--baud``, ``--mcu``, ``--timeout``, ``--stall-budget``, ``--wait``,
    ``--max-write-v``, ``--legacy-refusals``, ``--layout``), shell-quoted. A hint without
    ``--protocol legacy`` would fail on a legacy board."""
    opts = ["--port", str(args.port)]
    if getattr(args, "protocol", "framed") != "framed":
        opts += ["--protocol", args.protocol]
    if getattr(args, "baud", DEFAULT_BAUD) != DEFAULT_BAUD:
        opts += ["--baud", str(args.baud)]
    if getattr(args, "mcu", "model") != "model":
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
    (:func:`resolve_mcu`)."""
    _resolve_port(args, notice)
    if hasattr(args, "_port_fallback") and hasattr(args, "mcu") and args.port:
        args.mcu = resolve_mcu(args.port, args.mcu)


def resolve_mcu(port: str, mcu: str | None) -> str | None:
    """The MCU of the board on ``port`` given an explicit ``--mcu`` (None: not given): for the
    in-process emulator ``mcu``, the URL's ``mcu=`` or "model"; None for any other port (its
    MCU is not the host's choice). UserError when ``--mcu`` is given for another port or
    contradicts the URL's ``mcu=``."""
    if not is_emu_port(port):
        if mcu is not None:
            raise UserError(f"--mcu only applies to the in-process emulator (--port emu or "
                            f"emu://...); {port} is served elsewhere: choose its MCU where it "
                            "is served (snan-hil emu --mcu ...), or drop --mcu")
        return None
    in_url = _url_mcu(port)
    if mcu is not None and in_url is not None and mcu != in_url:
        raise UserError(f"--mcu {mcu} contradicts mcu={in_url} in --port {port}; give one")
    return mcu or in_url or "model"


def _url_mcu(port: str) -> str | None:
    """The ``mcu=`` option of an ``emu://`` URL (None when absent or for ``emu``)."""
    if port == EMU_PORT:
        return None
    values = parse_qs(urlsplit(port).query).get("mcu")
    return values[-1] if values else None


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


def _emu_state_text() -> str:
    """Where ``--port emu`` keeps its chip, for --help (argparse-escaped)."""
    path = str(default_state_path())
    home = os.path.expanduser("~")
    if path.startswith(home + os.sep):
        path = "~" + path[len(home):]
    return path.replace("%", "%%")


def port_url(port: str, *, protocol: str = "framed", state_file: str | None = None,
             seed: int | None = None, mcu: str | None = None, refusals: bool = False) -> str:
    """The device path or URL ``port`` stands for: ``emu`` -> the emulator's ``emu://`` URL
    speaking ``protocol`` (with ``state_file`` / ``seed`` when given, and the legacy
    ``refusals`` extension); an ``emu://`` URL gets ``mcu`` added when it names none;
    anything else as is."""
    if port == EMU_PORT:
        return emu_url(state_file, seed, protocol, mcu or "model", refusals)
    if is_emu_port(port):
        values = parse_qs(urlsplit(port).query).get("protocol")
        in_url = values[-1] if values else None
        # an unknown protocol= is the URL handler's to refuse (it names the choices)
        if in_url is not None and in_url in PROTOCOLS and in_url != protocol:
            raise UserError(f"--protocol {protocol} contradicts protocol={in_url} in --port "
                            f"{port}; give one")
        if in_url is None and protocol != "framed":   # the URL's default is framed
            port = _add_query(port, f"protocol={protocol}")
    if mcu not in (None, "model") and is_emu_port(port) and _url_mcu(port) is None:
        return _add_query(port, f"mcu={mcu}")
    return port


def _add_query(url: str, item: str) -> str:
    return url + ("&" if urlsplit(url).query else "?") + item


def is_emu_port(port: str) -> bool:
    """Whether ``port`` is the in-process emulator (``emu`` or an ``emu://`` URL)."""
    return port == EMU_PORT or port.startswith("emu://")


def emu_first_seq(seed: int | None) -> int:
    """First link sequence number of a session with the in-process emulator: 16 bits of
    ``SeedSequence([seed, crc32("link")])`` (seed None = 0, the emulator's default)."""
    ss = np.random.SeedSequence([int(seed or 0) & ((1 << 64) - 1), zlib.crc32(b"link")])
    return int(ss.generate_state(1)[0]) & 0xFFFF


def open_transport(port: str, baud: int = DEFAULT_BAUD, *, protocol: str = "framed",
                   state_file: str | None = None, seed: int | None = None,
                   mcu: str | None = None, refusals: bool = False) -> Transport:
    """Open the byte transport for ``port`` (UserError on failure); ``state_file``/``seed``/
    ``refusals`` only matter for the ``emu`` shorthand, ``mcu`` (None: not chosen) for the
    in-process emulator (:func:`resolve_mcu` refuses it for other ports)."""
    if protocol not in PROTOCOLS:
        raise UserError(f"unknown protocol {protocol!r}; use one of {', '.join(PROTOCOLS)}")
    if baud <= 0:
        raise UserError(f"--baud must be positive, got {baud}")
    if not port:
        raise UserError("empty --port; give 'emu', a device path or a socket:// URL")
    _check_network_url(port)
    if mcu is not None:
        resolve_mcu(port, mcu)
    try:
        return SerialTransport(port_url(port, protocol=protocol, state_file=state_file,
                                        seed=seed, mcu=mcu, refusals=refusals), baud)
    except TransportError as exc:
        raise UserError(_open_advice(port, str(exc))) from None


def _check_network_url(port: str) -> None:
    """A ``socket://`` or ``rfc2217://`` URL names a host and a port 1..65535 (pyserial's own
    messages for these end in its logging options or a comparison with None)."""
    scheme, sep, rest = port.partition("://")
    if not sep or scheme.lower() not in ("socket", "rfc2217"):
        return
    form = f"give {scheme}://HOST:PORT, e.g. {scheme}://127.0.0.1:5000"
    address = rest.split("?", 1)[0].split("/", 1)[0]
    host, colon, number = address.rpartition(":")
    if not colon or not host:
        raise UserError(f"--port {port}: no {'port' if not colon else 'host'} in the URL; "
                        f"{form}")
    if not number.isdigit():
        raise UserError(f"--port {port}: the port {number!r} is not a number; {form}")
    if not 1 <= int(number) <= 65535:
        raise UserError(f"--port {port}: port {int(number)} is outside 1..65535; {form}")


def _open_advice(port: str, reason: str) -> str:
    low = reason.lower()
    if "lock" in low or "busy" in low or "resource temporarily unavailable" in low:
        what = "it is in use by another program (close minicom/another snan-hil) and retry"
    elif "is a directory" in low or "inappropriate ioctl" in low or "not a tty" in low:
        what = ("it is not a serial device; give a port such as /dev/ttyUSB0, a pty printed by "
                "'snan-hil emu', or use --port emu")
    elif "no such file" in low or "errno 2]" in low:
        what = ("no such device; list ports with 'python -m serial.tools.list_ports', start "
                "'snan-hil emu' for a pty, or use --port emu")
    elif "permission" in low:
        what = "permission denied; add yourself to the 'dialout' group or check the device"
    elif "connection refused" in low or "timed out" in low:
        what = "nothing listens there; start 'snan-hil emu --socket HOST:PORT' or check the URL"
    else:
        what = "check the port name or URL, or use --port emu"
    return f"cannot open port {port}: {what} ({reason.removeprefix(f'cannot open {port}: ')})"


def open_client(port: str, baud: int = DEFAULT_BAUD, protocol: str = "framed", *,
                timeout: float | None = None, retries: int = DEFAULT_RETRIES,
                state_file: str | None = None, seed: int | None = None,
                mcu: str | None = None, max_write_v: float | None = None,
                legacy_refusals: bool = False, stall_budget_s: float | None = None,
                wait_s: float = 0.0) -> BoardClient:
    """Open ``port`` and return a connected client (HELLO done, protocol version checked).

    ``protocol``: "framed" -> :class:`LinkClient`, "legacy" -> :class:`LegacyClient`.
    ``state_file``/``seed`` are passed to the in-process emulator (port ``emu``) only.
    ``max_write_v``: the host's write limit (V; default the board's), checked before the
    port is opened. ``legacy_refusals``: the legacy ``-CODE,id`` extension, on the client and
    (port ``emu``) on the emulator. ``timeout`` (framed): the longest silence of one request,
    also before the first answer when given; ``stall_budget_s``: the stalls a run rides out;
    ``wait_s``: how long to wait for a board another host holds (BUSY) or a port another
    program holds.
    Raises :class:`UserError` (one line naming the port) if the port cannot be opened, the
    board does not answer, or it speaks another protocol version.
    """
    for option, value in (("--timeout", timeout), ("--stall-budget", stall_budget_s)):
        if value is not None and not (value > 0 and math.isfinite(value)):
            raise UserError(f"{option} must be a positive number of seconds, got {value}")
    if not (wait_s >= 0 and math.isfinite(wait_s)):
        raise UserError(f"--wait must be a number of seconds >= 0, got {wait_s}")
    if retries < 0:
        raise UserError(f"retries must be >= 0, got {retries}")
    if max_write_v is not None:
        check_max_write_v(MEMRICORE, max_write_v)
    if legacy_refusals and protocol != "legacy":
        raise UserError("--legacy-refusals is an extension of the legacy line protocol; give "
                        "--protocol legacy")
    if is_emu_port(port):
        _check_state_folder(state_file)
    transport = _open_waiting(port, baud, wait_s, protocol=protocol, state_file=state_file,
                              seed=seed, mcu=mcu, refusals=legacy_refusals)
    client: LinkClient | LegacyClient
    kwargs: dict[str, Any] = {"retries": retries}
    if timeout is not None:
        kwargs["timeout"] = timeout
    if protocol == "legacy":
        client = LegacyClient(transport, refusals=legacy_refusals, **kwargs)
    else:
        if timeout is not None:
            kwargs["connect_timeout"] = timeout        # never give up sooner than asked
        if stall_budget_s is not None:
            kwargs["stall_budget_s"] = stall_budget_s
        kwargs["busy_wait_s"] = wait_s
        if is_emu_port(port):
            # in-process emulator: the link's first sequence number from the chip seed, like
            # the emulator's boot nonce, so a run's frames (and board times, which count
            # their encoded length) repeat exactly; a real board's session draws a random one
            kwargs["first_seq"] = emu_first_seq(seed)
        client = LinkClient(transport, **kwargs)
    client.host_max_write_v = max_write_v
    try:
        if isinstance(client, LinkClient):
            RetryingClient(client).hello()     # HELLO is resent like every safe request
        else:
            client.hello()
    except LinkTimeoutError as exc:
        transport.close()
        other = "legacy" if protocol == "framed" else "framed"
        if exc.kind == "silent":
            raise UserError(f"no answer from the board on {port} ({protocol} protocol at {baud} "
                            f"baud): no byte at all came back; check power, cable and --baud, "
                            f"or try --protocol {other}") from None
        raise UserError(f"cannot talk to the board on {port}: {exc}") from None
    except BoardBusyError as exc:
        transport.close()
        raise UserError(str(exc)) from None
    except VersionMismatchError as exc:
        transport.close()
        raise UserError(str(exc)) from None
    except (BoardResetError, ProtocolError) as exc:
        transport.close()
        raise UserError(f"cannot talk to the board on {port}: {exc}") from None
    log.info("connected to %s on %s (%s protocol)", client.info and client.info.board_id, port,
             protocol)
    return client


def _open_waiting(port: str, baud: int, wait_s: float, **kwargs: Any) -> Transport:
    """:func:`open_transport`; while the port is in use by another program, tried again for
    up to ``wait_s`` seconds (a warning line says so once)."""
    deadline = time.monotonic() + wait_s
    warned = False
    while True:
        try:
            return open_transport(port, baud, **kwargs)
        except UserError as exc:
            if "in use by another program" not in str(exc) or time.monotonic() >= deadline:
                raise
            if not warned:
                log.warning("port %s is in use by another program; waiting up to %g s for it "
                            "(--wait)", port, wait_s)
                warned = True
            time.sleep(min(0.5, max(0.0, deadline - time.monotonic())))


def _check_state_folder(state_file: str | None) -> None:
    """UserError (one line) when the in-process emulator's chip would go into a missing
    folder: file options need an existing folder; only the default chip's folder in the
    user's data folder is made (docs/outputs.md)."""
    from pathlib import Path
    path = Path(state_file).expanduser() if state_file else default_state_path()
    if path.parent.is_dir() or path == user_state_path():
        return
    label = f"chip state {path}" if state_file else f"chip state (${STATE_ENV}) {path}"
    raise UserError(f"{label}: folder {path.parent} does not exist; create it first or give "
                    "another path")


def client_from_args(args: argparse.Namespace, **kwargs: Any) -> BoardClient:
    """``open_client`` from the options added by :func:`add_port_arguments`."""
    kwargs.setdefault("mcu", getattr(args, "mcu", None))
    kwargs.setdefault("max_write_v", getattr(args, "max_write_v", None))
    kwargs.setdefault("legacy_refusals", getattr(args, "legacy_refusals", False))
    kwargs.setdefault("stall_budget_s", getattr(args, "stall_budget_s", None))
    kwargs.setdefault("wait_s", getattr(args, "wait_s", 0.0))
    return open_client(args.port, args.baud, args.protocol, timeout=args.timeout, **kwargs)
