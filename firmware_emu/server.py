"""Serving an :class:`Emulator` on a pseudo-terminal or a TCP socket.

* :class:`PtyServer` opens a pty pair and answers on the master end; :attr:`PtyServer.slave_path`
  (e.g. ``/dev/pts/7``) is what pyserial, minicom or the old host software open as a serial
  port. The server does not keep the slave open itself, so it sees a client open (reads stop
  failing with EIO) and close (EIO again) and reports each as a connection event.
* :class:`TcpServer` listens on HOST:PORT and serves one connection at a time (a serial line
  has one peer); pyserial reaches it as ``socket://HOST:PORT``.

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

from snan_hil.errors import UserError
from snan_hil.firmware_emu.emulator import Emulator

log = logging.getLogger(__name__)

EventCallback = Callable[[str], None]

POLL_S = 0.05
IDLE_SAVE_S = 0.5


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


class TcpServer(_ServerBase):
    """The emulator on a listening TCP socket, one client at a time."""

    def __init__(self, emulator: Emulator, host: str, port: int,
                 on_event: EventCallback | None = None):
        super().__init__(emulator, on_event)
        try:
            infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
            family, _, _, _, addr = infos[0]
            self.sock = socket.socket(family, socket.SOCK_STREAM)
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self.sock.bind(addr)
            self.sock.listen(1)
        except OSError as exc:
            raise UserError(f"cannot listen on {host}:{port}: {exc.strerror or exc}; choose "
                            "another port or stop the program using it") from None
        self.address = self.sock.getsockname()[:2]
        self._client: socket.socket | None = None

    @property
    def url(self) -> str:
        """The pyserial URL of this server (``socket://host:port``)."""
        host, port = self.address
        return f"socket://{'[' + host + ']' if ':' in host else host}:{port}"

    def serve(self, stop: threading.Event | None = None) -> None:
        """Accept and serve clients until ``stop`` is set."""
        stop = stop or self._stop
        while not stop.is_set():
            try:
                ready, _, _ = select.select([self.sock], [], [], POLL_S)
            except (OSError, ValueError):
                return
            if not ready:
                self._idle()
                continue
            try:
                client, peer = self.sock.accept()
            except OSError:
                continue
            self.connections += 1
            self._event(f"connection {self.connections} from {peer[0]}:{peer[1]}")
            self._client = client
            try:
                self._serve_client(client, stop)
            finally:
                self._client = None
                client.close()
            self._event(f"connection {self.connections} from {peer[0]}:{peer[1]} closed")

    def _serve_client(self, client: socket.socket, stop: threading.Event) -> None:
        client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        while not stop.is_set():
            ready, _, _ = select.select([client], [], [], POLL_S)
            if not ready:
                self._idle()
                continue
            try:
                data = client.recv(65536)
            except OSError:
                return
            if not data:
                return
            out = self._answer(data, time.monotonic(), stop)
            if out:
                try:
                    client.sendall(out)
                except OSError:
                    return

    def close(self) -> None:
        for s in (self._client, self.sock):
            if s is not None:
                try:
                    s.close()
                except OSError:
                    pass
