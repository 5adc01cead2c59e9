"""The board's constants, defined once: reference values, converters, and who extends them."""

import dataclasses

import pytest

from snan_hil.calibration.readchain import ReadChain
from snan_hil.firmware_emu.config import BoardConfig
from snan_hil.protocol.board import MEMRICORE, PROGRAM_RAMP_V, BoardConstants
from snan_hil.protocol.messages import Info

BASE = {f.name for f in dataclasses.fields(BoardConstants)}


def test_memricore_values_are_the_board_reference():
    # shared/reference/memricore-board.md: 0.3 V reads (the old host's code 246 is above it),
    # writes up to 1.4 V (the old host rounds to 1147), 3.0 V is write-DAC code 2457
    assert MEMRICORE.dac_code(0.3) == 246 and MEMRICORE.read_code == 245
    assert MEMRICORE.max_write_code == 1146 and MEMRICORE.write_dac_code(1.4) == 1147
    assert MEMRICORE.write_dac_code(3.0) == 2457
    assert MEMRICORE.v_read_v == pytest.approx(0.29915, abs=1e-5)
    assert MEMRICORE.program_ramp_codes() == (246, 983, 8)
    assert PROGRAM_RAMP_V == (0.3, 1.2, 0.01)
    assert (MEMRICORE.dac_full_scale_code, MEMRICORE.adc_full_scale_code) == (4095, 16383)


@pytest.mark.parametrize("limit_v", [0.1, 0.25, 0.3, 0.77, 1.4, 4.9])
def test_floor_codes_never_exceed_the_limit(limit_v):
    b = BoardConstants(max_read_v=limit_v, max_write_v=limit_v)
    for code, volts in ((b.max_read_code, b.dac_volts), (b.max_write_code, b.write_dac_volts)):
        assert volts(code) <= limit_v < volts(code + 1)


def test_read_limit_holds_on_both_dacs():
    # a cell read uses the write DAC, a column read the row DACs: the read code fits both
    b = BoardConstants(dac_vref_v=2.5)
    assert b.max_read_code == min(b.dac_floor_code(0.3), b.write_dac_floor_code(0.3))
    assert b.write_dac_volts(b.max_read_code) <= 0.3 and b.dac_volts(b.max_read_code) <= 0.3


def test_cell_and_column_formulas_are_the_reference_ones():
    b = MEMRICORE
    v = b.read_code * 5.0 / 4095
    adc = 5000
    r_ref = 11 * 3000 * v * 2 ** 14 / (adc * 5.0) - 10 - 3000        # host's cell formula
    assert b.cell_resistance(adc) == pytest.approx(r_ref)
    x = 2500.0                                                        # a cell of 2.5 kOhm
    i = v / (x + 10)                                                  # column at virtual ground
    assert b.column_code(1 / x) == pytest.approx(2 ** 14 * i * 330 * 11 / 5.0)
    assert b.column_current_a(b.column_code(1 / x)) == pytest.approx(i)
    assert b.cell_conductance(0) == 0.0                               # open cell


def test_impossible_constants_are_refused_with_their_name():
    for name, value in (("dac_vref_v", 0.0), ("adc_bits", 17), ("rows", 0),
                        ("max_read_v", -0.1), ("compliance_a", float("inf"))):
        with pytest.raises(ValueError, match=name):
            BoardConstants(**{name: value})


def test_extensions_add_only_their_own_fields():
    emulator = {f.name for f in dataclasses.fields(BoardConfig)} - BASE
    assert emulator == {"max_pulse_width_us", "max_program_pulses", "board_id",
                        "row_dac_vdd_v", "timing", "on_board_learning"}
    fitted = {f.name for f in dataclasses.fields(ReadChain)} - BASE
    assert fitted == {"offset_code", "offset_column_code", "gain_factor", "calibrated",
                      "details"}
    link = {f.name for f in dataclasses.fields(Info)} - BASE
    assert link == {"protocol_version", "firmware_version", "board_id", "max_payload",
                    "capabilities", "boot_nonce"}
    assert list(Info().to_dict()) == list(Info.WIRE_FIELDS)
    assert set(Info.WIRE_FIELDS) == link | BASE | {"v_read_v", "read_code"}


def test_info_and_read_chain_carry_the_board_they_were_built_from():
    board = BoardConstants(gain=10.0, r_load_ohm=2000.0, max_read_v=0.25)
    info = Info.from_board(BoardConfig(gain=10.0, r_load_ohm=2000.0, max_read_v=0.25),
                           board_id="x")
    assert info.board == board and Info.decode(info.encode()).board == board
    chain = ReadChain.nominal(info)
    assert chain.board == board and chain.read_code == board.read_code
    assert chain.cell_conductance(3000) == board.cell_conductance(3000)
