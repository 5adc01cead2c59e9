"""Checked on what it was not fitted on (issue 36 point 3): held-out trains, the scores'
noise floor, the read noise of data without repeated reads."""

import math

import numpy as np
import pytest

from snan_hil.common.polarity import Polarity
from snan_hil.crossbar_model.fitted import LearningPulse, PulseSample, fit_device
from snan_hil.crossbar_model.validation import (estimate_read_noise, score_heldout,
                                                split_trains)

UP, DOWN = 0.05, 0.02
XMAX, XMIN = math.log(1.3e-3), math.log(30e-6)


def synthetic(cells=8, trains=6, per_train=80, c2c=0.25, sigma=0.004, seed=1, up=UP):
    """Alternating trains of a soft-bounds device; every pulse read before and after
    (independent reads with relative noise ``sigma``)."""
    rng = np.random.default_rng(seed)
    out = []
    for cell in range(cells):
        g = 80e-6
        for t in range(trains):
            pol = Polarity.SET if t % 2 == 0 else Polarity.RESET
            for _ in range(per_train):
                x = math.log(g)
                mean = up * (XMAX - x) if pol == Polarity.SET else -DOWN * (x - XMIN)
                g2 = g * math.exp(mean * (1 + c2c * rng.standard_normal()))
                reads = [v * math.exp(sigma * rng.standard_normal()) for v in (g, g2)]
                out.append(PulseSample(0, cell, pol, *reads))
                g = g2
    return out


def test_every_third_train_is_held_out_whole():
    s = synthetic(cells=2, trains=6, per_train=10)
    fit, held = split_trains(s, 3)
    assert len(held) == 2 * 2 * 10 and len(fit) == 2 * 4 * 10
    # held out: trains 2 and 5 of each cell (a RESET and a SET train), in order
    assert [h.polarity for h in held[:20]] == [Polarity.SET] * 10 + [Polarity.RESET] * 10
    with pytest.raises(ValueError):
        split_trains(s, 1)


def test_a_right_model_scores_at_its_noise_floor_a_wrong_one_does_not():
    samples = synthetic()
    fit, held = split_trains(samples, 3)
    model = fit_device(fit, LearningPulse(), g_ref_s=300e-6, read_noise=0.004)
    good = score_heldout(model, held)
    assert good.n == len(held) and good.bins >= 8
    assert good.median_abs_sigma == pytest.approx(good.floor_sigma, rel=0.10)
    assert abs(good.bias_sigma) < 0.3 and good.binned_sigma < 0.5
    assert good.z_median == pytest.approx(0.674, abs=0.08)
    # the same held-out pulses from a device 40 % faster on SET: the model misses them
    fast = synthetic(up=UP * 1.4)
    bad = score_heldout(model, split_trains(fast, 3)[1])
    assert bad.binned_sigma > 2 * good.binned_sigma and bad.bias_sigma > 0.5


def test_the_read_noise_comes_back_from_the_steps_scatter():
    for sigma in (0.002, 0.006):
        est = estimate_read_noise(synthetic(cells=10, sigma=sigma, c2c=0.2))
        assert est == pytest.approx(sigma, rel=0.3)
    assert math.isnan(estimate_read_noise(synthetic(cells=1, trains=2, per_train=20)))
