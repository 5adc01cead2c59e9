"""The numba kernels reproduce the plain reference implementation: same spike counts,
same trajectories, same (full engine: bit-identical) weights and astrocyte states."""

import numpy as np
import pytest

from snan_hil.host import snan_kernel as K
from snan_hil.host.agent import SoftwareSynapses, environment, run_trial
from snan_hil.host.config import load_config
from snan_hil.host.rng import WindowStream
from snan_hil.host.snan_reference import reference_window
from snan_hil.host.state import NetworkState

CASES = [
    ("snan-3x3", []),
    ("snan-3x3", ["astro.enabled=false"]),
    ("snan-3x3", ["stdp.mode=window", "stdp.pairing=nearest", "neuron.refractory=integrate"]),
    ("snan-3x3", ["astro.tau_ca_unit=ms", "synapse.w_inh=3", "decision.no_spike=stay"]),
    ("snan-3x3", ["stdp.mode=window", "synapse.init=truncate", "synapse.w_inh=4"]),
    # edge cases of the closed forms and event loops
    ("snan-3x3", ["neuron.t_ref_ms=0", "stdp.mode=window"]),
    ("snan-3x3", ["input.p=1.0"]),
    ("snan-3x3", ["neuron.v_rest=-1.0", "neuron.v_reset=-2.0", "neuron.i_bias=0.05"]),
    ("snan-3x3", ["input.dt_ms=0.5", "input.t_stim_ms=500", "astro.tau_ca=1",
                  "astro.tau_ca_unit=ms"]),
    ("snan-3x3", ["neuron.refractory=integrate", "neuron.t_ref_ms=5", "synapse.w_inh=2"]),
    ("snan-3x3", ["stdp.target=chosen"]),
    ("snan-3x3", ["stdp.target=chosen", "stdp.mode=window"]),
]


@pytest.mark.parametrize("preset, overrides", CASES)
def test_trials_identical_in_all_engines(preset, overrides):
    cfg = load_config(preset=preset, overrides=overrides + ["grid.max_steps=30"])
    env = environment(cfg)
    for seed, (start, goal) in enumerate([(0, 8), (4, 2), (7, 3)]):
        ref = run_trial(env, cfg, start, goal, seed=seed, engine="reference")
        full = run_trial(env, cfg, start, goal, seed=seed, engine="full")
        fast = run_trial(env, cfg, start, goal, seed=seed, engine="fast")
        assert ref.steps >= 1
        for other in (full, fast):
            assert np.array_equal(ref.path, other.path)
            assert np.array_equal(ref.counts, other.counts)
            assert ref.success == other.success
        assert np.array_equal(ref.weights, full.weights)
        np.testing.assert_allclose(ref.weights, fast.weights, rtol=0, atol=1e-12)


def test_membrane_carry_over_reading_identical_in_full_engine():
    cfg = load_config(preset="snan-3x3", overrides=["neuron.reset_each_window=false",
                                                    "grid.max_steps=25"])
    env = environment(cfg)
    ref = run_trial(env, cfg, 0, 8, seed=5, engine="reference")
    full = run_trial(env, cfg, 0, 8, seed=5, engine="full")
    assert np.array_equal(ref.path, full.path) and np.array_equal(ref.counts, full.counts)


def test_10x10_trial_identical():
    cfg = load_config(preset="snan-10x10", overrides=["grid.max_steps=12"])
    env = environment(cfg)
    ref = run_trial(env, cfg, 44, 99, seed=2, engine="reference")
    fast = run_trial(env, cfg, 44, 99, seed=2, engine="fast")
    assert np.array_equal(ref.path, fast.path) and np.array_equal(ref.counts, fast.counts)


@pytest.mark.parametrize("preset", ["snan-3x3", "snan-10x10"])
def test_random_astrocyte_states_windows(preset):
    """Windows started from random astrocyte states (calcium crossing its threshold inside
    the window, glutamate switching off, idle gaps): counts, STDP changes and the end
    states of the fast engine agree with the reference."""
    cfg = load_config(preset=preset, overrides=["grid.rows=3", "grid.cols=3"])
    fp, ip, tab = K.pack_params(cfg, K.ENGINE_FAST)
    rng = np.random.default_rng(11)
    steps = cfg.window_steps
    stream = WindowStream(123)
    n_cross = 0
    for trial in range(40):
        st = NetworkState.fresh(cfg)
        thr = cfg.astro.ca_thr
        st.g[:] = rng.choice([0.0, 0.21, 0.5, 3.0], size=9)
        st.ca[:] = thr * rng.uniform(0.3, 2.0, size=9)
        st.y[:] = rng.normal(0, 2e-4 if preset == "snan-3x3" else 2e-5, size=9)
        gap = int(rng.integers(0, 2000))
        st.t_now = gap
        fst = st.copy()
        fst.t_astro[:] = 0
        w = rng.uniform(0.5, 0.8, size=4)
        spikes = stream.spikes(steps, cfg.input.p)
        drive = np.where(spikes[:, None], w[None, :], 0.0)
        # reference: step the idle gap for every astrocyte, then the window
        ref_st = st.copy()
        reference_window_gap(ref_st, cfg, gap)
        res = reference_window(ref_st, cfg, 4, [1, 3, 5, 7], spikes, drive, record=True)
        n_cross += len({c for _, c in res.inter_spikes if c in (1, 3, 5, 7)})
        counts = np.zeros(4, dtype=np.int64)
        dw = np.zeros(4)
        K.fast_window(fp, ip, tab, 4, np.array([1, 3, 5, 7]), 4, spikes, drive, gap,
                      fst.v_mot, fst.ref_mot, fst.v_int, fst.ref_int, fst.g, fst.ca, fst.y,
                      fst.t_astro, counts, dw)
        assert list(counts) == list(res.counts), trial
        np.testing.assert_allclose(dw, res.dw, rtol=1e-9, atol=1e-12)
        for arr in ("g", "ca", "y"):
            np.testing.assert_allclose(getattr(fst, arr)[[1, 3, 4, 5, 7]],
                                       getattr(ref_st, arr)[[1, 3, 4, 5, 7]],
                                       rtol=1e-8, atol=1e-13)
    assert n_cross > 10   # the crafted states really switch interneurons on


def reference_window_gap(st, cfg, gap):
    """Advance every astrocyte by ``gap`` idle steps with the reference equations."""
    a = cfg.astro
    tau = a.tau_ca_ms
    dt = cfg.input.dt_ms
    for i in (1, 3, 4, 5, 7):   # the cells the window touches
        g, ca, y = st.g[i], st.ca[i], st.y[i]
        for _ in range(gap):
            g = g + dt * (-a.alpha_n_per_ms * g + a.k_n * 0.0)
            j = a.a if g > a.g_thr else 0.0
            ca, y = ca + dt * y, y + dt * (j - 2.0 * tau * y - ca) / (tau * tau)
        st.g[i], st.ca[i], st.y[i] = g, ca, y


class ScaledSynapses(SoftwareSynapses):
    """A stand-in for a hardware back-end: 10 % weaker read-out, logs every call."""

    def __init__(self, w, w_min, w_max):
        super().__init__(w, w_min, w_max)
        self.calls = 0
        self.updates = 0

    def drive(self, pre, dirs, spikes):
        self.calls += 1
        return 0.9 * super().drive(pre, dirs, spikes)

    def apply_update(self, pre, dirs, dw):
        self.updates += 1
        super().apply_update(pre, dirs, dw)


@pytest.mark.parametrize("engine", ["fast", "full"])
def test_backend_seam_same_result_in_reference_and_kernels(engine):
    cfg = load_config(preset="snan-3x3", overrides=["stdp.mode=window", "grid.max_steps=40"])
    env = environment(cfg)
    rng = np.random.default_rng(3)
    w0 = np.where(env.neighbour_table() >= 0, rng.uniform(0.5, 0.8, (9, 4)), 0.0)
    b_ref = ScaledSynapses(w0, cfg.stdp.w_min, cfg.stdp.w_max)
    b_k = ScaledSynapses(w0, cfg.stdp.w_min, cfg.stdp.w_max)
    r1 = run_trial(env, cfg, 0, 8, seed=9, backend=b_ref, engine="reference")
    r2 = run_trial(env, cfg, 0, 8, seed=9, backend=b_k, engine=engine)
    assert np.array_equal(r1.path, r2.path) and np.array_equal(r1.counts, r2.counts)
    assert b_ref.calls == b_k.calls == r1.steps == b_k.updates
    np.testing.assert_allclose(r1.weights, r2.weights, atol=1e-12)
    # the back-end really changes the network's input: plain software weights differ
    plain = run_trial(env, cfg, 0, 8, seed=9, weights=w0, engine=engine)
    assert not np.array_equal(plain.counts[:1], r2.counts[:1]) or \
        not np.array_equal(plain.path, r2.path)
