"""Records a run could not write into its history database in time, kept beside it until they
are (the journal-and-reconcile half of the history's contention policy, docs/bench.md).

A :class:`~snan_hil.records.history.Recorder` queues what another connection's lock keeps out
of the database and writes it when the lock is gone. When the lock outlasts the run's end (or
the queue grows past :data:`~snan_hil.records.history.MAX_QUEUED_DOCUMENTS`), the queue goes
to a **pending file**, ``<database>.pending/<run uid>-<n>.json`` (written atomically: a file
there is whole), and every later open of the database (:meth:`History.open
<snan_hil.records.history.History.open>`: any command, ``history``, ``watch``) applies the
files in order -- each in one transaction together with a marker row in ``meta``
(``applied:<file name>``), so a file two processes apply at once goes in once -- and then
deletes them. A pending file holds the run's own fields (its row is made if the database does
not have it yet), its pulses, cell results and documents, and its end (status, summary) when
the run had ended.

A base module: it imports no layer.
"""

from __future__ import annotations

import json
import logging
import sqlite3
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from snan_hil.files.atomicio import atomic_write_json

if TYPE_CHECKING:
    from snan_hil.records.history import History

__all__ = ["FORMAT", "pending_dir", "pending_files", "write_pending", "apply_pending"]

log = logging.getLogger(__name__)

FORMAT = "snan-hil-history-pending/1"
_MARK = "applied:"


def pending_dir(db_path: str | Path) -> Path:
    """The folder of the database's pending files: ``<database>.pending``."""
    return Path(str(db_path) + ".pending")


def pending_files(db_path: str | Path) -> list[Path]:
    """The pending files of the database at ``db_path``, in the order they are applied."""
    folder = pending_dir(db_path)
    return sorted(folder.glob("*.json")) if folder.is_dir() else []


def write_pending(db_path: str | Path, uid: str, seq: int, *, run: dict[str, Any],
                  pulses: Sequence[tuple[Any, ...]], cells: Sequence[tuple[Any, ...]],
                  documents: Sequence[tuple[str, dict[str, Any]]],
                  end: dict[str, Any] | None) -> Path:
    """Write one pending file of run ``uid`` (its ``seq``-th); its path. ``run``: the run's
    fields as :meth:`History.begin_run` takes them (``kind``, ``command``, ``started_utc``,
    ...); rows as :meth:`History.write_batch` takes them; ``end``: ``{status, summary,
    finished_utc}`` or None. Raises OSError (a full disk, a read-only folder)."""
    folder = pending_dir(db_path)
    folder.mkdir(exist_ok=True)
    path = folder / f"{uid}-{seq:06d}.json"
    atomic_write_json(path, {"format": FORMAT, "uid": uid, "seq": seq, "run": run,
                             "pulses": [list(r) for r in pulses],
                             "cells": [list(r) for r in cells],
                             "documents": [[name, doc] for name, doc in documents],
                             "end": end})
    return path


def apply_pending(db: History) -> int:
    """Apply the pending files of ``db`` in order (module docstring); how many went in. A
    lock stops at the first file it keeps out (the rest wait for the next open: their order
    matters); a file that cannot be read is left where it is with one log warning, and so
    are all of them when the database is damaged (``snan-hil history recover`` copies them
    beside its new database)."""
    files = pending_files(db.path)
    done = 0
    if files:
        from snan_hil.records.history import integrity_problem
        problem = integrity_problem(db.path)
        if problem is not None:                  # never added to a damaged database
            log.warning("history database %s is damaged (%s): its %d pending file(s) stay "
                        "in %s", db.path, problem, len(files), pending_dir(db.path))
            return 0
    for path in files:
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
            if not isinstance(data, dict) or data.get("format") != FORMAT:
                raise ValueError(f"not a {FORMAT} file")
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
    from snan_hil.records.history import History, _json
    with db.transaction() as c:
        if c.execute("SELECT 1 FROM meta WHERE key = ?", (_MARK + name,)).fetchone():
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
                  (_MARK + name, str(data.get("seq"))))
