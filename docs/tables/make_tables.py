"""Regenerate the docs' result tables from fixed-seed runs (snan_hil.tools.doc_tables).

Usage (from the repository, with its environment):

    .venv/bin/python docs/tables/make_tables.py                  # every block from the stored data
    .venv/bin/python docs/tables/make_tables.py --run SOURCE ... # run these sources again first
    .venv/bin/python docs/tables/make_tables.py --run all        # every source (about an hour)
    .venv/bin/python docs/tables/make_tables.py --check          # exit 1 if a block differs
    .venv/bin/python docs/tables/make_tables.py --list           # the sources and what they cost

A source's data goes to docs/tables/data/SOURCE.json; the blocks it renders replace the
marked blocks (<!-- table: NAME ... --> ... <!-- /table: NAME -->) of the docs.
"""

from __future__ import annotations

import argparse
import sys
import time

from snan_hil.tools import doc_tables as T


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", nargs="+", metavar="SOURCE", default=[],
                    help=f"run these sources again first (or 'all'): {', '.join(T.SOURCES)}")
    ap.add_argument("--check", action="store_true",
                    help="only say which blocks differ from their stored data (exit 1)")
    ap.add_argument("--list", action="store_true", help="the sources and their cost")
    ap.add_argument("--workers", type=int, default=2, help="processes of a source's runs")
    ap.add_argument("--cache", default=None, metavar="FILE",
                    help="readings result cache of the held-out sources (reused by a rerun)")
    args = ap.parse_args(argv)
    if args.list:
        for s in T.SOURCES.values():
            print(f"{s.name}: {', '.join(sorted(set(s.docs.values())))} ({s.cost})")
        return 0
    if args.check:
        bad = T.check()
        for line in bad:
            print(f"differs from its data: {line}")
        return 1 if bad else 0
    names = list(T.SOURCES) if args.run == ["all"] else args.run
    unknown = [n for n in names if n not in T.SOURCES]
    if unknown:
        print(f"unknown source {unknown[0]!r}; sources: {', '.join(T.SOURCES)}")
        return 2
    ctx = T.RunContext(workers=args.workers, cache=args.cache,
                       say=lambda line: print(time.strftime("%H:%M:%S"), line, flush=True))
    for name in names:
        t0 = time.perf_counter()
        T.run_source(name, ctx)
        print(f"{name}: ran in {time.perf_counter() - t0:.0f} s", flush=True)
    missing: list[str] = []
    for doc in T.render_all(missing=missing):
        print(f"rewrote the blocks of {doc}")
    for line in missing:
        print(f"no marked block for {line} (add its markers to the doc)")
    return 1 if missing else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
