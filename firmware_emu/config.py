"""The emulated MemriCore board: its constants plus what only the emulator needs.

:class:`BoardConfig` is a :class:`~snan_hil.protocol.board.BoardConstants` (converters, read
chain, safety limits: the one definition the host, the INFO message and the calibration use)
extended with emulator-only fields: the longest pulse and PROGRAM_CELL pulse budget the emulated
firmware accepts, the board id it reports, the row-DAC supply and the virtual-clock timing
(:class:`TimingConfig`: SPI at 15 MHz, 6 us DAC settling, 200 kS/s ADC, from
``shared/reference/memricore-board.md``). Values that are *assumptions* of this emulator (not
published) are marked so below.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from snan_hil.protocol.board import (ADC_DUMMY_CONVERSIONS, ADC_RATE_SPS, DAC_SETTLE_US,
                                     SPI_HZ, BoardConstants)
from snan_hil.protocol.transport import BITS_PER_BYTE

FIRMWARE_VERSION = (1, 0, 0)
"""Version of the emulated firmware (major, minor, patch)."""


@dataclass(frozen=True)
class TimingConfig:
    """Virtual-clock constants (Hz, us, samples/s, baud)."""

    spi_hz: float = SPI_HZ
    """SPI clock of the MCU; every byte costs 8 / spi_hz."""
    dac_settle_us: float = DAC_SETTLE_US
    """AD5328 output settling time after an update."""
    frontend_settle_us: float = 6.0
    """ASSUMPTION: wait after switching multiplexers / word line before sampling (the firmware
    uses the DAC settling time for every analog change)."""
    adc_rate_sps: float = ADC_RATE_SPS
    """TLC3541 throughput: a conversion cycle (sample + convert) takes 1 / rate = 5 us."""
    adc_dummy: int = ADC_DUMMY_CONVERSIONS
    """Conversions discarded before averaging (the pipelined ADC returns the previous result);
    the conversions averaged are the board's ``adc_averages``."""
    mcu_overhead_us: float = 4.0
    """CALIBRATED: MCU time per SPI transaction besides the clocked bits (chip-select GPIO
    toggling, HAL call, buffer handling). Not public; 4 us (~128 cycles of the 32 MHz MIK32, a
    plausible HAL-driver cost) makes the modelled spike (15 rows, 8 columns) cost the paper's
    ~700 us, the only published timing of the board. 1 us would give ~549 us."""
    uart_bits_per_byte: int = BITS_PER_BYTE
    """8N1 framing: start + 8 data + stop bits."""


@dataclass(frozen=True)
class BoardConfig(BoardConstants):
    """The board's constants (all fields of BoardConstants) plus the emulator's own."""

    max_pulse_width_us: float = 1_000_000.0
    """Longest write pulse accepted (us)."""
    max_program_pulses: int = 1000
    """Upper bound of pulses one PROGRAM_CELL may apply."""
    on_board_learning: bool = False
    """The Python MCU's on-board learning (issue 34 stage 1: INFO capability bit 8, LEARN_*
    requests; docs/protocol.md "On-board learning"). Off by default until the C firmware has it
    too, so both MCUs announce the same capabilities."""
    board_id: int = 0x4D43_0001
    """Identifier reported by INFO (ASSUMPTION: arbitrary for the emulator)."""
    row_dac_vdd_v: float = 5.0
    """Supply of the row DACs (V): their output clips there (AD5328 with GAIN set)."""
    timing: TimingConfig = field(default_factory=TimingConfig)


def board_id_text(board_id: int, chip_id: str | None = None) -> str:
    """The board id INFO reports: ``EMU-<board id, 8 hex digits>``, followed by ``/<chip id>``
    when the chip is known (docs/protocol.md, "Board identity")."""
    text = f"EMU-{board_id:08X}"
    return f"{text}/{chip_id}" if chip_id else text
