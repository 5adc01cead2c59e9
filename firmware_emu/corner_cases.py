"""Requests for corners of the C firmware that the seeded differential tester's draws do not
reach (issue 37 point 4), compared on both MCUs like the tester's own writes.

* **the timer's wrap** - TIMER32_1 counts MCU cycles in 32 bits, so it wraps every 2^32 / 32 MHz
  = 134.2 s; ``hal_now`` then carries into its high word. A board serving a lab wraps within
  minutes, but the emulator's clock does not run while the firmware is idle, and the tester's
  requests last milliseconds. :func:`timer_wrap` is a paced SPIKE_BATCH whose one spike falls
  in its last bin, more than 2^32 cycles after its start (run it in the collapsed poll timing:
  the spin timing would execute those 4.4 G cycles of waiting).
* **the timer's upper half** - :func:`timer_half`: a paced batch read 50 s in, when the
  timer's value is between 2^30 and 2^31 cycles (a wrong-way wait target lies half a wrap
  away there).
* **ADC saturation near full scale** - :func:`saturation` reads each column with 1..32 rows
  driven at the read code, so that the readings climb from mid scale to full scale: at the
  crossing some of a reading's conversions saturate and some do not (``ops_adc_read``).

* **PROGRAM_CELL's stop rules at their boundary** - :func:`program_at_reading` programs cells
  to the code they just read, so that a fine-tuning ramp starts exactly at its target.

:func:`timer_wrap` and :func:`saturation` return ``(name, request)`` pairs that :func:`run`
sends to a :class:`~.differential_fast.FastTwin` (a divergence raises, as in the tester).
"""

from __future__ import annotations

from snan_hil.firmware_emu.differential import raw_frame, wire
from snan_hil.firmware_emu.differential_fast import FastTwin, RequestStream
from snan_hil.protocol import messages as m
from snan_hil.protocol.board import MCU_HZ
from snan_hil.protocol.conformance import frames_of
from snan_hil.protocol.frames import Frame

TIMER_WRAP_S = (1 << 32) / MCU_HZ
"""Seconds between two wraps of the firmware's 32-bit cycle counter (134.2 s at 32 MHz)."""


def timer_wrap(row: int = 3, col: int = 2, read_code: int = 245) -> list[tuple[str, m.Request]]:
    """One paced SPIKE_BATCH lasting past the timer's wrap: bins of 65,535 us (the longest), a
    single spike in the last of ``n_bins`` = ceil(134.2 s / bin) + 1 bins."""
    bin_us = 0xFFFF
    n_bins = int(TIMER_WRAP_S * 1e6 / bin_us) + 2
    group = m.SpikeGroup(((row, read_code),), (n_bins - 1,))
    return [("spike_batch past the timer's wrap",
             m.SpikeBatch((group,), (col,), n_bins=n_bins, bin_us=bin_us, paced=True))]


def timer_half(row: int = 3, col: int = 2, read_code: int = 245,
               at_s: float = 50.0) -> list[tuple[str, m.Request]]:
    """One paced SPIKE_BATCH whose single spike is read ``at_s`` seconds in: with the timer
    between 2^30 and 2^31 cycles (33.6-67.1 s), a wait target computed the wrong way round
    lies half a wrap away, where a right one lies in the past."""
    bin_us = 0xFFFF
    n = int(at_s * 1e6 / bin_us)
    group = m.SpikeGroup(((row, read_code),), (n,))
    return [(f"spike_batch read {at_s:g} s in",
             m.SpikeBatch((group,), (col,), n_bins=n + 1, bin_us=bin_us, paced=True))]


def saturation(rows: int = 32, read_code: int = 245,
               cols: tuple[int, ...] = (0, 3, 7)) -> list[tuple[str, m.Request]]:
    """READ_COLUMN of each of ``cols`` with its first 1..``rows`` rows (of ``rows``, the
    board's) driven at ``read_code``, the others at 0 V."""
    return [(f"read_column {c} with {n} rows", m.ReadColumn(c, (read_code,) * n +
                                                           (0,) * (rows - n)))
            for c in cols for n in range(1, rows + 1)]


def send(twin: FastTwin, stream: RequestStream, name: str, req: m.Request) -> list[Frame]:
    """One request to both MCUs of ``twin``, compared; the firmware's reply frames."""
    stream.seq = (stream.seq + 1) & 0xFFFF
    out = twin.send(wire(raw_frame(req.TYPE, stream.seq, req.encode(), stream.nonce)), name)
    stream.learn(out)
    return [f for f in frames_of(twin.outs["firmware"]) if isinstance(f, Frame)]


def run(twin: FastTwin, stream: RequestStream,
        requests: list[tuple[str, m.Request]]) -> list[Frame]:
    """Send each request (after the stream's HELLO) to both MCUs of ``twin``, compared; the
    firmware's replies in order."""
    stream.learn(twin.send(stream.hello(), "HELLO"))
    replies: list[Frame] = []
    for name, req in requests:
        replies += send(twin, stream, name, req)
    return replies


BOUNDARY_CELLS = [(r, c) for r in range(0, 32, 2) for c in range(0, 8, 2)]
"""The cells :func:`program_at_reading` programs by default (64; with the tester's chip 1,
some of them read their target exactly at PROGRAM_CELL's first reading)."""


def program_at_reading(twin: FastTwin, stream: RequestStream,
                       cells: list[tuple[int, int]] | None = None,
                       read_code: int = 245) -> list[Frame]:
    """PROGRAM_CELL's stop rules at their boundary: for each cell, a READ_CELL, then a
    PROGRAM_CELL (fine tuning, tolerance 50) whose target is that reading - when its own first
    reading equals the target, both fine-tuning ramps are done before any pulse (``a <=
    target``, ``a >= target``). The PROGRAM_CELL replies, in order (after a HELLO)."""
    stream.learn(twin.send(stream.hello(), "HELLO"))
    replies: list[Frame] = []
    for row, col in BOUNDARY_CELLS if cells is None else cells:
        read = send(twin, stream, f"read_cell {row},{col}", m.ReadCell(row, col, read_code))
        reading = read[0].message() if read else None
        if not isinstance(reading, m.ReadCellReply):
            continue
        replies += send(twin, stream, f"program_cell {row},{col} to {reading.adc}",
                        m.ProgramCell(row, col, int(reading.adc), 50, 8, read_code=read_code,
                                      fine_tune=True))
    return replies
