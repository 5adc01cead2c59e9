"""Crossbar model benchmark: read/pulse throughput (wall), pulse response table, W&V pulse counts,
STDP lookup. Targets are printed next to the measurements.

Usage: ``.venv/bin/python bench/bench_crossbar.py``
"""

from __future__ import annotations

import time

import numpy as np

from snan_hil.crossbar_model import ArrayConfig, CrossbarArray, StdpLookup
from snan_hil.crossbar_model.characterize import (ideal_fine_tune, ideal_write_verify,
                                                 log_uniform_targets, pulse_steps)
from snan_hil.common.polarity import Polarity
from snan_hil.protocol.board import MEMRICORE

SERIES = MEMRICORE.r_load_ohm + MEMRICORE.r_switch_ohm   # cell-read path (3010 Ohm)
V_READ = MEMRICORE.max_read_v                             # the read limit (0.3 V)
V_WRITE_MAX = MEMRICORE.max_write_v                       # the write limit (1.4 V)


def rate(fn, n: int) -> float:
    t0 = time.perf_counter()
    for i in range(n):
        fn(i)
    return n / (time.perf_counter() - t0)


def throughput() -> None:
    a = CrossbarArray(seed=0)
    v = np.zeros(a.rows)
    v[:15] = 0.1
    col = rate(lambda i: a.column_current(v, i & 7), 50_000)
    cell = rate(lambda i: a.cell_current(i & 31, (i >> 5) & 7, V_READ, SERIES), 50_000)
    pulse = rate(lambda i: a.apply_pulse(i & 31, (i >> 5) & 7, V_READ + (i % 12) * 0.1,
                                         Polarity.SET if i & 1 else Polarity.RESET, 100e-6), 20_000)
    print(f"{'measure':<32}{'value':>14}{'target':>14}")
    print(f"{'column reads/s (wall)':<32}{col:>14,.0f}{'>= 50,000':>14}")
    print(f"{'cell reads/s (wall)':<32}{cell:>14,.0f}{'-':>14}")
    print(f"{'pulses/s (wall, 0.3-1.4 V)':<32}{pulse:>14,.0f}{'-':>14}")


def step_table() -> None:
    print("\nrelative conductance step of one 100 us pulse from the middle of the usable range")
    print(f"{'polarity':<10}{'amplitude V':>12}{'mean':>10}{'std':>10}")
    for s in pulse_steps(amplitudes=(0.35, 0.4, 0.5, 0.8, 1.1, 1.4)):
        print(f"{s.polarity.name:<10}{s.amplitude_v:>12.2f}{s.mean * 100:>9.2f}%{s.std * 100:>9.2f}%")


def write_verify_counts() -> None:
    cfg = ArrayConfig.default().with_overrides({"stuck.fraction": 0.0})
    print("\nstage-1 write-and-verify (ramp 0.3 -> 1.4 V, 100 us, +-10 %), 256 log-uniform targets in the "
          "usable range; stage 2 at 0.45 V")
    print(f"{'ramp step V':<12}{'mean pulses':>12}{'p90':>6}{'max':>6}{'target':>10}"
          f"{'fine pulses':>12}{'final |err| median':>20}{'<=3 %':>7}")
    for step in (0.01, 0.02, 0.05, 0.1):
        a = CrossbarArray(cfg, seed=3)
        counts, fine, errs = [], [], []
        for row, col, target in log_uniform_targets(a, 256, seed=5):
            counts.append(ideal_write_verify(a, row, col, target, ramp_step_v=step, v_read=V_READ,
                                             v_max=V_WRITE_MAX, series_ohm=SERIES))
            fine.append(ideal_fine_tune(a, row, col, target, v_read=V_READ, series_ohm=SERIES))
            errs.append(abs(a.conductance()[row, col] / target - 1))
        c = np.array(counts)
        e = np.array(errs)
        print(f"{step:<12.2f}{c.mean():>12.1f}{np.percentile(c, 90):>6.0f}{c.max():>6d}{'< 30':>10}"
              f"{np.mean(fine):>12.1f}{np.median(e) * 100:>19.2f}%{np.mean(e <= 0.03) * 100:>6.0f}%")


def stdp() -> None:
    t0 = time.perf_counter()
    look = StdpLookup.build()
    build = time.perf_counter() - t0
    w = np.random.default_rng(0).uniform(0, 1, 100_000)
    dt = np.random.default_rng(1).uniform(-30, 30, 100_000)
    t0 = time.perf_counter()
    look.delta_w(w, dt)
    per = (time.perf_counter() - t0) / len(w)
    print(f"\nVTEAM STDP lookup: build {build * 1e3:.0f} ms ({look.table.shape[0]}x{look.table.shape[1]}), "
          f"{1 / per:,.0f} lookups/s vectorised")
    for w0 in (0.1, 0.5, 0.9):
        row = look.delta_w(np.full_like(look.dt_grid_ms, w0), look.dt_grid_ms)
        print(f"  w0={w0:.1f}: max potentiation {row.max():.2e} at dt={look.dt_grid_ms[row.argmax()]:+.2f} ms, "
              f"max depression {row.min():.2e} at dt={look.dt_grid_ms[row.argmin()]:+.2f} ms")


if __name__ == "__main__":
    throughput()
    step_table()
    write_verify_counts()
    stdp()
