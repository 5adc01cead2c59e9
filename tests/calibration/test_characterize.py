"""Device characterisation on the board (``snan-hil characterize``): the fit recovers the
emulated device's own parameters; the model is stored per chip in the history database."""

import json
import math
import sqlite3

import numpy as np
import pytest

from snan_hil.calibration.bench import CellBench
from snan_hil.calibration.characterize import (CharacterizeConfig, characterize_cells,
                                               fit_measurement)
from snan_hil.calibration.testing import session_of
from snan_hil.common.polarity import Polarity
from snan_hil.crossbar_model.characterize import device_truth
from snan_hil.crossbar_model.fitted import DeviceModel, LearningPulse, PulseSample, fit_device
from snan_hil.firmware_emu.testing import lossy_inprocess_client
from snan_hil.records.history import History
from snan_hil.tools import cli

CELLS = [(r, c) for r in (0, 1) for c in range(4)] + [(7, 5), (9, 2)]


@pytest.fixture(scope="module")
def measured(tmp_path_factory):
    """8 + 2 cells of a fresh emulated chip (seed 0) characterised over the framed protocol,
    and the emulated device's own values of the model's parameters on those cells."""
    d = tmp_path_factory.mktemp("char")
    client, emu = lossy_inprocess_client(d / "chip.npz", seed=0)
    bench = CellBench(session_of(client))          # the nominal read chain: no layout
    ledger = bench.ledger
    cfg = CharacterizeConfig()
    m = characterize_cells(lambda r, c: bench.cell(r, c, width_us=cfg.pulse.width_us), CELLS,
                           cfg)
    model = fit_measurement(m)
    truth, c2c = device_truth(emu.array, CELLS, cfg.pulse, g_ref_s=cfg.g_ref_s,
                              g_low_s=cfg.g_low_s, g_high_s=cfg.g_high_s, c2c_pulses=100)
    fw = ledger.firmware_delta(client)
    client.close()
    return m, model, truth, c2c, ledger, fw


def test_the_fit_recovers_the_emulated_devices_parameters(measured):
    m, model, truth, c2c, _ledger, _fw = measured
    assert all(c.ok for c in model.cells) and len(model.cells) == len(CELLS)
    # stated bounds (docs/learning.md): mean step and asymmetry within 10 % / 0.05, the
    # device-to-device spread within 35 %, cycle-to-cycle within 0.06, the bounds within 20 %
    assert model.dw_min == pytest.approx(truth.dw_min, rel=0.10)
    assert abs(model.up_down - truth.up_down) < 0.05
    assert model.dw_min_dtod == pytest.approx(truth.dw_min_dtod, rel=0.35)
    assert abs(model.dw_min_std - c2c) < 0.06
    assert model.g_min_s == pytest.approx(truth.g_min_s, rel=0.20)
    assert model.g_max_s == pytest.approx(truth.g_max_s, rel=0.20)
    # and per cell: each cell's mean step at the reference within 20 % of its own
    for c in model.cells:
        t = truth.cell_fit(c.row, c.col)
        for pol in (Polarity.SET, Polarity.RESET):
            got, want = (float(f.mean_dx(pol, model.g_ref_s)) for f in (c, t))
            assert got == pytest.approx(want, rel=0.2), (c.row, c.col, pol)
    # the emulated device: SET stronger than RESET at the middle, ~30 % c2c (log-normal 0.30)
    assert truth.up_down > 0.1 and 0.25 < c2c < 0.4


def test_every_pulse_is_accounted_for_and_the_sweep_covers_the_window(measured):
    m, _model, _truth, _c2c, ledger, fw = measured
    assert ledger.confirmed == len(m.samples) == fw
    for rec in m.cells:
        assert len(rec.trains) == 4 and all("pulses" in t for t in rec.trains)
        g = [s.g_before_s for s in rec.samples]
        assert min(g) < 1.2 * m.config.g_low_s and max(g) > 0.85 * m.config.g_high_s


def test_a_device_model_round_trips_and_predicts_in_siemens(measured):
    model = measured[1]
    back = DeviceModel.from_dict(json.loads(json.dumps(model.to_dict())))
    assert back.parameters() == pytest.approx(model.parameters())
    g = np.array([100e-6, 500e-6, 900e-6])
    assert np.all(back.mean_step_s(Polarity.SET, g) > 0)
    assert np.all(back.mean_step_s(Polarity.RESET, g) < 0)
    # SET steps vanish at the chip curve's top, RESET steps at its bottom
    assert back.mean_step_s(Polarity.SET, back.g_max_s) == pytest.approx(0, abs=1e-12)
    assert back.mean_step_s(Polarity.RESET, back.g_min_s) == pytest.approx(0, abs=1e-12)
    with pytest.raises(ValueError, match="not a device model"):
        DeviceModel.from_dict({"format": "x"})


def test_fit_device_on_synthetic_soft_bounds_recovers_the_generating_values():
    rng = np.random.default_rng(4)
    samples = []
    truth = {"up": 0.05, "xmax": math.log(1.3e-3), "down": 0.02, "xmin": math.log(30e-6)}
    for cell in range(6):
        g = 100e-6
        for k in range(600):
            pol = Polarity.SET if (k // 100) % 2 == 0 else Polarity.RESET
            x = math.log(g)
            mean = truth["up"] * (truth["xmax"] - x) if pol == Polarity.SET \
                else -truth["down"] * (x - truth["xmin"])
            g2 = g * math.exp(mean * (1 + 0.2 * rng.standard_normal()))
            samples.append(PulseSample(0, cell, pol, g, g2))
            g = g2
    m = fit_device(samples, LearningPulse(), g_ref_s=300e-6, read_noise=0.0)
    assert m.up_rate == pytest.approx(truth["up"], rel=0.1)
    assert m.down_rate == pytest.approx(truth["down"], rel=0.15)
    assert m.g_max_s == pytest.approx(1.3e-3, rel=0.1)
    assert m.g_min_s == pytest.approx(30e-6, rel=0.25)
    assert m.dw_min_std == pytest.approx(0.2, abs=0.04)
    assert abs(m.up_slope) < 0.1 and m.dw_min_dtod < 0.1


def test_the_command_stores_the_model_in_the_chips_history(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(tmp_path / "chip.npz"))
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "data"))
    rc = cli.main(["characterize", "--port", "emu", "--cells", "2,2;3,3", "--repeats", "1",
                   "--json", "--model", str(tmp_path / "model.json")])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert out["pulses_match"] is True and out["pulses"] == out["firmware_pulses"] > 50
    with History.open(out["history"], create=False) as db:
        stored = db.latest_device_model(set_v=0.8, reset_v=0.6, width_us=100)
        run = db.runs("characterize")[0]
    assert stored is not None and stored["run_id"] == run.id and stored["cells"] == 2
    assert stored["model"]["dw_min"] == pytest.approx(out["model"]["dw_min"])
    assert run.pulses == out["pulses"]                    # every pulse in the history
    saved = DeviceModel.from_dict(json.loads((tmp_path / "model.json").read_text()))
    assert saved.dw_min == pytest.approx(out["model"]["dw_min"])


def test_the_board_job_validates_on_held_out_trains(tmp_path, monkeypatch, capsys):
    """``--holdout N`` on a board: the job fits without every N-th train of each cell and
    scores the model on them; the result carries the scores, the printed report a line."""
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(tmp_path / "chip.npz"))
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "data"))
    argv = ["characterize", "--port", "emu", "--cells", "2,2;3,3", "--repeats", "3",
            "--holdout", "3"]
    assert cli.main([*argv, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    held = out["holdout"]
    assert held is not None and held["n"] > 20
    assert math.isfinite(held["median_abs_sigma"]) and held["median_abs_sigma"] > 0
    assert cli.main(argv) == 0
    assert "held out every 3rd train" in capsys.readouterr().out
    assert cli.main(argv[:-2] + ["--json"]) == 0             # off on a board by default
    assert json.loads(capsys.readouterr().out)["holdout"] is None


def test_bad_options_are_one_line_before_the_board(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(tmp_path / "chip.npz"))
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "data"))
    for argv, text in ((["--set-v", "0.2"], "does not switch"),
                       (["--reset-v", "2.0"], "write limit"),
                       (["--cells", "40,1"], "outside"),
                       (["--repeats", "0"], "repeats"),
                       (["--cells", "1,1;1,1"], "twice"),
                       (["--holdout", "1"], "--holdout must be >= 2")):
        assert cli.main(["characterize", "--port", "emu", *argv]) == 2
        err = capsys.readouterr().err
        assert text in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "chip.npz").exists()          # nothing touched the chip


def test_a_version_2_history_is_migrated_and_keeps_its_runs(tmp_path):
    path = tmp_path / "h.sqlite"
    with History.open(path) as db:
        run = db.begin_run("pulse", command="snan-hil pulse")
    conn = sqlite3.connect(path)
    conn.execute("DROP TABLE device_models")
    conn.execute("ALTER TABLE runs DROP COLUMN pid")      # version 4's columns
    conn.execute("ALTER TABLE runs DROP COLUMN host")
    conn.execute("PRAGMA user_version = 2")
    conn.commit()
    conn.close()
    with History.open(path) as db:
        assert db.conn.execute("PRAGMA user_version").fetchone()[0] == 4
        assert db.has_run(run)
        db.add_device_model(run, {"pulse": {"set_v": 0.8, "reset_v": 0.6, "width_us": 100},
                                  "cells": [{"ok": True}]})
        assert db.latest_device_model()["cells"] == 1
