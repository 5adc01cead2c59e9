"""On-board learning's fixed point (issue 34 stage 1): the board's STDP update and pulse plan
(``firmware_emu/learn_fixed.py``) against the host's float STDP and PulsePlanner
(``tools/learn_agreement.py``; the large sample is ``bench/bench_learn_fixed.py``)."""

import pytest

from snan_hil.calibration.mapping import WeightMap
from snan_hil.firmware_emu import learn_fixed as lf
from snan_hil.host.hil.board_learning import from_q30, learn_block, to_q30
from snan_hil.tools.learn_agreement import agreement_sample, train_config
from snan_hil.tools.learn_agreement import fitted_chip_model as chip_model


def test_fixed_point_plans_equal_the_hosts_float_plans():
    out = agreement_sample(train_config(), chip_model(), 400, seed=3)
    assert out.pulses > 8000                        # plans that move many cells, both ways
    assert out.max_dw_error < 1e-8                  # a window's change: rounding only
    assert out.plans - out.equal <= 1, out.examples


def test_a_chord_of_the_table_is_not_enough():
    """Why the board interpolates by a quadratic: the same table read by chords differs."""
    cfg, model = train_config(), chip_model()
    setup = learn_block(cfg, model, WeightMap(), set_code=1, reset_code=1, width_us=100)
    rule = lf.rule_of(setup)
    from snan_hil.common.polarity import Polarity
    from snan_hil.host.hil.learning import PulsePlanner
    pl = PulsePlanner(model, WeightMap(), {(0, 0): (-1, -1)}, 0.001, 1.0, per_cell=False)
    n = 1 << rule.table_bits
    worst_quad = worst_chord = upper_quad = 0.0
    for i in range(2000):
        w = (i + 0.37) / 2000
        host = pl.step((0, 0), Polarity.SET, w)
        quad = from_q30(lf.step_ref(rule, lf.SET, to_q30(w)))
        j = min(int(w * n), n - 1)
        f = w * n - j
        chord = from_q30(rule.set_steps[j]) * (1 - f) + from_q30(rule.set_steps[j + 1]) * f
        worst_quad = max(worst_quad, abs(quad - host) / host)
        worst_chord = max(worst_chord, abs(chord - host) / host)
        if w > 0.1:
            upper_quad = max(upper_quad, abs(quad - host) / host)
    # relative error of a SET step: quadratic 4e-4 at most (near w = 0, where ln G bends
    # fastest), below 5e-5 above w = 0.1 (3.4e-5 measured); the chord 2.9e-3
    assert worst_quad * 5 < worst_chord and upper_quad < 5e-5


def test_remainders_accumulate_and_nothing_is_lost():
    """Forty updates of a tenth of a step: the board sends the host planner's pulses, plan by
    plan, and keeps the rest as the remainder (nothing lost, the intended weight exact)."""
    from snan_hil.common.polarity import Polarity
    from snan_hil.host.hil.learning import PulsePlanner
    model = chip_model()
    setup = learn_block(train_config(), model, WeightMap(), set_code=1, reset_code=1,
                        width_us=100)
    st = lf.LearnState(lf.rule_of(setup), [0], [to_q30(0.5)], [to_q30(0.5)])
    pl = PulsePlanner(model, WeightMap(), {(0, 0): (-1, -1)}, 0.001, 1.0, per_cell=False,
                      max_pulses=127)
    pl.start({(0, 0): 0.5})
    tenth = lf.step_ref(st.rule, lf.SET, st.w_est[0]) // 10
    board, host = [], []
    for _ in range(40):
        st.pending = [(0, tenth)]
        st.decide(0)
        pl.update((0, 0), from_q30(tenth))
        board += [(p, n) for _j, p, n in st.plan()]
        host += [(0 if o.polarity == Polarity.SET else 1, o.count) for o in pl.plan()]
    assert board == host and sum(n for p, n in board if p == lf.SET) >= 4
    assert st.w_int[0] == to_q30(0.5) + 40 * tenth
    larger = max(abs(lf.step_ref(st.rule, p, st.w_est[0])) for p in (lf.SET, lf.RESET))
    assert 2 * abs(st.w_int[0] - st.w_est[0]) <= larger


def test_the_plan_stays_inside_the_window_and_the_lane_not_chosen_is_not_changed():
    setup = learn_block(train_config(), chip_model(), WeightMap(), set_code=1, reset_code=1,
                        width_us=100)
    rule = lf.rule_of(setup)
    st = lf.LearnState(rule, [0, 1], [to_q30(0.99), to_q30(0.5)], [to_q30(0.99), to_q30(0.5)])
    st.window([0, 1], list(range(0, 1000, 7)), [[3, 50, 400], [3, 50, 400]])
    assert st.pending[0][1] == st.pending[1][1] > 0
    st.decide(0)
    assert st.w_int == [rule.w_max, to_q30(0.5)]   # clipped at w_max; lane 1 untouched
    (j, pol, n), = st.plan()
    w = lf.advance_ref(rule, pol, to_q30(0.99), n)
    assert (j, pol) == (0, lf.SET) and 2 * (w - rule.w_max) <= lf.step_ref(rule, pol, w)


@pytest.mark.parametrize("nearest", [False, True])
def test_window_change_is_the_hosts_pairing(nearest):
    from snan_hil.host import snan_kernel as K
    from snan_hil.host.kernel_params import kernel_params
    import dataclasses
    import numpy as np
    cfg = train_config()
    if nearest:
        cfg = dataclasses.replace(cfg, stdp=dataclasses.replace(cfg.stdp, pairing="nearest"))
    kp = kernel_params(cfg)
    rule = lf.rule_of(learn_block(cfg, chip_model(), WeightMap(), set_code=1, reset_code=1,
                                  width_us=100))
    assert rule.nearest == nearest
    rng = np.random.default_rng(5)
    for _ in range(50):
        pre = np.flatnonzero(rng.random(1000) < 0.15).astype(np.int64)
        post = np.sort(rng.choice(1000, 8, replace=False)).astype(np.int64)
        post[0] = pre[0]                            # a pre and a post spike in one step
        host = kp.k * K.stdp_lane(kp, pre, len(pre), post, len(post))
        assert abs(from_q30(lf.window_dw_ref(rule, pre.tolist(), post.tolist())) - host) < 3e-9
