"""``map`` converts ADC codes with the same read chain as every calibrated read, so they agree.

The board below has an amplifier gain 5 % below what it announces (10.45 instead of 11), and no
read or ADC noise, so a cell reads the same code every time: ``map`` (with the calibrated chain)
and write-and-verify's calibrated read (``BoardCellIO.read``) must then give the same conductance
to the last bit, and both must be near the true one; the nominal map must not.
"""

import csv
import dataclasses

import numpy as np
import pytest

from snan_hil.calibration.board_io import BoardCellIO, CellLimits, PulseLedger
from snan_hil.calibration.layout import Layout
from snan_hil.calibration.readchain import calibrate_read_chain
from snan_hil.firmware_emu.config import BoardConfig
from snan_hil.firmware_emu.emulator import Emulator
from snan_hil.firmware_emu.testing import ideal_array
from snan_hil.protocol.link import LinkClient
from snan_hil.protocol.transport import CallbackTransport
from snan_hil.tools import cli
from snan_hil.calibration.cellmap import read_map

ANNOUNCED = BoardConfig()
ACTUAL_GAIN = ANNOUNCED.gain * 0.95


def _board(mcu="model"):
    array = ideal_array(4)
    emu = Emulator(None, seed=4, config=dataclasses.replace(ANNOUNCED, gain=ACTUAL_GAIN),
                   array=array, adc_noise_lsb=0.0, mcu=mcu)
    if emu.firmware is not None:        # the C firmware announces its built-in constants
        announced = emu.firmware.info
        emu.firmware.info = lambda: {**announced(), "gain": ANNOUNCED.gain}
    client = LinkClient(CallbackTransport(emu.feed, name="emu"))
    client.hello()
    r_t = array.config.transistor.on_resistance_ohm
    g_true = 1.0 / (1.0 / array.conductance() + r_t)
    return client, g_true


def test_map_and_calibrated_reads_agree_on_every_cell(mcu):
    client, g_true = _board(mcu)
    cells = [(r, c) for r in range(6) for c in range(8)]
    ranked = sorted(cells, key=lambda rc: g_true[rc], reverse=True)
    chain = calibrate_read_chain(client, ranked[20:24], ranked[:6], n_reads=4)
    assert chain.gain_factor == pytest.approx(0.95, rel=0.005)

    cmap = read_map(client, chain=chain)
    nominal = read_map(client)
    limits = CellLimits.of(client.limits, client.info)
    for row, col in [(0, 0), (3, 5), (5, 7), (17, 2), (31, 7)]:
        io = BoardCellIO(client, chain, row, col, limits, PulseLedger())
        assert cmap.conductance()[row, col] == io.read()          # same code, same converter
        assert cmap.conductance()[row, col] == pytest.approx(g_true[row, col], rel=0.01)
        assert abs(nominal.conductance()[row, col] / g_true[row, col] - 1) > 0.03


def test_map_command_uses_the_layout_calibration(tmp_path, monkeypatch, capsys, mcu):
    chip = tmp_path / "chip.npz"
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(chip))
    client, _ = _board(mcu)
    chain = calibrate_read_chain(client, [(0, 0), (1, 1)], [(2, 2), (3, 3)], n_reads=2)
    layout = Layout.place((3, 3), (32, 8))
    layout.read_chain = dataclasses.replace(chain, gain_factor=0.9)   # clearly not nominal
    layout_path = layout.save(tmp_path / "layout.json")
    out = tmp_path / "map.csv"
    assert cli.main(["map", "--port", "emu", "--mcu", mcu, "--layout", str(layout_path),
                     "--csv", str(out)]) == 0
    printed = capsys.readouterr().out.replace("\n", "")
    assert "converted with the calibrated read chain of" in printed and "layout.json" in printed
    with open(out) as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 32 * 8
    loaded = Layout.load(layout_path).chain
    code = loaded.read_code
    for row in rows[:40]:
        adc = int(row["adc"])
        g = float(row["conductance_s"])
        assert g == pytest.approx(loaded.cell_conductance(adc, code), rel=1e-5)
        if adc > 0:
            assert not np.isclose(g, client.info.cell_conductance(adc, code), rtol=0.05)
