"""The differential tester at speed: seeded request streams, both MCUs, every write compared.

:mod:`.differential` draws its sequences with hypothesis (which shrinks a finding to a minimal
sequence) and spends most of its time drawing; this module draws from a seeded
:class:`random.Random` instead, so millions of frames can be compared (``bench/
bench_differential.py --fast``, the mutation tests of ``bench/bench_mutation.py``). The boards
are in-process emulators on copies of one chip without state files (kills and journal replays
are :mod:`.differential`'s); after **every write** both must give the same reply bytes (but
the free fields), the same SPI frames (chip select and bytes) and the same chip (conductance
states, breakdown, programming times, its clock and noise stream, the ADC noise stream), and
the firmware MCU no fault or reset.

The mix (per write): requests of every kind and code class - reads at 0 V, nominal, below, at
and above the limit, out-of-range cells, column reads, pulses (allowed and refused), small spike
batches, write-and-verify, STATUS, CLOCK, HELLO, RESET, raw and mutated payloads - with the
board's nonce mostly, else 0, a stale or a random one, any header flags or version now and then;
retransmissions of a recent request (only the latest SPIKE_BATCH: docs/firmware.md), damaged
frames, frames split over writes and two frames in one write, and a clean power cycle now and
then.
"""

from __future__ import annotations

import json
import random
import struct
import time
from dataclasses import dataclass, field
from typing import Any

from snan_hil.firmware_emu.config import BoardConfig
from snan_hil.firmware_emu.differential import raw_frame, wire
from snan_hil.firmware_emu.emulator import Emulator
from snan_hil.firmware_emu.testing import default_array
from snan_hil.firmware_emu.twin import ALL_FREE, Divergence
from snan_hil.protocol import messages as m
from snan_hil.protocol.conformance import compare_replies, frames_of
from snan_hil.protocol.crc import crc16
from snan_hil.protocol.frames import FLAG_RETRANSMIT, Frame, cobs_encode, peek_header

__all__ = ["SERIALS", "FastStats", "FastTwin", "RequestStream", "run_stream", "count_frames"]

B = BoardConfig()


@dataclass
class FastStats:
    """What a run did: writes (each compared), frames in them, power cycles, wall time."""

    writes: int = 0
    frames: int = 0
    restarts: int = 0
    seconds: float = 0.0
    cpu_seconds: float = 0.0
    kinds: dict[str, int] = field(default_factory=dict)

    @property
    def frames_per_s(self) -> float:
        """Compared frames per second of wall time."""
        return self.frames / self.seconds if self.seconds > 0 else 0.0

    @property
    def frames_per_cpu_s(self) -> float:
        """Compared frames per CPU-second of this process (independent of other load)."""
        return self.frames / self.cpu_seconds if self.cpu_seconds > 0 else 0.0


SERIALS = ("8B297CA46845", "A1", "0123456789ABCDEFGHIJKLMNOPQ", "Z-9_x.y", None)
"""Chip serials of the runs: usual, shortest, longest (27), every character class, none."""


def _emulator(serial: str | None, **kwargs: Any) -> Emulator:
    """An emulator without a state file whose chip has ``serial`` (the EEPROM identity record
    of the C firmware, ``Firmware.chip_id`` of the model), as a chip file would give it."""
    cls = type("SerialEmulator", (Emulator,), {"chip_serial": property(lambda self: serial)})
    return cls(None, **kwargs)


class FastTwin:
    """Both MCUs on copies of chip ``chip_seed`` (no state files) with the chip serial
    ``serial``, booted with ``nonces``. ``elf``: the firmware ELF (None: the default).
    :meth:`send` feeds both and compares; besides the bytes, an INFO's board id must name the
    chip's serial on both (the part before the ``/`` is the implementation's)."""

    def __init__(self, chip_seed: int, nonces: tuple[int, ...], *, elf: Any = None,
                 on_boot: Any = None, serial: str | None = None) -> None:
        self.chip_seed, self.nonces, self.elf = chip_seed, nonces, elf
        self.on_boot = on_boot
        self.serial = serial
        self.outs: dict[str, bytes] = {}
        """Both boards' answers to the last write."""
        self.arrays = {mcu: default_array(chip_seed) for mcu in ("model", "firmware")}
        self.emus: dict[str, Emulator] = {}
        self._boot()

    def _boot(self) -> None:
        for mcu, array in self.arrays.items():
            emu = _emulator(self.serial, seed=self.chip_seed, array=array, mcu=mcu,
                            boot_nonces=self.nonces,
                            elf=self.elf if mcu == "firmware" else None)
            emu.board.bus.trace = []
            self.emus[mcu] = emu
            if self.on_boot is not None and emu.backend is not None:
                self.on_boot(emu.backend.mcu)    # e.g. a coverage hook
        self._check("power-on")

    def restart(self, nonces: tuple[int, ...]) -> None:
        """A clean power cycle of both boards (the chips keep their state)."""
        for emu in self.emus.values():
            emu.close()
        self.nonces = nonces
        self._boot()

    def send(self, data: bytes, name: str) -> bytes:
        outs = self.outs = {mcu: emu.feed(data) for mcu, emu in self.emus.items()}
        why = compare_replies(outs["model"], outs["firmware"], ALL_FREE)
        if why:
            raise Divergence(f"{name}: replies differ: {why}")
        for mcu, out in outs.items():
            for serial in _info_serials(out):
                if serial != (self.serial or ""):
                    raise Divergence(f"{name}: the {mcu} names chip serial {serial!r} in "
                                     f"INFO, the chip's is {self.serial!r}")
        self._check(name)
        return outs["model"]

    def _check(self, name: str) -> None:
        a, b = self.emus["model"], self.emus["firmware"]
        mcu = b.backend.mcu if b.backend is not None else None
        if mcu is not None and (mcu.faults or mcu.resets):
            raise Divergence(f"{name}: the firmware MCU faulted: {dict(mcu.faults)}, resets "
                             f"{dict(mcu.reset_causes)}")
        ta, tb = a.board.bus.trace, b.board.bus.trace
        assert ta is not None and tb is not None
        if len(ta) != len(tb) or any(x.cs != y.cs or x.mosi != y.mosi for x, y in zip(ta, tb)):
            raise Divergence(f"{name}: SPI traffic differs ({len(ta)} frames on the model, "
                             f"{len(tb)} on the firmware)")
        ta.clear()
        tb.clear()
        ca, cb = a.array, b.array
        if not (ca.state.tobytes() == cb.state.tobytes() and ca.broken.tobytes() ==
                cb.broken.tobytes() and ca.t_prog.tobytes() == cb.t_prog.tobytes()
                and ca.time_s == cb.time_s):
            raise Divergence(f"{name}: the chips differ")
        if ca.noise_state != cb.noise_state or \
                a.board.front_end._rng.bit_generator.state != \
                b.board.front_end._rng.bit_generator.state:
            raise Divergence(f"{name}: the noise streams differ")

    def close(self) -> None:
        for emu in self.emus.values():
            emu.close()


def _info_serials(out: bytes) -> list[str]:
    """The chip serial of every INFO in ``out`` (the board id after its ``/``; "" without)."""
    found = []
    for seg in out.split(b"\0"):
        head = peek_header(seg) if seg else None
        if head is None or head[2] != m.Info.TYPE:
            continue
        for f in frames_of(seg + b"\0"):
            if isinstance(f, Frame):
                info = f.message()
                assert isinstance(info, m.Info)
                found.append(info.board_id.partition("/")[2])
    return found


def _pick(r: random.Random, weighted: list[tuple[float, Any]]) -> Any:
    """One of the weighted options; a callable option is called (only the one picked draws
    from ``r``)."""
    x = r.random() * sum(w for w, _ in weighted)
    value = weighted[-1][1]
    for w, v in weighted:
        x -= w
        if x <= 0:
            value = v
            break
    return value() if callable(value) else value


class RequestStream:
    """Seeded writes for a :class:`FastTwin` (module docstring): :meth:`next` -> (bytes, kind).
    Keeps what a host knows: the board's nonce (from INFO / RESET replies), the next seq, the
    last requests for retransmission."""

    def __init__(self, seed: int) -> None:
        self.r = random.Random(seed)
        self.nonce = 0
        self.old = [0x0BADF00D]
        self.seq = self.r.randrange(0x10000)
        self.sent: list[tuple[int, bytes]] = []
        self.last_spike: bytes | None = None
        self.pending: list[bytes] = []
        self.read_at: tuple[int, int] | None = None       # the cell of the last READ_CELL sent
        self.readings: dict[tuple[int, int], int] = {}    # the last reading of each cell

    # ------------------------------------------------------------------ fields
    def _row(self) -> int:
        r = self.r
        return _pick(r, [(3, lambda: r.choice((0, 1, B.rows - 1))),
                         (6, lambda: r.randrange(B.rows)), (0.3, lambda: r.choice((B.rows, 255)))])

    def _col(self) -> int:
        r = self.r
        return _pick(r, [(3, lambda: r.choice((0, 1, B.cols - 1))),
                         (6, lambda: r.randrange(B.cols)),
                         (0.3, lambda: r.choice((B.cols, 31, 255)))])

    def _read_code(self) -> int:
        r, lim, full = self.r, B.max_cell_read_code, B.write_dac_full_scale_code
        return _pick(r, [(4, B.read_code), (2, 0), (3, lambda: r.randint(1, lim)),
                         (0.3, lim + 1), (0.3, lambda: r.randint(lim + 1, full)),
                         (0.2, full + 1), (0.2, lambda: r.randrange(0x10000))])

    def _row_code(self) -> int:
        r, lim = self.r, B.max_row_read_code
        return _pick(r, [(6, 0), (2, B.read_code), (2, lambda: r.randint(1, lim)),
                         (0.1, lambda: r.choice((lim + 1, B.dac_full_scale_code))),
                         (0.05, lambda: r.randrange(0x10000))])

    # ------------------------------------------------------------------ messages
    def _message(self) -> tuple[str, m.Request | tuple[int, bytes]]:
        r = self.r
        kind = _pick(r, [(30, "read_cell"), (10, "read_column"), (6, "write_pulse"),
                         (4, "spike_batch"), (1.5, "program_cell"), (8, "status"),
                         (4, "clock"), (2, "hello"), (0.7, "reset"), (2, "raw"),
                         (3, "mutated")])
        return kind, self._build(kind)

    def _build(self, kind: str) -> m.Request | tuple[int, bytes]:
        r = self.r
        if kind == "read_cell":
            req = m.ReadCell(self._row(), self._col(), self._read_code())
            self.read_at = (req.row, req.col) if req.dac_code in (0, B.read_code) else None
            return req
        if kind == "read_column":
            n = B.rows if r.random() < 0.95 else r.randint(0, 40)
            return m.ReadColumn(self._col(), tuple(self._row_code() for _ in range(n)))
        if kind == "write_pulse":
            amp = _pick(r, [(8, lambda: r.randint(1, 700)),
                            (1, lambda: r.randint(701, B.max_write_code)),
                            (0.5, lambda: r.choice((0, B.max_write_code + 1, 4095)))])
            width = _pick(r, [(9, lambda: r.randint(1, 500)),
                              (0.5, lambda: r.choice((0, 1_000_001)))])
            return m.WritePulse(self._row(), self._col(), r.choice(list(m.Polarity)), amp,
                                width, 0 if r.random() < 0.7 else self._read_code())
        if kind == "spike_batch":
            n_bins = r.randint(1, 8)
            cols = tuple(sorted(r.sample(range(B.cols), r.randint(0, 3))))
            groups = tuple(m.SpikeGroup(
                tuple((self._row(), self._row_code() or B.read_code)
                      for _ in range(r.randint(0, 3))),
                tuple(sorted(r.sample(range(n_bins), r.randint(0, n_bins)))))
                for _ in range(r.randint(0, 2)))
            return m.SpikeBatch(groups, cols, n_bins, r.choice((1000, 50, 0)),
                                r.randrange(0x10000), r.random() < 0.1)
        if kind == "program_cell":
            start = r.choice((1, 2, r.randint(1, B.max_write_code)))
            ramp = (0, 0, 0) if r.random() < 0.6 else (
                start, r.choice((start, r.randint(1, B.max_write_code), B.max_write_code,
                                 B.max_write_code + 1)),
                r.choice((1, 2, r.randint(1, 200))))
            if self.readings and r.random() < 0.4:
                # a target at (or next to) the cell's last reading: the stop rules' boundaries
                (row, col), last = r.choice(sorted(self.readings.items()))
                return m.ProgramCell(row, col, max(0, last + r.randint(-2, 2)), r.randint(0, 3),
                                     r.randint(1, 4), *ramp)
            return m.ProgramCell(self._row(), self._col(), r.randint(0, B.adc_full_scale_code),
                                 r.randint(0, 400), r.randint(0, 6), *ramp)
        if kind == "status":
            return m.Status()
        if kind == "clock":
            return m.Clock()
        if kind == "hello":
            return m.Hello(1 if r.random() < 0.9 else r.randrange(256))
        if kind == "reset":
            return m.Reset()
        if kind == "raw":
            return (r.randrange(256), bytes(r.randrange(256) for _ in range(r.randint(0, 40))))
        inner = self._build(r.choice(("read_cell", "read_column", "write_pulse", "spike_batch",
                                      "program_cell", "hello")))
        assert isinstance(inner, m.Request)
        payload = bytearray(inner.encode())
        how = r.choice(("set", "cut", "add"))
        if how == "set" and payload:
            payload[r.randrange(len(payload))] = r.randrange(256)
        elif how == "cut" and payload:
            del payload[r.randrange(len(payload)):]
        else:
            payload += bytes(r.randrange(256) for _ in range(r.randint(1, 4)))
        return (inner.TYPE, bytes(payload))

    def _frame(self) -> tuple[str, int, bytes]:
        r = self.r
        kind, msg = self._message()
        type_, payload = msg if isinstance(msg, tuple) else (msg.TYPE, msg.encode())
        which = _pick(r, [(90, self.nonce), (4, 0), (3, self.old[-1]),
                          (3, lambda: r.randrange(1 << 32))])
        self.seq = (self.seq + 1) & 0xFFFF
        seq = self.seq if r.random() < 0.97 else r.randrange(0x10000)
        flags = 0 if r.random() < 0.97 else r.randrange(256)
        version = 1 if r.random() < 0.98 else r.randrange(256)
        raw = raw_frame(type_, seq, payload, which, flags=flags, version=version)
        self.sent = (self.sent + [(type_, raw)])[-4:]
        if type_ == m.SpikeBatch.TYPE:
            self.last_spike = raw
        return kind, type_, raw

    # ------------------------------------------------------------------ writes
    def hello(self) -> bytes:
        self.seq = (self.seq + 1) & 0xFFFF
        return b"\x00" + wire(raw_frame(m.Hello.TYPE, self.seq, m.Hello().encode(), 0))

    def next(self) -> tuple[bytes, str]:
        """The next write and its kind."""
        r = self.r
        if self.pending:
            return self.pending.pop(0), "split"
        what = _pick(r, [(85, "request"), (5, "retransmit"), (4, "damaged"), (3, "split"),
                         (3, "two")])
        if what == "retransmit" and self.sent:
            type_, raw = r.choice(self.sent)
            if type_ != m.SpikeBatch.TYPE or raw is self.last_spike:
                again = bytearray(raw)
                again[1] |= FLAG_RETRANSMIT
                again[-2:] = struct.pack("<H", crc16(bytes(again[:-2])))
                return b"\x00" + wire(bytes(again)), "retransmit"
        if what == "damaged":
            _, _, raw = self._frame()
            enc = bytearray(cobs_encode(raw))
            k = r.randrange(len(enc))
            how = r.choice(("flip", "drop", "insert", "cut", "junk"))
            if how == "flip":
                enc[k] = (enc[k] ^ (1 << r.randrange(8))) or 0x80
            elif how == "drop":
                del enc[k]
            elif how == "insert":
                enc.insert(k, r.randint(1, 255))
            elif how == "cut":
                del enc[k:]
            else:
                enc = bytearray(r.randint(1, 255) for _ in range(r.randint(1, 30)))
            return bytes(enc) + b"\x00", "damaged"
        kind, _, raw = self._frame()
        if what == "split":
            w = wire(raw)
            k = r.randint(1, len(w) - 1)
            self.pending = [w[k:]]
            return w[:k], kind
        if what == "two":
            _, _, raw2 = self._frame()
            return wire(raw) + wire(raw2), kind
        return (b"\x00" if r.random() < 0.2 else b"") + wire(raw), kind

    def learn(self, out: bytes) -> None:
        """The board's nonce from an INFO or RESET reply, the reading of the last READ_CELL
        (headers peeked, those frames decoded)."""
        for seg in out.split(b"\0"):
            head = peek_header(seg) if seg else None
            if head is None:
                continue
            if head[2] == m.ReadCellReply.TYPE and self.read_at is not None:
                for f in frames_of(seg + b"\0"):
                    if isinstance(f, Frame):
                        reply = f.message()
                        assert isinstance(reply, m.ReadCellReply)
                        self.readings[self.read_at] = int(reply.adc)
                continue
            if head[2] not in (m.Info.TYPE, m.ResetReply.TYPE):
                continue
            for f in frames_of(seg + b"\0"):
                if isinstance(f, Frame) and f.nonce != self.nonce:
                    self.old.append(self.nonce)
                    self.nonce = f.nonce


def count_frames(data: bytes) -> int:
    """The frames a write carries, intact or damaged: its 0x00-terminated non-empty pieces
    (a piece without its 0x00 yet - a split frame - counts when its end arrives; at least 1)."""
    return max(1, sum(1 for seg in data.split(b"\0")[:-1] if seg))


def run_stream(seed: int, frames: int, *, chip_seed: int | None = None, elf: Any = None,
               restart_every: int = 2000, stats: FastStats | None = None,
               on_boot: Any = None, on_reply: Any = None) -> FastStats:
    """Compare at least ``frames`` request frames on both MCUs, seeded; a clean power cycle
    about every ``restart_every`` writes. Divergence (an AssertionError) names the write.
    ``on_boot(mcu)``: called with the firmware's :class:`~.mcu_isa.IsaMcu` at every boot;
    ``on_reply(bytes)``: sees every answer of the C firmware."""
    stats = stats if stats is not None else FastStats()
    r = random.Random(seed ^ 0x5EED)
    nonces = tuple(r.randrange(1, 1 << 32) for _ in range(3))
    twin = FastTwin(chip_seed if chip_seed is not None else seed % 7, nonces, elf=elf,
                    on_boot=on_boot, serial=SERIALS[seed % len(SERIALS)])
    stream = RequestStream(seed)
    t0, c0 = time.perf_counter(), time.process_time()
    done = 0
    try:
        stream.learn(twin.send(stream.hello(), "HELLO"))
        while done < frames:
            data, kind = stream.next()
            try:
                out = twin.send(data, f"write {stats.writes + 1} ({kind}: {data.hex()})")
            except Divergence:
                raise
            if on_reply is not None:
                on_reply(twin.outs["firmware"])
            stream.learn(out)
            n = count_frames(data)
            done += n
            stats.frames += n
            stats.writes += 1
            stats.kinds[kind] = stats.kinds.get(kind, 0) + 1
            if restart_every and r.randrange(restart_every) == 0:
                stats.restarts += 1
                twin.restart(tuple(r.randrange(1, 1 << 32) for _ in range(3)))
                stream.nonce = 0
                stream.sent, stream.last_spike = [], None
                stream.learn(twin.send(stream.hello(), "HELLO after power cycle"))
    finally:
        stats.seconds += time.perf_counter() - t0
        stats.cpu_seconds += time.process_time() - c0
        twin.close()
    return stats


def summary(stats: FastStats) -> dict[str, Any]:
    """JSON-able figures of a run."""
    return {"writes": stats.writes, "frames": stats.frames, "restarts": stats.restarts,
            "seconds": round(stats.seconds, 3), "frames_per_s": round(stats.frames_per_s, 1),
            "cpu_seconds": round(stats.cpu_seconds, 3),
            "frames_per_cpu_s": round(stats.frames_per_cpu_s, 1),
            "kinds": json.loads(json.dumps(stats.kinds))}
