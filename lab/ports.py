"""How a board is reached: :class:`BoardAddress` (a port string or URL and the link options),
the transport and the greeted client. The one place a port string is interpreted.

Port forms: a device path (``/dev/ttyUSB0``, ``COM3``, a pty slave printed by ``snan-hil emu``)
or a pyserial URL (``socket://host:port``, ``rfc2217://host:port``, ``loop://``, and the
in-process emulator's ``emu://?state=PATH&seed=N&protocol=...``, registered here from
:mod:`snan_hil.firmware_emu.protocol_emu`). ``emu`` is shorthand for the emulator's URL with the
address's protocol (and a state file / seed given by the caller): :meth:`BoardAddress.url` is
the one place that maps it, and :attr:`BoardAddress.emulator` the one place an ``emu://`` URL
is read (:meth:`~snan_hil.firmware_emu.protocol_emu.EmuUrl.parse`). Every failure becomes one
:class:`UserError` line that names the port and what to do.
"""

from __future__ import annotations

import logging
import os
import time
import zlib
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import numpy as np
from serial.serialutil import SerialException

from snan_hil.board.session import with_read_retries
from snan_hil.common.errors import BoardLinkError, UserError
from snan_hil.config import loader as configio
from snan_hil.firmware_emu.protocol_emu import EmuUrl, emu_url, register_url_handler
from snan_hil.firmware_emu.state import STATE_ENV, default_state_path, made_by_us, twin_state_path
from snan_hil.protocol.board import MEMRICORE
from snan_hil.protocol.client import BoardClient
from snan_hil.protocol.errors import (BoardBusyError, BoardResetError, LinkTimeoutError,
                                      ProtocolError, TransportError, VersionMismatchError)
from snan_hil.protocol.legacy_client import LegacyClient
from snan_hil.protocol.link import DEFAULT_RETRIES, LinkClient, LinkTimes
from snan_hil.protocol.safety import check_max_write_v
from snan_hil.protocol.transport import DEFAULT_BAUD, SerialTransport, Transport

__all__ = ["EMU_PORT", "PROTOCOLS", "BoardAddress", "is_emu_port", "port_url", "resolve_mcu",
           "protocol_of_port",
           "emu_first_seq", "open_transport", "connect", "open_client", "default_chip_text"]

log = logging.getLogger(__name__)

EMU_PORT = "emu"
"""Shorthand for the in-process emulator's ``emu://`` URL (see :meth:`BoardAddress.url`)."""
PROTOCOLS = ("framed", "legacy")

register_url_handler()      # emu:// is a transport like socket://


def is_emu_port(port: str) -> bool:
    """Whether ``port`` is the in-process emulator (``emu`` or an ``emu://`` URL)."""
    return port == EMU_PORT or port.startswith("emu://")


def _parse_emu(port: str) -> EmuUrl:
    """The settings of an ``emu://`` URL; UserError (one line naming the port) if malformed."""
    try:
        return EmuUrl.parse(port)
    except SerialException as exc:
        raise UserError(_open_advice(port, str(exc))) from None


@dataclass(frozen=True)
class BoardAddress:
    """How to reach one board: ``port`` (see the module docstring) and the link options.

    ``baud`` (bit/s), ``timeout`` (framed: the longest silence of one request, s, also before
    the board first answers; legacy: the wait per try; None: the link's default),
    ``stall_budget_s`` (framed: the total of the line's stalls a run rides out; None: the
    link's default), ``wait_s`` (how long to wait for a board another host holds, BUSY, or a
    port another program holds; 0: stop at once), ``mcu`` (the in-process emulator's MCU,
    ``model`` or ``firmware``; None: not chosen), ``max_write_v`` (the host's write limit, V;
    None: the board's), ``legacy_refusals`` (the legacy ``-CODE,id`` extension),
    ``state_file`` and ``seed`` (the chip file and seed of the ``emu`` shorthand), ``device``
    (a fitted device model file: the in-process emulator's chip is its twin)."""

    port: str
    protocol: str = "framed"
    baud: int = DEFAULT_BAUD
    timeout: float | None = None
    mcu: str | None = None
    max_write_v: float | None = None
    legacy_refusals: bool = False
    state_file: str | None = None
    seed: int | None = None
    retries: int = DEFAULT_RETRIES
    stall_budget_s: float | None = None
    wait_s: float = 0.0
    device: str | None = None

    @property
    def in_process(self) -> bool:
        """Whether the board is the in-process emulator (``emu`` or ``emu://``)."""
        return is_emu_port(self.port)

    @cached_property
    def emulator(self) -> EmuUrl | None:
        """The in-process emulator's settings (None for any other port): the URL's, or for the
        ``emu`` shorthand this address's state file (default ``$SNAN_HIL_EMU_STATE`` or the
        user's chip), seed, protocol, MCU and refusals. UserError for a malformed URL."""
        if self.port == EMU_PORT:
            device = Path(self.device).expanduser() if self.device else None
            if self.state_file:
                state = Path(self.state_file).expanduser()
            elif device is not None:
                state = twin_state_path(device)
            else:
                state = default_state_path()
            return EmuUrl(state, self.seed, self.protocol, self.mcu or "model",
                          self.legacy_refusals, device=device)
        if self.port.startswith("emu://"):
            return _parse_emu(self.port)
        return None

    @property
    def chip_state(self) -> Path | None:
        """The in-process emulator's chip state file, else None."""
        emu = self.emulator
        return emu.state if emu is not None else None

    def check(self) -> None:
        """UserError (one line) for an option no board could take, before any I/O: timeout,
        retries, the host write limit, refusals without the legacy protocol, protocol, baud,
        an empty port, a malformed network URL, ``--mcu`` for a port it does not apply to."""
        for option, field, value in (("--timeout", "timeout_s", self.timeout),
                                     ("--stall-budget", "stall_budget_s", self.stall_budget_s),
                                     ("--wait", "wait_s", self.wait_s)):
            if value is not None:       # the bounds beside the field (a one-line ConfigError)
                configio.check_value(LinkTimes, field, value, key=f"{option} (seconds)")
        if self.retries < 0:
            raise UserError(f"retries must be >= 0, got {self.retries}")
        if self.max_write_v is not None:
            check_max_write_v(MEMRICORE, self.max_write_v)
        if self.legacy_refusals and self.protocol != "legacy":
            raise UserError("--legacy-refusals is an extension of the legacy line protocol; "
                            "give --protocol legacy")
        _check_link_options(self.port, self.protocol, self.baud)
        if self.mcu is not None:
            resolve_mcu(self.port, self.mcu)
        if self.device is not None:
            _check_device(self.port, self.device)

    def url(self) -> str:
        """The device path or URL the port stands for (:func:`port_url`)."""
        return port_url(self.port, protocol=self.protocol, state_file=self.state_file,
                        seed=self.seed, mcu=self.mcu, refusals=self.legacy_refusals,
                        device=self.device)


def _check_link_options(port: str, protocol: str, baud: int) -> None:
    if protocol not in PROTOCOLS:
        raise UserError(f"unknown protocol {protocol!r}; use one of {', '.join(PROTOCOLS)}")
    if baud <= 0:
        raise UserError(f"--baud must be positive, got {baud}")
    if not port:
        raise UserError("empty --port; give 'emu', a device path or a socket:// URL")
    _check_network_url(port)


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
    in_url = _url_value(port, "mcu")
    if mcu is not None and in_url is not None and mcu != in_url:
        raise UserError(f"--mcu {mcu} contradicts mcu={in_url} in --port {port}; give one")
    return mcu or in_url or "model"


def _check_device(port: str, device: str) -> None:
    """``--device`` names the chip of the in-process emulator only; an ``emu://`` URL that
    names another model contradicts it (UserError, one line)."""
    if not is_emu_port(port):
        raise UserError(f"--device makes the in-process emulator's chip the twin of a fitted "
                        f"model; {port} is not the in-process emulator: give --port emu (or "
                        "serve the twin with 'snan-hil emu --device FILE')")
    in_url = _url_value(port, "device")
    if in_url is not None and Path(in_url).expanduser() != Path(device).expanduser():
        raise UserError(f"--device {device} contradicts device={in_url} in --port {port}; "
                        "give one")


def _url_value(port: str, key: str) -> str | None:
    """The value of ``key`` in an ``emu://`` URL when it names one (None for ``emu``)."""
    if port == EMU_PORT:
        return None
    url = _parse_emu(port)
    return str(getattr(url, key)) if key in url.given else None


def protocol_of_port(port: str | None) -> str:
    """The protocol a command speaks on ``port`` when ``--protocol`` is not given: the one an
    ``emu://`` URL names (``protocol=legacy``), else framed (this project's firmware)."""
    if port is None or not is_emu_port(port):
        return "framed"
    return _url_value(port, "protocol") or "framed"


def port_url(port: str, *, protocol: str = "framed", state_file: str | None = None,
             seed: int | None = None, mcu: str | None = None, refusals: bool = False,
             device: str | None = None) -> str:
    """The device path or URL ``port`` stands for: ``emu`` -> the emulator's ``emu://`` URL
    speaking ``protocol`` (with ``state_file`` / ``seed`` when given, and the legacy
    ``refusals`` extension); an ``emu://`` URL gets ``protocol`` (refused when it names another
    one) and ``mcu`` added when it names none; anything else as is."""
    if port == EMU_PORT:
        return emu_url(state_file, seed, protocol, mcu or "model", refusals, device=device)
    if not is_emu_port(port):
        return port
    in_url = _url_value(port, "protocol")
    if in_url is not None and in_url != protocol:
        raise UserError(f"--protocol {protocol} contradicts protocol={in_url} in --port "
                        f"{port}; give one")
    if in_url is None and protocol != "framed":   # the URL's default is framed
        port = _add_query(port, f"protocol={protocol}")
    if mcu not in (None, "model") and _url_value(port, "mcu") is None:
        port = _add_query(port, f"mcu={mcu}")
    if device is not None and _url_value(port, "device") is None:
        port = _add_query(port, f"device={device}")
    return port


def _add_query(url: str, item: str) -> str:
    return url + ("&" if urlsplit(url).query else "?") + item


def emu_first_seq(seed: int | None) -> int:
    """First link sequence number of a session with the in-process emulator: 16 bits of
    ``SeedSequence([seed, crc32("link")])`` (seed None = 0, the emulator's default)."""
    ss = np.random.SeedSequence([int(seed or 0) & ((1 << 64) - 1), zlib.crc32(b"link")])
    return int(ss.generate_state(1)[0]) & 0xFFFF


def default_chip_text() -> str:
    """Where ``--port emu`` keeps its chip, for help texts (``~`` for the home folder,
    argparse-escaped)."""
    path = str(default_state_path())
    home = os.path.expanduser("~")
    if path.startswith(home + os.sep):
        path = "~" + path[len(home):]
    return path.replace("%", "%%")


def open_transport(port: str, baud: int = DEFAULT_BAUD, *, protocol: str = "framed",
                   state_file: str | None = None, seed: int | None = None,
                   mcu: str | None = None, refusals: bool = False) -> Transport:
    """Open the byte transport for ``port`` (UserError on failure); ``state_file``/``seed``/
    ``refusals`` only matter for the ``emu`` shorthand, ``mcu`` (None: not chosen) for the
    in-process emulator (:func:`resolve_mcu` refuses it for other ports)."""
    _check_link_options(port, protocol, baud)
    if mcu is not None:
        resolve_mcu(port, mcu)
    return _transport(BoardAddress(port, protocol, baud, mcu=mcu, legacy_refusals=refusals,
                                   state_file=state_file, seed=seed))


def _transport(address: BoardAddress) -> Transport:
    url = address.url()          # an emu:// URL is parsed there: malformed, one line
    try:
        return SerialTransport(url, address.baud)
    except TransportError as exc:
        raise UserError(_open_advice(address.port, str(exc))) from None


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


def check_state_folder(address: BoardAddress) -> None:
    """UserError (one line) when the in-process emulator's chip would go into a missing
    folder: file options need an existing folder; only the default chip's folder in the
    user's data folder is made (docs/outputs.md)."""
    path = address.chip_state
    if path is None or path.parent.is_dir() or made_by_us(path):
        return
    named = address.state_file or address.port != EMU_PORT
    label = f"chip state {path}" if named else f"chip state (${STATE_ENV}) {path}"
    raise UserError(f"{label}: folder {path.parent} does not exist; create it first or give "
                    "another path")


def connect(address: BoardAddress) -> BoardClient:
    """Open ``address`` and return a connected client (HELLO done, protocol version checked):
    "framed" -> :class:`LinkClient`, "legacy" -> :class:`LegacyClient`, with the host's write
    limit set. Raises :class:`UserError` (one line naming the port) if an option is unusable,
    the port cannot be opened, the board does not answer, or it speaks another protocol
    version."""
    address.check()
    check_state_folder(address)
    transport = _open_waiting(address)
    kwargs: dict[str, Any] = {"retries": address.retries}
    if address.timeout is not None:
        kwargs["timeout"] = address.timeout
    client: LinkClient | LegacyClient
    if address.protocol == "legacy":
        client = LegacyClient(transport, refusals=address.legacy_refusals, **kwargs)
    else:
        if address.timeout is not None:
            kwargs["connect_timeout"] = address.timeout      # never give up sooner than asked
        if address.stall_budget_s is not None:
            kwargs["stall_budget_s"] = address.stall_budget_s
        kwargs["busy_wait_s"] = address.wait_s
        if address.in_process:
            # in-process emulator: the link's first sequence number from the chip seed, like
            # the emulator's boot nonce, so a run's frames (and board times, which count
            # their encoded length) repeat exactly; a real board's session draws a random one
            kwargs["first_seq"] = emu_first_seq(address.seed)
        client = LinkClient(transport, **kwargs)
    client.host_max_write_v = address.max_write_v
    _greet(client, address)
    log.info("connected to %s on %s (%s protocol)", client.info and client.info.board_id,
             address.port, address.protocol)
    return client


def _open_waiting(address: BoardAddress) -> Transport:
    """The address's transport; while its port is in use by another program, tried again for
    up to ``address.wait_s`` seconds (a warning line says so once)."""
    deadline = time.monotonic() + address.wait_s
    warned = False
    while True:
        try:
            return _transport(address)
        except UserError as exc:
            if "in use by another program" not in str(exc) or time.monotonic() >= deadline:
                raise
            if not warned:
                log.warning("port %s is in use by another program; waiting up to %g s for it "
                            "(--wait)", address.port, address.wait_s)
                warned = True
            time.sleep(min(0.5, max(0.0, deadline - time.monotonic())))


def _greet(client: LinkClient | LegacyClient, address: BoardAddress) -> None:
    """HELLO (resent when lost over the framed link); every failure one line, the transport
    closed: a :class:`BoardLinkError` when the board or the line failed (no answer, garbled,
    busy, another protocol version, a reset), else a :class:`UserError`."""
    port, protocol = address.port, address.protocol
    try:
        if isinstance(client, LinkClient):
            with_read_retries(client).hello()  # HELLO is resent like every safe request
        else:
            client.hello()
    except LinkTimeoutError as exc:
        client.transport.close()
        other = "legacy" if protocol == "framed" else "framed"
        if exc.kind == "silent":
            raise BoardLinkError(f"no answer from the board on {port} ({protocol} protocol at "
                                 f"{address.baud} baud): no byte at all came back; check power, "
                                 f"cable and --baud, or try --protocol {other}") from None
        raise BoardLinkError(f"cannot talk to the board on {port}: {exc}") from None
    except (BoardBusyError, VersionMismatchError) as exc:
        client.transport.close()
        raise BoardLinkError(str(exc)) from None
    except (BoardResetError, ProtocolError) as exc:
        client.transport.close()
        kind = BoardLinkError if isinstance(exc, BoardLinkError) else UserError
        raise kind(f"cannot talk to the board on {port}: {exc}") from None


def open_client(port: str, baud: int = DEFAULT_BAUD, protocol: str = "framed", *,
                timeout: float | None = None, retries: int = DEFAULT_RETRIES,
                state_file: str | None = None, seed: int | None = None,
                mcu: str | None = None, max_write_v: float | None = None,
                legacy_refusals: bool = False, stall_budget_s: float | None = None,
                wait_s: float = 0.0, device: str | None = None) -> BoardClient:
    """:func:`connect` with the address's fields as arguments (for tests and benches that
    want a bare client; jobs get a :class:`~snan_hil.board.session.BoardSession` from
    :func:`snan_hil.lab.opener.plan_board`)."""
    return connect(BoardAddress(port, protocol, baud, timeout, mcu, max_write_v,
                                legacy_refusals, state_file, seed, retries, stall_budget_s,
                                wait_s, device))
