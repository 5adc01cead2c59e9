"""The crossbar synapse back-end: ADC codes back to weights, batch vs per-spike reads, fixed
weights during launches, fingerprints."""

import numpy as np
import pytest

from snan_hil.calibration.layout import LayoutError
from snan_hil.calibration.weights_io import load_weight_set
from snan_hil.host.agent import environment, synapse_tables
from snan_hil.host.hil.backend import CrossbarSynapses, FixedWeightsError
from snan_hil.host.hil.runner import (check_layout, layout_fingerprint, run_scenario,
                                      weights_fingerprint)
from snan_hil.host.hil.testing import make_weights, program_set, small_hil_config
from snan_hil.tools.ports import open_client


@pytest.fixture(scope="module")
def chip(tmp_path_factory, module_mcu):
    d = tmp_path_factory.mktemp("hilchip")
    hil = small_hil_config(max_steps=15)
    wpath = make_weights(d / "w.npz", sets=2, cycles=2, hil=hil)
    client = open_client("emu", state_file=str(d / "chip.npz"), seed=0, mcu=module_mcu)
    layout = program_set(client, wpath, 0, d / "layout.json")
    w, _ = load_weight_set(wpath, 0)
    env = environment(hil.model)
    nbr, _ = synapse_tables(env, hil.model)
    yield {"client": client, "layout": layout, "w": w, "wpath": wpath, "hil": hil, "nbr": nbr}
    client.close()


def _spikes(seed, p=0.15, steps=1000):
    return np.random.default_rng(seed).random(steps) < p


def _two_row_neuron(layout):
    return next(g["pre"] for g in layout.groups() if len(g["rows"]) == 2)


def test_drive_converts_adc_codes_to_programmed_weights(chip):
    layout, nbr, w = chip["layout"], chip["nbr"], chip["w"]
    back = CrossbarSynapses(chip["client"], layout, nbr)
    final_w = {(s.pre, s.post): layout.weight_map.weight(s.final_s, clip=False)
               for s in layout.synapses}
    for pre in (0, 14, _two_row_neuron(layout), 35):
        dirs = [d for d in range(4) if nbr[pre, d] >= 0]
        spikes = _spikes(pre)
        drive = back.drive(pre, dirs, spikes)
        assert drive.shape == (1000, len(dirs))
        assert np.all(drive[~spikes] == 0.0)              # input only at input spikes
        assert np.all(drive[spikes] > 0.0)
        for k, d in enumerate(dirs):
            post = int(nbr[pre, d])
            reads = drive[spikes, k]
            # one read: within a few % of the conductance measured after programming
            assert np.all(np.abs(reads - final_w[(pre, post)]) < 0.03)
            # mean of ~150 reads: within calibration error of the programmed (target) weight
            assert abs(reads.mean() - final_w[(pre, post)]) < 0.01
            assert abs(reads.mean() - w[pre, post]) < 0.04
            assert reads.std() > 0.0                        # every read has its own error
    assert back.stats.requests == 4                         # one round trip per window


def test_batch_and_per_spike_reads_have_the_same_statistics(chip):
    layout, nbr = chip["layout"], chip["nbr"]
    batch = CrossbarSynapses(chip["client"], layout, nbr, mode="batch")
    single = CrossbarSynapses(chip["client"], layout, nbr, mode="per_spike")
    pres = (7, _two_row_neuron(layout))
    for pre in pres:
        dirs = [d for d in range(4) if nbr[pre, d] >= 0]
        for rep in range(2):
            s = _spikes(100 * pre + rep)
            batch.drive(pre, dirs, s)
            single.drive(pre, dirs, s)
    sb, sp = batch.stats.synapse_stats(), single.stats.synapse_stats()
    assert sb.keys() == sp.keys() and len(sb) >= 6
    for key in sb:
        nb, mb, db = sb[key]
        ns, ms, ds = sp[key]
        assert nb == ns > 200
        se = np.sqrt(db ** 2 / nb + ds ** 2 / ns)
        assert abs(mb - ms) < 4 * se + 1e-3, key
        assert 0.6 < db / ds < 1.6, key
    assert single.stats.requests == single.stats.codes_read > 100 * batch.stats.requests


def test_batch_and_per_spike_launches_agree(chip):
    kw = dict(launches=3, seed=5, client=chip["client"], layout=chip["layout"])
    b = run_scenario("hw_astro", chip["w"], chip["hil"], mode="batch", **kw)
    p = run_scenario("hw_astro", chip["w"], chip["hil"], mode="per_spike", **kw)
    assert p.read_stats["requests"] > 50 * b.read_stats["requests"]
    same = sum(x == y for x, y in zip(b.path_lengths, p.path_lengths))
    assert same >= 2, (b.path_lengths, p.path_lengths)


def test_weights_are_fixed_during_launches(chip, module_mcu):
    client = chip["client"]
    back = CrossbarSynapses(client, chip["layout"], chip["nbr"])
    with pytest.raises(FixedWeightsError):
        back.apply_update(0, [1, 3], np.array([0.1, 0.1]))
    before = client.status().pulses_applied
    res = run_scenario("hw_noastro", chip["w"], chip["hil"], launches=2, seed=2,
                       client=client, layout=chip["layout"], baud=115200)
    assert client.status().pulses_applied == before         # no write pulse in a launch
    launch = res.launches[0]
    assert launch.decisions == launch.steps > 0
    assert launch.spikes > 100 * launch.decisions / 2
    # board clock covers the UART time of the launch's bytes plus time on the board
    assert launch.virtual_us > launch.wire_us > 0
    # array energy from CLOCK: the model integrates it; the C firmware cannot measure it (0)
    assert launch.energy_j > 0 if module_mcu == "model" else launch.energy_j == 0.0
    # programmed weights come back in the agent's [n_cells, 4] layout (up, down, left, right)
    assert back.weights()[0, 3] == pytest.approx(chip["w"][0, 1], abs=1e-12)   # right
    assert back.weights()[0, 1] == pytest.approx(chip["w"][0, 6], abs=1e-12)   # down
    assert back.weights()[0, 0] == 0.0 and back.weights()[0, 2] == 0.0


def test_fingerprint_guards_the_programmed_set(chip):
    layout, w = chip["layout"], chip["w"]
    grid = tuple(layout.grid)
    assert layout_fingerprint(layout) == weights_fingerprint(w, grid)
    assert check_layout(layout, w, grid, port="emu") == weights_fingerprint(w, grid)
    assert weights_fingerprint(w + 1e-9 * (w > 0), grid) == weights_fingerprint(w, grid)
    other = w.copy()
    other[0, 1] += 1e-3
    with pytest.raises(LayoutError, match="other weights"):
        check_layout(layout, other, grid, port="emu", weights_path="w.npz", set_index=1)
    w1, _ = load_weight_set(chip["wpath"], 1)
    with pytest.raises(LayoutError, match="program-weights w.npz --weight-set 1"):
        check_layout(layout, w1, grid, port="emu", weights_path="w.npz", set_index=1)


def test_software_and_hardware_launches_share_random_streams(chip):
    """Same seed and set: software launches are reproducible, and the hardware run uses the
    same trial indices (paired design)."""
    hil, w = chip["hil"], chip["w"]
    a = run_scenario("sw_astro", w, hil, set_index=1, launches=3, seed=9)
    b = run_scenario("sw_astro", w, hil, set_index=1, launches=3, seed=9)
    assert a.path_lengths == b.path_lengths
    assert [r.trial for r in a.launches] == [1000, 1001, 1002]
    c = run_scenario("sw_noastro", w, hil, set_index=1, launches=3, seed=9)
    assert [r.trial for r in c.launches] == [1000, 1001, 1002]
