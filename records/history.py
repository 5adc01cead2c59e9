"""The chip history database: every programming run, cell test, pulse ticket, retention run, map
and column-multiply test of one board, in one SQLite file (the standard library's ``sqlite3``).

A base module like :mod:`snan_hil.files.outputs`: it imports no layer (cells are ``(row, col)``,
polarities their names, conductances floats in S), and every layer may import it. The CLI
decides where the file lives (one per board identity, beside the board's layout:
:class:`snan_hil.board.files.BoardFiles`), opens it with :meth:`History.open`
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
    -- version 2 (additive): the run's metadata and uid, its documents, control requests
    runs(+ uid, sample, operator, note, tags_json)
    documents(id, run_id -> runs, name, uid, time, doc_json)     start/descriptor/event/stop
    controls(id, run_uid, time_utc, action, source)               pause / resume / stop
    -- version 3 (additive): device models fitted by ``characterize``
    device_models(id, run_id -> runs, time_utc, board_id, set_v, reset_v, width_us, cells,
                  model_json)
    -- version 4 (additive): the process that records a run (its crash is then recognised)
    runs(+ pid, host)

``kind``: program, screen, pulse, plan, read, console, retention, map, mac, hil, experiment,
characterize, learn. A ``device_models`` row is the compact device model a characterisation
fitted (:class:`snan_hil.crossbar_model.fitted.DeviceModel`'s ``to_dict``, kept as JSON: this
module imports no layer) at one learning pulse; :meth:`History.latest_device_model` is what
``snan-hil learn`` uses.
``status``: running, complete, interrupted, failed, crashed (a ``running`` run whose process,
``pid`` on ``host``, is gone: killed with SIGKILL, a power cut; shown so by every reader
(:func:`process_alive`) and written so when a later run begins on this host). ``outcome``
depends on the kind (program: ok / failed; screen: the cell's class; map and retention: read /
stable / unstable; pulse and plan: why it stopped). ``n`` is the pulse's number on that cell
within the run (1, 2, ...).
Record levels (:data:`LEVELS`): ``runs`` (run rows only), ``cells`` (+ one result per cell),
``pulses`` (+ every pulse).

Every run is one stream of documents (:mod:`snan_hil.records.documents`, the Bluesky event
model's shapes); the :class:`Recorder` is its subscriber: the documents go to ``documents``
verbatim (the run's record for export and for ``snan-hil watch``), and the pulses and cell
results also to their tables (the queryable view). The file is in WAL mode (``PRAGMA
journal_mode = WAL``): a reader -- ``history``, ``watch`` -- never blocks the running job, and
the job never blocks a reader. :meth:`History.backup` copies it with SQLite's online backup.

Failure policy (docs/bench.md): a file that is not a snan-hil history database is refused
before any work (:func:`check_history_file`, a :class:`HistoryError`, exit 2), as is a damaged
one a command would add to (:func:`check_history_intact`: SQLite's quick check; ``snan-hil
history recover``, :mod:`snan_hil.records.recover`, saves its rows); an SQLite file with
nothing in it (a first run cut while it created the file) is initialised. Another
connection's lock never drops a record: the :class:`Recorder` queues, waits at the run's end,
and leaves what a lock still keeps out in a pending file that the next open applies
(:mod:`snan_hil.records.pending`). A database that fails otherwise while a run records
(damaged, a full disk) gives one warning line, and the job stops before its next board
request (:meth:`Recorder.check`).
"""

from __future__ import annotations

import csv
import datetime as _dt
import io
import json
import logging
import math
import os
import socket
import sqlite3
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from snan_hil.common.errors import UserError
from snan_hil.common.version import __version__
from snan_hil.records.documents import RunMetadata, RunPublisher
from snan_hil.records.interrupts import RecordingStopped
from snan_hil.records.pending import FORMAT as PENDING_FORMAT
from snan_hil.records.pending import MARK, pending_dir, pending_files, write_pending

__all__ = ["SCHEMA_VERSION", "APPLICATION_ID", "FORMAT", "LEVELS", "KINDS", "CONTROL_ACTIONS",
           "HistoryError", "process_alive",
           "check_history_file", "History", "Recorder", "RunRow", "CellLifeEvent",
           "TABLE_COLUMNS"]

log = logging.getLogger(__name__)

SCHEMA_VERSION = 4
APPLICATION_ID = 0x534E4849          # "SNHI"
FORMAT = "snan-hil-history/1"
LEVELS = ("runs", "cells", "pulses")
KINDS = ("program", "screen", "pulse", "plan", "read", "console", "retention", "map", "mac",
         "hil", "experiment", "characterize", "learn", "selftest",
         "transfer")
CONTROL_ACTIONS = ("pause", "resume", "stop")
FLUSH_INTERVAL_S = 0.5
"""A recorder writes what it buffered at least this often (s) while events arrive, so a live
view follows a long cell (one transaction per cell otherwise)."""
_SQLITE_MAGIC = b"SQLite format 3\x00"
BUSY_TIMEOUT_S = 2.0
"""How long a write waits for another connection's lock before its records are queued (s)."""
RETRY_INTERVAL_S = 1.0
"""While a lock keeps a recorder's queue out: least time between two tries (s)."""
RETRY_BUSY_S = 0.1
"""While a lock keeps a recorder's queue out: how long each later try waits for it (s), so the
job is not held up."""
FINISH_WAIT_S = 30.0
"""How long the end of a run waits for a lock before its queue goes to a pending file (s)."""
MAX_QUEUED_DOCUMENTS = 50_000
"""A queue longer than this (documents; a pulse is one) goes to a pending file at once."""

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

_MIGRATIONS: dict[int, str] = {
    # 1 -> 2: run metadata and uid, the run's documents, control requests (all additive)
    2: """
ALTER TABLE runs ADD COLUMN uid TEXT;
ALTER TABLE runs ADD COLUMN sample TEXT;
ALTER TABLE runs ADD COLUMN operator TEXT;
ALTER TABLE runs ADD COLUMN note TEXT;
ALTER TABLE runs ADD COLUMN tags_json TEXT;
CREATE UNIQUE INDEX runs_uid ON runs(uid);
CREATE TABLE documents (
    id INTEGER PRIMARY KEY,
    run_id INTEGER NOT NULL REFERENCES runs(id) ON DELETE CASCADE,
    name TEXT NOT NULL,
    uid TEXT NOT NULL,
    time REAL NOT NULL,
    doc_json TEXT NOT NULL
);
CREATE INDEX documents_run ON documents(run_id, id);
CREATE TABLE controls (
    id INTEGER PRIMARY KEY,
    run_uid TEXT NOT NULL,
    time_utc TEXT NOT NULL,
    action TEXT NOT NULL,
    source TEXT
);
CREATE INDEX controls_run ON controls(run_uid, id);
""",
    # 2 -> 3: the device models fitted by ``characterize`` (additive)
    3: """
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
""",
    # 3 -> 4: the recording process, so a run whose process died is recognised (additive)
    4: """
ALTER TABLE runs ADD COLUMN pid INTEGER;
ALTER TABLE runs ADD COLUMN host TEXT;
""",
}
"""Schema steps: version -> the SQL that brings version - 1 to it (a new file runs them all)."""

TABLE_COLUMNS: dict[str, tuple[str, ...]] = {
    "runs": ("id", "kind", "command", "started_utc", "finished_utc", "status", "board_id",
             "firmware_version", "port", "protocol", "seed", "version", "record_level",
             "config_json", "summary_json", "uid", "sample", "operator", "note", "tags_json",
             "pid", "host"),
    "cell_results": ("id", "run_id", "row", "col", "time_utc", "outcome", "g_s", "target_s",
                     "pulses", "detail_json"),
    "pulses": ("id", "run_id", "row", "col", "n", "time_utc", "stage", "polarity",
               "amplitude_v", "width_us", "g_before_s", "g_after_s"),
    "documents": ("id", "run_id", "name", "uid", "time", "doc_json"),
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
    """None if ``path`` is missing, empty, a SQLite file carrying our application id, or an
    SQLite database with nothing in it (no application id, no table: what a first command
    killed while it created the file leaves; :meth:`History.open` initialises it); else what
    it is instead (for the message)."""
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
    if app_id != APPLICATION_ID and _sqlite_says(path) not in (APPLICATION_ID, 0):
        return "an SQLite database of another program"
    return None


def _sqlite_says(path: Path) -> int | None:
    """The application id SQLite reads (through a write-ahead log the file's header may not
    show yet: a creation killed after its commit, before the checkpoint), 0 for a database
    with no table at all (a creation killed before its commit), None when it cannot be read.
    Opens the file read-only (the POSIX-lock caveat of :func:`check_history_file`)."""
    try:
        conn = sqlite3.connect(f"{Path(path).resolve().as_uri()}?mode=ro", uri=True,
                               timeout=BUSY_TIMEOUT_S)
    except sqlite3.Error:
        return None
    try:
        app_id = int(conn.execute("PRAGMA application_id").fetchone()[0])
        if app_id:
            return app_id
        tables = int(conn.execute("SELECT count(*) FROM sqlite_master").fetchone()[0])
        version = int(conn.execute("PRAGMA user_version").fetchone()[0])
        return 0 if tables == 0 and version == 0 else -1
    except sqlite3.Error:
        return None
    finally:
        conn.close()


_INTACT: dict[tuple[str, int, int], str | None] = {}
"""Integrity checks already made in this process: (path, size, mtime ns) -> the problem."""


def integrity_problem(path: str | os.PathLike[str]) -> str | None:
    """The first problem SQLite's ``PRAGMA quick_check`` finds in the database at ``path``
    (pages, b-trees, records; ~0.3 s per 100 MB), or None when it is intact, missing or
    empty. A file whose check passed is not checked again in this process while its size and
    time stay the same. Never writes; read-only (the POSIX-lock caveat of
    :func:`check_history_file`)."""
    p = Path(path).expanduser()
    try:
        st = p.stat()
    except OSError:
        return None
    if st.st_size == 0:
        return None
    key = (str(p.resolve()), st.st_size, st.st_mtime_ns)
    if key in _INTACT:
        return _INTACT[key]
    problem: str | None
    try:
        conn = sqlite3.connect(f"{p.resolve().as_uri()}?mode=ro", uri=True,
                               timeout=BUSY_TIMEOUT_S)
        try:
            rows = conn.execute("PRAGMA quick_check(3)").fetchall()
        finally:
            conn.close()
        found = [line.strip() for r in rows for line in str(r[0]).splitlines()
                 if line.strip() and line.strip() != "ok" and not line.startswith("***")]
        problem = "; ".join(found[:2])[:200] or None
    except sqlite3.Error as exc:
        if _transient(exc):
            return None                 # locked: a writer is at work, not a damaged file
        problem = str(exc)
    _INTACT[key] = problem
    return problem


def check_history_intact(path: str | os.PathLike[str], option: str = "--history") -> Path:
    """``path`` (a file :func:`check_history_file` accepts) as a Path when SQLite finds it
    intact (:func:`integrity_problem`); else :class:`HistoryError`: it is damaged, nothing is
    added to it, and how to save what it holds (``snan-hil history recover``). What a command
    that adds to the history checks before any work."""
    p = check_history_file(path, option)
    problem = integrity_problem(p)
    if problem is not None:
        raise HistoryError(damaged_text(p, problem, option))
    return p


def damaged_text(path: Path, problem: str, option: str = "--history") -> str:
    """One line: the history database at ``path`` is damaged, and what to do."""
    return (f"{option} {path}: the history database is damaged (SQLite: {problem}); nothing "
            f"was added to it. Save what it still holds with 'snan-hil history recover "
            f"--history {path} -o NEW.sqlite', then move {path} away (the next run starts a "
            "new one) or record into --history NEW.sqlite")


def _transient(exc: BaseException) -> bool:
    """Whether an SQLite error is another connection's lock (SQLITE_BUSY, SQLITE_LOCKED and
    their extended codes): it passes; anything else (a damaged file, a full disk, an I/O
    error) does not."""
    code = getattr(exc, "sqlite_errorcode", None)
    if isinstance(code, int):
        return code & 0xFF in (5, 6)
    text = str(exc).lower()
    return "locked" in text or "busy" in text


def _host() -> str:
    return socket.gethostname()


def process_alive(pid: int | None, host: str | None, started_utc: str | None) -> bool | None:
    """Whether the process ``pid`` on ``host`` that began a run at ``started_utc`` still runs:
    None when it cannot be told (no pid recorded — a run of an older snan-hil —, or another
    host); False when no such process exists or the pid now belongs to a process started
    after the run (a reused pid)."""
    if pid is None or host is None or host != _host():
        return None
    import psutil             # ~30 ms, only to tell a stale run's process: not at every start
    try:
        created = psutil.Process(int(pid)).create_time()
    except (psutil.NoSuchProcess, psutil.ZombieProcess):
        return False
    except (psutil.Error, OverflowError, ValueError):
        return None
    try:
        started = _dt.datetime.fromisoformat(str(started_utc)).timestamp()
    except ValueError:
        return True
    return created <= started + 1.0


def check_history_file(path: str | os.PathLike[str], option: str = "--history") -> Path:
    """``path`` as a Path if it may hold this board's history (missing, empty, or ours);
    :class:`HistoryError` naming what it is otherwise. Never writes.

    It reads the file with ``open()``: never call it (nor :meth:`History.open`) on a file this
    process already has open as a database -- closing the descriptor drops the process's POSIX
    locks on it (SQLite's "how to corrupt" pitfall); share the open :class:`History`."""
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
    uid: str | None = None
    sample: str | None = None
    operator: str | None = None
    note: str | None = None
    tags: tuple[str, ...] = ()
    pid: int | None = None
    host: str | None = None

    def to_dict(self) -> dict[str, Any]:
        d = dict(self.__dict__)
        d["tags"] = list(self.tags)
        return d


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
        self.schema_version = SCHEMA_VERSION

    @classmethod
    def open(cls, path: str | os.PathLike[str], *, create: bool = True,
             timeout_s: float | None = None) -> History:
        """Open (``create``: create when missing) the database at ``path``; a write waits
        ``timeout_s`` (default :data:`BUSY_TIMEOUT_S`) for another process's lock."""
        timeout_s = BUSY_TIMEOUT_S if timeout_s is None else timeout_s
        p = check_history_file(path)
        if not create and not p.is_file():
            raise HistoryError(f"no history database at {p}: nothing was recorded there yet "
                               "(a command that uses this board records its runs there, "
                               "unless --record off; --history FILE names another file)")
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
        db.apply_pending()
        return db

    @property
    def pending_dir(self) -> Path:
        """Where runs that could not wait for a lock keep their records until they are
        applied (:mod:`snan_hil.records.pending`): ``<file>.pending/`` beside the file."""
        return pending_dir(self.path)

    def apply_pending(self) -> int:
        """Write the records runs left in :attr:`pending_dir` (they could not get the lock in
        time) into the database, in order, each file once; how many files were applied. A
        lock or a bad file leaves them for the next open (never raises for them)."""
        return _apply_pending(self)

    def _ensure_schema(self, create: bool) -> None:
        # one statement, one read snapshot: read one by one, another process's schema could
        # commit between them (application id 0 read before, tables after: "another program")
        app_id, version, tables = self.conn.execute(
            "SELECT (SELECT application_id FROM pragma_application_id()), "
            "(SELECT user_version FROM pragma_user_version()), "
            "(SELECT count(*) FROM sqlite_master)").fetchone()
        if app_id == 0 and version == 0 and tables == 0:
            if not create:
                raise HistoryError(f"{self.path} holds no history yet (an empty database: "
                                   "nothing was recorded there, or the first run was cut "
                                   "while it created the file; the next run initialises it)")
            if self._create():
                return
            # another process created it between the look above and our write lock
            app_id = self.conn.execute("PRAGMA application_id").fetchone()[0]
            version = self.conn.execute("PRAGMA user_version").fetchone()[0]
        if app_id != APPLICATION_ID:
            raise HistoryError(f"{self.path} is an SQLite database of another program, not a "
                               "snan-hil history database; give another file")
        if version > SCHEMA_VERSION:
            raise HistoryError(f"history database {self.path} has schema version {version}, "
                               f"this snan-hil knows up to {SCHEMA_VERSION}; update snan-hil")
        if version < SCHEMA_VERSION:        # additive steps; a reader of an old file migrates it
            self._wal()
            with self.transaction():
                now = self.conn.execute("PRAGMA user_version").fetchone()[0]
                for step in range(now + 1, SCHEMA_VERSION + 1):
                    _script(self.conn, _MIGRATIONS[step])
                    self.conn.execute(f"PRAGMA user_version = {step}")
                self.conn.execute("INSERT OR REPLACE INTO meta(key, value) VALUES (?, ?)",
                                  ("migrated_utc", _now()))
            self._checkpoint()
        elif create:
            self._wal()
        self.schema_version = int(self.conn.execute("PRAGMA user_version").fetchone()[0])

    def _create(self) -> bool:
        """Make the schema in an empty database, under the write lock: False (nothing done)
        when another process made it first (several commands starting on one new file)."""
        self._wal()
        with self.transaction():
            if self.conn.execute("SELECT count(*) FROM sqlite_master").fetchone()[0]:
                return False
            _script(self.conn, _SCHEMA)
            for step in sorted(_MIGRATIONS):
                _script(self.conn, _MIGRATIONS[step])
            self.conn.execute(f"PRAGMA application_id = {APPLICATION_ID}")
            self.conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")
            self.conn.executemany("INSERT INTO meta(key, value) VALUES (?, ?)",
                                  [("format", FORMAT), ("created_utc", _now()),
                                   ("created_by", _version())])
        self._checkpoint()
        return True

    def _checkpoint(self) -> None:
        """Write the WAL into the file: the header (application id, schema version) must be
        on disk for :func:`check_history_file`, which reads the file's first bytes."""
        try:
            self.conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")
        except sqlite3.Error as exc:             # another connection reads: it is retried
            log.info("history database %s: checkpoint postponed (%s)", self.path, exc)

    def _wal(self) -> None:
        """WAL mode (kept in the file): readers and the writer never block each other."""
        mode = self.conn.execute("PRAGMA journal_mode = WAL").fetchone()[0]
        if str(mode).lower() != "wal":
            log.info("history database %s: journal mode %s (WAL not available)", self.path,
                     mode)

    @contextmanager
    def transaction(self) -> Iterator[sqlite3.Connection]:
        """``BEGIN IMMEDIATE`` ... ``COMMIT`` (rolled back on any exception)."""
        self.conn.execute("BEGIN IMMEDIATE")
        try:
            yield self.conn
        except BaseException:
            self.conn.execute("ROLLBACK")
            raise
        try:
            self.conn.execute("COMMIT")
        except sqlite3.Error:                 # e.g. busy: nothing of it is kept, try again
            if self.conn.in_transaction:
                self.conn.execute("ROLLBACK")
            raise

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
                  config: Any = None, record_level: str = "pulses",
                  metadata: RunMetadata | None = None, started_utc: str | None = None) -> int:
        """Insert a run (status ``running``, this process's pid and host) and return its id;
        ``metadata``: its uid, sample, operator, note and tags (default: a new uid, nothing
        else); ``started_utc`` (default: now). A run with that uid recorded already (its
        pending records were applied first: :mod:`snan_hil.records.pending`) is that run."""
        fields = run_fields(kind, command=command, board_id=board_id,
                            firmware_version=firmware_version, port=port, protocol=protocol,
                            seed=seed, config=config, record_level=record_level,
                            metadata=metadata, started_utc=started_utc)
        self.mark_crashed()
        with self.transaction() as c:
            had = c.execute("SELECT id FROM runs WHERE uid = ?", (fields["uid"],)).fetchone()
            if had is not None:
                return int(had[0])
            return self.insert_run(c, fields)

    @staticmethod
    def insert_run(c: sqlite3.Connection, f: dict[str, Any]) -> int:
        """Insert the run of ``f`` (:func:`run_fields`) inside the caller's transaction."""
        cur = c.execute(
            "INSERT INTO runs(kind, command, started_utc, status, board_id, "
            "firmware_version, port, protocol, seed, version, record_level, config_json, "
            "uid, sample, operator, note, tags_json, pid, host) "
            "VALUES (?, ?, ?, 'running', ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
            (f["kind"], f["command"], f["started_utc"], f.get("board_id"),
             f.get("firmware_version"), f.get("port"), f.get("protocol"), f.get("seed"),
             f["version"], f["record_level"], _json(f.get("config")), f["uid"],
             f.get("sample"), f.get("operator"), f.get("note"), _json(list(f.get("tags") or [])),
             f.get("pid"), f.get("host")))
        return int(cur.lastrowid or 0)

    def mark_crashed(self) -> list[int]:
        """Set ``crashed`` on every ``running`` run of this host whose process is gone
        (:func:`process_alive`); their ids."""
        dead = [int(i) for i, pid, host, t in self.conn.execute(
                    "SELECT id, pid, host, started_utc FROM runs WHERE status = 'running' "
                    "AND pid IS NOT NULL").fetchall()
                if process_alive(pid, host, t) is False]
        if dead:
            with self.transaction() as c:
                c.executemany("UPDATE runs SET status = 'crashed' WHERE id = ? AND status = "
                              "'running'", [(i,) for i in dead])
        return dead

    def end_run(self, run_id: int, status: str, summary: Any = None,
                finished_utc: str | None = None) -> None:
        with self.transaction() as c:
            c.execute("UPDATE runs SET status = ?, finished_utc = ?, summary_json = ? "
                      "WHERE id = ?", (status, finished_utc or _now(), _json(summary), run_id))

    @staticmethod
    def _insert_cells(c: sqlite3.Connection, run_id: int, rows: Sequence[tuple]) -> None:
        c.executemany(
            "INSERT INTO cell_results(run_id, row, col, time_utc, outcome, g_s, target_s, "
            "pulses, detail_json) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
            [(run_id, int(r), int(col), t, str(o), _num(g), _num(tg),
              None if n is None else int(n), _json(d))
             for r, col, t, o, g, tg, n, d in rows])

    @staticmethod
    def _insert_documents(c: sqlite3.Connection, run_id: int,
                          docs: Sequence[tuple[str, dict[str, Any]]]) -> None:
        c.executemany("INSERT INTO documents(run_id, name, uid, time, doc_json) "
                      "VALUES (?, ?, ?, ?, ?)",
                      [(run_id, name, str(doc["uid"]), float(doc.get("time") or 0.0),
                        json.dumps(doc, allow_nan=False, separators=(",", ":")))
                       for name, doc in docs])

    def write_batch(self, run_id: int, *, pulses: Sequence[tuple] = (),
                    cells: Sequence[tuple] = (),
                    documents: Sequence[tuple[str, dict[str, Any]]] = ()) -> None:
        """Pulses, cell results and documents of a run in ONE transaction (what a recorder
        buffered), so a reader sees all of them or none."""
        with self.transaction() as c:
            if pulses:
                self._insert_pulses(c, run_id, pulses)
            if cells:
                self._insert_cells(c, run_id, cells)
            if documents:
                self._insert_documents(c, run_id, documents)

    def request_control(self, run_uid: str, action: str, source: str = "") -> int:
        """Ask the run ``run_uid`` to pause, resume or stop (it polls between pulses)."""
        if action not in CONTROL_ACTIONS:
            raise ValueError(f"unknown control action {action!r}")
        with self.transaction() as c:
            cur = c.execute("INSERT INTO controls(run_uid, time_utc, action, source) "
                            "VALUES (?, ?, ?, ?)", (run_uid, _now(), action, source))
            return int(cur.lastrowid or 0)

    def controls(self, run_uid: str, after_id: int = 0) -> list[tuple[int, str]]:
        """Control requests of ``run_uid`` after ``after_id``: [(id, action)] in order."""
        return [(int(i), str(a)) for i, a in self.conn.execute(
            "SELECT id, action FROM controls WHERE run_uid = ? AND id > ? ORDER BY id",
            (run_uid, int(after_id)))]

    def backup(self, dest: str | os.PathLike[str]) -> None:
        """Copy the database to ``dest`` with SQLite's online backup API (a consistent copy
        while a job writes; ``dest`` is replaced: the caller checks it and writes through a
        temporary file)."""
        target = sqlite3.connect(str(dest))
        try:
            self.conn.backup(target)
            target.execute("PRAGMA journal_mode = DELETE")   # a single self-contained file
        finally:
            target.close()

    @staticmethod
    def _insert_pulses(c: sqlite3.Connection, run_id: int, rows: Sequence[tuple]) -> None:
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
        return [self._run_row(row) for row in self.conn.execute(sql, args)]

    def _run_row(self, row: Sequence[Any]) -> RunRow:
        cols = TABLE_COLUMNS["runs"]
        d = dict(zip(cols, row[:len(cols)]))
        tags = _loads(d["tags_json"])
        status = d["status"]
        if status == "running" and process_alive(d["pid"], d["host"], d["started_utc"]) is False:
            status = "crashed"                 # its process is gone (module doc)
        return RunRow(
            id=d["id"], kind=d["kind"], command=d["command"], started_utc=d["started_utc"],
            finished_utc=d["finished_utc"], status=status, board_id=d["board_id"],
            firmware_version=d["firmware_version"], port=d["port"], protocol=d["protocol"],
            seed=d["seed"], version=d["version"], record_level=d["record_level"],
            config=_loads(d["config_json"]), summary=_loads(d["summary_json"]),
            cells=int(row[len(cols)]), pulses=int(row[len(cols) + 1]), uid=d["uid"],
            sample=d["sample"], operator=d["operator"], note=d["note"],
            tags=tuple(tags) if isinstance(tags, list) else (), pid=d["pid"], host=d["host"])

    def stage_pulses(self, uid: str, stages: Sequence[str]) -> int | None:
        """How many pulses of ``stages`` the run ``uid`` holds; None when no run has that uid
        (``snan-hil learn --resume`` reconciles its pulse journal with them)."""
        row = self.conn.execute("SELECT id FROM runs WHERE uid = ?", (uid,)).fetchone()
        if row is None:
            return None
        marks = ", ".join("?" * len(stages))
        return int(self.conn.execute(
            f"SELECT count(*) FROM pulses WHERE run_id = ? AND stage IN ({marks})",
            (int(row[0]), *stages)).fetchone()[0])

    def run(self, ref: int | str) -> RunRow | None:
        """One run by id (an int or digits) or uid (or a unique uid prefix of >= 6 chars; digits
        naming no id are tried as a uid prefix, since a hex prefix may be all digits)."""
        base = ("SELECT r.*, (SELECT count(*) FROM cell_results c WHERE c.run_id = r.id), "
                "(SELECT count(*) FROM pulses p WHERE p.run_id = r.id) FROM runs r ")
        text = str(ref).strip()
        if text.isdigit():
            row = self.conn.execute(base + "WHERE r.id = ?", (int(text),)).fetchone()
            if row is not None:
                return self._run_row(row)
            # a uid prefix may be all digits (uids are hex): fall through to it
        if len(text) < 6:
            return None
        rows = self.conn.execute(base + "WHERE r.uid LIKE ? LIMIT 2",
                                 (text.replace("%", "") + "%",)).fetchall()
        return self._run_row(rows[0]) if len(rows) == 1 else None

    def documents(self, run_id: int, after_id: int = 0) -> list[tuple[int, str, dict]]:
        """The run's documents after row ``after_id``: [(row id, name, doc)] in order."""
        return [(int(i), str(n), json.loads(d)) for i, n, d in self.conn.execute(
            "SELECT id, name, doc_json FROM documents WHERE run_id = ? AND id > ? ORDER BY id",
            (int(run_id), int(after_id)))]

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


def run_fields(kind: str, *, command: str, board_id: str | None = None,
               firmware_version: str | None = None, port: str | None = None,
               protocol: str | None = None, seed: int | None = None, config: Any = None,
               record_level: str = "pulses", metadata: RunMetadata | None = None,
               started_utc: str | None = None) -> dict[str, Any]:
    """A run's row as plain values (JSON-able: what a pending file keeps), this process's pid
    and host; ValueError for an unknown kind or level."""
    if kind not in KINDS:
        raise ValueError(f"unknown run kind {kind!r}")
    if record_level not in LEVELS:
        raise ValueError(f"unknown record level {record_level!r}")
    m = metadata or RunMetadata()
    return {"kind": kind, "command": command, "started_utc": started_utc or _now(),
            "board_id": board_id, "firmware_version": firmware_version, "port": port,
            "protocol": protocol, "seed": seed, "version": _version(),
            "record_level": record_level, "config": _clean_json(config), "uid": m.uid,
            "sample": m.sample, "operator": m.operator, "note": m.note, "tags": list(m.tags),
            "pid": os.getpid(), "host": _host()}


def _clean_json(obj: Any) -> Any:
    """``obj`` as the runs table stores it (JSON text read back: numpy and paths as text)."""
    text = _json(obj)
    return None if text is None else json.loads(text)


def _script(conn: sqlite3.Connection, sql: str) -> None:
    """Run the ``;``-separated statements of ``sql`` (inside the caller's transaction)."""
    for stmt in sql.strip().split(";"):
        if stmt.strip():
            conn.execute(stmt)


def _loads(text: str | None) -> Any:
    if text is None:
        return None
    try:
        return json.loads(text)
    except ValueError:
        return text


def _version() -> str:
    return f"snan-hil {__version__}"


class Recorder:
    """Records one run into a history database; never raises on a database problem while the
    run goes on, and never drops a record another program's lock keeps out.

    The run is a document stream (:class:`~snan_hil.records.documents.RunPublisher`,
    ``self.publisher``); the recorder is its subscriber and the cell observer of
    :mod:`snan_hil.calibration.observer` at once (``on_pulses``, ``on_cell``, ``on_cells``
    hand the events to the publisher, whose documents come back to :meth:`__call__`). Other
    subscribers (a live renderer, a JSON report) subscribe to ``self.publisher``; the start
    document is sent when the recorder is made.

    Each document is stored in ``documents``; pulses (level ``pulses``) and cell results
    (``cells``, ``pulses``) in their tables too. Writes are buffered: one transaction per cell
    result, and at least every :data:`FLUSH_INTERVAL_S` while events arrive, and at
    :meth:`finish`.

    **Contention** (several commands on one database is normal: the user's runs database is
    every software command's): a write another connection's lock keeps out past
    ``busy_timeout_s`` stays queued, in order, and is tried again at the next flush (at most
    every :data:`RETRY_INTERVAL_S`, each try waiting :data:`RETRY_BUSY_S`); :meth:`finish`
    waits up to :data:`FINISH_WAIT_S` for the lock, and what it still keeps out goes to a
    pending file beside the database (:mod:`snan_hil.records.pending`) that the next open of
    the database applies -- one warning line says so. A queue longer than
    :data:`MAX_QUEUED_DOCUMENTS` goes there too.

    **A run that cannot record**: any other error (a damaged file, a full disk, a database
    that cannot be made) is reported once through ``warn`` and recording stops; the job
    learns it from :meth:`check`, which raises :class:`~snan_hil.records.control.
    RecordingStopped` before its next board request (``calibration.control.ControlledClient``
    calls it; the run's clean-up runs as for a stop). The other subscribers go on.

    Events are duck-typed: ``row``, ``col``, ``polarity`` (enum or name), ``amplitude_v``,
    ``width_us``, ``g_before_s``, ``g_after_s``, ``stage``; and ``row``, ``col``, ``outcome``,
    ``g_s``, ``target_s``, ``pulses``, ``detail``.
    """

    def __init__(self, path: str | os.PathLike[str] | None, kind: str, *, command: str,
                 level: str = "pulses", warn: Callable[[str], object] | None = None,
                 metadata: RunMetadata | None = None,
                 subscribers: Sequence[Callable[[str, dict], None]] = (),
                 monotonic: Callable[[], float] | None = None,
                 busy_timeout_s: float | None = None,
                 **run_fields: Any) -> None:
        if level not in LEVELS:
            raise HistoryError(f"unknown record level {level!r}; one of {', '.join(LEVELS)}")
        if kind not in KINDS:
            raise ValueError(f"unknown run kind {kind!r}")
        self.path = None if path is None else Path(path)
        self.kind = kind
        self.level = level
        self.warn = warn or (lambda line: log.warning("%s", line))
        self.failed: str | None = None
        self.run_id: int | None = None
        self.db: History | None = None
        self.metadata = metadata or RunMetadata()
        self._monotonic = monotonic or _monotonic
        self._busy_s = BUSY_TIMEOUT_S if busy_timeout_s is None else float(busy_timeout_s)
        self._cells: list[tuple] = []
        self._pulses: list[tuple] = []
        self._docs: list[tuple[str, dict[str, Any]]] = []
        self._last_flush = self._monotonic()
        self.recorded = {"cells": 0, "pulses": 0}
        self.recorded_documents = 0
        self._command, self._run_fields = command, run_fields
        self._row = run_fields_of(kind, command, level, self.metadata, run_fields)
        self._streams: dict[str, str] = {}
        self._waiting_since: float | None = None  # a lock keeps the queue out since then
        self._next_try = 0.0
        self._pending: list[Path] = []            # this run's pending files (maybe applied)
        self._pending_seq = 0
        self._end: dict[str, Any] | None = None
        self.pending_file: Path | None = None
        """The last pending file this run left beside the database (None: all written)."""
        self.control: Any = None
        """The run's control channel (:class:`~snan_hil.records.control.RunControl`), if
        one polls this database; closed by :meth:`finish`."""
        start_fields: dict[str, Any] = {**run_fields, "record_level": level}
        self.publisher = RunPublisher(self.metadata, kind=kind, command=command,
                                      **start_fields)
        if self.path is not None:
            self._attempt(self._open)
        self.publisher.subscribe(self)
        for fn in subscribers:
            self.publisher.subscribe(fn)
        self.publisher.start()

    def _open(self) -> None:
        assert self.path is not None
        if self.db is None:
            problem = integrity_problem(self.path)      # never added to silently
            if problem is not None:
                raise HistoryError(f"damaged (SQLite: {problem}; 'snan-hil history recover' "
                                   "saves what it still holds)")
            self.db = History.open(self.path, timeout_s=self._busy_s if self._waiting_since
                                   is None else RETRY_BUSY_S)

    @property
    def uid(self) -> str:
        return self.metadata.uid

    @property
    def active(self) -> bool:
        """The run is in the database and recording goes on (nothing is queued)."""
        return (self.db is not None and self.run_id is not None and self.failed is None
                and self._waiting_since is None)

    @property
    def recording(self) -> bool:
        """Records go to a database (now, or once a lock is gone): a path and no failure."""
        return self.path is not None and self.failed is None

    @property
    def queued(self) -> int:
        """Documents waiting for the database (another connection's lock)."""
        return len(self._docs) if self._waiting_since is not None else 0

    def check(self) -> None:
        """Before the job's next board request: :class:`~snan_hil.records.control.
        RecordingStopped` once recording has failed (the class docstring)."""
        if self.failed is not None and self.path is not None:
            raise RecordingStopped(
                f"history database {self.path}: {self.failed}; the run cannot be recorded, "
                "so it was stopped before its next pulse (what it did is in its own outputs)")

    def controls(self, run_uid: str, after_id: int = 0) -> list[tuple[int, str]]:
        """The control requests of ``run_uid`` (:meth:`History.controls`) through this
        recorder's connection: [] while it has none or another connection's lock keeps the
        read out (:class:`~snan_hil.records.control.RunControl` polls it)."""
        if self.db is None:
            return []
        try:
            return self.db.controls(run_uid, after_id)
        except sqlite3.Error as exc:
            if _transient(exc):
                return []
            raise

    def _close_db(self) -> None:
        """Close the database if open (a failing close is ignored) and forget it."""
        if self.db is not None:
            try:
                self.db.close()
            except sqlite3.Error:
                pass
        self.db = None

    def _attempt(self, fn: Callable[[], Any]) -> bool:
        """Run ``fn`` (a step of writing); True when it went through. Another connection's
        lock: False, the records stay queued; any other error: recording fails (one line)."""
        if self.failed is not None:
            return False
        try:
            fn()
        except (sqlite3.Error, OSError, HistoryError) as exc:
            if isinstance(exc, sqlite3.Error) and _transient(exc):
                self._locked(exc)
                return False
            self._fail(exc)
            return False
        return True

    def _locked(self, exc: BaseException) -> None:
        now = self._monotonic()
        if self._waiting_since is None:
            self._waiting_since = now
            log.info("history database %s is locked by another connection (%s); this run's "
                     "records wait for it", self.path, exc)
        self._next_try = now + RETRY_INTERVAL_S
        if self.db is not None:                   # later tries must not hold up the job
            try:
                self.db.conn.execute(f"PRAGMA busy_timeout = {int(RETRY_BUSY_S * 1000)}")
            except sqlite3.Error:
                pass

    def _fail(self, exc: BaseException) -> None:
        self.failed = _describe_error(exc)
        lost = len(self._pulses)
        self.warn(f"history database {self.path}: {self.failed}; nothing more of this run is "
                  "recorded there" + (f" ({lost} pulses were not)" if lost else "") +
                  "; a board job stops before its next pulse")
        self._close_db()

    # ------------------------------------------------------------------ observer (adapter)
    def on_pulses(self, events: Sequence[Any]) -> None:
        """Pulses applied to one or more cells."""
        self.publisher.on_pulses(events)

    def on_cell(self, event: Any) -> None:
        """A cell's result (written with the buffered pulses in one transaction)."""
        self.publisher.on_cell(event)

    def on_cells(self, events: Sequence[Any]) -> None:
        """Results of many cells (a map, a retention run), written in one transaction."""
        for e in events:
            self.publisher.on_cell(e)
        self.flush()

    def progress(self, event: Any) -> None:
        """A progress callback: the job's progress into the stream."""
        self.publisher.progress(event)

    # ------------------------------------------------------------------ subscriber
    def __call__(self, name: str, doc: dict[str, Any]) -> None:
        if self.path is None or self.failed is not None:
            return                                # nothing is recorded
        if name == "start":
            self._docs.append((name, doc))
            self.flush()
            return
        if name == "descriptor":
            self._streams[doc["uid"]] = doc["name"]
            self._docs.append((name, doc))
            return
        if name == "stop":
            self._docs.append((name, doc))
            return                                # finish() writes it with the run's end
        stream = self._streams.get(doc.get("descriptor", ""), "")
        data = doc.get("data", {})
        t = _utc(doc.get("time"))
        if stream == "pulses":
            if self.level != "pulses":
                return
            self._pulses.append((data["row"], data["col"], data["n"], t, data["stage"],
                                 data["polarity"], data["amplitude_v"], data["width_us"],
                                 data["g_before_s"], data["g_after_s"]))
        elif stream == "cells":
            if self.level == "runs":
                return
            detail = _loads(data.get("detail"))
            self._cells.append((data["row"], data["col"], t, data["outcome"], data["g_s"],
                                data["target_s"], data["pulses"], detail))
        self._docs.append((name, doc))
        if stream == "cells" or self._monotonic() - self._last_flush >= FLUSH_INTERVAL_S:
            self.flush()

    def flush(self) -> None:
        """Write what is buffered (one transaction); while a lock keeps it out, try again at
        most every :data:`RETRY_INTERVAL_S` (the queue past :data:`MAX_QUEUED_DOCUMENTS`
        goes to a pending file)."""
        self._last_flush = now = self._monotonic()
        if self.path is None or self.failed is not None:
            self._cells, self._pulses, self._docs = [], [], []
            return
        if self._waiting_since is not None and now < self._next_try:
            if len(self._docs) > MAX_QUEUED_DOCUMENTS:
                self._spill()
            return
        if not self._write() and len(self._docs) > MAX_QUEUED_DOCUMENTS:
            self._spill()

    def _write(self) -> bool:
        """Open, apply this run's pending files, begin the run, write the queue: True when
        all of it is in the database."""
        if not self._attempt(self._open):
            return False
        assert self.db is not None
        db = self.db
        if self._pending and not self._attempt(self._apply_own):
            return False
        if self.run_id is None and not self._attempt(self._begin):
            return False
        n_p, n_c, n_d = len(self._pulses), len(self._cells), len(self._docs)
        if n_p or n_c or n_d:
            pulses, cells, docs = self._pulses[:n_p], self._cells[:n_c], self._docs[:n_d]

            def write() -> None:
                assert self.run_id is not None
                db.write_batch(self.run_id, pulses=pulses, cells=cells, documents=docs)
            if not self._attempt(write):
                return False
            del self._pulses[:n_p], self._cells[:n_c], self._docs[:n_d]
            self.recorded["pulses"] += n_p
            self.recorded["cells"] += n_c
            self.recorded_documents += n_d
        if self._end is not None:
            end = self._end

            def close_run() -> None:
                assert self.run_id is not None
                db.end_run(self.run_id, end["status"], end["summary"], end["finished_utc"])
            if not self._attempt(close_run):
                return False
            self._end = None
        if self._waiting_since is not None:
            self._waiting_since = None
            try:
                db.conn.execute(f"PRAGMA busy_timeout = {int(self._busy_s * 1000)}")
            except sqlite3.Error:
                pass
        return True

    def _begin(self) -> None:
        assert self.db is not None
        r = self._row
        self.run_id = self.db.begin_run(
            self.kind, command=self._command, record_level=self.level,
            board_id=r.get("board_id"), firmware_version=r.get("firmware_version"),
            port=r.get("port"), protocol=r.get("protocol"), seed=r.get("seed"),
            config=self._run_fields.get("config"), metadata=self.metadata,
            started_utc=r["started_utc"])

    def _apply_own(self) -> None:
        """This run's pending files first (their records come before the queue's); a lock
        keeps them for the next try."""
        assert self.db is not None
        self.db.apply_pending()
        left = [p for p in self._pending if p.exists()]
        if left:
            raise sqlite3.OperationalError("database is locked (pending records wait)")
        self._pending = []

    def _spill(self) -> None:
        """The queue (and the run's end, when it has ended) into a pending file beside the
        database (:mod:`snan_hil.records.pending`); a file that cannot be written fails the
        recording."""
        assert self.path is not None
        self._pending_seq += 1
        try:
            path = write_pending(self.path, self.uid, self._pending_seq, run=self._row,
                                 pulses=self._pulses, cells=self._cells, documents=self._docs,
                                 end=self._end)
        except (OSError, TypeError, ValueError) as exc:
            self._fail(OSError(f"its pending records cannot be kept either ({exc})"))
            return
        self.recorded["pulses"] += len(self._pulses)
        self.recorded["cells"] += len(self._cells)
        self.recorded_documents += len(self._docs)
        self._pulses, self._cells, self._docs = [], [], []
        self._end = None
        self._pending.append(path)
        self.pending_file = path

    def add_device_model(self, model: dict[str, Any], board_id: str | None = None) -> int | None:
        """Store a fitted device model with this run (:meth:`History.add_device_model`); its
        row id, None when the run is not recorded (no database, it failed, or a lock keeps
        it out: the model stays in the run's own report)."""
        self.flush()
        if not self.active:
            return None
        got: list[int] = []

        def write() -> None:
            assert self.db is not None
            got.append(self.db.add_device_model(self.run_id, model, board_id=board_id))
        self._attempt(write)
        return got[0] if got else None

    def finish(self, status: str, summary: Any = None, reason: str = "") -> None:
        """Send the stop document, write what is buffered, close the run with ``status``
        (complete, interrupted, failed) and ``summary``, close the file. A lock is waited
        for up to :data:`FINISH_WAIT_S`; what it still keeps out goes to a pending file (one
        warning line names it)."""
        if self.publisher.stopped:
            return
        self.publisher.stop(status, reason=reason, summary=summary)
        if self.path is not None and self.failed is None:
            self._end = {"status": status, "summary": _clean_json(summary),
                         "finished_utc": _now()}
            self.flush()                    # the usual write of what is buffered
            if self.path is not None and self.failed is None:
                self._finish_writes()       # what a lock still keeps out: wait, else pending
        self._close_db()
        if self.control is not None:
            self.control.close()

    def _finish_writes(self) -> None:
        if self.db is not None and self._waiting_since is not None:
            try:
                self.db.conn.execute(f"PRAGMA busy_timeout = {int(self._busy_s * 1000)}")
            except sqlite3.Error:
                pass
        deadline = self._monotonic() + FINISH_WAIT_S
        told = False
        while not self._write():
            if self.failed is not None:
                return
            if self._monotonic() >= deadline:
                self._spill()
                if self.failed is None:
                    self.warn(f"history database {self.path} stayed locked by another "
                              f"program; this run's records wait in {self.pending_file} and "
                              "go into the database the next time a command opens it")
                return
            if not told and FINISH_WAIT_S >= 1.0:
                told = True
                self.warn(f"history database {self.path} is locked by another program; "
                          f"waiting up to {FINISH_WAIT_S:g} s to record this run")
            if self.db is None:                   # locked while it was opened: pace the tries
                import time
                time.sleep(min(RETRY_BUSY_S, max(0.0, deadline - self._monotonic())))

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if self.publisher.stopped:
            self._close_db()
            return
        if exc_type is None:
            self.finish("complete")
        elif issubclass(exc_type, KeyboardInterrupt):
            self.finish("interrupted", reason=str(exc) or "interrupted")
        else:
            self.finish("failed", {"error": f"{exc_type.__name__}: {exc}"},
                        reason=f"{exc_type.__name__}: {exc}")


def run_fields_of(kind: str, command: str, level: str, metadata: RunMetadata,
                  fields: dict[str, Any]) -> dict[str, Any]:
    """The recorder's run row (:func:`run_fields`) from its keyword fields."""
    return run_fields(kind, command=command, record_level=level, metadata=metadata,
                      board_id=fields.get("board_id"),
                      firmware_version=fields.get("firmware_version"), port=fields.get("port"),
                      protocol=fields.get("protocol"), seed=fields.get("seed"),
                      config=fields.get("config"))


def _monotonic() -> float:
    return time.monotonic()


def _utc(t: Any) -> str:
    """UNIX seconds -> ISO UTC text (now when missing)."""
    if t is None:
        return _now()
    return _dt.datetime.fromtimestamp(float(t), _dt.timezone.utc).isoformat(
        timespec="milliseconds")


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


# -- pending files (records.pending) applied -------------------------------------------------

def _apply_pending(db: History) -> int:
    """Apply the pending files of ``db`` in order (:mod:`snan_hil.records.pending`); how many
    went in. A lock stops at the first file it keeps out (the rest wait for the next open:
    their order matters); a file that cannot be read is left where it is with one log
    warning, and so are all of them when the database is damaged (``snan-hil history
    recover`` copies them beside its new database)."""
    files = pending_files(db.path)
    done = 0
    if files:
        problem = integrity_problem(db.path)
        if problem is not None:                  # never added to a damaged database
            log.warning("history database %s is damaged (%s): its %d pending file(s) stay "
                        "in %s", db.path, problem, len(files), pending_dir(db.path))
            return 0
    for path in files:
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
            if not isinstance(data, dict) or data.get("format") != PENDING_FORMAT:
                raise ValueError(f"not a {PENDING_FORMAT} file")
            _apply(db, path.name, data)
        except sqlite3.Error as exc:
            log.info("history database %s: pending records in %s wait (%s)", db.path, path,
                     exc)
            break
        except FileNotFoundError:
            continue                              # applied and removed by another process
        except (OSError, ValueError, KeyError, TypeError) as exc:
            log.warning("history database %s: pending file %s cannot be applied (%s); it is "
                        "kept", db.path, path, exc)
            continue
        path.unlink(missing_ok=True)
        done += 1
    if files:
        try:
            pending_dir(db.path).rmdir()          # only when empty
        except OSError:
            pass
    return done


def _apply(db: History, name: str, data: dict[str, Any]) -> None:
    """One pending file in one transaction with its marker (nothing when it went in
    already)."""
    with db.transaction() as c:
        if c.execute("SELECT 1 FROM meta WHERE key = ?", (MARK + name,)).fetchone():
            return
        row = c.execute("SELECT id FROM runs WHERE uid = ?", (data["uid"],)).fetchone()
        run_id = int(row[0]) if row is not None else History.insert_run(c, data["run"])
        History._insert_pulses(c, run_id, [tuple(r) for r in data["pulses"]])
        History._insert_cells(c, run_id, [tuple(r) for r in data["cells"]])
        History._insert_documents(c, run_id, [(str(n), d) for n, d in data["documents"]])
        end = data.get("end")
        if end:
            c.execute("UPDATE runs SET status = ?, finished_utc = ?, summary_json = ? "
                      "WHERE id = ?", (end["status"], end["finished_utc"],
                                       _json(end.get("summary")), run_id))
        c.execute("INSERT INTO meta(key, value) VALUES (?, ?)",
                  (MARK + name, str(data.get("seq"))))
