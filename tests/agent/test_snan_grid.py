"""Grid environments: neighbours, walls, start/goal checks."""

import numpy as np
import pytest

from snan_hil.common.errors import UserError
from snan_hil.host.grid import GridWorld


def test_neighbour_table_corners_edges_centre():
    g = GridWorld(3, 4)
    t = g.neighbour_table()
    assert t.shape == (12, 4)
    # order: up, down, left, right
    assert list(t[0]) == [-1, 4, -1, 1]
    assert list(t[5]) == [1, 9, 4, 6]
    assert list(t[11]) == [7, -1, 10, -1]
    degrees = (t >= 0).sum(axis=1)
    assert degrees.sum() == 2 * len(g.inner_edges())
    # a 6x6 field has the paper's 120 input->motor synapses
    assert (GridWorld(6, 6).neighbour_table() >= 0).sum() == 120


def test_walls_block_both_directions_and_bump_table_keeps_synapse():
    g = GridWorld(3, 3, frozenset({frozenset({0, 1})}))
    t = g.neighbour_table()
    assert 1 not in t[0] and 0 not in t[1]
    assert list(g.neighbour_table(through_walls=True)[0]) == [-1, 3, -1, 1]
    assert g.wall_fraction == pytest.approx(1 / 12)
    assert g.reachable(0) == set(range(9))
    cut = g.with_walls([(0, 1), (0, 3)])
    assert cut.reachable(0) == {0}


def test_invalid_wall_and_cells_are_user_errors():
    with pytest.raises(UserError, match="adjacent"):
        GridWorld(3, 3, frozenset({frozenset({0, 4})}))
    with pytest.raises(UserError, match="positive"):
        GridWorld(0, 3)
    g = GridWorld(3, 3)
    with pytest.raises(UserError, match="equals a goal"):
        g.validate_cells(4, [4])
    with pytest.raises(UserError, match="outside"):
        g.validate_cells(0, [9])


def test_sampled_start_and_goal_differ_and_cover_the_grid():
    g = GridWorld(3, 3)
    rng = np.random.default_rng(0)
    pairs = [g.sample_start_goal(rng) for _ in range(2000)]
    assert all(s != t for s, t in pairs)
    assert {s for s, _ in pairs} == set(range(9)) == {t for _, t in pairs}
