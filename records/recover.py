"""Save what a damaged history database still holds into a new one (``snan-hil history
recover``).

SQLite's online backup (``history backup``) copies pages, the damaged ones too; this copies
rows. Every table of the history (:data:`~snan_hil.records.history.TABLE_COLUMNS`, and
``controls``) is read in order of its ``id`` in chunks of :data:`CHUNK` rows; a chunk that
cannot be read (a broken page on its way) is read again row by row, and the rows that still
fail are counted as lost. The rows keep their ids, so a pulse still points at its run; a row
whose run was lost is kept (foreign keys are not enforced while copying). The new file is a
history database of this version (it can be recorded into); the damaged one is only read.

A base module: it imports no layer.
"""

from __future__ import annotations

import sqlite3
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["RecoverReport", "recover", "CHUNK"]

CHUNK = 500
"""Rows read at once; a chunk that fails is read row by row."""
_GAP = 10_000
"""Ids tried one by one past the last readable row when the largest id cannot be read."""


@dataclass
class RecoverReport:
    """Rows copied and rows lost, per table."""

    copied: dict[str, int] = field(default_factory=dict)
    lost: dict[str, int] = field(default_factory=dict)

    @property
    def total_copied(self) -> int:
        return sum(self.copied.values())

    @property
    def total_lost(self) -> int:
        return sum(self.lost.values())


def recover(src: Path, dest: Path) -> RecoverReport:
    """Copy every readable row of the history database ``src`` into a new history database
    ``dest`` (which must not exist: the caller writes through a temporary file). Raises
    :class:`sqlite3.Error` when ``src`` cannot be opened at all."""
    from snan_hil.records.history import TABLE_COLUMNS, History
    tables = {**TABLE_COLUMNS,
              "controls": ("id", "run_uid", "time_utc", "action", "source")}
    report = RecoverReport()
    old = sqlite3.connect(f"{Path(src).resolve().as_uri()}?mode=ro", uri=True)
    try:
        with History.open(dest) as new:
            new.conn.execute("PRAGMA foreign_keys = OFF")
            for table, cols in tables.items():
                copied, lost = _copy_table(old, new.conn, table, cols)
                report.copied[table], report.lost[table] = copied, lost
            new.conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    finally:
        old.close()
    return report


def _largest_id(old: sqlite3.Connection, table: str) -> int | None:
    try:
        row = old.execute(f"SELECT max(id) FROM {table}").fetchone()
    except sqlite3.DatabaseError:
        return None
    return int(row[0]) if row and row[0] is not None else 0


def _copy_table(old: sqlite3.Connection, new: sqlite3.Connection, table: str,
                cols: tuple[str, ...]) -> tuple[int, int]:
    """(rows copied, rows lost) of one table."""
    names = ", ".join(cols)
    select = f"SELECT {names} FROM {table} WHERE id > ? AND id <= ? ORDER BY id"
    insert = f"INSERT INTO {table}({names}) VALUES ({', '.join('?' * len(cols))})"
    top = _largest_id(old, table)
    copied = 0
    failed: list[int] = []              # ids that could not be read (a row or none)
    last = seen = 0                     # seen: the last id read
    while True:
        hi = last + CHUNK
        try:
            rows: list[tuple[object, ...]] | None = old.execute(select, (last, hi)).fetchall()
        except sqlite3.OperationalError as exc:
            if "no such table" in str(exc):
                break
            rows = None
        except sqlite3.DatabaseError:
            rows = None
        if rows is None:
            rows = []
            for i in range(last + 1, hi + 1):
                try:
                    rows += old.execute(select, (i - 1, i)).fetchall()
                except sqlite3.DatabaseError:
                    failed.append(i)
        if rows:
            new.execute("BEGIN")
            new.executemany(insert, rows)
            new.execute("COMMIT")
            copied += len(rows)
            seen = max(seen, int(rows[-1][0]))          # type: ignore[call-overload]
        last = hi
        if (top is not None and last >= top) or (top is None and last - seen > _GAP):
            break
    # an unreadable id past the last row known to exist may never have been a row
    known = seen if top is None else max(seen, top)
    return copied, sum(1 for i in failed if i <= known)
