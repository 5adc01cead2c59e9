"""``snan-hil demo``: the project's main job, on the emulator.

1. the SNAN in software (3x3 and 10x10, with and without astrocytes) next to the paper's
   numbers (sections 3.1-3.2);
2. the hardware chain of the paper's Fig. 10 on an emulated MemriCore board: train the 6x6
   route weights, program every set into the crossbar (two-stage write-and-verify), run the
   four scenarios (software / crossbar x astro / no astro), print the comparison and the speed
   and energy report, and write everything to ``--out``.

The emulated chip of the demo lives in ``--out`` (``chip.npz``), never in the user's default
chip file, so the demo does not overwrite a chip programmed with ``--port emu``. Every stage
(software rows, training, each weight set) is checkpointed in ``--out/checkpoint``; ``--resume``
continues a demo that was stopped (a reused ``--out`` without it is refused).
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import io
import json
import time
from pathlib import Path
from collections.abc import Sequence
from typing import Any

from rich.table import Table

from snan_hil.common.version import __version__
from snan_hil.files.atomicio import atomic_write_json, atomic_write_text
from snan_hil.common.errors import UserError
from snan_hil.host.checkpoint import RunFolder, check_out, open_run
from snan_hil.calibration.weights_io import weights_fingerprint
from snan_hil.host.experiments.common import clean
from snan_hil.host.config import load_config
from snan_hil.host.hil.compare import (CompareJob, CompareRequest, adopt_old_snapshots,
                                       write_outputs)
from snan_hil.host.hil.config import HilConfig, load_hil_config
from snan_hil.host.hil.train import save_weights, train_sets
from snan_hil.host.hil.runner import check_launches
from snan_hil.host.hil.synapses import (HW_MODES, check_mode_for_config,
                                        check_mode_for_protocol)
from snan_hil.host.intervals import METHOD_TEXT, flat_intervals, format_interval, inside_text
from snan_hil.host.simulate import ComparisonRow, memory_estimate, snan_comparison
from snan_hil.files.outputs import OutputKind, Outputs, csv_kind, json_kind
from snan_hil.lab.opener import plan_board
from snan_hil.lab.ports import BoardAddress
from snan_hil.lab.runner import RunOptions, run_job
from snan_hil.tools.commands.compare import add_resume_option, print_results
from snan_hil.tools.commands._options import add_mode_option, add_set_option, set_values
from snan_hil.tools.commands.sim import note_kernel_compile
from snan_hil.tools.commands._snan import add_reading_option, reading_overrides
from snan_hil.tools.commands.train import check_sets_reach_training
from snan_hil.tools.console import console, err_console, progress_display, warn
from snan_hil.tools.output_kinds import (CHIP_STATE, HISTORY_DB, LAYOUT, WEIGHTS,
                                         add_force_option, compare_files)
from snan_hil.tools.resources import check_memory

COMPARISON_PRESETS = ("snan-3x3", "snan-10x10")
DEMO_FORMAT = "snan-hil-demo/1"
#: columns of software_vs_paper.csv before the 95 % intervals were added (still recognised)
TABLE_COLUMNS_V1 = ["grid", "astro", "trials", "success_rate", "paper_success_rate",
                    "median_steps", "paper_median_steps", "mean_steps",
                    "success_within_tolerance", "median_within_tolerance"]
#: the table's columns: the first ones as before, then the 95 % intervals (flat in the CSV,
#: [low, high] in JSON) and whether the paper's value lies inside them
TABLE_COLUMNS = [*TABLE_COLUMNS_V1, "success_rate_ci", "median_steps_ci",
                 "paper_success_inside", "paper_median_inside", "paper_success_distance",
                 "paper_median_distance", "ci_method"]
CSV_COLUMNS = list(flat_intervals({k: None for k in TABLE_COLUMNS}))
SOFTWARE_FILES: dict[str, OutputKind] = {
    "software_vs_paper.csv": csv_kind(",".join(CSV_COLUMNS),
                                      "the demo's software-vs-paper table",
                                      earlier=(",".join(TABLE_COLUMNS_V1),)),
    "demo.json": json_kind(DEMO_FORMAT, "a 'snan-hil demo' summary"),
}

NAME = "demo"
HELP = ("run the main job: SNAN in software vs the paper, then train -> program -> compare on "
        "the board emulator")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--trials", type=int, default=5000,
                        help="software trials per configuration (default 5000: intervals "
                             "narrow enough to compare with the paper's numbers; the paper "
                             "used 500)")
    add_reading_option(parser)
    parser.add_argument("--sets", type=int, default=10, help="6x6 weight sets to train (paper: 10)")
    parser.add_argument("--launches", type=int, default=10,
                        help="launches per set and scenario (paper: 10)")
    parser.add_argument("--seed", type=int, default=1, help="random seed of every stage")
    parser.add_argument("--out", default="demo-results", metavar="DIR",
                        help="folder for the weights, the emulated chip, the comparison files")
    parser.add_argument("--software-only", action="store_true",
                        help="only the software comparison (no emulator)")
    parser.add_argument("--protocol", choices=("framed", "legacy"), default="framed",
                        help="what the emulated board speaks: framed (this project's firmware, "
                             "the default) or legacy (the existing firmware's line protocol)")
    parser.add_argument("--mcu", choices=("model", "firmware"), default="model",
                        help="the emulated board's MCU: the Python firmware model (default) or "
                             "the C firmware ELF on an instruction-level RISC-V CPU (make "
                             "firmware builds it; framed protocol only)")
    add_mode_option(parser, HW_MODES, help="how the hw scenarios read the synapses (see "
                    "'snan-hil compare --help'; default: on-board where the board has the "
                    "decision window, else batch over framed, per-window over legacy)")
    add_set_option(parser, example="synapse.w_inh=10",
                   what="config override of every stage: the software comparison's presets "
                        "and the hardware chain's 6x6 model (after configs/hil-6x6.yaml's own "
                        "changes); grid size and astro.enabled are set by the stages")
    parser.add_argument("--json", action="store_true",
                        help="print the demo's summary as one JSON object (also written to "
                             "--out/demo.json) instead of tables")
    add_force_option(parser)
    add_resume_option(parser)


def comparison_table(rows: list) -> list[dict[str, Any]]:
    """The software-vs-paper rows as dicts (:data:`TABLE_COLUMNS`)."""
    out = []
    for r in rows:
        s = r.summary
        out.append({"grid": s["grid"], "astro": bool(r.astro), "trials": s["trials"],
                    "success_rate": s["success_rate"], "paper_success_rate": r.paper_success,
                    "median_steps": s["median_steps"], "paper_median_steps": r.paper_median,
                    "mean_steps": s["mean_steps"], "success_within_tolerance": r.success_ok,
                    "median_within_tolerance": r.median_ok,
                    "success_rate_ci": s.get("success_rate_ci"),
                    "median_steps_ci": s.get("median_steps_ci"),
                    **{k: v for k, v in r.paper.items() if k in TABLE_COLUMNS},
                    "ci_method": s.get("ci_method")})
    return out


def table_csv(table: list[dict[str, Any]]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=CSV_COLUMNS, lineterminator="\n")
    w.writeheader()
    for row in table:
        flat = flat_intervals(row)
        w.writerow({k: ("" if flat.get(k) is None else flat[k]) for k in CSV_COLUMNS})
    return buf.getvalue()


def check_software(trials: int, overrides: list[str]) -> None:
    """UserError (one line) unless the software comparison can run: ``trials`` >= 1 and its
    memory estimate fits (checked before anything is written)."""
    if trials < 1:
        raise UserError(f"--trials must be >= 1, got {trials}")
    for preset in COMPARISON_PRESETS:
        cfg = load_config(preset=preset, overrides=list(overrides))
        check_memory(memory_estimate(cfg, trials), f"{trials} trials of {preset}",
                     "give fewer --trials")


def run_snan_comparison(trials: int, seed: int, overrides: list[str], *,
                        show: bool = True, checkpoint: RunFolder | None = None) -> list:
    """Run the software SNAN next to the paper's numbers; print the table (``show``);
    returns the :class:`~snan_hil.host.simulate.ComparisonRow` rows. With a ``checkpoint``
    every finished row is committed and taken from there when the run is resumed."""
    check_software(trials, overrides)
    note_kernel_compile()
    t0 = time.perf_counter()

    def unit(preset: str, astro: bool) -> str:
        return f"software-{preset}-{'astro' if astro else 'noastro'}"

    def done(preset: str, astro: bool) -> ComparisonRow | None:
        data = checkpoint.done(unit(preset, astro)) if checkpoint is not None else None
        return ComparisonRow(**data) if data is not None else None

    def on_row(row: ComparisonRow) -> None:
        if checkpoint is not None:
            checkpoint.commit(unit(row.preset, row.astro), dataclasses.asdict(row))

    with progress_display() as progress:
        rows = snan_comparison(trials, seed, presets=COMPARISON_PRESETS,
                               overrides=tuple(overrides), progress=progress, done=done,
                               on_row=on_row)
    if not show:
        return rows
    table = Table(title=f"SNAN in software vs the paper ({trials} trials per row, seed {seed})")
    for col in ("grid", "astro", "success [95 % CI]", "paper", "median [95 % CI]", "paper",
                "mean", "paper in CI (succ/med)", "ok (succ/med)"):
        table.add_column(col, justify="right")
    for r in rows:
        s = r.summary
        med = "-" if s["median_steps"] is None else f"{s['median_steps']:.1f}"
        mean = "-" if s["mean_steps"] is None else f"{s['mean_steps']:.1f}"
        ok = ("yes" if r.success_ok else "no") + "/" + ("yes" if r.median_ok else "no")
        paper = r.paper
        inside = (inside_text(paper.get("paper_success_inside")) + "/"
                  + inside_text(paper.get("paper_median_inside")))
        table.add_row(s["grid"], "yes" if r.astro else "no",
                      f"{100 * s['success_rate']:.1f} % "
                      f"{format_interval(s.get('success_rate_ci'), percent=True)}",
                      f"{100 * r.paper_success:.1f} %",
                      f"{med} {format_interval(s.get('median_steps_ci'))}",
                      f"{r.paper_median:.0f}", mean, inside, ok)
    console.print(table)
    console.print(f"95 % intervals: {METHOD_TEXT}. tolerance: success +-7 points / median "
                  "+-25 %; the readings behind these numbers and the known gaps are in "
                  f"docs/model.md. Total {time.perf_counter() - t0:.1f} s.", highlight=False)
    return rows


def hil_chain_files(sets: int) -> dict[str, OutputKind]:
    """The files :func:`run_hil_chain` writes into its folder."""
    return {"weights.npz": WEIGHTS, "chip.npz": CHIP_STATE, "chip.layout.json": LAYOUT,
            "chip.history.sqlite": HISTORY_DB,
            **compare_files(list(range(sets)), programming=True)}


#: config keys a demo --set may not name: the stages set them (each runs with and without
#: astrocytes; the software rows are the paper's 3x3 and 10x10, the hardware chain its 6x6)
STAGE_KEYS = {"astro.enabled": "every stage runs with and without astrocytes",
              "grid.rows": "the stages run the paper's grids (3x3, 10x10 and the 6x6 task)",
              "grid.cols": "the stages run the paper's grids (3x3, 10x10 and the 6x6 task)"}


def check_demo_sets(overrides: Sequence[str]) -> None:
    """UserError (one line) for a ``--set`` of a key the demo's stages set themselves
    (:data:`STAGE_KEYS`) or an invalid one."""
    for key in set_values(overrides):
        if key in STAGE_KEYS:
            raise UserError(f"--set {key}: {STAGE_KEYS[key]}, so the demo does not take it; "
                            "use 'snan-hil sim' or 'train'/'compare' for other values")


def demo_hil_config(overrides: Sequence[str] = ()) -> HilConfig:
    """The hardware chain's HIL config: configs/hil-6x6.yaml (its ``set``), then the demo's
    ``--set`` ``overrides``. UserError (one line) for a key the stages set themselves
    (:data:`STAGE_KEYS`) or a --set the training would not use (``train_set``)."""
    check_demo_sets(overrides)
    hil = load_hil_config(overrides=list(overrides))
    check_sets_reach_training(hil, list(overrides))
    return hil


def run_hil_chain(out: Path, *, sets: int, launches: int, seed: int,
                  protocol: str = "framed", mode: str | None = None, mcu: str = "model",
                  show: bool = True, checkpoint: RunFolder | None = None,
                  overrides: Sequence[str] = ()) -> dict:
    """Train -> program -> compare -> report on an emulated chip kept in ``out/chip.npz``
    (``out`` checked by the caller, :func:`hil_chain_files`), speaking ``protocol``;
    ``mode``: how the hw scenarios read the synapses (None: the board's default). With a
    ``checkpoint`` (in ``out``) the training and every weight set are committed when
    finished, and a resumed run continues from there with the chip as it was. ``overrides``:
    the demo's ``--set`` texts, applied to the 6x6 model after the HIL config's own
    (:func:`demo_hil_config`)."""
    if sets < 1 or launches < 1:
        raise UserError(f"--sets and --launches must be >= 1, got {sets} and {launches}")
    hil = demo_hil_config(overrides)
    out.mkdir(parents=True, exist_ok=True)
    cycles = hil.task.cycles
    weights = out / "weights.npz"
    chip = out / "chip.npz"
    with progress_display() as progress:
        training = checkpoint.done("training") if checkpoint is not None else None
        if training is not None and weights.is_file() \
                and weights_fingerprint(weights) == training["sha256"]:
            summary = training["summary"]
        else:
            trained = train_sets(hil.train_config(), sets=sets, cycles=cycles, seed=seed,
                                 start=hil.task.start, goal=hil.task.goal, progress=progress,
                                 extra={"hil_config": hil.to_dict(), "base_seed": seed})
            save_weights(trained, weights)
            summary = trained.summary()
            if checkpoint is not None:
                checkpoint.commit("training", {"summary": summary,
                                               "sha256": weights_fingerprint(weights)})
        board = plan_board(BoardAddress("emu", protocol=protocol, state_file=str(chip), seed=0,
                                        mcu=mcu))
        request = CompareRequest(str(weights), hil, launches=launches, seed=seed, mode=mode,
                                 report_dir=out / "programming")
        job = CompareJob(request)
        if checkpoint is not None and checkpoint.resumed:
            adopt_old_snapshots(out, job.unit_order())
        results = run_job(job, board, RunOptions(
            history=out / "chip.history.sqlite", command="snan-hil demo", folder=checkpoint,
            progress=progress, seed=seed, warn=warn)).result
    results["training"] = summary
    paths = write_outputs(results, out)
    results["files"] = paths
    if show:
        print_results(results, paths)
    return results


def run(args: argparse.Namespace) -> int:
    files, hil_config = _check(args)
    # checked before the software comparison starts; a reused --out is resumed or refused
    out = check_out(Outputs(force=args.force), args.out, NAME, resume=args.resume,
                    files=files)
    checkpoint = open_run(out, NAME, _identity(args, hil_config), resume=args.resume)
    if checkpoint.resumed:
        err_console.print(f"resuming the run in {out}", highlight=False, soft_wrap=True)
    show = not args.json
    if show:
        from snan_hil.host.reading_presets import describe
        console.print(f"reading {describe(args.reading)}", highlight=False, soft_wrap=True,
                      markup=False)
    # the reading preset applies to the software comparison; the hardware chain runs
    # configs/hil-6x6.yaml (its own training reading) with the --set values
    rows = run_snan_comparison(args.trials, args.seed,
                               reading_overrides(args) + list(args.overrides), show=show,
                               checkpoint=checkpoint)
    table = comparison_table(rows)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "software_vs_paper.csv", table_csv(table))
    summary: dict[str, Any] = {"format": DEMO_FORMAT, "version": __version__, "seed": args.seed,
                               "trials": args.trials,
                               "reading": args.reading,
                               "software_vs_paper": table, "hil": None,
                               "files": {"software_vs_paper": str(out / "software_vs_paper.csv")}}
    if not args.software_only:
        _hardware_half(args, out, checkpoint, summary, show)
    summary = clean(summary)
    atomic_write_json(out / "demo.json", summary, indent=1, allow_nan=False)
    checkpoint.complete()
    if args.json:
        print(json.dumps(summary))
    else:
        console.print(f"wrote {out / 'software_vs_paper.csv'} and {out / 'demo.json'}",
                      highlight=False)
    return 0


def _check(args: argparse.Namespace) -> tuple[dict[str, OutputKind], HilConfig | None]:
    """Every option checked before any work (UserError, one line): the files the demo
    writes and the hardware chain's HIL config (None with ``--software-only``)."""
    files = dict(SOFTWARE_FILES)
    if not args.software_only:          # checked before the software comparison starts
        check_mode_for_protocol(args.protocol, args.mode)
        if args.sets < 1:
            raise UserError(f"--sets must be >= 1, got {args.sets}")
        check_launches(args.launches)
        files.update(hil_chain_files(args.sets))
        if args.mcu == "firmware":      # before any long work: the ELF and the protocol
            if args.protocol != "framed":
                raise UserError("the C firmware (--mcu firmware) speaks the framed protocol "
                                "only; use --protocol framed or --mcu model")
            from snan_hil.firmware_emu.fw_image import FirmwareImage
            FirmwareImage.load()
    check_demo_sets(args.overrides)
    hil_config = None if args.software_only else demo_hil_config(args.overrides)
    if hil_config is not None:          # --mode on-board and the --set model: before any work
        check_mode_for_config(args.mode, hil_config.launch_config(False))
    check_software(args.trials, args.overrides)
    return files, hil_config


def _identity(args: argparse.Namespace, hil_config: HilConfig | None) -> dict[str, Any]:
    """What a resumed demo must share with this one."""
    return {"trials": args.trials, "seed": args.seed, "overrides": list(args.overrides),
            **({"reading": args.reading} if args.reading != "scored" else {}),
            "software_only": bool(args.software_only),
            "hil": None if hil_config is None else {
                "sets": args.sets, "launches": args.launches, "protocol": args.protocol,
                "mode": args.mode, "hil_config": hil_config.to_dict(),
                # only when not the default, so runs started before --mcu still resume
                **({"mcu": args.mcu} if args.mcu != "model" else {})}}


def _hardware_half(args: argparse.Namespace, out: Path, checkpoint: RunFolder,
                   summary: dict[str, Any], show: bool) -> None:
    """The hardware chain (the comparison job on the emulated chip in ``out``), into
    ``summary``."""
    if show:
        console.rule("hardware chain on the board emulator (paper Fig. 10)")
    results = run_hil_chain(out, sets=args.sets, launches=args.launches, seed=args.seed,
                            protocol=args.protocol, mcu=args.mcu,
                            mode=args.mode.replace("-", "_") if args.mode else None,
                            show=show, checkpoint=checkpoint,
                            overrides=args.overrides)
    summary["hil"] = {k: results.get(k) for k in ("grid", "start", "goal", "sets",
                                                  "launches", "step_limit", "scenarios",
                                                  "acceptance")}
    summary["hil"]["mcu"] = args.mcu
    summary["hil"]["paper_median_steps"] = {"without astrocytes": 14.0,
                                            "with astrocytes": 7.0}
    summary["files"].update(results.get("files") or {})
