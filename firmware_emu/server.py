"""Serving an :class:`Emulator` on a pseudo-terminal or a TCP socket.

* :class:`PtyServer` opens a pty pair and answers on the master end; :attr:`PtyServer.slave_path`
  (e.g. ``/dev/pts/7``) is what pyserial, minicom or the old host software open as a serial
  port. The server does not keep the slave open itself, so it sees a client open (reads stop
  failing with EIO) and close (EIO again) and reports each as a connection event.
* :class:`TcpServer` listens on HOST:PORT and serves one connection at a time (a serial line
  has one peer); pyserial reaches it as ``socket://HOST:PORT``. Another connection is told at
  once that the board is busy (ERROR BUSY naming the served client and since when); a served
  client that stays silent for the idle timeout is dropped.

Both run in a daemon thread (``start()``/``stop()``) or in the caller's thread
(``serve(stop_event)``), call ``on_event(text)`` for every connection and disconnection, and let
the emulator save its chip while idle. Both pace replies in wall time: a reply is written no
earlier than ``Emulator.wall_scale`` x the board time its request took (virtual, without the
UART) after the request arrived — so over the legacy protocol (scale 1 by default) a mode-7
pulse is answered only after the pulse, as the real firmware does. Nothing here prints.
"""

from __future__ import annotations

import errno
import logging
import os
import select
import socket
import threading
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime

from snan_hil.common.errors import UserError
from snan_hil.firmware_emu.emulator import Emulator
from snan_hil.protocol.device import nak_reply
from snan_hil.protocol.errors import ErrorCode, FrameError
from snan_hil.protocol.frames import Frame, FrameDecoder, encode_frame
from snan_hil.protocol.messages import MAX_TEXT, ErrorReply

log = logging.getLogger(__name__)

EventCallback = Callable[[str], None]

POLL_S = 0.05
DEFAULT_IDLE_TIMEOUT_S = 120.0
"""A served TCP client that sends nothing for this long is disconnected (s)."""


class _ServerBase:
    def __init__(self, emulator: Emulator, on_event: EventCallback | None = None):
        self.emulator = emulator
        self.on_event = on_event
        self.connections = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def _event(self, text: str) -> None:
        log.info("%s", text)
        if self.on_event is not None:
            self.on_event(text)

    def _idle(self) -> None:
        self.emulator.maybe_save()

    def _answer(self, data: bytes, received: float, stop: threading.Event) -> bytes:
        """The emulator's reply to ``data`` (received at monotonic time ``received``), held
        back until the board time it took, scaled by ``wall_scale``, has passed."""
        emu = self.emulator
        out = emu.feed(data)
        if out and emu.wall_scale > 0:
            due = received + emu.last_busy_us * 1e-6 * emu.wall_scale
            while not stop.is_set():
                left = due - time.monotonic()
                if left <= 0:
                    break
                stop.wait(min(left, POLL_S))
        return out

    def start(self) -> "_ServerBase":
        """Serve in a daemon thread."""
        self._thread = threading.Thread(target=self.serve, args=(self._stop,),
                                        name=type(self).__name__, daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving, close the line, save the chip."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        self.close()
        self.emulator.close()

    def serve(self, stop: threading.Event | None = None) -> None:  # pragma: no cover
        raise NotImplementedError

    def close(self) -> None:  # pragma: no cover
        raise NotImplementedError

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


class PtyServer(_ServerBase):
    """The emulator on the master end of a new pseudo-terminal."""

    def __init__(self, emulator: Emulator, on_event: EventCallback | None = None):
        super().__init__(emulator, on_event)
        master, slave = os.openpty()
        tty.setraw(master)
        tty.setraw(slave)
        self.master_fd = master
        self.slave_path = os.ttyname(slave)
        os.close(slave)   # let clients open and close it; EIO on the master means "no client"
        self.connected = False

    def serve(self, stop: threading.Event | None = None) -> None:
        """Answer on the pty until ``stop`` is set."""
        stop = stop or self._stop
        fd = self.master_fd
        while not stop.is_set():
            try:
                ready, _, _ = select.select([fd], [], [], POLL_S)
            except (OSError, ValueError):
                return
            if not ready:
                if not self.connected:
                    self._set_connected(True)
                self._idle()
                continue
            try:
                data = os.read(fd, 65536)
            except OSError as exc:
                if exc.errno != errno.EIO:
                    log.error("pty %s: %s", self.slave_path, exc.strerror)
                    return
                if self.connected:
                    self._set_connected(False)
                self._idle()
                stop.wait(POLL_S)
                continue
            received = time.monotonic()
            if not self.connected:
                self._set_connected(True)
            out = self._answer(data, received, stop)
            if out:
                self._write(out)

    def _write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            try:
                view = view[os.write(self.master_fd, view):]
            except OSError as exc:
                log.warning("pty %s: reply dropped (%s)", self.slave_path, exc.strerror)
                return

    def _set_connected(self, connected: bool) -> None:
        self.connected = connected
        if connected:
            self.connections += 1
            self._event(f"client opened {self.slave_path} (connection {self.connections})")
        else:
            self._event(f"client closed {self.slave_path}")

    def close(self) -> None:
        try:
            os.close(self.master_fd)
        except OSError:
            pass


def listening_socket(host: str, port: int) -> socket.socket:
    """A TCP socket bound to ``host:port`` (port 0: a free one) and listening; UserError (one
    line) when the address cannot be used."""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
        family, _, _, _, addr = infos[0]
        sock = socket.socket(family, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(addr)
        sock.listen(8)
    except OSError as exc:
        raise UserError(f"cannot listen on {host}:{port}: {exc.strerror or exc}; choose "
                        "another port or stop the program using it") from None
    return sock


def parse_host_port(text: str) -> tuple[str, int]:
    """``HOST:PORT`` -> (host, port); UserError when malformed."""
    host, sep, port = text.rpartition(":")
    if not sep or not host:
        raise UserError(f"--socket {text!r}: expected HOST:PORT, e.g. 127.0.0.1:5555")
    try:
        number = int(port)
    except ValueError:
        raise UserError(f"--socket {text!r}: port {port!r} is not a number") from None
    if not 0 <= number <= 65535:
        raise UserError(f"--socket {text!r}: port must be 0..65535")
    return host.strip("[]"), number


@dataclass
class _Conn:
    """One TCP connection: its socket, peer text, when it came, when it last sent bytes."""

    sock: socket.socket
    peer: str
    number: int
    since: float = field(default_factory=time.time)
    last_rx: float = field(default_factory=time.monotonic)
    decoder: FrameDecoder = field(default_factory=FrameDecoder)
    busy_answers: int = 0


class TcpServer(_ServerBase):
    """The emulator on a listening TCP socket, one client at a time.

    The first connection is served; while it is, every further connection is told at once
    that the board is busy: each frame it sends is answered with ERROR BUSY (its seq, nonce 0,
    ``detail`` = seconds the current client has been served, the message naming the client and
    since when) and nothing reaches the board. A legacy-protocol server closes such a
    connection instead (the line protocol has no BUSY). When the served client leaves, the
    longest-waiting connection is served next. A served client that sends nothing for
    ``idle_timeout_s`` seconds (0 or None: never) is disconnected, which frees the board.
    ``sock``: a socket already listening on ``host:port`` (:func:`listening_socket`, so a
    caller can refuse an address before it makes anything), else one is opened here.
    """

    def __init__(self, emulator: Emulator, host: str, port: int,
                 on_event: EventCallback | None = None,
                 idle_timeout_s: float | None = DEFAULT_IDLE_TIMEOUT_S,
                 sock: socket.socket | None = None):
        super().__init__(emulator, on_event)
        if idle_timeout_s is not None and idle_timeout_s < 0:
            raise UserError(f"--idle-timeout must be >= 0 seconds, got {idle_timeout_s}")
        self.idle_timeout_s = idle_timeout_s or None
        self.sock = listening_socket(host, port) if sock is None else sock
        self.address = self.sock.getsockname()[:2]
        self._active: _Conn | None = None
        self._waiting: list[_Conn] = []
        self.busy_answers = 0
        self.dropped_idle = 0

    @property
    def url(self) -> str:
        """The pyserial URL of this server (``socket://host:port``)."""
        host, port = self.address
        return f"socket://{'[' + host + ']' if ':' in host else host}:{port}"

    def serve(self, stop: threading.Event | None = None) -> None:
        """Accept and serve clients until ``stop`` is set."""
        stop = stop or self._stop
        self._serving = stop
        try:
            while not stop.is_set():
                conns = ([self._active] if self._active else []) + self._waiting
                try:
                    ready, _, _ = select.select([self.sock] + [c.sock for c in conns], [], [],
                                                POLL_S)
                except (OSError, ValueError):
                    return
                if not ready:
                    self._idle()
                    self._drop_idle()
                    continue
                for sock in ready:
                    if sock is self.sock:
                        self._accept()
                        continue
                    conn = next((c for c in conns if c.sock is sock), None)
                    if conn is not None:
                        self._receive(conn)
                self._drop_idle()
        finally:
            for conn in ([self._active] if self._active else []) + self._waiting:
                self._close(conn, "server stopped")

    # -- connections ------------------------------------------------------------------------
    def _accept(self) -> None:
        try:
            sock, peer = self.sock.accept()
        except OSError:
            return
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.connections += 1
        conn = _Conn(sock, f"{peer[0]}:{peer[1]}", self.connections)
        if self._active is None:
            self._activate(conn)
            return
        active = self._active
        if self.emulator.protocol != "framed":
            self._event(f"connection {conn.number} from {conn.peer} refused: the board is busy "
                        f"serving {active.peer} (the line protocol has no BUSY answer)")
            self._close(conn, None)
            return
        self._event(f"connection {conn.number} from {conn.peer}: the board is busy serving "
                    f"{active.peer} since {_hms(active.since)}; its requests are answered BUSY")
        self._waiting.append(conn)

    def _activate(self, conn: _Conn) -> None:
        conn.since, conn.last_rx = time.time(), time.monotonic()
        self._active = conn
        self._event(f"connection {conn.number} from {conn.peer}")

    def _receive(self, conn: _Conn) -> None:
        try:
            data = conn.sock.recv(65536)
        except OSError:
            data = b""
        if not data:
            self._close(conn, "closed")
            return
        conn.last_rx = time.monotonic()
        if conn is not self._active:
            self._answer_busy(conn, data)
            return
        out = self._answer(data, conn.last_rx, getattr(self, "_serving", self._stop))
        conn.last_rx = time.monotonic()     # idle counts from the end of the board's work
        if out:
            try:
                conn.sock.sendall(out)
            except OSError:
                self._close(conn, "closed")

    def _answer_busy(self, conn: _Conn, data: bytes) -> None:
        """ERROR BUSY for every checked frame of a waiting connection, a NAK for every damaged
        one (docs/protocol.md, section 4: nonce 0, the board never saw them); nothing is
        executed."""
        active = self._active
        assert active is not None
        served_s = int(max(0.0, time.time() - active.since))
        text = f"serving {active.peer} since {_hms(active.since)}"
        out = bytearray()
        for event in conn.decoder.feed_events(data):
            if isinstance(event, FrameError):     # damaged: the client resends at once, and
                out += encode_frame(Frame.of(nak_reply(event), 0, 0))   # then hears BUSY
                continue
            err = ErrorReply(ErrorCode.BUSY, event.type & 0xFF, served_s & 0xFFFFFFFF,
                             text.encode()[:MAX_TEXT].decode("utf-8", "ignore"))
            out += encode_frame(Frame.of(err, event.seq, 0))
            conn.busy_answers += 1
            self.busy_answers += 1
        if out:
            try:
                conn.sock.sendall(bytes(out))
            except OSError:
                self._close(conn, "closed")

    def _drop_idle(self) -> None:
        limit = self.idle_timeout_s
        if limit is None:
            return
        now = time.monotonic()
        for conn in ([self._active] if self._active else []) + list(self._waiting):
            if now - conn.last_rx >= limit:
                self.dropped_idle += 1
                self._close(conn, f"dropped: no request for {limit:g} s (--idle-timeout)")

    def _close(self, conn: _Conn, why: str | None) -> None:
        try:
            conn.sock.close()
        except OSError:
            pass
        if why is not None:
            self._event(f"connection {conn.number} from {conn.peer} {why}")
        if conn is self._active:
            self._active = None
            if self._waiting:
                self._activate(self._waiting.pop(0))
        elif conn in self._waiting:
            self._waiting.remove(conn)

    def close(self) -> None:
        for s in [c.sock for c in ([self._active] if self._active else []) + self._waiting] \
                + [self.sock]:
            try:
                s.close()
            except OSError:
                pass


def _hms(epoch_s: float) -> str:
    """The time of day of the BUSY message: the server's local time with its UTC offset, ISO
    8601 (``14:03:07+02:00``; docs/protocol.md, section 4), so a host in another zone reads it
    right."""
    return datetime.fromtimestamp(epoch_s).astimezone().isoformat(timespec="seconds")[11:]
