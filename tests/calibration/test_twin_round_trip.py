"""The emulator becomes the measured chip (issue 36 point 2): a device model fitted on one
chip is made physical (``crossbar_model.device_twin``), emulated (``emu://?device=``), and
characterising the twin gives the model's parameters back within the stated bounds."""

import json
import math

import numpy as np
import pytest

from snan_hil.calibration.bench import CellBench
from snan_hil.calibration.characterize import (CharacterizeConfig, characterize_cells,
                                               fit_measurement)
from snan_hil.calibration.testing import session_of
from snan_hil.common.polarity import Polarity
from snan_hil.crossbar_model.device_twin import physical_step
from snan_hil.firmware_emu.testing import lossy_inprocess_client

CELLS = [(r, c) for r in (0, 1) for c in range(4)] + [(7, 5), (9, 2)]


def _characterise(state, seed, cells, device=None):
    client, emu = lossy_inprocess_client(state, seed=seed, device=device)
    bench = CellBench(session_of(client))          # the nominal read chain: no layout
    cfg = CharacterizeConfig()
    m = characterize_cells(lambda r, c: bench.cell(r, c, width_us=cfg.pulse.width_us), cells,
                           cfg)
    array = emu.array
    client.close()
    return fit_measurement(m), array


@pytest.fixture(scope="module")
def round_trip(tmp_path_factory):
    d = tmp_path_factory.mktemp("twin")
    original, source = _characterise(d / "lab-chip.npz", 0, CELLS)
    path = d / "model.json"
    path.write_text(json.dumps(original.to_dict()))
    back, twin = _characterise(d / "twin-chip.npz", 7, CELLS, device=str(path))
    return original, back, source, twin


def test_characterising_the_twin_gives_the_parameters_back(round_trip):
    original, back, _source, _twin = round_trip
    assert all(c.ok for c in back.cells) and len(back.cells) == len(CELLS)
    # the stated bounds of docs/crossbar_model.md section 7 (those of the fit itself)
    assert back.dw_min == pytest.approx(original.dw_min, rel=0.10)
    assert abs(back.up_down - original.up_down) < 0.05
    assert back.dw_min_dtod == pytest.approx(original.dw_min_dtod, rel=0.35)
    assert abs(back.dw_min_std - original.dw_min_std) < 0.06
    assert back.g_min_s == pytest.approx(original.g_min_s, rel=0.20)
    assert back.g_max_s == pytest.approx(original.g_max_s, rel=0.20)
    assert back.read_noise == pytest.approx(original.read_noise, rel=0.30)
    # each measured cell is itself again: its mean step at the reference within 20 %
    for c in original.cells:
        mine = back.cell_fit(c.row, c.col)
        for pol in (Polarity.SET, Polarity.RESET):
            assert float(mine.mean_dx(pol, original.g_ref_s)) == pytest.approx(
                float(c.mean_dx(pol, original.g_ref_s)), rel=0.20), (c.row, c.col, pol)


def test_the_twin_is_a_physical_chip_not_the_model_replayed(round_trip):
    original, _back, source, twin = round_trip
    # the twin's measured cells are YSZ devices of their own, at their places, whose
    # noise-free physics gives the model's step curve of that cell over the measured range;
    # an unmeasured cell is drawn anew
    g = np.array([80e-6, 300e-6, 700e-6])
    for r, c in CELLS:
        fit = original.cell_fit(r, c)
        for pol, amp, bound in ((Polarity.SET, 0.8, "g_max"), (Polarity.RESET, 0.6, "g_min")):
            rate = "rate_set" if pol == Polarity.SET else "rate_reset"
            vth = "vth_set" if pol == Polarity.SET else "vth_reset"
            steps = [physical_step(g, pol, bound_s=float(getattr(a.cells, bound)[r, c]),
                                   rate=float(getattr(a.cells, rate)[r, c]),
                                   vth=float(getattr(a.cells, vth)[r, c]),
                                   exponent=(a.config.switching.set_exponent
                                             if pol == Polarity.SET
                                             else a.config.switching.reset_exponent),
                                   amplitude_v=amp, width_s=100e-6, config=a.config)
                     for a in (twin,)]
            assert steps[0] == pytest.approx(fit.mean_dx(pol, g), rel=0.15, abs=5e-4), \
                (r, c, pol)
    assert twin.config.name.startswith("twin of")
    assert not np.allclose(twin.cells.rate_set[20:, :], source.cells.rate_set[20:, :])
    # it answers any pulse through the physics, e.g. a pulse the model never saw
    g0 = float(twin.conductance()[0, 0])
    twin.apply_pulse(0, 0, 1.2, Polarity.SET, 100e-6)
    assert float(twin.conductance()[0, 0]) > g0 * 1.2
    assert math.isfinite(twin.config.programming_noise.step_sigma_log)
