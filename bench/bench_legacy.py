"""Legacy-protocol HIL benchmark: the four-scenario comparison over the existing firmware's line
protocol, per hardware mode (per-window, per-spike), on the emulator.

Usage: ``python bench/bench_legacy.py [--quick] [--modes per-window,per-spike] [--repeat N]
[--sets K] [--launches L]``

In a temporary folder: ``snan-hil train`` of K weight sets (default 10, 20 cycles, seed 1),
then per mode, on a fresh default chip (seed 0) each time, the comparison
``snan-hil compare --weights W --port emu --protocol legacy --mode MODE`` runs (programming every
set over mode 7/9, 4 scenarios x K sets x L launches, default 10) — in one board session for
all sets, where the CLI opens one per set (and one for its HELLO check). The emulator seeds its
read noise from the chip's boot number, so the bench and the CLI draw different noise and
their hardware medians can differ by a step or two (docs/hil.md). Printed per mode:

* the compare's wall time (best of ``--repeat`` runs, each on a fresh chip; with two or more
  runs they are checked to give identical results, one run is "not checked") against the
  5-minute target of issue 11 (per-window; per-spike has no target);
* hardware decisions/s on the emulator (wall time of the hardware launches);
* reads and line bytes per decision (the client's counters) and the **wire-limited rate of a
  real board at 115200 baud**: bytes x 10 / baud + reads x the board's documented conversion
  time (DAC settling + 1 dummy + 10 averaged ADC conversions = 61 us); MCU and SPI time of the
  existing firmware are unknown and not included, so a real board is at most this fast;
* the medians and the acceptance checks.

The machine is shared (2 cores): wall times vary with the load; take the best of repeats.
``--quick``: 3 sets x 3 launches, one repeat.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

WALL_TARGET_S = 300.0           #: issue 11: compare --protocol legacy, per-window, full size
BAUD = 115200


def _run(mode: str, weights: Path, work: Path, hil, launches: int, seed: int) -> dict:
    from snan_hil.calibration.testing import session_of
    from snan_hil.host.hil.compare import CompareJob, CompareRequest
    from snan_hil.lab.runner import RunOptions, run_job
    from snan_hil.lab.ports import open_client

    chip = work / f"chip-{mode}-{time.monotonic_ns()}.npz"
    client = open_client("emu", BAUD, "legacy", state_file=str(chip), seed=0)
    t0 = time.perf_counter()
    try:
        request = CompareRequest(str(weights), hil, launches=launches, seed=seed, mode=mode,
                                 report_dir=work / "programming")
        res = run_job(CompareJob(request), session_of(client, chip.with_suffix(".layout.json"),
                                                      baud=BAUD),
                      RunOptions(record="off")).result
    finally:
        client.close()
    res["bench_wall_s"] = time.perf_counter() - t0
    return res


def _fingerprint(res: dict) -> str:
    rows = [(r["scenario"], r["set"], r["launch"], r["steps"], r["success"])
            for r in res["launch_rows"]]
    return json.dumps(rows)


def summarize(res: dict, conversion_us: float) -> dict:
    """Per-decision figures of the hardware launches of one compare."""
    hw = [r for r in res["launch_rows"] if r["scenario"].startswith("hw_")]
    dec = sum(r["decisions"] for r in hw)
    wall = sum(r["wall_s"] for r in hw)
    reads = sum(r["requests"] for r in hw)
    wire_us = sum(r["wire_us"] for r in hw)
    per_dec_us = (wire_us + reads * conversion_us) / dec
    return {"decisions": dec, "hw_wall_s": wall, "hw_decisions_per_s": dec / wall,
            "reads_per_decision": reads / dec,
            "bytes_per_decision": wire_us * 1e-6 * BAUD / 10 / dec,
            "wire_ms_per_decision": wire_us / dec / 1e3,
            "wire_limited_ms_per_decision": per_dec_us / 1e3,
            "wire_limited_decisions_per_s": 1e6 / per_dec_us}


def identical_text(identical: bool | None, runs: int) -> str:
    """What the bench prints for the run-to-run check: only two or more runs can be compared."""
    if identical is None or runs < 2:
        return f"not checked ({runs} run{'s' if runs != 1 else ''})"
    return f"{identical} ({runs} runs)"


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="3 sets x 3 launches, one repeat")
    ap.add_argument("--modes", default="per-window,per-spike")
    ap.add_argument("--repeat", type=int, default=None, help="runs per mode (default 3; "
                    "per-spike 1)")
    ap.add_argument("--sets", type=int, default=None)
    ap.add_argument("--launches", type=int, default=None)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--json", default=None, metavar="FILE", help="also write the figures here")
    args = ap.parse_args(argv)
    sets = args.sets or (3 if args.quick else 10)
    launches = args.launches or (3 if args.quick else 10)
    modes = [m.strip().replace("-", "_") for m in args.modes.split(",") if m.strip()]
    tmp = tempfile.TemporaryDirectory(prefix="bench_legacy_")
    work = Path(tmp.name)
    os.environ["SNAN_HIL_EMU_STATE"] = str(work / "chip.npz")   # never the user's chip
    from snan_hil.host.hil.config import load_hil_config
    from snan_hil.host.hil.train import save_weights, train_sets
    from snan_hil.protocol.board import MEMRICORE

    hil = load_hil_config()
    trained = train_sets(hil.train_config(), sets=sets, cycles=hil.task.cycles, seed=args.seed,
                         start=hil.task.start, goal=hil.task.goal)
    weights = save_weights(trained, work / "weights.npz")
    conversion_us = MEMRICORE.conversion_us
    print(f"compare over the legacy protocol on the emulator: {sets} sets x {launches} launches "
          f"x 4 scenarios, fresh chip (seed 0) per run; machine shared (2 cores)")
    figures = {}
    for mode in modes:
        repeat = args.repeat or (1 if args.quick or mode == "per_spike" else 3)
        walls, prints, res = [], set(), None
        for _ in range(repeat):
            res = _run(mode, weights, work, hil, launches, args.seed)
            walls.append(res["bench_wall_s"])
            prints.add(_fingerprint(res))
        assert res is not None
        s = summarize(res, conversion_us)
        s.update({"compare_wall_s": walls, "best_wall_s": min(walls),
                  # None: not checked (one run cannot be compared with anything)
                  "identical_runs": (len(prints) == 1) if len(walls) >= 2 else None,
                  "medians": {k: v["median_steps"] for k, v in res["scenarios"].items()},
                  "medians_all": {k: v["median_steps_all"] for k, v in res["scenarios"].items()},
                  "success": {k: v["success_rate"] for k, v in res["scenarios"].items()},
                  "acceptance": res["acceptance"]})
        figures[mode] = s
        target = f"<= {WALL_TARGET_S:.0f} s" if mode == "per_window" else "(none)"
        ok = "" if mode != "per_window" else ("  ok" if min(walls) <= WALL_TARGET_S
                                                else "  NOT MET")
        print(f"\n{mode.replace('_', '-')}:")
        print(f"  compare wall time      {min(walls):8.1f} s best of {len(walls)} "
              f"({', '.join(f'{w:.1f}' for w in walls)}); target {target}{ok}; runs identical: "
              f"{identical_text(s['identical_runs'], len(walls))}")
        print(f"  hardware decisions     {s['decisions']:8d}  ({s['hw_wall_s']:.1f} s of launches "
              f"in the last run)")
        print(f"  emulator, wall         {s['hw_decisions_per_s']:8.1f} hw decisions/s")
        print(f"  per decision           {s['reads_per_decision']:8.1f} reads (mode 9), "
              f"{s['bytes_per_decision']:.0f} bytes on the line")
        print(f"  real board @ {BAUD}  {s['wire_limited_decisions_per_s']:8.1f} decisions/s "
              f"wire-limited ({s['wire_ms_per_decision']:.2f} ms line + "
              f"{s['reads_per_decision'] * conversion_us / 1e3:.2f} ms conversion = "
              f"{s['wire_limited_ms_per_decision']:.2f} ms per decision)")
        print("  medians (successful)   " + ", ".join(f"{k} {v}" for k, v in s["medians"].items()))
        print("  medians (all), success " + ", ".join(
            f"{k} {s['medians_all'][k]} {100 * s['success'][k]:.0f}%" for k in s["medians"]))
        acc = s["acceptance"]
        print(f"  astro shortens sw/hw: {acc['sw_astro_shortens']}/{acc['hw_astro_shortens']}; "
              f"hw vs sw: {acc['hw_vs_sw_noastro']:+.0%} / {acc['hw_vs_sw_astro']:+.0%}")
    if args.json:
        Path(args.json).write_text(json.dumps(figures, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
