"""Calibration benchmark: programming the paper's 120 synapses on the emulator.

Usage: ``python bench/bench_calibration.py [--quick] [--full-retention]``

On a fresh default chip (seed 0) in a temporary folder, through the framed protocol and the
in-process emulator (virtual time from the board's CLOCK; the UART is accounted at the baud):

1. ``program_weights`` of a random 6x6 weight set (uniform in [0, 1]): wall time, virtual board
   time, pulses per cell, errors after stage 1 and 2 (targets: 120/120 in +-10 % after stage 1,
   median |error| <= 3 %, median pulses <= 30);
2. the same over a link that damages 1 % of the bytes (drops + bit flips): the board's pulse
   counter must equal the pulses the host applied;
3. a rerun on the programmed chip (idempotence: few or no pulses);
4. for comparison, the firmware's PROGRAM_CELL with the existing host software's ramp
   (0.3 -> 1.2 V in 0.01 V steps, then its stage 2), on a fresh chip;
5. retention: 10,000 read cycles (column path, one spike per row) of the first 8 cells
   (``--full-retention``: all 120); target: no drift beyond the read noise.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

from snan_hil.calibration.layout import Layout
from snan_hil.calibration.programmer import program_weights
from snan_hil.calibration.readback import retention_run, summarize_retention
from snan_hil.calibration.readchain import ReadChain
from snan_hil.calibration.testing import grid_weights, session_of
from snan_hil.firmware_emu.testing import lossy_inprocess_client

META = {"grid": [6, 6]}


def connect(state: Path, baud: int = 115200, loss: float = 0.0):
    """(client, emulator) on chip file ``state``; ``loss``: half dropped, half corrupted frames."""
    return lossy_inprocess_client(state, baud=baud, drop=loss / 2, corrupt=loss / 2, loss_seed=1,
                                  hello_attempts=20)


def program(state: Path, layout: Path, weights, *, baud=115200, loss=0.0):
    client, emu = connect(state, baud, loss)
    fw0 = emu.board.front_end.pulses_applied
    try:
        result = program_weights(session_of(client, layout), weights, META)
        fw = emu.board.front_end.pulses_applied - fw0
    finally:
        client.close()
    return result.report, fw


def firmware_ramp(state: Path, weights) -> dict:
    """PROGRAM_CELL with the host software's default ramp, same targets and layout."""
    client, emu = connect(state)
    info = client.info
    chain = ReadChain.nominal(info)
    layout = Layout.place((6, 6), (info.rows, info.cols), {(12, 4): "stuck"})
    t0, c0 = time.perf_counter(), client.clock().time_us
    pulses, inside1, errs = [], 0, []
    try:
        for s in layout.synapses:
            g = layout.weight_map.conductance(weights[s.pre, s.post])
            target = int(round(chain.cell_code(g)))
            tol = int(chain.cell_code(g) - chain.cell_code(g * 0.9))   # -10 % in G (tighter side)
            rep = client.program_cell(s.row, s.col, target, tol, max_pulses=1000)
            pulses.append(rep.pulses_stage1 + rep.pulses_stage2)
            inside1 += rep.ok
            final = statistics.fmean(chain.cell_conductance(client.read_cell(s.row, s.col))
                                     for _ in range(3))
            errs.append(abs(final / g - 1))
        virtual = (client.clock().time_us - c0) * 1e-6
    finally:
        client.close()
    return {"wall_s": time.perf_counter() - t0, "virtual_s": virtual, "ok": inside1,
            "median_pulses": statistics.median(pulses), "max_pulses": max(pulses),
            "median_err": statistics.median(errs)}


def row(name: str, value: str, target: str = "", ok: bool | None = None) -> None:
    mark = "" if ok is None else ("ok" if ok else "MISSED")
    print(f"  {name:44s} {value:>18s}   {target:18s} {mark}")


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="skip the lossy and baseline runs, "
                                                             "1,000 retention reads")
    parser.add_argument("--full-retention", action="store_true",
                        help="retention of all 120 cells (about 2 minutes)")
    args = parser.parse_args(argv)
    weights = grid_weights(6, 6, seed=2024)
    status = 0
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        t0 = time.perf_counter()
        rep, fw = program(d / "chip.npz", d / "layout.json", weights)
        s = rep["summary"]
        print("1. program-weights, 120 synapses, default chip (seed 0), 115200 baud")
        good = (s["stage1_ok"] == 120, s["median_abs_rel_error"] <= 0.03,
                s["median_pulses"] <= 30, fw == s["host_pulses"])
        row("cells inside +-10 % after stage 1", f"{s['stage1_ok']}/120", "120/120", good[0])
        row("cells inside +-10 % at the end", f"{s['ok']}/120", "120/120", s["ok"] == 120)
        row("median |relative error| after stage 2",
            f"{100 * s['median_abs_rel_error']:.2f} %", "<= 3 %", good[1])
        row("max |relative error|", f"{100 * s['max_abs_rel_error']:.2f} %", "<= 10 %")
        row("pulses per cell: median / mean / max",
            f"{s['median_pulses']} / {s['mean_pulses']:.1f} / {s['max_pulses']}", "median <= 30",
            good[2])
        row("pulses host / board counter", f"{s['host_pulses']} / {fw}", "equal", good[3])
        row("virtual board time", f"{s['virtual_s']:.2f} s")
        row("wall time", f"{s['wall_s']:.2f} s")
        status |= not all(good)

        if not args.quick:
            rep_fast, _ = program(d / "fast.npz", d / "fast.json", weights, baud=921600)
            row("virtual board time at 921600 baud (fresh chip)",
                f"{rep_fast['summary']['virtual_s']:.2f} s")
            lossy, fwl = program(d / "lossy.npz", d / "lossy.json", weights, loss=0.01)
            sl = lossy["summary"]
            print("\n2. same over a link damaging 1 % of the bytes (fresh chip)")
            ok_l = sl["ok"] == 120 and fwl == sl["host_pulses"]
            row("cells inside +-10 %", f"{sl['ok']}/120", "120/120", sl["ok"] == 120)
            row("pulses host / board counter", f"{sl['host_pulses']} / {fwl}", "equal", ok_l)
            row("lost pulse requests reconciled",
                f"{lossy['ledger']['reconciled']} ({lossy['ledger']['not_applied']} not run)")
            row("link retransmissions", f"{lossy['link']['retries']}")
            row("virtual / wall time", f"{sl['virtual_s']:.2f} s / {sl['wall_s']:.2f} s")
            status |= not ok_l

        again, _ = program(d / "chip.npz", d / "layout.json", weights)
        s2 = again["summary"]
        print("\n3. rerun on the programmed chip (idempotence)")
        row("pulses in total", f"{s2['host_pulses']}", "few", s2["host_pulses"] < 0.15 *
            s["host_pulses"])
        row("median pulses per cell", f"{s2['median_pulses']}", "0", s2["median_pulses"] == 0)
        row("virtual board time", f"{s2['virtual_s']:.2f} s")

        if not args.quick:
            base = firmware_ramp(d / "base.npz", weights)
            print("\n4. reference: firmware PROGRAM_CELL, host software's ramp (0.01 V steps)")
            row("cells inside +-10 %", f"{base['ok']}/120")
            row("pulses per cell: median / max",
                f"{base['median_pulses']} / {base['max_pulses']}")
            row("median |relative error|", f"{100 * base['median_err']:.2f} %")
            row("virtual / wall time", f"{base['virtual_s']:.2f} s / {base['wall_s']:.2f} s")

        n_reads = 1000 if args.quick else 10000
        client, _ = connect(d / "chip.npz")
        try:
            layout = Layout.load(d / "layout.json")
            if not args.full_retention:
                layout.synapses = layout.synapses[:8]
            c0, t1 = client.clock().time_us, time.perf_counter()
            cells = retention_run(client, layout, n_reads, "column")
            virtual = (client.clock().time_us - c0) * 1e-6
            wall = time.perf_counter() - t1
        finally:
            client.close()
        r = summarize_retention(cells)
        print(f"\n5. retention: {n_reads} read cycles of {r['cells']} cells (column path)")
        row("cells without drift beyond read noise", f"{r['stable']}/{r['cells']}",
            "all", r["stable"] == r["cells"])
        row("max |drift| (last vs first tenth)", f"{100 * r['max_abs_drift_rel']:.3f} %",
            "< read noise")
        row("median single-read noise", f"{100 * r['median_noise_rel']:.3f} %")
        row("virtual / wall time", f"{virtual:.1f} s / {wall:.1f} s")
        status |= r["stable"] != r["cells"]
        print(f"\ntotal bench wall time {time.perf_counter() - t0:.1f} s")
    return int(bool(status))


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
