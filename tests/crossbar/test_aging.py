"""The aging term (issue 36 point 3): wear fitted where the data show it — on sweeps of a
device whose window closes with use —, else the packaged assumption; retention drift from
the gaps between pulses."""

import math

import numpy as np
import pytest

from snan_hil.common.polarity import Polarity
from snan_hil.crossbar_model.aging import fit_aging, sweeps
from snan_hil.crossbar_model.config import ArrayConfig
from snan_hil.crossbar_model.fitted import LearningPulse, PulseSample, fit_device

XMAX0, XMIN0 = math.log(1.3e-3), math.log(30e-6)


def worn_sweeps(loss_per_cycle, cells=8, sweeps_=8, per_train=90, seed=3):
    """Soft-bounds sweeps whose window (both bounds towards the middle) closes by
    ``loss_per_cycle`` of itself per full-window cycle counted from the data's own steps."""
    rng = np.random.default_rng(seed)
    w0 = XMAX0 - XMIN0
    out = []
    for cell in range(cells):
        g, swing = 100e-6, 0.0
        for k in range(2 * sweeps_):
            pol = Polarity.SET if k % 2 == 0 else Polarity.RESET
            for _ in range(per_train):
                close = min(loss_per_cycle * swing / (2 * w0), 0.9) * w0 / 2
                x = math.log(g)
                mean = 0.05 * (XMAX0 - close - x) if pol == Polarity.SET \
                    else -0.02 * (x - XMIN0 - close)
                g2 = g * math.exp(mean * (1 + 0.2 * rng.standard_normal()))
                out.append(PulseSample(0, cell, pol, g, g2, swing_before=swing))
                swing += abs(math.log(g2 / g))
                g = g2
    return out


def test_sweeps_pair_trains():
    def pulses(*runs):
        return [PulseSample(0, 0, p, 1e-4, 1e-4) for p, n in runs for _ in range(n)]
    s, r = Polarity.SET, Polarity.RESET
    assert [len(x) for x in sweeps(pulses((s, 3), (r, 2), (s, 2), (r, 2)))] == [5, 4]
    # a last lone train joins the sweep before it
    assert [len(x) for x in sweeps(pulses((s, 3), (r, 2), (s, 2)))] == [7]


def test_a_closing_window_is_fitted_and_its_endurance_follows():
    samples = worn_sweeps(0.02)
    model = fit_device(samples, LearningPulse(), g_ref_s=300e-6, read_noise=0.003)
    aging = fit_aging(samples, model)
    assert aging.wear_fitted, aging.wear_source
    lo, hi = aging.window_loss_ci
    assert lo < 0.02 * 1.25 and hi > 0.02 * 0.75          # the truth inside, roughly
    assert aging.window_loss_per_cycle == pytest.approx(0.02, rel=0.35)
    assert aging.step_change_per_cycle < 0                # steps shrink with the window
    assert aging.endurance_cycles == pytest.approx(aging.window_closure / 0.02, rel=0.35)
    assert aging.cycles_seen > 5


def test_without_wear_the_packaged_assumption_stands_with_the_datas_interval():
    samples = worn_sweeps(0.0)
    model = fit_device(samples, LearningPulse(), g_ref_s=300e-6, read_noise=0.003)
    aging = fit_aging(samples, model)
    assert not aging.wear_fitted and aging.wear_source.startswith("assumption: packaged")
    lo, hi = aging.window_loss_ci
    assert lo < 0 < hi                                    # no change shown
    w = ArrayConfig.default().wear
    assert aging.window_closure == w.window_closure and aging.window_loss_per_cycle > 0
    assert aging.drift_nu == 0 and "no times" in aging.drift_source


def test_drift_is_fitted_from_gaps_between_pulses():
    rng = np.random.default_rng(5)
    nu, sigma = 0.02, 0.003
    pairs = []
    for _ in range(300):
        gap = float(rng.choice([0.01, 3600.0, 86400.0]))
        g = 300e-6
        later = g * ((gap + 1.0) / 1.0) ** -nu
        pairs.append((gap, g * math.exp(sigma * rng.standard_normal()),
                      later * math.exp(sigma * rng.standard_normal())))
    samples = worn_sweeps(0.0, cells=3, sweeps_=2)
    model = fit_device(samples, LearningPulse(), g_ref_s=300e-6, read_noise=sigma)
    aging = fit_aging(samples, model, retention=pairs)
    assert aging.drift_fitted and aging.drift_nu == pytest.approx(nu, rel=0.1)
    lo, hi = aging.drift_nu_ci
    assert lo < nu < hi
    # only short gaps: the data hold no retention, the assumption stands with its bound
    short = [(0.01, a, b) for _gap, a, b in pairs]
    assert not fit_aging(samples, model, retention=short).drift_fitted
