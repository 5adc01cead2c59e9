"""Duration of the astrocytic modulation in decisions and the (tau_Ca, A) family."""

import numpy as np
import pytest

from snan_hil.common.errors import UserError
from snan_hil.host.config import load_config
from snan_hil.host.experiments.calcium import (calcium_event, duration_steps, family_config,
                                               level_for_duration)


@pytest.fixture(scope="module")
def base():
    return load_config(preset="snan-10x10")


def test_duration_grows_monotonically_with_tau_ca(base):
    taus = [1.0, 1.5, 2, 3, 5, 8, 13, 22, 35]
    d = [duration_steps(family_config(base, t)) for t in taus]
    assert all(b > a for a, b in zip(d, d[1:]))
    assert [family_config(base, t).astro.tau_ca_s for t in taus] == taus


def test_below_one_second_only_the_amplitude_shrinks_and_duration_falls_to_zero(base):
    levels = [0.15, 0.2, 0.21, 0.22, 0.3, 0.5, 0.8, 1.0]
    cfgs = [family_config(base, s) for s in levels]
    assert all(c.astro.tau_ca_s == 1.0 for c in cfgs)
    d = [duration_steps(c) for c in cfgs]
    assert d[0] == 0 and d[1] == 0                 # A <= Ca_thr: never above threshold
    assert all(b > a for a, b in zip(d[1:], d[2:]))


def test_the_inverse_hits_the_requested_durations(base):
    for target in (1, 5, 30, 120):
        lvl = level_for_duration(base, target)
        assert duration_steps(family_config(base, lvl)) == pytest.approx(target, abs=0.02)


def test_duration_is_the_time_above_threshold_measured_on_the_euler_model(base):
    cfg = family_config(base, 4.0)
    ev = calcium_event(cfg)
    # replay the agent's equations step by step with the same mean-rate visit
    a, dt, p, n = cfg.astro, cfg.input.dt_ms, cfg.input.p, cfg.window_steps
    tau = a.tau_ca_ms
    g = ca = y = 0.0
    above = []
    for t in range(int((ev.end + 3) * n)):
        s = 1.0 if t < n and np.floor((t + 1) * p) > np.floor(t * p) else 0.0
        g = g + dt * (-a.alpha_n_per_ms * g + a.k_n * s)
        j = a.a if g > a.g_thr else 0.0
        ca, y = ca + dt * y, y + dt * (j - 2 * tau * y - ca) / tau ** 2
        above.append(ca > a.ca_thr)
    idx = np.nonzero(above)[0]
    assert ev.duration == pytest.approx((idx[-1] + 1 - idx[0]) / n)
    assert ev.onset == pytest.approx(idx[0] / n)


def test_bad_levels_are_user_errors(base):
    with pytest.raises(UserError):
        family_config(base, 0.0)
    with pytest.raises(UserError):
        level_for_duration(base, -1)
