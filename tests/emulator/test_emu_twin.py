"""The emulator's chip as the twin of a fitted device model (issue 36 point 2): ``emu://
?device=FILE``, ``--port emu --device FILE``, ``snan-hil emu --device FILE``; the twin kept in
its own chip file, a chip of another model (or none) refused in one line."""

import dataclasses
import json

import numpy as np
import pytest

from snan_hil.calibration.characterize import CharacterizeConfig
from snan_hil.crossbar_model import CrossbarArray
from snan_hil.crossbar_model.characterize import device_truth
from snan_hil.crossbar_model.device_twin import load_device_model, model_digest, twin_spec
from snan_hil.firmware_emu.faults import parse_faults
from snan_hil.firmware_emu.protocol_emu import EmuUrl, emu_url
from snan_hil.firmware_emu.state import TwinDevice, twin_state_path
from snan_hil.firmware_emu.testing import lossy_inprocess_client
from snan_hil.lab.ports import open_client
from snan_hil.tools import cli

CELLS = [(0, 0), (0, 1), (3, 2), (5, 7)]


@pytest.fixture(scope="module")
def model_file(tmp_path_factory):
    """A device model of 4 cells of the default chip (seed 3: not the seed the twins use),
    with a read noise, as a JSON file."""
    cfg = CharacterizeConfig()
    truth, c2c = device_truth(CrossbarArray(seed=3), CELLS, cfg.pulse, g_ref_s=cfg.g_ref_s,
                              g_low_s=cfg.g_low_s, g_high_s=cfg.g_high_s, c2c_pulses=40)
    model = dataclasses.replace(truth, dw_min_std=c2c, read_noise=0.003)
    path = tmp_path_factory.mktemp("model") / "model.json"
    path.write_text(json.dumps(model.to_dict()))
    return path


def test_emu_url_device_makes_the_twin_and_keeps_it(tmp_path, model_file):
    state = tmp_path / "twin.npz"
    client, emu = lossy_inprocess_client(state, seed=1, device=str(model_file))
    arr = emu.array
    spec = twin_spec(load_device_model(model_file), read_draws=10)
    for c in spec.cells:
        assert arr.cells.rate_set[c.row, c.col] == pytest.approx(c.rate_set)
        assert arr.cells.g_min[c.row, c.col] == pytest.approx(c.g_min_s)
        assert not arr.stuck_mask[c.row, c.col]
    assert arr.config.read_noise.relative_sigma == pytest.approx(0.003 * np.sqrt(10))
    assert emu.store.meta["device"]["digest"] == model_digest(load_device_model(model_file))
    client.close()
    # opened again with the model: the same chip (its serial), loaded not remade
    client, emu = lossy_inprocess_client(state, seed=1, device=str(model_file))
    assert emu.store.replayed is not None and emu.array.meta["device"]
    client.close()


def test_a_chip_of_another_kind_is_refused_in_one_line(tmp_path, model_file, capsys,
                                                       monkeypatch):
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "data"))
    plain = tmp_path / "plain.npz"
    client, _emu = lossy_inprocess_client(plain, seed=0)
    client.close()
    rc = cli.main(["info", "--port", f"emu://?state={plain}", "--device", str(model_file)])
    err = capsys.readouterr().err
    assert rc == 2 and "not the twin of" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


def test_port_emu_device_keeps_each_model_in_its_own_chip_file(tmp_path, model_file,
                                                                monkeypatch, capsys):
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "data"))
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(tmp_path / "default.npz"))
    rc = cli.main(["read-cell", "--port", "emu", "--device", str(model_file), "--cell", "0,0"])
    capsys.readouterr()
    assert rc == 0
    twin = twin_state_path(model_file)
    assert twin.is_file() and twin.parent.name == "twins"
    assert not (tmp_path / "default.npz").exists()          # the user's chip untouched
    assert TwinDevice.load(model_file).digest == \
        CrossbarArray.load(str(twin)).meta["device"]["digest"]


def test_bad_device_options_are_one_line(tmp_path, model_file, capsys, monkeypatch):
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "data"))
    bad = tmp_path / "bad.json"
    bad.write_text('{"format": "something-else"}')
    for argv, text in ((["--port", "emu", "--device", str(tmp_path / "none.json")],
                        "does not exist"),
                       (["--port", "emu", "--device", str(bad)], "not a device model"),
                       (["--port", "socket://127.0.0.1:5999", "--device", str(model_file)],
                        "not the in-process emulator")):
        assert cli.main(["info", *argv]) == 2
        err = capsys.readouterr().err
        assert text in err and "Traceback" not in err, err
        assert len(err.strip().splitlines()) == 1


def test_snan_hil_emu_reset_chip_with_a_device(tmp_path, model_file, capsys):
    state = tmp_path / "served.npz"
    assert cli.main(["emu", "--reset-chip", "--state", str(state), "--device",
                     str(model_file)]) == 0
    assert "the twin of" in capsys.readouterr().out
    arr = CrossbarArray.load(str(state))
    assert arr.meta["device"]["digest"] == TwinDevice.load(model_file).digest


def test_a_faulty_board_around_a_twin_chip(tmp_path, model_file):
    """``?fault=`` (the board's hardware) and ``?device=`` (the chip) together: the chip is
    the model's twin and the board's fault changes what it measures, as on the packaged chip."""
    def zero_read(name: str, fault: str | None) -> int:
        url = emu_url(tmp_path / f"{name}.npz", seed=1, device=model_file,
                      faults=parse_faults(fault) if fault else None)
        parsed = EmuUrl.parse(url)
        assert parsed.device == model_file
        assert parsed.faults.any == (fault is not None)
        client = open_client(url)
        try:
            return int(client.read_cell(9, 2, 0))
        finally:
            client.close()

    healthy = zero_read("healthy", None)
    assert zero_read("faulty", "adc-stuck-bit:6:1") == 64 + healthy
    digest = TwinDevice.load(model_file).digest
    for name in ("healthy", "faulty"):
        assert CrossbarArray.load(str(tmp_path / f"{name}.npz")).meta["device"]["digest"] \
            == digest
