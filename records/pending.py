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

import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from snan_hil.files.atomicio import atomic_write_json

__all__ = ["FORMAT", "MARK", "pending_dir", "pending_files", "write_pending"]

log = logging.getLogger(__name__)

FORMAT = "snan-hil-history-pending/1"
MARK = "applied:"
"""The ``meta`` key prefix that marks a pending file as applied (never applied twice)."""


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
