"""The equivalence run (issue 35 points 3 and 6): learning on the chip against software at
cycle 20 over three emulated chips, its verdict with its margin, measured against the targets.

Usage: ``python bench/bench_equivalence.py [--dir DIR] [--store]``

Runs the study of :mod:`snan_hil.tools.equivalence_study` in ``--dir`` (default: a temporary
folder; a folder that holds finished steps continues from them): three chips (seed, spread),
each characterised and learnt on with 30 paired sessions x 20 cycles of the software and chip
arms, the pilot's power (the first 10 sessions of chip B), the six cross-chip transfers, the
analysis. Prints, measured against the target:

* the TOST of the chip arm against software at cycle 20, pooled over the chips, at the
  issue's margin of +-15 % of the route, and the margin this run shows with 80 % power;
* per chip: the route ratio with its 90 % interval and the TOST verdict;
* the success-rate difference with its 90 % interval, per chip and pooled;
* every transfer: the share of the source chip's success kept on the target (target >= 90 %).

``--store``: also store the data as the docs' source ``equivalence`` and render its blocks
(docs/learning.md section 12), as ``docs/tables/make_tables.py --run equivalence`` does, and
draw docs/figures/equivalence.png.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

TARGET_MARGIN = 0.15            #: issue 35 point 3: the route within +-15 %
TRANSFER_TARGET = 0.90          #: learnt weights keep >= 90 % of the source chip's success


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dir", default=None, help="the study's folder (default: a temp dir)")
    ap.add_argument("--store", action="store_true",
                    help="store the data as the docs' source 'equivalence' and render it")
    a = ap.parse_args(argv)
    from snan_hil.tools.equivalence_study import run_study

    def say(line: str) -> None:
        print(time.strftime("%H:%M:%S"), line, flush=True)

    if a.dir is None:
        with tempfile.TemporaryDirectory() as d:
            data = run_study(Path(d), say=say)
    else:
        data = run_study(Path(a.dir), say=say)
    report(data)
    if a.store:
        from snan_hil.tools import doc_tables
        doc_tables.store_source("equivalence", data)
        for doc in doc_tables.render_all(["equivalence"]):
            print(f"rewrote the blocks of {doc}")
        from snan_hil.tools.equivalence_study import plot
        print(f"figure: {plot(data, doc_tables.ROOT / 'docs' / 'figures' / 'equivalence.png')}")
    return 0


def report(data: dict) -> None:
    res = data["result"]
    pooled = res["chips"].get("pooled")
    r = pooled["route"] if pooled else None
    wall = ("steps found done: " + str(data["steps_reused"]) if data["wall_s"] is None
            else f"{data['wall_s']:.0f} s wall")
    print(f"equivalence run: {len(data['chips'])} chips x {data['sessions']} paired sessions "
          f"x {data['cycles']} cycles (snan-hil {data['version']}, {wall}, load "
          f"~{data['load']:.1f})")
    p = data["pilot"]["chips"][f"learn-{data['pilot_chip']}"]
    if p.get("power"):
        pw = p["power"]
        print(f"pilot (chip {data['pilot_chip']}, first {data['pilot_sessions']} sessions): sd "
              f"of ln(chip/software) {pw['sd_log']:.3f}: {pw['route_pairs_needed']} route pairs"
              f" (~{pw['sessions_needed']} sessions) for 80 % power at +-15 %")
    if r is not None:
        lo, hi = r["ratio_ci"]
        margin = pooled["power"]["margin_allowed"]
        print(f"pooled TOST at cycle {res['cycle']}: route ratio chip/software {r['ratio']:.3f}"
              f" [90 % CI {lo:.3f}, {hi:.3f}] over {r['n']} route pairs; margin "
              f"+-{100 * TARGET_MARGIN:.0f} % (target): "
              f"{'equivalent' if r['equivalent'] else 'not shown'} (p = {r['p']:.3g}); the "
              f"margin this run shows with 80 % power: +-{100 * margin:.1f} % (target "
              f"+-{100 * TARGET_MARGIN:.0f} %: {'met' if margin <= TARGET_MARGIN else 'not met'})")
    for name, row in res["chips"].items():
        s, rr = row["success"], row.get("route")
        route = "no route TOST" if rr is None else (
            f"ratio {rr['ratio']:.3f} [{rr['ratio_ci'][0]:.3f}, {rr['ratio_ci'][1]:.3f}], "
            f"{'equivalent' if rr['equivalent'] else 'not shown'} at +-15 %")
        print(f"  {name}: {route}; success chip {100 * s['chip']:.0f} % vs software "
              f"{100 * s['software']:.0f} %, difference {100 * s['difference']:+.1f} points "
              f"[90 % CI {100 * s['ci'][0]:+.1f}, {100 * s['ci'][1]:+.1f}]")
    for t in res["transfer"]:
        kept = "-" if t["kept"] is None else f"{100 * t['kept']:.0f} %"
        print(f"  transfer {t['source']} -> {t['target']}: kept {kept} of the source's success "
              f"(target >= {100 * TRANSFER_TARGET:.0f} %: {'met' if t['met'] else 'not met'})")


if __name__ == "__main__":
    sys.exit(main())
