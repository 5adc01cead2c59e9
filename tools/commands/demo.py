"""``snan-hil demo``: the project's main job.

For now: the SNAN comparison run in software -- 3x3 and 10x10 grids, with and without
astrocytes, next to the paper's numbers (sections 3.1-3.2). Further stages (emulator,
hardware chain) are meant to be added as more functions called from :func:`run`.
"""

from __future__ import annotations

import argparse
import time

from rich.table import Table

from snan_hil.host.simulate import snan_comparison
from snan_hil.tools.console import console, progress_bar

NAME = "demo"
HELP = "run the main job: SNAN software comparison (3x3, 10x10, astro vs no-astro) vs the paper"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--trials", type=int, default=500,
                        help="trials per configuration (the paper used 500)")
    parser.add_argument("--seed", type=int, default=1, help="random seed")
    parser.add_argument("--set", dest="overrides", action="append", default=[],
                        metavar="KEY=VALUE", help="config override applied to every run")


def run_snan_comparison(trials: int, seed: int, overrides: list[str]) -> int:
    """Print the software SNAN results next to the paper's; returns 0."""
    from snan_hil.errors import UserError
    if trials < 1:
        raise UserError(f"--trials must be >= 1, got {trials}")
    t0 = time.perf_counter()
    with progress_bar() as bar:
        def on_start(preset: str, astro: bool):
            task = bar.add_task(f"{preset} {'astro' if astro else 'no astro'}", total=trials)
            return lambda n: bar.advance(task, n)
        rows = snan_comparison(trials, seed, overrides=tuple(overrides), on_start=on_start)
    table = Table(title=f"SNAN in software vs the paper ({trials} trials per row, seed {seed})")
    for col in ("grid", "astro", "success", "paper", "median", "paper", "mean",
                "ok (succ/med)"):
        table.add_column(col, justify="right")
    for r in rows:
        s = r.summary
        med = "-" if s["median_steps"] is None else f"{s['median_steps']:.1f}"
        mean = "-" if s["mean_steps"] is None else f"{s['mean_steps']:.1f}"
        ok = ("yes" if r.success_ok else "no") + "/" + ("yes" if r.median_ok else "no")
        table.add_row(s["grid"], "yes" if r.astro else "no",
                      f"{100 * s['success_rate']:.1f} %", f"{100 * r.paper_success:.1f} %",
                      med, f"{r.paper_median:.0f}", mean, ok)
    console.print(table)
    console.print("tolerance: success +-7 points / median +-25 %; the readings behind these "
                  "numbers and the known gaps are in docs/model.md. "
                  f"Total {time.perf_counter() - t0:.1f} s.")
    return 0


def run(args: argparse.Namespace) -> int:
    return run_snan_comparison(args.trials, args.seed, args.overrides)
