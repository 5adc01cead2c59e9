"""The chip history database: every programming run, cell test, pulse ticket, retention run, map
and column-multiply test of one board, in one SQLite file (the standard library's ``sqlite3``).

A base module like :mod:`snan_hil.files.outputs`: it imports no layer (cells are ``(row, col)``,
polarities their names, conductances floats in S), and every layer may import it. The CLI
decides where the file lives (one per board identity, beside the board's layout:
:func:`snan_hil.tools.layout_paths.default_history_path`), opens it with :meth:`History.open`
and hands a :class:`Recorder` to the library code as its cell observer
(:class:`snan_hil.calibration.observer.CellObserver`).

Schema (version :data:`SCHEMA_VERSION`; ``PRAGMA application_id`` = :data:`APPLICATION_ID`
marks the file as ours, ``PRAGMA user_version`` holds the version)::

    meta(key TEXT PRIMARY KEY, value TEXT)        format, created_utc, created_by
    runs(id, kind, command, started_utc, finished_utc, status, board_id, firmware_version,
         port, protocol, seed, version, record_level, config_json, summary_json)
    cell_results(id, run_id -> runs, row, col, time_utc, outcome, g_s, target_s, pulses,
                 detail_json)
    pulses(id, run_id -> runs, row, col, n, time_utc, stage, polarity, amplitude_v,
           width_us, g_before_s, g_after_s)
    device_models(id, run_id -> runs, time_utc, board_id, set_v, reset_v, width_us,
                  cells, model_json)                                   (since version 2)

``kind``: program, screen, pulse, retention, map, mac, characterize, learn. A
``device_models`` row is the compact device model a characterisation fitted
(:class:`snan_hil.crossbar_model.fitted.DeviceModel`'s ``to_dict``, kept as JSON: this module
imports no layer) at one learning pulse; :meth:`History.latest_device_model` is what
``snan-hil learn`` uses. Version 1 files are migrated in place when opened (the table is
added; nothing else changes). ``status``: running, complete,
interrupted, failed. ``outcome`` depends on the kind (program: ok / failed; screen: the cell's
class; map and retention: read / stable / unstable; pulse: why the ticket stopped). ``n`` is the
pulse's number on that cell within the run (1, 2, ...). Record levels (:data:`LEVELS`):
``runs`` (run rows only), ``cells`` (+ one result per cell), ``pulses`` (+ every pulse).

Failure policy (docs/bench.md): a file that is not a snan-hil history database is refused
before any work (:func:`check_history_file`, a :class:`HistoryError`, exit 2); a damaged or
locked database found while recording gives one warning line (through ``warn``) and the run
goes on unrecorded — recording never stops a programming run.
"""

from __future__ import annotations

import csv
import datetime as _dt
import io
import json
import logging
import math
import os
import sqlite3
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from snan_hil.common.errors import UserError

__all__ = ["SCHEMA_VERSION", "APPLICATION_ID", "FORMAT", "LEVELS", "KINDS", "HistoryError",
           "check_history_file", "History", "Recorder", "RunRow", "CellLifeEvent",
           "TABLE_COLUMNS"]

log = logging.getLogger(__name__)

SCHEMA_VERSION = 2
APPLICATION_ID = 0x534E4849          # "SNHI"
FORMAT = "snan-hil-history/1"
LEVELS = ("runs", "cells", "pulses")
KINDS = ("program", "screen", "pulse", "retention", "map", "mac", "characterize", "learn")
_SQLITE_MAGIC = b"SQLite format 3\x00"
BUSY_TIMEOUT_S = 2.0
"""How long a write waits for another process's lock before recording gives up (s)."""

_SCHEMA = """
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE runs (
    id INTEGER PRIMARY KEY,
    kind TEXT NOT NULL,
    command TEXT NOT NULL,
    started_utc TEXT NOT NULL,
    finished_utc TEXT,
    status TEXT NOT NULL,
    board_id TEXT,
    firmware_version TEXT,
    port TEXT,
    protocol TEXT,
    seed INTEGER,
    version TEXT NOT NULL,
    record_level TEXT NOT NULL,
    config_json TEXT,
    summary_json TEXT
);
CREATE TABLE cell_results (
    id INTEGER PRIMARY KEY,
    run_id INTEGER NOT NULL REFERENCES runs(id) ON DELETE CASCADE,
    row INTEGER NOT NULL,
    col INTEGER NOT NULL,
    time_utc TEXT NOT NULL,
    outcome TEXT NOT NULL,
    g_s REAL,
    target_s REAL,
    pulses INTEGER,
    detail_json TEXT
);
CREATE TABLE pulses (
    id INTEGER PRIMARY KEY,
    run_id INTEGER NOT NULL REFERENCES runs(id) ON DELETE CASCADE,
    row INTEGER NOT NULL,
    col INTEGER NOT NULL,
    n INTEGER NOT NULL,
    time_utc TEXT NOT NULL,
    stage TEXT,
    polarity TEXT NOT NULL,
    amplitude_v REAL NOT NULL,
    width_us INTEGER NOT NULL,
    g_before_s REAL,
    g_after_s REAL
);
CREATE INDEX cell_results_cell ON cell_results(row, col, run_id);
CREATE INDEX pulses_cell ON pulses(row, col, run_id, n);
"""

_DEVICE_MODELS = """
CREATE TABLE device_models (
    id INTEGER PRIMARY KEY,
    run_id INTEGER REFERENCES runs(id) ON DELETE CASCADE,
    time_utc TEXT NOT NULL,
    board_id TEXT,
    set_v REAL NOT NULL,
    reset_v REAL NOT NULL,
    width_us INTEGER NOT NULL,
    cells INTEGER NOT NULL,
    model_json TEXT NOT NULL
);
CREATE INDEX device_models_pulse ON device_models(set_v, reset_v, width_us, id);
"""
_SCHEMA += _DEVICE_MODELS

_MIGRATIONS: dict[int, str] = {2: _DEVICE_MODELS}
"""What each step of the schema adds, by the version it leads to."""

TABLE_COLUMNS: dict[str, tuple[str, ...]] = {
    "runs": ("id", "kind", "command", "started_utc", "finished_utc", "status", "board_id",
             "firmware_version", "port", "protocol", "seed", "version", "record_level",
             "config_json", "summary_json"),
    "cell_results": ("id", "run_id", "row", "col", "time_utc", "outcome", "g_s", "target_s",
                     "pulses", "detail_json"),
    "pulses": ("id", "run_id", "row", "col", "n", "time_utc", "stage", "polarity",
               "amplitude_v", "width_us", "g_before_s", "g_after_s"),
    "device_models": ("id", "run_id", "time_utc", "board_id", "set_v", "reset_v", "width_us",
                      "cells", "model_json"),
}
"""Columns of each table, in order (the CSV export's header)."""


class HistoryError(UserError):
    """A history file that cannot be used for this command (one line, exit code 2)."""


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds")


def _num(x: Any) -> float | None:
    if x is None:
        return None
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def _json(obj: Any) -> str | None:
    if obj is None:
        return None
    return json.dumps(obj, default=str, allow_nan=False, separators=(",", ":"))


def _sniff(path: Path) -> str | None:
    """None if ``path`` is missing, empty, or a SQLite file carrying our application id; else
    what it is instead (for the message)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(100)
    except FileNotFoundError:
        return None
    except IsADirectoryError:
        return "a folder"
    except OSError as exc:
        return f"unreadable ({exc.strerror or exc})"
    if not head:
        return None
    if not head.startswith(_SQLITE_MAGIC):
        return "not an SQLite database"
    if len(head) < 72:
        return "a truncated SQLite file"
    app_id = int.from_bytes(head[68:72], "big")
    if app_id != APPLICATION_ID:
        return "an SQLite database of another program"
    return None


def check_history_file(path: str | os.PathLike[str], option: str = "--history") -> Path:
    """``path`` as a Path if it may hold this board's history (missing, empty, or ours);
    :class:`HistoryError` naming what it is otherwise. Never writes."""
    p = Path(path).expanduser()
    what = _sniff(p)
    if what is not None:
        raise HistoryError(f"{option} {p}: is {what}, not a snan-hil history database; give "
                           "another file, or move it away (it is never overwritten)")
    return p


@dataclass(frozen=True)
class RunRow:
    """One row of ``runs`` (JSON fields decoded)."""

    id: int
    kind: str
    command: str
    started_utc: str
    finished_utc: str | None
    status: str
    board_id: str | None
    firmware_version: str | None
    port: str | None
    protocol: str | None
    seed: int | None
    version: str
    record_level: str
    config: Any
    summary: Any
    cells: int = 0
    pulses: int = 0

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


@dataclass(frozen=True)
class CellLifeEvent:
    """One event in a cell's life: a pulse (``polarity`` set) or a run's result for the cell."""

    time_utc: str
    run_id: int
    kind: str
    event: str                  # "pulse" or "result"
    g_s: float | None           # conductance after the event (S)
    pulses_total: int           # pulses applied to the cell so far (over all runs recorded)
    polarity: str | None = None
    amplitude_v: float | None = None
    width_us: int | None = None
    g_before_s: float | None = None
    outcome: str | None = None
    stage: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


class History:
    """An open history database (read and write). :meth:`open` checks the file is ours,
    creates or migrates the schema; errors are :class:`sqlite3.Error` / :class:`HistoryError`
    (the caller decides: :class:`Recorder` turns them into a warning)."""

    def __init__(self, conn: sqlite3.Connection, path: Path) -> None:
        self.conn = conn
        self.path = path

    @classmethod
    def open(cls, path: str | os.PathLike[str], *, create: bool = True,
             timeout_s: float | None = None) -> History:
        """Open (``create``: create when missing) the database at ``path``; a write waits
        ``timeout_s`` (default :data:`BUSY_TIMEOUT_S`) for another process's lock."""
        timeout_s = BUSY_TIMEOUT_S if timeout_s is None else timeout_s
        p = check_history_file(path)
        if not create and not p.is_file():
            raise HistoryError(f"no history database at {p}; it is written by program-weights, "
                               "cells test, pulse, retention, map and mac")
        if create:
            p.parent.mkdir(parents=True, exist_ok=True)
        conn = sqlite3.connect(str(p), timeout=timeout_s, isolation_level=None)
        try:
            conn.execute("PRAGMA foreign_keys = ON")
            db = cls(conn, p)
            db._ensure_schema(create)
        except BaseException:
            conn.close()
            raise
        return db

    def _ensure_schema(self, create: bool) -> None:
        app_id = self.conn.execute("PRAGMA application_id").fetchone()[0]
        version = self.conn.execute("PRAGMA user_version").fetchone()[0]
        tables = self.conn.execute("SELECT count(*) FROM sqlite_master").fetchone()[0]
        if app_id == 0 and version == 0 and tables == 0:
            if not create:
                raise HistoryError(f"{self.path} is an empty file, not a history database")
            with self.transaction():
                for stmt in _SCHEMA.strip().split(";"):
                    if stmt.strip():
                        self.conn.execute(stmt)
                self.conn.execute(f"PRAGMA application_id = {APPLICATION_ID}")
                self.conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")
                self.conn.executemany("INSERT INTO meta(key, value) VALUES (?, ?)",
                                      [("format", FORMAT), ("created_utc", _now()),
                                       ("created_by", _version())])
            return
        if app_id != APPLICATION_ID:
            raise HistoryError(f"{self.path} is an SQLite database of another program, not a "
                               "snan-hil history database; give another file")
        if version > SCHEMA_VERSION:
            raise HistoryError(f"history database {self.path} has schema version {version}, "
                               f"this snan-hil knows up to {SCHEMA_VERSION}; update snan-hil")
        for step in range(version + 1, SCHEMA_VERSION + 1):     # one migration per step
            with self.transaction():
                for stmt in _MIGRATIONS[step].strip().split(";"):
                    if stmt.strip():
                        self.conn.execute(stmt)
                self.conn.execute(f"PRAGMA user_version = {step}")
            log.info("history database %s migrated to schema version %d", self.path, step)

    @contextmanager
    def transaction(self) -> Iterator[sqlite3.Connection]:
        """``BEGIN IMMEDIATE`` ... ``COMMIT`` (rolled back on any exception)."""
        self.conn.execute("BEGIN IMMEDIATE")
        try:
            yield self.conn
        except BaseException:
            self.conn.execute("ROLLBACK")
            raise
        self.conn.execute("COMMIT")

    def close(self) -> None:
        self.conn.close()

    def __enter__(self) -> History:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ writing
    def begin_run(self, kind: str, *, command: str, board_id: str | None = None,
                  firmware_version: str | None = None, port: str | None = None,
                  protocol: str | None = None, seed: int | None = None,
                  config: Any = None, record_level: str = "pulses") -> int:
        """Insert a run (status ``running``) and return its id."""
        if kind not in KINDS:
            raise ValueError(f"unknown run kind {kind!r}")
        if record_level not in LEVELS:
            raise ValueError(f"unknown record level {record_level!r}")
        with self.transaction() as c:
            cur = c.execute(
                "INSERT INTO runs(kind, command, started_utc, status, board_id, "
                "firmware_version, port, protocol, seed, version, record_level, config_json) "
                "VALUES (?, ?, ?, 'running', ?, ?, ?, ?, ?, ?, ?, ?)",
                (kind, command, _now(), board_id, firmware_version, port, protocol, seed,
                 _version(), record_level, _json(config)))
            return int(cur.lastrowid or 0)

    def end_run(self, run_id: int, status: str, summary: Any = None) -> None:
        with self.transaction() as c:
            c.execute("UPDATE runs SET status = ?, finished_utc = ?, summary_json = ? "
                      "WHERE id = ?", (status, _now(), _json(summary), run_id))

    def add_cells(self, run_id: int, rows: Sequence[tuple]) -> None:
        """Rows ``(row, col, time_utc, outcome, g_s, target_s, pulses, detail)``."""
        with self.transaction() as c:
            c.executemany(
                "INSERT INTO cell_results(run_id, row, col, time_utc, outcome, g_s, target_s, "
                "pulses, detail_json) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                [(run_id, int(r), int(col), t, str(o), _num(g), _num(tg),
                  None if n is None else int(n), _json(d))
                 for r, col, t, o, g, tg, n, d in rows])

    def add_pulses(self, run_id: int, rows: Sequence[tuple]) -> None:
        """Rows ``(row, col, n, time_utc, stage, polarity, amplitude_v, width_us, g_before_s,
        g_after_s)``."""
        with self.transaction() as c:
            c.executemany(
                "INSERT INTO pulses(run_id, row, col, n, time_utc, stage, polarity, amplitude_v, "
                "width_us, g_before_s, g_after_s) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                [(run_id, int(r), int(col), int(n), t, None if st is None else str(st), str(p),
                  float(a), int(w), _num(gb), _num(ga))
                 for r, col, n, t, st, p, a, w, gb, ga in rows])

    def add_device_model(self, run_id: int | None, model: dict[str, Any], *,
                         board_id: str | None = None) -> int:
        """Store a fitted device model (``DeviceModel.to_dict()``: needs ``pulse`` with
        ``set_v``, ``reset_v``, ``width_us``, and ``cells``); its row id."""
        p = model["pulse"]
        with self.transaction() as c:
            cur = c.execute(
                "INSERT INTO device_models(run_id, time_utc, board_id, set_v, reset_v, width_us, "
                "cells, model_json) VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                (run_id, _now(), board_id, float(p["set_v"]), float(p["reset_v"]),
                 int(p["width_us"]), sum(1 for x in model.get("cells", []) if x.get("ok")),
                 _json(model)))
            return int(cur.lastrowid or 0)

    def device_models(self) -> list[dict[str, Any]]:
        """Every stored device model, newest first: ``{id, run_id, time_utc, board_id, set_v,
        reset_v, width_us, cells, model}``."""
        cols = TABLE_COLUMNS["device_models"]
        out = []
        for row in self.conn.execute(f"SELECT {', '.join(cols)} FROM device_models "
                                     "ORDER BY id DESC"):
            d = dict(zip(cols, row))
            d["model"] = _loads(d.pop("model_json"))
            out.append(d)
        return out

    def latest_device_model(self, *, set_v: float | None = None, reset_v: float | None = None,
                            width_us: int | None = None) -> dict[str, Any] | None:
        """The newest device model (of that learning pulse, where given), or None."""
        for d in self.device_models():
            if set_v is not None and abs(d["set_v"] - set_v) > 1e-9:
                continue
            if reset_v is not None and abs(d["reset_v"] - reset_v) > 1e-9:
                continue
            if width_us is not None and d["width_us"] != width_us:
                continue
            return d
        return None

    # ------------------------------------------------------------------ reading
    def has_run(self, run_id: int) -> bool:
        """Whether a run with this id is recorded."""
        return self.conn.execute("SELECT 1 FROM runs WHERE id = ?",
                                 (int(run_id),)).fetchone() is not None

    def runs(self, kind: str | None = None, limit: int | None = None) -> list[RunRow]:
        """Runs, newest first, with their counts of cell results and pulses."""
        sql = ("SELECT r.*, (SELECT count(*) FROM cell_results c WHERE c.run_id = r.id), "
               "(SELECT count(*) FROM pulses p WHERE p.run_id = r.id) FROM runs r")
        args: list[Any] = []
        if kind is not None:
            sql += " WHERE r.kind = ?"
            args.append(kind)
        sql += " ORDER BY r.id DESC"
        if limit is not None:
            sql += " LIMIT ?"
            args.append(int(limit))
        out = []
        for row in self.conn.execute(sql, args):
            d = dict(zip(TABLE_COLUMNS["runs"], row[:15]))
            out.append(RunRow(
                id=d["id"], kind=d["kind"], command=d["command"], started_utc=d["started_utc"],
                finished_utc=d["finished_utc"], status=d["status"], board_id=d["board_id"],
                firmware_version=d["firmware_version"], port=d["port"], protocol=d["protocol"],
                seed=d["seed"], version=d["version"], record_level=d["record_level"],
                config=_loads(d["config_json"]), summary=_loads(d["summary_json"]),
                cells=int(row[15]), pulses=int(row[16])))
        return out

    def latest_cell_results(self, kind: str) -> dict[tuple[int, int], tuple[str, str, int]]:
        """For every cell, the last result of a run of ``kind``: {(row, col): (outcome,
        time_utc, run_id)}."""
        rows = self.conn.execute(
            "SELECT c.row, c.col, c.outcome, c.time_utc, c.run_id FROM cell_results c "
            "JOIN runs r ON r.id = c.run_id WHERE r.kind = ? ORDER BY c.id", (kind,))
        return {(int(r), int(col)): (str(o), str(t), int(run)) for r, col, o, t, run in rows}

    def cell_life(self, row: int, col: int) -> list[CellLifeEvent]:
        """Every recorded pulse and result of cell (row, col), in order of recording, with the
        running count of pulses."""
        events: list[tuple[str, int, int, str, Any]] = []
        for rec in self.conn.execute(
                "SELECT p.id, p.run_id, r.kind, p.time_utc, p.stage, p.polarity, p.amplitude_v, "
                "p.width_us, p.g_before_s, p.g_after_s FROM pulses p JOIN runs r ON r.id = "
                "p.run_id WHERE p.row = ? AND p.col = ?", (row, col)):
            events.append((rec[3], 0, rec[0], "pulse", rec))
        for rec in self.conn.execute(
                "SELECT c.id, c.run_id, r.kind, c.time_utc, c.outcome, c.g_s, c.pulses "
                "FROM cell_results c JOIN runs r ON r.id = c.run_id WHERE c.row = ? AND "
                "c.col = ?", (row, col)):
            events.append((rec[3], 1, rec[0], "result", rec))
        # by time; a cell's pulses are written with (just before) its result
        events.sort(key=lambda e: (e[0], e[1], e[2]))
        out: list[CellLifeEvent] = []
        total = 0
        for _t, _order, _id, what, rec in events:
            if what == "pulse":
                _id, run_id, kind, t, stage, pol, amp, width, gb, ga = rec
                total += 1
                out.append(CellLifeEvent(t, run_id, kind, "pulse", ga, total, pol, amp, width,
                                         gb, stage=stage))
            else:
                _id, run_id, kind, t, outcome, g, _pulses = rec
                out.append(CellLifeEvent(t, run_id, kind, "result", g, total, outcome=outcome))
        return out

    def export_csv(self, table: str, run_id: int | None = None) -> str:
        """The rows of ``table`` (runs, cell_results, pulses) as CSV text; ``run_id`` limits
        them to one run."""
        if table not in TABLE_COLUMNS:
            raise HistoryError(f"unknown table {table!r}; one of {', '.join(TABLE_COLUMNS)}")
        cols = TABLE_COLUMNS[table]
        sql = f"SELECT {', '.join(cols)} FROM {table}"
        args: list[Any] = []
        if run_id is not None:
            sql += " WHERE " + ("id" if table == "runs" else "run_id") + " = ?"
            args.append(int(run_id))
        sql += " ORDER BY id"
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(cols)
        for row in self.conn.execute(sql, args):
            w.writerow(["" if v is None else v for v in row])
        return buf.getvalue()


def _loads(text: str | None) -> Any:
    if text is None:
        return None
    try:
        return json.loads(text)
    except ValueError:
        return text


def _version() -> str:
    from snan_hil import __version__
    return f"snan-hil {__version__}"


def _polarity_name(p: Any) -> str:
    name = getattr(p, "name", None)
    return str(name if name is not None else p)


class Recorder:
    """Records one run into a history database; never raises on a database problem.

    The first :class:`sqlite3.Error` or :class:`OSError` (a damaged or locked file, a full
    disk) is reported once through ``warn`` (one line) and recording stops for the rest of
    the run; the run itself goes on. Pulses and cell results are buffered and written one
    transaction per cell (:meth:`on_cell`) and at :meth:`finish`.

    It is the cell observer of :mod:`snan_hil.calibration.observer` (``on_pulses``,
    ``on_cell``; events duck-typed: ``row``, ``col``, ``polarity`` (enum or name),
    ``amplitude_v``, ``width_us``, ``g_before_s``, ``g_after_s``, ``stage``; and ``row``,
    ``col``, ``outcome``, ``g_s``, ``target_s``, ``pulses``, ``detail``).
    """

    def __init__(self, path: str | os.PathLike[str] | None, kind: str, *, command: str,
                 level: str = "pulses", warn: Callable[[str], object] | None = None,
                 **run_fields: Any) -> None:
        if level not in LEVELS:
            raise HistoryError(f"unknown record level {level!r}; one of {', '.join(LEVELS)}")
        self.path = None if path is None else Path(path)
        self.level = level
        self.warn = warn or (lambda line: log.warning("%s", line))
        self.failed: str | None = None
        self.run_id: int | None = None
        self.db: History | None = None
        self._cells: list[tuple] = []
        self._pulses: list[tuple] = []
        self._count: dict[tuple[int, int], int] = {}
        self.recorded = {"cells": 0, "pulses": 0}
        if self.path is None:
            return
        self._guard(lambda: self._start(kind, command, run_fields))

    def _start(self, kind: str, command: str, run_fields: dict[str, Any]) -> None:
        assert self.path is not None
        self.db = History.open(self.path)
        self.run_id = self.db.begin_run(kind, command=command, record_level=self.level,
                                        **run_fields)

    @property
    def active(self) -> bool:
        return self.db is not None and self.run_id is not None and self.failed is None

    def _close_db(self) -> None:
        """Close the database if open (a failing close is ignored) and forget it."""
        if self.db is not None:
            try:
                self.db.close()
            except sqlite3.Error:
                pass
        self.db = None

    def _guard(self, fn: Callable[[], Any]) -> None:
        if self.failed is not None:
            return
        try:
            fn()
        except (sqlite3.Error, OSError, HistoryError) as exc:
            self.failed = _describe_error(exc)
            self.warn(f"history database {self.path}: {self.failed}; this run is not recorded "
                      "there (the run itself goes on and writes its own report)")
            self._close_db()

    # ------------------------------------------------------------------ observer
    def on_pulses(self, events: Sequence[Any]) -> None:
        """Pulses applied to one or more cells (buffered)."""
        if not self.active or self.level != "pulses":
            return
        t = _now()
        for e in events:
            key = (int(e.row), int(e.col))
            n = self._count.get(key, 0) + 1
            self._count[key] = n
            self._pulses.append((key[0], key[1], n, t, getattr(e, "stage", None),
                                 _polarity_name(e.polarity), float(e.amplitude_v),
                                 int(e.width_us), e.g_before_s, e.g_after_s))

    def on_cell(self, event: Any) -> None:
        """A cell's result; writes it (and the buffered pulses) in one transaction."""
        if not self.active:
            return
        if self.level in ("cells", "pulses"):
            self._cells.append((event.row, event.col, _now(), event.outcome,
                                event.g_s, getattr(event, "target_s", None),
                                getattr(event, "pulses", None), getattr(event, "detail", None)))
        self.flush()

    def on_cells(self, events: Sequence[Any]) -> None:
        """Results of many cells (a map, a retention run), written in one transaction."""
        if not self.active:
            return
        if self.level in ("cells", "pulses"):
            t = _now()
            self._cells.extend((e.row, e.col, t, e.outcome, e.g_s, getattr(e, "target_s", None),
                                getattr(e, "pulses", None), getattr(e, "detail", None))
                               for e in events)
        self.flush()

    def flush(self) -> None:
        """Write what is buffered."""
        if not self.active or not (self._cells or self._pulses):
            return
        cells, pulses = self._cells, self._pulses
        self._cells, self._pulses = [], []

        def write() -> None:
            assert self.db is not None and self.run_id is not None
            if pulses:
                self.db.add_pulses(self.run_id, pulses)
            if cells:
                self.db.add_cells(self.run_id, cells)
            self.recorded["pulses"] += len(pulses)
            self.recorded["cells"] += len(cells)
        self._guard(write)

    def add_device_model(self, model: dict[str, Any], board_id: str | None = None) -> int | None:
        """Store a fitted device model with this run (:meth:`History.add_device_model`); its
        row id, None when the run is not recorded (no database, or it failed)."""
        self.flush()
        if not self.active:
            return None
        got: list[int] = []

        def write() -> None:
            assert self.db is not None
            got.append(self.db.add_device_model(self.run_id, model, board_id=board_id))
        self._guard(write)
        return got[0] if got else None

    def finish(self, status: str, summary: Any = None) -> None:
        """Write what is buffered, close the run with ``status`` and ``summary``, close the
        file."""
        self.flush()

        def end() -> None:
            assert self.db is not None and self.run_id is not None
            self.db.end_run(self.run_id, status, summary)
        if self.active:
            self._guard(end)
        self._close_db()

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if self.db is None:
            return
        if exc_type is None:
            self.finish("complete")
        elif issubclass(exc_type, KeyboardInterrupt):
            self.finish("interrupted")
        else:
            self.finish("failed", {"error": f"{exc_type.__name__}: {exc}"})


def _describe_error(exc: BaseException) -> str:
    text = str(exc) or type(exc).__name__
    low = text.lower()
    if "locked" in low or "busy" in low:
        return f"locked by another program ({text})"
    if "malformed" in low or "not a database" in low or "corrupt" in low:
        return f"damaged ({text})"
    if isinstance(exc, OSError):
        return exc.strerror or text
    return text
