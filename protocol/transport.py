"""Byte transports between host and board: one small interface, several implementations.

:class:`Transport` is pyserial-like: ``read(n, timeout)`` returns 1..n bytes as soon as any are
available (or ``b""`` after ``timeout`` seconds), ``write(data)``, ``reset_input_buffer()``,
``close()``, plus ``name`` (for error messages) and ``baud`` (bits/s of the line, ``None``
where there is no line).

Implementations:

- :class:`SerialTransport` — anything ``serial.serial_for_url`` opens: a device path
  (``/dev/ttyUSB0``, ``COM3``), ``loop://``, ``socket://host:port``, ``rfc2217://host:port``,
  and URL schemes other packages register with pyserial (the emulator's ``emu://``).
- :class:`PtyTransport` + :func:`open_pty_pair` — the master end of a pseudo-terminal (the
  board side of the emulator); the slave path is opened by pyserial like a real port.
- :func:`pipe_pair` — two connected in-process :class:`PipeTransport` ends (threads).
- :class:`CallbackTransport` — synchronous in-process board: ``write`` hands the bytes to a
  function (e.g. ``DeviceEndpoint.feed``) and buffers what it returns for ``read``.
- :class:`PacedTransport` — wrapper that paces bytes at a baud rate (10 bits per byte), so a
  pty or pipe behaves like a UART in time.
"""

from __future__ import annotations

import errno
import os
import select
import threading
import time
import tty
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import serial

from snan_hil.protocol.errors import TransportError

__all__ = [
    "DEFAULT_BAUD", "BITS_PER_BYTE", "Transport", "SerialTransport", "PtyTransport", "PtyPair",
    "open_pty_pair", "PipeTransport", "pipe_pair", "CallbackTransport", "PacedTransport",
    "wire_seconds",
]

DEFAULT_BAUD = 115200
BITS_PER_BYTE = 10  # 8N1: start + 8 data + stop


def wire_seconds(n_bytes: int, baud: int | None) -> float:
    """Time (s) ``n_bytes`` take on a UART at ``baud`` (0 if there is no line)."""
    return n_bytes * BITS_PER_BYTE / baud if baud else 0.0


class Transport(ABC):
    """A bidirectional byte stream. Subclasses implement ``_read``/``write``."""

    name: str = "transport"
    #: Line rate in bits/s, or None for in-process transports without a line.
    baud: int | None = None
    #: True when the other end answers inside ``write`` (in-process): an empty read then means
    #: nothing more will arrive, so a client need not wait for its timeout.
    synchronous: bool = False
    #: Default read timeout in seconds when ``read`` is called without one.
    timeout: float = 0.1

    def read(self, n: int = 1, timeout: float | None = None) -> bytes:
        """1..n bytes as soon as any are available, or b"" after ``timeout`` s."""
        return self._read(max(1, n), self.timeout if timeout is None else max(0.0, timeout))

    @abstractmethod
    def _read(self, n: int, timeout: float) -> bytes: ...

    @abstractmethod
    def write(self, data: bytes) -> None:
        """Send all of ``data`` (raises TransportError)."""

    def reset_input_buffer(self) -> None:
        """Discard received bytes not yet read."""
        while self._read(65536, 0.0):
            pass

    def pipeline(self, on: bool) -> None:  # noqa: B027 - optional hook: a line needs nothing
        """The host keeps requests outstanding (``on``) or waits for each reply: an in-process
        board must then let bytes arrive while it works instead of answering inside
        ``write`` (a real line does so anyway)."""

    def close(self) -> None:  # noqa: B027 - optional hook: most transports have nothing to free
        """Release the transport (idempotent)."""

    def __enter__(self) -> "Transport":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r})"


# --------------------------------------------------------------------------- pyserial
class SerialTransport(Transport):
    """A port opened with ``serial.serial_for_url`` (device path or URL).

    ``exclusive`` (POSIX device paths) takes an advisory lock so a port already used by another
    program is reported as busy instead of silently shared. A pyserial port class with a true
    ``synchronous`` attribute (an in-process board that answers inside ``write``) makes the
    transport synchronous: an empty read returns at once.
    """

    POLL_S = 0.02

    def __init__(self, url: str, baud: int = DEFAULT_BAUD, *, timeout: float = 0.1,
                 exclusive: bool = True):
        self.name, self.baud, self.timeout = url, int(baud), timeout
        kwargs: dict[str, Any] = {"baudrate": self.baud, "timeout": self.POLL_S,
                                  "write_timeout": None}
        if exclusive and not url.partition("://")[1]:
            kwargs["exclusive"] = True
        try:
            self._ser = serial.serial_for_url(url, **kwargs)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise TransportError(f"cannot open {url}: {_reason(exc)}") from None
        self._errors = _io_errors(serial.SerialException)
        self.synchronous = bool(getattr(self._ser, "synchronous", False))
        self._closed = False

    @property
    def serial(self):  # noqa: ANN201 - pyserial object, for callers that need it
        """The underlying pyserial object."""
        return self._ser

    def pipeline(self, on: bool) -> None:
        hook = getattr(self._ser, "pipeline", None)
        if hook is not None:
            hook(on)

    def _read(self, n: int, timeout: float) -> bytes:
        deadline = time.monotonic() + timeout
        ser = self._ser
        try:
            while True:
                waiting = ser.in_waiting
                if waiting:
                    return ser.read(min(n, waiting))
                if self.synchronous:
                    return b""
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return b""
                step = self.POLL_S if remaining >= self.POLL_S else remaining
                if ser.timeout != step:
                    ser.timeout = step
                first = ser.read(1)
                if first:
                    more = ser.in_waiting if n > 1 else 0
                    return first + ser.read(min(n - 1, more)) if more else first
        except self._errors as exc:
            raise self._lost("read from", exc) from None

    def write(self, data: bytes) -> None:
        try:
            self._ser.write(bytes(data))
        except self._errors as exc:
            raise self._lost("write to", exc) from None

    def reset_input_buffer(self) -> None:
        try:
            self._ser.reset_input_buffer()
        except self._errors as exc:
            raise self._lost("flushing", exc) from None

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            try:
                self._ser.close()
            except self._errors:
                pass

    def _lost(self, what: str, exc: BaseException) -> TransportError:
        idle = (" (a 'snan-hil emu --socket' server also drops a client that was silent for "
                "its --idle-timeout)") if self.name.startswith(("socket://", "rfc2217://")) \
            else ""
        return TransportError(
            f"{what} {self.name} failed ({_reason(exc)}): the board or emulator went away"
            f"{idle}; check cable and power, or restart 'snan-hil emu', then run the command "
            "again")


def _io_errors(serial_exception: type[BaseException]) -> tuple[type[BaseException], ...]:
    """Exceptions pyserial lets escape on a vanished port (termios.error is no OSError)."""
    errors: tuple[type[BaseException], ...] = (serial_exception, OSError)
    try:
        import termios
        errors += (termios.error,)
    except ImportError:  # pragma: no cover - Windows
        pass
    return errors


def _reason(exc: BaseException) -> str:
    if not isinstance(exc, OSError) and len(exc.args) == 2 and isinstance(exc.args[1], str):
        return exc.args[1]                                       # termios.error(errno, text)
    text = str(exc).strip() or type(exc).__name__
    return text.splitlines()[0]


# --------------------------------------------------------------------------- pty
class PtyTransport(Transport):
    """A raw file descriptor, typically a pty master (the board side of the emulator)."""

    def __init__(self, fd: int, name: str = "pty", baud: int | None = None,
                 owns_fd: bool = True):
        self.fd, self.name, self.baud, self._owns = fd, name, baud, owns_fd
        self._closed = False

    def _read(self, n: int, timeout: float) -> bytes:
        if self._closed:
            raise TransportError(f"{self.name} is closed")
        try:
            ready, _, _ = select.select([self.fd], [], [], timeout)
            if not ready:
                return b""
            return os.read(self.fd, n)
        except OSError as exc:
            if exc.errno == errno.EIO:  # no process holds the slave end open
                time.sleep(min(timeout, 0.05))
                return b""
            raise TransportError(f"read from {self.name} failed: {exc.strerror}") from None

    def write(self, data: bytes) -> None:
        view = memoryview(bytes(data))
        try:
            while view:
                sent = os.write(self.fd, view)
                view = view[sent:]
        except OSError as exc:
            raise TransportError(f"write to {self.name} failed: {exc.strerror}") from None

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            if self._owns:
                try:
                    os.close(self.fd)
                except OSError:
                    pass


@dataclass
class PtyPair:
    """A pseudo-terminal: ``master`` (transport for the board side) and ``slave_path``.

    The pair keeps its own descriptor of the slave open (raw mode) so the master never sees EIO
    while no client is connected. Any serial program can open ``slave_path``.
    """

    master: PtyTransport
    slave_path: str
    slave_fd: int

    def close(self) -> None:
        self.master.close()
        try:
            os.close(self.slave_fd)
        except OSError:
            pass

    def __enter__(self) -> "PtyPair":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def open_pty_pair(baud: int | None = None) -> PtyPair:
    """Open a pty in raw mode; returns the master transport and the slave's device path."""
    master_fd, slave_fd = os.openpty()
    tty.setraw(slave_fd)
    tty.setraw(master_fd)
    path = os.ttyname(slave_fd)
    return PtyPair(PtyTransport(master_fd, name=f"pty master of {path}", baud=baud),
                   path, slave_fd)


# --------------------------------------------------------------------------- in-process pipes
class _ByteQueue:
    def __init__(self) -> None:
        self.buf = bytearray()
        self.cond = threading.Condition()
        self.closed = False


class PipeTransport(Transport):
    """One end of an in-process byte pipe (see :func:`pipe_pair`); thread-safe."""

    def __init__(self, rx: _ByteQueue, tx: _ByteQueue, name: str, baud: int | None = None):
        self._rx, self._tx, self.name, self.baud = rx, tx, name, baud

    def _read(self, n: int, timeout: float) -> bytes:
        q = self._rx
        with q.cond:
            if not q.buf and not q.closed:
                q.cond.wait_for(lambda: q.buf or q.closed, timeout)
            data = bytes(q.buf[:n])
            del q.buf[:n]
            return data

    def write(self, data: bytes) -> None:
        q = self._tx
        with q.cond:
            if q.closed:
                raise TransportError(f"{self.name}: the other end is closed")
            q.buf += data
            q.cond.notify_all()

    def reset_input_buffer(self) -> None:
        with self._rx.cond:
            self._rx.buf.clear()

    def close(self) -> None:
        for q in (self._rx, self._tx):
            with q.cond:
                q.closed = True
                q.cond.notify_all()


def pipe_pair(name: str = "pipe", baud: int | None = None) -> tuple[PipeTransport, PipeTransport]:
    """Two connected in-process transports: (host end, board end)."""
    a, b = _ByteQueue(), _ByteQueue()
    return (PipeTransport(a, b, f"{name} (host end)", baud),
            PipeTransport(b, a, f"{name} (board end)", baud))


# --------------------------------------------------------------------------- synchronous
class CallbackTransport(Transport):
    """Synchronous in-process board: ``respond(bytes_written) -> bytes_to_read``.

    Wrap a sans-IO endpoint: ``CallbackTransport(endpoint.feed, name="emu")``. No threads;
    ``synchronous`` is True, so a client does not wait for its timeout when a reply was lost.
    ``on_close`` (optional) runs once at close (e.g. save emulator state).
    """

    synchronous = True

    def __init__(self, respond: Callable[[bytes], bytes], name: str = "in-process",
                 baud: int | None = None, on_close: Callable[[], None] | None = None):
        self._respond, self.name, self.baud, self._on_close = respond, name, baud, on_close
        self._rx = bytearray()
        self._lock = threading.Lock()
        self._closed = False

    def _read(self, n: int, timeout: float) -> bytes:
        with self._lock:
            data = bytes(self._rx[:n])
            del self._rx[:n]
            return data

    def write(self, data: bytes) -> None:
        if self._closed:
            raise TransportError(f"{self.name} is closed")
        out = self._respond(bytes(data))
        if out:
            with self._lock:
                self._rx += out

    def reset_input_buffer(self) -> None:
        with self._lock:
            self._rx.clear()

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            if self._on_close is not None:
                self._on_close()


# --------------------------------------------------------------------------- pacing
class PacedTransport(Transport):
    """Paces an inner transport at ``baud`` (10 bits per byte), like a UART.

    Writes: the call returns when the bytes would have left the line; they are handed to the
    inner transport in slices of ``slice_s`` seconds of line time, each no earlier than its
    wire time. Reads (``pace_reads``): bytes become readable no earlier than the time their
    last bit would have arrived, counted from when the reader first saw them (or from the end
    of the previous byte, whichever is later). Pacing only the board side of a pty/pipe makes
    both directions of a round trip take wire time. Wall-clock sleeps only; no busy waiting.
    """

    def __init__(self, inner: Transport, baud: int, *, pace_reads: bool = True,
                 pace_writes: bool = True, slice_s: float = 0.002):
        self.inner, self.baud = inner, int(baud)
        self.name = inner.name
        self.synchronous = inner.synchronous
        self.pace_reads, self.pace_writes, self.slice_s = pace_reads, pace_writes, slice_s
        self._byte_s = BITS_PER_BYTE / self.baud
        self._tx_free = 0.0  # monotonic time the transmit line becomes free
        self._rx_free = 0.0

    def pipeline(self, on: bool) -> None:
        self.inner.pipeline(on)

    def _read(self, n: int, timeout: float) -> bytes:
        data = self.inner.read(n, timeout)
        if data and self.pace_reads:
            start = max(time.monotonic(), self._rx_free)
            self._rx_free = start + len(data) * self._byte_s
            _sleep_until(self._rx_free)
        return data

    def write(self, data: bytes) -> None:
        data = bytes(data)
        if not self.pace_writes:
            self.inner.write(data)
            return
        step = max(1, int(self.slice_s / self._byte_s))
        t = max(time.monotonic(), self._tx_free)
        for pos in range(0, len(data), step):
            chunk = data[pos:pos + step]
            t += len(chunk) * self._byte_s
            _sleep_until(t)
            self.inner.write(chunk)
        self._tx_free = t

    def reset_input_buffer(self) -> None:
        self.inner.reset_input_buffer()

    def close(self) -> None:
        self.inner.close()


def _sleep_until(t: float) -> None:
    delay = t - time.monotonic()
    if delay > 0:
        time.sleep(delay)
