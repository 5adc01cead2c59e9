"""The 32x8 1T1R array: fixed interface, Ohm's law reads, column MAC, stuck cells, persistence,
and that write-and-verify can program it as the paper did."""

import inspect

import numpy as np
import pytest

from snan_hil.crossbar_model import ArrayConfig, ChipStateError, CrossbarArray
from snan_hil.crossbar_model.characterize import (ideal_fine_tune, ideal_write_verify,
                                                 log_uniform_targets)
from snan_hil.common.polarity import Polarity
from snan_hil.protocol.board import MEMRICORE

CFG = ArrayConfig.default()
R_T = CFG.transistor.on_resistance_ohm
R_MAC = R_T + CFG.transistor.mac_row_series_ohm
SERIES = MEMRICORE.r_load_ohm + MEMRICORE.r_switch_ohm  # board: 3 kOhm load + 10 Ohm switches
BOARD = {"v_read": MEMRICORE.max_read_v, "series_ohm": SERIES}


def test_fixed_interface_signatures():
    params = {name: list(inspect.signature(getattr(CrossbarArray, name)).parameters) for name in
              ("__init__", "from_yaml", "conductance", "cell_current", "column_current", "apply_pulse",
               "pulse_current", "save", "load")}
    assert params["__init__"] == ["self", "config", "seed"]
    assert params["from_yaml"] == ["path", "seed"]
    assert params["cell_current"] == ["self", "row", "col", "volts", "series_ohm"]
    assert params["column_current"] == ["self", "row_volts", "col"]
    assert params["apply_pulse"] == ["self", "row", "col", "amplitude_v", "polarity", "width_s"]
    assert params["pulse_current"] == ["self", "row", "col", "amplitude_v"]
    a = CrossbarArray.from_yaml(None, seed=0)
    assert (a.rows, a.cols) == (32, 8)
    assert a.conductance().shape == (32, 8) and a.stuck_mask.shape == (32, 8) and a.stuck_mask.dtype == bool


def test_same_seed_same_chip_other_seed_other_chip():
    a, b, c = CrossbarArray(seed=7), CrossbarArray(seed=7), CrossbarArray(seed=8)
    assert np.array_equal(a.conductance(), b.conductance())
    assert not np.array_equal(a.conductance(), c.conductance())
    assert a.cell_current(0, 0, 0.3, SERIES) == b.cell_current(0, 0, 0.3, SERIES)


def test_cell_read_follows_ohms_law_without_noise():
    a = CrossbarArray(CFG.ideal(), seed=1)
    g = a.conductance()
    for row, col, volts in [(0, 0, 0.3), (31, 7, 0.1), (5, 3, -0.2)]:
        expected = volts / (1.0 / g[row, col] + R_T + SERIES)
        assert a.cell_current(row, col, volts, SERIES) == pytest.approx(expected, rel=1e-12)


def test_cell_read_matches_the_host_read_formula():
    # ADC voltage gain*V*R_load/(R + R_sw + R_load) with R = memristor + transistor (what the host calls R)
    a = CrossbarArray(CFG.ideal(), seed=2)
    a.set_conductance(4, 4, 1 / 1500.0)
    i = a.cell_current(4, 4, 0.3, SERIES)
    v_adc = 11 * i * 3000.0
    assert v_adc == pytest.approx(11 * 0.3 * 3000.0 / (1500.0 + R_T + 10.0 + 3000.0), rel=1e-12)


def test_column_mac_equals_the_dot_product_without_noise():
    a = CrossbarArray(CFG.ideal(), seed=3)
    rng = np.random.default_rng(0)
    v = rng.uniform(0, 0.3, a.rows)
    g_eff = a.conductance() / (1.0 + a.conductance() * R_MAC)
    assert np.allclose(a.effective_conductance(), g_eff)
    for col in range(a.cols):
        assert a.column_current(v, col) == pytest.approx(float(v @ g_eff[:, col]), rel=1e-12)


def test_column_mac_with_noise_is_unbiased_and_within_the_noise():
    a = CrossbarArray(seed=3)
    v = np.zeros(a.rows)
    v[:15] = 0.1  # one spike on 15 rows, as in the paper
    ref = v @ a.effective_conductance()
    reads = np.array([[a.column_current(v, col) for col in range(a.cols)] for _ in range(400)])
    rel = reads / ref - 1.0
    assert np.all(np.abs(rel.mean(axis=0)) < 2e-3)
    assert np.all(rel.std(axis=0) < 0.01)  # per-cell 1 % noise averages down over 15 cells
    assert np.all(rel.std(axis=0) > 0.001)


def test_stuck_cells_have_the_configured_fraction_and_never_move():
    cfg = CFG.with_overrides({"stuck.fraction": 0.05, "stuck.high_fraction": 0.5})
    a = CrossbarArray(cfg, seed=5)
    assert a.stuck_mask.sum() == round(0.05 * 256)
    g0 = a.conductance()
    rows, cols = np.nonzero(a.stuck_mask)
    for r, c in zip(rows, cols):
        for _ in range(5):
            a.apply_pulse(r, c, 1.4, Polarity.SET, 1e-3)
            a.apply_pulse(r, c, 1.4, Polarity.RESET, 1e-3)
        a.set_conductance(r, c, 3e-4)
    assert np.array_equal(a.conductance()[a.stuck_mask], g0[a.stuck_mask])
    stuck_g = g0[a.stuck_mask]
    assert np.all((stuck_g > cfg.conductance.usable_max_s) | (stuck_g < cfg.conductance.usable_min_s))
    assert a.stuck_high.sum() >= 1 and (a.stuck_mask & ~a.stuck_high).sum() >= 1


def test_save_and_load_reproduce_state_and_random_stream(tmp_path):
    a = CrossbarArray(seed=11)
    a.apply_pulse(2, 3, 0.9, Polarity.SET, 100e-6)
    a.cell_current(0, 0, 0.3, SERIES)
    path = tmp_path / "chip.npz"
    a.save(str(path))
    b = CrossbarArray.load(str(path))
    assert np.array_equal(a.conductance(), b.conductance())
    assert np.array_equal(a.stuck_mask, b.stuck_mask)
    assert b.config == a.config and b.seed == 11
    v = np.full(32, 0.2)
    seq_a = [a.cell_current(1, 1, 0.3, SERIES), a.column_current(v, 4), a.apply_pulse(5, 5, 1.1, Polarity.RESET, 1e-4)]
    seq_b = [b.cell_current(1, 1, 0.3, SERIES), b.column_current(v, 4), b.apply_pulse(5, 5, 1.1, Polarity.RESET, 1e-4)]
    assert seq_a == seq_b
    assert np.array_equal(a.conductance(), b.conductance())
    # the file holds no pickled objects
    with np.load(path, allow_pickle=False) as d:
        assert all(d[k].dtype != object for k in d.files)


def test_save_keeps_the_exact_path_and_load_rejects_junk(tmp_path):
    a = CrossbarArray(seed=0)
    path = tmp_path / "chip.state"
    a.save(str(path))
    assert path.exists() and not (tmp_path / "chip.state.npz").exists()
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip")
    with pytest.raises(ChipStateError):
        CrossbarArray.load(str(junk))
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(ChipStateError, match="not a snan-hil chip state"):
        CrossbarArray.load(str(tmp_path / "other.npz"))


def test_load_turns_every_damaged_file_into_chip_state_error(tmp_path):
    path = tmp_path / "chip.npz"
    CrossbarArray(seed=1).save(str(path))
    raw = path.read_bytes()
    bad = tmp_path / "bad.npz"
    for blob, why in ((b"", "empty"), (raw[:len(raw) // 2], "truncated"),
                      (raw[:20], "truncated"), (b"\x80\x04junk", "not an npz")):
        bad.write_bytes(blob)
        with pytest.raises(ChipStateError, match=why):
            CrossbarArray.load(str(bad))
    with np.load(path) as d:
        data = {k: d[k] for k in d.files}
    for key, value in (("state", np.full((32, 8), np.nan)), ("cell_g_min", np.ones((3, 2))),
                       ("stuck_high", np.array(True))):
        np.savez(bad, **{**data, key: value})
        with pytest.raises(ChipStateError, match=key):
            CrossbarArray.load(str(bad))


def test_invalid_arguments_are_rejected():
    a = CrossbarArray(seed=0)
    with pytest.raises(IndexError):
        a.apply_pulse(32, 0, 1.0, Polarity.SET, 1e-4)
    with pytest.raises(ValueError, match="polarity"):
        a.apply_pulse(0, 0, 1.0, "set-ish", 1e-4)
    with pytest.raises(ValueError, match="amplitude"):
        a.apply_pulse(0, 0, -1.0, Polarity.SET, 1e-4)
    with pytest.raises(ValueError):
        a.column_current(np.zeros(31), 0)
    with pytest.raises(IndexError):
        a.column_current(np.zeros(32), 8)


# --- programmability: the paper's two-stage write-and-verify on this device model -------------

def test_write_and_verify_reaches_targets_quickly_and_fine_tuning_gets_close():
    a = CrossbarArray(CFG.with_overrides({"stuck.fraction": 0.0}), seed=21)
    pulses, stage1_err, final_err = [], [], []
    for row, col, target in log_uniform_targets(a, 96, seed=1):
        pulses.append(ideal_write_verify(a, row, col, target, v_max=MEMRICORE.max_write_v,
                                         **BOARD))
        stage1_err.append(a.conductance()[row, col] / target - 1)
        ideal_fine_tune(a, row, col, target, **BOARD)
        final_err.append(a.conductance()[row, col] / target - 1)
    assert np.mean(pulses) < 25
    assert np.mean(np.abs(stage1_err) <= 0.12) > 0.95  # true G inside ~10 % (reads have 1 % noise)
    assert np.median(np.abs(final_err)) < 0.02
    assert np.mean(np.abs(final_err) <= 0.03) > 0.85


def test_characterisation_takes_the_boards_read_and_write_voltages_from_the_caller():
    """crossbar_model knows no board (layering): the read voltage, write limit and series
    resistance of the ideal write-and-verify are the caller's parameters, with no default that
    would repeat a board constant (protocol/board.py holds them once)."""
    from snan_hil.crossbar_model import characterize as ch
    for fn, names in ((ch.read_conductance, ("v_read", "series_ohm")),
                      (ch.ideal_write_verify, ("v_read", "v_max", "series_ohm")),
                      (ch.ideal_fine_tune, ("v_read", "series_ohm"))):
        params = inspect.signature(fn).parameters
        for name in names:
            assert params[name].default is inspect.Parameter.empty, (fn.__name__, name)
    a = CrossbarArray(CFG.with_overrides({"stuck.fraction": 0.0}), seed=3)
    g = a.conductance()[2, 2]
    assert ch.read_conductance(a, 2, 2, **BOARD) == pytest.approx(g, rel=0.05)
