"""Two-stage write-and-verify as pure logic on model cells: convergence, bounds, safety."""

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from snan_hil.calibration.testing import ArrayCellIO
from snan_hil.calibration.wv import (RESET, SET, PulseNotApplied, ResponseModel, WVConfig,
                                     write_and_verify)
from snan_hil.crossbar_model import ArrayConfig, CrossbarArray


@pytest.fixture(scope="module")
def chip():
    cfg = ArrayConfig.from_yaml(None).with_overrides({"stuck.fraction": 0.0})
    return CrossbarArray(cfg, seed=7)


class StuckCell:
    """A cell that never moves (and records what it was asked)."""

    def __init__(self, g=2e-4, cap=1.4):
        self.g, self.cap, self.pulses = g, cap, []

    def read(self):
        return self.g

    def pulse(self, polarity, amplitude_v):
        self.pulses.append((polarity, amplitude_v))
        return self.g

    def amplitude_cap(self, polarity, conductance_s):
        return self.cap


def test_converges_into_window_then_closer(chip):
    cfg = WVConfig()
    model = ResponseModel(cfg)
    results = []
    for k, target in enumerate([60e-6, 150e-6, 400e-6, 667e-6, 950e-6]):
        io = ArrayCellIO(chip, k, 0)
        results.append(write_and_verify(io, target, cfg, model, verify_reads=3))
    for out in results:
        assert out.ok and out.stage1_ok, out.reason
        assert abs(out.stage1_s / out.target_s - 1) <= cfg.tolerance
        assert abs(out.rel_error) <= 0.05
        assert out.pulses_stage1 <= cfg.max_pulses_stage1
    # stage 2 brings the cells closer to their targets than stage 1 left them (on the whole)
    before = sorted(abs(o.stage1_s / o.target_s - 1) for o in results)
    after = sorted(abs(o.rel_error) for o in results)
    assert after[len(after) // 2] < 0.03
    assert sum(after) < sum(before) + 0.01


def test_stage2_is_the_papers_reset_then_set_order(chip):
    cfg = WVConfig()
    io = ArrayCellIO(chip, 10, 1)
    chip.set_conductance(10, 1, 5e-4)
    out = write_and_verify(io, 3e-4, cfg)
    stage2 = [p.polarity for p in out.trace if p.stage == 2]
    # once SET pulses start in stage 2, no RESET follows within the round
    if SET in stage2:
        assert RESET not in stage2[stage2.index(SET):]
    assert out.ok


def test_a_cell_already_at_its_target_gets_no_pulse(chip):
    io = ArrayCellIO(chip, 11, 2)
    g = sum(io.read() for _ in range(20)) / 20
    out = write_and_verify(io, g * 1.005, WVConfig())
    assert out.pulses == 0 and out.ok


def test_unresponsive_cell_fails_early_and_bounded():
    cfg = WVConfig()
    cell = StuckCell(g=2e-4)
    out = write_and_verify(cell, 8e-4, cfg)
    assert not out.ok and not out.stage1_ok
    assert "no response" in out.reason
    assert out.pulses < cfg.max_pulses_stage1
    assert all(v <= cfg.v_max + 1e-12 for _, v in cell.pulses)
    assert cell.pulses[-1][1] == pytest.approx(cfg.v_max)   # the ramp reached the maximum


def test_compliance_cap_below_floor_means_no_pulse():
    cell = StuckCell(g=2e-3, cap=0.2)
    out = write_and_verify(cell, 5e-4, WVConfig())
    assert not out.ok and "compliance" in out.reason and cell.pulses == []


def test_lost_pulse_is_not_counted():
    class Flaky(StuckCell):
        def __init__(self):
            super().__init__(g=1e-4)
            self.calls = 0

        def pulse(self, polarity, amplitude_v):
            self.calls += 1
            if self.calls == 1:
                raise PulseNotApplied()
            self.g *= 1.5 if polarity == SET else 0.7
            return self.g

    cell = Flaky()
    out = write_and_verify(cell, 2e-4, WVConfig())
    assert out.not_applied == 1
    assert out.pulses == cell.calls - 1


def test_config_validation():
    with pytest.raises(ValueError):
        WVConfig(tolerance=0.01, fine_tolerance=0.02)
    with pytest.raises(ValueError):
        WVConfig(v_max=0.3)
    with pytest.raises(ValueError):
        write_and_verify(StuckCell(), 0.0, WVConfig())


@settings(max_examples=25, deadline=None)
@given(target=st.floats(50e-6, 1e-3), start=st.floats(30e-6, 1.2e-3),
       v_max=st.floats(0.9, 1.4), seed=st.integers(0, 3))
def test_amplitudes_and_pulse_counts_always_bounded(target, start, v_max, seed):
    cfg = ArrayConfig.from_yaml(None).with_overrides({"stuck.fraction": 0.0})
    chip = CrossbarArray(cfg, seed=seed)
    chip.set_conductance(0, 0, 1 / (1 / start - 150) if start < 1 / 200 else start)
    wv = WVConfig(v_max=v_max, fine_v_max=min(1.0, v_max))
    io = ArrayCellIO(chip, 0, 0, v_max=v_max)
    out = write_and_verify(io, target, wv)
    amps = [v for _, v in io.pulses]
    assert all(wv.v_floor - 1e-9 <= v <= v_max + 1e-9 for v in amps)
    assert len(amps) == out.pulses
    assert out.pulses <= wv.max_rounds * (wv.max_pulses_stage1 + wv.max_pulses_stage2)
    assert out.ok == (abs(out.rel_error) <= wv.tolerance)
    assert math.isfinite(out.final_s)


# ---- cells that read no usable conductance (issue 13: open cell, NaN read) ---------------------
class ScriptedCell:
    """A cell whose reads follow ``before`` until the first pulse, then ``after``."""

    def __init__(self, before, after=2e-4):
        self.before, self.after, self.pulses = before, after, 0

    def read(self):
        return self.after if self.pulses else self.before

    def pulse(self, polarity, amplitude_v):
        self.pulses += 1
        return self.after

    def amplitude_cap(self, polarity, conductance_s):
        return 1.4


@pytest.mark.parametrize("g,needle", [(0.0, "open cell: reads 0 S before any pulse"),
                                      (-3e-7, "open cell: reads -3e-07 S before any pulse"),
                                      (6e-8, "open cell: reads 6e-08 S before any pulse "
                                             "(below 1e-06 S)"),
                                      (math.nan, "no valid read before any pulse"),
                                      (math.inf, "no valid read before any pulse")])
def test_a_cell_without_a_usable_first_read_fails_with_a_named_reason(g, needle):
    cell = ScriptedCell(g)
    out = write_and_verify(cell, 3e-4, WVConfig())
    assert not out.ok and needle in out.reason
    assert cell.pulses == 0 and out.pulses == 0                  # nothing applied to it


@pytest.mark.parametrize("after,needle", [(0.0, "open cell"), (math.nan, "no valid read")])
def test_a_cell_that_opens_after_a_pulse_stops_there(after, needle):
    cell = ScriptedCell(1e-4, after)
    out = write_and_verify(cell, 5e-4, WVConfig())
    assert not out.ok and needle in out.reason and "after a SET pulse" in out.reason
    assert cell.pulses == 1 and out.pulses_stage1 == 1 and len(out.trace) == 1


def test_a_nan_at_the_final_read_is_named_not_taken_for_an_error_of_nan_percent():
    class LateNaN(ScriptedCell):
        def read(self):
            self.reads = getattr(self, "reads", 0) + 1
            return 3e-4 if self.reads == 1 else math.nan
    out = write_and_verify(LateNaN(3e-4), 3e-4 * 1.001, WVConfig())
    assert not out.ok and "no valid read at the final read" in out.reason
