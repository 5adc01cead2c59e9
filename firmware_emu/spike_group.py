"""One group of a SPIKE_BATCH as the emulated firmware applies it (docs/protocol.md,
SPIKE_BATCH): the rows a spike drives together and the bins where it spikes.

Its own module because both spike paths take it: the reference, frame by frame
(:meth:`snan_hil.firmware_emu.firmware.Firmware.spike_batch`), and the whole-batch fast path
(:mod:`snan_hil.firmware_emu.spike_fastpath`), which the firmware imports.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class SpikeGroupSpec:
    """Rows (row, row-DAC code) a spike drives together, and the bins where it spikes."""

    rows: tuple[tuple[int, int], ...]
    bins: tuple[int, ...]
