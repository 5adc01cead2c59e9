"""``snan-hil run``: launch the agent on the 6x6 task in one scenario.

``sw_*`` use the weights as numbers; ``hw_*`` read every synapse from the crossbar at --port
(which must hold that weight set: ``snan-hil program-weights W --weight-set K --port P`` first).
The launch model is checked against the training config stored in the weights file
(:mod:`snan_hil.host.hil.trained_config`; ``--accept-config-diff`` to launch a different one).
Example: ``snan-hil run --scenario hw_astro --weights weights.npz --weight-set 3 --port emu``.
"""

from __future__ import annotations

import argparse
import json
import shlex
from pathlib import Path
from typing import Any

from rich.table import Table

from snan_hil.common.version import __version__
from snan_hil.host.intervals import METHOD_TEXT, format_interval
from snan_hil.board.session import BoardSession
from snan_hil.calibration.layout import LayoutError
from snan_hil.calibration.weights_io import load_weight_set
from snan_hil.common.errors import UserError
from snan_hil.host.calcium_trace import calcium_trace
from snan_hil.host.config import SnanConfig
from snan_hil.host.hil.synapses import (HW_MODES, check_mode_for_protocol,
                                        check_mode_for_scenarios)
from snan_hil.host.hil.compare import check_weights_grid, hw_totals
from snan_hil.host.hil.config import SCENARIOS, load_hil_config
from snan_hil.host.hil.report import speed_energy_table
from snan_hil.host.hil.runner import ScenarioResult, check_launches, scenario_parts
from snan_hil.host.hil.scenario import ScenarioConfig, ScenarioJob
from snan_hil.host.hil.trained_config import check_trained_config
from snan_hil.files.outputs import Outputs
from snan_hil.lab.group_run import run_group_job
from snan_hil.lab.opener import BoardPlan
from snan_hil.tools.commands._board import file_use, plan_from_args
from snan_hil.tools.commands._history import add_history_arguments
from snan_hil.tools.commands._group import add_group_option, group_plans, group_ports
from snan_hil.tools.commands._job import run_on_board, run_options
from snan_hil.tools.commands._options import (add_conversions_option, add_mode_option,
                                              check_conversions,
                                              add_weight_set_option,
                                              check_set_conflicts)
from snan_hil.tools.commands._run import metadata_from_args
from snan_hil.tools.commands.train import add_accept_option, add_hil_config_arguments
from snan_hil.tools.animate import ANIMATION, animate_trace, check_gif_name
from snan_hil.tools.console import console, err_console, progress_display
from snan_hil.tools.ports import add_port_arguments, board_options

NAME = "run"
RUN_FORMAT = "snan-hil-run/1"
HELP = "launch the agent N times on the 6x6 task: software or crossbar, with or without astrocytes"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scenario", required=True, choices=SCENARIOS,
                        help="sw_* = weights as numbers, hw_* = synapses read from the crossbar")
    parser.add_argument("--weights", required=True, metavar="FILE",
                        help="weights from 'snan-hil train' (.npz) or a .npy")
    add_weight_set_option(parser, help="weight set in the file", old_set=False)
    parser.add_argument("--launches", type=int, default=10, help="launches")
    parser.add_argument("--seed", type=int, default=1,
                        help="launch seed (launch l of set K uses trial K*1000+l)")
    add_mode_option(parser, HW_MODES)
    add_conversions_option(parser)
    parser.add_argument("--layout", default=None,
                        help="layout file of the chip (default: the port's, see program-weights)")
    add_hil_config_arguments(parser)
    add_accept_option(parser)
    add_port_arguments(parser)
    parser.add_argument("--animate", metavar="GIF", default=None,
                        help="write an animation of one launch: the agent on the grid over each "
                             "cell's astrocyte calcium (default: none)")
    parser.add_argument("--animate-launch", type=int, default=None, metavar="L",
                        help="with --animate: the launch it shows (default: 0)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    add_history_arguments(parser, default="cells")
    add_group_option(parser)


def hardware_record(res: ScenarioResult, session: BoardSession, n_cells: int
                    ) -> dict[str, Any]:
    """The hardware part of ``run --json``, recorded as ``compare.json`` records it: ``board``
    (identity from INFO: board_id, firmware_version, conversion_us; per decision: reads,
    line time, and — from the board's CLOCK — virtual and on-board time, array energy, or,
    without CLOCK (legacy protocol), the wire-limited time and rate of the speed table's
    "board over the line, wire-limited" row), ``read_stats`` and ``speed_energy``
    (:func:`~snan_hil.host.hil.report.speed_energy_table` of these launches)."""
    baud = session.baud
    hw = hw_totals([res], baud)
    if hw:
        hw["conversion_us"] = float(session.info.conversion_us)
    table = speed_energy_table(n_cells, hw=hw or None)
    dec = hw.get("decisions") or 0
    per = (lambda v: None if v is None or not dec else v / dec)  # noqa: E731
    board: dict[str, Any] = {
        **session.identity.to_dict(), "conversion_us": float(session.info.conversion_us),
        "protocol": session.protocol, "baud": baud, "decisions": dec,
        "reads_per_decision": per(hw.get("requests")),
        "spikes_per_decision": per(hw.get("spikes")),
        "wire_us_per_decision": per(hw.get("wire_us")),
        "virtual_us_per_decision": per(hw.get("virtual_us")),
        "board_us_per_decision": per(hw["virtual_us"] - hw["wire_us"])
        if hw.get("virtual_us") is not None and hw.get("wire_us") is not None else None,
        "energy_j_per_decision": per(hw.get("energy_j")),
        "wire_limited_us_per_decision": None, "wire_limited_decisions_per_s": None}
    for row in table["rows"]:
        if row["implementation"] == "board over the line, wire-limited":
            board["wire_limited_us_per_decision"] = row["time_per_decision_us"]
            board["wire_limited_decisions_per_s"] = 1e6 / row["time_per_decision_us"]
    return {"board": board, "read_stats": res.read_stats, "speed_energy": table,
            "session": session.snapshot()}


def run(args: argparse.Namespace) -> int:
    check_conversions(args)
    ports = group_ports(args, refusals=[
        (not scenario_parts(args.scenario)[0],
         f"--group runs a hardware scenario over a chip group; {args.scenario} runs in "
         "software: leave --group out"),
        (args.mode not in (None, "on-board"), f"--mode {args.mode}: a chip group runs the "
         "on-board decision windows (each on the chip of its input neuron); leave --mode out")])
    job, trained = _job(args, ports)
    anim = _animation_output(args)
    if ports is not None:               # one network over a chip group (docs/multiboard.md)
        plans = group_plans(args, ports, Outputs({"--weights": args.weights}),
                            updates_layout=False, inputs={"--weights": args.weights})
        with progress_display(enabled=not args.json) as show:
            done = run_group_job(job, plans, run_options(args, progress=show, seed=args.seed))
        _notes(args, trained)
        res, session, block = done.result, done.session, done.run_block()
    elif job.hw:                        # the board's refusals first, then the notes
        done = run_on_board(args, job, _plan(args), seed=args.seed)
        _notes(args, trained)
        res, session, block = done.result, done.session, done.run_block()
    else:
        _notes(args, trained)
        with progress_display(enabled=not args.json) as show:
            res = job.run_without_board(show)
        session, block = None, {**metadata_from_args(args).to_dict(), "history_run_id": None}
    hil, astro = job.hil, job.astro
    if anim is not None:
        _write_animation(args, res, hil.launch_config(astro), job.goal, anim)
    out = _record(args, job, res, trained, session) | {"run": block}
    if anim is not None:
        out["animation"] = str(anim)
    if args.json:
        print(json.dumps(out))
        return 0
    _print_run(args, res, out, hil.model.grid.max_steps, job.start, job.goal, anim)
    return 0


def _job(args: argparse.Namespace, group: list[str] | None = None
         ) -> tuple[ScenarioJob, Any]:
    """The scenario's job from the options, checked before any I/O (UserError, one line),
    and the check of the launch model against the weights' training config."""
    hw, astro = scenario_parts(args.scenario)
    # the scenario decides astro.enabled of every launch (HilConfig.launch_config)
    check_set_conflicts(args.overrides, {"astro.enabled": (f"--scenario {args.scenario}",
                                                           astro)})
    check_mode_for_scenarios((args.scenario,), args.mode)
    if hw:
        check_mode_for_protocol(args.protocol, args.mode)
    check_launches(args.launches)
    _w, meta = load_weight_set(args.weights, args.set_index)     # validated before any I/O
    hil = load_hil_config(args.config, args.overrides)
    check_weights_grid(meta, hil, args.weights)
    trained = check_trained_config(meta, hil, args.weights, accept=args.accept_config_diff)
    cfg = ScenarioConfig(args.scenario, args.weights, args.set_index, args.launches, args.seed,
                         args.mode.replace("-", "_") if args.mode else None,
                         conversions=args.conversions)
    return ScenarioJob(cfg, hil, program_hint=_program_hint(args, group)), trained


def _notes(args: argparse.Namespace, trained: Any) -> None:
    for line in trained.notes(args.weights):
        err_console.print(line, markup=False, highlight=False, soft_wrap=True)


def _record(args: argparse.Namespace, job: ScenarioJob, res: ScenarioResult, trained: Any,
            session: BoardSession | None) -> dict[str, Any]:
    """``run --json`` (without the run block)."""
    hil, hw = job.hil, job.hw
    out = res.summary() | {
        "format": RUN_FORMAT, "snan_hil_version": __version__,
        "start": job.start, "goal": job.goal, "step_limit": hil.model.grid.max_steps,
        "weights": str(args.weights), "n_sets": job.meta["n_sets"],
        "set_seed": job.meta.get("seed"),
        "port": args.port if hw else None, "protocol": args.protocol if hw else None,
        "baud": args.baud if hw else None,
        "layout": str(session.files.layout) if session is not None else None,
        "config": hil.to_dict(), "launch_config": hil.launch_config(job.astro).to_dict(),
        "trained_config_check": trained.to_dict(),
        "launch_details": [L.to_dict() for L in res.launches],
    }
    if session is not None:
        out.update(hardware_record(res, session, hil.model.n_cells))
    return out


def _animation_output(args: argparse.Namespace) -> Path | None:
    """The --animate GIF, checked (name, launch, not an input) before any work; sets
    ``args.animate_launch`` to 0 when not given."""
    anim = None
    if args.animate_launch is not None and not args.animate:
        raise UserError("--animate-launch picks the launch of an animation: give --animate "
                        "FILE.gif as well")
    if args.animate_launch is None:
        args.animate_launch = 0
    if args.animate:
        check_gif_name("--animate", args.animate)
        if not 0 <= args.animate_launch < args.launches:
            raise UserError(f"--animate-launch {args.animate_launch}: give 0.."
                            f"{args.launches - 1} (one of the {args.launches} launches)")
        anim = Outputs({"--weights": args.weights}).file("--animate", args.animate, ANIMATION)
    return anim


def _write_animation(args: argparse.Namespace, res: ScenarioResult, cfg: SnanConfig,
                     goal: int, anim: Path) -> None:
    launch = res.launches[args.animate_launch]
    trace = calcium_trace(cfg, launch.path, seed=args.seed, trial=launch.trial)
    animate_trace(trace, [goal], anim,
                  title=f"{args.scenario}, set {args.set_index}, launch {launch.launch} "
                        f"(seed {args.seed}): {launch.steps} steps, "
                        f"{'reached the goal' if launch.success else 'failed'}")


def _print_run(args: argparse.Namespace, res: ScenarioResult, out: dict[str, Any],
               max_steps: int, start: int, goal: int, anim: Path | None) -> None:
    t = Table(title=f"{args.scenario}: set {args.set_index} of {args.weights}, cell {start} -> "
                    f"{goal}, {args.launches} launches (seed {args.seed})")
    for col in ("launch", "path length", "reached goal"):
        t.add_column(col, justify="right")
    for L in res.launches:
        t.add_row(str(L.launch), str(L.steps), "yes" if L.success else
                  f"no (limit {max_steps})")
    console.print(t)
    med = "-" if res.median_steps is None else f"{res.median_steps:g}"
    console.print(f"median path length (successful launches): {med} steps "
                  f"{format_interval(out['median_steps_ci'])}; success "
                  f"{100 * res.success_rate:.0f} % "
                  f"{format_interval(out['success_rate_ci'], percent=True, digits=0)} "
                  f"(95 % intervals: {METHOD_TEXT})", highlight=False)
    b = out.get("board") or {}
    if b.get("virtual_us_per_decision") is not None:
        console.print(f"board per decision: {b['virtual_us_per_decision'] / 1e3:.1f} ms incl. UART"
                      + ("" if b["board_us_per_decision"] is None else
                         f", {b['board_us_per_decision'] / 1e3:.2f} ms on board")
                      + f", {b['energy_j_per_decision'] * 1e9:.1f} nJ array energy, "
                        f"{b['spikes_per_decision']:.0f} input spikes")
    elif b.get("wire_limited_us_per_decision") is not None:
        console.print(f"board per decision: no CLOCK over this protocol; wire-limited at "
                      f"{args.baud} baud {b['wire_limited_us_per_decision'] / 1e3:.2f} ms "
                      f"({b['wire_limited_decisions_per_s']:.1f} decisions/s: "
                      f"{b['reads_per_decision']:.1f} reads, line time + documented "
                      "conversion time; a real board is at most this fast)")
    if anim is not None:
        console.print(f"animation written to {anim}", highlight=False)


def _program_hint(args: argparse.Namespace, group: list[str] | None = None) -> str:
    if group is not None:
        model = "".join(f" {opt} {shlex.quote(str(v))}" for opt, v in (
            [("--config", args.config)] if getattr(args, "config", None) else [])
            + [("--set", o) for o in getattr(args, "overrides", None) or []])
        return (f"program the group first: snan-hil compare --weights "
                f"{shlex.quote(args.weights)}{model} --weight-set {args.set_index} --group "
                f"{shlex.quote(','.join(group))} --scenarios {args.scenario} --launches 1 "
                "--out DIR")
    return (f"program the chip first: snan-hil program-weights {shlex.quote(args.weights)} "
            f"--weight-set {args.set_index} {board_options(args)}")


def _plan(args: argparse.Namespace) -> BoardPlan:
    """The board's plan; a layout known before the port opens must exist (LayoutError, one
    line, before opening it)."""
    plan = plan_from_args(args, use=file_use(args), weights=args.weights)
    known = plan.files.layout
    if known is not None and not known.is_file():          # before opening the port
        raise LayoutError(f"no layout for port {args.port} ({known}); {_program_hint(args)}")
    return plan
