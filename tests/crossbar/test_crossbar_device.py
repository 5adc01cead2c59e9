"""YSZ 1T1R device physics: sourced config, thresholds, monotonic response, bounds, noise models."""

import math

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from snan_hil.crossbar_model import ArrayConfig, CrossbarArray, DeviceConfigError
from snan_hil.crossbar_model.config import sourced_leaves
from snan_hil.crossbar_model.device import conductance_of_state, pulse_response
from snan_hil.common.polarity import Polarity

CFG = ArrayConfig.default()
IDEAL = CFG.ideal()
MID = math.sqrt(CFG.conductance.usable_min_s * CFG.conductance.usable_max_s)


def _yaml_tree():
    import importlib.resources
    from snan_hil.config.loader import read_yaml
    return read_yaml(importlib.resources.files("snan_hil").joinpath("configs", "device-ysz.yaml"))


def test_every_yaml_parameter_has_a_source_or_assumption():
    leaves = sourced_leaves(_yaml_tree())
    assert len(leaves) >= 30
    for key, leaf in leaves.items():
        text = leaf.get("source") or leaf.get("assumption")
        assert isinstance(text, str) and len(text) > 15, key


def test_usable_range_matches_the_paper_mean_resistance():
    # weight 0.65 (paper's mean initial weight) mapped linearly onto the usable range -> ~1.5 kOhm
    c = CFG.conductance
    g = c.usable_min_s + 0.65 * (c.usable_max_s - c.usable_min_s)
    assert 1.0 / g == pytest.approx(1500.0, rel=0.02)
    assert c.g_min_s < c.usable_min_s and c.usable_max_s < c.g_max_s


def test_bad_config_files_give_one_line_user_errors(tmp_path):
    tree = _yaml_tree()
    del tree["read_noise"]["relative_sigma"]["assumption"]
    bad = tmp_path / "bad.yaml"
    bad.write_text(json.dumps(tree))   # JSON is YAML 1.2
    with pytest.raises(DeviceConfigError, match="read_noise.relative_sigma"):
        ArrayConfig.from_yaml(bad)
    tree = _yaml_tree()
    tree["switching"]["v_threshold_v"]["value"] = 0.2
    bad.write_text(json.dumps(tree))   # JSON is YAML 1.2
    with pytest.raises(DeviceConfigError,
                       match=r"switching.v_threshold_v: must be >= 0.3, got 0.2"):
        ArrayConfig.from_yaml(bad)
    with pytest.raises(DeviceConfigError, match="cannot read"):
        ArrayConfig.from_yaml(tmp_path / "missing.yaml")
    bad.write_text("a: [1, 2")
    with pytest.raises(DeviceConfigError, match="not valid YAML"):
        ArrayConfig.from_yaml(bad)


def _fresh(cfg=CFG, seed=0, g=MID):
    a = CrossbarArray(cfg.with_overrides({"stuck.fraction": 0.0}), seed=seed)
    for r in range(a.rows):
        for c in range(a.cols):
            a.set_conductance(r, c, g)
    return a


def test_no_state_change_at_or_below_0_3_v_even_for_long_pulses():
    a = _fresh()
    before = a.conductance()
    for pol in (Polarity.SET, Polarity.RESET):
        for v in (0.0, 0.1, 0.2, 0.3):
            for r in range(a.rows):
                a.apply_pulse(r, r % a.cols, v, pol, 1.0)  # one second, far longer than any write
    assert np.array_equal(a.conductance(), before)


def test_ten_thousand_reads_do_not_move_any_cell():
    a = CrossbarArray(seed=4)
    before = a.conductance()
    v = np.full(a.rows, 0.3)
    for k in range(10_000):
        a.cell_current(k % a.rows, k % a.cols, 0.3, 3010.0)
        a.column_current(v, k % a.cols)
    assert np.array_equal(a.conductance(), before)


@pytest.mark.parametrize("polarity,sign", [(Polarity.SET, 1), (Polarity.RESET, -1)])
def test_response_grows_with_amplitude_and_width_ideal_device(polarity, sign):
    a = _fresh(IDEAL)

    def step(v, w, cell=(0, 0)):
        a.set_conductance(*cell, MID)
        g0 = a.conductance()[cell]
        a.apply_pulse(*cell, v, polarity, w)
        return sign * (a.conductance()[cell] / g0 - 1.0)

    by_amp = [step(v, 100e-6) for v in (0.35, 0.5, 0.8, 1.1, 1.4)]
    assert by_amp[0] > 0 and np.all(np.diff(by_amp) > 0)
    by_width = [step(0.8, w) for w in (10e-6, 100e-6, 1e-3)]
    assert np.all(np.diff(by_width) > 0)


@pytest.mark.parametrize("polarity,sign", [(Polarity.SET, 1), (Polarity.RESET, -1)])
def test_response_grows_with_amplitude_in_expectation_with_noise(polarity, sign):
    a = _fresh(seed=2)
    means = []
    for v in (0.5, 0.8, 1.1, 1.4):
        steps = []
        for k in range(64):
            cell = (k % a.rows, k // a.rows)
            a.set_conductance(*cell, MID)
            g0 = a.conductance()[cell]
            a.apply_pulse(*cell, v, polarity, 100e-6)
            steps.append(sign * (a.conductance()[cell] / g0 - 1.0))
        means.append(np.mean(steps))
    assert np.all(np.diff(means) > 0) and means[0] > 0


def test_set_is_stronger_than_reset_at_high_amplitude():
    a = _fresh(IDEAL)
    a.apply_pulse(0, 0, 1.4, Polarity.SET, 100e-6)
    a.apply_pulse(1, 0, 1.4, Polarity.RESET, 100e-6)
    g = a.conductance()
    assert abs(math.log(g[0, 0] / MID)) > 1.5 * abs(math.log(g[1, 0] / MID))


def test_slicing_a_pulse_gives_the_same_result_on_an_ideal_device():
    a = _fresh(IDEAL)
    a.apply_pulse(0, 0, 1.0, Polarity.SET, 100e-6)
    for _ in range(10):
        a.apply_pulse(1, 0, 1.0, Polarity.SET, 10e-6)
    g = a.conductance()
    assert g[1, 0] == pytest.approx(g[0, 0], rel=1e-3)


def test_state_saturates_inside_the_device_bounds():
    a = _fresh(IDEAL)
    for _ in range(200):
        a.apply_pulse(0, 0, 1.4, Polarity.SET, 1e-3)
        a.apply_pulse(1, 0, 1.4, Polarity.RESET, 1e-3)
    g = a.conductance()
    assert g[0, 0] <= a.cells.g_max[0, 0] * (1 + 1e-12) and g[0, 0] > CFG.conductance.usable_max_s
    assert g[1, 0] >= a.cells.g_min[1, 0] * (1 - 1e-12) and g[1, 0] < CFG.conductance.usable_min_s


@settings(max_examples=40, deadline=None)
@given(pulses=st.lists(st.tuples(st.integers(0, 31), st.integers(0, 7), st.floats(0.0, 3.0),
                                 st.sampled_from([Polarity.SET, Polarity.RESET]), st.floats(0.0, 1e-2)), max_size=40),
       seed=st.integers(0, 5))
def test_random_pulses_never_give_nan_or_leave_the_bounds(pulses, seed):
    a = CrossbarArray(seed=seed)
    for row, col, amp, pol, width in pulses:
        i = a.apply_pulse(row, col, amp, pol, width)
        assert math.isfinite(i) and 0 <= i <= CFG.transistor.saturation_current_a
    g = a.conductance()
    assert np.all(np.isfinite(g))
    free = ~a.stuck_mask
    assert np.all(g[free] >= a.cells.g_min[free] * (1 - 1e-12))
    assert np.all(g[free] <= a.cells.g_max[free] * (1 + 1e-12))


def test_pulse_current_predicts_ohms_law_and_compliance():
    a = _fresh(IDEAL, g=1e-3)
    r_write = CFG.transistor.on_resistance_ohm + CFG.transistor.write_series_ohm
    assert a.pulse_current(0, 0, 1.2) == pytest.approx(1.2 / (1e3 + r_write))
    a.set_conductance(0, 0, 1.0)  # clipped to g_max
    assert a.pulse_current(0, 0, 10.0) == CFG.transistor.saturation_current_a
    before = a.conductance()
    a.pulse_current(0, 0, 1.4)
    assert np.array_equal(a.conductance(), before)
    # a RESET draws its peak current at the start, a SET at the end
    a.set_conductance(1, 0, MID)
    predicted = a.pulse_current(1, 0, 1.4)
    assert a.apply_pulse(1, 0, 1.4, Polarity.SET, 100e-6) > predicted


def test_divider_reduces_the_voltage_across_the_cell():
    # the same pulse switches a low-resistance cell less than a high-resistance one (both SET from the
    # same normalized state would differ only by the divider): compare against the no-series case
    kw = dict(s=0.5, amplitude_v=0.8, polarity=Polarity.SET, width_s=100e-6, g_min=2.5e-5, g_max=1.6667e-3,
              rate=2300.0, vth=0.3, exponent=2.0, i_sat=1.0, max_substep_dose=0.02)
    with_series = pulse_response(series_ohm=2000.0, **kw).s_after
    without = pulse_response(series_ohm=0.0, **kw).s_after
    assert 0.5 < with_series < without


def test_read_noise_is_about_one_percent_and_unbiased():
    a = _fresh(seed=1)
    r_t = CFG.transistor.on_resistance_ohm
    reads = np.array([a.cell_current(3, 2, 0.3, 0.0) for _ in range(4000)])
    g_read = 1.0 / (0.3 / reads - r_t)
    rel = g_read / a.conductance()[3, 2] - 1.0
    assert abs(np.mean(rel)) < 1.5e-3
    assert 0.007 < np.std(rel) < 0.013


def test_drift_is_off_by_default_and_lowers_g_when_enabled():
    a = _fresh(seed=3)
    before = a.conductance()
    a.advance_time(1e6)
    assert np.array_equal(a.conductance(), before)
    drifting = _fresh(CFG.with_overrides({"drift.nu_mean": 0.05, "drift.nu_sigma": 0.01}), seed=3)
    g0 = drifting.conductance()
    drifting.advance_time(1e4)
    g1 = drifting.conductance()
    assert np.all(g1 < g0)
    assert np.median(g1 / g0) == pytest.approx((1e4 + 1.0) ** -0.05, rel=0.05)
    # reprogramming restarts the drift clock of that cell
    drifting.apply_pulse(0, 0, 0.8, Polarity.SET, 100e-6)
    g2 = drifting.conductance()[0, 0]
    drifting.advance_time(0.0)
    assert drifting.conductance()[0, 0] == g2 and g2 > g1[0, 0]


def test_conductance_of_state_spans_the_bounds():
    assert conductance_of_state(0.0, 2e-5, 2e-3) == pytest.approx(2e-5)
    assert conductance_of_state(1.0, 2e-5, 2e-3) == pytest.approx(2e-3)
    assert conductance_of_state(0.5, 2e-5, 2e-3) == pytest.approx(2e-4)
