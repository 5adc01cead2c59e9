"""The physical ceiling of one on-board decision: how fast the board's parts allow it (issue 33).

A decision window's work is counted per decision (:class:`WindowCounts`: input spikes, column
reads, ADC frames, column-register and row-DAC writes, the MCU's instruction time, the bytes on
the wire) and :func:`ceiling` turns it into the time each part of the board needs, from the
datasheet figures alone (``snan_hil.protocol.board``, shared/reference/memricore-board.md):

* **ADC** (TLC3541 class): one conversion cycle of 1 / 200 kS/s = 5 us a frame;
* **DAC** (AD5328 class) and the front end: 6 us of settling after a row or column changes
  (the emulator's ASSUMPTION: the multiplexers and word line settle as the DAC does);
* **SPI** at 15 MHz: 16 bits a DAC word or ADC frame, 8 a column-register byte;
* **MCU**: its instruction time at 32 MHz (one instruction a cycle: the emulator's ISA MCU
  counts them; a lower bound on the real SCR1 core);
* **wire**: 10 bits a byte at the baud, each direction on its own (a full-duplex UART: the
  next request arrives while the board works and sends).

The analog **chain** of the lean read plan (docs/protocol.md "Read plan") is what the parts
allow in sequence: a read's first sample waits for its column to settle - counted from the
column-register latch, which follows the previous read's last frame on the shared SPI bus - or,
when nothing changed, for the ADC's cycle; its other samples follow one conversion cycle apart;
a row change adds its DAC words on the bus; the window ends with one readout frame. The ADC's
share of the chain is its conversion cycles, the rest is settling ("DAC"). The MCU and the wire
run beside the chain (the MCU computes in the chain's waits; the UART moves bytes while the board
works), so the ceiling is the largest of the four, and that part bounds the decision.

The standard plan (no READ_PLAN: SPIKE_BATCH's sequence) is counted as it runs: per spike and
row the row up, the DAC's settling, per column the select, the settling and a dummy plus the
averaged conversions, the row down, nothing overlapped (``standard=True``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

from snan_hil.protocol.board import ADC_DUMMY_CONVERSIONS, ADC_RATE_SPS, DAC_SETTLE_US, SPI_HZ
from snan_hil.protocol.transport import BITS_PER_BYTE

CONVERSION_US = 1e6 / ADC_RATE_SPS
"""One TLC3541 conversion cycle (us): 5 at 200 kS/s."""
FRAME_US = 16 / SPI_HZ * 1e6
"""An ADC frame or a row-DAC word on the SPI bus (us): 16 bits at 15 MHz."""
SELECT_US = 8 / SPI_HZ * 1e6
"""A column-register byte on the SPI bus (us)."""
SETTLE_US = DAC_SETTLE_US
"""Settling after a row or column change before a sample (us)."""

PARTS = ("ADC", "DAC", "MCU", "wire")


@dataclass(frozen=True)
class WindowCounts:
    """What one decision does, per decision (averages over a run).

    ``spikes``: input spikes; ``reads``: column reads; ``selects``: reads whose column register
    (or row) changed before them (they wait for the settling); ``row_words``: row-DAC words;
    ``conversions``: ADC conversions a read (the lean plan's N; the standard plan's averages);
    ``request_bytes`` / ``reply_bytes``: on the wire, each way; ``mcu_us``: the MCU's
    instruction time (None: not measured); ``standard``: the standard read plan."""

    spikes: float
    reads: float
    selects: float
    row_words: float
    conversions: int
    request_bytes: float
    reply_bytes: float
    mcu_us: float | None = None
    standard: bool = False


@dataclass(frozen=True)
class Ceiling:
    """The ceiling of a decision: per part its time (us), the chain's shares, the bound."""

    parts_us: dict[str, float]
    chain_us: float
    time_us: float
    bound: str
    counts: WindowCounts

    @property
    def decisions_per_s(self) -> float:
        return 1e6 / self.time_us

    def to_dict(self) -> dict[str, Any]:
        return {"parts_us": dict(self.parts_us), "chain_us": self.chain_us,
                "time_us": self.time_us, "bound": self.bound,
                "decisions_per_s": self.decisions_per_s, "counts": asdict(self.counts)}


def chain_shares(c: WindowCounts) -> tuple[float, float]:
    """(ADC share, settling share) of the analog chain of one decision (us), module doc."""
    n = c.conversions
    if c.standard:
        # per row and spike: word up, DAC settle, word down; per read: select, settle, then
        # the dummy and the averaged conversions back to back
        frames = c.reads * (n + ADC_DUMMY_CONVERSIONS)
        settle = (c.row_words * FRAME_US + (c.row_words / 2) * SETTLE_US
                  + c.reads * (SELECT_US + SETTLE_US))
        return frames * CONVERSION_US, settle
    unchanged = max(c.reads - c.selects, 0.0)
    adc = ((n - 1) * c.reads + unchanged + 1) * CONVERSION_US
    settle = c.selects * (FRAME_US + SELECT_US + SETTLE_US) + c.row_words * FRAME_US
    return adc, settle


def ceiling(c: WindowCounts, baud: int) -> Ceiling:
    """The ceiling of a decision with counts ``c`` at ``baud`` (module doc)."""
    adc, settle = chain_shares(c)
    chain = adc + settle
    byte_us = BITS_PER_BYTE / baud * 1e6
    wire = max(c.request_bytes, c.reply_bytes) * byte_us
    parts = {"ADC": adc, "DAC": settle, "MCU": c.mcu_us or 0.0, "wire": wire}
    candidates = {"ADC" if adc >= settle else "DAC": chain, "MCU": parts["MCU"],
                  "wire": wire}
    bound = max(candidates, key=lambda k: candidates[k])
    return Ceiling(parts, chain, candidates[bound], bound, c)


def lean_window_counts(cells: Sequence[tuple[int, int]], spikes: int,
                       paced: bool = False) -> tuple[int, int]:
    """(reads that wait for settling, row-DAC words) of one window of the lean read plan with
    the reads ``cells`` ((row, column) in the request's order) and ``spikes`` input spikes, by
    the board's rule (docs/protocol.md "Read plan"): every other spike reads in reverse; a read
    waits when its row or column changed (a PACED window turns the word line off between
    spikes); a row change writes the old row to 0 and the new one up, and the window ends
    with the row back at 0."""
    if not cells or not spikes:
        return 0, 0
    waits = words = 0
    row: int | None = None
    col: int | None = None
    back = list(cells)[::-1]
    for k in range(spikes):
        if paced:
            col = None
        for r, c in (back if k % 2 else cells):
            changed = False
            if r != row:
                words += 1 if row is None else 2
                row, changed = r, True
            if c != col:
                col, changed = c, True
            waits += changed
    return waits, words + 1
