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
    ("snan-3x3", ["astro.tau_ca_s=0.0012", "synapse.w_inh=3", "decision.no_spike=stay"]),
    ("snan-3x3", ["stdp.mode=window", "synapse.init=truncate", "synapse.w_inh=4"]),
    # edge cases of the closed forms and event loops
    ("snan-3x3", ["neuron.t_ref_ms=0", "stdp.mode=window"]),
    ("snan-3x3", ["input.p=1.0"]),
    ("snan-3x3", ["neuron.v_rest=-1.0", "neuron.v_reset=-2.0", "neuron.i_bias=0.05"]),
    ("snan-3x3", ["input.dt_ms=0.5", "input.t_stim_ms=500", "astro.tau_ca_s=0.001"]),
    ("snan-3x3", ["neuron.refractory=integrate", "neuron.t_ref_ms=5", "synapse.w_inh=2"]),
    ("snan-3x3", ["stdp.target=chosen"]),
    ("snan-3x3", ["stdp.target=chosen", "stdp.mode=window"]),
    ("snan-3x3", ["stdp.target=depress_others"]),
    ("snan-3x3", ["stdp.target=depress_others", "stdp.mode=window"]),
    ("snan-3x3", ["stdp.target=normalize"]),
    ("snan-3x3", ["stdp.target=normalize", "stdp.mode=window", "stdp.pairing=nearest"]),
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


def _one_update(target, w_row, dw, chosen, k=1.5, w_min=0.001, w_max=1.0):
    """The kernel's window update on one cell with 3 lanes; returns the new weights."""
    w = np.zeros((1, 4))
    w[0, :3] = w_row
    K.apply_window_stdp(w, 0, np.array([0, 1, 2, 0]), 3, np.array(list(dw) + [0.0]),
                        chosen, K.TARGET_CODES[target], k, w_min, w_max)
    return w[0, :3]


def test_window_update_targets():
    w, dw = [0.6, 0.7, 0.5], [0.1, 0.2, -0.05]
    np.testing.assert_allclose(_one_update("all", w, dw, 1), [0.7, 1.0, 0.45])
    np.testing.assert_allclose(_one_update("chosen", w, dw, 1), [0.6, 1.0, 0.5])
    np.testing.assert_allclose(_one_update("depress_others", w, dw, 1), [0.5, 1.0, 0.45])
    # normalize: "all", then scaled back to the row sum before the update (1.8)
    new = _one_update("normalize", w, dw, 0, k=1.0)
    assert new.sum() == pytest.approx(1.8)
    np.testing.assert_allclose(new, np.array([0.7, 0.9, 0.45]) * 1.8 / 2.05)
    # the winner's share grows even when every lane was potentiated (k = 1.5)
    up = _one_update("normalize", w, [0.1, 0.1, 0.1], 0)
    assert up.sum() == pytest.approx(1.8)
    assert up[0] > 0.6 and up[1] < 0.7
    # no lane chosen (-1): depress_others depresses every lane
    np.testing.assert_allclose(_one_update("depress_others", w, dw, -1), [0.5, 0.5, 0.45])


@pytest.mark.parametrize("target", ["depress_others", "normalize"])
def test_python_window_loop_matches_kernel_for_target(target):
    """The Python window loop (any back-end) applies the same update as the numba trial
    loop: a software back-end run gives the kernel's weights."""
    cfg = load_config(preset="snan-3x3", overrides=[f"stdp.target={target}",
                                                     "stdp.mode=window", "grid.max_steps=25"])
    env = environment(cfg)
    rng = np.random.default_rng(5)
    w0 = np.where(env.neighbour_table() >= 0, rng.uniform(0.5, 0.8, (9, 4)), 0.0)
    kern = run_trial(env, cfg, 0, 8, seed=4, weights=w0, engine="fast")
    back = SoftwareSynapses(w0, cfg.stdp.w_min, cfg.stdp.w_max,
                            normalize=target == "normalize")
    py = run_trial(env, cfg, 0, 8, seed=4, backend=back, engine="fast")
    assert np.array_equal(kern.path, py.path)
    np.testing.assert_allclose(kern.weights, py.weights, rtol=0, atol=1e-12)
    assert not np.allclose(kern.weights, w0)
