"""Where each synapse lives in the crossbar, which cells are bad, and the calibration: the layout.

Placement (the paper's): the N synapses of a grid SNAN, in the order of
:func:`~snan_hil.calibration.weights_io.grid_synapses` (pre ascending, then post), fill a block
of ``ceil(N / cols)`` rows row-major — for a 6x6 grid 120 synapses into rows 0-14 x columns 0-7.
The rows below the block are spares. A synapse whose nominal cell is bad (known from an earlier
run or found by the screen / a failed programming) is moved to the next free healthy spare cell
(row-major from the first spare row); all other synapses keep their nominal cell, so the layout
stays stable from run to run.

The layout is saved as JSON (format in docs/calibration.md) with the read-chain calibration and
the weight map, so ``read-weights`` and ``run`` can turn ADC codes back into weights.

A chip of a group (a network larger than one chip, :mod:`snan_hil.calibration.chip_group`)
holds a share of the network: the synapses of some input neurons (``pres``), placed the same
way; a layout without ``pres`` holds them all.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from snan_hil.files.outputs import Outputs, json_kind
from snan_hil.board.identity import BoardIdentity
from snan_hil.board.session import BoardSession
from snan_hil.files.atomicio import atomic_write_json
from snan_hil.calibration.mapping import WeightMap
from snan_hil.calibration.readchain import ReadChain
from snan_hil.calibration.weights_io import grid_synapses
from snan_hil.common.errors import UserError

__all__ = ["LAYOUT_FORMAT", "LayoutError", "Synapse", "Layout", "check_layout_owner",
           "check_layout_writable", "load_session_layout", "share_synapses"]

LAYOUT_FORMAT = "snan-hil-layout/1"


CELL_TEST_MARK = "cell test"
USER_LIST_MARK = "user cell list"
"""Reason prefix of bad-cell marks from program-weights --cells-only / --cells-avoid: they hold
for that run only (the next programming run drops them before it applies its own lists)."""
"""How a bad-cell reason set from a cell test begins (``snan-hil cells test`` marks, and the
history's classes ``program-weights`` applies); a later good test of the cell removes it."""


class LayoutError(UserError):
    """A layout file is missing, unreadable or does not fit the board / weights."""


def _num(x: float | None) -> float | None:
    """JSON-safe float (None for NaN/inf)."""
    if x is None or not math.isfinite(x):
        return None
    return float(x)


@dataclass
class Synapse:
    """One synapse ``pre -> post`` in cell (row, col), with its last programming result."""

    pre: int
    post: int
    row: int
    col: int
    weight: float | None = None       # last programmed weight
    target_s: float | None = None     # its target conductance (S)
    final_s: float | None = None      # conductance read after programming (S)
    ok: bool | None = None            # within the window after programming
    moved_from: list[list[int]] = field(default_factory=list)   # earlier cells [row, col]
    stale: str | None = None
    """Why the cell no longer holds the programmed weight (a ``pulse`` ticket changed it after
    programming), None while it does; cleared when the synapse is programmed again."""

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "pre": self.pre, "post": self.post, "row": self.row, "col": self.col,
            "weight": _num(self.weight), "target_s": _num(self.target_s),
            "final_s": _num(self.final_s), "ok": self.ok,
            "moved_from": [list(m) for m in self.moved_from]}
        if self.stale:
            d["stale"] = self.stale
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "Synapse":
        return cls(int(d["pre"]), int(d["post"]), int(d["row"]), int(d["col"]),
                   d.get("weight"), d.get("target_s"), d.get("final_s"), d.get("ok"),
                   [list(map(int, m)) for m in d.get("moved_from", [])],
                   str(d["stale"]) if d.get("stale") else None)


@dataclass
class Layout:
    """Synapse placement, bad cells, read-chain calibration and weight map of one board."""

    grid: tuple[int, int]
    array: tuple[int, int]                       # crossbar rows, cols
    block_rows: int                              # rows 0..block_rows-1 hold the block
    synapses: list[Synapse]
    bad_cells: dict[tuple[int, int], str] = field(default_factory=dict)   # cell -> reason
    weight_map: WeightMap = field(default_factory=WeightMap)
    read_chain: ReadChain | None = None
    board: dict[str, Any] = field(default_factory=dict)    # board_id, firmware_version, port
    updated: str = ""
    pres: tuple[int, ...] | None = None
    """The input neurons whose synapses this chip holds (a chip of a group,
    :mod:`snan_hil.calibration.chip_group`); None: every input neuron of the grid."""

    # ------------------------------------------------------------------ construction
    @classmethod
    def place(cls, grid: tuple[int, int], array: tuple[int, int],
              bad_cells: dict[tuple[int, int], str] | None = None,
              weight_map: WeightMap | None = None,
              pres: "tuple[int, ...] | None" = None) -> "Layout":
        """Nominal placement of a grid's synapses (block row-major), bad cells moved to spares;
        ``pres``: only the synapses of these input neurons (a chip of a group), None: all.
        LayoutError when they do not fit the array."""
        rows, cols = int(grid[0]), int(grid[1])
        arows, acols = int(array[0]), int(array[1])
        share = None if pres is None else tuple(sorted(int(p) for p in pres))
        pairs = share_synapses(rows, cols, share)
        block = math.ceil(len(pairs) / acols)
        if block > arows:
            what = (f"{len(pairs)} synapses of a {rows}x{cols} grid" if share is None else
                    f"the {len(pairs)} synapses of {len(share)} input neurons")
            raise LayoutError(f"{what} need {block} rows of {acols} cells; the crossbar has "
                              f"{arows} rows (a larger network: a group of chips, --group)")
        syn = [Synapse(pre, post, k // acols, k % acols) for k, (pre, post) in enumerate(pairs)]
        layout = cls((rows, cols), (arows, acols), block, syn, dict(bad_cells or {}),
                     weight_map or WeightMap(), pres=share)
        layout.relocate_bad()
        return layout

    # ------------------------------------------------------------------ queries
    @property
    def n_synapses(self) -> int:
        return len(self.synapses)

    @property
    def n_neurons(self) -> int:
        return self.grid[0] * self.grid[1]

    def pairs(self) -> list[tuple[int, int]]:
        """The (pre, post) synapses this layout must hold, sorted: the grid's, or those of
        :attr:`pres`."""
        return share_synapses(self.grid[0], self.grid[1], self.pres)

    def used_cells(self) -> set[tuple[int, int]]:
        return {(s.row, s.col) for s in self.synapses}

    def cell_of(self, pre: int, post: int) -> tuple[int, int]:
        """(row, col) of synapse pre -> post (KeyError if there is none)."""
        for s in self.synapses:
            if s.pre == pre and s.post == post:
                return s.row, s.col
        raise KeyError(f"no synapse {pre} -> {post} in the layout")

    def spare_cells(self) -> list[tuple[int, int]]:
        """Free healthy cells below the block, row-major."""
        used = self.used_cells()
        return [(r, c) for r in range(self.block_rows, self.array[0])
                for c in range(self.array[1])
                if (r, c) not in used and (r, c) not in self.bad_cells]

    def groups(self) -> list[dict[str, Any]]:
        """Per input neuron, its rows and the cells in each: ``[{pre, rows: [{row, cells:
        [{col, post}]}]}]`` — a spike of ``pre`` drives each listed row (one at a time, so a
        column read sums nothing else) and reads the listed columns."""
        out: dict[int, dict[int, list[dict[str, int]]]] = {}
        for s in self.synapses:
            out.setdefault(s.pre, {}).setdefault(s.row, []).append({"col": s.col, "post": s.post})
        return [{"pre": pre, "rows": [{"row": r, "cells": sorted(cells, key=lambda c: c["col"])}
                                      for r, cells in sorted(rows.items())]}
                for pre, rows in sorted(out.items())]

    # ------------------------------------------------------------------ ADC codes -> weights
    @property
    def chain(self) -> ReadChain:
        """The stored read-chain calibration (LayoutError if the layout has none)."""
        if self.read_chain is None:
            raise LayoutError("layout holds no read-chain calibration; run program-weights")
        return self.read_chain

    def weight_from_column_code(self, adc: ArrayLike, row_code: int | None = None) -> Any:
        """Weight of a synapse from the column-read ADC code of a spike that drove only its
        row at row-DAC ``row_code`` (default: the nominal read code). Not clipped to [0, 1]."""
        g = self.chain.column_cell_conductance(_codes(adc), row_code)
        return self.weight_map.weight(g, clip=False)

    def weight_from_cell_code(self, adc: ArrayLike, read_code: int | None = None) -> Any:
        """Weight of a synapse from a READ_CELL ADC code (not clipped)."""
        g = self.chain.cell_conductance(_codes(adc), read_code)
        return self.weight_map.weight(g, clip=False)

    def column_code_of_weight(self, weight: ArrayLike, row_code: int | None = None) -> Any:
        """Expected column-read ADC code of a synapse of ``weight`` (one driven row)."""
        return self.chain.column_code(self.weight_map.conductance(weight), row_code)

    # ------------------------------------------------------------------ changes
    def synapse_at(self, row: int, col: int) -> Synapse | None:
        """The synapse programmed in cell (row, col), or None."""
        return next((s for s in self.synapses if (s.row, s.col) == (row, col)), None)

    def stale_synapses(self) -> list[Synapse]:
        """Synapses whose cell was changed after programming (:attr:`Synapse.stale`)."""
        return [s for s in self.synapses if s.stale]

    def mark_bad(self, row: int, col: int, reason: str) -> None:
        self.bad_cells[(int(row), int(col))] = reason

    def relocate(self, index: int) -> tuple[int, int]:
        """Move synapse ``index`` to the next free healthy spare; LayoutError if none left."""
        spares = self.spare_cells()
        if not spares:
            raise LayoutError(
                f"no free spare cell left for synapse {self.synapses[index].pre} -> "
                f"{self.synapses[index].post}: the layout marks {len(self.bad_cells)} cells bad; "
                "if earlier runs marked them (e.g. with unreachable targets), forget them with "
                "'snan-hil program-weights WEIGHTS --fresh-layout' (the screen finds the "
                "really stuck cells again), or on the emulator start a fresh chip with "
                "'snan-hil emu --reset-chip'")
        s = self.synapses[index]
        s.moved_from.append([s.row, s.col])
        s.row, s.col = spares[0]
        s.final_s = s.ok = None
        s.stale = None
        return s.row, s.col

    def relocate_bad(self) -> list[int]:
        """Move every synapse sitting on a bad cell to a spare; returns their indices."""
        moved = []
        for i, s in enumerate(self.synapses):
            if (s.row, s.col) in self.bad_cells:
                self.relocate(i)
                moved.append(i)
        return moved

    # ------------------------------------------------------------------ persistence
    def to_dict(self) -> dict[str, Any]:
        return {
            "format": LAYOUT_FORMAT,
            "updated": self.updated,
            "board": dict(self.board),
            "grid": list(self.grid),
            "array": list(self.array),
            "block": {"first_row": 0, "rows": self.block_rows, "cols": self.array[1]},
            "spare_rows": [self.block_rows, self.array[0] - 1],
            "weight_map": self.weight_map.to_dict(),
            "read_chain": self.read_chain.to_dict() if self.read_chain else None,
            "bad_cells": [{"row": r, "col": c, "reason": why}
                          for (r, c), why in sorted(self.bad_cells.items())],
            "synapses": [s.to_dict() for s in self.synapses],
            "groups": self.groups(),
            **({} if self.pres is None else {"pres": list(self.pres)}),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str = "layout") -> "Layout":
        if d.get("format") != LAYOUT_FORMAT:
            raise LayoutError(f"{source}: not a snan-hil layout (format {d.get('format')!r}, "
                              f"expected {LAYOUT_FORMAT!r})")
        try:
            layout = cls(
                grid=(int(d["grid"][0]), int(d["grid"][1])),
                array=(int(d["array"][0]), int(d["array"][1])),
                block_rows=int(d["block"]["rows"]),
                synapses=[Synapse.from_dict(s) for s in d["synapses"]],
                bad_cells={(int(b["row"]), int(b["col"])): str(b.get("reason", ""))
                           for b in d.get("bad_cells", [])},
                weight_map=WeightMap.from_dict(d["weight_map"]),
                read_chain=ReadChain.from_dict(d["read_chain"]) if d.get("read_chain") else None,
                board=dict(d.get("board") or {}),
                updated=str(d.get("updated", "")),
                pres=None if d.get("pres") is None else tuple(int(p) for p in d["pres"]),
            )
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise LayoutError(f"{source}: malformed layout ({type(exc).__name__}: {exc})") \
                from None
        layout.check()
        return layout

    def check(self) -> None:
        """Consistency: cells inside the array, no cell used twice, the grid's synapses."""
        cells = [(s.row, s.col) for s in self.synapses]
        if len(set(cells)) != len(cells):
            raise LayoutError("layout uses a cell for two synapses")
        for r, c in cells:
            if not (0 <= r < self.array[0] and 0 <= c < self.array[1]):
                raise LayoutError(f"layout cell ({r},{c}) outside the {self.array[0]}x"
                                  f"{self.array[1]} crossbar")
        pairs = sorted((s.pre, s.post) for s in self.synapses)
        if pairs != self.pairs():
            what = "" if self.pres is None else f" (its {len(self.pres)} input neurons)"
            raise LayoutError(f"layout synapses are not those of a {self.grid[0]}x"
                              f"{self.grid[1]} grid{what}")

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write atomically (temporary file + rename)."""
        return self.write_snapshot(path, self.snapshot())

    @staticmethod
    def write_snapshot(path: str | os.PathLike[str], snapshot: dict[str, Any]) -> Path:
        """Write a :meth:`snapshot` atomically (temporary file + rename)."""
        return atomic_write_json(path, snapshot, indent=1, allow_nan=False)

    def snapshot(self) -> dict[str, Any]:
        """The layout as it stands now, stamped ``updated`` (what :meth:`save` writes; nothing
        in it changes when the layout changes later)."""
        self.updated = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
        return self.to_dict()

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> "Layout":
        path = Path(path)
        if not path.is_file():
            if path.exists():
                what = "a folder" if path.is_dir() else "not a regular file"
                raise LayoutError(f"layout {path} is {what}; give a layout file (.layout.json) "
                                  "with --layout")
            raise LayoutError(f"layout file {path} does not exist; run 'snan-hil "
                              "program-weights' first or pass --layout")
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise LayoutError(f"cannot read layout {path}: {exc}") from None
        if not isinstance(data, dict):
            raise LayoutError(f"layout {path} is not a layout (a JSON {type(data).__name__}, "
                              "not an object); give the layout file program-weights wrote")
        return cls.from_dict(data, str(path))


def share_synapses(rows: int, cols: int,
                   pres: "tuple[int, ...] | None" = None) -> list[tuple[int, int]]:
    """The (pre, post) synapses of a rows x cols grid (:func:`grid_synapses` order), only
    those of input neurons ``pres`` when given."""
    pairs = grid_synapses(rows, cols)
    if pres is None:
        return pairs
    keep = set(pres)
    return [p for p in pairs if p[0] in keep]


def check_layout_writable(path: str | os.PathLike[str] | None) -> None:
    """UserError (one line) unless the layout file at ``path`` can be rewritten (a job that
    marks a synapse of it stale checks it before its first pulse)."""
    if path is None:
        return
    Outputs().file("--layout", path, json_kind(LAYOUT_FORMAT, "a snan-hil layout"),
                   updates=True)


def check_layout_owner(layout: Layout, identity: BoardIdentity, path: str | os.PathLike[str],
                       port: str) -> None:
    """LayoutError (one line) unless ``layout`` was made on the board (and chip) ``identity``
    (:meth:`~snan_hil.board.identity.BoardIdentity.owns`; layouts or boards without an
    identity, old legacy firmware, are not checked)."""
    recorded = BoardIdentity.from_record(layout.board)
    if identity.owns(recorded):
        return
    raise LayoutError(f"layout {path} was made on board {recorded.board_id}, but {port} is "
                      f"board {identity.board_id}{identity.other_chip_note(recorded)}; "
                      f"program this board first (snan-hil program-weights ... --port {port}) "
                      "or pass its own --layout")


def load_session_layout(session: BoardSession,
                        path: str | os.PathLike[str] | None = None) -> Layout:
    """The layout of the board of ``session`` (``path``, default the session's layout file),
    checked to belong to that board (:func:`check_layout_owner`); LayoutError (one line)
    otherwise or when there is none."""
    where = Path(path) if path is not None else session.files.layout
    if where is None:
        raise LayoutError(f"the board on {session.port} has no layout file; run 'snan-hil "
                          "program-weights' first or pass --layout")
    layout = Layout.load(where)
    check_layout_owner(layout, session.identity, where, session.port)
    return layout


def _codes(adc: ArrayLike) -> float | NDArray[np.float64]:
    """ADC code(s) as the read chain takes them: a scalar stays a float, anything else an
    array of floats."""
    codes = np.asarray(adc, dtype=float)
    return float(codes) if codes.ndim == 0 else codes
