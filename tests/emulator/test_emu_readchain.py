"""The emulated read chain against the host software's formulas, and the SPI trace of a read."""

import numpy as np
import pytest

from snan_hil.firmware_emu import registers as reg
from snan_hil.firmware_emu.spi_devices import TLC3541
from snan_hil.firmware_emu.testing import make_firmware

# Defaults of the existing host software (shared/reference/memricore-board.md).
DAC_BITS, VREF_DAC, ADC_BITS, VREF_ADC = 12, 5.0, 14, 5.0
R_LOAD, R_SW, GAIN, SUM_GAIN = 3000.0, 10.0, 11.0, 330.0


def dac_volts(code):
    return code * VREF_DAC / (2 ** DAC_BITS - 1)


def host_resistance(adc, v_read):
    """R = gain * R_load * V_read * 2^adc_bit / (adc * Vref_adc) - R_sw - R_load."""
    return GAIN * R_LOAD * v_read * 2 ** ADC_BITS / (adc * VREF_ADC) - R_SW - R_LOAD


@pytest.mark.parametrize("g_target", [5e-5, 1.5e-4, 6.67e-4, 1e-3])
def test_cell_read_inverts_with_host_formula(g_target):
    fw = make_firmware()
    array = fw.board.array
    array.set_conductance(4, 3, g_target)
    g = array.conductance()[4, 3]
    r_on = array.config.transistor.on_resistance_ohm
    adc = fw.read_cell(4, 3, 245)
    v_read = dac_volts(245)
    r = host_resistance(adc, v_read)
    # The formula gives memristor + select transistor; quantisation allows half an LSB.
    half_lsb = abs(host_resistance(adc - 0.5, v_read) - host_resistance(adc + 0.5, v_read)) / 2
    assert r == pytest.approx(1 / g + r_on, abs=half_lsb + 1e-9)
    assert v_read == pytest.approx(0.3, abs=1e-3)


def test_column_read_matches_sum_formula():
    fw = make_firmware()
    array = fw.board.array
    rng = np.random.default_rng(3)
    for row in range(32):
        array.set_conductance(row, 5, rng.uniform(5e-5, 3e-4))
    codes = rng.integers(0, 120, size=32)
    adc = fw.read_column(list(codes), 5)
    currents = dac_volts(codes) * array.effective_conductance()[:, 5]
    expected = 2 ** ADC_BITS * currents.sum() * SUM_GAIN * GAIN / VREF_ADC
    assert 0 < expected < 2 ** ADC_BITS - 1
    assert adc == pytest.approx(expected, abs=1.0)


def test_column_read_saturates_and_flags_it():
    fw = make_firmware()
    for row in range(32):
        fw.board.array.set_conductance(row, 0, 1e-3)
    adc = fw.read_column([245] * 32, 0)
    assert adc == 2 ** ADC_BITS - 1
    assert fw.last_saturated
    assert fw.counters.saturated_reads == 1
    assert fw.board.front_end.saturated_samples >= 10
    fw.read_column([10] + [0] * 31, 0)
    assert not fw.last_saturated


def test_adc_noise_is_averaged():
    fw = make_firmware(adc_noise_lsb=3.0)
    reads = [fw.read_cell(0, 0, 245) for _ in range(40)]
    # Ten conversions per reading: spread of readings ~ 3/sqrt(10) LSB, far below 3 LSB.
    assert 0 < np.std(reads) < 2.0


def test_spi_trace_of_one_cell_read():
    fw = make_firmware()
    bus = fw.board.bus
    row, col, code = 21, 6, 245
    bus.start_trace()
    adc = fw.read_cell(row, col, code)
    trace = bus.stop_trace()
    frames = [(t.cs, t.mosi) for t in trace]
    assert frames[0] == (reg.CS_SR_COL, bytes((reg.WL_EN | col,)))
    # Bit line 21 sits on the second multiplexer (16-31) at address 5.
    assert frames[1] == (reg.CS_SR_ROW, bytes((reg.MUX_HI_EN | 5,)))
    assert frames[2] == (reg.CS_WRITE_DAC, bytes((0x00, 0xF5)))     # code 245
    adc_frames = trace[3:14]
    assert all(t.cs == reg.CS_ADC and t.mosi == b"\0\0" for t in adc_frames)
    assert frames[14:] == [(reg.CS_SR_COL, b"\x00"), (reg.CS_SR_ROW, b"\x00"),
                           (reg.CS_WRITE_DAC, b"\x00\x00")]
    # Sampling starts only after the 6 us settling of the DAC; conversions are >= 5 us apart.
    assert adc_frames[0].t_us - trace[2].t_us >= 6.0
    starts = np.array([t.t_us for t in adc_frames])
    assert np.all(np.diff(starts) >= 5.0 - 1e-9)
    # The first (dummy) frame carries the stale previous result; the driver averages the
    # next ten, decoded as (b0 << 6) | (b1 >> 2).
    values = [TLC3541.decode(*t.miso) for t in adc_frames]
    assert values[0] != adc
    assert abs(adc - sum(values[1:]) / 10) <= 0.5
    for line in map(str, trace):
        assert "MOSI" in line and "MISO" in line
