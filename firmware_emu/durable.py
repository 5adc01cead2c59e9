"""The emulated chip of a state file, kept durable: snapshot + write-ahead journal.

:class:`ChipStore` is what an :class:`~snan_hil.firmware_emu.emulator.Emulator` with a state
file holds. On open it loads the snapshot (or creates a chip from the seed), replays the
journal (:mod:`.journal`) onto it, snapshots again if anything was replayed, and records the new
boot. While the emulator runs, :meth:`ChipStore.record` appends what each request changed before
its reply is sent; :meth:`ChipStore.idle` syncs pending records; :meth:`ChipStore.compact`
writes a snapshot that takes in the journal and starts a new one (when the journal passes
``compact_bytes``, and at :meth:`ChipStore.close`).

The snapshot's ``meta`` (:attr:`CrossbarArray.meta`) holds the chip's identity and history:

* ``chip``: the chip's serial, 12 hex digits drawn once when the chip is created (the one
  random value that takes no seed: it names this chip, it changes no behaviour). INFO reports
  it after the board id (``EMU-4D430001/<serial>``), so the host keys the chip's layout by it;
  ``snan-hil emu --reset-chip`` makes a chip with a new serial;
* ``seed``: the seed the chip was created from;
* ``boots``: how often an emulator has started on this chip (the boot number seeds the boot
  nonce and the ADC noise of that boot, so a restarted emulator draws a new nonce and the
  host sees the restart);
* ``journal_seq``: the last journal record the snapshot contains.

The caller holds the state file's lock (:func:`.state.acquire`) for the store's lifetime.
"""

from __future__ import annotations

import logging
import os
import secrets
import threading
from pathlib import Path
from typing import Any

from snan_hil.files.atomicio import atomic_write_bytes
from snan_hil.firmware_emu import state
from snan_hil.common.errors import UserError
from snan_hil.firmware_emu.journal import (ChipJournal, ReplayResult, _fsync_dir, count_records,
                                           journal_path)

log = logging.getLogger(__name__)

CHIP_META_FORMAT = "snan-hil-emu-chip/1"
COMPACT_BYTES = 1 << 20
"""Journal size (bytes) at which the store writes a new snapshot (~15,000 read records or
~5,000 pulse records; a snapshot takes ~10 ms)."""


def new_serial() -> str:
    """A new chip serial: 12 upper-case hex digits."""
    return secrets.token_hex(6).upper()


def new_meta(seed: int, device: state.TwinDevice | None = None) -> dict[str, Any]:
    """The meta of a chip created now from ``seed`` (the twin of ``device``: its digest and
    file recorded as ``device``)."""
    meta: dict[str, Any] = {"format": CHIP_META_FORMAT, "chip": new_serial(), "seed": int(seed),
                            "boots": 0, "journal_seq": 0}
    if device is not None:
        meta["device"] = device.meta()
    return meta


def check_twin(array: Any, path: Path, device: state.TwinDevice | None) -> None:
    """UserError (one line) when the chip saved at ``path`` is not the twin of ``device``
    (another model's, or a chip not made of a model); nothing when no device is asked for."""
    if device is None:
        return
    have = (array.meta or {}).get("device") or {}
    if have.get("digest") == device.digest:
        return
    what = (f"the twin of {have.get('model', 'another model')}" if have
            else "a chip not made of a device model")
    raise UserError(f"chip state {path} is {what}, not the twin of {device.path}; give another "
                    "state file (or none: each model has its own), or replace it with "
                    f"'snan-hil emu --reset-chip --state {path} --device {device.path}'")


def create_chip(path: str | os.PathLike, seed: int = 0, serial: str | None = None,
                device: state.TwinDevice | None = None, spread: float = 1.0):
    """Write a fresh chip from ``seed`` (a new serial, or ``serial``: test benches and the
    conformance vectors name their chip; the twin of ``device`` when given; ``spread``: its
    device-to-device sigmas scaled, :func:`state.new_array`, recorded in the chip's meta) to
    ``path``, replacing any chip there and its journal. The caller holds the lock. Returns the
    array."""
    path = Path(path)
    array = state.new_array(seed, device=device, spread=spread)
    array.meta = new_meta(seed, device)
    if spread != 1.0:
        array.meta["spread"] = float(spread)
    if serial is not None:
        array.meta["chip"] = str(serial)
    state.save_array(array, path, meta=array.meta)
    for leftover in (journal_path(path), journal_path(path).with_name(
            journal_path(path).name + ".discarded")):
        leftover.unlink(missing_ok=True)
    _fsync_dir(path.parent)
    return array


def chip_serial(path: str | os.PathLike) -> str | None:
    """The serial of the chip saved at ``path`` (None: no file, or a file from before serials
    existed)."""
    path = Path(path)
    if not path.is_file():
        return None
    serial = state.load_array(path).meta.get("chip")
    return str(serial) if serial else None


def copy_chip(path: str | os.PathLike, dest: str | os.PathLike) -> None:
    """Copy a stopped chip (its state file; the journal of a clean stop is empty) to ``dest``
    atomically. UserError while an emulator runs on it or its journal holds records."""
    path, dest = Path(path), Path(dest)
    _not_open_here(path)
    release = state.acquire(path)
    try:
        if count_records(journal_path(path)):
            raise UserError(f"chip {path} was not stopped cleanly (its journal holds records); "
                            "open it once (e.g. 'snan-hil info --port emu') to replay them")
        atomic_write_bytes(dest, path.read_bytes())
    finally:
        release()


def restore_chip(src: str | os.PathLike, path: str | os.PathLike) -> None:
    """Put the chip saved by :func:`copy_chip` at ``src`` back as the chip of ``path`` (its
    journal is removed: its records are of the chip being replaced). UserError while an
    emulator runs on it."""
    path = Path(path)
    _not_open_here(path)
    release = state.acquire(path)
    try:
        atomic_write_bytes(path, Path(src).read_bytes())
        _fsync_dir(path.parent)
        journal_path(path).unlink(missing_ok=True)
    finally:
        release()


def remove_chip(path: str | os.PathLike) -> None:
    """Remove the chip of ``path`` (state file and journal; the next emulator creates a fresh
    chip from its seed). UserError while an emulator runs on it."""
    path = Path(path)
    _not_open_here(path)
    release = state.acquire(path)
    try:
        path.unlink(missing_ok=True)
        journal_path(path).unlink(missing_ok=True)
        _fsync_dir(path.parent)
    finally:
        release()


_open_stores: dict[Path, list] = {}      # resolved path -> [store, users]
_open_guard = threading.Lock()


def _not_open_here(path: Path) -> None:
    entry = _open_stores.get(path.expanduser().resolve())
    if entry is not None and not entry[0].closed:
        raise UserError(f"chip {path} is open in this process; close its client first")


def open_store(path: str | os.PathLike, seed: int = 0, **kwargs: Any) -> "ChipStore":
    """The :class:`ChipStore` of ``path``, shared by the emulators of this process that use
    the file at the same time (one chip, one journal: they see and record the same cells);
    give it back with :func:`release_store`. Each call counts a boot."""
    key = Path(path).expanduser().resolve()
    with _open_guard:
        entry = _open_stores.get(key)
        if entry is None or entry[0].closed:
            store = ChipStore(path, seed, **kwargs)
            _open_stores[key] = [store, 1]
            return store
        store = entry[0]
        check_twin(store.array, store.path, kwargs.get("device"))
        entry[1] += 1
        store.boot()
        return store


def release_store(store: "ChipStore", *, clean: bool = True) -> None:
    """One user less; the last one closes the store (snapshot), or with ``clean=False``
    abandons it as a kill would (:meth:`ChipStore.abandon`)."""
    key = store.path.expanduser().resolve()
    finish = store.close if clean else store.abandon
    with _open_guard:
        entry = _open_stores.get(key)
        if entry is None or entry[0] is not store:
            finish()
            return
        entry[1] -= 1
        if entry[1] <= 0:
            del _open_stores[key]
            finish()


class ChipStore:
    """The durable chip of ``path`` (see module doc). UserError (one line) when the chip or
    its journal cannot be read or written."""

    def __init__(self, path: str | os.PathLike, seed: int = 0, *, sync: str = "interval",
                 sync_interval_s: float = 1.0, compact_bytes: int = COMPACT_BYTES,
                 device: state.TwinDevice | None = None):
        try:
            self._open(path, seed, sync, sync_interval_s, compact_bytes, device)
        except OSError as exc:
            raise UserError(f"cannot keep the chip of {path}: {exc.strerror or exc}"
                            f"{f' ({exc.filename})' if exc.filename else ''}; check the "
                            "folder's permissions and free space") from None

    def _open(self, path: str | os.PathLike, seed: int, sync: str, sync_interval_s: float,
              compact_bytes: int, device: state.TwinDevice | None) -> None:
        self.path = Path(path)
        self.compact_bytes = int(compact_bytes)
        existed = self.path.exists()
        if existed:
            array = state.load_array(self.path)
            check_twin(array, self.path, device)
        else:
            array = state.new_array(seed, device=device)
        meta = dict(array.meta)
        snapshot_needed = not existed
        if meta.get("format") != CHIP_META_FORMAT or not meta.get("chip"):
            # a fresh chip, or a state file written before serials and journals existed
            meta = {**new_meta(int(getattr(array, "seed", seed)),
                               device if not existed else None), "boots": 0}
            snapshot_needed = True
            for stale in (journal_path(self.path),):
                if stale.exists():     # cannot belong to this chip (it had no serial)
                    os.replace(stale, stale.with_name(stale.name + ".discarded"))
        self.array = array
        self.meta = meta
        self.journal = ChipJournal(journal_path(self.path), meta["chip"],
                                   int(meta.get("journal_seq", 0)), sync=sync,
                                   sync_interval_s=sync_interval_s)
        self.replayed: ReplayResult = self.journal.replay(array)
        if self.replayed.records:
            log.info("chip %s: %d journal record(s) replayed onto the snapshot (%d cell(s))",
                     self.path, self.replayed.records, len(self.replayed.cells_changed))
        boots = self.replayed.boots if self.replayed.boots is not None else meta["boots"]
        self.boot_number = int(boots) + 1
        self.meta["boots"] = int(boots)
        if snapshot_needed or self.replayed.records or self.replayed.torn_bytes \
                or self.replayed.discarded or self.journal.old_format:
            self._snapshot()
            self.journal.open(array, fresh=True)
        else:
            self.journal.open(array, fresh=False)
        self.journal.boot(self.boot_number)
        self.meta["boots"] = self.boot_number
        self.dirty = False
        self.closed = False

    def boot(self) -> int:
        """Count one more start of an emulator on this (already open) chip; its number."""
        self.journal.record(self.array)
        self.boot_number += 1
        self.journal.boot(self.boot_number)
        self.meta["boots"] = self.boot_number
        return self.boot_number

    @property
    def serial(self) -> str:
        return str(self.meta["chip"])

    @property
    def seed(self) -> int:
        return int(self.meta.get("seed", getattr(self.array, "seed", 0)))

    # ------------------------------------------------------------------ while running
    def record(self) -> bool:
        """Journal what the last request changed (call before its reply is sent)."""
        changed = self.journal.record(self.array)
        if changed:
            self.dirty = True
        if self.journal.bytes > self.compact_bytes:
            self.compact()
        return changed

    def idle(self) -> None:
        """Nothing to answer: sync pending records."""
        if self.journal.pending:
            self.journal.sync()

    def compact(self) -> None:
        """Write a snapshot holding everything journaled, then start a new journal."""
        self.journal.record(self.array)           # anything not yet journaled
        self._snapshot()
        self.journal.truncate(self.array)        # down to its header
        self.dirty = False

    def _snapshot(self) -> None:
        self.meta["journal_seq"] = self.journal.seq
        self.array.meta = dict(self.meta)
        state.save_array(self.array, self.path, meta=self.meta)
        _fsync_dir(self.path.parent)              # the rename is durable before the journal
        #                                           it replaces is emptied

    def abandon(self) -> None:
        """Stop as a kill does (test benches): nothing more is written - every answered
        request is in the journal already - and the journal file is closed; the next open
        replays it."""
        if not self.closed:
            self.journal.close()
            self.closed = True

    def close(self) -> None:
        """Snapshot (if the journal holds anything) and close the journal (idempotent)."""
        if self.closed:
            return
        try:
            if self.journal.seq > int(self.meta.get("journal_seq", 0)) or self.dirty:
                self.compact()       # after a clean stop the state file alone is the chip
        finally:
            self.journal.close()
            self.closed = True
