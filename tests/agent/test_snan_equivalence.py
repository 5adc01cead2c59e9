"""The trial kernel reproduces the plain reference implementation: same spike counts, same
trajectories, weights and network states within rounding (1e-12), in every reading."""

import numpy as np
import pytest

from snan_hil.host import snan_kernel as K
from snan_hil.host.agent import SoftwareSynapses, environment, run_trial
from snan_hil.host.config import load_config
from snan_hil.host.kernel_params import kernel_params
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


#: state carried across windows (neuron.reset_each_window=false) in combination with the
#: other readings: the interneurons and motor neurons of every cell keep their potentials
#: and refractory counters, idle cells are caught up event by event
CARRIED = [["neuron.reset_each_window=false", *o] for o in (
    [],
    ["astro.enabled=false"],
    ["neuron.refractory=integrate"],
    ["stdp.mode=window", "stdp.pairing=nearest", "synapse.w_inh=50"],
    ["stdp.mode=window", "stdp.target=normalize", "synapse.w_inh=3"],
    ["stdp.target=depress_others", "decision.no_spike=stay"],
    ["astro.tau_ca_s=0.0012", "synapse.w_inh=3", "stdp.target=chosen"],
    ["neuron.i_bias=0.06"],                 # interneurons fire on their bias alone
    ["neuron.i_bias=0.06", "neuron.refractory=integrate", "neuron.t_ref_ms=5"],
    ["neuron.i_bias=-0.01", "synapse.init=truncate"],
    ["neuron.v_rest=-1.0", "neuron.v_reset=-2.0", "neuron.i_bias=0.05"],
    ["input.dt_ms=0.5", "input.t_stim_ms=500", "astro.tau_ca_s=0.001"],
    ["neuron.t_ref_ms=0", "stdp.mode=window"],
    ["input.p=1.0"],
    ["grid.walls=bump"],
)]
CASES += [("snan-3x3", o) for o in CARRIED]


def _same_trial(ref, fast):
    assert np.array_equal(ref.path, fast.path)
    assert np.array_equal(ref.counts, fast.counts)
    assert ref.success == fast.success
    np.testing.assert_allclose(ref.weights, fast.weights, rtol=0, atol=1e-12)


@pytest.mark.parametrize("preset, overrides", CASES)
def test_trials_identical_in_kernel_and_reference(preset, overrides):
    cfg = load_config(preset=preset, overrides=overrides + ["grid.max_steps=30"])
    env = environment(cfg)
    for seed, (start, goal) in enumerate([(0, 8), (4, 2), (7, 3)]):
        ref = run_trial(env, cfg, start, goal, seed=seed, engine="reference")
        fast = run_trial(env, cfg, start, goal, seed=seed, engine="fast")
        assert ref.steps >= 1
        _same_trial(ref, fast)


@pytest.mark.parametrize("walls, carried", [("prune", False), ("bump", False),
                                             ("prune", True), ("bump", True)])
def test_maze_trials_identical(walls, carried):
    """Mazes (walls pruning synapses, or synapses kept and the agent bumping into the wall),
    in both readings of the membrane reset."""
    from snan_hil.host.experiments.mazes import maze_task
    cfg = load_config(preset="snan-3x3", overrides=[
        "grid.rows=4", "grid.cols=4", "grid.max_steps=25", f"grid.walls={walls}",
        f"neuron.reset_each_window={str(not carried).lower()}"])
    for seed in range(3):
        env, start, goals = maze_task(4, 4, 0.3, 1, np.random.default_rng(seed))
        ref = run_trial(env, cfg, start, goals, seed=seed, engine="reference")
        fast = run_trial(env, cfg, start, goals, seed=seed, engine="fast")
        _same_trial(ref, fast)


def test_carried_state_changes_the_trials():
    """The carried reading is a different model (else the cases above test nothing new)."""
    base = load_config(preset="snan-3x3", overrides=["grid.max_steps=30"])
    carried = base.replace(**{"neuron.reset_each_window": False})
    env = environment(base)
    differ = sum(not np.array_equal(run_trial(env, base, 0, 8, seed=s).counts[:3],
                                    run_trial(env, carried, 0, 8, seed=s).counts[:3])
                 for s in range(6))
    assert differ >= 3


@pytest.mark.parametrize("carried", [False, True])
def test_10x10_trial_identical(carried):
    cfg = load_config(preset="snan-10x10", overrides=[
        "grid.max_steps=12", f"neuron.reset_each_window={str(not carried).lower()}"])
    env = environment(cfg)
    ref = run_trial(env, cfg, 44, 99, seed=2, engine="reference")
    fast = run_trial(env, cfg, 44, 99, seed=2, engine="fast")
    _same_trial(ref, fast)


def _random_states(cfg, rng, preset, carried):
    st = NetworkState.fresh(cfg)
    thr = cfg.astro.ca_thr
    st.g[:] = rng.choice([0.0, 0.21, 0.5, 3.0], size=9)
    st.ca[:] = thr * rng.uniform(0.3, 2.0, size=9)
    st.y[:] = rng.normal(0, 2e-4 if preset == "snan-3x3" else 2e-5, size=9)
    if carried:
        n = cfg.neuron
        r = cfg.ref_steps
        st.v_int[:] = rng.uniform(n.v_rest - 3.0, n.v_thr_inter / (1 + cfg.astro.eta), 9)
        st.v_mot[:] = rng.uniform(n.v_rest - 30.0, n.v_thr_motor, 9)
        for v, ref in ((st.v_int, st.ref_int), (st.v_mot, st.ref_mot)):
            hold = rng.random(9) < 0.3
            first = 0 if n.refractory == "integrate" else 1   # integrate: 0 = check at once
            ref[hold] = rng.integers(first, r + 1, size=int(hold.sum())) if r else 0
            if n.refractory == "clamp":
                v[hold & (ref > 0)] = n.v_reset
            else:   # integrate: a refractory neuron may sit above its threshold
                v[hold] += rng.uniform(0.0, 8.0, int(hold.sum()))
    return st


def _kernel_window(kp, st, w, spikes, t_now):
    """The kernel's window on the 3x3 grid's centre cell (candidates 1, 3, 5, 7, weights
    ``w``) from network state ``st`` (every cell up to date with step 0) at step t_now."""
    ts = K.new_trial_state(kp, 9, 1)
    for name in ("v_mot", "ref_mot", "v_int", "ref_int", "g", "ca", "y"):
        getattr(ts, name)[:] = getattr(st, name)
    ts.cands[:] = [1, 3, 5, 7]
    ts.wl[:] = w
    ts.flags[:] = spikes
    sp = np.flatnonzero(spikes)
    ts.sp[:sp.size] = sp
    ts.iv[K.IV_NS] = sp.size
    K.window(K.params_ref(kp), K.state_ref(ts), 4, 4, t_now, ts.no_drive, False)
    return ts


@pytest.mark.parametrize("preset, overrides", [
    ("snan-3x3", []), ("snan-10x10", []),
    ("snan-3x3", ["neuron.reset_each_window=false"]),
    ("snan-10x10", ["neuron.reset_each_window=false"]),
    ("snan-3x3", ["neuron.reset_each_window=false", "neuron.refractory=integrate",
                  "neuron.i_bias=0.05"]),
])
def test_windows_from_random_states(preset, overrides):
    """Windows started from random states after an idle gap (calcium crossing its threshold
    inside the window, glutamate switching off; with the carried reading also random
    potentials and refractory counters): counts, STDP changes and the end states of every
    cell the window touches agree with the reference."""
    cfg = load_config(preset=preset, overrides=["grid.rows=3", "grid.cols=3", *overrides])
    carried = not cfg.neuron.reset_each_window
    kp = kernel_params(cfg)
    rng = np.random.default_rng(11)
    steps = cfg.window_steps
    stream = WindowStream(123)
    touched = [1, 3, 4, 5, 7]
    n_cross = 0
    for trial in range(40):
        st = _random_states(cfg, rng, preset, carried)
        gap = int(rng.integers(0, 2000))
        w = rng.uniform(0.5, 0.8, size=4)
        spikes = stream.spikes(steps, cfg.input.p)
        drive = np.where(spikes[:, None], w[None, :], 0.0)
        # reference: step the idle gap for every cell, then the window
        ref_st = st.copy()
        reference_gap(ref_st, cfg, gap)
        res = reference_window(ref_st, cfg, 4, [1, 3, 5, 7], spikes, drive, record=True)
        n_cross += len({c for _, c in res.inter_spikes if c in (1, 3, 5, 7)})
        ts = _kernel_window(kp, st, w, spikes, gap)
        assert list(ts.counts) == list(res.counts), trial
        np.testing.assert_allclose(ts.dw, res.dw, rtol=1e-9, atol=1e-12)
        arrays = ["g", "ca", "y"] + (["v_int", "v_mot", "ref_int", "ref_mot"] if carried
                                     else [])
        for arr in arrays:
            np.testing.assert_allclose(getattr(ts, arr)[touched],
                                       getattr(ref_st, arr)[touched],
                                       rtol=1e-8, atol=1e-11, err_msg=f"{arr} {trial}")
        assert np.all(ts.t_cell[touched] == gap + steps)
    assert n_cross > 10   # the crafted states really switch interneurons on


def test_long_idle_gaps_with_the_state_carried():
    """Cells idle for up to 30 s with their calcium far above threshold: their interneurons
    fire tonically all the while and inhibit their motor neurons (the catch-up of the
    carried reading); the window after it agrees with the reference."""
    cfg = load_config(preset="snan-10x10", overrides=["grid.rows=3", "grid.cols=3",
                                                      "neuron.reset_each_window=false"])
    kp = kernel_params(cfg)
    rng = np.random.default_rng(7)
    steps = cfg.window_steps
    stream = WindowStream(5)
    touched = [1, 3, 4, 5, 7]
    for trial in range(4):
        st = _random_states(cfg, rng, "snan-10x10", True)
        st.ca[:] = cfg.astro.ca_thr * rng.uniform(5.0, 50.0, size=9)
        st.y[:] = 0.0
        gap = int(rng.integers(10_000, 30_000))
        spikes = stream.spikes(steps, cfg.input.p)
        w = rng.uniform(0.5, 0.8, size=4)
        drive = np.where(spikes[:, None], w[None, :], 0.0)
        ref_st = st.copy()
        reference_gap(ref_st, cfg, gap)
        res = reference_window(ref_st, cfg, 4, [1, 3, 5, 7], spikes, drive)
        ts = _kernel_window(kp, st, w, spikes, gap)
        assert list(ts.counts) == list(res.counts), trial
        for arr in ("ca", "y", "v_int", "v_mot", "ref_int", "ref_mot"):
            np.testing.assert_allclose(getattr(ts, arr)[touched],
                                       getattr(ref_st, arr)[touched],
                                       rtol=1e-8, atol=1e-11, err_msg=f"{arr} {trial}")


def reference_gap(st, cfg, gap):
    """Advance every cell by ``gap`` idle steps with the reference equations (astrocytes
    only when the potentials are reset every window)."""
    if gap == 0:
        return
    if cfg.neuron.reset_each_window:
        a = cfg.astro
        tau = a.tau_ca_ms
        dt = cfg.input.dt_ms
        for i in range(cfg.n_cells):
            g, ca, y = st.g[i], st.ca[i], st.y[i]
            for _ in range(gap):
                g = g + dt * (-a.alpha_n_per_ms * g + a.k_n * 0.0)
                j = a.a if g > a.g_thr else 0.0
                ca, y = ca + dt * y, y + dt * (j - 2.0 * tau * y - ca) / (tau * tau)
            st.g[i], st.ca[i], st.y[i] = g, ca, y
        return
    idle = cfg.replace(**{"input.t_stim_ms": gap * cfg.input.dt_ms})
    reference_window(st, idle, 0, [], np.zeros(gap, dtype=bool), np.zeros((gap, 0)))


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


class SmearedSynapses(ScaledSynapses):
    """A back-end whose drive also reaches the step after each spike (drive off the input
    spikes: the kernel's per-lane event path)."""

    def drive(self, pre, dirs, spikes):
        d = super().drive(pre, dirs, spikes)
        out = d.copy()
        out[1:] += 0.5 * d[:-1]
        return out


@pytest.mark.parametrize("overrides", [[], ["neuron.reset_each_window=false"]])
def test_drive_off_the_input_spikes(overrides):
    cfg = load_config(preset="snan-3x3", overrides=["stdp.mode=window", "grid.max_steps=30",
                                                     *overrides])
    env = environment(cfg)
    rng = np.random.default_rng(4)
    w0 = np.where(env.neighbour_table() >= 0, rng.uniform(0.4, 0.6, (9, 4)), 0.0)
    for seed in range(3):
        r1 = run_trial(env, cfg, 0, 8, seed=seed, engine="reference",
                       backend=SmearedSynapses(w0, cfg.stdp.w_min, cfg.stdp.w_max))
        r2 = run_trial(env, cfg, 0, 8, seed=seed, engine="fast",
                       backend=SmearedSynapses(w0, cfg.stdp.w_min, cfg.stdp.w_max))
        _same_trial(r1, r2)


@pytest.mark.parametrize("engine", ["fast"])
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
    p = K.params_ref(kernel_params(load_config(preset="snan-3x3", overrides=[
        f"stdp.target={target}", f"stdp.k={k}", f"stdp.w_min={w_min}", f"stdp.w_max={w_max}"])))
    w = np.zeros((1, 4))
    w[0, :3] = w_row
    upd = np.zeros(4)
    K.window_changes(p, np.array(list(dw) + [0.0]), 3, chosen, upd)
    K.apply_window_stdp(p, w, 0, np.array([0, 1, 2, 0]), 3, upd, chosen)
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
