"""Weight map and read chain: inverses, and calibration of a board whose gain is not nominal."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from snan_hil.calibration.mapping import WeightMap
from snan_hil.calibration.readchain import ReadChain, calibrate_read_chain
from snan_hil.common.errors import UserError
from snan_hil.firmware_emu.config import BoardConfig
from snan_hil.firmware_emu.emulator import Emulator
from snan_hil.protocol.link import LinkClient
from snan_hil.protocol.messages import Info
from snan_hil.protocol.transport import CallbackTransport

R_T = 150.0   # the crossbar model's select transistor (part of the "cell" conductance)


def test_weight_map_endpoints_and_inverse():
    wm = WeightMap(50e-6, 1e-3)
    assert wm.conductance(0) == pytest.approx(50e-6)
    assert wm.conductance(1) == pytest.approx(1e-3)
    assert wm.conductance(0.65) == pytest.approx(1 / 1500, rel=0.01)  # the paper's 1.5 kOhm
    w = np.linspace(0, 1, 11)
    np.testing.assert_allclose(wm.weight(wm.conductance(w)), w, atol=1e-12)
    assert wm.weight(2e-3) == 1.0 and wm.weight(2e-3, clip=False) > 1.0
    for bad in ((1e-3, 5e-5), (0.0, 1e-3), (float("nan"), 1e-3)):
        with pytest.raises(UserError):
            WeightMap(*bad)


@given(g=st.floats(5e-6, 3e-3), code=st.integers(20, 246), off=st.floats(-3, 3),
       gain=st.floats(0.8, 1.2))
def test_chain_conversions_invert(g, code, off, gain):
    chain = ReadChain(offset_code=off, offset_column_code=off / 2, gain_factor=gain)
    assert chain.cell_conductance(chain.cell_code(g, code), code) == pytest.approx(g, rel=1e-9)
    assert chain.column_cell_conductance(chain.column_code(g, code), code) == \
        pytest.approx(g, rel=1e-9)


def test_nominal_chain_matches_the_board_reference_formula():
    info = Info()
    chain = ReadChain.nominal(info)
    assert chain.read_code == info.read_code == 245   # 245 * 5 / 4095 <= 0.3 V
    assert info.dac_volts(246) > 0.3
    adc = 5000
    v = 245 * 5 / 4095
    r_host = 11 * 3000 * v * 2 ** 14 / (adc * 5) - 10 - 3000   # memricore-board.md
    assert chain.cell_resistance(adc) == pytest.approx(r_host)
    assert chain.cell_conductance(0) == 0.0                    # open cell, no division error


def _client_for(emu: Emulator) -> LinkClient:
    client = LinkClient(CallbackTransport(emu.feed, name="emu"), retries=2)
    client.hello()
    return client


def test_calibration_identifies_a_gain_error_the_board_does_not_report(mcu):
    # The board's amplifier has gain 10.45 while it announces the nominal 11 (5 % error).
    emu = Emulator(None, seed=4, config=BoardConfig(gain=10.45), mcu=mcu)
    if emu.firmware is not None:        # the C firmware announces its built-in constants
        announced = emu.firmware.info
        emu.firmware.info = lambda: {**announced(), "gain": 11.0}
    client = _client_for(emu)
    assert client.info.gain == 11.0
    array = emu.array
    cells = [(r, c) for r in range(4) for c in range(8)]
    g_true = {rc: 1 / (1 / array.conductance()[rc] + R_T) for rc in cells}
    ranked = sorted(cells, key=lambda rc: g_true[rc], reverse=True)
    chain = calibrate_read_chain(client, ranked[10:14], ranked[:6], n_reads=8)
    assert chain.calibrated
    assert chain.gain_factor == pytest.approx(10.45 / 11.0, rel=0.005)
    nominal = ReadChain.nominal(client.info)
    errs_cal, errs_nom = [], []
    for rc in ranked[:12]:
        adc = np.mean([client.read_cell(*rc) for _ in range(10)])
        errs_cal.append(abs(chain.cell_conductance(adc) / g_true[rc] - 1))
        errs_nom.append(abs(nominal.cell_conductance(adc) / g_true[rc] - 1))
    # calibrated: within read noise (1 % per read -> 0.32 % for a mean of 10; 3 sigma) plus the
    # 0.5 % tolerance of the fitted gain factor
    assert max(errs_cal) < 3 * 0.01 / np.sqrt(10) + 0.005
    assert min(errs_nom) > 0.03           # nominal constants: several percent off
    assert chain.details["linearity_error"] < 0.01


def test_calibration_on_a_nominal_board_keeps_gain_near_one(mcu):
    emu = Emulator(None, seed=5, mcu=mcu)
    client = _client_for(emu)
    chain = calibrate_read_chain(client, [(0, 0), (1, 1)], [(2, 2), (3, 3), (4, 4)], n_reads=6)
    assert chain.gain_factor == pytest.approx(1.0, abs=0.005)
    assert abs(chain.offset_code) < 1.0
