"""Emulator speed: commands per second (wall) and virtual-to-wall time ratios.

Runs the in-process emulator (framed protocol, synchronous transport, default chip with noise,
115200 baud virtual UART) through the real protocol client and reports:

* READ_CELL / WRITE_PULSE / STATUS round trips per second of wall time;
* virtual board time per wall time for a cell read and for a SPIKE_BATCH decision window
  (1000 bins of 1 ms, spike probability 0.15 per bin, 15 rows at 0.1 V, 8 columns read);
* the modelled cost of one spike (15 rows, 8 columns) next to the paper's ~700 us.

A ratio > 1 means the emulator runs faster than the board it models.
Usage: ``python bench/bench_emulator.py [--quick]``.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from snan_hil.firmware_emu.firmware import SpikeGroupSpec
from snan_hil.firmware_emu.inprocess import open_inprocess_transport
from snan_hil.firmware_emu.testing import default_array, make_firmware
from snan_hil.protocol.link import LinkClient
from snan_hil.protocol.messages import Polarity, SpikeGroup


def timed(fn, n: int) -> float:
    t0 = time.perf_counter()
    for _ in range(n):
        fn()
    return time.perf_counter() - t0


def main(argv: list[str]) -> int:
    quick = "--quick" in argv
    n = 200 if quick else 1000
    windows = 2 if quick else 5
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        transport = open_inprocess_transport(str(Path(tmp) / "chip.npz"), seed=0)
        emu = transport.emulator
        client = LinkClient(transport)
        client.hello()
        clock = emu.board.clock

        def measure(name, fn, count, target):
            v0 = clock.now_us
            wall = timed(fn, count)
            virtual_s = (clock.now_us - v0) * 1e-6
            rows.append((name, f"{count / wall:,.0f} /s", target,
                         f"{virtual_s / wall:.2f}", f"{clock.now_us - v0:,.0f} us / {count}"))

        measure("READ_CELL round trip", lambda: client.read_cell(3, 3), n, ">= 1,000 /s")
        measure("WRITE_PULSE 100 us + read", lambda: client.write_pulse(
            3, 3, Polarity.RESET, 400, 100), n // 2, ">= 500 /s")
        measure("STATUS round trip", client.status, n, ">= 2,000 /s")

        rng = np.random.default_rng(0)
        spikes = 0
        v0 = clock.now_us
        t0 = time.perf_counter()
        for _ in range(windows):
            bins = tuple(int(b) for b in np.flatnonzero(rng.random(1000) < 0.15))
            spikes += len(bins)
            group = SpikeGroup(tuple((r, 82) for r in range(15)), bins)
            client.spike_batch([group], list(range(8)), n_bins=1000, bin_us=1000)
        wall = time.perf_counter() - t0
        virtual_us = clock.now_us - v0
        rows.append(("SPIKE_BATCH window (1 s, p=0.15)", f"{windows / wall:,.2f} windows/s",
                     ">= 1 window/s", f"{virtual_us * 1e-6 / wall:.2f}",
                     f"{virtual_us / windows / 1e3:,.1f} ms virtual per window, "
                     f"{spikes / windows:.0f} spikes"))
        uart_share = clock.breakdown_us["uart"] / clock.now_us
        client.close()

    fw = make_firmware(default_array(0))
    t0 = fw.clock.now_us
    fw.spike_batch([SpikeGroupSpec(tuple((r, 82) for r in range(15)), (0,))], list(range(8)),
                   n_bins=1, bin_us=1000)
    spike_us = fw.clock.now_us - t0

    print(f"{'measurement':36} {'wall rate':>18} {'target':>15} {'virtual/wall':>13}  notes")
    for name, rate, target, ratio, note in rows:
        print(f"{name:36} {rate:>18} {target:>15} {ratio:>13}  {note}")
    print(f"{'one spike: 15 rows, 8 columns':36} {spike_us:>15.1f} us {'~700 us':>15} "
          f"{'':>13}  paper's estimate; includes 2 row-register bytes of the batch")
    print(f"UART share of virtual time over the run: {uart_share:.0%} (115200 baud)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
