"""The learnt weights and the pulse ledger of a ``snan-hil learn`` run as a plain dataset a
reviewer can reload (issue 36 point 4): two CSV files beside ``learn.json``.

* ``cell_ledger.csv`` — the chip arm's pulses per cell and cycle: ``session, cycle, stage,
  row, col, pre, direction, set, reset, board`` (``stage``: ``program`` for the session's
  write-and-verify, ``learn`` / ``learn+refresh`` for the learning pulses; ``pre, direction``:
  the synapse the cell holds, empty for a spare or a cell the layout does not name);
* ``weights.csv`` — per arm, session, cycle and synapse: ``arm, session, cycle, pre,
  direction, row, col, w_intended, w_estimate, w_final`` (weight units 0..1; ``w_intended``:
  what the software rule holds after the cycle, ``w_estimate``: the planner's estimate of the
  device after the cycle's pulses, ``w_final``: the weight read from the chip — the chip
  arm — or the simulated device's — the device arm — after the last cycle, on the last
  cycle's rows only; ``row, col``: the chip arm's cell, empty otherwise).

:func:`load_dataset` reads them back as lists of typed rows; their totals agree with
``learn.json``'s ledger (tests/hil/test_learn_dataset.py).
"""

from __future__ import annotations

import csv
import io
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from snan_hil.files.atomicio import atomic_write_text

__all__ = ["CELL_LEDGER", "WEIGHTS", "CELL_LEDGER_HEADER", "WEIGHTS_HEADER", "write_dataset",
           "load_dataset", "LearnDataset"]

CELL_LEDGER = "cell_ledger.csv"
WEIGHTS = "weights.csv"
CELL_LEDGER_HEADER = "session,cycle,stage,row,col,pre,direction,set,reset,board"
WEIGHTS_HEADER = ("arm,session,cycle,pre,direction,row,col,w_intended,w_estimate,w_final")


def _cell_owner(cells: Mapping[Any, Sequence[int]] | None) -> dict[tuple[int, int], Any]:
    return {(int(rc[0]), int(rc[1])): key for key, rc in (cells or {}).items()}


def write_dataset(doc: Mapping[str, Any], out: Path,
                  cells: Mapping[Any, Sequence[int]] | None = None) -> dict[str, str]:
    """Write the two files of the module doc from a learn document ``doc``
    (:func:`~snan_hil.host.hil.learn.run_learning`'s) into ``out``; ``cells``: synapse key
    ``(pre, direction)`` -> chip cell ``(row, col)`` of the chip arm. Returns {name: path}."""
    owner = _cell_owner(cells)
    keys = [tuple(int(v) for v in k) for k in doc.get("synapses", [])]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CELL_LEDGER_HEADER.split(","))
    for session, cycle, stage, row, col, n_set, n_reset, board in \
            (doc.get("ledger") or {}).get("cells", []):
        key = owner.get((int(row), int(col)))
        w.writerow([session, cycle, stage, row, col, "" if key is None else key[0],
                    "" if key is None else key[1], n_set, n_reset,
                    "" if board is None else board])
    atomic_write_text(out / CELL_LEDGER, buf.getvalue())
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(WEIGHTS_HEADER.split(","))
    where = {key: rc for key, rc in ((tuple(int(v) for v in k), rc)
                                     for k, rc in (cells or {}).items())}
    for arm, a in doc.get("arms", {}).items():
        for k, s in enumerate(a.get("sessions", [])):
            ints, ests = s.get("w_intended") or [], s.get("w_estimate") or []
            final = s.get("weights")
            for c, (wi, we) in enumerate(zip(ints, ests), start=1):
                last = c == len(ints)
                for j, key in enumerate(keys):
                    rc = where.get(key) if arm == "chip" else None
                    w.writerow([arm, k, c, key[0], key[1], "" if rc is None else rc[0],
                                "" if rc is None else rc[1], f"{wi[j]:.6g}", f"{we[j]:.6g}",
                                f"{final[j]:.6g}" if last and final is not None else ""])
    atomic_write_text(out / WEIGHTS, buf.getvalue())
    return {CELL_LEDGER: str(out / CELL_LEDGER), WEIGHTS: str(out / WEIGHTS)}


@dataclass
class LearnDataset:
    """What :func:`load_dataset` gives: the rows of both files, typed (ints, floats, None for
    an empty field)."""

    cell_ledger: list[dict[str, Any]]
    weights: list[dict[str, Any]]

    def pulses(self, stage_prefix: str = "learn") -> int:
        """Pulses of the stages starting with ``stage_prefix`` (all: "")."""
        return sum(r["set"] + r["reset"] for r in self.cell_ledger
                   if str(r["stage"]).startswith(stage_prefix))

    def per_cell(self, session: int, stage_prefix: str = "learn") -> dict[tuple[int, int], int]:
        """Pulses of one session per cell (row, col)."""
        out: dict[tuple[int, int], int] = {}
        for r in self.cell_ledger:
            if r["session"] == session and str(r["stage"]).startswith(stage_prefix):
                key = (r["row"], r["col"])
                out[key] = out.get(key, 0) + r["set"] + r["reset"]
        return out


def _typed(row: dict[str, str], ints: Sequence[str], floats: Sequence[str]
           ) -> dict[str, Any]:
    out: dict[str, Any] = dict(row)
    for k in ints:
        out[k] = int(row[k]) if row[k] != "" else None
    for k in floats:
        out[k] = float(row[k]) if row[k] != "" else None
    return out


def load_dataset(folder: str | Path) -> LearnDataset:
    """Read ``cell_ledger.csv`` and ``weights.csv`` of a learn run's folder. ValueError when a
    file's header is not the dataset's."""
    folder = Path(folder)
    tables = []
    for name, header, ints, floats in (
            (CELL_LEDGER, CELL_LEDGER_HEADER,
             ("session", "cycle", "row", "col", "pre", "direction", "set", "reset", "board"),
             ()),
            (WEIGHTS, WEIGHTS_HEADER, ("session", "cycle", "pre", "direction", "row", "col"),
             ("w_intended", "w_estimate", "w_final"))):
        with open(folder / name, newline="", encoding="utf-8") as fh:
            reader = csv.DictReader(fh)
            if ",".join(reader.fieldnames or []) != header:
                raise ValueError(f"{folder / name}: not a learn dataset file (header "
                                 f"{reader.fieldnames})")
            tables.append([_typed(r, ints, floats) for r in reader])
    return LearnDataset(*tables)
