"""Random mazes (paper section 3.3): walls between adjacent cells at a given wall fraction,
and start / goal placement that keeps every goal reachable.

Wall fraction ``f`` = walls / inner edges (adjacent cell pairs; 180 on 10x10, 12 on 3x3).
Exactly ``round(f * E)`` walls are placed. Two named rules:

* ``component`` (default): the walls are ``round(f * E)`` distinct inner edges drawn
  uniformly. The maze may fall apart into several connected pieces (above ~45 % on 10x10 it
  always does: a connected grid needs N - 1 = 99 open edges of 180). The start is drawn
  uniformly among the cells whose piece holds at least ``1 + n_goals`` cells, and the goals
  uniformly (distinct) among the other cells of the start's piece, so every goal is
  reachable. If no piece is large enough the maze is drawn again (same random stream).
* ``connected``: a uniformly random spanning tree (Wilson's algorithm) is kept open and the
  walls are drawn among the other edges, so the whole grid stays connected; start and goals
  are uniform over all cells. Only possible for ``f <= (E - N + 1) / E`` (45 % on 10x10);
  larger fractions raise :class:`UserError`.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from snan_hil.common.errors import UserError
from snan_hil.host.grid import GridWorld, inner_edges

MazeRule = Literal["component", "connected"]
MAZE_RULES = ("component", "connected")
_MAX_REDRAWS = 10_000


def n_walls(rows: int, cols: int, fraction: float) -> int:
    """Number of walls for a wall fraction (rounded to the nearest edge count)."""
    if not 0.0 <= fraction <= 1.0:
        raise UserError(f"wall fraction must be in [0, 1], got {fraction}")
    edges = rows * (cols - 1) + cols * (rows - 1)
    return int(round(fraction * edges))


def max_connected_fraction(rows: int, cols: int) -> float:
    """Largest wall fraction a connected maze can have: (E - (N - 1)) / E."""
    edges = rows * (cols - 1) + cols * (rows - 1)
    return (edges - (rows * cols - 1)) / edges if edges else 0.0


def _spanning_tree(rows: int, cols: int, rng: np.random.Generator) -> set[frozenset[int]]:
    """Uniform random spanning tree of the grid graph (Wilson's loop-erased random walks)."""
    env = GridWorld(rows, cols)
    nbr = env.neighbour_table()
    n = env.n_cells
    in_tree = np.zeros(n, dtype=bool)
    nxt = np.full(n, -1, dtype=np.int64)
    in_tree[int(rng.integers(n))] = True
    tree: set[frozenset[int]] = set()
    for start in rng.permutation(n):
        u = int(start)
        while not in_tree[u]:
            opts = nbr[u][nbr[u] >= 0]
            nxt[u] = int(opts[int(rng.integers(len(opts)))])
            u = int(nxt[u])
        u = int(start)
        while not in_tree[u]:
            in_tree[u] = True
            tree.add(frozenset((u, int(nxt[u]))))
            u = int(nxt[u])
    return tree


def random_maze(rows: int, cols: int, fraction: float, rng: np.random.Generator,
                rule: MazeRule = "component") -> GridWorld:
    """A grid with exactly ``n_walls(rows, cols, fraction)`` walls (see module doc)."""
    if rule not in MAZE_RULES:
        raise UserError(f"unknown maze rule {rule!r} ({', '.join(MAZE_RULES)})")
    k = n_walls(rows, cols, fraction)
    edges = inner_edges(rows, cols)
    if rule == "component":
        pick = rng.choice(len(edges), size=k, replace=False) if k else np.zeros(0, int)
        return GridWorld(rows, cols, frozenset(frozenset(edges[int(i)]) for i in pick))
    limit = max_connected_fraction(rows, cols)
    if fraction > limit + 1e-12:
        raise UserError(f"maze rule 'connected': a {rows}x{cols} maze stays connected only up "
                        f"to {100 * limit:.1f} % walls, got {100 * fraction:.1f} %; use rule "
                        f"'component'")
    tree = _spanning_tree(rows, cols, rng)
    free = [e for e in edges if frozenset(e) not in tree]
    pick = rng.choice(len(free), size=k, replace=False) if k else np.zeros(0, int)
    return GridWorld(rows, cols, frozenset(frozenset(free[int(i)]) for i in pick))


def components(env: GridWorld) -> np.ndarray:
    """Label (0..) of the connected piece of every cell; pieces numbered in the order of
    their lowest cell."""
    nbr = env.neighbour_table().tolist()
    label = [-1] * env.n_cells
    n_pieces = 0
    for first in range(env.n_cells):
        if label[first] >= 0:
            continue
        label[first] = n_pieces
        stack = [first]
        while stack:
            for nb in nbr[stack.pop()]:
                if nb >= 0 and label[nb] < 0:
                    label[nb] = n_pieces
                    stack.append(nb)
        n_pieces += 1
    return np.array(label, dtype=np.int64)


def place_task(env: GridWorld, n_goals: int, rng: np.random.Generator
               ) -> tuple[int, tuple[int, ...]] | None:
    """Start and ``n_goals`` distinct goals in the start's piece (None if no piece holds
    ``1 + n_goals`` cells)."""
    label = components(env)
    sizes = np.bincount(label)
    ok = np.nonzero(sizes[label] >= 1 + n_goals)[0]
    if ok.size == 0:
        return None
    start = int(ok[int(rng.integers(ok.size))])
    mates = [int(c) for c in np.nonzero(label == label[start])[0] if c != start]
    goals = rng.choice(len(mates), size=n_goals, replace=False)
    return start, tuple(mates[int(i)] for i in goals)


def maze_task(rows: int, cols: int, fraction: float, n_goals: int, rng: np.random.Generator,
              rule: MazeRule = "component") -> tuple[GridWorld, int, tuple[int, ...]]:
    """A maze and a start/goals placement on it, by ``rule`` (see module doc)."""
    if n_goals < 1 or n_goals >= rows * cols:
        raise UserError(f"number of goals must be in 1..{rows * cols - 1}, got {n_goals}")
    if rule == "component" and n_walls(rows, cols, fraction) == (
            rows * (cols - 1) + cols * (rows - 1)):
        raise UserError(f"a {rows}x{cols} maze with {100 * fraction:.0f} % walls has no two "
                        f"connected cells; lower the wall fraction")
    for _ in range(_MAX_REDRAWS):
        env = random_maze(rows, cols, fraction, rng, rule)
        if rule == "connected":
            cells = rng.choice(env.n_cells, size=1 + n_goals, replace=False)
            return env, int(cells[0]), tuple(int(c) for c in cells[1:])
        placed = place_task(env, n_goals, rng)
        if placed is not None:
            return env, placed[0], placed[1]
    raise UserError(f"no {rows}x{cols} maze with {100 * fraction:.0f} % walls had a piece of "
                    f"{1 + n_goals} cells in {_MAX_REDRAWS} draws; lower the wall fraction")
