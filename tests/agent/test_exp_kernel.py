"""The experiments run the agent's trial kernel: equal to the agent's run_trial with default
options, and the options they add (several goals, return to start, plasticity targets,
VTEAM lookup)."""

import numpy as np
import pytest

from snan_hil.host.agent import run_trial, synapse_tables
from snan_hil.host.config import load_config
from snan_hil.host import snan_kernel as K
from snan_hil.host.experiments.mazes import maze_task
from snan_hil.host.experiments.trials import nav_batch, prepare, run_one
from snan_hil.host.plasticity import Plasticity, vteam_lookup
from snan_hil.host.grid import GridWorld
from snan_hil.host.rng import trial_keys
from snan_hil.host.state import initial_weights


def _weights(cfg, nbr, seed, trial):
    _key, _task, w_seed = trial_keys(seed, trial)
    return initial_weights(cfg, nbr, np.random.default_rng(w_seed))


@pytest.mark.parametrize("astro,mode", [(True, "trial_end"), (False, "trial_end"),
                                        (True, "window"), (False, "window")])
def test_default_options_equal_the_agents_run_trial(astro, mode):
    cfg = load_config(preset="snan-10x10", overrides=[
        f"astro.enabled={str(astro).lower()}", f"stdp.mode={mode}", "grid.max_steps=300"])
    prep = prepare(cfg)
    rng = np.random.default_rng(5)
    for trial in range(6):
        env, start, goals = maze_task(10, 10, [0.0, 0.3][trial % 2], 1 + trial % 3, rng)
        nbr, move = synapse_tables(env, cfg)
        w = _weights(cfg, nbr, 9, trial)
        ref = run_trial(env, cfg, start, goals, seed=9, trial=trial, weights=w)
        key, _t, _w = trial_keys(9, trial)
        steps, ok, path, w_out = run_one(prep, nbr, move, start, goals, w, key)
        assert (steps, ok) == (ref.steps, ref.success)
        assert np.array_equal(path, ref.path)
        assert np.array_equal(w_out, ref.weights)


def test_open_grid_batch_equals_simulate():
    from snan_hil.host.simulate import simulate
    cfg = load_config(preset="snan-3x3")
    res = nav_batch(cfg, {"trials": [0, 40]}, 17)
    sim = simulate(cfg, 40, 17)
    assert np.array_equal(res["steps"], sim.steps)
    assert np.array_equal(res["success"], sim.success)


@pytest.mark.parametrize("rule, carried", [("component", False), ("connected", True)])
def test_maze_batch_paths_equal_the_agents_trials(rule, carried):
    """nav_batch skips the STDP arithmetic of trial_end runs (it discards the learned
    weights): the paths are still the agent's, for either maze rule and membrane reading."""
    from snan_hil.host.experiments.trials import maze_rng
    cfg = load_config(preset="snan-10x10", overrides=[
        "grid.max_steps=400", f"neuron.reset_each_window={str(not carried).lower()}"])
    res = nav_batch(cfg, {"trials": [0, 6], "walls": 0.3, "goals": 2, "maze_rule": rule,
                          "keep": list(range(6))}, 5)
    for ex in res["examples"]:
        env, start, goals = maze_task(10, 10, 0.3, 2, maze_rng(5, ex["trial"]), rule)
        assert (start, list(goals)) == (ex["start"], ex["goals"])
        r = run_trial(env, cfg, start, goals, seed=5, trial=ex["trial"])
        assert r.path.tolist() == ex["path"] and r.success == ex["success"]


def _first_all_visited(path, goals):
    seen = set()
    for i, c in enumerate(path):
        seen.add(int(c))
        if set(goals) <= seen:
            return i
    return None


def test_multi_goal_trial_ends_exactly_when_all_goals_were_visited():
    cfg = load_config(preset="snan-10x10", overrides=["grid.max_steps=2000"])
    res = nav_batch(cfg, {"trials": [0, 12], "walls": 0.3, "goals": 3,
                          "keep": list(range(12))}, 3)
    assert len(res["examples"]) == 12
    n_ok = 0
    for ex in res["examples"]:
        path, goals = ex["path"], ex["goals"]
        assert len(goals) == 3 and ex["start"] not in goals
        end = _first_all_visited(path, goals)
        if ex["success"]:
            n_ok += 1
            assert end == len(path) - 1        # not before, not after
            assert path[-1] in goals
        else:
            assert end is None and len(path) - 1 == cfg.grid.max_steps
    assert n_ok > 0


def test_return_to_start_needs_all_goals_then_the_start():
    cfg = load_config(preset="snan-10x10", overrides=["grid.max_steps=3000"])
    res = nav_batch(cfg, {"trials": [0, 8], "walls": 0.2, "goals": 3,
                          "return_to_start": True, "keep": list(range(8))}, 4)
    n_ok = 0
    for ex in res["examples"]:
        path = ex["path"]
        if ex["success"]:
            n_ok += 1
            end = _first_all_visited(path, ex["goals"])
            assert end is not None and end < len(path) - 1
            assert path[-1] == ex["start"]
            assert ex["start"] not in path[end:-1]   # the first return after the goals
    assert n_ok > 0


def test_chosen_target_changes_only_the_chosen_synapses():
    cfg = load_config(preset="snan-3x3", overrides=["grid.max_steps=30", "stdp.target=all"])
    env = GridWorld(3, 3)
    nbr, move = synapse_tables(env, cfg)
    w = _weights(cfg, nbr, 2, 0)
    key, _t, _w = trial_keys(2, 0)
    steps, _ok, path, w_all = run_one(prepare(cfg), nbr, move, 0, (8,), w, key)
    _s, _o, path2, w_ch = run_one(prepare(cfg, Plasticity(target="chosen")), nbr, move, 0,
                                  (8,), w, key)
    assert np.array_equal(path, path2)               # trial_end: same trial
    used = {(int(a), d) for a, b in zip(path[:-1], path[1:]) for d in range(4)
            if nbr[a, d] == b}
    changed = {(int(i), int(d)) for i, d in zip(*np.nonzero(w_ch != w))}
    assert changed and changed <= used
    assert len({(int(i), int(d)) for i, d in zip(*np.nonzero(w_all != w))}) > len(changed)


def test_normalize_target_keeps_each_cells_weight_sum():
    cfg = load_config(preset="snan-3x3", overrides=["grid.max_steps=20", "stdp.w_max=5"])
    env = GridWorld(3, 3)
    nbr, move = synapse_tables(env, cfg)
    w = _weights(cfg, nbr, 3, 0)
    key, _t, _w = trial_keys(3, 0)
    _s, _o, _p, w2 = run_one(prepare(cfg, Plasticity(target="normalize")), nbr, move, 0,
                             (8,), w, key)
    assert not np.allclose(w2, w)
    assert np.allclose(w2.sum(axis=1), w.sum(axis=1))


def test_lut_value_matches_the_vteam_lookup():
    look, _gp, _gd = vteam_lookup(0.04)
    rng = np.random.default_rng(0)
    w = rng.random(200)
    dt = rng.uniform(-40, 40, 200)
    ours = [K.lut_value(look.table, a, b, look.dt_grid_ms[0],
                         look.dt_grid_ms[1] - look.dt_grid_ms[0]) for a, b in zip(w, dt)]
    assert np.allclose(ours, look.delta_w(w, dt), atol=1e-12)


def test_vteam_depression_option_rescales_only_the_depression_branch():
    dev, gp, gd = vteam_lookup(0.04)
    bal, gp2, gd2 = vteam_lookup(0.04, 0.03)
    assert gp == gp2 and gd == gp and gd2 < gd
    pos = dev.dt_grid_ms > 0
    assert np.array_equal(dev.table[:, pos], bal.table[:, pos])
    assert np.isclose(-bal.delta_w(np.full(dev.dt_grid_ms.size, 0.5), dev.dt_grid_ms).min(),
                      0.03)


def test_vteam_lane_pairs_post_after_pre_as_potentiation():
    look, _gp, _gd = vteam_lookup(0.04)

    def params(pairing):
        # the device's own reading (the crossbar model's default spike and mapping), which
        # is the lookup above
        cfg = load_config(preset="snan-3x3", overrides=[
            f"stdp.pairing={pairing}", "vteam.mapping=conductance", "vteam.balance=0",
            "vteam.spike_t_neg_ms=30"])
        return K.params_ref(prepare(cfg, Plasticity(rule="vteam", vteam_peak=0.04)).params)

    sp = np.array([10, 500], dtype=np.int64)
    post = np.array([12], dtype=np.int64)          # 2 steps after the first pre spike
    for pairing in ("all_to_all", "nearest"):
        dw = K.vteam_lane(params(pairing), sp, 2, post, 1, 0.6)
        assert np.isclose(dw, look.delta_w(0.6, 3.0))  # the far pre spike is out of range
    post = np.array([8], dtype=np.int64)           # pre 2 steps after post: depression
    dw = K.vteam_lane(params("all_to_all"), sp, 2, post, 1, 0.6)
    assert dw < 0 and np.isclose(dw, look.delta_w(0.6, -1.0))


def test_the_agents_stdp_target_option_is_followed_when_present():
    cfg = load_config(preset="snan-3x3", overrides=["grid.max_steps=40"])
    if not hasattr(cfg.stdp, "target"):
        pytest.skip("the agent has no stdp.target option yet")
    cfg = cfg.replace(**{"stdp.target": "chosen"})
    env = GridWorld(3, 3)
    nbr, move = synapse_tables(env, cfg)
    for trial in range(4):
        w = _weights(cfg, nbr, 6, trial)
        ref = run_trial(env, cfg, 0, 8, seed=6, trial=trial, weights=w)
        key, _t, _w = trial_keys(6, trial)
        _s, _o, path, w_out = run_one(prepare(cfg), nbr, move, 0, (8,), w, key)
        assert np.array_equal(path, ref.path) and np.array_equal(w_out, ref.weights)
