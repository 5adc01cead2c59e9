"""Wall time of `snan-hil experiment all` (figures 3-7) on this machine.

Runs the same sweep as the command (one sweep over every figure, local processes on all
cores) and prints the wall time against the target of 150 s at the paper's trial counts on
2 cores (issue 14; it was 345 s before the single trial kernel, and the first target was 15
minutes). ``--trials N`` runs N trials per condition instead and extrapolates linearly in
the number of trials (marked "extrapolated": trial cost varies between conditions, so this
is only an estimate). On a shared machine the wall time includes other people's work: the
CPU time of this process and its workers is printed too.

    .venv/bin/python bench/bench_experiments.py                 # paper counts
    .venv/bin/python bench/bench_experiments.py --trials 50     # quick estimate
"""

from __future__ import annotations

import argparse
import os
import resource
import tempfile
import time

from snan_hil.host.experiments.common import RunOptions
from snan_hil.host.experiments.executor import ProcessExecutor, default_workers
from snan_hil.host.experiments.runner import execute, plan

TARGET_S = 150
PAPER_UNITS_NOTE = "paper counts: 500 trials per condition; fig7 769/606/198 sessions"


def _cpu_s() -> float:
    """User + system CPU seconds of this process and its finished children."""
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(
        resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=None,
                    help="trials per condition (default: the paper's counts)")
    ap.add_argument("--workers", type=int, default=None, help="default: all cores")
    ap.add_argument("--out", default=None, help="keep the figures here (default: temp dir)")
    args = ap.parse_args()
    opts = RunOptions(trials=args.trials)
    p = plan(["all"], opts)
    full = plan(["all"], RunOptions())
    workers = args.workers or default_workers()
    out = args.out or tempfile.mkdtemp(prefix="bench-exp-")
    t0 = time.perf_counter()
    c0 = _cpu_s()
    execute(p, ProcessExecutor(workers), out)
    wall = time.perf_counter() - t0
    cpu = _cpu_s() - c0
    scale = full.units / p.units
    est = wall * scale
    per_fig: dict[str, int] = {}
    for t in p.tasks:
        per_fig[t.key[0]] = per_fig.get(t.key[0], 0) + t.weight
    print(f"experiment all: {len(p.tasks)} tasks, {p.units} trial units "
          f"({', '.join(f'{k} {v}' for k, v in per_fig.items())}); {workers} workers on "
          f"{os.cpu_count()} cores; figures in {out}")
    print(f"{'measurement':<44} {'value':>12} {'target':>12}")
    label = "wall time, paper counts" if args.trials is None else \
        f"wall time, {args.trials} trials/condition"
    print(f"{label:<44} {wall:>10.1f} s {'':>12}")
    print(f"{'cpu time, all processes':<44} {cpu:>10.1f} s {'':>12}")
    verdict = "measured" if args.trials is None else f"extrapolated x{scale:.1f}"
    ok = "OK" if est <= TARGET_S else "OVER"
    print(f"{'wall time at paper counts (' + verdict + ')':<44} {est:>10.1f} s "
          f"{'<= ' + str(TARGET_S) + ' s':>12}  {ok}")
    print(PAPER_UNITS_NOTE)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
