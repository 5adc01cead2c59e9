"""Held-out seeds of every tuned reading (issue 35 point 4; docs/model.md "Held-out seeds",
docs/learning.md §5): the score-chosen defaults, the paper-literal reading and the VTEAM
mapping re-evaluated on master seeds their searches never used, printed as tables of the
measured values next to the paper's (the pooled held-out figure, the tuning seed's, the spread
over seeds).

Usage: ``python bench/bench_heldout.py [--readings scored,paper-literal,vteam] [--workers 2]
[--cache FILE] [--from-data]``

Runs ``snan_hil.host.heldout.evaluate`` for each reading (its task results cached in
``--cache``, so a rerun or ``docs/tables/make_tables.py --run heldout-*`` with the same cache
takes seconds), prints the wall time, the CPU time of this process and its workers and the
load average. ``--from-data``: print the tables of the stored runs
(docs/tables/data/heldout-*.json) without running.
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import time

from snan_hil.host.heldout import TUNED
from snan_hil.tools import doc_tables as T


def _cpu() -> float:
    me = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def _verdict(doc: dict) -> list[str]:
    """One line per target: does the paper's value lie inside the pooled held-out interval,
    and inside the tuning seed's?"""
    out = []
    pooled = doc["heldout"]["pooled"]["conditions"]
    tune = doc["tuning"]["conditions"]
    for t in doc["targets"]:
        c, q = t["condition"], t["quantity"]
        held = T.inside(q, t["paper"], pooled[c].get(q + "_ci"))
        tuned = T.inside(q, t["paper"], tune[c].get(q + "_ci"))
        if (held == "yes") != (tuned == "yes"):
            out.append(f"  {c} {q}: paper {T.paper_value(q, t['paper'])} inside the tuning "
                       f"seed's interval: {tuned}; inside the held-out one: {held}")
    return out


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--readings", default=",".join(TUNED))
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--cache", default=None, metavar="FILE",
                    help="readings result cache (default: none, every unit runs)")
    ap.add_argument("--from-data", action="store_true",
                    help="print the stored runs (docs/tables/data) without running")
    args = ap.parse_args(argv)
    names = [n.strip() for n in args.readings.split(",") if n.strip()]
    unknown = [n for n in names if n not in TUNED]
    if unknown:
        print(f"unknown reading {unknown[0]!r}; readings: {', '.join(TUNED)}")
        return 2
    load0 = os.getloadavg()[0]
    t0, c0 = time.perf_counter(), _cpu()
    ctx = T.RunContext(workers=args.workers, cache=args.cache,
                       say=lambda line: print(time.strftime("%H:%M:%S"), line, flush=True))
    for name in names:
        source = T.SOURCES[f"heldout-{name}"]
        doc = T.load_data(source.name) if args.from_data else source.run(ctx)
        print(f"\n## {name}: {doc['title']}\n")
        for text in source.render(doc).values():
            print(text)
        moved = _verdict(doc)
        print("where the tuning seed and the held-out seeds disagree about the paper's value:")
        print("\n".join(moved) if moved else "  nowhere")
        if not args.from_data:
            print(f"{name}: {doc['wall_s']:.0f} s wall")
    if not args.from_data:
        print(f"\nall: {time.perf_counter() - t0:.0f} s wall, {_cpu() - c0:.0f} s CPU (this "
              f"process and its workers), {args.workers} workers, load average "
              f"{load0:.1f} before, {os.getloadavg()[0]:.1f} after")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
