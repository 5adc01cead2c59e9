"""Speed of the readings sweep: the full stage-A cross product (80 readings of w_inh x state
carried x STDP mode x pairing x target, docs/model.md "Readings sweep") raced to 5000
trials, against issue 26's target of 20 minutes on 2 cores.

Usage: ``python bench/bench_readings.py [--trials N] [--workers W] [--quick]``

Runs ``snan-hil readings`` with a fresh cache in a temporary folder and prints its wall time,
the CPU time of all its processes, the CPU time divided by the workers (what an otherwise idle
machine with that many cores takes), the machine's load average before and after, and the
per-round summary. ``--quick``: 250 trials (a smoke run of the same machinery).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

TARGET_S = 20 * 60
STAGE_A = ["--vary", "synapse.w_inh=1,5,10,20,50", "--vary", "neuron.reset_each_window=true,false",
           "--vary", "stdp.mode=trial_end,window", "--vary", "stdp.pairing=all_to_all,nearest",
           "--vary", "stdp.target=all,chosen"]


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=5000)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(argv)
    trials = 250 if args.quick else args.trials
    exe = Path(sys.executable).with_name("snan-hil")
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "sweep"
        cmd = [str(exe), "readings", *STAGE_A, "--trials", str(trials), "--yes", "--workers",
               str(args.workers), "--cache", str(Path(d) / "cache.sqlite"), "--out", str(out)]
        load0 = os.getloadavg()
        t0 = time.perf_counter()
        rc = subprocess.call(cmd, stdout=subprocess.DEVNULL,
                             env={**os.environ, "SNAN_HIL_PROGRESS_INTERVAL_S": "600"})
        wall = time.perf_counter() - t0
        ru = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = ru.ru_utime + ru.ru_stime
        load1 = os.getloadavg()
        if rc != 0:
            print(f"snan-hil readings failed (exit {rc})")
            return rc
        doc = json.loads((out / "readings.json").read_text())
    print(f"stage A, 80 readings raced to {trials} trials, {args.workers} workers")
    for r in doc["rounds"]:
        print(f"  round {r['round']}: {r['readings']} readings to {r['trials']} trials, "
              f"{r['tasks_run']} tasks, {r['dropped']} dropped, {r['wall_s']:.0f} s")
    print(f"wall {wall:.0f} s, CPU {cpu:.0f} s (CPU / {args.workers} workers: "
          f"{cpu / args.workers:.0f} s); load average {load0[0]:.1f} before, {load1[0]:.1f} "
          "after")
    ok = cpu / args.workers <= TARGET_S
    print(f"target: <= {TARGET_S} s on {args.workers} cores: wall {wall:.0f} s "
          f"({'met' if wall <= TARGET_S else 'not met'} at this load), CPU / cores "
          f"{cpu / args.workers:.0f} s ({'met' if ok else 'NOT met'})")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
