"""``snan-hil experiment``: reproduce the paper's figures 3-7 (numbers, figure, report).

Examples::

    snan-hil experiment fig5                       # paper trial counts, all cores
    snan-hil experiment all --trials 50 --out results
    snan-hil experiment fig7 --dask tcp://scheduler:8786
"""

from __future__ import annotations

import argparse
import json

from rich.table import Table

from snan_hil.host.checkpoint import check_out, open_run
from snan_hil.host.experiments.common import ROUTE_TASKS, RunOptions
from snan_hil.host.experiments.executor import make_executor
from snan_hil.host.snan_kernel import TARGET_CODES as TARGETS
from snan_hil.host.experiments.mazes import MAZE_RULES
from snan_hil.host.experiments.runner import FIGURES, execute, plan
from snan_hil.host.plasticity import PLASTICITY_RULES
from snan_hil.tools.commands._options import (add_executor_options, add_set_option,
                                              check_executor_options, check_set_conflicts,
                                              set_values)
from snan_hil.files.outputs import Outputs
from snan_hil.host.experiments.common import clean
from snan_hil.tools.console import console, err_console, progress_display
from snan_hil.host.intervals import METHOD_TEXT, format_interval, inside_text
from snan_hil.tools.headlines import headlines
from snan_hil.tools.output_kinds import add_force_option, experiment_figure
from snan_hil.tools.verdicts import print_verdicts

NAME = "experiment"
HELP = "run the paper's experiments (fig3..fig7 or all): CSV/JSON, PNG and a report each"


OPTS = RunOptions()
"""The run options' defaults the command line starts from."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("figures", nargs="+", metavar="FIGURE",
                        choices=(*FIGURES, "all"),
                        help=f"one or more of {', '.join(FIGURES)}, all")
    parser.add_argument("--trials", type=int, default=None,
                        help="trials per condition (fig7: sessions per grid size); "
                             "default: the paper's counts (500; fig7 769/606/198)")
    parser.add_argument("--out", default="results", metavar="DIR",
                        help="output folder; each figure writes DIR/<figure>/, the run's "
                             "checkpoint goes to DIR/checkpoint/ (see --resume)")
    parser.add_argument("--seed", type=int, default=OPTS.seed, help="master seed of the sweep")
    add_executor_options(parser,
                         dask_note="needs the dask extra; default: local worker processes")
    parser.add_argument("--plasticity", choices=PLASTICITY_RULES, default=OPTS.plasticity,
                        help="learning rule: additive STDP or the VTEAM device lookup")
    parser.add_argument("--maze-rule", choices=MAZE_RULES, default=OPTS.maze_rule,
                        help="how mazes keep goals reachable (docs/experiments.md)")
    parser.add_argument("--route-target", choices=tuple(TARGETS), default=None,
                        help="fig7: synapses that receive a window's STDP change (the "
                             "config key stdp.target; default: --set stdp.target if given, "
                             f"else {OPTS.route_target})")
    parser.add_argument("--route-task", choices=ROUTE_TASKS, default=OPTS.route_task,
                        help="fig7: start/goal fixed per session or random every cycle")
    parser.add_argument("--route-train-astro", action=argparse.BooleanOptionalAction,
                        default=OPTS.route_train_astro,
                        help="fig7: astrocytes during the training trials")
    add_set_option(parser, example="synapse.w_inh=10", what="override a value of every preset")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object: per figure its files and headline numbers "
                             "next to the paper's")
    add_force_option(parser)
    parser.add_argument("--resume", action="store_true",
                        help="continue the run in --out where it stopped (its checkpoint/ holds "
                             "every finished task; the figures and options must be the same); "
                             "without it a folder holding an earlier run is refused (also with "
                             "--force)")


def run(args: argparse.Namespace) -> int:
    check_executor_options(args)
    opts = RunOptions(seed=args.seed, trials=args.trials, plasticity=args.plasticity,
                      overrides=tuple(args.overrides), maze_rule=args.maze_rule,
                      route_target=route_target(args), route_task=args.route_task,
                      route_train_astro=args.route_train_astro)
    p = plan(args.figures, opts)
    # checked before any work; a reused --out is resumed or refused (host.checkpoint)
    out = check_out(Outputs(force=args.force), args.out, NAME, resume=args.resume,
                    folders={f: experiment_figure(f) for f in p.figures})
    executor = make_executor(args.workers, args.dask)
    checkpoint = open_run(out, NAME, {"figures": p.figures, "options": opts.to_dict()},
                          resume=args.resume)
    if not args.json:                    # at once: the first tasks may compile for a while
        err_console.print(f"experiment {' '.join(p.figures)}: {len(p.tasks)} task(s) into "
                          f"{out} (on a first run the kernels are compiled first, ~20-40 s)",
                          markup=False, highlight=False, soft_wrap=True)
    with progress_display() as progress:
        figures = execute(p, executor, out, progress=progress, checkpoint=checkpoint)
    checkpoint.complete()
    heads = {fig.name: headlines(fig.name, fig.data, fig.rows) for fig in figures}
    if args.json:
        print(json.dumps(clean({"seed": args.seed, "trials": args.trials, "figures": [
            {"figure": fig.name, "title": fig.title, "files": fig.files,
             "headlines": heads[fig.name]} for fig in figures]}), allow_nan=False))
    else:
        table = Table(title=f"snan-hil experiment (seed {args.seed})")
        table.add_column("figure")
        table.add_column("files")
        for fig in figures:
            table.add_row(fig.name, "\n".join(fig.files[e] for e in ("md", "png", "csv",
                                                                      "json")))
        console.print(table)
        console.print(headline_table(heads))
        console.print(f"95 % intervals: {METHOD_TEXT}", highlight=False)
    print_verdicts(NAME, {"figures": {fig.name: fig.data for fig in figures}},
                   json_mode=args.json)
    return 0


def route_target(args: argparse.Namespace) -> str:
    """fig7's STDP target: --route-target, else --set stdp.target, else the run options'
    default ("chosen"); the two giving different values are refused (one line) before any
    work."""
    if args.route_target is None:
        return str(set_values(args.overrides).get("stdp.target", OPTS.route_target))
    check_set_conflicts(args.overrides, {"stdp.target": (f"--route-target {args.route_target}",
                                                         args.route_target)})
    return str(args.route_target)


def _value(quantity: str, v) -> str:
    if v is None:
        return "-"
    if "rate" in quantity or "fraction" in quantity:
        return f"{100 * float(v):.1f} %"
    return f"{float(v):g}"


def headline_table(heads: dict[str, list[dict]]) -> Table:
    """The headline numbers of every figure next to the paper's."""
    t = Table(title="headline numbers: ours next to the paper's")
    for col in ("figure", "condition", "quantity", "ours", "ours 95 % CI", "paper",
                "paper inside"):
        t.add_column(col, justify="left" if col in ("figure", "condition", "quantity")
                     else "right")
    for name, rows in heads.items():
        if not rows:
            t.add_row(name, "(no number the paper states)", "", "", "", "", "")
        keys = list(dict.fromkeys(k for h in rows for k in h["condition"]))
        varying = [k for k in keys if len({str(h["condition"].get(k)) for h in rows}) > 1]
        for h in rows:
            cond = ", ".join(f"{k}={v}" for k, v in h["condition"].items()
                             if k in (varying or keys))
            t.add_row(name, cond, h["quantity"].replace("_", " "),
                      _value(h["quantity"], h["ours"]),
                      format_interval(h.get("ours_ci"), percent="rate" in h["quantity"]),
                      _value(h["quantity"], h["paper"]), inside_text(h.get("paper_inside")))
    return t
