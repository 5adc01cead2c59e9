"""SNAN agent speed: decisions per second on one core (one decision = one 1 s window of the
whole network at 1 ms steps), and the time of 500 trials x 1000 decisions on 10x10.

Target (issue 2): >= 50,000 decisions/s for 10x10 with astrocytes; the paper's own CPU
estimate is 64.4 us per decision (15,500 decisions/s) for a 6x6 field.
Usage: ``python bench/bench_snan.py [--quick]``.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from snan_hil.host import snan_kernel as K
from snan_hil.host.agent import environment, synapse_tables
from snan_hil.host.config import load_config
from snan_hil.host.kernel_params import kernel_params
from snan_hil.host.simulate import simulate, trial_setup

TARGET_10X10_ASTRO = 50_000


def fixed_length_batch(cfg, trials: int, seed: int = 1) -> tuple[int, float]:
    """Run ``trials`` trials that never reach a goal (goal = -1): exactly max_steps
    decisions each. Returns (decisions, seconds)."""
    env = environment(cfg)
    nbr, move = synapse_tables(env, cfg)
    starts = np.zeros(trials, dtype=np.int64)
    w0 = np.zeros((trials, env.n_cells, 4))
    keys = np.zeros(trials, dtype=np.uint64)
    for i in range(trials):
        s, _g, w, key = trial_setup(cfg, env, nbr, seed, i)
        starts[i], w0[i], keys[i] = s, w, np.uint64(key)
    goals = np.full((trials, 1), -1, dtype=np.int64)
    p = kernel_params(cfg)
    paths = np.zeros((trials, cfg.grid.max_steps + 1), dtype=np.int64)
    steps = np.zeros(trials, dtype=np.int64)
    ok = np.zeros(trials, dtype=np.bool_)
    w_out = np.zeros_like(w0)
    t0 = time.perf_counter()
    K.run_batch_kernel(p, nbr[None], move[None], starts, goals, np.ones(trials, np.int64), w0,
                       keys, paths, steps, ok, w_out)
    return int(steps.sum()), time.perf_counter() - t0


def main(argv: list[str]) -> int:
    quick = "--quick" in argv
    simulate(load_config(preset="snan-3x3"), 2, 0)  # compile / load the numba cache
    rows = []
    for preset in ("snan-3x3", "snan-10x10"):
        for astro in (False, True):
            cfg = load_config(preset=preset, overrides=[f"astro.enabled={str(astro).lower()}"])
            trials = 50 if quick else 200
            if preset == "snan-3x3":
                trials *= 5
            dec, wall = fixed_length_batch(cfg, trials)
            rate = dec / wall
            target = TARGET_10X10_ASTRO if (preset == "snan-10x10" and astro) else None
            rows.append((preset, astro, dec, wall, rate, target))
    print("SNAN decisions per second (fast engine, one core, trials that run to the limit)")
    print(f"{'config':12s} {'astro':>5s} {'decisions':>10s} {'wall s':>8s} "
          f"{'decisions/s':>12s} {'us/decision':>12s} {'target':>10s}")
    status = 0
    for preset, astro, dec, wall, rate, target in rows:
        verdict = ""
        if target is not None:
            verdict = f">= {target:,}" + (" ok" if rate >= target else " MISSED")
            status |= int(rate < target)
        print(f"{preset:12s} {'yes' if astro else 'no':>5s} {dec:10d} {wall:8.2f} "
              f"{rate:12,.0f} {1e6 / rate:12.1f} {verdict:>10s}")
    cfg = load_config(preset="snan-10x10")
    n = 50 if quick else 500
    for astro in (True, False):
        c = load_config(preset="snan-10x10", overrides=[f"astro.enabled={str(astro).lower()}"])
        dec, wall = fixed_length_batch(c, n)
        print(f"10x10 {'with' if astro else 'without'} astrocytes, {n} trials x "
              f"{cfg.grid.max_steps} decisions: {wall:.2f} s ({dec / wall:,.0f} decisions/s)")
    # the paper's batches (trials stop at the goal)
    for preset in ("snan-3x3", "snan-10x10"):
        for astro in (False, True):
            c = load_config(preset=preset, overrides=[f"astro.enabled={str(astro).lower()}"])
            r = simulate(c, 50 if quick else 500, 1)
            print(f"paper batch {preset} astro={'yes' if astro else 'no '}: {r.trials} trials, "
                  f"{r.decisions} decisions in {r.wall_s:.2f} s")
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
