"""Board wiring of the emulated MemriCore: chip selects and the bits of the two 74HC595s.

The public sources say only that two 74HC595 shift registers select rows and columns and drive
the multiplexers (bit lines 0-15 on one multiplexer, 16-31 on the other) and that the word line
is a 3-bit address plus an enable. The bit assignment below is this emulator's ASSUMPTION; the
firmware and the analog front end both use these constants, so changing one place changes both.

Row register (``SR_ROW``)::

    bit 0-3  MUX_ADDR   bit line within the selected multiplexer (0-15)
    bit 4    MUX_LO_EN  multiplexer of bit lines 0-15 on: connects that line to the write bus
    bit 5    MUX_HI_EN  multiplexer of bit lines 16-31 on
    bit 6    ROWDAC_EN  all 32 row-DAC outputs drive the bit lines (column multiply, spikes)
    bit 7    (unused)

Column register (``SR_COL``)::

    bit 0-2  WL_ADDR    word line (column) 0-7
    bit 3    WL_EN      3.3 V on that word line: opens its 32 transistors
    bit 4    SUM_PATH   column output into the 330 Ohm summing amplifier (virtual ground)
                        instead of the 3000 Ohm load resistor
    bit 5    POL_SET    pulse polarity: 0 = positive pulse on the bit line (RESET, G down),
                        1 = negative pulse (SET, G up; bit line grounded, column driven)
    bit 6    PULSE_GATE write bus connected straight across the cell for a programming pulse
    bit 7    (unused)

The write bus is driven by the separate write DAC: it gives the read voltage of a single-cell
read (through the load resistor) and the amplitude of a programming pulse.
"""

from __future__ import annotations

# Chip-select names on the SPI bus.
CS_ROW_DAC = ("DAC0", "DAC1", "DAC2", "DAC3")
"""Row DACs: DACk drives rows 8k .. 8k+7 (channel A = first row)."""
CS_WRITE_DAC = "WDAC"
CS_ADC = "ADC"
CS_SR_ROW = "SR_ROW"
CS_SR_COL = "SR_COL"

# Row register bits.
MUX_ADDR_MASK = 0x0F
MUX_LO_EN = 1 << 4
MUX_HI_EN = 1 << 5
ROWDAC_EN = 1 << 6

# Column register bits.
WL_ADDR_MASK = 0x07
WL_EN = 1 << 3
SUM_PATH = 1 << 4
POL_SET = 1 << 5
PULSE_GATE = 1 << 6


def row_select_byte(row: int) -> int:
    """Row-register value that connects bit line ``row`` (0-31) to the write bus."""
    return (row & MUX_ADDR_MASK) | (MUX_HI_EN if row >= 16 else MUX_LO_EN)


def col_select_byte(col: int, *, sum_path: bool = False, set_polarity: bool = False,
                    pulse: bool = False) -> int:
    """Column-register value that opens word line ``col`` (0-7) with the given path bits."""
    value = (col & WL_ADDR_MASK) | WL_EN
    if sum_path:
        value |= SUM_PATH
    if set_polarity:
        value |= POL_SET
    if pulse:
        value |= PULSE_GATE
    return value
