"""``snan-hil learn``: route learning with the weights on the chip — three arms on paired seeds
(software STDP, software with the fitted device model, the chip), every STDP update of the chip
arm applied as SET/RESET pulses (:mod:`snan_hil.host.hil.learn`; docs/learning.md).

Examples::

    snan-hil characterize --port emu          # the device model the device and chip arms use
    snan-hil learn --port emu --sessions 10 --out learn-results
    snan-hil learn --port emu --protocol legacy --sessions 3 --out learn-legacy
    snan-hil learn --port emu --resume --out learn-results      # after a kill
    snan-hil compare --weights learn-results/learnt.npz --weight-set 9 --no-program --port emu

Writes into ``--out``: ``learn.json`` (everything), ``curves.csv`` (median and success per arm
and cycle with 95 % intervals), ``sessions.csv`` (every test and training trial),
``ledger.csv`` (the chip arm's pulses per session and cycle: SET, RESET, array energy),
``learn.png`` (the learning curves beside the paper's Fig. 7 values, and the ledger),
``cell_ledger.csv`` and ``weights.csv`` (pulses per cell and cycle, weights per synapse and
cycle: :mod:`snan_hil.host.hil.learn_dataset`) and, with
the chip arm, ``learnt.npz`` (the weights each session left on the chip, as ``train`` writes
them) while the board's layout records the last session's learnt weights as programmed — so
``compare --no-program`` launches on the chip's learnt state.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import io
import json
import dataclasses
import time
from pathlib import Path
from typing import Any

import numpy as np
from rich.table import Table

from snan_hil.calibration.layout import Layout
from snan_hil.calibration.weights_io import compact_to_dense, validate_weights
from snan_hil.common.errors import UserError
from snan_hil.crossbar_model.fitted import MODEL_FORMAT, DeviceModel, LearningPulse
from snan_hil.files.atomicio import atomic_write_json, atomic_write_text
from snan_hil.files.outputs import Outputs, csv_kind, json_kind, png_kind
from snan_hil.host.checkpoint import RunFolder, check_out, open_run
from snan_hil.host.experiments.calcium import family_config, level_for_duration
from snan_hil.host.hil.config import load_hil_config
from snan_hil.host.hil.learn import (ARMS, LearnConfig, LearnJob, LearnTask, board_units,
                                    run_learning)
from snan_hil.host.hil.learn_chip import layout_cells
from snan_hil.host.hil.learn_dataset import (CELL_LEDGER, CELL_LEDGER_HEADER, WEIGHTS_HEADER,
                                             write_dataset)
from snan_hil.host.hil.learn_dataset import WEIGHTS as DATASET_WEIGHTS
from snan_hil.host.hil.learning import PulseBudget
from snan_hil.host.hil.synapses import HW_MODES, check_mode, check_mode_for_protocol
from snan_hil.host.hil.train import TrainResult, save_weights
from snan_hil.lab.fanout import BoardSet, run_on_boards
from snan_hil.lab.opener import BoardPlan, FileUse
from snan_hil.lab.runner import JobRun
from snan_hil.records.history import History
from snan_hil.tools.commands._board import file_use, plan_from_args
from snan_hil.tools.commands._boards import add_board_options, board_set, print_boards
from snan_hil.tools.commands._history import add_history_arguments, recording
from snan_hil.tools.commands._job import run_on_board, run_options
from snan_hil.tools.commands._run import runs_database
from snan_hil.tools.commands._options import (add_conversions_option, add_mode_option,
                                              check_conversions)
from snan_hil.tools.commands.characterize import check_pulse_amplitudes
from snan_hil.tools.commands.train import add_hil_config_arguments
from snan_hil.common.numba_cache import announce_compile
from snan_hil.tools.console import console, err_console, progress_display
from snan_hil.tools.device_figures import LEARN_PNG_FORMAT, plot_learning
from snan_hil.tools.output_kinds import WEIGHTS, add_force_option
from snan_hil.tools.ports import add_port_arguments
from snan_hil.tools.verdicts import print_verdicts

NAME = "learn"
HELP = ("route learning with the weights on the chip: software / fitted device model / chip "
        "arms on paired seeds, STDP updates as SET/RESET pulses (paper Fig. 7 on hardware)")

RESULT_FORMAT = "snan-hil-learn/1"
CURVES_HEADER = ("arm,cycle,sessions,median_steps,median_ci_low,median_ci_high,success_rate,"
                 "success_ci_low,success_ci_high,pulses_per_cycle")
SESSIONS_HEADER = "arm,session,cycle,test_steps,test_success,train_steps,train_success,pulses"
LEDGER_HEADER = "session,cycle,stage,set,reset,energy_j,energy_estimate_j"
FILES = {"learn.json": json_kind(RESULT_FORMAT, "a 'snan-hil learn' result"),
         "curves.csv": csv_kind(CURVES_HEADER, "a 'snan-hil learn' CSV"),
         "sessions.csv": csv_kind(SESSIONS_HEADER, "a 'snan-hil learn' CSV"),
         "ledger.csv": csv_kind(LEDGER_HEADER, "a 'snan-hil learn' CSV"),
         "learn.png": png_kind(LEARN_PNG_FORMAT, "a 'snan-hil learn' figure"),
         "learnt.npz": WEIGHTS,
         CELL_LEDGER: csv_kind(CELL_LEDGER_HEADER, "a 'snan-hil learn' CSV"),
         DATASET_WEIGHTS: csv_kind(WEIGHTS_HEADER, "a 'snan-hil learn' CSV")}
#: 5x5 astrocytes (not in the paper): the 10x10 family at this calcium duration, as fig7
DURATION_5X5 = 25.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--grid", type=int, default=6, metavar="N",
                        help="N x N field: 6 = the hardware task of configs/hil-6x6.yaml "
                             "(18 -> 0); 3, 5, 10 = fig7's configs (the chip arm needs N <= 8: "
                             "4 N (N - 1) synapses in 32 x 8 cells)")
    parser.add_argument("--start", type=int, default=None,
                        help="start cell (default: 18 on 6x6, else the last cell)")
    parser.add_argument("--goal", type=int, default=None, help="goal cell (default: 0)")
    parser.add_argument("--sessions", type=int, default=10,
                        help="sessions per arm (fresh random weights each, paired across arms)")
    parser.add_argument("--cycles", type=int, default=20, help="training cycles per session")
    parser.add_argument("--seed", type=int, default=1, help="master seed of the sessions")
    parser.add_argument("--arms", default=",".join(ARMS),
                        help="comma-separated subset of " + ", ".join(ARMS))
    parser.add_argument("--device-seed", type=int, default=0, metavar="N",
                        help="device-model arm: another draw of its devices and their noise "
                             "from the same model over the same sessions (default 0; two "
                             "values show how two chips of one model differ: the noise of the "
                             "arm's prediction, docs/learning.md section 3)")
    parser.add_argument("--refresh-every", type=int, default=0, metavar="N",
                        help="chip arm: re-read the synapses every N cycles and correct them "
                             "(0: open loop)")
    parser.add_argument("--pulse-budget", type=int, default=None, metavar="N",
                        help="device and chip arms: at most N learning pulses a session "
                             "(default: no limit; docs/learning.md section 8)")
    parser.add_argument("--cell-budget", type=int, default=None, metavar="N",
                        help="at most N learning pulses per synapse cell and session (default: "
                             "no limit)")
    parser.add_argument("--plan-pulses", type=int, default=None, metavar="N",
                        help="at most N pulses per synapse in one cycle's plan (default: no "
                             "limit)")
    parser.add_argument("--threshold-steps", type=float, default=0.5, metavar="X",
                        help="send a pulse only while a synapse's pending change is at least X "
                             "predicted steps (0.5: round to the nearest step; 1: thresholded)")
    parser.add_argument("--pace", type=float, default=1.0, metavar="F",
                        help="with --pulse-budget: one cycle may take at most this share of "
                             "the session's pulses left (default 1: no pacing)")
    pulse = LearningPulse()
    parser.add_argument("--set-v", type=float, default=pulse.set_v,
                        help="SET amplitude of the learning pulse, V (the device model must be "
                             "of this pulse)")
    parser.add_argument("--reset-v", type=float, default=pulse.reset_v,
                        help="RESET amplitude of the learning pulse, V")
    parser.add_argument("--width-us", type=int, default=pulse.width_us,
                        help="width of the learning pulse, us")
    parser.add_argument("--model", metavar="FILE", default=None,
                        help="device model JSON (characterize --model); default: the newest "
                             "model of this pulse in the board's history database")
    parser.add_argument("--chip-model", action="store_true",
                        help="plan the chip arm's pulses with the chip-level fit only (default: "
                             "each cell's own fit where it was measured)")
    add_mode_option(parser, HW_MODES,
                    help="how the chip arm reads the synapses: on-board = one DECISION_WINDOW "
                         "per decision, the board reads the synapses and runs the motor "
                         "neurons and answers their spike times for STDP; batch = one "
                         "SPIKE_BATCH per decision, the host runs the motor neurons; per-spike, "
                         "per-window as in run (docs/learning.md); default: on-board on a board "
                         "with DECISION_WINDOW, batch on one with SPIKE_BATCH, per-window "
                         "otherwise")
    add_conversions_option(parser)
    parser.add_argument("--layout", default=None,
                        help="layout file of the chip (default: the port's)")
    parser.add_argument("--out", default="learn-results", metavar="DIR",
                        help="folder for the results and the run's checkpoint/")
    parser.add_argument("--resume", action="store_true",
                        help="continue the run in --out where it stopped (no pulse is sent "
                             "twice)")
    parser.add_argument("--no-figure", action="store_true", help="skip learn.png")
    add_hil_config_arguments(parser)
    add_port_arguments(parser)
    add_board_options(parser, "sessions")      # several boards: docs/multiboard.md
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    add_history_arguments(parser)
    add_force_option(parser)


COMPILE_NOTE = ("compiling the network kernels (first run after an install or a change, about "
                "a minute)…")


def _compile_note() -> None:
    err_console.print(COMPILE_NOTE, markup=False, highlight=False, soft_wrap=True)


def model_config(args: argparse.Namespace):
    """(SNAN model config, start, goal) of ``--grid`` (6: the HIL config; else fig7's)."""
    n = int(args.grid)
    if n == 6 or args.config is not None:
        hil = load_hil_config(args.config, args.overrides)
        cfg = hil.model
        start = hil.task.start if args.start is None else args.start
        goal = hil.task.goal if args.goal is None else args.goal
        if n != cfg.grid.rows:
            raise UserError(f"--grid {n} does not match the config's {cfg.grid.rows}x"
                            f"{cfg.grid.cols} field; leave --grid out with --config")
        return cfg, start, goal
    from snan_hil.host.config import load_config
    if n == 3:
        cfg = load_config(preset="snan-3x3", overrides=args.overrides)
    elif n in (5, 10):
        sets = [] if n == 10 else ["grid.rows=5", "grid.cols=5", "grid.max_steps=300"]
        cfg = load_config(preset="snan-10x10", overrides=[*sets, *args.overrides])
        if n == 5:
            cfg = family_config(cfg, level_for_duration(cfg, DURATION_5X5))
    else:
        raise UserError(f"--grid {n}: give 3, 5, 6 or 10 (or --config FILE for another field)")
    start = n * n - 1 if args.start is None else args.start
    goal = 0 if args.goal is None else args.goal
    return cfg, start, goal


def budget_of(args: argparse.Namespace) -> PulseBudget:
    """The learning pulses' budget of ``--pulse-budget`` ... ``--pace`` (UserError, one
    line, for a value out of range)."""
    try:
        return PulseBudget(args.pulse_budget, args.cell_budget, args.plan_pulses,
                           args.threshold_steps, args.pace)
    except ValueError as exc:
        raise UserError(f"learn: {exc}") from None


def _model_of(args: argparse.Namespace, pulse: LearningPulse, history_path: Path | None
              ) -> tuple[DeviceModel, str]:
    if args.model:
        if not Path(args.model).expanduser().exists():
            raise UserError(f"--model {args.model}: no such file; write a device model with "
                            "'snan-hil characterize --model FILE', or leave --model out for "
                            "the newest model of this pulse in the board's history")
        try:
            data = json.loads(Path(args.model).expanduser().read_text(encoding="utf-8"))
            model = DeviceModel.from_dict(data)
        except (OSError, ValueError) as exc:
            why = str(exc).removeprefix(f"not a device model ({MODEL_FORMAT}): ")
            if isinstance(exc, json.JSONDecodeError):
                why = f"not JSON ({exc.msg} at line {exc.lineno})"
            raise UserError(f"--model {args.model}: not a device model ({MODEL_FORMAT}): "
                            f"{why}; write one with 'snan-hil characterize --model FILE'") \
                from None
        source = f"--model {args.model}"
    else:
        found = None
        if history_path is not None and Path(history_path).is_file():
            with History.open(history_path, create=False) as db:
                found = db.latest_device_model(set_v=pulse.set_v, reset_v=pulse.reset_v,
                                               width_us=pulse.width_us)
        if found is None:
            raise UserError(f"no device model of the learning pulse (SET {pulse.set_v:g} V, "
                            f"RESET {pulse.reset_v:g} V, {pulse.width_us} us) in the board's "
                            f"history {history_path}; run 'snan-hil characterize --port "
                            f"{args.port}' with the same pulse first, or give --model FILE")
        model = DeviceModel.from_dict(found["model"])
        source = f"history {history_path} (model {found['id']}, run {found['run_id']})"
    p = model.pulse
    if (abs(p.set_v - pulse.set_v) > 1e-9 or abs(p.reset_v - pulse.reset_v) > 1e-9
            or p.width_us != pulse.width_us):
        raise UserError(f"the device model is of SET {p.set_v:g} V / RESET {p.reset_v:g} V / "
                        f"{p.width_us} us, the learning pulse is SET {pulse.set_v:g} V / RESET "
                        f"{pulse.reset_v:g} V / {pulse.width_us} us; give the model's pulse "
                        "(--set-v, --reset-v, --width-us) or characterise this one")
    return model, source


NAMES = {"arms": "--arms", "sessions": "--sessions", "cycles": "--cycles",
         "refresh_every": "--refresh-every", "set_v": "--set-v", "reset_v": "--reset-v",
         "width_us": "--width-us", "mode": "--mode", "device_seed": "--device-seed"}
"""How the learning job names its config's fields in messages: the options."""

UNITS = "per-cycle/1"
"""The checkpoint's units (chip units per session and cycle, the runner's pulse journal): a
checkpoint of another cut is refused on --resume."""


def run(args: argparse.Namespace) -> int:
    check_conversions(args)
    job = _job(args)
    lc = job.lc
    boards = _boards(args, lc)          # --boards/--dask: checked, not opened yet
    plan = _board_plan(args, lc, boards)
    outs = plan.outputs if plan is not None else Outputs(_named(args), force=args.force)
    out = check_out(outs, args.out, NAME, resume=args.resume, files=_files(args, lc, boards))
    board = _peek(args, job, plan)                 # who the board is (opened once, closed)
    job.model, model_source = _model_of(args, lc.pulse, board.get("history")) \
        if "device" in lc.arms or "chip" in lc.arms else (None, None)
    folder = open_run(out, NAME, _identity(args, job, board, boards), resume=args.resume)
    if folder.resumed:
        err_console.print(f"resuming the run in {out}", highlight=False, soft_wrap=True)
    t0 = time.perf_counter()
    with announce_compile(_compile_note):        # "compiling ..." when numba compiles
        doc, layout_path = _learn(args, job, plan, boards, folder)
    doc["model_source"] = model_source
    paths = _write_files(args, doc, out, job, layout_path)
    folder.complete()
    doc["wall_total_s"] = time.perf_counter() - t0
    _report(args, doc, paths)
    print_verdicts(NAME, doc, json_mode=args.json)
    return 0


def _write_files(args: argparse.Namespace, doc: dict[str, Any], out: Path, job: LearnJob,
                 layout_path: Path | None) -> dict[str, str]:
    """The run's files (module doc): the tables and figure, the dataset per cell and cycle,
    with the chip arm on one board the learnt weights, then ``learn.json``. {name: path}."""
    lc, chip = job.lc, "chip" in doc["arms"] and layout_path is not None
    paths = write_outputs(doc, out, job.cfg, lc, figure=not args.no_figure)
    cells = layout_cells(Layout.load(layout_path), job.task.nbr) \
        if chip and layout_path is not None else None
    paths.update(write_dataset(doc, out, cells))       # per cell and cycle, reloadable
    if chip and layout_path is not None:
        paths.update(record_learnt(doc, out, layout_path, job.cfg, lc))
    atomic_write_json(out / "learn.json", {"format": RESULT_FORMAT, **doc}, indent=1,
                      allow_nan=False, default=_jsonable)
    paths["learn.json"] = str(out / "learn.json")
    return paths


def _job(args: argparse.Namespace) -> LearnJob:
    """The learning job of the options (checked without a board: one line)."""
    arms = tuple(a.strip() for a in str(args.arms).split(",") if a.strip())
    cfg, start, goal = model_config(args)
    try:
        pulse = LearningPulse(args.set_v, args.reset_v, args.width_us)
    except ValueError as exc:
        raise UserError(f"learn: {exc}") from None
    check_pulse_amplitudes(args)
    budget = budget_of(args)
    lc = LearnConfig(start=int(start), goal=int(goal), sessions=args.sessions,
                     cycles=args.cycles, seed=args.seed, arms=arms,
                     refresh_every=args.refresh_every, per_cell=not args.chip_model,
                     mode=args.mode.replace("-", "_") if args.mode else None, pulse=pulse,
                     budget=budget, conversions=args.conversions,
                     device_seed=args.device_seed)
    job = LearnJob(cfg, lc, names=NAMES)
    if "chip" in arms:
        check_mode_for_protocol(args.protocol, args.mode)
    return job


def _named(args: argparse.Namespace) -> dict[str, Any]:
    return {"--config": args.config, "--model": args.model}


def _boards(args: argparse.Namespace, lc: LearnConfig) -> BoardSet | None:
    """``--boards``/``--dask`` checked (UserError, one line): None without them."""
    record = recording(args) and args.record != "off"
    boards = board_set(args, use=FileUse(record=record, updates_layout=True), what="sessions",
                       reassign_note=" (one board: continue a lost run with --resume)",
                       refusals=[("chip" not in lc.arms,
                                  "--boards/--dask spread the chip arm's sessions; --arms has "
                                  "no chip (add it, or leave --boards out)")])
    if boards is not None and not args.model:
        raise UserError("--boards/--dask need the device model as a file (--model FILE, "
                        "'snan-hil characterize --model FILE'): each board's history is on "
                        "its worker")
    return boards


def _board_plan(args: argparse.Namespace, lc: LearnConfig, boards: BoardSet | None
                ) -> BoardPlan | None:
    """The opener's plan of the chip arm's one board (None: no chip arm, or several boards):
    its layout (rewritten at the end: the learnt weights) and history database checked."""
    if "chip" not in lc.arms or boards is not None:
        return None
    return plan_from_args(args, use=file_use(args, updates_layout=True), named=_named(args))


def _files(args: argparse.Namespace, lc: LearnConfig, boards: BoardSet | None
           ) -> dict[str, Any]:
    return {k: v for k, v in FILES.items()
            if (k != "learnt.npz" or "chip" in lc.arms and boards is None)
            and (k != "learn.png" or not args.no_figure)}


def _peek(args: argparse.Namespace, job: LearnJob, plan: BoardPlan | None) -> dict[str, Any]:
    """The board of ``plan`` opened once to say who it is (the run's identity: a resumed run
    must be on the same board, in the same mode) and where its files are; without a board of
    its own, the history the device model is read from (the opener's, without HELLO)."""
    if plan is None:
        if ("device" in job.lc.arms or "chip" in job.lc.arms) and not args.model \
                and getattr(args, "boards", None) is None and getattr(args, "dask", None) is None:
            return {"history": plan_from_args(args, use=file_use(args, record=True))
                    .files.history}
        return {}
    with plan.open() as session:
        return {"key": session.identity.resume_key(args.port),
                "mode": check_mode(session.client, job.lc.mode, job.cfg),
                "layout": session.files.layout, "history": session.files.history}


def _identity(args: argparse.Namespace, job: LearnJob, board: dict[str, Any],
              boards: BoardSet | None) -> dict[str, Any]:
    """What a resumed run must match (the configs, the model, the board, the units' cut)."""
    model = job.model.to_dict() if job.model is not None else None
    return {"config": job.cfg.to_dict(), "learn": job.lc.to_dict(), "units": UNITS,
            "model": hashlib.sha256(json.dumps(model, sort_keys=True).encode())
            .hexdigest()[:16],
            "board": {**board["key"], "protocol": args.protocol, "mcu": args.mcu,
                      "layout": str(board["layout"]), "mode": board["mode"]}
            if "key" in board else {"boards": list(boards.ports) if boards.ports else None,
                                    "dask": boards.dask, "protocol": boards.link.protocol,
                                    "mcu": boards.link.mcu}
            if boards is not None else None}


def _learn(args: argparse.Namespace, job: LearnJob, plan: BoardPlan | None,
           boards: BoardSet | None, folder: RunFolder) -> tuple[dict[str, Any], Path | None]:
    """The run: on one board through the job runner; else the arms without a board here and
    the chip sessions on several boards (reached first: a scheduler that does not answer is
    one line before any arm runs). The results document and the board's layout file."""
    if plan is not None:
        done = run_on_board(args, job, plan, folder=folder, seed=args.seed)
        doc = done.result
        doc["history"] = history_block(done)
        doc["link_summary"] = link_summary(doc.get("link", []), args.baud)
        return doc, done.session.files.layout
    if boards is None:
        with progress_display(enabled=not args.json) as progress:
            return run_learning(job.cfg, job.lc, model=job.model, folder=folder,
                                progress=progress, names=NAMES), None
    return _on_boards(args, job, boards, folder), None


def _on_boards(args: argparse.Namespace, job: LearnJob, boards: BoardSet,
               folder: RunFolder) -> dict[str, Any]:
    """The arms without a board here, each chip session on a board
    (:func:`snan_hil.lab.fanout.run_on_boards`, reached first: a scheduler that does not
    answer is one line before any arm runs); recorded once here (``--history``, else the
    user's runs database), each board's history holding its sessions' pulses."""
    history = None
    if recording(args):
        history = Path(args.history).expanduser() if args.history else runs_database()
    with progress_display(enabled=not args.json) as progress:
        options = run_options(args, folder=folder, progress=progress, seed=job.lc.seed)
        done = run_on_boards(job, boards, dataclasses.replace(options, progress=None),
                             host=dataclasses.replace(options, history=history),
                             on_boards=lambda found: print_boards(found))
    doc = done.result
    doc["units"] = board_units(done.units, done.records)
    doc["boards"] = done.boards         # each board's history holds its own sessions
    doc["history"] = {"path": None, "boards": [
        (b.get("session") or {}).get("files", {}).get("history") for b in done.boards]}
    doc["link_summary"] = link_summary(doc.get("link", []), args.baud)
    return doc


def history_block(done: JobRun[Any]) -> dict[str, Any]:
    """Where the run's pulses are recorded: the history database, this run and the earlier
    (killed) runs of its checkpoint, the pulses all of them hold (the ledger's check), those
    this run holds, those recorded from a killed run's journal."""
    this = int(done.recorded.get("pulses", 0))
    return {"path": str(done.history) if done.history is not None else None,
            "run": done.history_run_id,
            "runs": [r["run"] for r in done.earlier_runs] + [done.history_run_id],
            "pulses_recorded": this + sum(int(r["pulses"]) for r in done.earlier_runs),
            "pulses_this_run": this, "recovered": done.recovered}


def _report(args: argparse.Namespace, doc: dict[str, Any], paths: dict[str, str]) -> None:
    if args.json:
        print(json.dumps({"arms": {a: v["curves"] for a, v in doc["arms"].items()},
                          "ledger_total": doc.get("ledger", {}).get("total"),
                          "history": doc.get("history"), "link": doc.get("link_summary"),
                          "files": paths}, default=_jsonable))
        return
    print_summary(doc, paths)


def _jsonable(v: Any) -> Any:
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (np.floating,)):
        return float(v)
    return str(v)


def link_summary(cycles: list[dict], baud: int) -> dict[str, Any] | None:
    """Per learning cycle (train + test) of the chip arm: wall time, bytes on the line, and the
    wire time those bytes take at ``baud`` (8N1: 10 bits a byte) — a real board's floor."""
    if not cycles:
        return None
    walls = [c["wall_s"] for c in cycles]
    wire = [c["wire_bytes"] for c in cycles]
    return {"cycles": len(cycles), "wall_s_median": float(np.median(walls)),
            "wall_s_max": float(np.max(walls)), "wire_bytes_median": float(np.median(wire)),
            "baud": baud, "wire_s_median_at_baud": float(np.median(wire)) * 10 / baud,
            "wire_s_at_115200": float(np.median(wire)) * 10 / 115200,
            "pulses_median": float(np.median([c["pulses"] for c in cycles])),
            "decisions_median": float(np.median([c["decisions"] for c in cycles]))}


def write_outputs(doc: dict, out: Path, cfg, lc: LearnConfig, *, figure: bool) -> dict[str, str]:
    paths: dict[str, str] = {}
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CURVES_HEADER.split(","))
    for arm, a in doc["arms"].items():
        c = a["curves"]
        for cyc in range(len(c["median"])):
            mci = c["median_ci"][cyc] or [None, None]
            sci = c["success_ci"][cyc] or [None, None]
            ppc = (c.get("pulses_per_cycle") or [None] * (cyc + 1))
            w.writerow([arm, cyc, c["sessions"], _n(c["median"][cyc]), _n(mci[0]), _n(mci[1]),
                        _n(c["success"][cyc]), _n(sci[0]), _n(sci[1]),
                        _n(ppc[cyc - 1]) if cyc and len(ppc) >= cyc else ""])
    atomic_write_text(out / "curves.csv", buf.getvalue())
    paths["curves.csv"] = str(out / "curves.csv")
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(SESSIONS_HEADER.split(","))
    for arm, a in doc["arms"].items():
        for k, s in enumerate(a["sessions"]):
            for cyc in range(len(s["test_steps"])):
                tr = cyc - 1
                w.writerow([arm, k, cyc, s["test_steps"][cyc], int(s["test_success"][cyc]),
                            s["train_steps"][tr] if cyc else "",
                            int(s["train_success"][tr]) if cyc else "",
                            s["pulses"][tr] if cyc and s["pulses"] else ""])
    atomic_write_text(out / "sessions.csv", buf.getvalue())
    paths["sessions.csv"] = str(out / "sessions.csv")
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(LEDGER_HEADER.split(","))
    for r in (doc.get("ledger") or {}).get("rows", []):
        w.writerow([r["session"], r["cycle"], r["stage"], r["set"], r["reset"],
                    _n(r["energy_j"]), _n(r["energy_estimate_j"])])
    atomic_write_text(out / "ledger.csv", buf.getvalue())
    paths["ledger.csv"] = str(out / "ledger.csv")
    if figure:
        led = doc.get("ledger") or {}
        per_cycle: dict[int, dict[str, int]] = {}
        for r in led.get("rows", []):
            if r["stage"].startswith("learn"):
                d = per_cycle.setdefault(int(r["cycle"]), {"cycle": int(r["cycle"]),
                                                           "set": 0, "reset": 0})
                d["set"] += r["set"]
                d["reset"] += r["reset"]
        paper = doc.get("paper") or {}
        marks = None
        if paper.get("size"):
            marks = {"median": paper["median"], "success": paper["success"],
                     "label": f"paper Fig. 7 ({paper['size']}x{paper['size']})"}
        else:
            s5 = paper.get("sizes", {}).get("5")
            if s5:
                marks = {"median": {"0": s5[0], "20": s5[1]},
                         "success": {"0": s5[2], "20": s5[3]},
                         "label": "paper Fig. 7, 5x5 (no 6x6 curve)"}
        plot_learning({a: v["curves"] for a, v in doc["arms"].items()},
                      sorted(per_cycle.values(), key=lambda d: d["cycle"]),
                      list(led.get("per_cell", {}).values()), out / "learn.png",
                      title=f"route learning {cfg.grid.rows}x{cfg.grid.cols}, {lc.start} -> "
                            f"{lc.goal}: {lc.sessions} paired sessions per arm, {lc.cycles} "
                            f"cycles (tests without astrocytes)", paper=marks)
        paths["learn.png"] = str(out / "learn.png")
    return paths


def record_learnt(doc: dict, out: Path, layout_path: Path, cfg, lc: LearnConfig
                  ) -> dict[str, str]:
    """``learnt.npz``: the weights each chip session left (read from the chip, clipped to
    0..1), as ``train`` writes weight sets; the layout records the last one as programmed."""
    sessions = doc["arms"]["chip"]["sessions"]
    keys = [tuple(k) for k in doc["synapses"]]
    rows, cols = cfg.grid.rows, cfg.grid.cols
    n_cells = rows * cols
    dense, init = [], []
    for s in sessions:
        w = np.zeros((n_cells, 4))
        for key, v in zip(keys, s["weights"]):
            w[key] = min(max(round(float(v), 6), 0.0), 1.0)
        d = compact_to_dense(w, rows, cols)
        validate_weights(d, rows, cols, what="learnt weights")
        dense.append(d)
    task = LearnTask(cfg, lc)
    for k in range(len(sessions)):
        init.append(compact_to_dense(task.initial(k), rows, cols))
    from snan_hil.host.experiments.route import configs as route_configs, RouteProtocol
    train_cfg, _ = route_configs(cfg, RouteProtocol(cycles=lc.cycles))
    res = TrainResult(weights=np.array(dense), initial=np.array(init), grid=(rows, cols),
                      start=lc.start, goal=lc.goal,
                      seeds=np.arange(len(sessions), dtype=np.int64) + lc.seed,
                      cycles=lc.cycles, steps=np.array([s["train_steps"] for s in sessions]),
                      success=np.array([s["train_success"] for s in sessions], dtype=bool),
                      config=train_cfg, wall_s=float(doc["arm_wall_s"].get("chip", 0.0)),
                      extra={"learnt_on_chip": True, "command": "snan-hil learn",
                             "seed": lc.seed})
    path = save_weights(res, out / "learnt.npz")
    last = dense[-1]
    fresh = Layout.load(layout_path)
    for syn in fresh.synapses:
        wv = float(last[syn.pre, syn.post])
        syn.weight, syn.target_s = wv, float(fresh.weight_map.conductance(wv))
        syn.final_s, syn.ok, syn.stale = syn.target_s, True, None
    fresh.save(layout_path)
    doc["learnt"] = {"weights": str(path), "sets": len(sessions),
                     "layout": str(layout_path), "layout_holds_set": len(sessions) - 1}
    return {"learnt.npz": str(path)}


def _n(v: Any) -> str:
    if v is None:
        return ""
    return f"{float(v):.6g}"


def _print_prediction_and_budget(doc: dict, cyc: int) -> None:
    """How the device-model arm predicts the chip arm's last-cycle route (issue 36: within
    +-10 %), and the learning pulses against the budget."""
    arms = doc["arms"]
    if "device" in arms and "chip" in arms:
        md, mc = (arms[a]["curves"]["median"][cyc] for a in ("device", "chip"))
        if md and mc:
            console.print(f"the device-model arm predicts the chip's cycle-{cyc} route: {md:g} "
                          f"vs {mc:g} steps ({100 * (md / mc - 1):+.0f} %"
                          f"{_ratio_interval(arms, cyc)})", highlight=False)
    budget = (doc.get("config") or {}).get("budget") or {}
    for arm in ("device", "chip"):
        ses = arms.get(arm, {}).get("sessions") or []
        if ses and ses[0].get("pulses"):
            per = [sum(x["pulses"]) for x in ses]
            cell = max(x.get("max_cell_pulses", 0) for x in ses)
            limits = "" if budget.get("session_pulses") is None else (
                f" (budget {budget['session_pulses']} a session, "
                f"{budget.get('cell_pulses')} a cell)")
            console.print(f"{arm} arm: learning pulses per session mean "
                          f"{sum(per) / len(per):.0f}, max {max(per)}; per cell and session "
                          f"max {cell}{limits}", highlight=False)


def _ratio_interval(arms: dict, cyc: int) -> str:
    """``", 95 % interval [lo, hi] over N paired sessions"`` of the device-model arm's median
    route over the chip arm's at test ``cyc`` (:func:`snan_hil.host.intervals.
    median_ratio_interval`: sessions paired by their seeds), "" when an arm has no success."""
    from snan_hil.host.intervals import median_ratio_interval
    whole = [[s for s in arms[a]["sessions"] if len(s["test_steps"]) > cyc]
             for a in ("device", "chip")]
    n = min(len(whole[0]), len(whole[1]))
    steps, ok = ([[s[f][cyc] for s in w[:n]] for w in whole]
                 for f in ("test_steps", "test_success"))
    got = median_ratio_interval(steps[0], ok[0], steps[1], ok[1], seed=1) if n else None
    if got is None:
        return ""
    lo, hi = got[1]
    return (f"; 95 % interval {100 * (lo - 1):+.0f} % .. {100 * (hi - 1):+.0f} % over {n} "
            f"paired sessions")


def print_summary(doc: dict, paths: dict[str, str]) -> None:
    arms = doc["arms"]
    cyc = doc["config"]["cycles"]
    t = Table(title=f"route learning {doc['task']['grid'][0]}x{doc['task']['grid'][1]}, "
                    f"{doc['task']['start']} -> {doc['task']['goal']}: tests without "
                    f"astrocytes, median of the successful tests [95 % CI] / success")
    t.add_column("arm")
    shown = sorted({0, min(5, cyc), cyc})
    for c in shown:
        t.add_column(f"cycle {c}", justify="right")
    def cell(c: dict, k: int) -> str:
        m, ci = c["median"][k], c["median_ci"][k]
        med = "-" if m is None else f"{m:g}"
        rng = "" if ci is None else f" [{ci[0]:g}, {ci[1]:g}]"
        return f"{med}{rng} / {100 * c['success'][k]:.0f} %"
    for arm, a in arms.items():
        c = a["curves"]
        t.add_row(f"{arm} ({c['sessions']})", *[cell(c, k) for k in shown])
    console.print(t)
    _print_prediction_and_budget(doc, cyc)
    led = doc.get("ledger")
    if led:
        h = doc.get("history") or {}
        mode = doc.get("chip_mode")
        arm = "chip arm" if mode is None else f"chip arm (--mode {str(mode).replace('_', '-')})"
        if h.get("boards"):             # several boards: each board's history has its own
            console.print(f"{arm}: {led['total']} pulses in the ledger; each board's history "
                          "database records its own: " + ", ".join(map(str, h["boards"])),
                          highlight=False, soft_wrap=True)
        runs = h.get("runs") or [h.get("run")]
        which = (f"run {runs[0]}" if len(runs) == 1 else
                 "runs " + ", ".join(str(r) for r in runs) + ": the killed and resumed parts")
        rec_note = f"; {h['recovered']} recovered from the journal" if h.get("recovered") else ""
        if h.get("boards"):
            pass
        elif h.get("pulses_recorded") is not None:
            console.print(f"{arm}: {led['total']} pulses in the ledger, "
                          f"{h.get('pulses_recorded')} in the history database "
                          f"({which}{rec_note})", highlight=False)
        else:
            console.print(f"{arm}: {led['total']} pulses in the ledger (none recorded "
                          "in a history database)", highlight=False)
        ls = doc.get("link_summary")
        if ls:
            console.print(f"per learning cycle: {ls['wall_s_median']:.2f} s wall (median), "
                          f"{ls['wire_bytes_median']:.0f} bytes on the line = "
                          f"{ls['wire_s_at_115200']:.2f} s at 115200 baud, "
                          f"{ls['pulses_median']:.0f} pulses, {ls['decisions_median']:.0f} "
                          "decisions", highlight=False)
    if doc.get("learnt"):
        ln = doc["learnt"]
        console.print(f"learnt weights: {ln['weights']} ({ln['sets']} sets; the layout holds "
                      f"set {ln['layout_holds_set']}: compare --weights {ln['weights']} "
                      f"--weight-set {ln['layout_holds_set']} --no-program)", highlight=False)
    console.print("written: " + ", ".join(paths.values()), highlight=False)
