"""Maze generation: exact wall counts, the two reachability rules, unreachable handling."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from snan_hil.common.errors import UserError
from snan_hil.host.experiments.mazes import (components, max_connected_fraction, maze_task,
                                             n_walls, random_maze)


@settings(max_examples=40, deadline=None)
@given(rows=st.integers(2, 8), cols=st.integers(2, 8), frac=st.floats(0, 1),
       seed=st.integers(0, 2**32 - 1))
def test_component_rule_has_exactly_the_wall_fraction(rows, cols, frac, seed):
    env = random_maze(rows, cols, frac, np.random.default_rng(seed))
    edges = rows * (cols - 1) + cols * (rows - 1)
    assert len(env.walls) == round(frac * edges) == n_walls(rows, cols, frac)
    assert all(frozenset(e) in {frozenset(x) for x in env.inner_edges()} for e in env.walls)


def test_ten_by_ten_counts():
    assert n_walls(10, 10, 0.4) == 72 and n_walls(10, 10, 0.9) == 162
    assert max_connected_fraction(10, 10) == pytest.approx(81 / 180)


@pytest.mark.parametrize("frac", [0.0, 0.2, 0.45])
def test_connected_rule_keeps_the_grid_connected(frac):
    rng = np.random.default_rng(1)
    for _ in range(20):
        env = random_maze(10, 10, frac, rng, rule="connected")
        assert len(env.walls) == n_walls(10, 10, frac)
        assert len(env.reachable(0)) == 100


def test_connected_rule_refuses_fractions_that_cannot_be_connected():
    with pytest.raises(UserError, match="connected only up to 45.0"):
        random_maze(10, 10, 0.5, np.random.default_rng(0), rule="connected")


@pytest.mark.parametrize("frac,goals", [(0.3, 1), (0.6, 3), (0.9, 1), (0.9, 3)])
def test_component_rule_places_goals_reachable_from_the_start(frac, goals):
    rng = np.random.default_rng(7)
    for _ in range(30):
        env, start, gs = maze_task(10, 10, frac, goals, rng)
        assert len(env.walls) == n_walls(10, 10, frac)
        assert len(gs) == goals and len(set(gs)) == goals and start not in gs
        assert set(gs) <= env.reachable(start)


def test_high_wall_fractions_split_the_maze_but_goals_stay_reachable():
    env, start, gs = maze_task(10, 10, 0.9, 3, np.random.default_rng(3))
    assert len(set(components(env).tolist())) > 1      # unreachable cells exist
    assert set(gs) <= env.reachable(start)


def test_no_piece_large_enough_is_a_user_error():
    with pytest.raises(UserError, match="no two connected cells"):
        maze_task(3, 3, 1.0, 1, np.random.default_rng(0))
    with pytest.raises(UserError):
        maze_task(3, 3, 0.5, 9, np.random.default_rng(0))


def test_components_agree_with_reachability():
    env = random_maze(6, 7, 0.55, np.random.default_rng(11))
    lab = components(env)
    for c in range(env.n_cells):
        assert set(np.nonzero(lab == lab[c])[0].tolist()) == env.reachable(c)
