"""Single-neuron and astrocyte behaviour of the reference equations on crafted inputs."""

import math

import numpy as np
import pytest

from snan_hil.host.config import load_config
from snan_hil.host.snan_reference import lif_step, reference_window
from snan_hil.host.state import NetworkState


def _first_crossing(current, thr, alpha):
    """Analytic first step n with current*(1-alpha^n)/(1-alpha) > thr (from v = 0)."""
    n = 1
    while current * (1 - alpha ** n) / (1 - alpha) <= thr:
        n += 1
    return n


@pytest.mark.parametrize("current", [0.1, 0.3, 2.0])
def test_lif_threshold_reset_and_clamped_refractory(current):
    cfg = load_config(preset="snan-3x3")
    alpha = math.exp(-1 / 150)
    v, ref, spikes = 0.0, 0, []
    trace = []
    for t in range(400):
        v, ref, s = lif_step(v, ref, current, 7.0, cfg, alpha)
        trace.append(v)
        if s:
            spikes.append(t)
    n1 = _first_crossing(current, 7.0, alpha)
    assert spikes[0] == n1 - 1
    # after a spike: 40 steps held at reset (input ignored), then the same climb again
    assert all(trace[spikes[0] + k] == 0.0 for k in range(1, 41))
    assert spikes[1] - spikes[0] == 40 + n1
    assert all(x <= 7.0 for x in trace)


def test_lif_integrate_mode_spikes_right_after_refractoriness():
    cfg = load_config(preset="snan-3x3", overrides=["neuron.refractory=integrate"])
    alpha = math.exp(-1 / 150)
    v, ref, spikes = 0.0, 0, []
    for t in range(200):
        v, ref, s = lif_step(v, ref, 2.0, 7.0, cfg, alpha)
        if s:
            spikes.append(t)
    # with input 2.0 per step v passes 7 within 4 steps, i.e. during refractoriness
    assert spikes[1] - spikes[0] == 41


def test_lif_subthreshold_bias_never_fires():
    cfg = load_config(preset="snan-3x3")
    alpha = math.exp(-1 / 150)
    v, ref = 0.0, 0
    for _ in range(5000):
        v, ref, s = lif_step(v, ref, 0.02, 7.0, cfg, alpha)
        assert not s
    assert v == pytest.approx(0.02 / (1 - alpha), rel=1e-6)   # ~3.0 < 7


def _window(cfg, ca0, spikes=None, w=0.65):
    """Agent on cell 4 of 3x3; candidate 1 gets astrocyte state ca0 (y = 0, G = 0)."""
    st = NetworkState.fresh(cfg)
    st.ca[1] = ca0
    steps = cfg.window_steps
    if spikes is None:
        spikes = np.zeros(steps, dtype=bool)
        spikes[::7] = True
    cands = [1, 3, 5, 7]
    drive = np.where(spikes[:, None], w, 0.0) * np.ones((1, 4))
    res = reference_window(st, cfg, 4, cands, spikes, drive, record=True)
    return res, st


def test_astrocyte_lowers_interneuron_threshold_only_above_ca_thr():
    cfg = load_config(preset="snan-10x10", overrides=["grid.rows=3", "grid.cols=3"])
    thr = cfg.astro.ca_thr
    above, st = _window(cfg, thr + 0.05)
    assert st.ca[1] > thr                      # tau_Ca = 22 s: still above after 1 s
    below, _ = _window(cfg, thr - 0.05)
    at, _ = _window(cfg, thr)                  # H(0) = 0 and Ca only decays from here
    inter_above = [t for t, c in above.inter_spikes if c == 1]
    # bias-only interneuron with lowered threshold 7/6 fires tonically:
    alpha = math.exp(-1 / 150)
    n_low = _first_crossing(0.02, 7.0 / 6.0, alpha)
    assert inter_above[0] == n_low - 1
    assert np.all(np.diff(inter_above) == n_low + 40)
    assert not [1 for t, c in below.inter_spikes if c == 1]
    assert not [1 for t, c in at.inter_spikes if c == 1]
    # its motor neuron is silenced; the other candidates are unaffected
    assert above.counts[0] == 0 and below.counts[0] > 0
    assert list(above.counts[1:]) == list(below.counts[1:])


def test_without_astrocytes_calcium_is_ignored():
    cfg = load_config(preset="snan-10x10", overrides=["grid.rows=3", "grid.cols=3",
                                                      "astro.enabled=false"])
    res, _ = _window(cfg, 5.0)
    assert not [1 for t, c in res.inter_spikes if c == 1]
    assert res.counts[0] > 0


def test_single_input_spike_does_not_reach_glutamate_threshold():
    cfg = load_config(preset="snan-3x3")
    one = np.zeros(cfg.window_steps, dtype=bool)
    one[10] = True
    _, st = _window(cfg, 0.0, spikes=one)
    assert st.g[4] == pytest.approx(0.2 * 0.999 ** 989)   # k_n once, then decay
    assert st.ca[4] == 0.0                                 # J never switched on
    two = one.copy()
    two[12] = True
    _, st2 = _window(cfg, 0.0, spikes=two)
    assert st2.ca[4] > 0.0
    assert np.all(st2.ca[[0, 1, 2, 3, 5, 6, 7, 8]] == 0.0)  # only the occupied cell


def test_calcium_pulse_duration_follows_tau_and_a():
    """Idle astrocyte after one 1 s visit: suppression lasts ~5-10 s for the 3x3 values
    and ~100 s for the 10x10 values (tau_Ca in seconds), as the paper's text says."""
    durations = {}
    for preset in ("snan-3x3", "snan-10x10"):
        cfg = load_config(preset=preset)
        a = cfg.astro
        tau, dt = a.tau_ca_ms, 1.0
        g = ca = y = 0.0
        above = []
        for t in range(200_000):
            s = 1.0 if (t < 1000 and t % 7 == 0) else 0.0
            g = g + dt * (-a.alpha_n_per_ms * g + a.k_n * s)
            j = a.a if g > a.g_thr else 0.0
            ca, y = ca + dt * y, y + dt * (j - 2 * tau * y - ca) / tau ** 2
            if ca > a.ca_thr:
                above.append(t)
        durations[preset] = (above[0], above[-1])
    on3, off3 = durations["snan-3x3"]
    on10, off10 = durations["snan-10x10"]
    assert 3_000 < off3 - on3 < 10_000
    assert 80_000 < off10 - on10 < 130_000
    assert on3 < 1_500 and on10 < 4_000
