"""Grid environments: an M x K grid of cells, four moves, optional walls between cells.

Cells are numbered row-major, ``cell = row * cols + col`` with row 0 at the top. The four
moves are, in this fixed order, up (row-1), down (row+1), left (col-1), right (col+1);
every per-cell table in the project (neighbours, weights, spike counts) uses this order.
A move off the grid does not exist. A wall blocks the move between two adjacent cells
in both directions.
"""

from __future__ import annotations

import functools
from collections import deque
from dataclasses import dataclass, field
from typing import Iterable

import numpy as np

from snan_hil.common.errors import UserError

DIRECTIONS = ("up", "down", "left", "right")
_DR = (-1, 1, 0, 0)
_DC = (0, 0, -1, 1)


@dataclass(frozen=True)
class GridWorld:
    """An M x K grid with optional walls (each wall is an unordered pair of adjacent cells)."""

    rows: int
    cols: int
    walls: frozenset[frozenset[int]] = field(default_factory=frozenset)

    def __post_init__(self) -> None:
        if self.rows < 1 or self.cols < 1:
            raise UserError(f"grid size must be positive, got {self.rows}x{self.cols}")
        walls = frozenset(frozenset(w) for w in self.walls)
        for w in walls:
            pair = sorted(w)
            if len(pair) != 2 or not self._adjacent(*pair):
                raise UserError(f"wall {pair} is not between two adjacent cells of the "
                                f"{self.rows}x{self.cols} grid")
        object.__setattr__(self, "walls", walls)

    # ---- basic geometry ---------------------------------------------------------------
    @property
    def n_cells(self) -> int:
        return self.rows * self.cols

    def rc(self, cell: int) -> tuple[int, int]:
        return divmod(int(cell), self.cols)

    def cell(self, row: int, col: int) -> int:
        return row * self.cols + col

    def _in(self, cell: int) -> bool:
        return 0 <= cell < self.n_cells

    def _adjacent(self, a: int, b: int) -> bool:
        if not (self._in(a) and self._in(b)):
            return False
        (ra, ca), (rb, cb) = self.rc(a), self.rc(b)
        return abs(ra - rb) + abs(ca - cb) == 1

    def neighbour_table(self, through_walls: bool = False) -> np.ndarray:
        """int64 [n_cells, 4]: neighbour per direction, -1 where off-grid (or walled,
        unless ``through_walls``). A fresh copy of a table computed once per grid."""
        key = bool(through_walls)
        cache = self.__dict__.setdefault("_tables", {})
        table = cache.get(key)
        if table is None:
            table = _open_table(self.rows, self.cols).copy()
            if not through_walls:
                for wall in self.walls:
                    a, b = sorted(wall)
                    d = 1 if b - a == self.cols else 3      # b below a, or right of a
                    table[a, d] = -1
                    table[b, d - 1] = -1
            cache[key] = table
        return table.copy()

    # ---- walls ------------------------------------------------------------------------
    def inner_edges(self) -> list[tuple[int, int]]:
        """All pairs of adjacent cells (candidate wall positions), each once: per cell its
        down then its right neighbour, cells in order."""
        return list(_inner_edges(self.rows, self.cols))

    @property
    def wall_fraction(self) -> float:
        edges = len(self.inner_edges())
        return len(self.walls) / edges if edges else 0.0

    def with_walls(self, walls: Iterable[Iterable[int]]) -> "GridWorld":
        return GridWorld(self.rows, self.cols, frozenset(frozenset(w) for w in walls))

    def reachable(self, start: int) -> set[int]:
        """Cells reachable from ``start`` through open moves."""
        table = self.neighbour_table()
        seen = {int(start)}
        queue = deque([int(start)])
        while queue:
            c = queue.popleft()
            for nb in table[c]:
                if nb >= 0 and int(nb) not in seen:
                    seen.add(int(nb))
                    queue.append(int(nb))
        return seen

    def validate_cells(self, start: int, goals: Iterable[int]) -> tuple[int, tuple[int, ...]]:
        """Check start/goal indices; raise UserError on out-of-range or start == goal."""
        goals = tuple(int(g) for g in goals)
        if not goals:
            raise UserError("at least one goal cell is needed")
        for name, c in [("start", start), *[("goal", g) for g in goals]]:
            if not self._in(int(c)):
                raise UserError(f"{name} cell {c} is outside the {self.rows}x{self.cols} grid "
                                f"(cells 0..{self.n_cells - 1})")
        if int(start) in goals:
            raise UserError(f"start cell {start} equals a goal cell; choose a different goal")
        if len(set(goals)) != len(goals):
            raise UserError("goal cells must be distinct")
        return int(start), goals

    def sample_start_goal(self, rng: np.random.Generator) -> tuple[int, int]:
        """Uniform random start and goal with start != goal."""
        start = int(rng.integers(self.n_cells))
        goal = int(rng.integers(self.n_cells - 1))
        if goal >= start:
            goal += 1
        return start, goal


@functools.lru_cache(maxsize=64)
def _open_table(rows: int, cols: int) -> np.ndarray:
    """Neighbour table of the open rows x cols grid (see ``GridWorld.neighbour_table``)."""
    cell = np.arange(rows * cols)
    r, c = np.divmod(cell, cols)
    table = np.full((rows * cols, 4), -1, dtype=np.int64)
    for d in range(4):
        r2, c2 = r + _DR[d], c + _DC[d]
        ok = (r2 >= 0) & (r2 < rows) & (c2 >= 0) & (c2 < cols)
        table[ok, d] = r2[ok] * cols + c2[ok]
    table.flags.writeable = False
    return table


def inner_edges(rows: int, cols: int) -> tuple[tuple[int, int], ...]:
    """The inner edges of the open rows x cols grid (``GridWorld.inner_edges``), cached."""
    return _inner_edges(rows, cols)


@functools.lru_cache(maxsize=64)
def _inner_edges(rows: int, cols: int) -> tuple[tuple[int, int], ...]:
    edges = []
    for cell in range(rows * cols):
        r, c = divmod(cell, cols)
        if r + 1 < rows:
            edges.append((cell, cell + cols))
        if c + 1 < cols:
            edges.append((cell, cell + 1))
    return tuple(edges)

