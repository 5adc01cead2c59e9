"""A fault-injecting line between a host and a board, for tests and benches (issue 27).

A real line does more than damage bytes: a USB-serial adapter, a loaded PC or a descheduled
emulator *holds* them - a few tenths of a second now and then, or a whole second or more -
and a cable pulled for a moment loses them. :class:`LineFaults` describes such a line:

* ``rate``: the fraction of bytes damaged, each one flipped (one bit), dropped, duplicated or
  preceded by an inserted random byte (:data:`DAMAGE_KINDS`, equally likely);
* ``delays_per_s`` / ``delay_s``: the line holds everything (both directions) now and then -
  on average ``delays_per_s`` times a second of line time, at seeded random moments - for a
  random time in ``delay_s`` (s), as a busy adapter or PC does whatever the traffic;
* ``delay_rate`` / ``delay_s``: the fraction of bytes before which the line holds for a
  random time in ``delay_s`` (s) - holds that grow with the traffic. Either way the line stays
  first-in first-out, so the bytes behind a held byte wait too;
* ``stalls``: whole stalls of a chosen length (:class:`Stall`): after a given number of
  bytes in one direction the line holds everything (``lose=False``: delivered when the stall
  ends, as an adapter's buffer does) or loses everything (``lose=True``: a dead line) in the
  given directions for ``length_s`` seconds.

Every random choice is drawn per byte from a generator seeded with ``seed`` (and the
direction), so a run is repeatable whatever the chunking of the bytes; only the wall-clock
moments depend on the machine.

Two ways to put it between a client and a board:

* :class:`FaultyTransport` wraps the host's :class:`~snan_hil.protocol.transport.Transport`
  (e.g. the in-process emulator's): single-threaded, the held bytes are delivered while the
  host reads, so it needs no thread and works on a synchronous (in-process) board too - it
  makes the pair asynchronous (``synchronous`` False), like a real line;
* :class:`FaultyRelay` is a TCP proxy (a daemon thread) in front of ``snan-hil emu --socket``
  (``bench/bench_link.py``), one client at a time; what it still holds of a client that
  disconnects is dropped, like a closed port's buffer.

Both count what they did in :class:`FaultStats`.
"""

from __future__ import annotations

import heapq
import random
import select
import socket
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Self

from snan_hil.protocol.transport import Transport

__all__ = ["DAMAGE_KINDS", "DIRECTIONS", "Stall", "LineFaults", "FaultStats", "FaultyStream",
           "FaultyLine", "FaultyTransport", "FaultyRelay"]

DAMAGE_KINDS = ("flip", "drop", "dup", "insert")
"""How a damaged byte is damaged: one bit flipped, dropped, sent twice, a random byte before."""

DIRECTIONS = ("to_board", "to_host")
"""The two directions of a line: host -> board and board -> host."""


@dataclass(frozen=True)
class Stall:
    """The line stalls for ``length_s`` seconds once ``after_bytes`` bytes have passed in
    direction ``trigger`` (one of :data:`DIRECTIONS`); the stall holds (``lose`` False) or
    loses (``lose`` True) the bytes of ``directions`` ("both", "to_board" or "to_host")."""

    after_bytes: int
    length_s: float
    trigger: str = "to_host"
    directions: str = "both"
    lose: bool = False

    def __post_init__(self) -> None:
        if self.after_bytes < 0 or not self.length_s >= 0:
            raise ValueError(f"a stall needs after_bytes >= 0 and length_s >= 0: {self}")
        if self.trigger not in DIRECTIONS:
            raise ValueError(f"trigger must be one of {DIRECTIONS}, got {self.trigger!r}")
        if self.directions not in ("both", *DIRECTIONS):
            raise ValueError(f"directions must be 'both' or one of {DIRECTIONS}")

    def affects(self, direction: str) -> bool:
        """Whether the stall holds or loses the bytes of ``direction``."""
        return self.directions in ("both", direction)


@dataclass(frozen=True)
class LineFaults:
    """What a faulty line does (module docstring); rates are fractions of bytes in [0, 1],
    ``delay_s`` a (shortest, longest) hold in seconds."""

    rate: float = 0.0
    kinds: tuple[str, ...] = DAMAGE_KINDS
    delay_rate: float = 0.0
    delay_s: tuple[float, float] = (0.1, 0.4)
    delays_per_s: float = 0.0
    stalls: tuple[Stall, ...] = ()
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("rate", "delay_rate"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {value}")
        unknown = set(self.kinds) - set(DAMAGE_KINDS)
        if unknown or not self.kinds:
            raise ValueError(f"kinds must be some of {DAMAGE_KINDS}, got {self.kinds}")
        if not self.delays_per_s >= 0:
            raise ValueError(f"delays_per_s must be >= 0, got {self.delays_per_s}")
        low, high = self.delay_s
        if not 0.0 <= low <= high:
            raise ValueError(f"delay_s must be (low, high) with 0 <= low <= high: {self.delay_s}")


@dataclass
class FaultStats:
    """What a faulty line did, both directions together."""

    bytes_in: int = 0           # bytes that entered the line
    bytes_out: int = 0          # bytes that left it
    damaged: dict[str, int] = field(default_factory=lambda: {k: 0 for k in DAMAGE_KINDS})
    delays: int = 0             # holds (delay_rate, delays_per_s) that held bytes
    delay_s: float = 0.0        # their total length, s
    stalls: int = 0             # stalls that began
    stalled_s: float = 0.0      # their total length, s
    lost_in_stalls: int = 0     # bytes lost in stalls with lose=True

    @property
    def damaged_bytes(self) -> int:
        """Bytes damaged, every kind."""
        return sum(self.damaged.values())


class FaultyLine:
    """Both directions of one faulty line: the shared stall state and the statistics."""

    def __init__(self, faults: LineFaults):
        self.faults = faults
        self.stats = FaultStats()
        self.streams = {d: FaultyStream(self, d) for d in DIRECTIONS}
        self._pending = sorted(faults.stalls, key=lambda s: s.after_bytes)
        #: (start, end, stall) of every stall begun
        self.active: list[tuple[float, float, Stall]] = []
        self._hold_rng = random.Random(faults.seed * 2 + 2_000_003)
        self._next_hold: float | None = None
        self._hold = (0.0, 0.0)
        self._hold_counted = True

    def _held_until(self, now: float) -> float:
        """When the current random hold (``delays_per_s``) covering ``now`` ends (0: none)."""
        rate = self.faults.delays_per_s
        if not rate:
            return 0.0
        rng = self._hold_rng
        if self._next_hold is None:
            self._next_hold = now + rng.expovariate(rate)
        while now >= self._next_hold:
            start = self._next_hold
            self._hold = (start, start + rng.uniform(*self.faults.delay_s))
            self._hold_counted = False
            self._next_hold = self._hold[1] + rng.expovariate(rate)
        start, end = self._hold
        if not start <= now < end:
            return 0.0
        if not self._hold_counted:              # count the holds that held bytes
            self._hold_counted = True
            self.stats.delays += 1
            self.stats.delay_s += end - start
        return end

    def _trigger(self, direction: str, count: int, now: float) -> None:
        """Start the stalls whose byte count ``direction`` reached."""
        for stall in list(self._pending):
            if stall.trigger == direction and count >= stall.after_bytes:
                self._pending.remove(stall)
                self.active.append((now, now + stall.length_s, stall))
                self.stats.stalls += 1
                self.stats.stalled_s += stall.length_s

    def _stalled(self, direction: str, now: float) -> tuple[float, bool]:
        """(the time the stalls of ``direction`` covering ``now`` end - 0 if none, whether
        one of them loses bytes)."""
        end, lose = 0.0, False
        for start, stop, stall in self.active:
            if start <= now < stop and stall.affects(direction):
                end = max(end, stop)
                lose = lose or stall.lose
        return end, lose


class FaultyStream:
    """One direction of a :class:`FaultyLine`: ``feed(data, now)`` -> the bytes that leave the
    line and when (a first-in first-out list of (time, bytes))."""

    def __init__(self, line: FaultyLine, direction: str):
        self.line, self.direction = line, direction
        seed = line.faults.seed * 2 + DIRECTIONS.index(direction)
        self._damage_rng = random.Random(seed)
        self._delay_rng = random.Random(seed + 1_000_003)
        self._free = 0.0            # the line is busy holding bytes until then
        self.count = 0              # bytes that entered this direction

    def feed(self, data: bytes, now: float) -> list[tuple[float, bytes]]:
        """The bytes ``data`` entering at ``now`` become: a list of (leave time, bytes)."""
        line, faults, stats = self.line, self.line.faults, self.line.stats
        out: list[tuple[float, bytes]] = []
        for b in data:
            self.count += 1
            stats.bytes_in += 1
            line._trigger(self.direction, self.count, now)
            stall_end, lose = line._stalled(self.direction, now)
            if lose:
                stats.lost_in_stalls += 1
                continue
            leave = max(now, self._free, stall_end, line._held_until(now))
            if faults.delay_rate and self._delay_rng.random() < faults.delay_rate:
                hold = self._delay_rng.uniform(*faults.delay_s)
                stats.delays += 1
                stats.delay_s += hold
                leave += hold
            self._free = leave
            damaged = self._damage(b)
            if damaged:
                stats.bytes_out += len(damaged)
                if out and out[-1][0] == leave:
                    out[-1] = (leave, out[-1][1] + damaged)
                else:
                    out.append((leave, damaged))
        return out

    def _damage(self, b: int) -> bytes:
        faults, rng = self.line.faults, self._damage_rng
        if not faults.rate or rng.random() >= faults.rate:
            return bytes((b,))
        kind = faults.kinds[rng.randrange(len(faults.kinds))]
        self.line.stats.damaged[kind] += 1
        if kind == "flip":
            return bytes((b ^ (1 << rng.randrange(8)),))
        if kind == "dup":
            return bytes((b, b))
        if kind == "insert":
            return bytes((rng.randrange(256), b))
        return b""                                                      # drop


class FaultyTransport(Transport):
    """The host's end of ``inner`` through a faulty line (module docstring).

    Writes enter the host -> board direction and reach ``inner`` when the line lets them go;
    what ``inner`` sends enters the board -> host direction and is readable when it leaves the
    line. Progress happens inside :meth:`read` and :meth:`write` (no thread): a host that
    waits for a reply reads, and that moves the line.
    """

    POLL_S = 0.002
    """How often the inner transport is polled while the line holds bytes (s)."""

    def __init__(self, inner: Transport, faults: LineFaults):
        self.inner, self.faults = inner, faults
        self.name = f"{inner.name} (through a faulty line)"
        self.baud = inner.baud
        self.timeout = inner.timeout
        self.synchronous = False
        self.line = FaultyLine(faults)
        self._to_board: deque[tuple[float, bytes]] = deque()
        self._to_host: deque[tuple[float, bytes]] = deque()

    @property
    def stats(self) -> FaultStats:
        """What the line did so far."""
        return self.line.stats

    def _pump(self) -> None:
        """Deliver what is due to the board; take in what the board sent."""
        now = time.monotonic()
        while self._to_board and self._to_board[0][0] <= now:
            self.inner.write(self._to_board.popleft()[1])
        while True:
            data = self.inner.read(65536, 0.0)
            if not data:
                break
            self._to_host.extend(self.line.streams["to_host"].feed(data, time.monotonic()))

    def _read(self, n: int, timeout: float) -> bytes:
        deadline = time.monotonic() + timeout
        while True:
            self._pump()
            now = time.monotonic()
            if self._to_host and self._to_host[0][0] <= now:
                out = bytearray()
                while self._to_host and self._to_host[0][0] <= now and len(out) < n:
                    out += self._to_host.popleft()[1]
                if len(out) > n:
                    self._to_host.appendleft((now, bytes(out[n:])))
                    del out[n:]
                return bytes(out)
            if now >= deadline:
                return b""
            due = [deadline]
            if self._to_host:
                due.append(self._to_host[0][0])
            if self._to_board:
                due.append(self._to_board[0][0])
            step = min(due) - now
            if not self.inner.synchronous:
                step = min(step, self.POLL_S)   # the board may answer at any moment
            time.sleep(max(0.0, step))

    def write(self, data: bytes) -> None:
        self._to_board.extend(self.line.streams["to_board"].feed(bytes(data), time.monotonic()))
        self._pump()

    def reset_input_buffer(self) -> None:
        """Discard what already left the line towards the host (bytes still on the line
        arrive later, as on a real line)."""
        self._pump()
        now = time.monotonic()
        while self._to_host and self._to_host[0][0] <= now:
            self._to_host.popleft()

    def close(self) -> None:
        self.inner.close()


class TcpRelay:
    """A TCP relay in a daemon thread: listens on ``listen`` (port 0 picks one: :attr:`url`)
    and connects each client to ``target`` (host, port), one client at a time; what happens to
    the bytes of a connection is the subclass's :meth:`_serve` (``start()`` / ``stop()`` or a
    ``with`` block)."""

    def __init__(self, target: tuple[str, int], listen: tuple[str, int] = ("127.0.0.1", 0)):
        self.target = target
        self._sock = socket.create_server(listen)
        self.address: tuple[str, int] = self._sock.getsockname()[:2]
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def url(self) -> str:
        """``socket://host:port`` of the relay (what a client opens)."""
        return f"socket://{self.address[0]}:{self.address[1]}"

    def start(self) -> Self:
        self._thread = threading.Thread(target=self._run, name=type(self).__name__,
                                        daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        self._sock.close()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _run(self) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([self._sock], [], [], 0.05)
            if not ready:
                continue
            try:
                client, _ = self._sock.accept()
            except OSError:
                return
            try:
                upstream = socket.create_connection(self.target)
            except OSError:
                client.close()
                continue
            for s in (client, upstream):
                s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._serve(client, upstream)

    def _serve(self, client: socket.socket, upstream: socket.socket) -> None:
        """Relay one connection until either side closes or the relay stops."""
        raise NotImplementedError


class FaultyRelay(TcpRelay):
    """A TCP proxy with a faulty line in it (module docstring).

    Listens on ``listen`` (port 0 picks one: :attr:`url`) and connects each client to
    ``target`` (host, port), one client at a time; ``faults`` apply to each connection afresh
    (a new :class:`FaultyLine` with the same seed), ``stats`` add up over connections. Runs in
    a daemon thread: ``start()`` / ``stop()`` or a ``with`` block.
    """

    POLL_S = 0.005

    def __init__(self, target: tuple[str, int], faults: LineFaults,
                 listen: tuple[str, int] = ("127.0.0.1", 0)):
        super().__init__(target, listen)
        self.faults = faults
        self.lines: list[FaultyLine] = []

    @property
    def stats(self) -> FaultStats:
        """What the lines of every connection did, added up."""
        total = FaultStats()
        for line in self.lines:
            s = line.stats
            total.bytes_in += s.bytes_in
            total.bytes_out += s.bytes_out
            for kind, count in s.damaged.items():
                total.damaged[kind] += count
            total.delays += s.delays
            total.delay_s += s.delay_s
            total.stalls += s.stalls
            total.stalled_s += s.stalled_s
            total.lost_in_stalls += s.lost_in_stalls
        return total

    def _serve(self, client: socket.socket, upstream: socket.socket) -> None:
        line = FaultyLine(self.faults)
        self.lines.append(line)
        self._relay(client, upstream, line)

    def _relay(self, client: socket.socket, upstream: socket.socket, line: FaultyLine) -> None:
        # (leave time, order, destination, bytes): a heap keeps both directions in time order
        queue: list[tuple[float, int, int, bytes]] = []
        order = 0
        route = {client: (upstream, line.streams["to_board"]),
                 upstream: (client, line.streams["to_host"])}
        try:
            while not self._stop.is_set():
                now = time.monotonic()
                while queue and queue[0][0] <= now:
                    _t, _o, dst, data = heapq.heappop(queue)
                    (client if dst == 0 else upstream).sendall(data)
                wait = self.POLL_S if not queue else max(0.0, min(self.POLL_S,
                                                                  queue[0][0] - now))
                ready, _, _ = select.select(list(route), [], [], wait)
                for src in ready:
                    data = src.recv(65536)
                    if not data:
                        return                  # what the line still holds is dropped
                    dst_sock, stream = route[src]
                    dst = 0 if dst_sock is client else 1
                    for leave, chunk in stream.feed(data, time.monotonic()):
                        heapq.heappush(queue, (leave, order, dst, chunk))
                        order += 1
        except OSError:
            return
        finally:
            client.close()
            upstream.close()
