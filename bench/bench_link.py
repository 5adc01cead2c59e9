"""A damaged link: ``program-weights`` through a TCP proxy that damages bytes (issue 13, sec. 6).

Usage: ``python bench/bench_link.py [--grid N] [--repeat K] [--rates 0,0.01,0.05] [--seed S]``

For each rate: a fresh ``snan-hil emu --socket`` (a subprocess, the same fresh chip each time),
a :class:`~snan_hil.protocol.testing.CorruptingProxy` in front of it that flips, drops,
duplicates or inserts that fraction of the bytes in both directions (seeded), and
``program_weights`` of an N x N grid (default 6 x 6: 120 synapses) through the proxy, exactly
what ``snan-hil program-weights --port socket://PROXY`` runs. Printed: wall time (best of
``--repeat``), the ratio to the clean run, link counters, the pulses the host confirmed and the
board's pulse counter, and the targets:

* 1 % damaged bytes: completes in <= 3x the clean time;
* 5 %: completes;
* every rate: every synapse programmed, the board's pulse counter equals the host's pulses
  (no pulse applied twice).

The machine is shared (2 cores): report the best of several runs.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from snan_hil.calibration.programmer import program_weights
from snan_hil.calibration.testing import grid_weights, session_of
from snan_hil.protocol.testing import CorruptingProxy
from snan_hil.tools.ports import open_client

TARGET_1PCT = 3.0


def start_emulator(state: Path, seed: int) -> tuple[subprocess.Popen, tuple[str, int]]:
    """``snan-hil emu --socket 127.0.0.1:0`` on a fresh chip; (process, (host, port))."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "snan_hil.tools.cli", "emu", "--socket", "127.0.0.1:0",
         "--state", str(state), "--seed", str(seed), "--idle-timeout", "0"],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    assert proc.stdout is not None
    deadline = time.monotonic() + 60
    for line in proc.stdout:
        found = re.search(r"socket://([\d.]+):(\d+)", line)
        if found:
            return proc, (found.group(1), int(found.group(2)))
        if time.monotonic() > deadline:
            break
    proc.kill()
    raise RuntimeError("the emulator did not start")


def one_run(rate: float, grid: int, seed: int, damage_seed: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        proc, target = start_emulator(d / "chip.npz", seed)
        try:
            with CorruptingProxy(target, rate, seed=damage_seed) as proxy:
                t0 = time.monotonic()
                client = open_client(proxy.url, 115200, "framed")
                try:
                    result = program_weights(session_of(client, d / "layout.json",
                                                        port=proxy.url),
                                             grid_weights(grid, grid, seed=11),
                                             {"grid": [grid, grid]})
                    wall = time.monotonic() - t0
                    counters = client.counters_dict()
                finally:
                    client.close()
                damaged = sum(proxy.to_target.counts.values()) + \
                    sum(proxy.to_client.counts.values())
        finally:
            proc.terminate()
            proc.wait(timeout=30)
    s = result.report["summary"]
    return {"wall_s": wall, "ok": s["ok"], "cells": s["cells"],
            "complete": result.report["complete"], "host_pulses": s["host_pulses"],
            "board_pulses": s["firmware_pulses"], "retries": counters["retries"],
            "naks": counters["bad_crc_reported"], "timeouts": counters["timeouts"],
            "damaged_bytes": damaged}


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grid", type=int, default=6)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--rates", default="0,0.01,0.05")
    ap.add_argument("--seed", type=int, default=0, help="chip seed")
    args = ap.parse_args(argv)
    rates = [float(r) for r in args.rates.split(",")]
    print(f"program-weights, {args.grid}x{args.grid} grid, through a TCP proxy damaging bytes "
          f"(flip/drop/duplicate/insert, both directions); best of {args.repeat} "
          "(shared 2-core machine)")
    print(f"{'damaged':>8} {'wall s':>8} {'x clean':>8} {'ok':>9} {'pulses host/board':>18} "
          f"{'retries':>8} {'NAKs':>6} {'timeouts':>8} {'bytes hit':>9}  target")
    clean = None
    status = 0
    for rate in rates:
        runs = [one_run(rate, args.grid, args.seed, damage_seed=k) for k in range(args.repeat)]
        best = min(runs, key=lambda r: r["wall_s"])
        if clean is None and rate == 0:
            clean = best["wall_s"]
        ratio = best["wall_s"] / clean if clean else float("nan")
        all_ok = all(r["complete"] and r["ok"] == r["cells"]
                     and r["host_pulses"] == r["board_pulses"] for r in runs)
        if rate == 0:
            target = "reference" + ("" if all_ok else ": FAILED")
        elif abs(rate - 0.01) < 1e-12:
            met = all_ok and ratio <= TARGET_1PCT
            target = f"<= {TARGET_1PCT:g}x clean: {'ok' if met else 'NOT MET'}"
        else:
            met = all_ok
            target = f"completes: {'ok' if met else 'NOT MET'}"
        if rate and not (all_ok and (abs(rate - 0.01) > 1e-12 or ratio <= TARGET_1PCT)):
            status = 1
        print(f"{rate:>8.1%} {best['wall_s']:>8.2f} {ratio:>8.2f} "
              f"{best['ok']:>4}/{best['cells']:<4} "
              f"{best['host_pulses']:>8}/{best['board_pulses']:<9} {best['retries']:>8} "
              f"{best['naks']:>6} {best['timeouts']:>8} {best['damaged_bytes']:>9}  {target}",
              flush=True)
        if args.repeat > 1:
            print(f"{'':>8} all runs: " + ", ".join(f"{r['wall_s']:.2f} s" for r in runs))
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
