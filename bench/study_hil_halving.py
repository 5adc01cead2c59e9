"""When do astrocytes halve the 6x6 route? (docs/hil.md, "When astrocytes halve the route")

Usage: ``python bench/study_hil_halving.py [--base-seeds 1,11,...] [--cycles 1,2,3,5,10,20]
[--limits 100,300] [--json FILE]``

The paper's hardware claim: astrocytes shorten the median route on the 6x6 field from ~14 to
~7 steps (Fig. 10C). For each training strength (training cycles per weight set, the
committed training reading of configs/hil-6x6.yaml) and each launch step limit: 10 sets per
base seed (default 10 base seeds: 100 weight sets), 10 software launches per set without and
with astrocytes. Prints per condition and metric (median of the successful launches; median
of all launches, a failed launch counted at the step limit) both medians with 95 % intervals
that resample whole weight sets, the ratio astrocytes / none with its paired interval, and
whether the paper's 0.5 lies inside it.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base-seeds", default=",".join(str(1 + 10 * i) for i in range(10)))
    ap.add_argument("--cycles", default="1,2,3,5,10,20")
    ap.add_argument("--limits", default="100,300")
    ap.add_argument("--set", dest="sets_model", action="append", default=[],
                    metavar="KEY=VALUE", help="change the HIL model (training and launches)")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    from snan_hil.files.atomicio import atomic_write_json
    from snan_hil.host.hil.config import load_hil_config
    from snan_hil.host.hil.study import set_bootstrap, study_reading

    seeds = [int(s) for s in args.base_seeds.split(",") if s]
    base = load_hil_config(overrides=args.sets_model)
    print(f"6x6, cell {base.task.start} -> {base.task.goal}; {len(seeds)} base seeds x 10 sets "
          f"x 10 launches; training overrides {base.train_overrides}")
    print("cycles limit metric      no astro [95 % CI, sets]  astro [95 % CI]      ratio "
          "[95 % CI]      0.5 inside  success none/astro")
    rows = []
    for limit in (int(x) for x in args.limits.split(",")):
        for cycles in (int(x) for x in args.cycles.split(",")):
            hil = load_hil_config(overrides=[*args.sets_model, f"grid.max_steps={limit}"])
            hil = dataclasses.replace(hil, task=dataclasses.replace(hil.task, cycles=cycles))
            t0 = time.perf_counter()
            res = study_reading(hil, f"cycles={cycles}", (), base_seeds=seeds)
            b = set_bootstrap(res, 10, seed=seeds[0])
            rows.append({"cycles": cycles, "step_limit": limit, **b})
            for metric, key in (("successful", "median_steps"), ("all", "median_steps_all")):
                n, a, r = b["sw_noastro"], b["sw_astro"], b["ratio"][metric]
                print(f"{cycles:6d} {limit:5d} {metric:11s} {n[key]:6g} {_ci(n[key + '_ci'])}"
                      f"{'':6s}{a[key]:6g} {_ci(a[key + '_ci'])}    {r['ratio']:.2f} "
                      f"{_ci(r['ratio_ci'], 2)}   {'yes' if r['halves'] else 'no':3s}"
                      f"         {100 * n['success_rate']:.0f} / {100 * a['success_rate']:.0f} %"
                      f"  ({time.perf_counter() - t0:.0f} s)", flush=True)
    print("paper (Fig. 10C): ~14 without, ~7 with astrocytes (ratio 0.5)")
    if args.json:
        atomic_write_json(args.json, {"base_seeds": seeds, "rows": rows})
    return 0


def _ci(ci, nd: int = 0) -> str:
    return f"[{ci[0]:.{nd}f}, {ci[1]:.{nd}f}]"


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
