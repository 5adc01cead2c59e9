"""``snan-hil train``: route learning of K weight sets for the hardware experiment.

Example: ``snan-hil train --grid 6 --start 18 --goal 0 --sets 10 --cycles 20 --seed 1
-o weights.npz`` (the paper's "trained 10 times ... from cell 18 to cell 0").
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np
from rich.table import Table

from snan_hil.common.errors import UserError
from snan_hil.host.hil.config import HilConfig, HilTask, load_hil_config
from snan_hil.host.hil.train import (TrainResult, save_weights, set_seeds, train_sets,
                                     training_memory_estimate)
from snan_hil.host.config import SnanConfig
from snan_hil.tools.commands._options import (add_set_option, check_set_conflicts, set_values,
                                               value_text)
from snan_hil.tools.commands._snan import parse_grid
from snan_hil.files.outputs import Outputs
from snan_hil.tools.console import console, progress_display
from snan_hil.tools.output_kinds import WEIGHTS, add_force_option
from snan_hil.tools.resources import check_memory

NAME = "train"
HELP = "train K route weight sets with STDP (weights kept across cycles) and save them (.npz)"


def add_hil_config_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", metavar="FILE", default=None,
                        help="HIL config or a SNAN config file (default: configs/hil-6x6.yaml)")
    add_set_option(parser, example="astro.tau_ca_s=4", what="override a model value")


def check_sets_reach_training(hil: HilConfig, overrides: list[str]) -> None:
    """Refuse a ``--set`` that the training would silently replace: training runs with
    astrocytes and the HIL config's ``train_set`` on top of the model
    (:meth:`HilConfig.train_config`), so ``--set astro.enabled=false`` or a ``--set`` of a
    ``train_set`` key with another value would not reach it. UserError, one line."""
    if not overrides:
        return
    forced = {"astro.enabled": True, **hil.train_overrides}
    cfg = hil.train_config()
    for key, value in set_values(overrides).items():
        if key not in forced:
            continue
        used: object = cfg
        for part in key.split("."):
            used = getattr(used, part)
        if used != value or isinstance(used, bool) != isinstance(value, bool):
            why = ("training runs with astrocytes" if key == "astro.enabled"
                   else f"the HIL config's train_set ({hil.source}) sets it for training")
            raise UserError(f"--set {key}={value_text(value)} would not reach the training: "
                            f"{why} ({key}={value_text(used)}); give a HIL config with another "
                            "train_set (--config)")


def add_accept_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--accept-config-diff", action="store_true",
                        help="launch even if the model differs from the training config stored "
                             "in the weights file (the differences are printed and recorded)")


TASK = HilTask()
"""The task's defaults (those of ``configs/hil-6x6.yaml``, the default --config) the help
texts show."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--grid", metavar="N|MxK", default=None,
                        help="grid size (default: from the config, 6x6)")
    parser.add_argument("--start", type=int, default=None,
                        help=f"start cell (default: the config's task.start, {TASK.start})")
    parser.add_argument("--goal", type=int, default=None,
                        help=f"goal cell (default: the config's task.goal, {TASK.goal})")
    parser.add_argument("--sets", type=int, default=10, help="weight sets K (one per seed)")
    parser.add_argument("--cycles", type=int, default=None,
                        help="training trials per set, weights carried over (default: the "
                             f"config's task.cycles, {TASK.cycles})")
    parser.add_argument("--seed", type=int, default=1,
                        help="seed of set 0; set k uses seed + k")
    parser.add_argument("-o", "--output", required=True, metavar="FILE.npz",
                        help="output file (.npz, written atomically)")
    add_hil_config_arguments(parser)
    parser.add_argument("--json", action="store_true", help="print a JSON summary")
    add_force_option(parser)


def run(args: argparse.Namespace) -> int:
    if not str(args.output).endswith(".npz"):
        raise UserError(f"-o {args.output}: the output must be an .npz file")
    overrides = list(args.overrides)
    if args.grid is not None:
        rows, cols = parse_grid(args.grid)
        check_set_conflicts(overrides, {"grid.rows": (f"--grid {args.grid}", rows),
                                        "grid.cols": (f"--grid {args.grid}", cols)})
        overrides = [f"grid.rows={rows}", f"grid.cols={cols}", *overrides]
    hil = load_hil_config(args.config, overrides)
    check_sets_reach_training(hil, args.overrides)
    start = hil.task.start if args.start is None else args.start
    goal = hil.task.goal if args.goal is None else args.goal
    cycles = hil.task.cycles if args.cycles is None else args.cycles
    if args.sets < 1:
        raise UserError(f"--sets must be >= 1, got {args.sets}")
    if cycles < 1:
        raise UserError(f"--cycles must be >= 1, got {cycles}")
    cfg = hil.train_config()
    check_memory(training_memory_estimate(cfg, args.sets),
                 f"training {args.sets} set(s) on a {cfg.grid.rows}x{cfg.grid.cols} grid",
                 "use a smaller --grid or fewer --sets")
    output = Outputs({"--config": args.config}, force=args.force).file("-o", args.output, WEIGHTS)
    if not args.force and output.is_file():
        _check_replaces_same_training(output, cfg, sets=args.sets, seed=args.seed,
                                      cycles=cycles, grid=(hil.model.grid.rows,
                                                           hil.model.grid.cols),
                                      start=start, goal=goal)
    extra = {"hil_config": hil.to_dict(), "base_seed": args.seed}
    with progress_display(enabled=not args.json) as progress:
        result = train_sets(cfg, sets=args.sets, cycles=cycles, seed=args.seed, start=start,
                            goal=goal, extra=extra, progress=progress)
    path = save_weights(result, output)
    summary = result.summary() | {"output": str(path)}
    if args.json:
        print(json.dumps(summary))
        return 0
    _print_sets(result, args.sets, cfg, start, goal, cycles, path)
    return 0


def _print_sets(result: TrainResult, sets: int, cfg: Any, start: int, goal: int, cycles: int,
                path: Path) -> None:
    """The trained sets as a table: seed, steps of the first and last cycle, median, success."""
    t = Table(title=f"route training {result.grid[0]}x{result.grid[1]}, cell {start} -> {goal}, "
                    f"{cycles} cycles per set ({cfg.name}, astrocytes on, stdp {cfg.stdp.mode})")
    for col in ("set", "seed", "steps cycle 1", "steps last cycle", "median steps",
                "success (cycles)"):
        t.add_column(col, justify="right")
    for k in range(sets):
        t.add_row(str(k), str(result.seeds[k]), str(result.steps[k, 0]),
                  str(result.steps[k, -1]), f"{np.median(result.steps[k]):.0f}",
                  f"{int(result.success[k].sum())}/{cycles}")
    console.print(t)
    console.print(f"weights written to {path} ({result.wall_s:.1f} s)")


def _check_replaces_same_training(output: Path, cfg: SnanConfig, *, sets: int, seed: int,
                                  cycles: int, grid: tuple[int, int], start: int,
                                  goal: int) -> None:
    """A trained weights file holds long work: ``-o`` replaces one (without ``--force``) only
    when it holds the very training requested (training is deterministic, so it is written
    again the same); otherwise UserError (one line) saying what the file holds."""
    want = {"sets": sets, "seeds": [int(s) for s in set_seeds(seed, sets)], "cycles": cycles,
            "grid": list(grid), "start": start, "goal": goal,
            "config": json.loads(json.dumps(cfg.to_dict()))}
    try:
        with np.load(output, allow_pickle=False) as d:
            seeds = [int(s) for s in d["seeds"]]
            have = {"sets": int(d["weights"].shape[0]), "seeds": seeds,
                    "cycles": int(d["cycles"]), "grid": [int(g) for g in d["grid"]],
                    "start": int(d["start"]), "goal": int(d["goal"]),
                    "config": json.loads(str(d["config"]))}
    except Exception as exc:  # noqa: BLE001 - any damage: the file is not ours to judge
        raise UserError(f"-o {output} holds trained weights that cannot be read "
                        f"({type(exc).__name__}); give another file name, or --force to "
                        "replace it") from None
    if have == want:
        return
    name = have["config"].get("name", "?") if isinstance(have["config"], dict) else "?"
    seed_text = (f"seed {seeds[0]}" if len(seeds) == 1
                 else f"seeds {seeds[0]}..{seeds[-1]}" if seeds else "no seeds")
    differs = ", ".join(k for k in want if have[k] != want[k])
    raise UserError(
        f"-o {output} holds other trained weights ({have['sets']} set(s), {seed_text}, "
        f"{have['cycles']} cycles, {have['grid'][0]}x{have['grid'][1]} {have['start']} -> "
        f"{have['goal']}, config {name}; differs in {differs}); training would replace them: "
        "give another file name, or --force to replace it")
