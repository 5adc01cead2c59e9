"""A fitted model made physical (``crossbar_model.device_twin``): the vectorised physics is the
emulator's own, every measured cell gets its own device at its place, the population and the
sources follow the measured cells."""

import dataclasses
import math

import numpy as np
import pytest

from snan_hil.common.errors import UserError
from snan_hil.common.polarity import Polarity
from snan_hil.crossbar_model import ArrayConfig, CrossbarArray
from snan_hil.crossbar_model.characterize import device_truth
from snan_hil.crossbar_model.device import pulse_response
from snan_hil.crossbar_model.device_twin import physical_step, twin_spec
from snan_hil.crossbar_model.fitted import CellFit, LearningPulse

CFG = ArrayConfig.default()
CELLS = [(0, 0), (0, 1), (4, 3), (9, 7), (20, 2)]


def test_the_vectorised_step_is_pulse_responses():
    r_t = CFG.transistor.on_resistance_ohm
    series = r_t + CFG.transistor.write_series_ohm
    g_min, g_max = 24e-6, 1.8e-3
    g_cell = np.geomspace(40e-6, 1.2e-3, 9)
    for pol, amp, rate, expo in ((Polarity.SET, 0.8, 2300.0, 2.0),
                                 (Polarity.RESET, 0.6, 1200.0, 1.7),
                                 (Polarity.SET, 1.2, 1800.0, 2.0)):
        got = physical_step(g_cell, pol, bound_s=g_max if pol == Polarity.SET else g_min,
                            rate=rate, vth=0.31, exponent=expo, amplitude_v=amp, width_s=1e-4,
                            config=CFG)
        want = []
        for g in g_cell:
            g_mem = g / (1 - g * r_t)
            s = math.log(g_mem / g_min) / math.log(g_max / g_min)
            res = pulse_response(s, amp, pol, 1e-4, g_min, g_max, rate, 0.31, expo, series,
                                 CFG.transistor.saturation_current_a,
                                 CFG.switching.max_substep_dose)
            g1 = g_min * (g_max / g_min) ** res.s_after
            want.append(math.log(g1 / (1 + g1 * r_t)) - math.log(g))
        assert np.max(np.abs(got - np.array(want))) < 1e-9, pol


@pytest.fixture(scope="module")
def model():
    m, c2c = device_truth(CrossbarArray(seed=1), CELLS, LearningPulse(), g_ref_s=525e-6,
                          g_low_s=45e-6, g_high_s=1.2e-3, c2c_pulses=30)
    bad = CellFit(30, 5, math.log(525e-6), *([math.nan] * 6), ok=False, reason="no response")
    return dataclasses.replace(m, dw_min_std=c2c, read_noise=0.003, cells=m.cells + (bad,))


def test_measured_cells_get_their_devices_and_the_rest_their_population(model):
    spec = twin_spec(model, read_draws=10)
    assert [(c.row, c.col) for c in spec.cells] == CELLS and spec.stuck == ((30, 5),)
    source = CrossbarArray(seed=1)
    for c in spec.cells:
        # the twin's device takes the fitted curve: its SET and RESET steps at the reference
        fit = model.cell_fit(c.row, c.col)
        for pol, bound, rate in ((Polarity.SET, c.g_max_s, c.rate_set),
                                 (Polarity.RESET, c.g_min_s, c.rate_reset)):
            step = physical_step(np.array([525e-6]), pol, bound_s=bound, rate=rate,
                                 vth=c.vth_set, exponent=(2.0 if pol == Polarity.SET else 1.7),
                                 amplitude_v=0.8 if pol == Polarity.SET else 0.6,
                                 width_s=1e-4, config=CFG)[0]
            assert step == pytest.approx(float(fit.mean_dx(pol, 525e-6)), rel=0.08)
        assert c.misfit_up < 0.1 and c.misfit_down < 0.15
        # the measured device (its own truth): close, where the data were
        assert c.g_min_s == pytest.approx(source.cells.g_min[c.row, c.col], rel=0.25)
    arr = spec.build(seed=9)
    for c in spec.cells:
        assert arr.cells.rate_reset[c.row, c.col] == c.rate_reset
        assert not arr.stuck_mask[c.row, c.col]
    assert arr.stuck_mask[30, 5]
    cfg = spec.config
    assert cfg.stuck.fraction == pytest.approx(1 / 6)
    assert cfg.read_noise.relative_sigma == pytest.approx(0.003 * math.sqrt(10))
    # the dose factor's sigma gives the model's cycle-to-cycle spread with the random walk
    assert cfg.programming_noise.step_sigma_log == pytest.approx(
        math.sqrt(math.log1p(model.dw_min_std ** 2)), abs=0.02)
    g_min = np.exp(np.log([c.g_min_s for c in spec.cells]))
    assert cfg.conductance.g_min_s == pytest.approx(float(np.exp(np.log(g_min).mean())))
    assert cfg.variability.g_min_sigma_log == pytest.approx(float(np.log(g_min).std(ddof=1)))
    assert spec.sources["switching.v_threshold_v"].startswith("assumption")
    assert spec.sources["wear"].startswith("assumption")
    # the same spec and seed: the same chip; another seed: another draw of the unmeasured
    again = spec.build(seed=9)
    assert np.array_equal(again.cells.g_max, arr.cells.g_max)
    other = spec.build(seed=10)
    assert not np.array_equal(other.cells.g_max[25:], arr.cells.g_max[25:])


def test_a_model_without_a_usable_cell_is_refused(model):
    none = dataclasses.replace(model, cells=tuple(dataclasses.replace(c, ok=False)
                                                  for c in model.cells))
    with pytest.raises(UserError, match="no cell that gives a physical device"):
        twin_spec(none)
