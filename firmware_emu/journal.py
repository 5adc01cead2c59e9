"""Write-ahead journal of the emulated chip: what a returned request did survives a kill.

The chip's durable state is its snapshot (the state file, e.g. ``chip.npz``, written by
:mod:`.state`) plus this journal beside it (``chip.npz.journal``). After every request that
changed the chip, and before its reply leaves the emulator, :class:`ChipJournal` appends one
record with the *result* of the request: the new internal state and programming time of every
cell that changed, the chip's clock and the state of its runtime random stream (programming and
read noise). A request that only drew noise (a read, a spike batch) appends a record with the
random stream alone. Replay (:meth:`ChipJournal.replay`) puts those values back onto the
snapshot: no physics is recomputed, so the chip after a replay is bit for bit the chip the
killed emulator held after its last answered request — the same conductances and the same next
random draws (``tests/emulator/test_emu_durable.py`` compares a replayed chip with one saved
cleanly,
array by array and reply by reply).

Why results and not requests: replaying the requests would need every input of the physics —
the chip's noise stream after all the reads in between, the board's ADC noise stream, the
firmware's last reading of each cell (its compliance check) — so the journal records what they
produced instead.

Boot records count the emulator's starts (the boot number seeds the boot nonce and the ADC
noise of that boot, see :class:`~snan_hil.firmware_emu.emulator.Emulator`).

Durability (fsync discipline):

* every record is written with one ``write(2)`` before the reply is returned: once the host has
  the reply, the record is in the kernel, so a kill of the emulator (SIGKILL included) loses
  nothing of it; a kill in the middle of a request loses at most that request (its record was
  not written, or was written torn and is cut off at replay);
* ``sync="interval"`` (default): the journal is ``fdatasync``'ed after a record when the last
  sync is more than ``sync_interval_s`` old, when the emulator goes idle, and at compaction and
  close: an operating-system crash or power loss loses at most about the last
  ``sync_interval_s`` of programming (a kill of the emulator still loses nothing);
* ``sync="request"``: every record that changed cells is ``fdatasync``'ed before the reply
  (power-loss safe, ~4 ms per pulse on an ext4 SSD volume);
* boot records and headers are always synced.

File format: records of ``u32 length | u32 CRC-32 of the payload | payload`` (little endian).
Payload byte 0 is the record type: ``H`` header (JSON: format, chip serial, base sequence
number), ``B`` boot (u64 sequence number, u32 boot number), ``C`` chip (u64 sequence number,
f64 chip time, the PCG64 state as 16 + 16 bytes + u8 + u32, u16 cell count, per cell u8 row,
u8 column, f64 state, f64 programming time, f64 wear in full-window cycles; format /1
journals, written before wear was recorded, lack the wear and are still replayed). Sequence
numbers count up by one. A record whose
length or CRC does not check ends the journal when nothing valid follows it (a write torn by a
kill, which tears only the last write); replay cuts the file there. When a valid record with a
later sequence number follows it, or a record's CRC checks but its content does not, the file
was damaged in the middle: replay stops with one line naming the journal and leaves the file
as it is (cutting it would silently revert every change after the damage).
"""

from __future__ import annotations

import json
import logging
import os
import struct
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from snan_hil.common.errors import UserError

log = logging.getLogger(__name__)

JOURNAL_FORMAT = "snan-hil-chip-journal/2"
#: journals written before cell wear was recorded (cells without their wear): still replayed
JOURNAL_FORMATS = ("snan-hil-chip-journal/1", JOURNAL_FORMAT)
SYNC_MODES = ("interval", "request")

_FRAME = struct.Struct("<II")
_BOOT = struct.Struct("<cQI")
_CHIP = struct.Struct("<cQd16s16sBIH")
_CELL_V1 = struct.Struct("<BBdd")
_CELL = struct.Struct("<BBddd")          # + the cell's wear (full-window cycles)
_MAX_RECORD = 1 << 20


def journal_path(state_file: str | os.PathLike) -> Path:
    """The journal beside a state file: ``NAME.journal``."""
    p = Path(state_file)
    return p.with_name(p.name + ".journal")


def _unpack_rng(st: bytes, inc: bytes, has: int, uint: int) -> dict:
    return {"bit_generator": "PCG64",
            "state": {"state": int.from_bytes(st, "little"), "inc": int.from_bytes(inc, "little")},
            "has_uint32": has, "uinteger": uint}


@dataclass
class ReplayResult:
    """What :meth:`ChipJournal.replay` found."""

    records: int = 0            #: records applied
    skipped: int = 0            #: records at or below the snapshot's sequence number
    boots: int | None = None    #: last boot number recorded (None: no boot record)
    last_seq: int = 0
    torn_bytes: int = 0         #: bytes cut off the end (a write torn by a kill)
    discarded: str | None = None  #: why the whole journal was ignored (another chip's)
    cells_changed: set[tuple[int, int]] = field(default_factory=set)


class ChipJournal:
    """The journal of one chip (see module doc). ``chip``: the chip's serial (a journal of
    another chip is never replayed); ``seq``: last sequence number already in the snapshot."""

    def __init__(self, path: str | os.PathLike, chip: str, seq: int, *,
                 sync: str = "interval", sync_interval_s: float = 1.0):
        if sync not in SYNC_MODES:
            raise ValueError(f"sync must be one of {', '.join(SYNC_MODES)}, got {sync!r}")
        self.path = Path(path)
        self.chip = str(chip)
        self.seq = int(seq)
        self.sync_mode = sync
        self.sync_interval_s = float(sync_interval_s)
        self._fd: int | None = None
        self._unsynced = False
        self._last_sync = time.monotonic()
        self.bytes = 0
        self.records_written = 0
        self.syncs = 0
        self._last_state: np.ndarray | None = None
        self._last_tprog: np.ndarray | None = None
        self._last_time_s = 0.0
        self._last_rng: tuple | None = None
        self._last_revision: int | None = None
        self._header_bytes = 0
        self._cell = _CELL          # the cell record of the file being replayed

    # ------------------------------------------------------------------ reading
    def replay(self, array: Any) -> ReplayResult:
        """Apply the records after the snapshot's sequence number to ``array``; cut a torn
        tail. A journal of another chip (or without a valid header) is left out and renamed
        ``NAME.journal.discarded`` (never applied, never deleted)."""
        res = ReplayResult(last_seq=self.seq)
        try:
            data = self.path.read_bytes()
        except FileNotFoundError:
            return res
        pos, good = 0, 0
        header: dict | None = None
        while pos + _FRAME.size <= len(data):
            length, crc = _FRAME.unpack_from(data, pos)
            body = data[pos + _FRAME.size:pos + _FRAME.size + length]
            if length == 0 or length > _MAX_RECORD or len(body) != length \
                    or zlib.crc32(body) != crc:
                # a damaged header before valid records is damage too (issue 27 item 8:
                # setting the journal aside would silently revert the chip to its snapshot);
                # only a journal that is nothing but a torn header is a torn write
                self._check_tail(data, pos)
                break
            pos += _FRAME.size + length
            if header is None:
                header = self._read_header(body, pos, res)
                if res.discarded:
                    return res
                assert header is not None           # _read_header refused or discarded it
                self._cell = _CELL if header["format"] == JOURNAL_FORMAT else _CELL_V1
                good = pos
                continue
            seq = self._apply_record(body, pos - _FRAME.size - length, array, res)
            if seq > self.seq:
                res.records += 1
                self.seq = seq
            else:
                res.skipped += 1
            good = pos
        if header is None and data:
            res.discarded = "no valid header"
            self._discard(res.discarded)
            return res
        self._cut_torn_tail(len(data), good, res)
        res.last_seq = self.seq
        self.bytes = good
        return res

    def _read_header(self, body: bytes, end: int, res: ReplayResult) -> dict | None:
        """The first record (ending at byte ``end``): the header, checked; one of another chip
        or format is set aside (``res.discarded`` set, :meth:`_discard`)."""
        if body[:1] != b"H":         # checksum right, content wrong: not a torn write
            self._damaged(0, "it does not start with its header record")
        try:
            header = json.loads(body[1:].decode())
        except (UnicodeDecodeError, ValueError):
            self._damaged(0, "its header record is not readable")
        self._header_bytes = end
        if not isinstance(header, dict) or header.get("format") not in JOURNAL_FORMATS \
                or header.get("chip") != self.chip:
            res.discarded = (f"it belongs to chip {header.get('chip')!r}, not "
                             f"{self.chip!r}" if isinstance(header, dict)
                             else "bad header")
            self._discard(res.discarded)
        return header

    def _apply_record(self, body: bytes, start: int, array: Any, res: ReplayResult) -> int:
        """Apply one boot or chip record (starting at byte ``start``) to ``array`` when it is
        newer than the snapshot; returns its sequence number."""
        kind = body[:1]
        if kind == b"B" and len(body) == _BOOT.size:
            _, seq, boot = _BOOT.unpack(body)
            self._check_continues(seq)
            if seq > self.seq:
                res.boots = boot
        elif kind == b"C" and len(body) >= _CHIP.size:
            _, seq, time_s, st, inc, has, uint, n = _CHIP.unpack_from(body)
            cell = self._cell
            if len(body) != _CHIP.size + n * cell.size:
                self._damaged(start, "a record of unknown kind or size")
            self._check_continues(seq)
            if seq > self.seq:
                cells = [cell.unpack_from(body, _CHIP.size + i * cell.size)
                         for i in range(n)]
                array.restore_cells([c[0] for c in cells], [c[1] for c in cells],
                                    [c[2] for c in cells], [c[3] for c in cells],
                                    [c[4] for c in cells] if cell is _CELL else None)
                array.time_s = time_s
                array.noise_state = _unpack_rng(st, inc, has, uint)
                res.cells_changed.update((c[0], c[1]) for c in cells)
        else:                    # checksum right, content wrong: not a torn write
            self._damaged(start, "a record of unknown kind or size")
        return int(seq)

    def _cut_torn_tail(self, size: int, good: int, res: ReplayResult) -> None:
        res.torn_bytes = size - good
        if res.torn_bytes:
            log.warning("chip journal %s: %d torn byte(s) at the end cut off (a write "
                        "interrupted by a kill)", self.path, res.torn_bytes)
            with open(self.path, "r+b") as fh:
                fh.truncate(good)
                os.fsync(fh.fileno())

    def _check_tail(self, data: bytes, pos: int) -> None:
        """The record at ``pos`` does not check. A kill tears only the last write, so a torn
        tail holds no valid record after it; a valid record further on (a chip or boot
        record with a later sequence number and a right checksum) means the file was damaged
        in the middle: :meth:`_damaged`."""
        end = len(data)
        for p in range(pos + 1, end - _FRAME.size - _BOOT.size + 1):
            length, crc = _FRAME.unpack_from(data, p)
            start = p + _FRAME.size
            if length > end - start or length < _BOOT.size:
                continue
            kind = data[start:start + 1]
            if kind == b"B":
                if length != _BOOT.size:
                    continue
                seq = _BOOT.unpack_from(data, start)[1]
            elif kind == b"C":
                if length < _CHIP.size:
                    continue
                fields = _CHIP.unpack_from(data, start)
                if length != _CHIP.size + fields[7] * self._cell.size:
                    continue
                seq = fields[1]
            else:
                continue
            if seq > self.seq and zlib.crc32(data[start:start + length]) == crc:
                self._damaged(pos, f"valid records follow from byte {p} (record {seq})")

    def _damaged(self, pos: int, why: str) -> None:
        """Stop (UserError, one line): the journal is damaged before its end; it is left as
        it is (never cut, never replayed in part)."""
        state = self.path.with_name(self.path.name[:-len(".journal")]) \
            if self.path.name.endswith(".journal") else None
        raise UserError(
            f"chip journal {self.path} is damaged in the middle (at byte {pos}: {why}); it was "
            "left as it is, the chip was not opened: replaying it in part would lose or mix "
            "changes. Restore it from a copy, or move it away to use the state file"
            + (f" {state}" if state is not None else "") + " alone (its changes since the "
            "last snapshot are then lost)")

    def _check_continues(self, seq: int) -> None:
        """Records are numbered one after the other: a record beyond the next number means the
        state file is older than the journal (replaced by an older copy), and applying the
        rest would mix two states of the chip."""
        if seq > self.seq + 1:
            raise UserError(
                f"chip journal {self.path} does not continue its state file (the file holds "
                f"the chip up to record {self.seq}, the journal goes on from record {seq}: was "
                "the state file replaced by an older copy?); move the journal away to use the "
                "state file as it is")

    def _discard(self, why: str) -> None:
        aside = self.path.with_name(self.path.name + ".discarded")
        log.warning("chip journal %s ignored (%s); moved to %s", self.path, why, aside)
        os.replace(self.path, aside)

    @property
    def old_format(self) -> bool:
        """The replayed file was written in an earlier format (its cell records lack the
        wear): it must be replaced by a fresh journal after a snapshot, not appended to."""
        return self._cell is not _CELL

    # ------------------------------------------------------------------ writing
    def open(self, array: Any, *, fresh: bool) -> None:
        """Start appending (``fresh``: a new file with only the header, e.g. after the snapshot
        took in everything); remember ``array`` as the journaled state."""
        flags = os.O_WRONLY | os.O_CREAT | os.O_APPEND
        if fresh or self.old_format or not self.path.exists() or self.bytes == 0 \
                or not self._header_bytes:
            tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.tmp")
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
            try:
                header = json.dumps({"format": JOURNAL_FORMAT, "chip": self.chip,
                                     "base_seq": self.seq}).encode()
                os.write(fd, _frame(b"H" + header))
                os.fsync(fd)
            finally:
                os.close(fd)
            os.replace(tmp, self.path)
            _fsync_dir(self.path.parent)
            self.bytes = _FRAME.size + 1 + len(header)
            self._header_bytes = self.bytes
            self._cell = _CELL
        self._fd = os.open(self.path, flags, 0o644)
        self.remember(array)

    def truncate(self, array: Any) -> None:
        """Empty the journal down to its header (the snapshot holds everything; its
        ``journal_seq`` says so) and keep appending."""
        assert self._fd is not None, "journal not open"
        os.ftruncate(self._fd, self._header_bytes)
        os.fdatasync(self._fd)
        self.bytes = self._header_bytes
        self._unsynced = False
        self._last_sync = time.monotonic()
        self.remember(array)

    def remember(self, array: Any) -> None:
        """Take ``array`` as it is now as the state the journal has recorded."""
        self._last_state = array.state.copy()
        self._last_tprog = array.t_prog.copy()
        self._last_time_s = float(array.time_s)
        rng = array.noise_state
        if rng.get("bit_generator") != "PCG64":
            raise ValueError(f"the journal records PCG64 noise streams, not "
                             f"{rng.get('bit_generator')}")
        self._last_rng = (rng["state"]["state"], rng["state"]["inc"], rng["has_uint32"],
                          rng["uinteger"])
        self._last_revision = array.revision
        array.changed_cells.clear()

    def boot(self, boot: int) -> None:
        """Record a start of the emulator (synced at once)."""
        self.seq += 1
        self._write(_BOOT.pack(b"B", self.seq, int(boot)))
        self.sync()

    def record(self, array: Any) -> bool:
        """Append what changed on ``array`` since the last record (cells, chip time, noise
        stream); nothing if nothing changed. True if cells changed (a durable change).

        The changed cells come from ``array.changed_cells`` (pulses, set_conductance); a
        change of the array's ``revision`` without any (state written another way) falls
        back to comparing every cell with the last recorded state."""
        if self._fd is None:
            return False
        rng = array.noise_state
        st = rng["state"]
        key = (st["state"], st["inc"], rng["has_uint32"], rng["uinteger"])
        time_s = array.time_s
        cells = sorted(array.changed_cells)
        array.changed_cells.clear()
        revision = array.revision
        if revision != self._last_revision:
            self._last_revision = revision
            if not cells:
                assert self._last_state is not None and self._last_tprog is not None
                diff = (array.state != self._last_state) | (array.t_prog != self._last_tprog)
                cells = list(zip(*(i.tolist() for i in np.nonzero(diff))))
        if not cells and time_s == self._last_time_s and key == self._last_rng:
            return False
        self.seq += 1
        state, tprog, wear = array.state, array.t_prog, getattr(array, "wear", None)
        parts = [_CHIP.pack(b"C", self.seq, float(time_s), key[0].to_bytes(16, "little"),
                            key[1].to_bytes(16, "little"), key[2], key[3], len(cells))]
        if cells:
            last_state, last_tprog = self._last_state, self._last_tprog
            assert last_state is not None and last_tprog is not None
            for r, c in cells:
                s, t = state[r, c].item(), tprog[r, c].item()
                parts.append(_CELL.pack(r, c, s, t,
                                        0.0 if wear is None else wear[r, c].item()))
                last_state[r, c], last_tprog[r, c] = s, t
        self._last_time_s = float(time_s)
        self._last_rng = key
        self._write(b"".join(parts))
        durable = bool(cells)
        if (durable and self.sync_mode == "request") \
                or time.monotonic() - self._last_sync >= self.sync_interval_s:
            self.sync()
        return durable

    def _write(self, payload: bytes) -> None:
        assert self._fd is not None, "journal not open"
        frame = _FRAME.pack(len(payload), zlib.crc32(payload)) + payload
        done = os.write(self._fd, frame)
        while done < len(frame):                 # a regular file takes it whole; just in case
            done += os.write(self._fd, frame[done:])
        self.bytes += len(frame)
        self.records_written += 1
        self._unsynced = True

    def sync(self) -> None:
        """fdatasync what was written (no-op if nothing is pending)."""
        if self._fd is not None and self._unsynced:
            os.fdatasync(self._fd)
            self.syncs += 1
        self._unsynced = False
        self._last_sync = time.monotonic()

    @property
    def pending(self) -> bool:
        """Records written but not yet synced."""
        return self._unsynced

    def close(self) -> None:
        if self._fd is not None:
            try:
                if self._unsynced:
                    os.fdatasync(self._fd)
            finally:
                os.close(self._fd)
                self._fd = None
                self._unsynced = False


def count_records(path: str | os.PathLike) -> int:
    """Valid records after the header of a journal file (0 for none or no file): a journal
    that a clean stop emptied holds none."""
    try:
        data = Path(path).read_bytes()
    except FileNotFoundError:
        return 0
    pos, n = 0, -1
    while pos + _FRAME.size <= len(data):
        length, crc = _FRAME.unpack_from(data, pos)
        body = data[pos + _FRAME.size:pos + _FRAME.size + length]
        if length == 0 or len(body) != length or zlib.crc32(body) != crc:
            break
        pos += _FRAME.size + length
        n += 1
    return max(n, 0)


def _frame(payload: bytes) -> bytes:
    return _FRAME.pack(len(payload), zlib.crc32(payload)) + payload


def _fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
