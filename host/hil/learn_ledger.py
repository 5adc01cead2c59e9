"""The chip arm's pulse ledger (``snan-hil learn``, docs/learning.md section 6): per (session,
cycle, stage) the SET and RESET pulses and the array energy, per cell the pulses (wear) and per
(session, cycle, stage) and cell the SET and RESET pulses (the dataset's pulse ledger,
:mod:`snan_hil.host.hil.learn_dataset`), and the pulses whose fate is unknown (``uncertain``:
sent when a run was killed, never sent again).

Each unit of the chip arm keeps the rows of its own pulses (:class:`UnitLedger`, in the unit's
record); the run's ledger is put together from the records alone (:meth:`Ledger.of`), so it is
the same whether the units ran on one board, on several, or over several resumed runs.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

from snan_hil.common.polarity import Polarity

__all__ = ["Ledger", "UnitLedger", "PulseLike", "Counted", "estimate_energy"]


class PulseLike(Protocol):
    """What the ledger reads of a pulse (a :class:`~snan_hil.calibration.observer.PulseEvent`
    or a :class:`Counted` one)."""

    @property
    def row(self) -> int: ...

    @property
    def col(self) -> int: ...

    @property
    def polarity(self) -> Polarity: ...


@dataclass(frozen=True)
class Counted:
    """A pulse an earlier attempt applied (its journal says so): counted, never sent again;
    its amplitude and conductances are not known here (0, None)."""

    row: int
    col: int
    polarity: Polarity
    amplitude_v: float = 0.0
    width_us: int = 0
    g_before_s: float | None = None
    g_after_s: float | None = None
    stage: str | None = None


def estimate_energy(events: Iterable[Any], r_switch_ohm: float) -> float:
    """Host estimate of the pulses' array energy (J): V^2 / (1/G + R_sw) x width, G the
    conductance read before the pulse (after it where none was read); 0 for a pulse whose
    conductance is not known (:class:`Counted`)."""
    total = 0.0
    for e in events:
        g = e.g_before_s if e.g_before_s else e.g_after_s
        if g and g > 0:
            total += e.amplitude_v ** 2 / (1.0 / g + r_switch_ohm) * e.width_us * 1e-6
    return total


@dataclass
class UnitLedger:
    """The ledger rows of one unit of the chip arm on board ``board`` (None: one board):
    its rows, its cells' pulse counts (keys ``row,col``, ``board-<i>:row,col`` on several
    boards), per row and cell ``[session, cycle, stage, row, col, SET, RESET, board]``
    (``cell_rows``) and its uncertain pulses."""

    board: int | None = None
    rows: list[dict[str, Any]] = field(default_factory=list)
    cells: dict[str, int] = field(default_factory=dict)
    uncertain: int = 0
    cell_rows: list[list[Any]] = field(default_factory=list)

    def add(self, session: int, cycle: int, stage: str, pulses: Sequence[PulseLike],
            energy_j: float | None, estimate_j: float, *, uncertain: int | None = None,
            board: int | None = None) -> dict[str, Any]:
        """One row of ``pulses`` (``board``: the board whose chip they went to, default this
        unit's; a row of a lost board's pulses names that board); ``uncertain``: the row's
        pulses of unknown fate (the row gets the key; not in the counts)."""
        board = self.board if board is None else board
        row: dict[str, Any] = {
            "session": session, "cycle": cycle, "stage": stage,
            "set": sum(1 for p in pulses if p.polarity == Polarity.SET),
            "reset": sum(1 for p in pulses if p.polarity == Polarity.RESET),
            "energy_j": energy_j, "energy_estimate_j": estimate_j}
        if uncertain is not None:
            row["uncertain"] = int(uncertain)
            self.uncertain += int(uncertain)
        if board is not None:
            row["board"] = int(board)
        self.rows.append(row)
        prefix = "" if board is None else f"board-{int(board)}:"
        counts: dict[tuple[int, int], list[int]] = {}
        for p in pulses:
            key = f"{prefix}{p.row},{p.col}"
            self.cells[key] = self.cells.get(key, 0) + 1
            n = counts.setdefault((int(p.row), int(p.col)), [0, 0])
            n[0 if p.polarity == Polarity.SET else 1] += 1
        for (r, c), (n_set, n_reset) in counts.items():
            self.cell_rows.append([session, cycle, stage, r, c, n_set, n_reset,
                                   None if board is None else int(board)])
        return row

    def to_record(self) -> dict[str, Any]:
        return {"rows": self.rows, "cells": self.cells, "uncertain": self.uncertain,
                "cell_rows": self.cell_rows}

    @classmethod
    def from_record(cls, record: Mapping[str, Any], board: int | None = None) -> UnitLedger:
        return cls(board, [dict(r) for r in record.get("rows", [])],
                   dict(record.get("cells", {})), int(record.get("uncertain", 0)),
                   [list(c) for c in record.get("cell_rows", [])])


@dataclass
class Ledger:
    """The chip arm's ledger of a run (module doc): ``rows``, ``per_cell``, ``cells`` (per
    row and cell: ``[session, cycle, stage, row, col, SET, RESET, board]``), ``uncertain``
    (pulses sent when a run was stopped whose fate is unknown: never resent, not in
    :attr:`total`)."""

    rows: list[dict[str, Any]] = field(default_factory=list)
    per_cell: dict[str, int] = field(default_factory=dict)
    uncertain: int = 0
    cells: list[list[Any]] = field(default_factory=list)

    @classmethod
    def of(cls, records: Iterable[Mapping[str, Any]]) -> Ledger:
        """The ledger of the chip units' ``records`` (in unit order)."""
        out = cls()
        for rec in records:
            out.rows += [dict(r) for r in rec.get("rows", [])]
            for key, n in rec.get("cells", {}).items():
                out.per_cell[key] = out.per_cell.get(key, 0) + int(n)
            out.uncertain += int(rec.get("uncertain", 0))
            out.cells += [list(c) for c in rec.get("cell_rows", [])]
        return out

    @property
    def total(self) -> int:
        return sum(r["set"] + r["reset"] for r in self.rows)

    def to_dict(self) -> dict[str, Any]:
        return {"rows": self.rows, "per_cell": self.per_cell, "total": self.total,
                "uncertain": self.uncertain, "cells": self.cells}
