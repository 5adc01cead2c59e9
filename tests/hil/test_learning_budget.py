"""Learning within a budget (issue 36 point 5): the planner's session, cell and plan limits,
the threshold, pacing; what is held back stays in the remainder (buffered transfer); with no
budget the plans are today's (a reference of the unbudgeted rule beside it)."""

import math

import numpy as np
import pytest

from snan_hil.calibration.mapping import WeightMap
from snan_hil.common.polarity import Polarity
from snan_hil.crossbar_model.fitted import DeviceModel, LearningPulse
from snan_hil.host.hil.learning import PulseBudget, PulsePlanner


def _model():
    chip = dict(up_rate=0.047, up_slope=-0.08, down_rate=0.0095, down_slope=-0.39)
    return DeviceModel(LearningPulse(), 525e-6, dw_min=0.034, up_down=0.2, dw_min_dtod=0.18,
                       up_down_dtod=0.17, dw_min_std=0.3, g_min_s=33e-6, g_max_s=1.25e-3,
                       g_min_dtod=0.07, g_max_dtod=0.06, read_noise=0.0027, **chip)


KEYS = [(i, d) for i in range(12) for d in range(4)]


def planner(budget=None):
    budget = budget if budget is not None else PulseBudget()
    cells = {k: (j // 8, j % 8) for j, k in enumerate(KEYS)}
    p = PulsePlanner(_model(), WeightMap(), cells, 0.001, 1.0, budget=budget)
    rng = np.random.default_rng(0)
    p.start({k: float(rng.uniform(0.5, 0.8)) for k in KEYS})
    return p


def reference_plan(p):
    """Today's rule (before budgets), written out: SET/RESET while the pending change is at
    least half a predicted step, within the window, at most max_pulses per synapse."""
    out = {}
    for key in p.w_int:
        pending = p.w_int[key] - p.w_est[key]
        if pending == 0:
            continue
        pol = Polarity.SET if pending > 0 else Polarity.RESET
        sign = math.copysign(1.0, pending)
        w, steps = p.w_est[key], []
        while len(steps) < p.max_pulses:
            s = p.step(key, pol, w)
            if sign * s <= 1e-9 or sign * (p.w_int[key] - w) < 0.5 * abs(s):
                break
            if not p.w_min - 0.5 * abs(s) <= w + s <= p.w_max + 0.5 * abs(s):
                break
            steps.append(s)
            w += s
        if steps:
            out[key] = (pol, steps)
    return out


def updates(p, seed, scale=0.3):
    rng = np.random.default_rng(seed)
    for k in KEYS:
        p.update(k, float(rng.normal(0.05, scale)))


def test_without_a_budget_the_plan_is_todays():
    p = planner()
    for seed in range(3):
        updates(p, seed)
        want = reference_plan(p)
        got = {o.key: (o.polarity, list(o.steps)) for o in p.plan()}
        assert got == want


def test_the_session_budget_holds_and_the_rest_stays_buffered():
    p = planner(PulseBudget(session_pulses=60, cell_pulses=None))
    pending_before = sum(abs(p.w_int[k] - p.w_est[k]) for k in KEYS)
    updates(p, 1, scale=0.4)
    wanted = sum(len(v[1]) for v in reference_plan(p).values())
    orders = p.plan()
    sent = sum(o.count for o in orders)
    assert wanted > 60 and sent == 60 == p.session_spent
    # nothing lost: what was not sent is still intended
    assert sum(abs(p.w_int[k] - p.w_est[k]) for k in KEYS) > pending_before
    assert p.plan() == []                               # the session's budget is spent
    p.start({k: 0.6 for k in KEYS})                     # a new session: a new budget
    assert p.session_spent == 0


def test_the_largest_pending_change_goes_first():
    p = planner(PulseBudget(session_pulses=3))
    for k in KEYS:
        p.w_int[k] = p.w_est[k]
    big, small = KEYS[5], KEYS[9]
    p.w_int[big] = p.w_est[big] + 0.2
    p.w_int[small] = p.w_est[small] + 0.05
    orders = p.plan()
    assert [o.key for o in orders] == [big] and orders[0].count == 3


def test_the_latest_trials_synapses_go_first():
    """recent_first: a synapse the latest trial updated gets the budget before an older,
    larger remainder; without it the larger remainder goes first."""
    for recent, first in ((True, KEYS[9]), (False, KEYS[5])):
        p = planner(PulseBudget(session_pulses=2, recent_first=recent))
        for k in KEYS:
            p.w_int[k] = p.w_est[k]
        p.w_int[KEYS[5]] = p.w_est[KEYS[5]] + 0.3        # an old remainder
        p.update(KEYS[9], 0.05)                           # the latest trial's update
        orders = p.plan()
        assert [o.key for o in orders] == [first], recent
        assert p.plan() == []                             # the budget is spent
    # a plan consumes the freshness: the next one ranks by size again
    p = planner(PulseBudget(session_pulses=100, plan_pulses=1))
    p.update(KEYS[1], 0.05)
    p.plan()
    assert not p._fresh


def test_cell_and_plan_limits_and_pacing():
    p = planner(PulseBudget(session_pulses=200, cell_pulses=4, plan_pulses=2, plan_share=0.25))
    counts = {k: 0 for k in KEYS}
    firsts = []
    for seed in range(8):
        updates(p, seed, scale=0.5)
        orders = p.plan()
        firsts.append(sum(o.count for o in orders))
        for o in orders:
            assert o.count <= 2
            counts[o.key] += o.count
    assert max(counts.values()) <= 4 and sum(counts.values()) <= 200
    assert firsts[0] <= math.ceil(0.25 * 200)


def test_thresholded_transfer_waits_for_a_whole_step():
    for threshold, sent in ((0.5, 1), (1.0, 0)):
        p = planner(PulseBudget(threshold_steps=threshold))
        for k in KEYS:
            p.w_int[k] = p.w_est[k]
        k = KEYS[0]
        step = p.step(k, Polarity.SET, p.w_est[k])
        p.w_int[k] = p.w_est[k] + 0.7 * step
        assert sum(o.count for o in p.plan()) == sent


def test_pulses_not_applied_are_refunded_and_the_state_restores():
    p = planner(PulseBudget(session_pulses=20))
    updates(p, 2)
    orders = p.plan()
    o = orders[0]
    p.not_applied(o.key, o.steps)
    assert p.session_spent == 20 - o.count
    q = planner(PulseBudget(session_pulses=20))
    q.restore(p.state())
    assert q.spent == p.spent and q.w_est == p.w_est
    with pytest.raises(ValueError, match="session_pulses"):
        PulseBudget(session_pulses=0)
    with pytest.raises(ValueError, match="threshold_steps"):
        PulseBudget(threshold_steps=0.2)


def _measured_model(set_v):
    """The chip-level model of 6 cells of the default emulated chip at SET ``set_v`` / RESET
    0.6 V: what a perfect characterisation gives (noise-free steps, cycle-to-cycle from
    noisy pulses), with the board's read noise."""
    import dataclasses

    from snan_hil.crossbar_model import CrossbarArray
    from snan_hil.crossbar_model.characterize import device_truth
    cells = [(0, c) for c in range(6)]
    model, c2c = device_truth(CrossbarArray(seed=0), cells, LearningPulse(set_v, 0.6, 100),
                              g_ref_s=525e-6, g_low_s=45e-6, g_high_s=1.2e-3, c2c_pulses=40)
    return dataclasses.replace(model, dw_min_std=c2c, read_noise=0.0027, cells=())


def test_paired_sessions_learn_as_well_within_the_budget():
    """10 paired sessions of the 6x6 task on the device-model arm: today's rule (SET 0.8 V,
    no budget) and the budget (SET 1.2 V; 200 a session, 30 a cell, 2 a cycle, pacing 0.15):
    the budget holds in every session, the pulses drop more than fourfold, and learning still
    works: at least 6 of 10 sessions solve the task at cycle 20. Whether the success is *the
    same* as today's needs many sessions: bench/bench_budget.py (100 device-arm sessions: 85 %
    vs 89 %, no difference shown; and the chip arm). A transfer that starves the route (the
    largest *unclipped* push first, tried while choosing the policy) solved 37-43 % there and
    fails this test."""
    from snan_hil.host.hil.config import load_hil_config
    from snan_hil.host.hil.learn import LearnConfig, run_learning
    hil = load_hil_config(None, [])
    out = {}
    for name, set_v, budget in (("today", 0.8, PulseBudget()),
                                ("budget", 1.2, PulseBudget(200, 30, 2, 0.5, 0.15))):
        model = _measured_model(set_v)
        lc = LearnConfig(start=hil.task.start, goal=hil.task.goal, sessions=10, cycles=20,
                         seed=1, arms=("device",), budget=budget, pulse=model.pulse)
        out[name] = run_learning(hil.model, lc, model=model)["arms"]["device"]["sessions"]
    today = [s["test_success"][-1] for s in out["today"]]
    budgeted = [s["test_success"][-1] for s in out["budget"]]
    assert all(sum(s["pulses"]) <= 200 and s["max_cell_pulses"] <= 30 for s in out["budget"])
    mean = {k: np.mean([sum(s["pulses"]) for s in v]) for k, v in out.items()}
    assert mean["today"] > 4 * mean["budget"]
    assert sum(budgeted) >= 6 and sum(today) >= 6, (today, budgeted)
