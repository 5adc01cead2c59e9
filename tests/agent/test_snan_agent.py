"""The agent API: trials, weights carried across trials, walls, several goals, batches,
and the effect of the astrocytes."""

import numpy as np
import pytest

from snan_hil.common.errors import UserError
from snan_hil.host.agent import environment, run_trial
from snan_hil.host.config import load_config
from snan_hil.host.grid import GridWorld
from snan_hil.host.simulate import simulate, trial_setup
from snan_hil.host.agent import synapse_tables


def test_trial_result_is_consistent():
    cfg = load_config(preset="snan-3x3")
    env = environment(cfg)
    r = run_trial(env, cfg, 0, 8, seed=4)
    assert r.path[0] == 0 and r.steps == len(r.path) - 1
    steps = np.abs(np.diff(r.path))
    assert set(steps) <= {1, 3}                       # only moves to 4-neighbours
    if r.success:
        assert r.path[-1] == 8 and 8 not in r.path[:-1]
    else:
        assert r.steps == cfg.grid.max_steps
    assert r.counts.shape == (r.steps, 4)
    assert r.weights.shape == (9, 4)


def test_given_weights_drive_the_choice_and_persist():
    cfg = load_config(preset="snan-3x3", overrides=["astro.enabled=false",
                                                    "grid.max_steps=1", "stdp.target=all"])
    env = environment(cfg)
    w = np.full((9, 4), 0.5)
    w[4] = [0.5, 0.5, 0.5, 0.8]                       # centre: "right" is strongest
    r = run_trial(env, cfg, 4, 0, seed=1, weights=w)
    assert list(r.path) == [4, 5]
    # trial_end: the trial ran on w, the learned weights come back changed (all-to-all
    # pairing potentiates every firing synapse), bounded by w_max
    assert np.all(r.weights[4] > w[4]) and np.all(r.weights[4] <= cfg.stdp.w_max)
    others = [0, 1, 2, 3, 5, 6, 7, 8]
    expected = np.where(env.neighbour_table() >= 0, w, 0.0)   # no synapse off the grid
    assert np.array_equal(r.weights[others], expected[others])
    off = run_trial(env, load_config(preset="snan-3x3", overrides=[
        "astro.enabled=false", "grid.max_steps=1", "stdp.mode=off"]), 4, 0, seed=1, weights=w)
    assert np.array_equal(off.weights[4], w[4])


def test_stdp_trial_end_does_not_change_the_trial_but_window_mode_does():
    base = ["astro.enabled=false"]
    env = GridWorld(3, 3)
    paths = {}
    for mode in ("off", "trial_end", "window"):
        cfg = load_config(preset="snan-3x3", overrides=base + [f"stdp.mode={mode}"])
        paths[mode] = [tuple(run_trial(env, cfg, 0, 8, seed=s).path) for s in range(12)]
    assert paths["off"] == paths["trial_end"]
    assert paths["off"] != paths["window"]


def test_walls_prune_or_bump():
    env = GridWorld(3, 3, frozenset({frozenset({4, 5}), frozenset({4, 1}),
                                      frozenset({4, 3})}))
    w = np.full((9, 4), 0.5)
    w[4] = [1.0, 0.001, 0.001, 0.001]                 # "up" is strongest, but walled
    cfg = load_config(preset="snan-3x3", overrides=["astro.enabled=false",
                                                    "grid.max_steps=1"])
    pruned = run_trial(env, cfg, 4, 0, seed=2, weights=w)
    assert list(pruned.path) == [4, 7]                # the only open move
    bump = load_config(preset="snan-3x3", overrides=["astro.enabled=false",
                                                     "grid.max_steps=1", "grid.walls=bump"])
    bumped = run_trial(env, bump, 4, 0, seed=2, weights=w)
    assert list(bumped.path) == [4, 4]                # chose "up", hit the wall, stayed
    assert bumped.counts[0, 0] > 0


def test_several_goals_must_all_be_visited():
    cfg = load_config(preset="snan-3x3", overrides=["grid.max_steps=300"])
    env = environment(cfg)
    r = run_trial(env, cfg, 4, [0, 8], seed=7)
    assert r.success
    assert 0 in r.path and 8 in r.path and r.path[-1] in (0, 8)


def test_bad_trial_inputs_are_user_errors():
    cfg = load_config(preset="snan-3x3")
    env = environment(cfg)
    with pytest.raises(UserError):
        run_trial(env, cfg, 3, 3)
    with pytest.raises(UserError):
        run_trial(GridWorld(4, 4), cfg, 0, 1)
    with pytest.raises(UserError):
        run_trial(env, cfg, 0, 1, weights=np.zeros((4, 4)))
    with pytest.raises(UserError):
        simulate(cfg, 0)


def test_batch_trial_can_be_replayed_alone():
    cfg = load_config(preset="snan-3x3")
    res = simulate(cfg, 20, seed=3)
    env = environment(cfg)
    nbr, _ = synapse_tables(env, cfg)
    for i in (0, 7, 19):
        start, goal, _w, _key = trial_setup(cfg, env, nbr, 3, i)
        alone = run_trial(env, cfg, start, goal, seed=3, trial=i)
        assert np.array_equal(alone.path, res.path(i))


def test_astrocytes_make_the_3x3_agent_better():
    """Behaviour, not the paper's exact numbers: with astrocytes the agent succeeds more
    often and needs fewer steps (150 trials each)."""
    with_a = simulate(load_config(preset="snan-3x3"), 150, seed=11).summary()
    without = simulate(load_config(preset="snan-3x3", overrides=["astro.enabled=false"]),
                       150, seed=11).summary()
    assert with_a["success_rate"] >= 0.95
    assert with_a["success_rate"] - without["success_rate"] >= 0.1
    assert with_a["mean_steps"] < without["mean_steps"]


def test_summary_statistics_match_the_per_trial_arrays():
    res = simulate(load_config(preset="snan-3x3", overrides=["astro.enabled=false"]), 60, 2)
    s = res.summary()
    ok = res.steps[res.success]
    assert s["trials"] == 60 and 0 <= s["success_rate"] <= 1
    assert s["successes"] == ok.size
    assert s["median_steps"] == float(np.median(ok))
    assert np.all(res.steps[~res.success] == 100)


def test_stdp_target_chosen_changes_only_the_chosen_moves_synapses():
    """stdp.target=chosen: only synapses (cell -> next cell of the path) change; 'all' changes
    more."""
    from snan_hil.host.agent import environment, run_trial, synapse_tables
    from snan_hil.host.config import load_config
    over = ["grid.max_steps=20", "astro.enabled=false"]
    cfg_all = load_config(preset="snan-3x3", overrides=over + ["stdp.target=all"])
    cfg_ch = load_config(preset="snan-3x3", overrides=over + ["stdp.target=chosen"])
    env = environment(cfg_ch)
    nbr, move = synapse_tables(env, cfg_ch)
    w0 = np.where(nbr >= 0, 0.6, 0.0)
    res_ch = run_trial(env, cfg_ch, 0, 8, seed=3, weights=w0.copy())
    res_all = run_trial(env, cfg_all, 0, 8, seed=3, weights=w0.copy())
    assert np.array_equal(res_ch.path, res_all.path)       # trial_end: same walk either way
    moved = {(int(a), int(b)) for a, b in zip(res_ch.path[:-1], res_ch.path[1:])}
    changed_ch = {(int(c), int(d)) for c, d in np.argwhere(res_ch.weights != w0)}
    changed_all = {(int(c), int(d)) for c, d in np.argwhere(res_all.weights != w0)}
    assert changed_ch
    assert all((c, int(move[c, d])) in moved for c, d in changed_ch)
    assert changed_ch < changed_all                         # 'all' also changes other candidates
