"""Study of the HIL training readings in software (docs/hil.md, "Training readings").

Usage: ``python bench/study_hil_training.py [--base-seeds 1,11,...] [--sets K]
[--launches L] [--reading NAME=KEY=VALUE[;KEY=VALUE]] [--json FILE]``

For each reading (default: the four ``stdp.target`` choices on top of configs/hil-6x6.yaml)
and each base seed (default 1, 11, ..., 91: 10 x 10 = 100 weight sets): ``snan-hil train``
of the sets, then 10 software launches per set without and with astrocytes. Prints, per
reading, the median of the successful launches, the success rate, the median of all
launches (a failed launch counted at the step limit), the spread of that median over the
base seeds and the share of trained weights at exactly w_max. About 5 s per reading.
"""

from __future__ import annotations

import argparse
import sys
import time

DEFAULT_READINGS = {
    "normalize (HIL default)": (),
    "chosen": ("stdp.target=chosen",),
    "depress_others": ("stdp.target=depress_others",),
    "all": ("stdp.target=all",),
}


def _reading(text: str) -> tuple[str, tuple[str, ...]]:
    name, _, rest = text.partition("=")
    if not rest:
        raise argparse.ArgumentTypeError(f"--reading {text!r}: use NAME=KEY=VALUE[;KEY=VALUE]")
    return name, tuple(p for p in rest.split(";") if p)


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base-seeds", default=",".join(str(1 + 10 * i) for i in range(10)))
    ap.add_argument("--sets", type=int, default=10)
    ap.add_argument("--launches", type=int, default=10)
    ap.add_argument("--reading", type=_reading, action="append", default=None,
                    help="NAME=KEY=VALUE[;KEY=VALUE] (repeatable; default: the four targets)")
    ap.add_argument("--set", dest="sets_model", action="append", default=[],
                    metavar="KEY=VALUE",
                    help="change the HIL model for training and launches alike (repeatable; "
                         "e.g. astro.a=3), where --reading changes the training only")
    ap.add_argument("--json", default=None, help="also write the results to this file")
    args = ap.parse_args(argv)
    from snan_hil.files.atomicio import atomic_write_json
    from snan_hil.host.hil.config import load_hil_config
    from snan_hil.host.hil.study import set_bootstrap, study_reading

    seeds = [int(s) for s in args.base_seeds.split(",") if s]
    readings = dict(args.reading) if args.reading else DEFAULT_READINGS
    hil = load_hil_config(overrides=args.sets_model)
    if args.sets_model:
        print(f"model --set {' '.join(args.sets_model)}")
    print(f"6x6, cell {hil.task.start} -> {hil.task.goal}, {hil.task.cycles} training cycles, "
          f"step limit {hil.model.grid.max_steps}; base seeds {seeds} x {args.sets} sets x "
          f"{args.launches} launches; HIL training overrides {hil.train_overrides}")
    print("per scenario: median of successful {95 % CI} / success {95 % CI} / median of all "
          "launches {95 % CI} [min-max of that median over base seeds]; CI of the medians: "
          "bootstrap over whole weight sets (a set's 10 launches together), of the success: "
          "Wilson; ratio astro/no astro with its paired set-bootstrap interval")
    out = []
    for name, over in readings.items():
        t0 = time.perf_counter()
        res = study_reading(hil, name, over, base_seeds=seeds, sets=args.sets,
                            launches=args.launches)
        s = res.summary()
        b = set_bootstrap(res, args.launches, seed=seeds[0])
        s["set_bootstrap"] = b
        for sc in ("sw_noastro", "sw_astro"):      # the intervals over whole weight sets
            s[sc]["median_steps_ci"] = b[sc]["median_steps_ci"]
            s[sc]["median_steps_all_ci"] = b[sc]["median_steps_all_ci"]
            lo, hi = b[sc]["median_steps_ci"]
            s[sc]["paper_inside"] = lo <= s[sc]["paper_median_steps"] <= hi
            s[sc]["paper_distance"] = (0.0 if s[sc]["paper_inside"] else
                                       (s[sc]["paper_median_steps"] - hi
                                        if s[sc]["paper_median_steps"] > hi
                                        else s[sc]["paper_median_steps"] - lo))
        out.append(s)
        cells = []
        for sc in ("sw_noastro", "sw_astro"):
            v = s[sc]
            ps = v["per_seed_median_all"]
            cells.append(f"{v['median_steps']:g} {_ci(v['median_steps_ci'])} / "
                         f"{100 * v['success_rate']:.0f} % "
                         f"{_ci(v['success_rate_ci'], 100)} / "
                         f"{v['median_steps_all']:g} {_ci(v['median_steps_all_ci'])} "
                         f"[{min(ps):g}-{max(ps):g}]")
        rs, ra = b["ratio"]["successful"], b["ratio"]["all"]
        cells.append(f"ratio {rs['ratio']:.2f} {_ci(rs['ratio_ci'])} / all "
                     f"{ra['ratio']:.2f} {_ci(ra['ratio_ci'])}")
        shorter = sum(a < b for a, b in zip(s["sw_astro"]["per_seed_median_all"],
                                            s["sw_noastro"]["per_seed_median_all"]))
        print(f"{name:26s} no astro {cells[0]:30s} astro {cells[1]:30s} {cells[2]} "
              f"astro shorter in {shorter}/{len(seeds)} seeds, at w_max "
              f"{100 * s['frac_at_wmax']:.0f} %  ({time.perf_counter() - t0:.0f} s)",
              flush=True)
        for sc in ("sw_noastro", "sw_astro"):
            v = s[sc]
            d = v["paper_distance"]
            where = ("inside" if v["paper_inside"] else
                     f"OUTSIDE ({abs(d):g} steps {'below' if d < 0 else 'above'})")
            print(f"{'':26s} {sc}: paper median {v['paper_median_steps']:g} is {where} the "
                  f"95 % interval {_ci(v['median_steps_ci'])}")
    print("paper (Fig. 10C): ~14 steps without, ~7 with astrocytes")
    if args.json:
        atomic_write_json(args.json, {"base_seeds": seeds, "sets": args.sets,
                                      "launches": args.launches, "readings": out})
    return 0


def _ci(ci, scale: float = 1.0) -> str:
    return "{-}" if ci is None else "{" + f"{scale * ci[0]:.3g}-{scale * ci[1]:.3g}" + "}"


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
