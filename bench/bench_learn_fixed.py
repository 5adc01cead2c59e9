"""On-board learning's fixed point against the host's float rule (issue 34 stage 1, point 1):
the board's STDP update and pulse plan (``firmware_emu/learn_fixed.py``, what the Python MCU
runs) against the host's float STDP and ``PulsePlanner`` (chip curve, no budget) on a large
random sample of training trials (``tools/learn_agreement.py``: 24 synapses, 1-29 windows a
trial, p = 0.15 input spikes, 0-11 motor spikes a window, each plan compared from equal
states).

Usage: ``python bench/bench_learn_fixed.py [--trials N] [--seeds S] [--bits B ...]``
(default 5000 trials x 2 seeds at b = 6; ``--bits 4 5 6 7`` compares table sizes).

Target: equal pulse orders on >= 99.9 % of the plans (issue 34 point 1). Prints measured vs
target with the Wilson 95 % interval; exit 1 when the target is missed.
"""

from __future__ import annotations

import argparse
import math
import sys
import time

AGREEMENT_TARGET = 0.999


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    p = k / n
    d = 1 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return c - h, c + h


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=5000)
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--bits", type=int, nargs="+", default=[6])
    a = ap.parse_args(argv)
    from snan_hil.tools.learn_agreement import (agreement_sample, fitted_chip_model,
                                                train_config)
    cfg, model = train_config(), fitted_chip_model()
    ok = True
    for bits in a.bits:
        plans = equal = pulses = 0
        worst = 0.0
        t0 = time.process_time()
        for seed in range(1, a.seeds + 1):
            out = agreement_sample(cfg, model, a.trials, seed=seed, table_bits=bits)
            plans, equal, pulses = plans + out.plans, equal + out.equal, pulses + out.pulses
            worst = max(worst, out.max_dw_error)
        lo, hi = wilson(equal, plans)
        met = equal / plans >= AGREEMENT_TARGET
        ok &= met or bits != 6
        print(f"table 2^{bits}: equal plans {equal}/{plans} = {100 * equal / plans:.3f} % "
              f"[{100 * lo:.3f}, {100 * hi:.3f}] (target >= {100 * AGREEMENT_TARGET:.1f} %: "
              f"{'met' if met else 'MISSED'}); {pulses} host pulses planned; largest window "
              f"change error {worst:.2e} (weight units); {time.process_time() - t0:.0f} s CPU")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
