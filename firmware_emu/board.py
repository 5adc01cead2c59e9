"""The emulated board's hardware: virtual clock, SPI bus, the six SPI chips and the front end.

``Board(array)`` wires four :class:`AD5328` row DACs (chip selects DAC0..DAC3, rows 8k..8k+7),
the write DAC (WDAC), the TLC3541 ADC (ADC) and the two 74HC595 registers (SR_ROW, SR_COL) to
one :class:`SpiBus`, and connects them to an :class:`AnalogFrontEnd` over the crossbar
``array`` (anything with the ``CrossbarArray`` interface of :mod:`snan_hil.crossbar_model`).
The firmware (:mod:`snan_hil.firmware_emu.firmware`) talks to the hardware only through
``board.bus``.
"""

from __future__ import annotations

from snan_hil.firmware_emu import registers as reg
from snan_hil.firmware_emu.analog import AnalogFrontEnd
from snan_hil.firmware_emu.clock import VirtualClock
from snan_hil.firmware_emu.config import BoardConfig
from snan_hil.firmware_emu.spi_devices import (AD5328, ShiftRegister595, SpiBus, TLC3541,
                                               WriteDac)

DEFAULT_ADC_NOISE_LSB = 0.5
"""ASSUMPTION: ADC input-referred noise (LSB rms); TLC3541 typical SNR ~81 dB at 14 bits."""


class Board:
    """Hardware of one emulated MemriCore board around a crossbar ``array``."""

    def __init__(self, array, config: BoardConfig | None = None, *, seed: int = 0,
                 baud: int = 115200, adc_noise_lsb: float = DEFAULT_ADC_NOISE_LSB):
        self.config = config or BoardConfig()
        self.array = array
        self.clock = VirtualClock(self.config.timing, baud)
        self.bus = SpiBus(self.clock)
        cfg = self.config
        self.row_dacs = [AD5328(name, vref=cfg.dac_vref_v, vdd=cfg.row_dac_vdd_v, bits=cfg.dac_bits)
                         for name in reg.CS_ROW_DAC]
        self.write_dac = WriteDac(reg.CS_WRITE_DAC, vref=cfg.write_dac_vref_v,
                                  bits=cfg.write_dac_bits)
        self.sr_row = ShiftRegister595(reg.CS_SR_ROW)
        self.sr_col = ShiftRegister595(reg.CS_SR_COL)
        self.front_end = AnalogFrontEnd(array, cfg, self.clock, self.row_dacs, self.write_dac,
                                        self.sr_row, self.sr_col, adc_noise_lsb=adc_noise_lsb,
                                        seed=seed)
        self.adc = TLC3541(self.front_end.sample_code, self.clock.adc_cycle_us, reg.CS_ADC,
                           sample_many=self.front_end.sample_codes)
        for cs, dev in zip(reg.CS_ROW_DAC, self.row_dacs):
            self.bus.attach(cs, dev)
        self.bus.attach(reg.CS_WRITE_DAC, self.write_dac)
        self.bus.attach(reg.CS_ADC, self.adc)
        self.bus.attach(reg.CS_SR_ROW, self.sr_row)
        self.bus.attach(reg.CS_SR_COL, self.sr_col)

    def power_cycle(self) -> None:
        """Power-on state of every chip (registers cleared, DAC control at reset defaults)."""
        for dac in self.row_dacs:
            dac.power_on_reset()
        self.write_dac.code = 0
        self.write_dac.power_down = 0
        self.sr_row.shift = self.sr_row.latch = 0
        self.sr_col.shift = self.sr_col.latch = 0
        self.front_end._row_volts = None
        self.front_end.update()
