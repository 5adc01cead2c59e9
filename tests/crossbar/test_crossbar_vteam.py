"""VTEAM model: the paper's equations, sign checks, exact integration, bounds, no NaN."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from snan_hil.crossbar_model.vteam import VTEAM, VTEAMParams

P = VTEAMParams()


def test_defaults_are_table_tab2():
    assert (P.v_on, P.v_off, P.r_on, P.r_off) == (0.6, -0.6, 500.0, 25e3)
    assert (P.k_on, P.k_off, P.A_on, P.A_off) == (-3.96e-8, 1.054e-8, 2.357, 2.022)
    assert P.a_on == pytest.approx(36.8e-9) and P.a_off == pytest.approx(0.12e-9)
    assert P.x_c == pytest.approx(40e-9) and P.x_con == pytest.approx(38e-9)


@pytest.mark.parametrize("field,value,word", [
    ("k_on", 3.96e-8, "K_on"),
    ("k_off", -1.054e-8, "K_off"),
    ("v_on", -0.6, "v_on"),
    ("v_off", 0.6, "v_off"),
    ("r_on", 30e3, "R_on"),
    ("x_off", -1e-9, "x_on"),
    ("x_c", 0.0, "x_c"),
    ("A_on", float("nan"), "A_on"),
])
def test_wrong_signs_are_rejected_with_a_clear_message(field, value, word):
    with pytest.raises(ValueError, match=word):
        VTEAMParams(**{field: value})


def test_window_functions_and_memristance_follow_the_equations():
    m = VTEAM()
    x = np.array([0.0, 1e-9, 3e-9])
    assert np.allclose(m.f_off(x), np.exp(-np.exp((x - 0.12e-9) / 40e-9)))
    assert np.allclose(m.f_on(x), np.exp(-np.exp((36.8e-9 - x) / 38e-9)))
    assert m.resistance(P.x_on) == pytest.approx(500.0)
    assert m.resistance(P.x_off) == pytest.approx(25e3)
    mid = 0.5 * (P.x_on + P.x_off)
    assert m.resistance(mid) == pytest.approx(500.0 * math.sqrt(50.0))


def test_dxdt_is_zero_between_thresholds_and_signed_outside():
    m = VTEAM()
    x = 1e-9
    for v in (-0.6 + 1e-9, -0.3, 0.0, 0.3, 0.6 - 1e-9):
        assert m.dxdt(v, x) == 0.0
    assert m.dxdt(1.0, x) < 0  # SET: barrier shrinks, R down
    assert m.dxdt(-1.0, x) > 0  # RESET: barrier grows, R up
    expected = -3.96e-8 * (1.0 / 0.6 - 1) ** 2.357 * float(m.f_on(x))
    assert m.dxdt(1.0, x) == pytest.approx(expected)


def _rk4(m, x0, t, v, substeps=200):
    """Brute-force reference: RK4 of the paper's ODE on a very fine grid (v interpolated)."""
    x = x0
    for k in range(len(t) - 1):
        h = (t[k + 1] - t[k]) / substeps
        for j in range(substeps):
            ta = t[k] + j * h

            def vv(tt):
                return float(np.interp(tt, t, v))

            k1 = float(m.dxdt(vv(ta), x))
            k2 = float(m.dxdt(vv(ta + h / 2), x + h / 2 * k1))
            k3 = float(m.dxdt(vv(ta + h / 2), x + h / 2 * k2))
            k4 = float(m.dxdt(vv(ta + h), x + h * k3))
            x = min(max(x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4), m.params.x_on), m.params.x_off)
    return x


@pytest.mark.parametrize("bounds", ["tunnel-3nm", "window-40nm"])
def test_exact_integration_matches_a_brute_force_solution(bounds):
    m = VTEAM(VTEAMParams.paper(bounds))
    p = m.params
    t = np.array([0.0, 0.02, 0.05, 0.06, 0.09, 0.12])
    v = np.array([0.0, 1.2, 1.1, -1.3, -0.9, 0.0])
    x0 = p.x_on + 0.4 * (p.x_off - p.x_on)
    exact = float(m.apply_waveform(x0, t, v))
    ref = _rk4(m, x0, t, v, substeps=100)
    assert exact != pytest.approx(x0, abs=1e-6 * (p.x_off - p.x_on))  # the waveform did something
    assert exact == pytest.approx(ref, abs=1e-4 * abs(ref - x0) + 1e-18)


def test_result_does_not_depend_on_the_sampling_step():
    m = VTEAM()
    x0 = 1.5e-9
    finals = []
    for dt in (1e-3, 1e-4, 1e-5, 1e-6):
        t = np.arange(0.0, 0.2 + dt / 2, dt)
        # triangles whose vertices fall on every grid: 0 -> 1.2 V at 50 ms -> 0 at 100 ms -> -1.2 V -> 0
        v = np.interp(t, [0.0, 0.05, 0.1, 0.15, 0.2], [0.0, 1.2, 0.0, -1.2, 0.0])
        finals.append(float(m.apply_waveform(x0, t, v)))
    assert np.ptp(finals) <= 1e-9 * abs(finals[0] - x0) + 1e-20
    # a smooth waveform converges as the step shrinks
    sine = [float(m.apply_waveform(x0, t, 1.3 * np.sin(2 * np.pi * 20 * t)))
            for t in (np.linspace(0, 0.1, 2001), np.linspace(0, 0.1, 20001))]
    assert sine[0] == pytest.approx(sine[1], rel=1e-4)


def test_splitting_a_pulse_changes_nothing():
    m = VTEAM()
    whole = m.apply_waveform(2e-9, np.array([0.0, 0.01]), np.array([1.0, 1.0]))
    x = 2e-9
    for k in range(10):
        x = m.apply_waveform(x, np.array([k * 1e-3, (k + 1) * 1e-3]), np.array([1.0, 1.0]))
    assert float(x) == pytest.approx(float(whole), rel=1e-9)


def test_subthreshold_waveform_never_changes_the_state():
    m = VTEAM()
    t = np.linspace(0, 1.0, 1001)
    v = 0.599 * np.sin(2 * np.pi * 5 * t)
    assert float(m.apply_waveform(1e-9, t, v)) == 1e-9


def test_state_saturates_at_the_bounds():
    m = VTEAM()
    long = np.array([0.0, 100.0])
    assert float(m.apply_waveform(1e-9, long, np.array([1.2, 1.2]))) == P.x_on
    assert float(m.apply_waveform(1e-9, long, np.array([-1.2, -1.2]))) == P.x_off


def test_simulate_agrees_with_apply_waveform_and_gives_ohmic_current():
    m = VTEAM()
    t = np.linspace(0, 0.2, 4001)
    v = 1.1 * np.sin(2 * np.pi * 10 * t)
    xs, i = m.simulate(1.5e-9, t, v)
    assert xs[-1] == pytest.approx(float(m.apply_waveform(1.5e-9, t, v)), rel=1e-12)
    assert np.allclose(i, v / m.resistance(xs))
    assert np.all((xs >= P.x_on) & (xs <= P.x_off))


@settings(max_examples=60, deadline=None)
@given(volts=st.lists(st.floats(-5.0, 5.0, allow_nan=False), min_size=2, max_size=30),
       dts=st.lists(st.floats(0.0, 0.5, allow_nan=False), min_size=29, max_size=29),
       w0=st.floats(0.0, 1.0))
def test_random_waveforms_stay_finite_and_bounded(volts, dts, w0):
    m = VTEAM()
    t = np.concatenate([[0.0], np.cumsum(dts[: len(volts) - 1])])
    x = float(m.apply_waveform(m.x_from_weight(w0), t, np.array(volts)))
    assert math.isfinite(x) and P.x_on <= x <= P.x_off


def test_bad_waveforms_are_rejected():
    m = VTEAM()
    with pytest.raises(ValueError):
        m.apply_waveform(1e-9, np.array([0.0, 1.0]), np.array([0.0, np.nan]))
    with pytest.raises(ValueError):
        m.apply_waveform(1e-9, np.array([1.0, 0.0]), np.array([1.0, 1.0]))


def test_weight_mapping_round_trips():
    m = VTEAM()
    w = np.linspace(0, 1, 11)
    assert np.allclose(m.weight_from_x(m.x_from_weight(w)), w)
    assert float(m.weight_from_x(P.x_on)) == pytest.approx(1.0)
    assert float(m.weight_from_x(P.x_off)) == pytest.approx(0.0)
