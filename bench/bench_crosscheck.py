"""Cross-check of the SNAN kernel with Brian2 (docs/model.md, "Cross-check with Brian2").

Usage: ``python bench/bench_crosscheck.py [--trials N] [--max-steps M] [--grid G]``

For each reading (the score-chosen defaults, state carried across windows, in-trial STDP on
every candidate, the paper-literal preset) and ``--trials`` trials of a G x G grid (seed 1,
random start/goal as ``simulate`` draws them, at most ``--max-steps`` decisions): the trial in the
project's kernel and in Brian2 driven with the kernel's recorded input spike trains. Prints
per reading the decision windows compared, those whose motor spike counts differ, the
trials whose decisions differ, and both simulators' time per decision measured in this run
(CPU time of this process, so that a loaded machine does not inflate it; kernel: a batch of
500 trials of the same reading, best of 3; Brian2: the compared trials, numpy target).
Target: every window and every decision equal (or each difference explained).
"""

from __future__ import annotations

import argparse
import sys
import time

READINGS = {
    "defaults (score-chosen)": [],
    "state carried": ["neuron.reset_each_window=false"],
    "in-trial STDP, all": ["stdp.mode=window", "stdp.target=all"],
    "paper-literal preset": ["neuron.reset_each_window=false", "stdp.mode=window",
                             "stdp.target=all"],
}


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=3)
    ap.add_argument("--max-steps", type=int, default=12)
    ap.add_argument("--grid", type=int, default=3)
    args = ap.parse_args(argv)
    import numpy as np
    from snan_hil.host.simulate import simulate
    from snan_hil.host.config import load_config
    from snan_hil.host.crosscheck_brian2 import compare_trial
    from snan_hil.host.grid import GridWorld
    from snan_hil.host.rng import trial_keys

    preset = "snan-3x3" if args.grid == 3 else "snan-10x10"
    print(f"{args.grid}x{args.grid} ({preset}), {args.trials} trials, at most {args.max_steps} "
          "decisions each, seed 1; Brian2 numpy target")
    print(f"{'reading':26s} {'windows':>8s} {'count diffs':>11s} {'paths differ':>12s} "
          f"{'kernel us/dec':>13s} {'Brian2 us/dec':>13s} {'ratio':>8s}")
    status = 0
    for name, sets in READINGS.items():
        cfg = load_config(preset=preset, overrides=[*sets, f"grid.rows={args.grid}",
                                                    f"grid.cols={args.grid}",
                                                    f"grid.max_steps={args.max_steps}"])
        env = GridWorld(cfg.grid.rows, cfg.grid.cols)
        windows = diffs = paths = decisions = 0
        b2_s = 0.0
        for trial in range(args.trials):
            _key, task_seed, _w = trial_keys(1, trial)
            start, goal = env.sample_start_goal(np.random.default_rng(task_seed))
            c = compare_trial(cfg, start, goal, seed=1, trial=trial)
            windows += c.windows
            diffs += len(c.count_mismatches)
            paths += c.first_divergence is not None
            decisions += len(c.brian2.counts)
            b2_s += c.brian2.cpu_s
        best = float("inf")
        for _ in range(3):
            t0 = time.process_time()
            r = simulate(cfg, 500, seed=1).summary()
            best = min(best, (time.process_time() - t0) / max(r["decisions"], 1))
        k_us = 1e6 * best
        b_us = 1e6 * b2_s / max(decisions, 1)
        print(f"{name:26s} {windows:8d} {diffs:11d} {paths:12d} {k_us:13.1f} {b_us:13.0f} "
              f"{b_us / k_us:7.0f}x", flush=True)
        status |= int(diffs > 0 or paths > 0)
    print("target: 0 count differences and 0 differing paths "
          f"({'met' if status == 0 else 'NOT met'})")
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
