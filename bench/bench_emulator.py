"""Emulator speed: commands per second (wall) and virtual-to-wall time ratios, fast and reference.

Runs the in-process emulator (framed protocol, synchronous transport, default chip with noise,
115200 baud virtual UART) through the real protocol client and reports:

* READ_CELL / WRITE_PULSE / STATUS round trips per second of wall time;
* SPIKE_BATCH decision windows (1000 bins of 1 ms, spike probability 0.15 per bin) in two
  shapes: the HIL agent's (1 row at the read code, 4 columns read) and the full one (15 rows at
  0.1 V, 8 columns read), each with the fast ADC path (default) and the per-frame reference
  path (``Firmware.fast = False``), and the fast/reference speed-up;
* the modelled cost of one spike (15 rows, 8 columns) next to the paper's ~700 us.

* the wall time of ``snan-hil compare`` at full size on the emulator (10 weight sets x 10
  launches x 4 scenarios, programming included; bench/bench_hil.py's measurement, one run)
  against the 40 s target of issue 14.

Both paths give the same codes, virtual time and energy (tests/emulator/test_emu_fastpath.py); the
bench checks that on its own windows too. A window on a throwaway emulator first loads the
compiled batch kernel, so no measured window pays for it. A ratio > 1 means the emulator runs
faster than the board it models. The machine's 2 cores are shared: rates vary with the load.
Usage: ``python bench/bench_emulator.py [--quick] [--no-compare]`` (``--quick``: fewer
commands and windows, the compare at 3 sets x 3 launches, where the target does not apply).
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from snan_hil.firmware_emu.spike_group import SpikeGroupSpec
from snan_hil.firmware_emu.inprocess import emulator_of, open_inprocess_transport
from snan_hil.firmware_emu.testing import default_array, make_firmware
from snan_hil.protocol.board import MEMRICORE
from snan_hil.protocol.link import LinkClient
from snan_hil.protocol.messages import Polarity, SpikeGroup

SPEEDUP_TARGET = 4.0
"""Fast path vs the per-frame reference, HIL window (1 row, 4 columns)."""
COMPARE_TARGET_S = 40.0
"""Issue 14: ``snan-hil compare`` at full size on the emulator in at most 40 s of wall time."""


def timed(fn, n: int) -> float:
    t0 = time.perf_counter()
    for _ in range(n):
        fn()
    return time.perf_counter() - t0


def window_bins(seed: int, windows: int) -> list[tuple[int, ...]]:
    rng = np.random.default_rng(seed)
    return [tuple(int(b) for b in np.flatnonzero(rng.random(1000) < 0.15))
            for _ in range(windows)]


def open_emulator(tmp: Path, name: str, fast: bool):
    transport = open_inprocess_transport(str(tmp / f"{name}.npz"), seed=0)
    emulator_of(transport).firmware.fast = fast
    client = LinkClient(transport)
    client.hello()
    return client, emulator_of(transport).board.clock


def spike_windows(tmp: Path, rows: tuple[tuple[int, int], ...], columns: list[int],
                  bins: list[tuple[int, ...]]) -> dict[bool, tuple[float, float, list[int]]]:
    """Per path (fast: True/False): wall time (s), virtual time (us) and all codes of the
    windows, each on a fresh emulator (chip seed 0). The paths alternate window by window, so
    a change of machine load affects both alike."""
    runs = {fast: open_emulator(tmp, f"chip-{fast}-{len(rows)}", fast) for fast in (True, False)}
    wall = dict.fromkeys(runs, 0.0)
    codes = {fast: [] for fast in runs}
    v0 = {fast: clock.now_us for fast, (_, clock) in runs.items()}
    for b in bins:
        for fast, (client, _) in runs.items():
            t0 = time.perf_counter()
            res = client.spike_batch([SpikeGroup(rows, b)], columns, n_bins=1000, bin_us=1000)
            wall[fast] += time.perf_counter() - t0
            codes[fast].extend(res.codes)
    out = {}
    for fast, (client, clock) in runs.items():
        out[fast] = (wall[fast], clock.now_us - v0[fast], codes[fast])
        client.close()
    return out


def main(argv: list[str]) -> int:
    quick = "--quick" in argv
    n = 200 if quick else 1000
    windows = 3 if quick else 10
    rows = []
    with tempfile.TemporaryDirectory() as tmpdir:
        tmp = Path(tmpdir)
        warm, _ = open_emulator(tmp, "warm-up", True)    # loads the compiled batch kernel
        warm.spike_batch([SpikeGroup(((5, 245),), (0, 3))], [0, 1], n_bins=4, bin_us=1000)
        warm.close()
        transport = open_inprocess_transport(str(tmp / "chip.npz"), seed=0)
        emu = emulator_of(transport)
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
        client.close()

        speedups = {}
        same = True
        shapes = (("HIL: 1 row, 4 cols", ((5, MEMRICORE.read_code),), [0, 1, 2, 3], windows),
                  ("15 rows, 8 cols", tuple((r, 82) for r in range(15)), list(range(8)),
                   max(windows // 2, 2)))
        for label, spike_rows, columns, count in shapes:
            bins = window_bins(0, count)
            spikes = sum(map(len, bins)) / count
            result = spike_windows(tmp, spike_rows, columns, bins)
            for fast in (True, False):
                wall, virtual, _ = result[fast]
                path = "fast" if fast else "reference"
                target = ">= 1 window/s" if fast else ""
                rows.append((f"SPIKE_BATCH {label}, {path}", f"{count / wall:,.2f} windows/s",
                             target, f"{virtual * 1e-6 / wall:.2f}",
                             f"{wall / count * 1e3:.1f} ms wall, {virtual / count / 1e3:,.1f} ms "
                             f"virtual per window, {spikes:.0f} spikes"))
            speedups[label] = result[False][0] / result[True][0]
            same &= result[True][1:] == result[False][1:]

    fw = make_firmware(default_array(0))
    t0 = fw.clock.now_us
    fw.spike_batch([SpikeGroupSpec(tuple((r, 82) for r in range(15)), (0,))], list(range(8)),
                   n_bins=1, bin_us=1000)
    spike_us = fw.clock.now_us - t0

    print(f"{'measurement':48} {'wall rate':>18} {'target':>15} {'virtual/wall':>13}  notes")
    for name, rate, target, ratio, note in rows:
        print(f"{name:48} {rate:>18} {target:>15} {ratio:>13}  {note}")
    for label, speedup in speedups.items():
        target = f">= {SPEEDUP_TARGET:.0f}x" if label.startswith("HIL") else ""
        print(f"{'SPIKE_BATCH ' + label + ', fast vs reference':48} {speedup:>17.1f}x "
              f"{target:>15}")
    print(f"{'one spike: 15 rows, 8 columns':48} {spike_us:>15.1f} us {'~700 us':>15} "
          f"{'':>13}  paper's estimate; includes 2 row-register bytes of the batch")
    print(f"fast and reference paths: {'identical' if same else 'DIFFERENT'} codes and "
          f"virtual time")
    if "--no-compare" not in argv:
        from bench_hil import measure_compare             # bench/ is the script's folder
        sets = 3 if quick else 10
        with tempfile.TemporaryDirectory() as tmpdir:
            timing = measure_compare(Path(tmpdir), sets=sets, launches=sets, log=lambda t: None)
        wall, cpu, _res = timing.best
        full = sets == 10
        status = ("ok" if wall <= COMPARE_TARGET_S else "OVER") if full else "(full size only)"
        print(f"{f'snan-hil compare --port emu, {sets} sets x {sets} launches x 4':48} "
              f"{wall:>15.1f} s {f'<= {COMPARE_TARGET_S:.0f} s':>15} {status:>13}  "
              f"{cpu:.1f} s CPU; bench/bench_hil.py --repeat N for the best of N runs")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
