"""Firmware MCU benchmark: instructions/s of the ISA-level MCU, the virtual time of one spike
(15 rows, 8 columns) from the firmware's own SPI traffic, and hardware decisions/s of the
hw_astro scenario with ``--mcu firmware`` against ``--mcu model``.

Usage: ``python bench/bench_firmware.py [--launches L] [--repeat R]`` (needs ``make firmware``).
The machine is shared (2 cores): the best of ``--repeat`` runs is reported.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

DECISIONS_TARGET = 20.0
PAPER_SPIKE_US = 700.0


def spike_us(mcu: str) -> tuple[float, int]:
    """Virtual us from the first row-DAC word of a spike to the end of its last (15 rows up,
    8 columns read, rows back to 0), and the SPI frames it took."""
    from snan_hil.firmware_emu.emulator import Emulator
    from snan_hil.firmware_emu.testing import default_array
    from snan_hil.protocol import messages as m
    from snan_hil.protocol.link import LinkClient
    from snan_hil.protocol.transport import CallbackTransport
    emu = Emulator(None, 0, array=default_array(0), mcu=mcu)
    client = LinkClient(CallbackTransport(emu.feed, name="bench"))
    client.hello()
    bus = emu.board.bus
    bus.start_trace()
    client.spike_batch([m.SpikeGroup(tuple((r, 82) for r in range(15)), (0,))], list(range(8)),
                       n_bins=1)
    trace = [t for t in bus.stop_trace() if t.cs.startswith("DAC") or t.cs in ("ADC", "SR_COL")]
    end = trace[-1].t_us + 16 * 1e6 / emu.board.config.timing.spi_hz
    if mcu == "firmware":       # the firmware's SPI clock: 32 MHz / 2
        end = trace[-1].t_us + 16 / 16.0
    return end - trace[0].t_us, len(trace)


def decisions(mcu: str, launches: int, work: Path) -> tuple[float, int, float, int]:
    """(hw decisions/s, decisions, wall s, MCU instructions) of hw_astro on a programmed chip."""
    from snan_hil.host.hil.compare import run_compare
    from snan_hil.host.hil.config import load_hil_config
    from snan_hil.host.hil.train import save_weights, train_sets
    from snan_hil.firmware_emu.inprocess import emulator_of
    from snan_hil.tools.ports import open_client
    hil = load_hil_config()
    wpath = work / "weights.npz"
    if not wpath.exists():
        trained = train_sets(hil.train_config(), sets=1, cycles=hil.task.cycles, seed=1,
                             start=hil.task.start, goal=hil.task.goal)
        save_weights(trained, wpath)
    state = work / f"chip-{mcu}.npz"
    client = open_client("emu", 115200, state_file=str(state), seed=0, mcu=mcu)
    try:
        res = run_compare(wpath, hil, client=client, port="emu",
                          layout_path=work / f"layout-{mcu}.json", launches=launches, seed=1,
                          baud=115200, report_dir=work / f"prog-{mcu}")
        emu = emulator_of(client.transport)
        instr = emu.backend.mcu.instructions if emu.backend is not None else 0
    finally:
        client.close()
    hw = [r for r in res["launch_rows"] if r["scenario"] == "hw_astro"]
    dec = sum(r["decisions"] for r in hw)
    wall = sum(r["wall_s"] for r in hw)
    return dec / wall, dec, wall, instr


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--launches", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=1)
    args = ap.parse_args(argv)
    tmp = tempfile.TemporaryDirectory(prefix="bench_fw_")
    work = Path(tmp.name)
    os.environ["SNAN_HIL_EMU_STATE"] = str(work / "chip.npz")
    print("one spike, 15 rows x 8 columns (virtual time from the SPI traffic)")
    for mcu in ("model", "firmware"):
        us, frames = spike_us(mcu)
        print(f"  --mcu {mcu:<8} {us:8.1f} us  ({frames} SPI frames; "
              f"paper ~{PAPER_SPIKE_US:.0f} us)")
    # instructions/s on a spike-heavy load
    from snan_hil.firmware_emu.emulator import Emulator
    from snan_hil.firmware_emu.testing import default_array
    from snan_hil.protocol import messages as m
    from snan_hil.protocol.link import LinkClient
    from snan_hil.protocol.transport import CallbackTransport
    emu = Emulator(None, 0, array=default_array(0), mcu="firmware")
    client = LinkClient(CallbackTransport(emu.feed, name="bench"))
    client.hello()
    mcu = emu.backend.mcu
    best = 0.0
    for _ in range(max(1, args.repeat)):
        i0, t0 = mcu.instructions, time.perf_counter()
        client.spike_batch([m.SpikeGroup(((1, 82),), tuple(range(0, 1000, 7)))], [0, 1, 2, 3],
                           n_bins=1000)
        best = max(best, (mcu.instructions - i0) / (time.perf_counter() - t0))
    print(f"ISA MCU: {best / 1e6:.2f} M instructions/s (HIL-shape window, with peripheral "
          f"callbacks; best of {args.repeat})")
    print(f"hw_astro, {args.launches} launches, 1 weight set (programming excluded)")
    rates = {}
    for mcu_kind in ("model", "firmware"):
        best_rate = 0.0
        for _ in range(max(1, args.repeat)):
            rate, dec, wall, instr = decisions(mcu_kind, args.launches, work)
            best_rate = max(best_rate, rate)
        rates[mcu_kind] = best_rate
        print(f"  --mcu {mcu_kind:<8} {best_rate:7.1f} decisions/s ({dec} decisions, "
              f"{wall:.1f} s)")
    ok = rates["firmware"] >= DECISIONS_TARGET
    print(f"target >= {DECISIONS_TARGET:.0f} hw decisions/s with --mcu firmware: "
          f"{'ok' if ok else 'NOT MET'} ({rates['firmware']:.1f}/s)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
