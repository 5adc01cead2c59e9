"""Out to the tools labs know (issue 36 point 4): the aihwkit device configuration reproduces
the model's steps under aihwkit's own update rule, and the CrossSim-style tables read as
CrossSim reads them hold the model's mean steps and spread."""

import json
import math

import numpy as np
import pytest

from snan_hil.common.polarity import Polarity
from snan_hil.crossbar_model.device_twin import spec_from_mapping, twin_spec
from snan_hil.crossbar_model.export import (aihwkit_export, crosssim_tables,
                                            read_crosssim_table, weight_scale, write_crosssim)
from snan_hil.crossbar_model.fitted import CellFit, DeviceModel, LearningPulse
from snan_hil.tools import cli


@pytest.fixture
def model():
    cell = CellFit(0, 0, math.log(525e-6), 0.047, -0.08, math.log(1.25e-3), 0.0095, -0.39,
                   math.log(33e-6))
    return DeviceModel(LearningPulse(), 525e-6, dw_min=0.034, up_down=0.2, dw_min_dtod=0.18,
                       up_down_dtod=0.17, dw_min_std=0.3, g_min_s=33e-6, g_max_s=1.25e-3,
                       g_min_dtod=0.07, g_max_dtod=0.06, up_rate=0.047, up_slope=-0.08,
                       down_rate=0.0095, down_slope=-0.39, read_noise=0.0027, cells=(cell,),
                       points=1000)


def aihwkit_mean_step(params, w, up):
    """aihwkit's PiecewiseStepDevice mean step at weight w (its documented rule: dw_min
    (1 +- up_down) times the node values interpolated linearly over [w_min, w_max])."""
    nodes = np.linspace(params["w_min"], params["w_max"], len(params["piecewise_up"]))
    v = np.interp(w, nodes, params["piecewise_up" if up else "piecewise_down"])
    return params["dw_min"] * (1 + params["up_down"] if up else 1 - params["up_down"]) * v


def test_the_aihwkit_device_steps_as_the_model_does(model):
    doc = json.loads(json.dumps(aihwkit_export(model)))
    p = doc["device"]["parameters"]
    x_c, s = weight_scale(model)
    assert (p["w_min"], p["w_max"]) == (-1.0, 1.0)
    w = np.linspace(-0.95, 0.95, 39)
    g = np.exp(x_c + s * w)
    for up, pol in ((True, Polarity.SET), (False, Polarity.RESET)):
        want = np.abs(np.asarray(model.mean_dx(pol, g))) / s
        got = aihwkit_mean_step(p, w, up)
        # linear between 21 nodes: the curve within 5 % (docs/crossbar_model.md section 7)
        assert got == pytest.approx(want, rel=0.05, abs=1e-4 * p["dw_min"])
        nodes = np.linspace(-1, 1, 21)
        at = np.abs(np.asarray(model.mean_dx(pol, np.exp(x_c + s * nodes)))) / s
        assert aihwkit_mean_step(p, nodes, up) == pytest.approx(at, rel=1e-9, abs=1e-15)
    # the soft bounds: no SET step at w_max, no RESET step at w_min
    assert p["piecewise_up"][-1] == pytest.approx(0, abs=1e-12)
    assert p["piecewise_down"][0] == pytest.approx(0, abs=1e-12)
    assert p["dw_min_std"] == model.dw_min_std and p["dw_min_dtod"] == model.dw_min_dtod
    assert p["w_max_dtod"] == pytest.approx(model.g_max_dtod / s)
    assert doc["forward"]["w_noise"] == pytest.approx(model.read_noise / s)
    assert set(doc["mapping"]) >= {"dw_min", "up_down", "dw_min_std", "piecewise_up / "
                                   "piecewise_down", "forward.w_noise"}
    soft = doc["soft_bounds_device"]["parameters"]
    assert "piecewise_up" not in soft and soft["dw_min"] == p["dw_min"]


def test_crosssim_tables_read_back_with_the_models_mean_and_spread(model, tmp_path):
    written = write_crosssim(model, tmp_path / "lut")
    assert [p.name for p in written] == ["dG_increasing.txt", "dG_decreasing.txt",
                                         "lookup.json"]
    for name, pol in (("dG_increasing.txt", Polarity.SET), ("dG_decreasing.txt",
                                                             Polarity.RESET)):
        g, cdf, dg = read_crosssim_table(tmp_path / "lut" / name)
        assert np.allclose(np.diff(g), np.diff(g)[0]) and np.allclose(np.diff(cdf), 0.01)
        assert np.all(np.diff(dg, axis=0) * (1 if pol == Polarity.SET else -1) >= -1e-18)
        # CrossSim's mean update: the CDF-weighted average of the rows
        mean = (np.diff(cdf)[:, None] * dg[:-1]).sum(axis=0)
        want = model.mean_step_s(pol, g)
        inside = np.abs(want) > 1e-3 * np.abs(want).max()
        assert mean[inside] == pytest.approx(want[inside], rel=0.03)
    tables = crosssim_tables(model)
    assert set(tables) == {Polarity.SET, Polarity.RESET}


def test_export_device_command(tmp_path, model, capsys):
    path = tmp_path / "m.json"
    path.write_text(json.dumps(model.to_dict()))
    rc = cli.main(["export-device", str(path), "--aihwkit", str(tmp_path / "a.json"),
                   "--crosssim", str(tmp_path / "lut"), "--twin", str(tmp_path / "t.json")])
    assert rc == 0
    assert json.loads((tmp_path / "a.json").read_text())["device"]["class"] == \
        "PiecewiseStepDevice"
    twin = json.loads((tmp_path / "t.json").read_text())
    assert twin["format"] == "snan-hil-twin/1" and len(twin["cells"]) == 1
    # the written twin builds the same chip as the model's own
    spec = spec_from_mapping(twin)
    a, b = spec.build(seed=3), twin_spec(model, read_draws=10).build(seed=3)
    assert np.array_equal(a.cells.rate_set, b.cells.rate_set)
    assert a.config == b.config and spec.sources["cells"].startswith("fitted")
    assert (tmp_path / "lut" / "dG_decreasing.txt").is_file()
    capsys.readouterr()
    assert cli.main(["export-device", str(path)]) == 2
    assert "give --aihwkit" in capsys.readouterr().err
    (tmp_path / "x.json").write_text("{}")
    assert cli.main(["export-device", str(path), "--aihwkit", str(tmp_path / "x.json")]) == 2
    err = capsys.readouterr().err
    assert "x.json" in err and len(err.strip().splitlines()) == 1
