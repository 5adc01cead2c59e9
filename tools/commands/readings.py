"""``snan-hil readings``: a scored sweep of the model's readings over every headline condition
of the paper (:mod:`snan_hil.host.readings`; docs/model.md, "Readings sweep").

Examples::

    snan-hil readings --vary synapse.w_inh=1,5,10,20,50 --vary neuron.reset_each_window=true,false
    snan-hil readings --vary stdp.mode=trial_end,window --trials 500 --out sweep-500
    snan-hil readings --vary astro.tau_ca_unit=s,ms --dask tcp://scheduler:8786
"""

from __future__ import annotations

import argparse
import io
import json
import math
import shlex
import sys
import time
from pathlib import Path
from typing import Any

from snan_hil.files.atomicio import atomic_write_bytes, atomic_write_json, atomic_write_text
from snan_hil.common.errors import UserError
from snan_hil.host import readings as R
from snan_hil.host import readings_report as report
from snan_hil.host.experiments.common import clean
from snan_hil.host.experiments.executor import make_executor, seed_tasks
from snan_hil.files.outputs import OutputKind, Outputs, csv_kind, json_kind, png_kind
from snan_hil.tools.commands._options import (add_executor_options, add_set_option,
                                              check_executor_options)
from snan_hil.tools.console import console, progress_display
from snan_hil.tools.output_kinds import add_force_option
from snan_hil.files.userdata import user_data_dir

NAME = "readings"
HELP = ("sweep the model's readings over every headline condition of the paper and rank them "
        "by their distance to the paper's numbers")

READINGS_JSON = json_kind(R.RESULTS_FORMAT, "a 'snan-hil readings' result")
READINGS_PNG = png_kind(report.HEATMAP_FORMAT, "a 'snan-hil readings' heat map")
TRADEOFF_PNG = png_kind(report.TRADEOFF_FORMAT, "a 'snan-hil readings' trade-off figure")
CACHE = OutputKind("a 'snan-hil readings' cache", R.ResultCache.owns)


def default_cache() -> Path:
    """``<user data folder>/readings-cache.sqlite`` (:mod:`snan_hil.files.userdata`)."""
    return user_data_dir() / "readings-cache.sqlite"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--vary", action="append", default=[], metavar="KEY=V1,V2,...",
                        help="a config key and its values (repeatable; the sweep is the cross "
                             "product). Any key of the model config, or astro.tau_ca_unit=s,ms "
                             "(each condition's tau_Ca read in seconds or milliseconds)")
    parser.add_argument("--from", dest="from_files", action="append", default=[],
                        metavar="READINGS_JSON",
                        help="instead of --vary: rerun the --best readings of earlier sweeps "
                             "(their readings.json; repeatable), e.g. at more --trials")
    parser.add_argument("--best", type=int, default=10,
                        help="with --from: how many of the best readings to run")
    add_set_option(parser, example="synapse.w_inh=20",
                   what="fix a value under every reading")
    parser.add_argument("--targets", default="paper", metavar="paper|FILE",
                        help="the numbers to score against: 'paper' (configs/paper-targets.yaml) "
                             "or a YAML file of the same form")
    parser.add_argument("--trials", type=int, default=5000,
                        help="trials per condition that the best readings reach (route "
                             "learning: trials/5 sessions, >= 10; 6x6 task: 10 sets x 10 "
                             "launches per 100 trials)")
    parser.add_argument("--race", action=argparse.BooleanOptionalAction, default=True,
                        help="racing (default): every reading starts at --race-start trials, "
                             "the readings clearly worse than the round's best (paired "
                             "bootstrap) are dropped, the others run to twice the trials, ... "
                             "up to --trials; --no-race runs every reading to --trials")
    parser.add_argument("--race-start", type=int, default=None, metavar="N",
                        help="trials of the first racing round, below --trials (default "
                             f"{R.RACE_START}; one round of --trials when that is fewer)")
    parser.add_argument("--race-keep", type=int, default=R.RACE_KEEP, metavar="K",
                        help="the K best readings of a round (by distance) are never dropped "
                             f"(default {R.RACE_KEEP})")
    parser.add_argument("--seed", type=int, default=1,
                        help="master seed (every reading sees the same trials)")
    parser.add_argument("--out", default="readings", metavar="DIR",
                        help="output folder: readings.json, readings.csv, readings.md, "
                             "readings.png")
    parser.add_argument("--heatmap", default=None, metavar="KEY_X,KEY_Y",
                        help="two varied keys for the heat map (default: the first two --vary "
                             "keys; the best distance over the other keys)")
    add_executor_options(parser, dask_note="same results as local processes; default: local "
                                              "worker processes")
    parser.add_argument("--cache", default=None, metavar="FILE",
                        help="SQLite cache of finished (reading, condition, trials, seed) "
                             f"results (default: {default_cache()})")
    parser.add_argument("--no-cache", action="store_true",
                        help="run everything, read and write no cache")
    parser.add_argument("--yes", action="store_true",
                        help=f"allow more than {R.MAX_COMBINATIONS} combinations")
    parser.add_argument("--top", type=int, default=report.MD_ROWS,
                        help="readings listed in the printed table and readings.md")
    parser.add_argument("--json", action="store_true",
                        help="print the result document (JSON) instead of tables")
    add_force_option(parser)


def _targets(text: str) -> tuple[list[R.Target], str]:
    if text == "paper":
        return R.load_targets(), str(R.DEFAULT_TARGETS)
    p = Path(text).expanduser()
    if not p.is_file():
        raise UserError(f"--targets {text}: no such file; give 'paper' or a YAML targets file "
                        f"like {R.DEFAULT_TARGETS}")
    return R.load_targets(p), str(p)


def _read_doc(path: str) -> dict:
    p = Path(path).expanduser()
    try:
        return json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise UserError(f"--from {path}: no such file; give the readings.json of an earlier "
                        "sweep") from None
    except IsADirectoryError:
        raise UserError(f"--from {path}: is a folder; give its readings.json") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise UserError(f"--from {path}: not a readings result ({exc.__class__.__name__}); "
                        "give the readings.json of an earlier sweep") from None


def _heat_keys(text: str | None, vary: dict) -> list[str]:
    keys = list(vary)
    if text is None:
        return [k for k in keys if len(vary[k]) > 1][:2]
    parts = [k.strip() for k in text.split(",")]
    if len(parts) != 2 or parts[0] == parts[1]:
        raise UserError(f"--heatmap {text!r}: give two different varied keys, KEY_X,KEY_Y")
    bad = [k for k in parts if k not in vary]
    if bad:
        raise UserError(f"--heatmap: {bad[0]} is not a --vary key "
                        f"({', '.join(keys) or 'nothing varies'})")
    return parts


def _check_options(args: argparse.Namespace) -> None:
    if args.trials < 1:
        raise UserError(f"--trials must be >= 1, got {args.trials}")
    if args.race_start is None:             # the default: one round when --trials is fewer
        args.race_start = R.RACE_START
    elif args.race_start < 1:
        raise UserError(f"--race-start must be >= 1, got {args.race_start}")
    elif args.race and args.race_start >= args.trials:
        raise UserError(f"--race-start {args.race_start} must be below --trials {args.trials} "
                        "(racing starts at --race-start trials and doubles up to --trials); "
                        "give a smaller --race-start, or --no-race")
    if args.race_keep < 1:
        raise UserError(f"--race-keep must be >= 1, got {args.race_keep}")
    if args.top < 1:
        raise UserError(f"--top must be >= 1, got {args.top}")
    check_executor_options(args)
    if args.no_cache and args.cache:
        raise UserError("--cache and --no-cache exclude each other")
    if args.seed < 0:
        raise UserError(f"--seed must be >= 0, got {args.seed}")
    if args.best != 10 and not args.from_files:
        raise UserError("--best needs --from (the sweeps whose best readings to rerun)")


def _readings(
        args: argparse.Namespace) -> tuple[list[R.Reading] | None, dict[str, list[Any]]]:
    """(the readings to rerun from --from, or None; the varied keys), their number checked."""
    explicit = None
    if args.from_files:
        if args.vary:
            raise UserError("--from and --vary exclude each other (--from reruns the readings "
                            "of earlier sweeps)")
        explicit = R.best_of([(f, _read_doc(f)) for f in args.from_files], args.best)
        vary = R.varied_keys(explicit)
        n = len(explicit)
    else:
        vary = R.parse_vary(args.vary)
        n = math.prod(len(v) for v in vary.values())
    if n == 0:
        raise UserError("--vary gives an empty product; give at least one value per key")
    if n > R.MAX_COMBINATIONS and not args.yes:
        raise UserError(f"--vary gives {n} combinations (more than {R.MAX_COMBINATIONS}); "
                        "vary fewer keys or values, or add --yes to run them all")
    return explicit, vary


def _cache_path(args: argparse.Namespace, outs: Outputs) -> Path | None:
    """The result cache (None with --no-cache), checked to be one and writable."""
    cache_path = None if args.no_cache else Path(args.cache or default_cache()).expanduser()
    if cache_path is not None:
        if cache_path.is_file() and not R.ResultCache.owns(cache_path):
            raise UserError(f"--cache {cache_path}: exists and is not a readings cache; give "
                            "another --cache path (or --no-cache)")
        outs.file("--cache", cache_path, CACHE, updates=True, create_folder=True)
    return cache_path


def run(args: argparse.Namespace) -> int:
    _check_options(args)
    explicit, vary = _readings(args)
    heat = _heat_keys(args.heatmap, vary)
    targets, targets_path = _targets(args.targets)
    outs, out, md = _outputs(args, vary, targets, targets_path)
    plan = R.plan_sweep(vary, targets, args.trials, args.seed, base=args.overrides,
                        readings=explicit)
    cache_path = _cache_path(args, outs)
    t_start = time.perf_counter()
    rows, summary = _sweep(args, plan, cache_path)
    wall_s = time.perf_counter() - t_start
    command = "snan-hil " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    doc = clean(R.result_document(plan, rows, vary=vary, base=args.overrides,
                                  targets_path=targets_path, command=command, rounds=summary))
    doc["cache"] = None if cache_path is None else str(cache_path)
    doc["wall_s"] = wall_s
    trade = _write(args, doc, heat, out, md)
    if args.json:
        print(json.dumps(doc, allow_nan=False))
        return 0
    console.print(report.rich_table(doc, args.top))
    console.print(f"{report.TIE_NOTE} Wall time {wall_s:.0f} s.", highlight=False)
    console.print(f"wrote {out}/readings.json, .csv, .md, .png"
                  + (f" and {out}/tradeoff.png, .md" if trade else ""),
                  highlight=False)
    return 0


def _outputs(args: argparse.Namespace, vary: Any, targets: Any, targets_path: Any
             ) -> tuple[Outputs, Path, Path]:
    """(the outputs, the --out folder, its readings.md), every file checked before work."""
    inputs = {"--targets": targets_path}
    inputs.update({f"--from {f}": f for f in args.from_files})
    outs = Outputs(inputs, force=args.force)
    out = outs.folder("--out", args.out, files={
        "readings.json": READINGS_JSON, "readings.csv": csv_kind(
            ",".join(report.csv_header({"vary": vary, "targets": [
                {"condition": t.condition, "quantity": t.quantity} for t in targets]})),
            "a 'snan-hil readings' CSV"),
        "readings.png": READINGS_PNG, "tradeoff.png": TRADEOFF_PNG})
    md = out / "readings.md"
    if md.exists() and not args.force and not (out / "readings.json").exists():
        raise UserError(f"--out {args.out}: readings.md exists and is not from a readings "
                        "sweep; move it away, give another --out, or --force to replace it")
    return outs, out, md


def _sweep(args: argparse.Namespace, plan: Any, cache_path: Path | None) -> tuple[Any, Any]:
    """Run the sweep's rounds (raced or not) through the executor, each result committed to
    the cache as it comes: (rows, the rounds' summary)."""
    executor = make_executor(args.workers, args.dask)
    rounds = R.race_rounds(args.trials, args.race_start) if args.race else [args.trials]
    cache = R.ResultCache(cache_path)
    try:
        if not args.json:
            cached0 = R.sweep_tasks(plan, cache, hi=rounds[0])[1]
            console.print(f"readings: {len(plan.readings)} combination(s) x "
                          f"{len(plan.units)} units; rounds of "
                          f"{', '.join(map(str, rounds))} trials"
                          f"{' (racing)' if len(rounds) > 1 else ''}; {len(cached0)} result(s) "
                          "of the first round from the cache (progress counts trials, weighted "
                          "by their cost)", highlight=False)
        with progress_display(enabled=not args.json) as progress:
            def run_tasks(tasks: list, label: str) -> list:
                tasks = seed_tasks(tasks, args.seed)

                def commit(i: int, result: dict) -> None:
                    t = tasks[i]
                    cache.put(t.key[0], t.params["unit"], t.params["reading"],
                              int(t.params["trials"][1]), args.seed, plan.fingerprint, result)
                return executor.execute(tasks, progress=progress, task=label, on_result=commit)

            return R.race(plan, cache, rounds, run_tasks, keep=args.race_keep)
    finally:
        cache.close()


def _write(args: argparse.Namespace, doc: dict[str, Any], heat: Any, out: Path,
           md: Path) -> bool:
    """Every output made in memory first (a failure leaves no partial set of files), then
    written; whether the trade-off figure was."""
    csv_text = report.csv_text(doc)
    md_text = report.markdown(doc, top=args.top)
    png = io.BytesIO()
    report.heatmap_figure(doc, heat, png)
    trade = None
    if report.has_tradeoff(doc):
        trade = io.BytesIO()
        report.tradeoff_figure(doc, trade)
        trade_md = report.tradeoff_markdown(doc)
    out.mkdir(parents=True, exist_ok=True)
    if trade is not None:
        atomic_write_bytes(out / "tradeoff.png", trade.getvalue())
        atomic_write_text(out / "tradeoff.md", trade_md)
    atomic_write_bytes(out / "readings.png", png.getvalue())
    atomic_write_text(out / "readings.csv", csv_text)
    atomic_write_text(md, md_text)
    atomic_write_json(out / "readings.json", doc, indent=1)
    return trade is not None
