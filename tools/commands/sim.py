"""``snan-hil sim``: a batch of SNAN navigation trials in software (paper sections 3.1-3.2).

Example: ``snan-hil sim --grid 10 --no-astro --trials 500 --seed 1 --json``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from rich.table import Table

from snan_hil.common.errors import UserError
from snan_hil.host.calcium_trace import calcium_trace
from snan_hil.host.experiments.common import clean
from snan_hil.host.intervals import METHOD_TEXT, format_interval, inside_text
from snan_hil.host.plots import plot_sim
from snan_hil.host.config import SnanConfig
from snan_hil.host.simulate import (SimResult, kernel_cached, memory_estimate, paper_fields,
                                    paper_result, simulate)
from snan_hil.tools.animate import ANIMATION, animate_trace, check_gif_name
from snan_hil.tools.commands._snan import add_model_arguments, config_from_args
from snan_hil.files.outputs import Outputs
from snan_hil.tools.console import console, err_console, progress_display
from snan_hil.tools.output_kinds import SIM_PLOT, add_force_option
from snan_hil.tools.resources import check_memory

NAME = "sim"
HELP = "simulate SNAN navigation trials in software and summarise success and path lengths"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_model_arguments(parser)
    parser.add_argument("--trials", type=int, default=500, help="number of trials")
    parser.add_argument("--seed", type=int, default=1, help="random seed of the batch")
    parser.add_argument("--engine", choices=("auto", "fast", "reference"),
                        default="auto",
                        help="fast/auto: the event-driven trial kernel (every reading); "
                             "reference: the plain per-step Python reference (slow)")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object (summary + config) instead of tables")
    parser.add_argument("--plot", metavar="PNG", default=None,
                        help="write the path-length histogram (with the paper's median and "
                             "success rate for 3x3 and 10x10) and a few trajectories (default: "
                             "no plot)")
    parser.add_argument("--animate", metavar="GIF", default=None,
                        help="write an animation of one trial: the agent on the grid over each "
                             "cell's astrocyte calcium (default: none)")
    parser.add_argument("--animate-trial", type=int, default=None, metavar="K",
                        help="with --animate: the trial it shows (default: the first trial "
                             f"with at least {MIN_ANIMATED_STEPS} steps, else the longest)")
    add_force_option(parser)


COMPILE_NOTE = ("compiling the trial kernel (first run after an install or a change, about a "
                "minute)…")


def note_kernel_compile() -> None:
    """One line on stderr when the trial kernel will compile before the first trial (numba's
    cache is cold), whether or not stderr is a terminal."""
    if not kernel_cached():
        err_console.print(COMPILE_NOTE, markup=False, highlight=False, soft_wrap=True)


MIN_ANIMATED_STEPS = 5
"""The default animated trial has at least this many steps (a 1-step trial is 2 frames)."""


def default_trial(result) -> int:
    """The first trial with at least :data:`MIN_ANIMATED_STEPS` steps, else the longest."""
    steps = np.asarray(result.steps)
    long = np.nonzero(steps >= MIN_ANIMATED_STEPS)[0]
    return int(long[0]) if long.size else int(np.argmax(steps))


def run(args: argparse.Namespace) -> int:
    if args.trials < 1:
        raise UserError(f"--trials must be >= 1, got {args.trials}")
    cfg = config_from_args(args)
    check_memory(memory_estimate(cfg, args.trials),
                 f"a {cfg.grid.rows}x{cfg.grid.cols} grid with {args.trials} trial(s)",
                 "use a smaller --grid or fewer --trials")
    outs = Outputs({"--config": args.config}, force=args.force)
    plot = outs.file("--plot", args.plot, SIM_PLOT) if args.plot else None
    anim = _animation_output(args, outs)
    # chunks of at most ~2e6 cell-trials, so a large grid reports progress every few seconds
    chunk = max(1, min(25, 2_000_000 // (cfg.grid.rows * cfg.grid.cols)))
    if args.engine != "reference":
        note_kernel_compile()
    with progress_display(enabled=not args.json) as progress:
        result = simulate(cfg, args.trials, args.seed, engine=args.engine, chunk=chunk,
                          progress=progress)
    summary = result.summary()
    paper = paper_result(cfg)
    if paper is not None:       # 3x3 / 10x10: the paper's numbers, inside our 95 % intervals?
        summary.update(paper_fields(paper, summary))
    plot_path = None
    if plot is not None:
        plot_path = str(plot_sim(result, plot))
    if anim is not None:
        _write_animation(args, cfg, result, anim)
    if args.json:
        out = clean(summary)
        out["config_name"] = cfg.name
        out["reading"] = args.reading
        out["config"] = cfg.to_dict()
        if plot_path:
            out["plot"] = plot_path
        if anim is not None:
            out["animation"] = str(anim)
        print(json.dumps(out))
        return 0
    _print_summary(args, cfg, summary, paper, plot_path, anim)
    return 0


def _animation_output(args: argparse.Namespace, outs: Outputs) -> Path | None:
    """The --animate GIF, checked (name, trial, not an input) before the simulation."""
    anim = None
    if args.animate_trial is not None and not args.animate:
        raise UserError("--animate-trial picks the trial of an animation: give --animate "
                        "FILE.gif as well")
    if args.animate:
        check_gif_name("--animate", args.animate)
        if args.animate_trial is not None and not 0 <= args.animate_trial < args.trials:
            raise UserError(f"--animate-trial {args.animate_trial}: give 0..{args.trials - 1} "
                            f"(one of the {args.trials} trials)")
        anim = outs.file("--animate", args.animate, ANIMATION)
    return anim


def _write_animation(args: argparse.Namespace, cfg: SnanConfig, result: SimResult,
                     anim: Path) -> None:
    k = args.animate_trial if args.animate_trial is not None else default_trial(result)
    trace = calcium_trace(cfg, result.path(k), seed=args.seed, trial=k)
    astro = "with" if cfg.astro.enabled else "without"
    animate_trace(trace, [int(result.goals[k])], anim,
                  title=f"{cfg.grid.rows}x{cfg.grid.cols} {astro} astrocytes, trial {k} "
                        f"(seed {args.seed}): {int(result.steps[k])} steps, "
                        f"{'reached the goal' if result.success[k] else 'failed'}")


def _print_summary(args: argparse.Namespace, cfg: SnanConfig, summary: dict[str, Any],
                   paper: tuple[float, float] | None, plot_path: str | None,
                   anim: Path | None) -> None:
    table = Table(title=f"SNAN {summary['grid']} "
                        f"{'with' if summary['astro'] else 'without'} astrocytes "
                        f"({cfg.name}, seed {args.seed})", show_header=False)
    table.add_column("quantity", style="bold")
    table.add_column("value", justify="right")

    def fmt(v, spec="{:.1f}"):
        return "-" if v is None else spec.format(v)

    table.add_row("reading", args.reading)
    table.add_row("trials", str(summary["trials"]))
    table.add_row("success rate", f"{100 * summary['success_rate']:.1f} % "
                                  f"({summary['successes']}/{summary['trials']}), 95 % CI "
                                  f"{format_interval(summary['success_rate_ci'], percent=True)}")
    table.add_row("step limit", str(summary["step_limit"]))
    table.add_row("median path (successful)", f"{fmt(summary['median_steps'])}, 95 % CI "
                                              f"{format_interval(summary['median_steps_ci'])}")
    if paper is not None:
        table.add_row("paper: success / median",
                      f"{100 * paper[0]:.1f} % (inside CI: "
                      f"{inside_text(summary['paper_success_inside'])}) / {paper[1]:g} "
                      f"(inside CI: {inside_text(summary['paper_median_inside'])})")
    table.add_row("mean path (successful)", fmt(summary["mean_steps"]))
    table.add_row("p10 / p25 / p75 / p90",
                  " / ".join(fmt(summary[k], "{:.0f}")
                             for k in ("p10_steps", "p25_steps", "p75_steps", "p90_steps")))
    table.add_row("min / max path", f"{fmt(summary['min_steps'], '{}')} / "
                                    f"{fmt(summary['max_steps_taken'], '{}')}")
    table.add_row("decisions simulated", str(summary["decisions"]))
    table.add_row("engine", summary["engine"])
    table.add_row("kernel time", f"{summary['wall_s']:.2f} s "
                               f"({fmt(summary['decisions_per_s'], '{:,.0f}')} decisions/s)")
    console.print(table)
    console.print(f"95 % intervals: {METHOD_TEXT}", highlight=False)
    if plot_path:
        console.print(f"plot written to {plot_path}")
    if anim is not None:
        console.print(f"animation written to {anim}", highlight=False)
