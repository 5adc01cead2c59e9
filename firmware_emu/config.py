"""Constants of the emulated MemriCore board: converters, read chain, limits, timing.

Defaults are the public facts about the board and its host software
(``shared/reference/memricore-board.md``): 12-bit DACs and a 14-bit ADC, both at a 5 V
reference, a 3000 Ohm load resistor, 10 Ohm of switches, an amplifier gain of 11, a 330 Ohm
column-sum transimpedance, a 2 mA current limit; SPI at 15 MHz, 6 us DAC settling, 200 kS/s ADC.
Values that are *assumptions* of this emulator (not published) are marked so below.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

from snan_hil.protocol.safety import floor_code

FIRMWARE_VERSION = (1, 0, 0)
"""Version of the emulated firmware (major, minor, patch)."""


@dataclass(frozen=True)
class TimingConfig:
    """Virtual-clock constants (Hz, us, samples/s, baud)."""

    spi_hz: float = 15e6
    """SPI clock of the MCU; every byte costs 8 / spi_hz."""
    dac_settle_us: float = 6.0
    """AD5328 output settling time after an update."""
    frontend_settle_us: float = 6.0
    """ASSUMPTION: wait after switching multiplexers / word line before sampling (the firmware
    uses the DAC settling time for every analog change)."""
    adc_rate_sps: float = 200e3
    """TLC3541 throughput: a conversion cycle (sample + convert) takes 1 / rate = 5 us."""
    adc_dummy: int = 1
    """Conversions discarded before averaging (the pipelined ADC returns the previous result)."""
    adc_average: int = 10
    """Conversions averaged per reading, as the real driver."""
    mcu_overhead_us: float = 4.0
    """CALIBRATED: MCU time per SPI transaction besides the clocked bits (chip-select GPIO
    toggling, HAL call, buffer handling). Not public; 4 us (~128 cycles of the 32 MHz MIK32, a
    plausible HAL-driver cost) makes the modelled spike (15 rows, 8 columns) cost the paper's
    ~700 us, the only published timing of the board. 1 us would give ~549 us."""
    uart_bits_per_byte: int = 10
    """8N1 framing: start + 8 data + stop bits."""


@dataclass(frozen=True)
class BoardConfig:
    """Electrical constants and safety limits of the board (V, Ohm, A, bits)."""

    rows: int = 32
    cols: int = 8
    dac_bits: int = 12
    vref_dac: float = 5.0
    adc_bits: int = 14
    vref_adc: float = 5.0
    v_read_max: float = 0.3
    """Interlock: largest read voltage (V); also the highest row-DAC code of a column read."""
    v_write_max: float = 1.4
    """Interlock: largest write-pulse amplitude (V), either polarity."""
    compliance_a: float = 2e-3
    """Interlock: largest predicted cell current of a write pulse (A) (host's soft_cc)."""
    r_load: float = 3000.0
    r_switches: float = 10.0
    gain: float = 11.0
    sum_gain: float = 330.0
    max_pulse_width_us: float = 1_000_000.0
    """Longest write pulse accepted (us)."""
    max_program_pulses: int = 1000
    """Upper bound of pulses one PROGRAM_CELL may apply."""
    board_id: int = 0x4D43_0001
    """Identifier reported by INFO (ASSUMPTION: arbitrary for the emulator)."""
    timing: TimingConfig = field(default_factory=TimingConfig)

    # -- converters -------------------------------------------------------------------------
    @property
    def dac_full_scale(self) -> int:
        return (1 << self.dac_bits) - 1

    @property
    def adc_full_scale(self) -> int:
        return (1 << self.adc_bits) - 1

    def dac_volts(self, code: int) -> float:
        """DAC code -> volts, V = code * Vref / (2^bits - 1) (the host's formula)."""
        return code * self.vref_dac / self.dac_full_scale

    def dac_code(self, volts: float) -> int:
        """Volts -> nearest DAC code, clipped to the code range."""
        code = round(volts * self.dac_full_scale / self.vref_dac)
        return int(min(max(code, 0), self.dac_full_scale))

    def floor_code(self, volts: float) -> int:
        """Largest DAC code whose voltage does not exceed ``volts`` (a hard limit in V)."""
        return floor_code(volts, self.dac_code, self.dac_volts)

    @property
    def read_code_max(self) -> int:
        """Largest read DAC code: the largest code at or below v_read_max (245 = 0.2991 V for
        0.3 V; code 246 = 0.3004 V, the old host's "0.3 V" read, is above the limit)."""
        return self.floor_code(self.v_read_max)

    @property
    def write_code_max(self) -> int:
        """Largest write-pulse DAC code: the largest code at or below v_write_max (1146 =
        1.3993 V for 1.4 V)."""
        return self.floor_code(self.v_write_max)

    def as_dict(self) -> dict:
        return asdict(self)
