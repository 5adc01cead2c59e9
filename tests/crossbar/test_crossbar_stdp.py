"""Memristive STDP windows from VTEAM (paper Fig. 2B/D procedure) and the dw(w, dt) lookup."""

import numpy as np
import pytest

from snan_hil.crossbar_model.vteam import VTEAM, VTEAMParams
from snan_hil.crossbar_model.vteam_stdp import (
    BiTriangularSpike,
    StdpLookup,
    pair_waveform,
    stdp_window,
)

DTS = np.arange(-40.0, 40.5, 0.5)


def test_single_spikes_are_subthreshold_but_pairs_are_not():
    spike = BiTriangularSpike()
    t = np.linspace(-5, 40, 9001)
    assert np.max(np.abs(spike(t))) < 0.6
    _, v = pair_waveform(spike, 3.0)
    assert np.max(v) > 0.6
    with pytest.raises(ValueError, match="below the switching thresholds"):
        stdp_window(0.5, [1.0], BiTriangularSpike(a_pos=0.65))


def test_a_lone_spike_does_not_change_the_device():
    m = VTEAM()
    tb, vb = BiTriangularSpike().breakpoints()
    assert float(m.apply_waveform(1e-9, tb * 1e-3, vb)) == 1e-9


@pytest.mark.parametrize("w0", [0.1, 0.3, 0.5, 0.7, 0.9])
def test_window_shape_potentiation_after_depression_before(w0):
    dw = stdp_window(w0, DTS)
    pos, neg = dw[DTS > 0], dw[DTS < 0]
    assert np.all(pos >= 0) and np.max(pos) > 0
    assert np.all(neg <= 0) and np.min(neg) < 0
    # decays with |dt| beyond the peak, and vanishes once the lobes no longer overlap
    peak_p = int(np.argmax(pos))
    assert np.all(np.diff(pos[peak_p:]) <= 1e-15)
    peak_n = int(np.argmin(neg))
    assert np.all(np.diff(neg[:peak_n + 1]) <= 1e-15)
    assert dw[np.argmin(np.abs(DTS - 35))] == 0.0 and dw[np.argmin(np.abs(DTS + 35))] == 0.0
    assert pos[DTS[DTS > 0] == 15.0][0] < 0.2 * np.max(pos)


def test_window_depends_on_the_initial_state():
    dw = stdp_window(np.array([0.1, 0.5, 0.9]), np.array([2.0, -2.0]))
    # conductance changes scale with G (exponential memristance): larger at higher weights
    assert dw[0, 0] < dw[1, 0] < dw[2, 0]
    assert dw[0, 1] > dw[1, 1] > dw[2, 1]
    # at the ON bound no further potentiation is possible
    assert stdp_window(1.0, [2.0])[0] == pytest.approx(0.0, abs=1e-12)


def test_reversed_orientation_mirrors_the_window():
    a = stdp_window(0.5, [3.0, -3.0])
    b = stdp_window(0.5, [3.0, -3.0], orientation=-1)
    assert np.sign(a[0]) == -np.sign(b[0]) and np.sign(a[1]) == -np.sign(b[1])


def test_lookup_reproduces_the_direct_computation():
    look = StdpLookup.build(dt_step_ms=0.5)
    assert look.table.shape == (101, len(look.dt_grid_ms))
    w = np.array([0.0, 0.37, 0.5, 0.81, 1.0])
    dt = np.array([2.0, -2.0, 7.5, -13.0, 4.0])
    direct = np.array([stdp_window(wi, [di])[0] for wi, di in zip(w, dt)])
    got = look.delta_w(w, dt)
    assert np.allclose(got, direct, rtol=0.05, atol=1e-7)
    assert look.delta_w(0.5, 1000.0) == 0.0 and look.delta_w(0.5, -1000.0) == 0.0
    assert np.all((look.apply(np.array([0.0, 1.0]), 2.0) >= 0) & (look.apply(np.array([0.0, 1.0]), 2.0) <= 1))


def test_lookup_scaling_is_recorded(tmp_path):
    look = StdpLookup.build(dt_step_ms=1.0)
    norm = look.normalized_to(0.04)
    assert np.max(norm.delta_w(np.full_like(norm.dt_grid_ms, 0.5), norm.dt_grid_ms)) == pytest.approx(0.04)
    assert norm.gain > 1
    path = tmp_path / "lut.npz"
    norm.save(str(path))
    back = StdpLookup.load(str(path))
    assert back.gain == norm.gain and np.array_equal(back.table, norm.table)
    assert back.meta["spike"]["a_pos"] == BiTriangularSpike().a_pos


def test_other_bounds_give_a_weaker_but_same_shaped_window():
    narrow = stdp_window(0.5, [2.0, -2.0])
    wide = stdp_window(0.5, [2.0, -2.0], params=VTEAMParams.paper("window-40nm"))
    assert np.all(np.sign(narrow) == np.sign(wide))
    assert np.all(np.abs(wide) < np.abs(narrow))
