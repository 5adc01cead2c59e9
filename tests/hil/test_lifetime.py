"""A chip's life of learning sessions (issue 36 point 5): sessions on one emulated chip within
the budget, the host's per-cell ledger of pulses and the wear it predicts from them against the
chip's own wear."""

import dataclasses

import numpy as np
import pytest

from snan_hil.crossbar_model import CrossbarArray
from snan_hil.crossbar_model.aging import fit_aging
from snan_hil.crossbar_model.characterize import device_truth
from snan_hil.crossbar_model.device_twin import twin_spec
from snan_hil.crossbar_model.fitted import LearningPulse
from snan_hil.host.hil.config import load_hil_config
from snan_hil.host.hil.learning import PulseBudget
from snan_hil.host.hil.lifetime import LifetimeConfig, run_lifetime


@pytest.fixture(scope="module")
def life():
    cells = [(0, c) for c in range(4)]
    pulse = LearningPulse(1.2, 0.6, 100)
    model, c2c = device_truth(CrossbarArray(seed=2), cells, pulse, g_ref_s=525e-6,
                              g_low_s=45e-6, g_high_s=1.2e-3, c2c_pulses=30)
    model = dataclasses.replace(model, dw_min_std=c2c, read_noise=0.0027)
    model = dataclasses.replace(model, aging=fit_aging([], model))     # packaged wear
    spec = twin_spec(model, read_draws=10)
    spec = dataclasses.replace(spec, config=spec.config.with_overrides(
        {"wear.endurance_cycles": 20.0}))                              # a chip that wears
    array = spec.build(seed=4)
    hil = load_hil_config(None, [])
    lc = LifetimeConfig(start=hil.task.start, goal=hil.task.goal, sessions=2, cycles=4,
                        budget=PulseBudget(60, 6, 2, 0.5, 0.5), refresh_every=2, pulse=pulse)
    return run_lifetime(hil.model, lc, model, array), array


def test_the_budget_holds_and_every_pulse_is_in_the_cell_ledger(life):
    run, _array = life
    for s in run["sessions"]:
        assert s["learning_pulses"] <= 60 and s["max_cell_pulses"] <= 6
        assert len(s["tests"]) == 5 and s["programming_pulses"] > 0
    cells = run["cells"]
    assert sum(c["learning_pulses"] for c in cells) == sum(s["learning_pulses"]
                                                           for s in run["sessions"])
    assert sum(c["programming_pulses"] for c in cells) == sum(s["programming_pulses"]
                                                              for s in run["sessions"])


def test_the_hosts_wear_prediction_follows_the_chips_wear(life):
    run, array = life
    cells = [c for c in run["cells"] if c["learning_pulses"] + c["programming_pulses"]]
    pred = np.array([c["predicted_cycles"] for c in cells])
    true = np.array([c["true_wear_cycles"] for c in cells])
    assert true.min() > 0 and pred.min() > 0
    # the same order of magnitude (model cycles vs device cycles: k ~ 0.9) and correlated
    assert 0.5 < pred.sum() / true.sum() < 2.0
    assert np.corrcoef(pred, true)[0, 1] > 0.8
    assert run["model_endurance_cycles"] > 1e4                        # packaged: 1e5 cycles
    assert array.wear.sum() == pytest.approx(sum(c["true_wear_cycles"] for c in run["cells"]))
