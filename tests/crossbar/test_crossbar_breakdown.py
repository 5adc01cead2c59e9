"""What pulses from 0.3 V up to the old firmware's 3 V clamp do to a YSZ cell: switching speed
over the whole range, and breakdown above 2.5 V across the memristor (configs/device-ysz.yaml)."""

import importlib.resources
import json

import numpy as np
import pytest

from snan_hil.crossbar_model import ArrayConfig, CrossbarArray, DeviceConfigError
from snan_hil.config import loader as configio
from snan_hil.crossbar_model.characterize import pulse_steps
from snan_hil.crossbar_model.config import sourced_leaves
from snan_hil.common.polarity import Polarity

CFG = ArrayConfig.default()
NO_BREAKDOWN = CFG.with_overrides({"breakdown.v_breakdown_v": 100.0})


def test_switching_speeds_up_monotonically_from_threshold_to_3_volts():
    amps = (0.35, 0.5, 0.8, 1.1, 1.4, 1.7, 2.0, 2.5, 3.0)
    steps = pulse_steps(NO_BREAKDOWN, amplitudes=amps, repeats=1)
    for pol in (Polarity.SET, Polarity.RESET):
        mean = [abs(s.mean) for s in steps if s.polarity == pol]
        assert all(a < b for a, b in zip(mean, mean[1:])), (pol, mean)
    by = {(s.polarity, s.amplitude_v): s.mean for s in steps}
    # the per-100-us table quoted in configs/device-ysz.yaml (from mid range)
    for (pol, v), quoted in {(Polarity.SET, 1.4): 0.56, (Polarity.SET, 1.7): 0.94,
                             (Polarity.SET, 2.0): 1.46, (Polarity.RESET, 1.4): -0.24,
                             (Polarity.RESET, 1.7): -0.33, (Polarity.RESET, 2.0): -0.41}.items():
        assert by[(pol, v)] == pytest.approx(quoted, rel=0.15), (pol, v)


def test_a_pulse_above_breakdown_shorts_the_cell_for_good():
    chip = CrossbarArray(CFG.ideal(), seed=1)
    g_short = CFG.breakdown.g_short_s
    chip.set_conductance(0, 0, 1e-4)                       # 10 kOhm: V_mem ~ 0.98 V
    chip.apply_pulse(0, 0, 3.0, Polarity.RESET, 100e-6)    # old firmware's RESET clamp
    assert chip.broken[0, 0] and chip.stuck_mask[0, 0]
    assert chip.conductance()[0, 0] == pytest.approx(g_short)
    chip.apply_pulse(0, 0, 1.0, Polarity.RESET, 100e-6)    # it no longer switches
    chip.set_conductance(0, 0, 1e-4)
    assert chip.conductance()[0, 0] == pytest.approx(g_short)
    # the highest amplitude of the existing host's ramps never breaks a cell, whatever its state
    for k, g in enumerate(np.geomspace(2e-5, 2e-3, 24)):
        row, col = k % 32, 1 + k // 32
        chip.set_conductance(row, col, g)
        for pol in (Polarity.SET, Polarity.RESET):
            chip.apply_pulse(row, col, 1.7, pol, 1e-3)
        assert not chip.broken[row, col]
    assert chip.broken.sum() == 1


def test_breakdown_depends_on_the_voltage_across_the_memristor():
    chip = CrossbarArray(CFG.ideal(), seed=2)
    r_t = CFG.transistor.on_resistance_ohm + CFG.transistor.write_series_ohm
    v_bd = CFG.breakdown.v_breakdown_v
    # a RESET raises R during the pulse: the end decides; a 2.6 V pulse on a 20 kOhm cell
    chip.set_conductance(1, 0, 5e-5)
    chip.apply_pulse(1, 0, 2.6, Polarity.RESET, 100e-6)
    assert chip.broken[1, 0]
    # just below: V_mem < v_bd at the start and, on a cell already at its bound, at the end
    g_min = float(chip.cells.g_min[2, 0])
    chip.set_conductance(2, 0, g_min)
    v_safe = 0.99 * v_bd * (1 / g_min + r_t) * g_min
    chip.apply_pulse(2, 0, v_safe, Polarity.RESET, 100e-6)
    assert not chip.broken[2, 0]
    # the transistor's saturation current limits V_mem on a low-resistance cell: 2.8 V SET on
    # ~600 Ohm puts only I_sat x R = 1.8 V on the memristor
    chip.set_conductance(3, 0, 1 / 600)
    chip.apply_pulse(3, 0, 2.8, Polarity.SET, 10e-6)
    assert not chip.broken[3, 0]


def test_broken_cells_survive_save_and_old_chip_files_still_load(tmp_path):
    chip = CrossbarArray(CFG, seed=3)
    chip.set_conductance(4, 4, 1e-4)
    chip.apply_pulse(4, 4, 3.0, Polarity.RESET, 100e-6)
    path = tmp_path / "chip.npz"
    chip.save(str(path))
    back = CrossbarArray.load(str(path))
    assert back.broken[4, 4] and back.broken.sum() == 1
    assert np.array_equal(back.conductance(), chip.conductance())
    # a file from before breakdown was modelled: no 'broken', no breakdown section
    with np.load(path) as d:
        data = {k: d[k] for k in d.files if k != "broken"}
    cfg = json.loads(str(data["config_json"]))
    del cfg["breakdown"]
    data["config_json"] = np.array(json.dumps(cfg))
    old = tmp_path / "old.npz"
    with open(old, "wb") as fh:
        np.savez(fh, **data)
    loaded = CrossbarArray.load(str(old))
    assert loaded.config.breakdown == CFG.breakdown and not loaded.broken.any()


def test_the_breakdown_parameters_carry_their_assumption():
    tree = configio.read_yaml(importlib.resources.files("snan_hil").joinpath(
        "configs", "device-ysz.yaml"))
    leaves = sourced_leaves(tree)
    for key in ("breakdown.v_breakdown_v", "breakdown.g_short_s"):
        assert "assumption" in leaves[key] and len(leaves[key]["assumption"]) > 40
    assert "3 V" in leaves["switching.set_exponent"]["assumption"]
    with pytest.raises(DeviceConfigError, match="v_breakdown_v"):
        CFG.with_overrides({"breakdown.v_breakdown_v": 0.2})
