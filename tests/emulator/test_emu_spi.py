"""Register-level SPI device models: AD5328, write DAC, TLC3541, 74HC595, bus timing."""

import pytest

from snan_hil.firmware_emu.clock import VirtualClock
from snan_hil.firmware_emu.config import TimingConfig
from snan_hil.firmware_emu.spi_devices import (AD5328, ShiftRegister595, SpiBus, TLC3541,
                                               WriteDac)


def test_ad5328_data_word_layout_and_continuous_update():
    dac = AD5328("D")
    # After reset the LDAC mode holds outputs: a data word loads only the input register.
    dac.frame(AD5328.data_word(5, 0xABC), 0.0)
    assert dac.input_reg[5] == 0xABC and dac.dac_reg[5] == 0
    assert AD5328.data_word(5, 0xABC) == bytes((0x5A, 0xBC))  # address nibble, 12-bit code
    # LDAC control word "00" (continuous): pending inputs load, later writes go straight out.
    dac.frame(bytes((0xA0, 0x00)), 0.0)
    assert dac.dac_reg[5] == 0xABC
    dac.frame(AD5328.data_word(0, 4095), 0.0)
    assert dac.output_volts(0) == pytest.approx(5.0)
    assert dac.output_volts(5) == pytest.approx(0xABC * 5.0 / 4095)


def test_ad5328_hold_mode_and_single_ldac_pulse():
    dac = AD5328("D")
    dac.frame(AD5328.control_word(0b01, 0b01), 0.0)   # hold
    dac.frame(AD5328.data_word(2, 1000), 0.0)
    dac.frame(AD5328.data_word(3, 2000), 0.0)
    assert dac.outputs()[2:4] == [0.0, 0.0]
    dac.frame(AD5328.control_word(0b01, 0b10), 0.0)   # one LDAC pulse: both update together
    assert dac.dac_reg[2:4] == [1000, 2000]
    dac.frame(AD5328.data_word(2, 10), 0.0)           # still holding afterwards
    assert dac.dac_reg[2] == 1000


def test_ad5328_gain_power_down_and_reset():
    dac = AD5328("D")
    dac.frame(AD5328.control_word(0b01, 0b00), 0.0)
    dac.frame(AD5328.data_word(1, 1000), 0.0)          # channel B (group A-D)
    dac.frame(AD5328.data_word(6, 1000), 0.0)          # channel G (group E-H)
    dac.frame(AD5328.control_word(0b00, 0x10), 0.0)    # GAIN bit of A-D only
    assert dac.output_volts(1) == pytest.approx(2 * 1000 * 5.0 / 4095)
    assert dac.output_volts(6) == pytest.approx(1000 * 5.0 / 4095)
    dac.frame(AD5328.data_word(1, 4095), 0.0)
    assert dac.output_volts(1) == pytest.approx(5.0)   # clipped to VDD
    dac.frame(AD5328.control_word(0b10, 1 << 6), 0.0)  # power down channel G
    assert dac.output_volts(6) == 0.0 and dac.output_volts(1) > 0
    dac.frame(AD5328.control_word(0b11, 0x0000), 0.0)  # data reset keeps control
    assert dac.dac_reg == [0] * 8 and dac.gain2[0]
    dac.frame(bytes((0xF0, 0x00)), 0.0)                # data + control reset
    assert not dac.gain2[0] and dac.ldac_mode == AD5328.LDAC_HOLD


def test_ad5328_short_frame_is_ignored_and_counted():
    dac = AD5328("D")
    dac.frame(bytes((0xA0, 0x00)), 0.0)
    dac.frame(bytes((0x1F,)), 0.0)
    assert dac.framing_errors == 1 and dac.dac_reg == [0] * 8


def test_write_dac_word_and_power_down():
    wdac = WriteDac()
    wdac.frame(WriteDac.data_word(246), 0.0)
    assert wdac.output_volts() == pytest.approx(246 * 5.0 / 4095)
    wdac.frame(bytes((0x30 | 0x00, 246)), 0.0)          # PD bits 11: three-state
    assert wdac.output_volts() == 0.0


def test_tlc3541_returns_previous_conversion_in_driver_format():
    values = iter([0x3FFF, 0x1234, 5])
    adc = TLC3541(lambda: next(values), cycle_us=5.0)
    first = adc.frame(b"\0\0", 0.0)
    assert TLC3541.decode(*first) == 0           # nothing converted yet: stale result
    second = adc.frame(b"\0\0", 5.0)
    assert TLC3541.decode(*second) == 0x3FFF
    assert second == bytes((0xFF, 0xFC))        # 14 bits MSB first, then two zero bits
    assert TLC3541.decode(*adc.frame(b"\0\0", 10.0)) == 0x1234
    assert adc.ready_at_us() == pytest.approx(15.0)


def test_74hc595_latches_last_byte_and_shifts_out_previous():
    sr = ShiftRegister595("SR")
    seen = []
    sr.on_change(lambda: seen.append(sr.latch))
    assert sr.frame(b"\x13", 0.0) == b"\x00"
    assert sr.latch == 0x13
    assert sr.frame(b"\xaa\x55", 0.0) == b"\x13\xaa"   # daisy-chain output QH'
    assert sr.latch == 0x55 and seen == [0x13, 0x55]


def test_bus_timing_15mhz_overhead_and_adc_cycle():
    timing = TimingConfig(mcu_overhead_us=1.0)
    clock = VirtualClock(timing)
    bus = SpiBus(clock)
    bus.attach("SR", ShiftRegister595("SR"))
    bus.attach("ADC", TLC3541(lambda: 0, cycle_us=clock.adc_cycle_us))
    bus.transfer("SR", b"\x01")
    assert clock.now_us == pytest.approx(1.0 + 8 / 15.0)
    t = clock.now_us
    bus.transfer("ADC", b"\0\0")
    bus.transfer("ADC", b"\0\0")
    # The second conversion cannot start before 1 / 200 kS/s after the first started.
    first_start = t + 1.0
    assert clock.now_us == pytest.approx(first_start + 5.0 + 16 / 15.0)
    assert clock.breakdown_us["adc"] == pytest.approx(5.0 - 1.0 - 16 / 15.0)
    assert bus.transactions == 3 and bus.bytes == 5
