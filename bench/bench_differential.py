"""Differential testing of the two MCUs, the long run (issue 27, point 2).

Usage: ``python bench/bench_differential.py [--sequences N] [--steps K] [--seeds S,S,...]
[--findings DIR]``

For each seed, hypothesis runs ``--sequences`` request sequences of up to ``--steps`` rules
(:class:`snan_hil.firmware_emu.differential.DifferentialMachine`: requests of every kind and
code class, retransmissions, damaged frames, split writes, reconnects, kills with a journal
replay and clean restarts) against the Python firmware model and the C firmware on the
instruction-level MCU, on copies of one chip, and compares after every step the replies (byte
for byte but the implementation's free fields), the SPI traffic and the chip. Printed per seed
and in total: sequences, writes, frames (requests, intact or damaged), restarts and kills,
wall time, frames per second, and the findings: a divergence stops that seed's run after
hypothesis has shrunk it; the minimal sequence is printed and written as a sequence-vector file
(``DIR/last-finding.jsonl``, the format of conformance/v1/framed/sequences.jsonl).

Target: no divergence (a finding is a bug in one of the MCUs, or an undocumented difference).
The short seeded run of the same machine is tests/firmware/test_differential.py (``make test``).

``--fast --frames N [--seeds ...]``: the seeded tester without hypothesis
(:mod:`snan_hil.firmware_emu.differential_fast`: no shrinking, no kills; every write compared on
both MCUs), N compared frames per seed. Targets (issue 37): >= 2,000 compared frames/s, and a
long run of >= 10^6 compared frames without a divergence.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import time
from pathlib import Path

from snan_hil.firmware_emu import differential


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sequences", type=int, default=150, help="sequences per seed")
    ap.add_argument("--steps", type=int, default=40, help="rules per sequence (at most)")
    ap.add_argument("--seeds", default="1,2,3,4", help="comma-separated hypothesis seeds")
    ap.add_argument("--findings", type=Path, default=None,
                    help="folder for the minimal failing sequence (default: a temp folder)")
    ap.add_argument("--fast", action="store_true",
                    help="the seeded tester without hypothesis (differential_fast)")
    ap.add_argument("--frames", type=int, default=100_000,
                    help="with --fast: compared frames per seed")
    args = ap.parse_args(argv)
    if args.fast:
        return _fast(args)
    if args.sequences < 1 or args.steps < 1:
        print("bench_differential: --sequences and --steps must be >= 1", file=sys.stderr)
        return 2
    try:
        seeds = [int(x) for x in args.seeds.split(",") if x.strip()]
    except ValueError:
        print(f"bench_differential: --seeds {args.seeds!r} is not a list of integers",
              file=sys.stderr)
        return 2
    findings = args.findings or Path(tempfile.mkdtemp(prefix="snan-diff-findings-"))
    differential.findings_dir(findings)
    print(f"{'seed':>6} {'sequences':>9} {'writes':>7} {'frames':>7} {'restarts':>8} "
          f"{'kills':>5} {'wall s':>7} {'frames/s':>8}  finding")
    total = differential.Stats()
    t_all = time.perf_counter()
    status = 0
    for seed in seeds:
        before = dataclasses.replace(differential.STATS)
        t0 = time.perf_counter()
        finding = "none"
        try:
            differential.run_seeded(seed, examples=args.sequences, steps=args.steps)
        except AssertionError as exc:
            status = 1
            head = str(exc).splitlines()[0]
            finding = f"{head} (minimal sequence: {findings / 'last-finding.jsonl'})"
            print(exc, file=sys.stderr)
        dt = time.perf_counter() - t0
        now = differential.STATS
        d = {f.name: getattr(now, f.name) - getattr(before, f.name)
             for f in dataclasses.fields(now)}
        for k, v in d.items():
            setattr(total, k, getattr(total, k) + v)
        print(f"{seed:>6} {d['sequences']:>9} {d['steps']:>7} {d['frames']:>7} "
              f"{d['restarts']:>8} {d['kills']:>5} {dt:>7.1f} {d['frames'] / dt:>8.1f}  "
              f"{finding}", flush=True)
    dt = time.perf_counter() - t_all
    print(f"{'all':>6} {total.sequences:>9} {total.steps:>7} {total.frames:>7} "
          f"{total.restarts:>8} {total.kills:>5} {dt:>7.1f} {total.frames / dt:>8.1f}  "
          f"{'none: target met' if status == 0 else 'FINDINGS (target: none)'}")
    print("(sequences include the runs hypothesis replays while shrinking a finding; "
          "every write is compared on both MCUs)")
    return status


def _fast(args: argparse.Namespace) -> int:
    import os

    from snan_hil.firmware_emu import differential_fast
    try:
        seeds = [int(x) for x in args.seeds.split(",") if x.strip()]
    except ValueError:
        print(f"bench_differential: --seeds {args.seeds!r} is not a list of integers",
              file=sys.stderr)
        return 2
    if args.frames < 1:
        print("bench_differential: --frames must be >= 1", file=sys.stderr)
        return 2
    total = differential_fast.FastStats()
    print(f"{'seed':>6} {'writes':>9} {'frames':>9} {'cycles':>6} {'wall s':>8} {'frames/s':>9} "
          f"{'cpu s':>8} {'/cpu-s':>7} {'load':>5}  finding", flush=True)
    status = 0
    for seed in seeds:
        stats = differential_fast.FastStats()
        finding = "none"
        try:
            differential_fast.run_stream(seed, args.frames, stats=stats)
        except AssertionError as exc:
            status = 1
            finding = str(exc).splitlines()[0][:300]
        for name in ("writes", "frames", "restarts", "seconds", "cpu_seconds"):
            setattr(total, name, getattr(total, name) + getattr(stats, name))
        print(f"{seed:>6} {stats.writes:>9} {stats.frames:>9} {stats.restarts:>6} "
              f"{stats.seconds:>8.1f} {stats.frames_per_s:>9.1f} {stats.cpu_seconds:>8.1f} "
              f"{stats.frames_per_cpu_s:>7.1f} {os.getloadavg()[0]:>5.1f}  {finding}",
              flush=True)
    print(f"{'all':>6} {total.writes:>9} {total.frames:>9} {total.restarts:>6} "
          f"{total.seconds:>8.1f} {total.frames_per_s:>9.1f} {total.cpu_seconds:>8.1f} "
          f"{total.frames_per_cpu_s:>7.1f}")
    rate_ok = max(total.frames_per_s, total.frames_per_cpu_s) >= 2000
    print(f"target >= 2000 compared frames/s: {'met' if rate_ok else 'NOT met'} "
          f"({total.frames_per_s:.0f}/s wall, {total.frames_per_cpu_s:.0f} per CPU-second of "
          f"this process at load {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores)")
    print("target >= 10^6 compared frames without a divergence: "
          f"{'met' if total.frames >= 1_000_000 and status == 0 else 'NOT met'} "
          f"({total.frames} frames, {'no divergence' if status == 0 else 'DIVERGENCE'})")
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
